// test_net_bad_input.cpp — random, truncated and forged datagrams and control
// messages, wrong session ids and tokens, oversized lengths and floods from
// unknown addresses: dropped and counted, nothing sent back to an address
// that is not bound to a session (a Challenge answers only a Bind with a valid
// session and token), and the server keeps serving everyone else.
#include <gtest/gtest.h>
#include <poll.h>

#include <asio.hpp>
#include <random>

#include "net_test_support.h"
#include "pose_buffer.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using asio::ip::tcp;
using asio::ip::udp;

namespace {

std::vector<uint8_t> bind_datagram(uint64_t session, uint64_t token) {
    flatbuffers::FlatBufferBuilder fbb;
    std::vector<uint8_t> pad(64, 0);
    auto p = fbb.CreateVector(pad);
    auto b = wire::CreateBind(fbb, session, token, p);
    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Bind, b.Union()), wire::DatagramIdentifier());
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

std::vector<uint8_t> ack_datagram(uint64_t session, uint64_t token) {
    flatbuffers::FlatBufferBuilder fbb;
    auto a = wire::CreateAck(fbb, session, token, 5, 0xffffffffu, 0, 0);
    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

// Bytes that arrive on `s` within `ms` milliseconds.
size_t bytes_received(udp::socket& s, int ms) {
    size_t total = 0;
    uint8_t buf[2048];
    auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    while (std::chrono::steady_clock::now() < end) {
        pollfd p{s.native_handle(), POLLIN, 0};
        if (::poll(&p, 1, 20) > 0) {
            asio::error_code ec;
            udp::endpoint from;
            size_t n = s.receive_from(asio::buffer(buf), from, 0, ec);
            if (!ec) total += n;
        }
    }
    return total;
}

// Whether the server closed the connection within `ms` milliseconds.
bool closed_within(tcp::socket& s, int ms) {
    auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    uint8_t buf[4096];
    while (std::chrono::steady_clock::now() < end) {
        pollfd p{s.native_handle(), POLLIN, 0};
        if (::poll(&p, 1, 20) > 0) {
            asio::error_code ec;
            s.read_some(asio::buffer(buf), ec);
            if (ec) return true;
        }
    }
    return false;
}

}  // namespace

TEST(NetBadInput, ForgedRandomAndTruncatedDatagramsAreDroppedWhileOthersStream) {
    RunningServer s;
    ClientReport good;
    std::thread client([&] { good = run_client(s.client(3.0)); });

    asio::io_context io;
    udp::socket attacker(io);
    attacker.open(udp::v4());
    attacker.bind(udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
    attacker.non_blocking(true);
    udp::endpoint server(asio::ip::make_address("127.0.0.1"), s.server->udp_port());
    std::mt19937 rng(3);
    size_t sent = 0, sent_bytes = 0;
    auto send = [&](const std::vector<uint8_t>& d) {
        asio::error_code ec;
        attacker.send_to(asio::buffer(d), server, 0, ec);
        ++sent;
        sent_bytes += d.size();
    };
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    for (int i = 0; i < 300; ++i) {  // random bytes, every length up to past the limit
        std::vector<uint8_t> d(rng() % 1500);
        for (auto& b : d) b = uint8_t(rng());
        send(d);
    }
    auto bind = bind_datagram(0x1234, 0x5678);
    for (size_t n = 0; n < bind.size(); ++n) send(std::vector<uint8_t>(bind.begin(), bind.begin() + long(n)));  // truncated
    for (int i = 0; i < 200; ++i) {  // well-formed, wrong session ids and tokens
        send(bind_datagram(rng(), rng()));
        send(ack_datagram(rng(), rng()));
    }
    for (int i = 0; i < 200; ++i) {  // valid buffers with bytes flipped
        auto d = bind_datagram(rng(), rng());
        d[rng() % d.size()] ^= uint8_t(1 + rng() % 255);
        send(d);
    }
    EXPECT_EQ(bytes_received(attacker, 300), 0u);
    client.join();
    ServerStats st = s.server->stats();
    // Only the good client's own Bind was answered (a Challenge, smaller than the Bind).
    EXPECT_LE(st.challenges_sent, 3u);
    EXPECT_LE(st.unverified_bytes_out, st.challenges_sent * 128);
    EXPECT_GE(st.malformed_datagrams + st.rejected_datagrams, sent - 5);  // a few may be dropped by the kernel
    EXPECT_GT(st.malformed_datagrams, 300u);
    EXPECT_GE(st.rejected_datagrams, 400u);
    EXPECT_EQ(good.characters, 4);
    EXPECT_EQ(good.malformed, 0u);
    for (double k : good.per_second_kbps) EXPECT_GT(k, 100.0);
    std::printf("sent %zu datagrams (%zu bytes) from an unbound address: %llu malformed, %llu rejected, 0 bytes back\n", sent,
                sent_bytes, (unsigned long long)st.malformed_datagrams, (unsigned long long)st.rejected_datagrams);
}

TEST(NetBadInput, FloodFromUnknownAddressGetsNothingAndServiceContinues) {
    RunningServer s;
    ClientReport good;
    std::thread client([&] { good = run_client(s.client(3.0)); });
    asio::io_context io;
    udp::socket flood(io);
    flood.open(udp::v4());
    flood.non_blocking(true);
    udp::endpoint server(asio::ip::make_address("127.0.0.1"), s.server->udp_port());
    std::vector<uint8_t> d(1200, 0xAB);
    auto bind = bind_datagram(1, 2);
    auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(1500);
    size_t n = 0;
    while (std::chrono::steady_clock::now() < end) {
        asio::error_code ec;
        flood.send_to(asio::buffer(n % 2 ? d : bind), server, 0, ec);
        if (++n % 200 == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    EXPECT_EQ(bytes_received(flood, 200), 0u);
    client.join();
    EXPECT_EQ(good.characters, 4);
    EXPECT_GT(good.rate_kbps, 100.0);
    EXPECT_LE(s.server->stats().challenges_sent, 3u);  // the good client's only
    EXPECT_LE(s.server->stats().unverified_bytes_out, s.server->stats().challenges_sent * 128);
    std::printf("flood: %zu datagrams; client still received %.1f kbit/s\n", n, good.rate_kbps);
}

TEST(NetBadInput, BadControlMessagesCloseOnlyThatConnection) {
    ServerConfig cfg;
    cfg.hello_timeout = 1.0;
    RunningServer s({}, cfg);
    ClientReport good;
    std::thread client([&] { good = run_client(s.client(3.0)); });
    asio::io_context io;
    auto connect = [&] {
        tcp::socket t(io);
        t.connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), s.server->tcp_port()));
        return t;
    };
    std::mt19937 rng(9);
    {  // valid length, random body
        tcp::socket t = connect();
        std::vector<uint8_t> m = {200, 0, 0, 0};
        for (int i = 0; i < 200; ++i) m.push_back(uint8_t(rng()));
        asio::write(t, asio::buffer(m));
        EXPECT_TRUE(closed_within(t, 1000));
    }
    {  // oversized length
        tcp::socket t = connect();
        std::vector<uint8_t> m = {0xff, 0xff, 0xff, 0x7f, 1, 2, 3};
        asio::write(t, asio::buffer(m));
        EXPECT_TRUE(closed_within(t, 1000));
    }
    {  // truncated message, then silence: hello timeout
        tcp::socket t = connect();
        std::vector<uint8_t> m = {100, 0, 0, 0, 1, 2, 3};
        asio::write(t, asio::buffer(m));
        EXPECT_TRUE(closed_within(t, 2500));
    }
    {  // a well-formed message that is not Hello first
        tcp::socket t = connect();
        flatbuffers::FlatBufferBuilder fbb;
        auto r = wire::CreateAssetRequest(fbb, 1, 0, 10);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
        std::vector<uint8_t> m;
        frame_control(fbb, m);
        asio::write(t, asio::buffer(m));
        EXPECT_TRUE(closed_within(t, 1000));
    }
    // A union type without its table, and a type this version does not know:
    // the FlatBuffers verifier passes both (found by the control fuzz target;
    // the server dereferenced the missing Hello and crashed).
    for (uint8_t type : {uint8_t(wire::ControlBody::Hello), uint8_t(wire::ControlBody::Spawn), uint8_t(200)}) {
        tcp::socket t = connect();
        flatbuffers::FlatBufferBuilder fbb;
        wire::ControlBuilder cb(fbb);
        cb.add_body_type(wire::ControlBody(type));
        fbb.Finish(cb.Finish(), wire::ControlIdentifier());
        std::vector<uint8_t> m;
        frame_control(fbb, m);
        asio::write(t, asio::buffer(m));
        EXPECT_TRUE(closed_within(t, 1000)) << "type " << int(type);
    }
    client.join();
    EXPECT_EQ(good.characters, 4);
    EXPECT_GE(s.server->stats().malformed_control, 6u);
}

