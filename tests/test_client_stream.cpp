// test_client_stream.cpp — the server's session core (server/client_stream.h,
// server/server_core.h) driven without sockets: control bytes in, framed
// control messages out, datagrams from made-up addresses, ticks at made-up
// times, a sink that keeps what would have been sent.
#include <gtest/gtest.h>

#include <map>
#include <random>
#include <set>
#include <thread>
#include <utility>

#include "client_stream.h"
#include "control_messages.h"
#include "errors.h"
#include "net_test_support.h"
#include "server_core.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::default_assets;

namespace {
using progskin::net::testing::frame_of;
using progskin::net::testing::hello;

const PeerAddress kTcp = PeerAddress::v4(0x7f000001, 0);        // 127.0.0.1
const PeerAddress kHome = PeerAddress::v4(0xc0a80001, 40000);   // 192.168.0.1:40000
const PeerAddress kOther = PeerAddress::v4(0x0a000002, 50000);  // 10.0.0.2:50000

std::vector<uint8_t> bytes_of(const flatbuffers::FlatBufferBuilder& fbb) {
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

// rtt_us: the echo as if the datagram left that long ago (the server's RTT sample).
std::vector<uint8_t> ack(const ClientStream& s, uint32_t seq, uint32_t bits = 0xffffffffu, uint32_t rtt_us = 0) {
    flatbuffers::FlatBufferBuilder fbb;
    auto a = wire::CreateAck(fbb, s.id(), s.token(), seq, bits, now_us32() - rtt_us, 0);
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
            EXPECT_TRUE(frame_of(d.bytes)) << "not a Frame datagram";
            bytes += d.bytes.size() + UDP_IP_OVERHEAD;
        }
        EXPECT_EQ(bytes, r.wire_bytes);
        EXPECT_LE(r.wire_bytes, budget);
    }
}

// Repairs (ServerConfig::repair_lost) under Acks that lie: a client that
// acknowledges only its even datagrams, every odd one "lost",
// gets each of its recent frame datagrams at most kMaxRepairs times more (each
// time in at most kMaxRepairCopies copies: half its datagrams are lost), byte for byte,
// only at its bound address, and its stream stays within its cap; with
// repairs off, none.
TEST(ClientStream, LyingAcksGetEachDatagramAFewTimesMoreWithinTheCap) {
    for (const bool repair : {true, false}) {
        Fixture f(256);
        f.cfg.repair_lost = repair;  // read by the core's sessions through its config
        f.core = std::make_unique<ServerCore>(f.cfg, default_assets(), default_instances(default_assets()));
        f.core->set_udp_port(4242);
        f.s = f.core->open(kTcp, 100.0);
        ASSERT_TRUE(f.s->on_control(hello(256), 100.0));
        f.bind(kHome, 101.0);
        ASSERT_EQ(f.s->state(), SessionState::Streaming);
        f.sink.sent.clear();
        for (int t = 1; t <= 90; ++t) {
            const double now = 102.0 + t / 30.0;
            // Only the even datagrams are acknowledged: every odd one "lost".
            if (f.s->seq() > 0 && (f.s->seq() - 1) % 2 == 0) f.core->on_datagram(ack(*f.s, f.s->seq() - 1, 0), kHome, now, f.sink);
            f.core->tick(now, f.sink);
        }
        std::map<std::vector<uint8_t>, int> copies;
        size_t wire = 0;
        for (const auto& d : f.sink.sent) {
            EXPECT_TRUE(d.to == kHome);
            ++copies[d.bytes];
            wire += d.bytes.size() + UDP_IP_OVERHEAD;
        }
        size_t repeated = 0;
        for (const auto& [bytes, n] : copies) {
            EXPECT_LE(n, 1 + ClientStream::kMaxRepairs * ClientStream::kMaxRepairCopies) << "a datagram went more than kMaxRepairs times again";
            repeated += size_t(n - 1);
        }
        const uint64_t repaired = f.core->stats().datagrams_repaired;
        std::printf("repair %s: %zu datagrams, %llu repairs, %zu repeated, %.1f kbit/s (cap 256)\n", repair ? "on" : "off",
                    f.sink.sent.size(), (unsigned long long)repaired, repeated, double(wire) * 8 / 1000 / 3.0);
        EXPECT_EQ(repeated, size_t(repaired));
        EXPECT_LE(double(wire), 1.04 * 3 * 256 * 125 + 4000);
        if (repair) {
            EXPECT_GT(repaired, 0u);
            EXPECT_LE(repaired, size_t(ClientStream::kMaxRepairs * ClientStream::kMaxRepairCopies) * (f.sink.sent.size() / 2 + 1));
        } else {
            EXPECT_EQ(repaired, 0u);
        }
    }
}

