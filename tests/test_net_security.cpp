// test_net_security.cpp — the ten flaws of "Hardening: sessions that survive
// attackers and bad networks", each reproduced on loopback with real sockets
// (docs/protocol.md "Security"): a peer that stops reading, predictable ids,
// a forged source address, slots held over TCP, a NAT rebinding, running out
// of descriptors, an oversized Welcome, a hostile asset size, glTF URIs
// outside the cache and a lost stream that must be an error.
#include <gtest/gtest.h>
#include <netinet/ip.h>
#include <netinet/udp.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <atomic>
#include <cstring>
#include <fstream>
#include <random>
#include <set>
#include <sstream>

#include "asset_cache.h"
#include "crypto.h"
#include "errors.h"
#include "net_test_support.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using asio::ip::tcp;
using asio::ip::udp;
namespace fs = std::filesystem;

namespace {

const auto kLoopback = asio::ip::make_address("127.0.0.1");

std::vector<uint8_t> framed(const flatbuffers::FlatBufferBuilder& fbb) {
    std::vector<uint8_t> m;
    frame_control(fbb, m);
    return m;
}

std::vector<uint8_t> hello_message(const std::string& name = "probe") {
    flatbuffers::FlatBufferBuilder fbb;
    auto n = fbb.CreateString(name);
    auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, n, 0, 0);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    return framed(fbb);
}

std::vector<uint8_t> stats_message() {
    flatbuffers::FlatBufferBuilder fbb;
    wire::StatsBuilder sb(fbb);
    sb.add_rate_kbps(1);
    auto so = sb.Finish();
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Stats, so.Union()), wire::ControlIdentifier());
    return framed(fbb);
}

// Reads one framed control message within `ms`; false on timeout or close.
bool read_message(tcp::socket& s, std::vector<uint8_t>& body, int ms) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    auto read_n = [&](uint8_t* dst, size_t n) {
        size_t got = 0;
        while (got < n) {
            const int left = int(std::chrono::duration_cast<std::chrono::milliseconds>(end - std::chrono::steady_clock::now()).count());
            if (left <= 0) return false;
            pollfd p{s.native_handle(), POLLIN, 0};
            if (::poll(&p, 1, left) <= 0) return false;
            const ssize_t r = ::recv(s.native_handle(), dst + got, n - got, 0);
            if (r <= 0) return false;
            got += size_t(r);
        }
        return true;
    };
    uint8_t len[4];
    if (!read_n(len, 4)) return false;
    uint32_t n = 0;
    read_length({len, 4}, n);
    if (n > MAX_CONTROL_MESSAGE) return false;
    body.resize(n);
    return read_n(body.data(), n);
}

// Connects, says Hello, returns the Welcome's (session id, token).
std::pair<uint64_t, uint64_t> handshake(tcp::socket& t, uint16_t port) {
    t.connect(tcp::endpoint(kLoopback, port));
    asio::write(t, asio::buffer(hello_message()));
    std::vector<uint8_t> body;
    if (!read_message(t, body, 3000)) throw Error("no Welcome");
    const wire::Control* c = verify_control(body);
    if (!c || c->body_type() != wire::ControlBody::Welcome) throw Error("not a Welcome");
    return {c->body_as_Welcome()->session_id(), c->body_as_Welcome()->udp_token()};
}

// Whether the server closed `s` within `ms` (what it sends meanwhile is read and dropped).
bool closed_within(tcp::socket& s, int ms) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    uint8_t buf[4096];
    while (std::chrono::steady_clock::now() < end) {
        pollfd p{s.native_handle(), POLLIN, 0};
        if (::poll(&p, 1, 20) > 0 && ::recv(s.native_handle(), buf, sizeof buf, 0) <= 0) return true;
    }
    return false;
}

size_t udp_bytes_within(udp::socket& s, int ms) {
    size_t total = 0;
    uint8_t buf[2048];
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    while (std::chrono::steady_clock::now() < end) {
        pollfd p{s.native_handle(), POLLIN, 0};
        if (::poll(&p, 1, 20) > 0) {
            const ssize_t r = ::recv(s.native_handle(), buf, sizeof buf, MSG_DONTWAIT);
            if (r > 0) total += size_t(r);
        }
    }
    return total;
}

