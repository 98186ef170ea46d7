// test_client_stream.cpp — the server's session core (server/client_stream.h,
// server/server_core.h) driven without sockets: control bytes in, framed
// control messages out, datagrams from made-up addresses, ticks at made-up
// times, a sink that keeps what would have been sent.
#include <gtest/gtest.h>

#include "client_stream.h"
#include "net_test_support.h"
#include "server_core.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::default_assets;

namespace {

const PeerAddress kTcp = PeerAddress::v4(0x7f000001, 0);        // 127.0.0.1
const PeerAddress kHome = PeerAddress::v4(0xc0a80001, 40000);   // 192.168.0.1:40000
const PeerAddress kOther = PeerAddress::v4(0x0a000002, 50000);  // 10.0.0.2:50000

std::vector<uint8_t> bytes_of(const flatbuffers::FlatBufferBuilder& fbb) {
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

std::vector<uint8_t> hello(uint32_t max_kbps) {
    flatbuffers::FlatBufferBuilder fbb;
    auto name = fbb.CreateString("unit");
    auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, name, 0, max_kbps);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    return bytes_of(fbb);
}

std::vector<uint8_t> ack(const ClientStream& s, uint32_t seq) {
    flatbuffers::FlatBufferBuilder fbb;
    auto a = wire::CreateAck(fbb, s.id(), s.token(), seq, 0xffffffffu, now_us32(), 0);
    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
    return bytes_of(fbb);
}

// The framed control message at `i` of the stream's output (length prefix checked).
const wire::Control* output_message(const ClientStream& s, size_t i) {
    if (i >= s.output().size()) return nullptr;
    const std::vector<uint8_t>& m = s.output()[i];
    uint32_t n = 0;
    if (!read_length(m, n) || n + 4 != m.size()) return nullptr;
    return verify_control(std::span(m).subspan(4));
}

// A core with the default character set and one session welcomed at t = 100 s.
struct Fixture {
    ServerConfig cfg;
    std::unique_ptr<ServerCore> core;
    std::shared_ptr<ClientStream> s;
    DatagramCollector sink;
    explicit Fixture(uint32_t max_kbps = 0) {
        cfg.client_timeout = 10.0;
        core = std::make_unique<ServerCore>(cfg, default_assets(), default_instances(default_assets()));
        core->set_udp_port(4242);
        s = core->open(kTcp, 100.0);
        EXPECT_TRUE(s->on_control(hello(max_kbps), 100.0));
    }
    // The Challenge the last datagram to `to` carried (empty if none).
    std::vector<uint8_t> challenge_to(const PeerAddress& to) {
        if (sink.sent.empty() || !(sink.sent.back().to == to)) return {};
        const wire::Datagram* d = verify_datagram(sink.sent.back().bytes);
        if (!d || d->body_type() != wire::DatagramBody::Challenge) return {};
        return {d->body_as_Challenge()->nonce()->begin(), d->body_as_Challenge()->nonce()->end()};
    }
    // Bind from `from`, then answer its Challenge from `from` at `now`.
    void bind(const PeerAddress& from, double now) {
        flatbuffers::FlatBufferBuilder b;
        build_bind(b, s->id(), s->token());
        core->on_datagram(bytes_of(b), from, now, sink);
        const std::vector<uint8_t> nonce = challenge_to(from);
        ASSERT_EQ(nonce.size(), CHALLENGE_NONCE);
        flatbuffers::FlatBufferBuilder r;
        build_challenge_response(r, s->id(), s->token(), nonce);
        core->on_datagram(bytes_of(r), from, now, sink);
    }
};

}  // namespace

TEST(ClientStream, HelloIsAnsweredWithWelcomeAndTheInstances) {
    Fixture f;
    EXPECT_EQ(f.s->state(), SessionState::Welcomed);
    ASSERT_GE(f.s->output().size(), 2u);
    const wire::Control* w = output_message(*f.s, 0);
    ASSERT_TRUE(w);
    ASSERT_EQ(w->body_type(), wire::ControlBody::Welcome);
    EXPECT_EQ(w->body_as_Welcome()->session_id(), f.s->id());
    EXPECT_EQ(w->body_as_Welcome()->udp_token(), f.s->token());
    EXPECT_EQ(w->body_as_Welcome()->udp_port(), 4242);
    EXPECT_EQ(w->body_as_Welcome()->assets()->size(), default_assets().size());
    EXPECT_FALSE(w->body_as_Welcome()->datagram_keys());  // no sealing configured
    const wire::Control* added = output_message(*f.s, 1);
    ASSERT_TRUE(added);
    ASSERT_EQ(added->body_type(), wire::ControlBody::InstanceAdded);
    EXPECT_EQ(added->body_as_InstanceAdded()->instances()->size(), default_instances(default_assets()).size());
    // Written by the shell, one at a time: the queue empties, the session stays.
    while (!f.s->output().empty()) f.s->on_written();
    EXPECT_EQ(f.s->state(), SessionState::Welcomed);
    // A second Hello is out of place: counted malformed, closed.
    EXPECT_FALSE(f.s->on_control(hello(0), 100.5));
    EXPECT_EQ(f.s->state(), SessionState::Closed);
    EXPECT_EQ(f.s->close_reason(), "unexpected control message in this state");
    EXPECT_EQ(f.core->stats().malformed_control, 1u);
}