// A repair that is lost too goes again (ClientStream::repair_again): the
// client acknowledges every datagram but one, which goes again each time an
// Ack of a datagram sent after its last send leaves it out (at most
// kMaxRepairs times, while its tick is at most kRepairTicks old), each time
// in kRepairCopies copies (the budget is unlimited); a datagram acknowledged
// after its first repair goes no more.
TEST(ClientStream, ALostRepairGoesAgainUntilAcknowledged) {
    Fixture f(0);
    f.bind(kHome, 101.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    double now = 102.0;
    // Ack everything sent so far (bits: every earlier datagram but `skip`'s).
    auto ack_all = [&](int64_t skip_a, int64_t skip_b) {
        const uint32_t a = f.s->seq() - 1;
        uint32_t bits = 0xffffffffu;
        for (int64_t skip : {skip_a, skip_b})
            if (skip >= 0 && a - uint32_t(skip) >= 1 && a - uint32_t(skip) <= 32) bits &= ~(1u << (a - uint32_t(skip) - 1));
        // Lost by time: the Ack comes at least the loss delay (9/8 of the
        // RTT, 1 ms here: the echo makes it 1 ms) after the datagram left.
        std::this_thread::sleep_for(std::chrono::milliseconds(4));
        f.core->on_datagram(ack(*f.s, a, bits, 1000), kHome, now, f.sink);
    };
    for (int t = 0; t < 40; ++t) {  // past the rate's start and the baselines' grace
        now += 1.0 / 30;
        f.core->tick(now, f.sink);
        ack_all(-1, -1);
    }
    // Datagram `lost` never arrives; datagram `late` arrives as its first repair.
    auto tick_one = [&](std::vector<uint8_t>& bytes) {
        now += 1.0 / 30;
        const size_t before = f.sink.sent.size();
        f.core->tick(now, f.sink);
        EXPECT_EQ(f.sink.sent.size(), before + 1) << "one datagram a tick at this rate";
        bytes = f.sink.sent.back().bytes;
        return int64_t(f.s->seq() - 1);
    };
    std::vector<uint8_t> lost_bytes, late_bytes;
    const int64_t lost = tick_one(lost_bytes);
    const int64_t late = tick_one(late_bytes);
    const uint64_t repaired0 = f.core->stats().datagrams_repaired;
    bool late_acked = false;
    for (int t = 0; t < 12; ++t) {
        std::vector<uint8_t> b;
        tick_one(b);
        const size_t late_copies = size_t(std::count_if(f.sink.sent.begin(), f.sink.sent.end(), [&](const auto& d) { return d.bytes == late_bytes; }));
        late_acked = late_acked || late_copies >= 1 + ClientStream::kRepairCopies;
        ack_all(lost, late_acked ? -1 : late);
    }
    auto copies = [&](const std::vector<uint8_t>& bytes) {
        return std::count_if(f.sink.sent.begin(), f.sink.sent.end(), [&](const auto& d) { return d.bytes == bytes && d.to == kHome; });
    };
    std::printf("lost datagram sent %ld times, the late one %ld times, %llu repairs\n", long(copies(lost_bytes)), long(copies(late_bytes)),
                (unsigned long long)(f.core->stats().datagrams_repaired - repaired0));
    EXPECT_EQ(copies(lost_bytes), 1 + ClientStream::kMaxRepairs * ClientStream::kRepairCopies);
    EXPECT_EQ(copies(late_bytes), 1 + ClientStream::kRepairCopies);
    EXPECT_EQ(f.core->stats().datagrams_repaired - repaired0, uint64_t((ClientStream::kMaxRepairs + 1) * ClientStream::kRepairCopies));
}

// How many copies a repair goes in: enough that all of them are lost less
// often than kRepairMiss at the link's loss before repairs, from
// kRepairCopies (a clean link) up to kMaxRepairCopies.
TEST(ClientStream, RepairCopiesFollowTheLinksLoss) {
    EXPECT_EQ(ClientStream::repair_copies(0.0), ClientStream::kRepairCopies);
    EXPECT_EQ(ClientStream::repair_copies(0.03), 2);   // 9e-4
    EXPECT_EQ(ClientStream::repair_copies(0.05), 3);   // 2.5e-3, then 1.25e-4
    EXPECT_EQ(ClientStream::repair_copies(0.1), 3);    // 1e-3
    EXPECT_EQ(ClientStream::repair_copies(0.2), 4);    // 8e-3, then 1.6e-3: the most
    EXPECT_EQ(ClientStream::repair_copies(1.0), ClientStream::kMaxRepairCopies);
    EXPECT_EQ(ClientStream::repair_copies(-1.0), ClientStream::kRepairCopies);  // out of range: clamped
}

// A link that loses every tenth datagram on its first send: the book's first
// loss reads about 0.1, and each lost datagram goes again once, in 3 or 4
// copies (the budget is unlimited; 2 on a clean link), byte for byte.
TEST(ClientStream, RepairsOfALossyLinkGoInMoreCopies) {
    Fixture f(0);
    f.bind(kHome, 101.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    double now = 102.0;
    std::set<uint32_t> received;
    std::map<uint32_t, std::vector<uint8_t>> first_bytes;
    size_t lost_on_first = 0, scanned = f.sink.sent.size();
    for (int t = 0; t < 400; ++t) {
        now += 1.0 / 30;
        f.core->tick(now, f.sink);
        // What went since the last look: this tick's datagrams and the
        // repairs the last Ack made.
        for (size_t k = std::exchange(scanned, f.sink.sent.size()); k < f.sink.sent.size(); ++k) {
            const std::optional<FrameDatagram> d = frame_of(f.sink.sent[k].bytes);
            if (!d) continue;
            const uint32_t seq = d->seq;
            if (!first_bytes.count(seq)) {  // its first send: every tenth lost
                first_bytes[seq] = f.sink.sent[k].bytes;
                if (seq % 10 == 7) {
                    ++lost_on_first;
                    continue;
                }
            }
            received.insert(seq);  // a repair always arrives
        }
        if (received.empty()) continue;
        const uint32_t a = *received.rbegin();
        uint32_t bits = 0;
        for (uint32_t i = 0; i < 32; ++i)
            if (received.count(a - 1 - i)) bits |= 1u << i;
        std::this_thread::sleep_for(std::chrono::milliseconds(2));  // past the loss delay (1 ms)
        f.core->on_datagram(ack(*f.s, a, bits, 1000), kHome, now, f.sink);
    }
    ASSERT_GT(lost_on_first, 20u);
    // The datagrams lost on their first send, and how often each went.
    std::map<size_t, int> sends_of_lost;
    for (const auto& [seq, bytes] : first_bytes) {
        // (past the average's warm-up; the last ones may not be repaired yet)
        if (seq % 10 != 7 || seq < 150 || seq + 40 > first_bytes.rbegin()->first) continue;
        const auto n = std::count_if(f.sink.sent.begin(), f.sink.sent.end(), [&](const auto& d) { return d.bytes == bytes; });
        ++sends_of_lost[size_t(n)];
    }
    std::printf("first loss %.3f; lost datagrams by sends:", f.s->first_loss());
    for (const auto& [n, k] : sends_of_lost) std::printf(" %zu x %d", n, k);
    std::printf("\n");
    EXPECT_NEAR(f.s->first_loss(), 0.1, 0.02);
    // Its first send and one repair in 3 copies, or 4 right after a loss
    // (the average is then a little over 0.1: 0.107^3 > kRepairMiss).
    ASSERT_FALSE(sends_of_lost.empty());
    EXPECT_GE(sends_of_lost.begin()->first, size_t(1 + 3));
    EXPECT_LE(sends_of_lost.rbegin()->first, size_t(1 + ClientStream::kMaxRepairCopies));
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

// ServerConfig::max_candidates: each tick a client weighs only the most
// important characters, exactly the top ones of what every character would
// weigh, whether the camera moves a little (the previous tick's cut finds
// them) or jumps across the scene (the cut fails and every one is ordered).
TEST(ClientStream, OnlyTheMostImportantCharactersAreWeighed) {
    ServerConfig cfg;
    cfg.max_candidates = 20;
    std::vector<InstanceSpec> specs;
    for (int k = 0; k < 150; ++k) {
        InstanceSpec s;
        s.asset = k % 2;
        s.position = glm::vec3(float(k) * 1.3f, 0.0f, float(k % 7) * 0.9f);
        specs.push_back(s);
    }
    ServerCore core(cfg, default_assets(), specs);
    auto client = ClientStream::detached(core, 7, 1000);
    DatagramCollector sink;
    std::vector<float> every;
    for (uint32_t tick = 1; tick <= 60; ++tick) {
        ViewSpec v;
        v.has_camera = true;
        // A walk along the row, and every 10th tick a jump to its far end.
        const float x = tick % 10 == 0 ? 190.0f - float(tick) : float(tick) * 1.7f + 0.37f;
        v.camera = glm::vec3(x, 1.6f, -4.0f);
        client->set_view(v);
        const EncodedFrame& f = core.encoder().encode(tick);
        client->send_frame(f, 1 << 20, sink);
        compute_importance(v, f, core.assets(), 7, every);
        const std::vector<float>& weighed = client->importance();
        ASSERT_EQ(weighed.size(), every.size());
        size_t kept = 0;
        float least_kept = INFINITY, most_left = 0.0f;
        for (size_t i = 0; i < every.size(); ++i) {
            if (weighed[i] > 0.0f) {
                ++kept;
                EXPECT_EQ(weighed[i], every[i]) << "tick " << tick << " instance " << i;
                least_kept = std::min(least_kept, every[i]);
            } else {
                most_left = std::max(most_left, every[i]);
            }
        }
        ASSERT_EQ(kept, 20u) << "tick " << tick;
        ASSERT_GE(least_kept, most_left) << "tick " << tick << ": a more important character was left out";
    }
}

// The frame's grid (spatial_grid.h): a client with a camera weighs only the
// instances of the cells around it, and keeps exactly what it keeps when it
// weighs every slot (the same frame without its grid): the same importance,
// the same picks, tick after tick, for a crowd with a dense cluster, a
// sparse field and a line, a camera walking through it, jumping out of it
// and standing far away, with and without a view radius.
TEST(ClientStream, TheGridFindsTheCandidatesEverySlotWould) {
    for (const double radius : {0.0, 60.0}) {
        ServerConfig cfg;
        cfg.max_candidates = 30;
        cfg.view_radius = radius;
        std::vector<InstanceSpec> specs;
        std::mt19937 rng(5);
        std::uniform_real_distribution<float> u(-150.0f, 150.0f), near(-3.0f, 3.0f);
        for (int k = 0; k < 300; ++k) {
            InstanceSpec s;
            s.asset = k % 2;
            if (k < 120) s.position = glm::vec3(20.0f + near(rng), 0.0f, -10.0f + near(rng));  // a crowd
            else if (k < 200) s.position = glm::vec3(u(rng), 0.0f, 40.0f);                  // a line
            else s.position = glm::vec3(u(rng), 0.0f, u(rng));                              // a field
            specs.push_back(s);
        }
        ServerCore core(cfg, default_assets(), specs);
        auto with_grid = ClientStream::detached(core, 7, 400);
        auto without = ClientStream::detached(core, 7, 400);
        DatagramCollector sink_a, sink_b;
        for (uint32_t tick = 1; tick <= 40; ++tick) {
            ViewSpec v;
            v.has_camera = true;
            const float x = tick % 13 == 0 ? 900.0f : tick % 7 == 0 ? -140.0f : -60.0f + float(tick) * 4.1f;
            v.camera = glm::vec3(x, 1.6f, tick % 2 ? -8.0f : 35.0f);
            with_grid->set_view(v);
            without->set_view(v);
            const EncodedFrame& f = core.encoder().encode(tick);
            ASSERT_TRUE(f.grid.built());
            EncodedFrame bare = f;
            bare.grid = SpatialGrid{};
            with_grid->send_frame(f, 1 << 20, sink_a);
            without->send_frame(bare, 1 << 20, sink_b);
            ASSERT_EQ(with_grid->importance(), without->importance()) << "tick " << tick << " radius " << radius;
            ASSERT_EQ(with_grid->picks().size(), without->picks().size()) << "tick " << tick;
            for (size_t p = 0; p < with_grid->picks().size(); ++p) {
                EXPECT_EQ(with_grid->picks()[p].instance, without->picks()[p].instance);
                EXPECT_EQ(with_grid->picks()[p].k, without->picks()[p].k);
            }
            size_t kept = 0;
            for (const float w : with_grid->importance()) kept += w > 0.0f;
            if (radius == 0) {
                EXPECT_EQ(kept, 30u) << "tick " << tick;
            }
            EXPECT_EQ(without->weighed(), specs.size());
            // (a third of the scene stands in one cell: a grid's worst case)
            EXPECT_LT(with_grid->weighed(), specs.size() * 3 / 4) << "tick " << tick;
        }
    }
}

namespace {

std::vector<uint8_t> spawn_message(uint32_t request, std::vector<int32_t> clips = {}) {
    flatbuffers::FlatBufferBuilder fbb;
    auto vc = fbb.CreateVector(clips);
    auto s = wire::CreateSpawn(fbb, request, 0, vc);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Spawn, s.Union()), wire::ControlIdentifier());
    return bytes_of(fbb);
}

std::vector<uint8_t> view_message(size_t weights) {
    std::vector<wire::InstanceWeight> ws;
    for (size_t i = 0; i < weights; ++i) ws.emplace_back(uint16_t(i), 1.0f);
    flatbuffers::FlatBufferBuilder fbb;
    auto vw = fbb.CreateVectorOfStructs(ws);
    wire::ViewBuilder vb(fbb);
    vb.add_weights(vw);
    auto v = vb.Finish();
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::View, v.Union()), wire::ControlIdentifier());
    return bytes_of(fbb);
}

