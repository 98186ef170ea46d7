// test_client_session.cpp — ClientSession (client/session.h), the client's
// protocol core, driven without sockets: control bytes and datagrams built
// with the FlatBuffers builders of proto/wire.h go in, what it writes to its
// Outbox (control messages, datagrams) and its phase, events and counters
// come out. Time is the test's (the session's clock included).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include "crypto.h"
#include "session.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
namespace fs = std::filesystem;

namespace {

double g_now = 100;
double test_clock() { return g_now; }

constexpr uint64_t kSession = 77, kToken = 99, kAssetId = 0x5e551017'7e570001ull;
constexpr uint64_t kAssetSize = 100000;  // 4 requests of at most MAX_ASSET_CHUNK (32768)

using Bytes = std::vector<uint8_t>;

// One control message as the server frames it (4-byte length + body).
template <class T>
Bytes control(flatbuffers::FlatBufferBuilder& b, wire::ControlBody type, flatbuffers::Offset<T> body) {
    b.Finish(wire::CreateControl(b, type, body.Union()), wire::ControlIdentifier());
    Bytes out;
    frame_control(b, out);
    return out;
}

template <class T>
Bytes datagram(flatbuffers::FlatBufferBuilder& b, uint32_t seq, uint32_t send_time, wire::DatagramBody type,
               flatbuffers::Offset<T> body) {
    b.Finish(wire::CreateDatagram(b, seq, send_time, type, body.Union()), wire::DatagramIdentifier());
    return {b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize()};
}

// A Welcome: one asset (Fox.glb, kAssetSize bytes), 30 ticks/s, and the
// datagram keys when given.
Bytes welcome(const Bytes& keys = {}) {
    flatbuffers::FlatBufferBuilder b;
    auto name = b.CreateString("Fox.glb");
    wire::AssetBuilder ab(b);
    ab.add_asset_id(kAssetId);
    ab.add_name(name);
    ab.add_size(kAssetSize);
    ab.add_bone_count(24);
    const std::vector<flatbuffers::Offset<wire::Asset>> list{ab.Finish()};
    auto assets = b.CreateVector(list);
    flatbuffers::Offset<flatbuffers::Vector<uint8_t>> k;
    if (!keys.empty()) k = b.CreateVector(keys);
    wire::WelcomeBuilder wb(b);
    wb.add_version(PROTOCOL_VERSION);
    wb.add_session_id(kSession);
    wb.add_udp_token(kToken);
    wb.add_udp_port(7778);
    wb.add_tick_rate(30.0f);
    wb.add_assets(assets);
    if (!keys.empty()) wb.add_datagram_keys(k);
    return control(b, wire::ControlBody::Welcome, wb.Finish());
}

Bytes refuse(const std::string& why) {
    flatbuffers::FlatBufferBuilder b;
    auto r = wire::CreateRefuse(b, PROTOCOL_VERSION, b.CreateString(why));
    return control(b, wire::ControlBody::Refuse, r);
}

// InstanceAdded: instance `id` of asset 0, live poses.
Bytes instance_added(uint16_t id) {
    flatbuffers::FlatBufferBuilder b;
    wire::InstanceBuilder ib(b);
    ib.add_id(id);
    ib.add_asset(0);
    ib.add_speed(1.0f);
    const std::vector<flatbuffers::Offset<wire::Instance>> list{ib.Finish()};
    auto m = wire::CreateInstanceAdded(b, b.CreateVector(list));
    return control(b, wire::ControlBody::InstanceAdded, m);
}

// A Frame datagram carrying no chunk.
Bytes frame(uint32_t seq, uint32_t tick, uint32_t send_time = 0) {
    Bytes d;
    write_frame_datagram(seq, send_time, tick, false, {}, {}, d);
    return d;
}

// The control messages the session wrote (verified), taken out of the Outbox.
std::vector<const wire::Control*> take_control(Outbox& out, std::vector<Bytes>& keep) {
    keep.clear();
    size_t at = 0;
    uint32_t n = 0;
    while (read_length({out.control.data() + at, out.control.size() - at}, n)) {
        keep.emplace_back(out.control.begin() + long(at) + 4, out.control.begin() + long(at) + 4 + n);
        at += 4 + size_t(n);
    }
    EXPECT_EQ(at, out.control.size()) << "a control message cut short";
    out.control.clear();
    std::vector<const wire::Control*> msgs;
    for (const Bytes& m : keep) {
        msgs.push_back(verify_control(m));
        EXPECT_NE(msgs.back(), nullptr);
    }
    return msgs;
}

// The datagrams the session queued, taken out of the Outbox.
std::vector<Bytes> take_datagrams(Outbox& out) {
    std::vector<Bytes> d;
    for (size_t i = 0; i < out.datagrams(); ++i) d.emplace_back(out.datagram(i).begin(), out.datagram(i).end());
    out.clear_datagrams();
    return d;
}

class ClientSessionTest : public ::testing::Test {
protected:
    void SetUp() override {
        g_now = 100;
        cfg.cache_dir = (fs::temp_directory_path() / ("progskin-session-test-" + std::to_string(::getpid()))).string();
        cfg.connect_timeout = 10;
        cfg.stream_timeout = 5;
    }
    void TearDown() override { fs::remove_all(cfg.cache_dir); }