TEST(ClientStream, BindGetsAChallengeAndTheRightResponseBinds) {
    Fixture f;
    // An unpadded Bind is smaller than the Challenge would be: no answer at all.
    flatbuffers::FlatBufferBuilder small;
    auto sb = wire::CreateBind(small, f.s->id(), f.s->token());
    small.Finish(wire::CreateDatagram(small, 0, 0, wire::DatagramBody::Bind, sb.Union()), wire::DatagramIdentifier());
    f.core->on_datagram(bytes_of(small), kHome, 100.5, f.sink);
    EXPECT_TRUE(f.sink.sent.empty());
    EXPECT_EQ(f.core->stats().unverified_bytes_out, 0u);
    flatbuffers::FlatBufferBuilder b;
    build_bind(b, f.s->id(), f.s->token());
    const std::vector<uint8_t> bind = bytes_of(b);
    f.core->on_datagram(bind, kHome, 101.0, f.sink);
    ASSERT_EQ(f.sink.sent.size(), 1u);
    EXPECT_TRUE(f.sink.sent[0].to == kHome);
    EXPECT_LT(f.sink.sent[0].bytes.size(), bind.size());  // never amplifies toward an unproven address
    const std::vector<uint8_t> nonce = f.challenge_to(kHome);
    ASSERT_EQ(nonce.size(), CHALLENGE_NONCE);
    EXPECT_EQ(f.s->state(), SessionState::Welcomed);  // not bound by a Bind alone
    EXPECT_FALSE(f.s->bound());
    ServerStats st = f.core->stats();
    EXPECT_EQ(st.challenges_sent, 2u);  // the unanswered one counts
    EXPECT_EQ(st.unverified_bytes_out, f.sink.sent[0].bytes.size());

    // The nonce from another address, then a wrong nonce from the right one: rejected.
    flatbuffers::FlatBufferBuilder r1;
    build_challenge_response(r1, f.s->id(), f.s->token(), nonce);
    f.core->on_datagram(bytes_of(r1), kOther, 101.1, f.sink);
    std::vector<uint8_t> wrong = nonce;
    wrong[0] ^= 1;
    flatbuffers::FlatBufferBuilder r2;
    build_challenge_response(r2, f.s->id(), f.s->token(), wrong);
    f.core->on_datagram(bytes_of(r2), kHome, 101.2, f.sink);
    EXPECT_FALSE(f.s->bound());
    EXPECT_EQ(f.core->stats().rejected_datagrams, 2u);
    EXPECT_EQ(f.sink.sent.size(), 1u);  // nothing answered

    // The right nonce from the challenged address: bound, Streaming, BindAck.
    flatbuffers::FlatBufferBuilder r3;
    build_challenge_response(r3, f.s->id(), f.s->token(), nonce);
    f.core->on_datagram(bytes_of(r3), kHome, 101.3, f.sink);
    EXPECT_TRUE(f.s->bound());
    EXPECT_TRUE(f.s->peer() == kHome);
    EXPECT_EQ(f.s->state(), SessionState::Streaming);
    ASSERT_EQ(f.sink.sent.size(), 2u);
    const wire::Datagram* d = verify_datagram(f.sink.sent[1].bytes);
    ASSERT_TRUE(d);
    EXPECT_EQ(d->body_type(), wire::DatagramBody::BindAck);
    EXPECT_TRUE(f.sink.sent[1].to == kHome);
    // A nonce is good once: the same response again is rejected.
    f.core->on_datagram(bytes_of(r3), kHome, 101.4, f.sink);
    EXPECT_EQ(f.core->stats().rejected_datagrams, 3u);
}