// A UDP relay between one client and the server, standing in for a NAT:
// nat_change() gives the relay a new upstream port (the server sees the
// client's address change); blackhole drops everything both ways.
class Relay {
public:
    explicit Relay(uint16_t server_port) : server_(kLoopback, server_port), front_(io_), up_(std::make_unique<udp::socket>(io_)) {
        front_.open(udp::v4());
        front_.bind(udp::endpoint(kLoopback, 0));
        open_up();
        thread_ = std::thread([this] { loop(); });
    }
    ~Relay() {
        running_ = false;
        thread_.join();
    }
    uint16_t port() const { return front_.local_endpoint().port(); }
    void nat_change() { change_ = true; }
    std::atomic<bool> blackhole{false};
    std::atomic<uint64_t> down{0};  // datagrams relayed server -> client

private:
    void open_up() {
        up_ = std::make_unique<udp::socket>(io_);
        up_->open(udp::v4());
        up_->bind(udp::endpoint(kLoopback, 0));
    }
    void loop() {
        uint8_t buf[2048];
        while (running_) {
            if (change_.exchange(false)) open_up();
            pollfd p[2] = {{front_.native_handle(), POLLIN, 0}, {up_->native_handle(), POLLIN, 0}};
            if (::poll(p, 2, 5) <= 0) continue;
            asio::error_code ec;
            udp::endpoint from;
            if (p[0].revents) {
                const size_t n = front_.receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec) {
                    client_ = from;
                    if (!blackhole) up_->send_to(asio::buffer(buf, n), server_, 0, ec);
                }
            }
            if (p[1].revents) {
                const size_t n = up_->receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec && !blackhole && client_.port()) {
                    front_.send_to(asio::buffer(buf, n), client_, 0, ec);
                    ++down;
                }
            }
        }
    }
    udp::endpoint server_, client_;
    asio::io_context io_;
    udp::socket front_;
    std::unique_ptr<udp::socket> up_;
    std::atomic<bool> running_{true}, change_{false};
    std::thread thread_;
};

// A hostile control server for client tests: answers Hello with a Welcome
// announcing one asset (`declared` bytes, content `bytes`), then serves at
// most `serve` bytes of chunks in answer to AssetRequests.
class FakeServer {
public:
    FakeServer(std::string name, std::vector<uint8_t> bytes, uint64_t declared, uint64_t serve)
        : name_(std::move(name)), bytes_(std::move(bytes)), declared_(declared), serve_(serve), acc_(io_) {
        acc_.open(tcp::v4());
        acc_.bind(tcp::endpoint(kLoopback, 0));
        acc_.listen();
        thread_ = std::thread([this] { run(); });
    }
    ~FakeServer() {
        ::shutdown(acc_.native_handle(), SHUT_RDWR);
        done_ = true;
        thread_.join();
    }
    uint16_t port() const { return acc_.local_endpoint().port(); }
    ClientOptions client() const {
        ClientOptions o;
        o.host = "127.0.0.1";
        o.port = port();
        o.duration = 1;
        o.connect_timeout = 1.5;
        o.cache_dir = RunningServer::cache_dir() + "/fake-" + std::to_string(port());
        return o;
    }

private:
    void run() {
        pollfd p{acc_.native_handle(), POLLIN, 0};
        while (!done_ && ::poll(&p, 1, 20) == 0) {
        }
        if (done_) return;
        asio::error_code ec;
        tcp::socket t(io_);
        acc_.accept(t, ec);
        if (ec) return;
        std::vector<uint8_t> body;
        if (!read_message(t, body, 3000)) return;
        flatbuffers::FlatBufferBuilder fbb;
        auto nm = fbb.CreateString(name_);
        std::vector<int16_t> order = {0}, parents = {-1};
        auto vo = fbb.CreateVector(order);
        auto vp = fbb.CreateVector(parents);
        auto asset = wire::CreateAsset(fbb, content_hash(bytes_), nm, declared_, 1, false, vo, vp);
        std::vector<flatbuffers::Offset<wire::Asset>> as = {asset};
        auto va = fbb.CreateVector(as);
        auto w = wire::CreateWelcome(fbb, PROTOCOL_VERSION, 1, 2, 9, 30.0f, 1000, va);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Welcome, w.Union()), wire::ControlIdentifier());
        asio::write(t, asio::buffer(framed(fbb)), ec);
        uint64_t served = 0;
        while (!done_) {
            if (!read_message(t, body, 200)) {
                uint8_t b;
                if (::recv(t.native_handle(), &b, 1, MSG_PEEK | MSG_DONTWAIT) == 0) break;  // client gone
                continue;
            }
            const wire::Control* c = verify_control(body);
            if (!c || c->body_type() != wire::ControlBody::AssetRequest) continue;
            const wire::AssetRequest* r = c->body_as_AssetRequest();
            if (served >= serve_ || r->offset() >= bytes_.size()) continue;
            const size_t n = std::min<size_t>(r->length(), bytes_.size() - r->offset());
            flatbuffers::FlatBufferBuilder f;
            auto data = f.CreateVector(bytes_.data() + r->offset(), n);
            auto ch = wire::CreateAssetChunk(f, r->asset_id(), r->offset(), declared_, data);
            f.Finish(wire::CreateControl(f, wire::ControlBody::AssetChunk, ch.Union()), wire::ControlIdentifier());
            asio::write(t, asio::buffer(framed(f)), ec);
            served += n;
        }
    }
    std::string name_;
    std::vector<uint8_t> bytes_;
    uint64_t declared_, serve_;
    asio::io_context io_;
    tcp::acceptor acc_;
    std::atomic<bool> done_{false};
    std::thread thread_;
};