// The Spawned answers in the session's output, in order: (ok, reason).
std::vector<std::pair<bool, std::string>> spawned_answers(const ClientStream& s) {
    std::vector<std::pair<bool, std::string>> r;
    for (size_t i = 0; i < s.output().size(); ++i)
        if (const wire::Control* c = output_message(s, i); c && c->body_type() == wire::ControlBody::Spawned)
            r.emplace_back(c->body_as_Spawned()->ok(), c->body_as_Spawned()->reason() ? c->body_as_Spawned()->reason()->str() : "");
    return r;
}

uint64_t refusals(const ServerCore& core, const std::string& reason) {
    const ServerStats st = core.stats();
    auto it = st.refusals.find(reason);
    return it == st.refusals.end() ? 0 : it->second;
}

}  // namespace

// Characters per session (MAX_SPAWNED) and per address
// (max_characters_per_address), clips per Spawn and repeated clips: each
// refused with its reason in Spawned and counted by reason.
TEST(ClientStream, SpawnsAreBoundedPerSessionAndPerAddress) {
    Fixture f;
    auto second = f.core->open(kTcp, 100.0);  // the same address
    ASSERT_TRUE(second->on_control(hello(0), 100.0));
    auto elsewhere = f.core->open(kOther, 100.0);
    ASSERT_TRUE(elsewhere->on_control(hello(0), 100.0));
    for (uint32_t r = 0; r < 17; ++r) f.s->on_control(spawn_message(r), 100.1);
    auto a = spawned_answers(*f.s);
    ASSERT_EQ(a.size(), 17u);
    for (int i = 0; i < 16; ++i) EXPECT_TRUE(a[size_t(i)].first) << i;
    EXPECT_FALSE(a[16].first);
    EXPECT_EQ(refusals(*f.core, "characters_per_session"), 1u);
    for (uint32_t r = 0; r < 16; ++r) second->on_control(spawn_message(r), 100.1);
    a = spawned_answers(*second);
    ASSERT_EQ(a.size(), 16u);
    EXPECT_TRUE(a[15].first);  // 32 from this address
    auto third = f.core->open(kTcp, 100.1);
    ASSERT_TRUE(third->on_control(hello(0), 100.1));
    third->on_control(spawn_message(1), 100.1);
    a = spawned_answers(*third);
    ASSERT_EQ(a.size(), 1u);
    EXPECT_FALSE(a[0].first);
    EXPECT_NE(a[0].second.find("per address"), std::string::npos) << a[0].second;
    EXPECT_EQ(refusals(*f.core, "characters_per_address"), 1u);
    // Another address is not affected; clips beyond the limit or repeated are refused.
    elsewhere->on_control(spawn_message(1, {0}), 100.1);
    elsewhere->on_control(spawn_message(2, std::vector<int32_t>(MAX_INSTANCE_CLIPS + 1, 0)), 100.1);
    elsewhere->on_control(spawn_message(3, {0, 0}), 100.1);
    a = spawned_answers(*elsewhere);
    ASSERT_EQ(a.size(), 3u);
    EXPECT_TRUE(a[0].first);
    EXPECT_FALSE(a[1].first);
    EXPECT_FALSE(a[2].first);
    EXPECT_NE(a[2].second.find("repeated"), std::string::npos) << a[2].second;
    EXPECT_EQ(refusals(*f.core, "spawn_invalid"), 2u);
    // A session that closes gives its characters back to its address.
    f.s->close("gone");
    third->on_control(spawn_message(99), 100.2);
    EXPECT_TRUE(spawned_answers(*third).back().first);
}