TEST(ClientStream, AcksCountOnlyFromTheBoundAddress) {
    Fixture f;
    f.bind(kHome, 101.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    const ServerStats before = f.core->stats();
    const std::vector<uint8_t> a = ack(*f.s, 0);
    f.core->on_datagram(a, kOther, 105.0, f.sink);
    ServerStats st = f.core->stats();
    EXPECT_EQ(st.rejected_datagrams, before.rejected_datagrams + 1);
    EXPECT_EQ(st.unverified_bytes_in, before.unverified_bytes_in + a.size());
    // A forged token from the bound address: rejected too.
    flatbuffers::FlatBufferBuilder fbb;
    auto x = wire::CreateAck(fbb, f.s->id(), f.s->token() ^ 1, 0, 0, 0, 0);
    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Ack, x.Union()), wire::DatagramIdentifier());
    f.core->on_datagram(bytes_of(fbb), kHome, 105.0, f.sink);
    EXPECT_EQ(f.core->stats().rejected_datagrams, before.rejected_datagrams + 2);
    // The Ack from the bound address is accepted and keeps the session alive:
    // at 112 s (11 s after binding, 7 s after that Ack) it still streams; Acks
    // from elsewhere do not: at 115.5 s (10.5 s after it) it timed out.
    f.core->on_datagram(a, kHome, 105.0, f.sink);
    EXPECT_EQ(f.core->stats().rejected_datagrams, before.rejected_datagrams + 2);
    f.core->tick(112.0, f.sink);
    EXPECT_EQ(f.s->state(), SessionState::Streaming);
    f.core->on_datagram(a, kOther, 114.0, f.sink);
    f.core->tick(115.5, f.sink);
    EXPECT_EQ(f.s->state(), SessionState::Closing);
    EXPECT_EQ(f.core->stats().timeouts, 1u);
    const wire::Control* g = output_message(*f.s, f.s->output().size() - 1);
    ASSERT_TRUE(g);
    ASSERT_EQ(g->body_type(), wire::ControlBody::Goodbye);
    EXPECT_EQ(g->body_as_Goodbye()->reason()->str(), "timeout: no acks");
}

TEST(ClientStream, TickSendsFramesWithinTheBudget) {
    Fixture f(64);  // 64 kbit/s cap
    f.bind(kHome, 101.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    f.sink.sent.clear();
    // Ticks of the core over 3 s at 30 Hz (acked, so the session lives): the
    // rate stays within the 64 kbit/s cap (1.04 x, plus the bucket's depth).
    for (int t = 1; t <= 90; ++t) {
        const double now = 102.0 + t / 30.0;
        f.core->on_datagram(ack(*f.s, f.s->seq() - 1), kHome, now, f.sink);
        f.core->tick(now, f.sink);
    }
    size_t wire = 0;
    for (const auto& d : f.sink.sent) wire += d.bytes.size() + UDP_IP_OVERHEAD;
    EXPECT_GT(wire, 3 * 64 * 125 / 2);
    EXPECT_LE(double(wire), 1.04 * 3 * 64 * 125 + 800);
    EXPECT_EQ(f.core->stats().wire_bytes_sent, wire);
    EXPECT_EQ(f.core->stats().datagrams_sent, f.sink.sent.size());
    // One send under an explicit budget: the frames fit it, all to the bound address.
    FrameEncoder& enc = f.core->encoder();
    uint32_t tick = 100;
    for (size_t budget : {size_t(300), size_t(700), size_t(1500)}) {
        f.sink.sent.clear();
        const TickResult r = f.s->send_frame(enc.encode(++tick), budget, f.sink);
        ASSERT_GT(r.datagrams, 0u) << budget;
        ASSERT_EQ(f.sink.sent.size(), r.datagrams);
        size_t bytes = 0;
        for (const auto& d : f.sink.sent) {
            EXPECT_TRUE(d.to == kHome);
            EXPECT_LE(d.bytes.size(), MAX_DATAGRAM);
            const wire::Datagram* g = verify_datagram(d.bytes);
            ASSERT_TRUE(g);
            EXPECT_EQ(g->body_type(), wire::DatagramBody::Frame);
            bytes += d.bytes.size() + UDP_IP_OVERHEAD;
        }
        EXPECT_EQ(bytes, r.wire_bytes);
        EXPECT_LE(r.wire_bytes, budget);
    }
}

TEST(ClientStream, NotBoundWithinClientTimeoutIsClosedWithItsReason) {
    Fixture f;
    while (!f.s->output().empty()) f.s->on_written();
    f.core->tick(109.9, f.sink);  // 9.9 s after the Welcome
    EXPECT_EQ(f.s->state(), SessionState::Welcomed);
    f.core->tick(110.2, f.sink);
    EXPECT_EQ(f.s->state(), SessionState::Closing);
    EXPECT_EQ(f.core->stats().timeouts, 1u);
    const wire::Control* g = output_message(*f.s, 0);
    ASSERT_TRUE(g);
    ASSERT_EQ(g->body_type(), wire::ControlBody::Goodbye);
    EXPECT_EQ(g->body_as_Goodbye()->reason()->str(), "timeout: UDP address not bound");
    // Closing: once the Goodbye is written, Closed with the reason.
    f.s->on_written();
    EXPECT_EQ(f.s->state(), SessionState::Closed);
    EXPECT_EQ(f.s->close_reason(), "timeout");
    EXPECT_EQ(f.core->stats().sessions_active, 0u);
}

TEST(ClientStream, NoHelloWithinHelloTimeoutClosesAndAClosingPeerThatDoesNotReadIsDropped) {
    ServerConfig cfg;
    ServerCore core(cfg, default_assets(), {});
    DatagramCollector sink;
    auto quiet = core.open(kTcp, 0.0);
    core.tick(cfg.hello_timeout - 0.1, sink);
    EXPECT_EQ(quiet->state(), SessionState::AwaitHello);
    core.tick(cfg.hello_timeout + 0.1, sink);
    EXPECT_EQ(quiet->state(), SessionState::Closed);
    EXPECT_EQ(quiet->close_reason(), "timeout");
    // A Refuse nobody reads: Closed 1 s later with "(not read)".
    auto old = core.open(kTcp, 10.0);
    flatbuffers::FlatBufferBuilder fbb;
    auto h = wire::CreateHello(fbb, PROTOCOL_VERSION + 1);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    EXPECT_FALSE(old->on_control(bytes_of(fbb), 10.0));
    EXPECT_EQ(old->state(), SessionState::Closing);
    const wire::Control* r = output_message(*old, 0);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->body_type(), wire::ControlBody::Refuse);
    core.tick(10.9, sink);
    EXPECT_EQ(old->state(), SessionState::Closing);
    core.tick(11.1, sink);
    EXPECT_EQ(old->state(), SessionState::Closed);
    EXPECT_EQ(old->close_reason(), "refused: protocol version " + std::to_string(PROTOCOL_VERSION + 1) +
                                       " not supported; this server speaks version " + std::to_string(PROTOCOL_VERSION) +
                                       " (not read)");
    EXPECT_EQ(core.stats().refused, 1u);
}