std::string error_of(const ClientOptions& o) {
    try {
        run_client(o);
    } catch (const std::exception& e) {
        return e.what();
    }
    return "";
}

long peak_rss_kib() {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmHWM:", 0) == 0) return std::stol(line.substr(6));
    return -1;
}

// MT19937-64 output -> state word (inverse of the tempering).
uint64_t untemper(uint64_t y) {
    auto undo_right = [](uint64_t v, int s, uint64_t m) {
        uint64_t x = v;
        for (int i = 0; i < 64 / s + 1; ++i) x = v ^ ((x >> s) & m);
        return x;
    };
    auto undo_left = [](uint64_t v, int s, uint64_t m) {
        uint64_t x = v;
        for (int i = 0; i < 64 / s + 1; ++i) x = v ^ ((x << s) & m);
        return x;
    };
    y = undo_right(y, 43, ~0ull);
    y = undo_left(y, 37, 0xFFF7EEE000000000ull);
    y = undo_left(y, 17, 0x71D67FFFEDA60000ull);
    y = undo_right(y, 29, 0x5555555555555555ull);
    return y;
}

}  // namespace

// Flaw 1: a peer that asks for data and stops reading must not stall the
// single server thread (the timeout's Goodbye was a blocking write).
TEST(NetSecurity, PeerThatStopsReadingDoesNotFreezeOthers) {
    ServerConfig cfg;
    cfg.client_timeout = 2.0;
    RunningServer s({}, cfg);
    ClientReport good;
    std::string good_error;
    {
        // Download the assets once, so the streaming client binds at once.
        ClientOptions warm = s.client(0.3);
        run_client(warm);
    }
    std::thread client([&] {
        try {
            good = run_client(s.client(5.0));
        } catch (const std::exception& e) {
            good_error = e.what();
        }
    });
    asio::io_context io;
    tcp::socket attacker(io);
    attacker.open(tcp::v4());
    attacker.set_option(asio::socket_base::receive_buffer_size(4096));
    attacker.connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
    asio::write(attacker, asio::buffer(hello_message("slow reader")));
    // ~2.6 MB of one-byte asset requests: ~5 MB of answers it never reads.
    std::vector<uint8_t> reqs;
    const uint64_t asset = default_assets()[0]->id;
    for (int i = 0; i < 60000; ++i) {
        flatbuffers::FlatBufferBuilder fbb;
        auto r = wire::CreateAssetRequest(fbb, asset, uint64_t(i % 1000), 1);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
        frame_control(fbb, reqs);
    }
    asio::error_code ec;
    attacker.non_blocking(true);
    size_t written = 0;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(3);
    while (written < reqs.size() && std::chrono::steady_clock::now() < until) {
        const size_t n = attacker.write_some(asio::buffer(reqs.data() + written, reqs.size() - written), ec);
        if (ec == asio::error::would_block) {
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
            continue;
        }
        if (ec) break;
        written += n;
    }
    client.join();  // the attacker's socket stays open (unread) until here
    attacker.close();
    ASSERT_EQ(good_error, "");
    ASSERT_GE(good.per_second_kbps.size(), 4u);
    for (double k : good.per_second_kbps) EXPECT_GT(k, 50.0);
    std::printf("slow reader wrote %zu bytes of requests; good client per second:", written);
    for (double k : good.per_second_kbps) std::printf(" %.0f", k);
    std::printf(" kbit/s\n");
}

// Flaw 2: 156 handshakes (312 outputs of std::mt19937_64) must not predict
// the next session's id and token.
TEST(NetSecurity, SessionIdsAndTokensAreUnpredictable) {
    RunningServer s;
    asio::io_context io;
    std::vector<uint64_t> out;
    for (int i = 0; i < 156; ++i) {
        tcp::socket t(io);
        auto [id, token] = handshake(t, s.server->tcp_port());
        out.push_back(id);
        out.push_back(token);
    }
    std::ostringstream state;
    for (uint64_t v : out) state << untemper(v) << ' ';
    state << 312;
    std::mt19937_64 clone;
    std::istringstream(state.str()) >> clone;
    const uint64_t predicted_id = clone(), predicted_token = clone();
    tcp::socket t(io);
    auto [id, token] = handshake(t, s.server->tcp_port());
    EXPECT_NE(id, predicted_id);
    EXPECT_NE(token, predicted_token);
    std::set<uint64_t> distinct(out.begin(), out.end());
    EXPECT_EQ(distinct.size(), out.size());
}