// A View of more than MAX_VIEW_WEIGHTS weights closes the session (counted);
// one of MAX_VIEW_WEIGHTS is accepted.
TEST(ClientStream, ViewsOverTheWeightLimitAreRefused) {
    Fixture f;
    EXPECT_TRUE(f.s->on_control(view_message(MAX_VIEW_WEIGHTS), 100.1));
    EXPECT_EQ(f.s->state(), SessionState::Welcomed);
    EXPECT_FALSE(f.s->on_control(view_message(MAX_VIEW_WEIGHTS + 1), 100.2));
    EXPECT_EQ(f.s->state(), SessionState::Closed);
    EXPECT_EQ(refusals(*f.core, "view_too_large"), 1u);
}

// A 16,000-instance scene: InstanceAdded batches are queued as the client
// reads, never more than half the output limit at once, each message within
// MAX_CONTROL_MESSAGE, and every instance is announced once.
TEST(ClientStream, ALargeSceneIsAnnouncedWithinTheOutputLimit) {
    ServerConfig cfg;
    ServerCore core(cfg, default_assets(), crowd_layout(default_assets(), 16000));
    auto s = core.open(kTcp, 100.0);
    ASSERT_TRUE(s->on_control(hello(0), 100.0));
    std::set<int> announced;
    size_t most_queued = 0, messages = 0, duplicates = 0;
    for (int round = 0; round < 10000 && !s->output().empty(); ++round) {
        size_t queued = 0;
        for (const auto& m : s->output()) queued += m.size();
        most_queued = std::max(most_queued, queued);
        const wire::Control* c = output_message(*s, 0);
        ASSERT_TRUE(c);
        if (c->body_type() == wire::ControlBody::InstanceAdded) {
            ++messages;
            for (const wire::Instance* in : *c->body_as_InstanceAdded()->instances()) duplicates += !announced.insert(in->id()).second;
        }
        s->on_written();
    }
    EXPECT_EQ(announced.size(), 16000u);
    EXPECT_EQ(duplicates, 0u);
    EXPECT_LE(most_queued, cfg.max_queued_bytes / 2);
    EXPECT_EQ(s->state(), SessionState::Welcomed);
    std::printf("16,000 instances in %zu InstanceAdded messages, at most %zu bytes queued\n", messages, most_queued);
}