    ClientSession& make() {
        s = std::make_unique<ClientSession>(cfg, out, test_clock);
        return *s;
    }
    // Channel up (Hello taken), then the Welcome: Binding.
    ClientSession& welcomed(const Bytes& keys = {}) {
        make();
        s->start(g_now, "server:7777");
        s->on_channel_ready();
        out.control.clear();
        s->on_control_bytes(welcome(keys), g_now);
        EXPECT_EQ(s->phase(), SessionPhase::Binding) << s->error();
        out.control.clear();  // the AssetRequests
        return *s;
    }
    void feed(const Bytes& d, bool from_server = true) { s->on_datagram(d, from_server, g_now); }
    bool raised(ClientEvent::Type t) const {
        for (const ClientEvent& e : s->events())
            if (e.type == t) return true;
        return false;
    }

    ClientConfig cfg;
    Outbox out;
    std::unique_ptr<ClientSession> s;
    std::vector<Bytes> keep;
};

}  // namespace

TEST_F(ClientSessionTest, WelcomeConnectsAndRequestsTheUncachedAsset) {
    ClientSession& c = make();
    EXPECT_EQ(c.state(), ClientState::Idle);
    c.start(g_now, "server:7777");
    EXPECT_EQ(c.phase(), SessionPhase::OpeningChannel);
    c.on_channel_ready();
    EXPECT_EQ(c.phase(), SessionPhase::AwaitWelcome);
    auto hello = take_control(out, keep);
    ASSERT_EQ(hello.size(), 1u);
    ASSERT_EQ(hello[0]->body_type(), wire::ControlBody::Hello);
    EXPECT_EQ(hello[0]->body_as_Hello()->version(), PROTOCOL_VERSION);
    EXPECT_EQ(hello[0]->body_as_Hello()->client_name()->str(), cfg.name);

    // The Welcome in two reads: nothing happens until it is whole.
    const Bytes w = welcome();
    c.on_control_bytes(std::span(w).first(3), g_now);
    EXPECT_EQ(c.phase(), SessionPhase::AwaitWelcome);
    EXPECT_TRUE(out.control.empty());
    c.on_control_bytes(std::span(w).subspan(3), g_now);
    EXPECT_TRUE(raised(ClientEvent::Type::Connected));
    EXPECT_EQ(c.phase(), SessionPhase::Binding);
    EXPECT_EQ(c.state(), ClientState::Connecting);
    EXPECT_EQ(c.udp_port(), 7778);
    EXPECT_DOUBLE_EQ(c.tick_rate(), 30.0);
    ASSERT_EQ(c.asset_names().size(), 1u);
    EXPECT_EQ(c.asset_names()[0], "Fox.glb");
    ASSERT_EQ(c.assets().size(), 1u);
    EXPECT_EQ(c.assets()[0], nullptr);

    // Not cached: four chunks requested in flight, in order.
    auto requests = take_control(out, keep);
    ASSERT_EQ(requests.size(), 4u);
    uint64_t offset = 0;
    for (const wire::Control* m : requests) {
        ASSERT_EQ(m->body_type(), wire::ControlBody::AssetRequest);
        const wire::AssetRequest* r = m->body_as_AssetRequest();
        EXPECT_EQ(r->asset_id(), kAssetId);
        EXPECT_EQ(r->offset(), offset);
        EXPECT_EQ(r->length(), std::min<uint64_t>(MAX_ASSET_CHUNK, kAssetSize - offset));
        offset += r->length();
    }
    EXPECT_EQ(offset, kAssetSize);
}