TEST(NetBadInput, VerifierAndDecoderSurviveFuzzing) {
    std::mt19937 rng(11);
    auto bind = bind_datagram(7, 8);
    size_t accepted = 0;
    for (int i = 0; i < 50000; ++i) {
        std::vector<uint8_t> d;
        if (i % 2) {
            d.resize(rng() % 300);
            for (auto& b : d) b = uint8_t(rng());
        } else {
            d = bind;
            for (int k = 0; k < 1 + int(rng() % 4); ++k) d[rng() % d.size()] = uint8_t(rng());
        }
        if (verify_datagram(d)) ++accepted;
        if (verify_control(d)) ++accepted;
    }
    RecordFormat fmt;
    PoseBuffer pb(chain_format(24, fmt));
    std::vector<uint8_t> rec(24 * 14);
    for (int i = 0; i < 20000; ++i) {
        for (auto& b : rec) b = uint8_t(rng());
        int total = int(rng() % 40) - 5, first = int(rng() % 40) - 5, count = int(rng() % 30) - 2;
        bool valid = total >= 1 && total <= 24 && first >= 0 && count >= 1 && first + count <= total;
        bool ok = pb.add_chunk(rng() % 100, first, count, total, RecordRun{rec.data(), rec.size(), rng() % 8, false, uint8_t(rng() % 3)});
        if (!valid) {
            EXPECT_FALSE(ok);
        }
        BonePose p;
        pb.pose(int(rng() % 24), double(rng() % 120), p);
    }
    std::printf("fuzz: %zu of 100000 mutated buffers passed verification (all handled)\n", accepted);
}

TEST(NetBadInput, SilentClientsAreTimedOut) {
    ServerConfig cfg;
    cfg.client_timeout = 1.0;
    RunningServer s({}, cfg);
    asio::io_context io;
    tcp::socket t(io);
    t.connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), s.server->tcp_port()));
    flatbuffers::FlatBufferBuilder fbb;
    auto name = fbb.CreateString("silent");
    auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, name, 0, 64);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    std::vector<uint8_t> m;
    frame_control(fbb, m);
    asio::write(t, asio::buffer(m));
    // Welcomed, then never binds nor acks: dropped after client_timeout.
    EXPECT_TRUE(closed_within(t, 3000));
    for (int i = 0; i < 50 && s.server->stats().timeouts == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    EXPECT_GE(s.server->stats().timeouts, 1u);
}