// Every InstanceAdded the server builds fits the receivers' limits by
// construction: instance_table_bound covers the worst Instance table (the
// most clips, every field), and instances_per_message cuts by bytes.
TEST(ControlMessages, InstanceAddedBatchesFitTheControlLimit) {
    const ServerAssets& assets = default_assets();
    InstanceSpec worst;
    worst.selection = -1;
    worst.owner = 7;
    for (size_t c = 0; c < MAX_INSTANCE_CLIPS; ++c) worst.announced_clips.push_back(int(c));
    worst.walk_radius = 1;
    worst.walk_speed = 1;
    worst.publisher_start_us = ~0ull;
    worst.world_id = ~0ull;
    std::vector<std::pair<int, InstanceSpec>> added;
    for (int i = 0; i < 4000; ++i) added.emplace_back(i, worst);
    flatbuffers::FlatBufferBuilder empty, one;
    build_instances_added(empty, assets, {});
    build_instances_added(one, assets, std::span(added).first(1));
    EXPECT_LE(one.GetSize() - empty.GetSize(), instance_table_bound(assets, worst));
    EXPECT_LE(instance_table_bound(assets, worst), MAX_INSTANCE_TABLE_BYTES);
    const size_t n = instances_per_message(assets, added);
    ASSERT_GE(n, 1u);
    flatbuffers::FlatBufferBuilder full;
    build_instances_added(full, assets, std::span(added).first(n));
    EXPECT_LE(full.GetSize(), MAX_CONTROL_MESSAGE);
    EXPECT_TRUE(verify_control({full.GetBufferPointer(), full.GetSize()}));
    // Instances of no clips: more per message, still within the limit and the verifier's table limit.
    for (auto& [id, sp] : added) sp.announced_clips.clear();
    const size_t m = instances_per_message(assets, added);
    EXPECT_GT(m, n);
    EXPECT_LE(m, MAX_BATCH_INSTANCES);
    flatbuffers::FlatBufferBuilder many;
    build_instances_added(many, assets, std::span(added).first(m));
    EXPECT_LE(many.GetSize(), MAX_CONTROL_MESSAGE);
    EXPECT_TRUE(verify_control({many.GetBufferPointer(), many.GetSize()}));
    // The encoder refuses an instance whose table could not fit.
    FrameEncoder enc(assets, {}, 30.0f);
    InstanceSpec over = worst;
    over.announced_clips.push_back(int(MAX_INSTANCE_CLIPS));
    EXPECT_THROW(enc.add_instance(over), Error);
}