TEST_F(ClientSessionTest, RefuseFailsWithReasonRefused) {
    ClientSession& c = make();
    c.start(g_now, "server:7777");
    c.on_channel_ready();
    out.control.clear();
    c.on_control_bytes(refuse("server full"), g_now);
    EXPECT_EQ(c.state(), ClientState::Failed);
    EXPECT_EQ(c.fail_reason(), FailReason::Refused);
    EXPECT_EQ(c.error(), "server refused the connection: server full");
    EXPECT_TRUE(raised(ClientEvent::Type::Failed));
    // Nothing more is read or sent.
    c.on_control_bytes(welcome(), g_now);
    EXPECT_EQ(c.state(), ClientState::Failed);
    EXPECT_TRUE(out.control.empty());
}

TEST_F(ClientSessionTest, ConnectingPhasesTimeOutWithTheirMessage) {
    ClientSession& c = make();
    c.start(g_now, "server:7777");
    c.update(g_now + 9);
    EXPECT_EQ(c.phase(), SessionPhase::OpeningChannel);
    c.update(g_now + 11);
    EXPECT_EQ(c.fail_reason(), FailReason::Timeout);
    EXPECT_EQ(c.error(), "cannot connect to server:7777: timed out");

    ClientSession& t = make();
    t.start(g_now, "server:7777");
    t.on_transport_connected();
    EXPECT_EQ(t.phase(), SessionPhase::Handshaking);
    t.update(g_now + 11);
    EXPECT_EQ(t.error(), "TLS handshake with server:7777: timed out");

    ClientSession& p = make();  // plain channel closed before the Welcome
    p.start(g_now, "server:7777");
    p.on_channel_ready();
    p.on_channel_closed();
    EXPECT_EQ(p.fail_reason(), FailReason::ChannelLost);
    EXPECT_NE(p.error().find("does it expect TLS?"), std::string::npos) << p.error();
}

TEST_F(ClientSessionTest, FrameBeforeBindAckBindsTheStream) {
    ClientSession& c = welcomed();
    c.update(g_now);
    auto sent = take_datagrams(out);
    ASSERT_EQ(sent.size(), 1u);
    const wire::Datagram* bind = verify_datagram(sent[0]);
    ASSERT_NE(bind, nullptr);
    ASSERT_EQ(bind->body_type(), wire::DatagramBody::Bind);
    EXPECT_EQ(bind->body_as_Bind()->session_id(), kSession);
    EXPECT_EQ(bind->body_as_Bind()->token(), kToken);

    // From another address: counted as malformed, not bound.
    feed(frame(5, 1), false);
    EXPECT_EQ(c.stats(g_now).malformed, 1u);
    EXPECT_EQ(c.phase(), SessionPhase::Binding);
    c.update(g_now + 0.1);  // still binding, 0.2 s apart
    EXPECT_EQ(out.datagrams(), 0u);

    feed(frame(5, 1));
    EXPECT_EQ(c.phase(), SessionPhase::Streaming);
    EXPECT_EQ(c.state(), ClientState::Streaming);
    EXPECT_EQ(c.stats(g_now).datagrams, 1u);
    // Bound: no more Binds (no character waits for frames).
    c.update(g_now + 0.3);
    for (const Bytes& d : take_datagrams(out)) EXPECT_NE(verify_datagram(d)->body_type(), wire::DatagramBody::Bind);
}

TEST_F(ClientSessionTest, DuplicateDatagramIsCounted) {
    ClientSession& c = welcomed();
    feed(frame(5, 1));
    feed(frame(5, 1));
    EXPECT_EQ(c.stats(g_now).duplicates, 1u);
    feed(frame(3, 1));  // older but new: taken
    EXPECT_EQ(c.stats(g_now).duplicates, 1u);
    feed(frame(3, 1));
    EXPECT_EQ(c.stats(g_now).duplicates, 2u);
    EXPECT_EQ(c.stats(g_now).datagrams, 2u);
    EXPECT_EQ(c.stats(g_now).malformed, 0u);
}

TEST_F(ClientSessionTest, NoDatagramForStreamTimeoutWithCharactersLosesTheStream) {
    ClientSession& c = welcomed();
    c.on_control_bytes(instance_added(0), g_now);
    ASSERT_EQ(c.state(), ClientState::Connecting) << c.error();
    feed(frame(1, 1));
    const double last = g_now;
    g_now = last + 4;
    c.update(g_now);
    EXPECT_EQ(c.state(), ClientState::Streaming) << c.error();
    g_now = last + 6;
    c.update(g_now);
    EXPECT_EQ(c.state(), ClientState::Failed);
    EXPECT_EQ(c.fail_reason(), FailReason::StreamLost);
    EXPECT_EQ(c.error(), "lost the stream: no datagram for 6 s");

    // Without characters, silence is no loss.
    g_now = 100;
    ClientSession& quiet = welcomed();
    feed(frame(1, 1));
    quiet.update(g_now + 6);
    EXPECT_EQ(quiet.state(), ClientState::Streaming) << quiet.error();
}