// Flaw 3: a Bind with a forged source address (raw socket) must not make the
// server stream to that address: it gets one Challenge, smaller than the Bind.
TEST(NetSecurity, ForgedSourceBindGetsOnlyAChallenge) {
    const int raw = ::socket(AF_INET, SOCK_RAW, IPPROTO_RAW);
    if (raw < 0) GTEST_SKIP() << "raw sockets not permitted here (" << std::strerror(errno) << ")";
    RunningServer s;
    asio::io_context io;
    udp::socket victim(io);
    victim.open(udp::v4());
    victim.bind(udp::endpoint(kLoopback, 0));
    tcp::socket t(io);
    auto [id, token] = handshake(t, s.server->tcp_port());
    const uint16_t victim_port = victim.local_endpoint().port(), server_port = s.server->udp_port();
    auto forged = [&](const flatbuffers::FlatBufferBuilder& fbb) {  // IPv4 + UDP header, source = the victim
        std::vector<uint8_t> pkt(sizeof(iphdr) + sizeof(udphdr) + fbb.GetSize());
        auto* ip = reinterpret_cast<iphdr*>(pkt.data());
        ip->version = 4;
        ip->ihl = 5;
        ip->ttl = 64;
        ip->protocol = IPPROTO_UDP;
        ip->tot_len = htons(uint16_t(pkt.size()));
        ip->saddr = htonl(INADDR_LOOPBACK);
        ip->daddr = htonl(INADDR_LOOPBACK);
        auto* u = reinterpret_cast<udphdr*>(pkt.data() + sizeof(iphdr));
        u->source = htons(victim_port);
        u->dest = htons(server_port);
        u->len = htons(uint16_t(sizeof(udphdr) + fbb.GetSize()));
        u->check = 0;  // optional over IPv4
        std::memcpy(pkt.data() + sizeof(iphdr) + sizeof(udphdr), fbb.GetBufferPointer(), fbb.GetSize());
        sockaddr_in to{};
        to.sin_family = AF_INET;
        to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        return ::sendto(raw, pkt.data(), pkt.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof to) == ssize_t(pkt.size());
    };
    flatbuffers::FlatBufferBuilder bind;
    build_bind(bind, id, token);
    ASSERT_TRUE(forged(bind));
    size_t received = 0;
    for (int i = 0; i < 8; ++i) {  // keep it alive over TCP and with forged Acks from the victim's address
        asio::write(t, asio::buffer(stats_message()));
        flatbuffers::FlatBufferBuilder ack;
        auto a = wire::CreateAck(ack, id, token, uint32_t(i * 10), 0xffffffffu, 0, 0);
        ack.Finish(wire::CreateDatagram(ack, 0, 0, wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
        forged(ack);
        received += udp_bytes_within(victim, 250);
    }
    ::close(raw);
    EXPECT_LE(received, size_t(bind.GetSize()));  // at most the Challenge: no amplification
    EXPECT_GE(s.server->stats().challenges_sent, 1u);
    std::printf("forged Bind of %u bytes: the victim received %zu bytes in 2 s\n", bind.GetSize(), received);
}

// Flaw 4: sessions that never bind UDP are dropped after client_timeout
// whatever they send over TCP, so they cannot hold every slot.
TEST(NetSecurity, UnboundSessionsCannotHoldSlots) {
    ServerConfig cfg;
    cfg.max_clients = 4;
    cfg.client_timeout = 1.5;
    RunningServer s({}, cfg);
    asio::io_context io;
    std::vector<std::unique_ptr<tcp::socket>> holders;
    for (int i = 0; i < 4; ++i) {
        holders.push_back(std::make_unique<tcp::socket>(io));
        handshake(*holders.back(), s.server->tcp_port());
    }
    std::vector<bool> closed(holders.size(), false);
    const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(2500);
    while (std::chrono::steady_clock::now() < end) {
        for (size_t i = 0; i < holders.size(); ++i) {
            asio::error_code ec;
            if (!closed[i]) asio::write(*holders[i], asio::buffer(stats_message()), ec);
            if (!closed[i] && closed_within(*holders[i], 50)) closed[i] = true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    for (size_t i = 0; i < holders.size(); ++i) EXPECT_TRUE(closed[i]) << "holder " << i << " still open";
    ClientReport r;
    EXPECT_NO_THROW(r = run_client(s.client(1.0)));
    EXPECT_EQ(r.characters, 4);
}

// The same address cannot open more than max_per_address connections.
TEST(NetSecurity, ConnectionsPerAddressAreLimited) {
    ServerConfig cfg;
    cfg.max_per_address = 3;
    RunningServer s({}, cfg);
    asio::io_context io;
    std::vector<std::unique_ptr<tcp::socket>> open;
    for (int i = 0; i < 3; ++i) {
        open.push_back(std::make_unique<tcp::socket>(io));
        handshake(*open.back(), s.server->tcp_port());
    }
    tcp::socket extra(io);
    extra.connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
    std::vector<uint8_t> body;
    ASSERT_TRUE(read_message(extra, body, 2000));
    const wire::Control* c = verify_control(body);
    ASSERT_TRUE(c && c->body_type() == wire::ControlBody::Refuse);
    EXPECT_NE(c->body_as_Refuse()->reason()->str().find("too many connections"), std::string::npos);
    EXPECT_TRUE(closed_within(extra, 2000));
}

// Flaw 5: a NAT rebinding (the client's address changes) must not lose the
// stream: the client binds again after 1 s of silence and the stream moves
// once the new address answers the Challenge.
TEST(NetSecurity, StreamSurvivesNatRebinding) {
    RunningServer s;
    Relay relay(s.server->udp_port());
    ClientOptions o = s.client(5.0);
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = relay.port();
    ClientReport r;
    std::string err;
    std::thread client([&] {
        try {
            r = run_client(o);
        } catch (const std::exception& e) {
            err = e.what();
        }
    });
    for (int i = 0; i < 300 && relay.down < 30; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_GE(relay.down.load(), 30u);
    relay.nat_change();
    const uint64_t at_change = relay.down;
    std::this_thread::sleep_for(std::chrono::milliseconds(3000));
    const uint64_t after = relay.down - at_change;
    client.join();
    EXPECT_EQ(err, "");
    EXPECT_GT(after, 30u) << "no frames after the address changed";
    ASSERT_FALSE(r.per_second_kbps.empty());
    EXPECT_GT(r.per_second_kbps.back(), 50.0);
}

// Flaw 6: when accept() fails for lack of descriptors the server waits
// instead of spinning on the pending connection.
TEST(NetSecurity, AcceptBacksOffWhenOutOfDescriptors) {
    RunningServer s;
    rlimit old{};
    ::getrlimit(RLIMIT_NOFILE, &old);
    int highest = 0;
    for (const auto& e : fs::directory_iterator("/proc/self/fd")) highest = std::max(highest, std::atoi(e.path().filename().c_str()));
    rlimit low = old;
    low.rlim_cur = rlim_t(highest + 64);
    ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &low), 0);
    // The client's socket first, then every descriptor left taken: freeing
    // one for it afterwards raced the server's own threads (in this
    // process), which could take it first ("socket: Too many open files").
    const int c = ::socket(AF_INET, SOCK_STREAM, 0);
    const int null_fd = ::open("/dev/null", O_RDONLY);
    ASSERT_GE(null_fd, 0);
    std::vector<int> filler = {null_fd};
    for (;;) {
        const int fd = ::dup(null_fd);
        if (fd < 0) break;
        filler.push_back(fd);
    }
    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    to.sin_port = htons(s.server->tcp_port());
    const bool connected = c >= 0 && ::connect(c, reinterpret_cast<sockaddr*>(&to), sizeof to) == 0;
    const int connect_errno = connected ? 0 : errno;
    rusage r0{}, r1{};
    ::getrusage(RUSAGE_SELF, &r0);
    std::this_thread::sleep_for(std::chrono::milliseconds(1000));
    ::getrusage(RUSAGE_SELF, &r1);
    for (int fd : filler) ::close(fd);
    ::setrlimit(RLIMIT_NOFILE, &old);
    auto secs = [](const rusage& r) {
        return double(r.ru_utime.tv_sec + r.ru_stime.tv_sec) + 1e-6 * double(r.ru_utime.tv_usec + r.ru_stime.tv_usec);
    };
    const double cpu = secs(r1) - secs(r0);
    ASSERT_TRUE(connected) << (c < 0 ? "socket: " : "connect: ") << std::strerror(connect_errno);
    EXPECT_LT(cpu, 0.3) << "the server spun on accept()";
    // With descriptors back, the waiting connection is served.
    const std::vector<uint8_t> hello = hello_message();
    ASSERT_EQ(::send(c, hello.data(), hello.size(), 0), ssize_t(hello.size()));
    pollfd p{c, POLLIN, 0};
    EXPECT_EQ(::poll(&p, 1, 5000), 1) << "no answer within 5 s (the accept is retried every 100 ms)";
    ::close(c);
    std::printf("1 s out of descriptors: %.3f s of CPU, %llu failed accepts\n", cpu,
                (unsigned long long)s.server->stats().accept_errors);
}

// Flaw 7: a Welcome over the control message limit refuses that session
// with a reason; the process keeps serving. (Instances travel apart in
// version 4; a catalogue of 100 assets still exceeds the limit.)
TEST(NetSecurity, OversizedWelcomeRefusesOnlyThatSession) {
    std::vector<std::shared_ptr<ServerAsset>> many;
    for (int i = 0; i < 100; ++i) many.push_back(default_assets()[size_t(i) % 2]);
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    Server server(cfg, many, default_instances(default_assets()));
    std::thread thread([&] { server.run(); });
    struct Stop {
        Server& s;
        std::thread& t;
        ~Stop() { s.stop(); t.join(); }
    } stop{server, thread};
    struct {
        Server* server;
    } s{&server};
    asio::io_context io;
    for (int attempt = 0; attempt < 2; ++attempt) {
        tcp::socket t(io);
        t.connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
        asio::write(t, asio::buffer(hello_message()));
        std::vector<uint8_t> body;
        ASSERT_TRUE(read_message(t, body, 3000));
        const wire::Control* c = verify_control(body);
        ASSERT_TRUE(c && c->body_type() == wire::ControlBody::Refuse);
        EXPECT_NE(c->body_as_Refuse()->reason()->str().find("control message limit"), std::string::npos);
    }
}

// Flaw 8: a server announcing a huge asset must not make the client reserve
// it: memory follows the bytes received, and sizes over the limit are refused.
TEST(NetSecurity, ClientMemoryFollowsAssetBytesReceived) {
    {
        FakeServer fake("huge.glb", std::vector<uint8_t>(1 << 16, 7), uint64_t(1) << 40, 0);
        const std::string e = error_of(fake.client());
        EXPECT_NE(e.find("limit"), std::string::npos) << e;
    }
    std::ofstream("/proc/self/clear_refs") << "5";  // reset the peak RSS
    const long before = peak_rss_kib();
    FakeServer fake("big.glb", std::vector<uint8_t>(1 << 16, 7), uint64_t(200) << 20, 1 << 16);
    const std::string e = error_of(fake.client());
    const long grown = peak_rss_kib() - before;
    EXPECT_NE(e.find("timed out"), std::string::npos) << e;
    EXPECT_LT(grown, 64 * 1024) << "peak RSS grew by " << grown << " KiB for 64 KiB received";
    std::printf("200 MiB announced, 64 KiB sent: peak RSS +%ld KiB\n", grown);
}

// Flaw 9: external URIs of a .gltf resolve only inside the cache folder.
TEST(NetSecurity, GltfUrisOutsideTheCacheAreRefused) {
    const fs::path root = fs::path(RunningServer::cache_dir()) / "uri-test";
    fs::create_directories(root / "cache");
    std::ofstream(root / "secret.bin") << "0123456789abcdef";
    std::ofstream(root / "cache" / "ok.bin") << "0123456789abcdef";
    auto gltf = [](const std::string& uri) {
        return "{\"asset\":{\"version\":\"2.0\"},\"buffers\":[{\"byteLength\":16,\"uri\":\"" + uri + "\"}]}";
    };
    for (const std::string uri : {"../secret.bin", "/etc/hostname", "%2e%2e/secret.bin", "sub/../../secret.bin",
                                   "file:///etc/hostname", "missing.bin"}) {
        const fs::path p = root / "cache" / "x.gltf";
        std::ofstream(p) << gltf(uri);
        EXPECT_THROW(check_external_uris(p.string()), Error) << uri;
    }
    const fs::path ok = root / "cache" / "ok.gltf";
    std::ofstream(ok) << gltf("ok.bin");
    EXPECT_NO_THROW(check_external_uris(ok.string()));
    // End to end: a server serving such a .gltf: the asset is refused before
    // anything is opened, and the client says which and why (it goes on
    // without that asset; this fake server streams nothing, so the run ends
    // in an error with its report).
    const std::string text = gltf("../../etc/hostname");
    FakeServer fake("evil.gltf", std::vector<uint8_t>(text.begin(), text.end()), text.size(), text.size());
    ClientReport rep;
    try {
        run_client(fake.client());
    } catch (const ClientRunError& e) {
        rep = e.report;
    }
    ASSERT_EQ(rep.assets_failed.size(), 1u) << rep.error;
    EXPECT_EQ(rep.assets_failed[0].first, "evil.gltf");
    EXPECT_NE(rep.assets_failed[0].second.find("outside the cache folder"), std::string::npos) << rep.assets_failed[0].second;
}

// Flaw 10: when the stream is lost for good (here the server times the
// session out after its datagrams stop), the client reports an error.
TEST(NetSecurity, LostStreamIsAnError) {
    ServerConfig cfg;
    cfg.client_timeout = 1.5;
    RunningServer s({}, cfg);
    Relay relay(s.server->udp_port());
    ClientOptions o = s.client(8.0);
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = relay.port();
    std::string err;
    std::thread client([&] { err = error_of(o); });
    for (int i = 0; i < 300 && relay.down < 30; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    relay.blackhole = true;
    const auto t0 = std::chrono::steady_clock::now();
    client.join();
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_NE(err.find("timeout"), std::string::npos) << "client ended with \"" << err << "\"";
    EXPECT_LT(waited, 6.0);
}

// Connect tokens (off by default): with a public key configured, Hello must
// carry a token signed by the matching secret key; expired, forged, missing,
// replayed or other-server tokens are refused with the reason.
TEST(NetSecurity, ConnectTokensAreCheckedWhenConfigured) {
    namespace c = progskin::net::crypto;
    c::PublicKey pk;
    c::SecretKey sk;
    c::signing_keypair(pk, sk);
    ServerConfig cfg;
    cfg.token_public_key = c::to_hex(pk);
    cfg.public_address = "game.example:7777";
    RunningServer s({}, cfg);
    asio::io_context io;
    auto hello_with = [&](const std::string& token) {
        tcp::socket t(io);
        t.connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
        flatbuffers::FlatBufferBuilder fbb;
        auto n = fbb.CreateString("token test");
        auto tk = fbb.CreateString(token);
        auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, n, token.empty() ? 0 : tk, 0);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
        asio::write(t, asio::buffer(framed(fbb)));
        std::vector<uint8_t> body;
        if (!read_message(t, body, 3000)) return std::string("no answer");
        const wire::Control* ctl = verify_control(body);
        if (!ctl) return std::string("malformed");
        if (ctl->body_type() == wire::ControlBody::Welcome) return std::string("welcome");
        if (ctl->body_type() == wire::ControlBody::Refuse) return ctl->body_as_Refuse()->reason()->str();
        return std::string("other");
    };
    const uint64_t now = c::unix_now();
    const std::string good = c::issue_connect_token(sk, 7, now, 60, cfg.public_address);
    EXPECT_EQ(hello_with(good), "welcome");
    EXPECT_EQ(hello_with(good), "connect token already used");
    EXPECT_EQ(hello_with(c::issue_connect_token(sk, 7, now - 120, 60, cfg.public_address)), "connect token expired");
    c::PublicKey other_pk;
    c::SecretKey other_sk;
    c::signing_keypair(other_pk, other_sk);
    EXPECT_EQ(hello_with(c::issue_connect_token(other_sk, 7, now, 60, cfg.public_address)), "connect token signature invalid");
    EXPECT_NE(hello_with(c::issue_connect_token(sk, 7, now, 60, "elsewhere:7777")).find("another server"), std::string::npos);
    EXPECT_EQ(hello_with(""), "missing connect token");
    EXPECT_EQ(hello_with("garbage"), "malformed connect token");
    // The existing client carries it in --token unchanged.
    ClientOptions o = s.client(0.5);
    o.token = c::issue_connect_token(sk, 8, now, 60, cfg.public_address);
    ClientReport r;
    EXPECT_NO_THROW(r = run_client(o));
    EXPECT_EQ(r.characters, 4);
    EXPECT_GE(s.server->stats().tokens_refused, 6u);
}

// A server configuration with the test-only certificate pair (tests/data/tls).
static ServerConfig test_tls_config() {
    ServerConfig cfg;
    cfg.tls_cert_file = std::string(PROGSKIN_TEST_DATA) + "/tls/test_cert.pem";
    cfg.tls_key_file = std::string(PROGSKIN_TEST_DATA) + "/tls/test_key.pem";
    return cfg;
}

// One framed control message body read from a TLS stream (blocking);
// false when its length is over the limit.
static bool read_tls_message(asio::ssl::stream<tcp::socket>& tls, std::vector<uint8_t>& body) {
    uint8_t len[4];
    asio::read(tls, asio::buffer(len));
    uint32_t n = 0;
    read_length({len, 4}, n);
    if (n > MAX_CONTROL_MESSAGE) return false;
    body.resize(n);
    asio::read(tls, asio::buffer(body));
    return true;
}

// TLS on the control channel (off by default): a TLS client that verifies the
// server's certificate gets its Welcome; a plain-TCP Hello fails the
// handshake and only that connection is closed.
TEST(NetSecurity, ControlChannelOverTlsWhenConfigured) {
    ServerConfig cfg = test_tls_config();
    RunningServer s({}, cfg);
    asio::io_context io;
    asio::ssl::context ctx(asio::ssl::context::tls_client);
    ctx.load_verify_file(cfg.tls_cert_file);
    ctx.set_verify_mode(asio::ssl::verify_peer);
    asio::ssl::stream<tcp::socket> tls(io, ctx);
    tls.set_verify_callback(asio::ssl::host_name_verification("localhost"));
    tls.next_layer().connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
    tls.handshake(asio::ssl::stream_base::client);
    asio::write(tls, asio::buffer(hello_message("tls")));
    std::vector<uint8_t> body;
    ASSERT_TRUE(read_tls_message(tls, body));
    const wire::Control* c = verify_control(body);
    ASSERT_TRUE(c);
    EXPECT_EQ(c->body_type(), wire::ControlBody::Welcome);
    // Plain TCP: the handshake fails, that connection closes, the TLS session stays.
    tcp::socket plain(io);
    plain.connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
    asio::write(plain, asio::buffer(hello_message("plain")));
    EXPECT_TRUE(closed_within(plain, 2000));
    for (int i = 0; i < 50 && s.server->stats().tls_failures == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    EXPECT_EQ(s.server->stats().tls_failures, 1u);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));  // sessions_active is counted each tick
    EXPECT_EQ(s.server->stats().sessions_active, 1u);
}

// Sealed datagrams (with TLS, off by default): the keys come in the Welcome;
// the Bind, Challenge, ChallengeResponse, BindAck and Frames are all sealed;
// an unsealed Bind, a forged one and a replayed one get nothing.
TEST(NetSecurity, SealedDatagramsWhenConfigured) {
    namespace c = progskin::net::crypto;
    ServerConfig cfg = test_tls_config();
    cfg.seal_datagrams = true;
    RunningServer s({}, cfg);
    asio::io_context io;
    asio::ssl::context ctx(asio::ssl::context::tls_client);
    ctx.load_verify_file(cfg.tls_cert_file);
    ctx.set_verify_mode(asio::ssl::verify_peer);
    asio::ssl::stream<tcp::socket> tls(io, ctx);
    tls.next_layer().connect(tcp::endpoint(kLoopback, s.server->tcp_port()));
    tls.handshake(asio::ssl::stream_base::client);
    asio::write(tls, asio::buffer(hello_message("sealed")));
    std::vector<uint8_t> body;
    ASSERT_TRUE(read_tls_message(tls, body));
    const wire::Control* ctl = verify_control(body);
    ASSERT_TRUE(ctl && ctl->body_type() == wire::ControlBody::Welcome);
    const wire::Welcome* w = ctl->body_as_Welcome();
    ASSERT_TRUE(w->datagram_keys() && w->datagram_keys()->size() == 2 * c::KEY_BYTES);
    c::Key down{}, up{};
    std::copy(w->datagram_keys()->begin(), w->datagram_keys()->begin() + c::KEY_BYTES, down.begin());
    std::copy(w->datagram_keys()->begin() + c::KEY_BYTES, w->datagram_keys()->end(), up.begin());
    const uint64_t id = w->session_id(), token = w->udp_token();
    c::Sealer sealer(up);
    c::Opener opener(down);

    udp::socket u(io);
    u.open(udp::v4());
    u.bind(udp::endpoint(kLoopback, 0));
    const udp::endpoint server(kLoopback, s.server->udp_port());
    std::vector<uint8_t> wire_buf, plain;
    auto send_sealed = [&](const flatbuffers::FlatBufferBuilder& fbb) {
        c::seal_datagram(sealer, id, PROTOCOL_VERSION, {fbb.GetBufferPointer(), fbb.GetSize()}, wire_buf);
        u.send_to(asio::buffer(wire_buf), server);
        return wire_buf;
    };
    // Unsealed Bind: dropped, nothing back.
    flatbuffers::FlatBufferBuilder bind;
    build_bind(bind, id, token);
    u.send_to(asio::buffer(bind.GetBufferPointer(), bind.GetSize()), server);
    EXPECT_EQ(udp_bytes_within(u, 200), 0u);
    // The same Bind sealed: answered with a (sealed) Challenge.
    std::vector<uint8_t> sealed_bind = send_sealed(bind);
    // Receive sealed datagrams for up to `ms`, returning the opened ones.
    auto receive = [&](int ms) {
        std::vector<std::vector<uint8_t>> got;
        const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
        uint8_t buf[2048];
        while (std::chrono::steady_clock::now() < end) {
            pollfd p{u.native_handle(), POLLIN, 0};
            if (::poll(&p, 1, 10) <= 0) continue;
            const ssize_t r = ::recv(u.native_handle(), buf, sizeof buf, MSG_DONTWAIT);
            if (r <= 0) continue;
            uint64_t seq = 0;
            EXPECT_EQ(c::open_datagram(opener, id, PROTOCOL_VERSION, {buf, size_t(r)}, plain, seq), c::OpenResult::ok);
            got.push_back(plain);
        }
        return got;
    };
    auto challenge = receive(200);
    ASSERT_EQ(challenge.size(), 1u);
    const wire::Datagram* d = verify_datagram(challenge[0]);
    ASSERT_TRUE(d && d->body_type() == wire::DatagramBody::Challenge);
    EXPECT_LT(challenge[0].size(), size_t(bind.GetSize()));
    // The sealed Bind replayed, then with one byte changed (forged): nothing.
    u.send_to(asio::buffer(sealed_bind), server);
    sealed_bind[sealed_bind.size() / 2] ^= 1;
    u.send_to(asio::buffer(sealed_bind), server);
    EXPECT_EQ(udp_bytes_within(u, 200), 0u);
    flatbuffers::FlatBufferBuilder resp;
    const auto* nonce = d->body_as_Challenge()->nonce();
    build_challenge_response(resp, id, token, {nonce->data(), nonce->size()});
    send_sealed(resp);
    auto stream = receive(700);
    size_t frames = 0, acks = 0;
    for (const auto& g : stream) {
        FrameDatagram fd;
        const wire::Datagram* x = verify_datagram(g);
        ASSERT_TRUE(x || read_frame_datagram(g, fd));
        frames += !x;
        acks += x && x->body_type() == wire::DatagramBody::BindAck;
    }
    EXPECT_EQ(acks, 1u);
    EXPECT_GE(frames, 10u);
    // The unsealed Bind is rejected; the replayed and the forged one carry a
    // sequence already opened: stale (dropped before the tag).
    EXPECT_GE(s.server->stats().rejected_datagrams, 1u);
    EXPECT_GE(s.server->stats().stale_datagrams, 2u);
    std::printf("sealed: %zu frames in 0.7 s, every one opened; unsealed, replayed and forged datagrams dropped\n", frames);
}