// A full server: a Hello evicts the oldest session still unbound
// evict_after past its Welcome, else the one silent longest, else the
// newest of the address holding the most (when it holds more than the
// newcomer's + 1); otherwise Refuse "server full".
TEST(ServerCore, AFullServerEvictsUnboundThenSilentThenTheBusiestAddress) {
    ServerConfig cfg;
    cfg.max_clients = 3;
    cfg.evict_after = 2.0;
    ServerCore core(cfg, default_assets(), default_instances(default_assets()));
    DatagramCollector sink;
    const PeerAddress a = PeerAddress::v4(0x0a000001, 0), b = PeerAddress::v4(0x0a000002, 0);
    auto s1 = core.open(a, 100.0);
    ASSERT_TRUE(s1->on_control(hello(0), 100.0));
    auto s2 = core.open(a, 100.5);
    ASSERT_TRUE(s2->on_control(hello(0), 100.5));
    auto s3 = core.open(a, 101.0);
    ASSERT_TRUE(s3->on_control(hello(0), 101.0));
    // Too early for anybody to be unbound long: the busiest address (3 > 0 + 1) gives its newest.
    auto n1 = core.open(b, 101.5);
    ASSERT_TRUE(n1->on_control(hello(0), 101.5));
    EXPECT_EQ(s3->state(), SessionState::Closing);
    EXPECT_EQ(refusals(core, "evicted_address_share"), 1u);
    // Later: s1 (unbound since 100.0) goes before s2 (since 100.5).
    auto n2 = core.open(b, 103.0);
    ASSERT_TRUE(n2->on_control(hello(0), 103.0));
    EXPECT_FALSE(s1->is_open());
    EXPECT_TRUE(s2->is_open());
    EXPECT_EQ(refusals(core, "evicted_unbound"), 1u);
    // Now a: 1 session, b: 2; a third from b finds nobody to evict once all are bound and heard.
    for (auto& s : {s2, n1, n2}) {
        flatbuffers::FlatBufferBuilder bind;
        build_bind(bind, s->id(), s->token());
        const PeerAddress from = PeerAddress::v4(0x0a0000f0, uint16_t(5000 + s->id() % 1000));
        core.on_datagram(bytes_of(bind), from, 103.1, sink);
        const wire::Datagram* d = verify_datagram(sink.sent.back().bytes);
        ASSERT_TRUE(d && d->body_type() == wire::DatagramBody::Challenge);
        flatbuffers::FlatBufferBuilder r;
        build_challenge_response(r, s->id(), s->token(), {d->body_as_Challenge()->nonce()->data(), CHALLENGE_NONCE});
        core.on_datagram(bytes_of(r), from, 103.1, sink);
        ASSERT_EQ(s->state(), SessionState::Streaming);
    }
    auto n3 = core.open(b, 103.5);
    EXPECT_FALSE(n3->on_control(hello(0), 103.5));
    EXPECT_EQ(refusals(core, "server_full"), 1u);
    // One goes silent (no Ack for evict_after): it is evicted for the next newcomer.
    auto n4 = core.open(b, 106.0);
    EXPECT_TRUE(n4->on_control(hello(0), 106.0));
    EXPECT_EQ(refusals(core, "evicted_idle"), 1u);
}