TEST_F(ClientSessionTest, AcksCarryTheReceivedSequenceBits) {
    ClientSession& c = welcomed();
    feed(frame(10, 1, 1000));
    feed(frame(12, 3, 1200));  // 11 lost
    feed(frame(13, 4, 1300));
    const double arrival = g_now;
    c.update(g_now + 0.05);
    const wire::Ack* ack = nullptr;
    auto sent = take_datagrams(out);
    for (const Bytes& d : sent)
        if (const wire::Datagram* g = verify_datagram(d); g && g->body_type() == wire::DatagramBody::Ack) ack = g->body_as_Ack();
    ASSERT_NE(ack, nullptr);
    EXPECT_EQ(ack->session_id(), kSession);
    EXPECT_EQ(ack->token(), kToken);
    EXPECT_EQ(ack->ack(), 13u);
    EXPECT_EQ(ack->ack_bits(), 0b101u);  // 12 received, 11 not, 10 received
    EXPECT_EQ(ack->echo_time_us(), 1300u);
    EXPECT_NEAR(double(ack->hold_us()), 50000.0, 2.0);
    EXPECT_DOUBLE_EQ(c.stats(arrival).loss, 0.25);

    // Acked: the next update sends none until a frame arrives.
    c.update(g_now + 0.1);
    for (const Bytes& d : take_datagrams(out)) EXPECT_NE(verify_datagram(d)->body_type(), wire::DatagramBody::Ack);
}

TEST_F(ClientSessionTest, DatagramKeysSealBothWaysAndNeedTls) {
    Bytes keys(2 * crypto::KEY_BYTES, 0x11);
    std::fill(keys.begin() + crypto::KEY_BYTES, keys.end(), 0x22);  // server->client, then client->server
    crypto::Key down{}, up{};
    down.fill(0x11);
    up.fill(0x22);

    make();  // keys over a plain channel
    s->start(g_now, "server:7777");
    s->on_channel_ready();
    s->on_control_bytes(welcome(keys), g_now);
    EXPECT_EQ(s->fail_reason(), FailReason::BadServerData);
    EXPECT_EQ(s->error(), "server sent datagram keys over an unencrypted channel");

    cfg.tls = true;
    ClientSession& c = welcomed(keys);
    c.update(g_now);
    auto sent = take_datagrams(out);
    ASSERT_EQ(sent.size(), 1u);
    EXPECT_EQ(verify_datagram(sent[0]), nullptr);  // sealed
    crypto::Opener opener(up);
    Bytes plain;
    uint64_t seq = 0;
    ASSERT_EQ(crypto::open_datagram(opener, kSession, PROTOCOL_VERSION, sent[0], plain, seq), crypto::OpenResult::ok);
    ASSERT_NE(verify_datagram(plain), nullptr);
    EXPECT_EQ(verify_datagram(plain)->body_type(), wire::DatagramBody::Bind);

    feed(frame(1, 1));  // unsealed: dropped
    EXPECT_EQ(c.stats(g_now).malformed, 1u);
    EXPECT_EQ(c.phase(), SessionPhase::Binding);
    crypto::Sealer sealer(down);
    Bytes sealed;
    crypto::seal_datagram(sealer, kSession, PROTOCOL_VERSION, frame(1, 1), sealed);
    feed(sealed);
    EXPECT_EQ(c.phase(), SessionPhase::Streaming);
    EXPECT_EQ(c.stats(g_now).wire_bytes, sealed.size() + UDP_IP_OVERHEAD);
    feed(sealed);  // replayed (a duplicate on the network): dropped, counted a duplicate
    EXPECT_EQ(c.stats(g_now).malformed, 1u);
    EXPECT_EQ(c.stats(g_now).duplicates, 1u);
    Bytes forged;
    crypto::seal_datagram(sealer, kSession, PROTOCOL_VERSION, frame(2, 1), forged);
    forged[forged.size() / 2] ^= 1;  // one bit of the ciphertext: the tag fails
    feed(forged);
    EXPECT_EQ(c.stats(g_now).malformed, 2u);
    EXPECT_EQ(c.stats(g_now).duplicates, 1u);
}