TEST(ClientStream, InstancesNotYetAnnouncedOrOwnGetNoImportance) {
    ServerCore core(ServerConfig{}, default_assets(), default_instances(default_assets()));
    const size_t n = default_instances(default_assets()).size();
    auto client = ClientStream::detached(core, 7, 1000);  // every instance announced
    InstanceSpec own = default_instances(default_assets())[0];
    own.owner = 7;
    const int mine = core.add_instance(own);
    const int npc = core.add_instance(default_instances(default_assets())[1]);
    DatagramCollector sink;
    uint32_t tick = 0;
    auto sent_to_client = [&](int instance) {
        for (const Pick& p : client->picks())
            if (p.instance == instance) return true;
        return false;
    };
    client->send_frame(core.encoder().encode(++tick), 1 << 20, sink);
    ASSERT_EQ(client->importance().size(), n + 2);
    for (size_t i = 0; i < n; ++i) EXPECT_GT(client->importance()[i], 0.0f) << i;
    EXPECT_EQ(client->importance()[size_t(npc)], 0.0f);  // not announced yet: not streamed
    EXPECT_FALSE(sent_to_client(npc));
    EXPECT_TRUE(sent_to_client(0));
    client->sync_instances();  // InstanceAdded for the NPC only (never its own)
    ASSERT_EQ(client->output().size(), 1u);
    const std::vector<uint8_t>& m = client->output()[0];
    const wire::Control* c = verify_control(std::span(m).subspan(4));
    ASSERT_TRUE(c && c->body_type() == wire::ControlBody::InstanceAdded);
    ASSERT_EQ(c->body_as_InstanceAdded()->instances()->size(), 1u);
    EXPECT_EQ(c->body_as_InstanceAdded()->instances()->Get(0)->id(), npc);
    client->send_frame(core.encoder().encode(++tick), 1 << 20, sink);
    EXPECT_GT(client->importance()[size_t(npc)], 0.0f);
    EXPECT_TRUE(sent_to_client(npc));
    EXPECT_EQ(client->importance()[size_t(mine)], 0.0f);
    EXPECT_FALSE(sent_to_client(mine));
}