// Admission: each address opens at most connects_per_second (8 s of burst),
// the rest closed at once; at most max_handshakes sessions wait for Hello,
// the oldest closed for a newer one.
TEST(ServerCore, ConnectionRateAndHandshakesInProgressAreBounded) {
    ServerConfig cfg;
    cfg.connects_per_second = 2;  // a burst of 16
    cfg.max_handshakes = 4;
    cfg.max_per_address = 0;
    ServerCore core(cfg, default_assets(), default_instances(default_assets()));
    std::vector<std::shared_ptr<ClientStream>> v;
    for (int i = 0; i < 20; ++i) v.push_back(core.open(kTcp, 100.0 + 0.001 * i));
    size_t closed = 0;
    for (auto& s : v) closed += s->state() == SessionState::Closed;
    EXPECT_EQ(refusals(core, "connect_rate"), 4u);  // 20 - 16
    EXPECT_EQ(refusals(core, "handshake_evicted"), 12u);  // 16 admitted, 4 may wait
    EXPECT_EQ(closed, 16u);
    for (size_t i = 12; i < 16; ++i) EXPECT_EQ(v[i]->state(), SessionState::AwaitHello) << i;  // the newest wait
    // 0.75 s later the bucket holds one more (1.5 connections: not two).
    EXPECT_EQ(core.open(kTcp, 100.75)->state(), SessionState::AwaitHello);
    EXPECT_EQ(core.open(kTcp, 100.75)->state(), SessionState::Closed);
    // Another address has its own bucket.
    EXPECT_EQ(core.open(kOther, 100.75)->state(), SessionState::AwaitHello);
}