// apply_frame, the one frame application: epochs and root blocks reach the
// pose buffers (never interpolated across an epoch); chunks of instances
// without a target are skipped and counted.
TEST(ClientSessionFrames, ApplyFrameKeepsEpochsAndRoots) {
    const RecordFormat fmt;
    auto frame_at = [&](uint32_t tick, uint8_t epoch, double x) {
        RootPose root;
        root.position = {x, 0.0, 0.0};
        Bytes absolute(ROOT_BYTES), payload;
        EXPECT_TRUE(encode_root(root, absolute.data()));
        Bytes blocks, records;
        write_root(absolute.data(), 0, nullptr, nullptr, blocks);  // an absolute root block (root_block.h)
        BitWriter w(records);  // the identity, parent-relative (bone_record.h): 12 bits each
        write_record(RecordInts{}, false, w);
        write_record(RecordInts{}, false, w);
        // Instance 0: root block, bone 0; instance 1 (no target): bone 0.
        std::vector<ChunkOut> chunks(2);
        chunks[0].head = ChunkHead{0, 0, 1, epoch, CHUNK_ROOT, {1}};
        chunks[0].rec_bits = 12;
        chunks[0].block_bytes = blocks.size();
        chunks[1].head = ChunkHead{1, 0, 1, 0, 0, {1}};
        chunks[1].rec_from = 12;
        chunks[1].rec_bits = 12;
        chunks[1].block_from = blocks.size();
        EXPECT_TRUE(write_frame_payload(chunks, 0, records.data(), blocks.data(), payload));
        Bytes d;
        write_frame_datagram(tick, 0, tick, false, {}, payload, d);
        return d;
    };
    auto root_at_11 = [&](uint8_t second_epoch) {
        PoseBuffer buffer(chain_format(1, fmt));
        const std::vector<PoseTarget> targets{{&buffer, fmt.size()}};
        for (auto [tick, epoch, x] : {std::tuple{10u, uint8_t(1), 0.0}, std::tuple{12u, second_epoch, 2.0}}) {
            const Bytes d = frame_at(tick, epoch, x);
            FrameDatagram fd;
            EXPECT_TRUE(read_frame_datagram(d, fd));
            const FrameApplied a = apply_frame(fd, targets);
            EXPECT_TRUE(a.read);
            EXPECT_EQ(a.applied, 1);
            EXPECT_EQ(a.refused, 0);
            EXPECT_EQ(a.record_bits, 12u);
            EXPECT_EQ(a.unknown_chunks, 1);
        }
        RootPose r;
        EXPECT_TRUE(buffer.root(11.0, r));
        return r.position.x;
    };
    EXPECT_NEAR(root_at_11(1), 1.0, 1e-3);  // one epoch: interpolated
    EXPECT_NEAR(root_at_11(2), 0.0, 1e-3);  // a new epoch: the older frame held
}

// A frame that comes after a newer one (late, or a server's repair) was
// needed by the display from the frame two before it on (FrameApplied::
// reach_from, which the display delay covers: the cubic between 10 and 11
// takes 12 as its outer neighbour): frames 10, 11 and 13, then 12 late,
// reaches back to 10; a frame in order to the newest before it.
TEST(ClientSessionFrames, ALateFrameReachesBackTwoFrames) {
    const RecordFormat fmt;
    auto frame_at = [&](uint32_t tick) {
        Bytes payload;
        Bytes records;
        BitWriter w(records);
        write_record(RecordInts{}, false, w);
        ChunkOut chunk;  // instance 0, bone 0 of show 1
        chunk.head = ChunkHead{0, 0, 1, 0, 0, {1}};
        chunk.rec_bits = 12;
        EXPECT_TRUE(write_frame_payload(std::span(&chunk, 1), 0, records.data(), nullptr, payload));
        Bytes d;
        write_frame_datagram(tick, 0, tick, false, {}, payload, d);
        return d;
    };
    PoseBuffer buffer(chain_format(1, fmt));
    const std::vector<PoseTarget> targets{{&buffer, fmt.size()}};
    auto reach = [&](uint32_t tick) {
        const Bytes d = frame_at(tick);
        FrameDatagram fd;
        EXPECT_TRUE(read_frame_datagram(d, fd));
        const FrameApplied a = apply_frame(fd, targets);
        EXPECT_TRUE(a.read);
        EXPECT_EQ(a.applied, 1);
        return a.reach_from;
    };
    EXPECT_TRUE(std::isinf(reach(10)));  // the first frame: nothing to reach back to
    EXPECT_DOUBLE_EQ(reach(11), 10.0);
    EXPECT_DOUBLE_EQ(reach(13), 11.0);
    EXPECT_DOUBLE_EQ(reach(12), 10.0) << "the late frame was needed from tick 10 on, not from its own tick";
    EXPECT_DOUBLE_EQ(buffer.needed_from(12, 0), 10.0);
    EXPECT_DOUBLE_EQ(buffer.needed_from(10, 0), 10.0);  // none before it: its own tick
}