// Liveness does not depend on how fast the shell reads: a Streaming session
// times out client_timeout after its newest Ack as of the last time the UDP
// queue was found empty (input_drained), not as of now.
TEST(ServerCore, AcksCountAsOfTheLastTimeTheQueueWasEmpty) {
    Fixture f;
    f.bind(kHome, 100.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    f.core->on_datagram(ack(*f.s, 0), kHome, 101.0, f.sink);
    f.core->input_drained(101.5);
    f.core->tick(112.0, f.sink);  // 11 s after the Ack, but the queue was last seen empty 0.5 s after it
    EXPECT_EQ(f.s->state(), SessionState::Streaming);
    f.core->input_drained(111.5);
    f.core->tick(112.1, f.sink);
    EXPECT_NE(f.s->state(), SessionState::Streaming);
}

// ServerCore::tick's `encoded` callback (a world node publishes its cells
// from it, server/world_bus.h): once per tick, with that tick's frame,
// before any session's datagram of the tick is sent.
TEST(ServerCore, TheEncodedCallbackComesBeforeTheSessionsWork) {
    Fixture f;
    f.bind(kHome, 100.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    int calls = 0;
    uint32_t last_tick = 0;
    for (int t = 1; t <= 5; ++t) {
        f.sink.sent.clear();
        size_t sent_before = SIZE_MAX;
        f.core->tick(100.0 + t / 30.0, f.sink, [&](const EncodedFrame& frame) {
            ++calls;
            sent_before = f.sink.sent.size();
            EXPECT_GT(frame.tick, last_tick);
            last_tick = frame.tick;
            EXPECT_EQ(&frame, &f.core->encoder().frame());
        });
        EXPECT_EQ(calls, t);
        EXPECT_EQ(sent_before, 0u) << "tick " << t << ": a session's datagram went before the frame was handed out";
        EXPECT_FALSE(f.sink.sent.empty()) << "tick " << t << ": the streaming session sent nothing (the check above proves nothing)";
    }
}

// An Ack crossing the Goodbye: the session is saying goodbye, or erased,
// when its datagram arrives. Counted as late (not as an attack) while it
// closes and for 2 s after, then rejected.
TEST(ClientStream, DatagramsOfAJustClosedSessionAreLateNotRejected) {
    Fixture f;
    f.bind(kHome, 101.0);
    ASSERT_EQ(f.s->state(), SessionState::Streaming);
    const std::vector<uint8_t> a = ack(*f.s, 0);
    const uint64_t id = f.s->id();
    ServerStats before = f.core->stats();
    f.s->goodbye("shutdown", 101.5);
    ASSERT_FALSE(f.s->is_open());
    f.core->on_datagram(a, kHome, 101.6, f.sink);
    EXPECT_EQ(f.core->stats().late_datagrams, before.late_datagrams + 1);
    EXPECT_EQ(f.core->stats().rejected_datagrams, before.rejected_datagrams);
    before = f.core->stats();
    f.core->erase(id, 102.0);
    f.core->on_datagram(a, kHome, 102.5, f.sink);
    ServerStats st = f.core->stats();
    EXPECT_EQ(st.late_datagrams, before.late_datagrams + 1);
    EXPECT_EQ(st.rejected_datagrams, before.rejected_datagrams);
    f.core->on_datagram(a, kHome, 104.5, f.sink);  // 2.5 s after: forgotten
    st = f.core->stats();
    EXPECT_EQ(st.late_datagrams, before.late_datagrams + 1);
    EXPECT_EQ(st.rejected_datagrams, before.rejected_datagrams + 1);
}
