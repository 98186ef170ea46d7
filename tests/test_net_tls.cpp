// test_net_tls.cpp — the Client's authenticated, encrypted sessions on
// loopback with real sockets (docs/protocol.md "Security"): TLS on the
// control channel verified by a pinned fingerprint or a CA file, sealed
// datagrams both ways with the verification error unchanged, clear failures
// for a wrong pin, a CA that did not sign, a configuration that trusts
// nothing; forged, unsealed and replayed datagrams dropped and counted; and
// the server's self-signed development identity (server/tls_identity.h).
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>

#include <asio.hpp>
#include <atomic>
#include <filesystem>
#include <mutex>

#include "crypto.h"
#include "errors.h"
#include "net_test_support.h"
#include "tls_identity.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using asio::ip::udp;
namespace fs = std::filesystem;

namespace {

const std::string kCert = std::string(PROGSKIN_TEST_DATA) + "/tls/test_cert.pem";  // CN localhost, SAN 127.0.0.1
const std::string kKey = std::string(PROGSKIN_TEST_DATA) + "/tls/test_key.pem";

ServerConfig tls_config(bool seal) {
    ServerConfig cfg;
    cfg.tls_cert_file = kCert;
    cfg.tls_key_file = kKey;
    cfg.seal_datagrams = seal;
    return cfg;
}

std::string temp_dir(const std::string& name) {
    const fs::path p = fs::temp_directory_path() / ("progskin-tls-test-" + std::to_string(::getpid()) + "-" + name);
    fs::remove_all(p);
    return p.string();
}

// Runs a Client until it fails, streams or `seconds` pass; returns its state.
ClientState drive(Client& c, double seconds) {
    const double end = now_seconds() + seconds;
    while (now_seconds() < end) {
        c.update(now_seconds());
        if (c.state() == ClientState::Failed || c.state() == ClientState::Streaming) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return c.state();
}

ClientConfig config(const RunningServer&) {
    ClientConfig cfg;
    cfg.tls = true;
    cfg.cache_dir = RunningServer::cache_dir();
    cfg.connect_timeout = 5;
    return cfg;
}

// A UDP relay between the client and the server (the client's --udp-via):
// it forwards both ways, keeps the last datagram sent to the client, and
// can inject datagrams toward the client from the address the client
// streams from (so only the seal can tell them apart).
class Relay {
public:
    explicit Relay(uint16_t server_port)
        : server_(asio::ip::make_address("127.0.0.1"), server_port), front_(io_), up_(io_) {
        for (udp::socket* s : {&front_, &up_}) {
            s->open(udp::v4());
            s->bind(udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
        }
        thread_ = std::thread([this] { loop(); });
    }
    ~Relay() {
        running_ = false;
        thread_.join();
    }
    uint16_t port() const { return front_.local_endpoint().port(); }
    std::vector<uint8_t> last_down() {
        std::lock_guard<std::mutex> l(m_);
        return last_;
    }
    // A new upstream port: the server sees the client's address change (a NAT rebinding).
    void nat_change() { change_ = true; }
    void inject(const std::vector<uint8_t>& d) {
        std::lock_guard<std::mutex> l(m_);
        asio::error_code ec;
        front_.send_to(asio::buffer(d), client_, 0, ec);
    }

private:
    void loop() {
        uint8_t buf[2048];
        while (running_) {
            if (change_.exchange(false)) {
                std::lock_guard<std::mutex> l(m_);
                asio::error_code ec;
                up_.close(ec);
                up_.open(udp::v4());
                up_.bind(udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
            }
            pollfd p[2] = {{front_.native_handle(), POLLIN, 0}, {up_.native_handle(), POLLIN, 0}};
            if (::poll(p, 2, 5) <= 0) continue;
            std::lock_guard<std::mutex> l(m_);
            asio::error_code ec;
            udp::endpoint from;
            if (p[0].revents) {
                const size_t n = front_.receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec) {
                    client_ = from;
                    up_.send_to(asio::buffer(buf, n), server_, 0, ec);
                }
            }
            if (p[1].revents) {
                const size_t n = up_.receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec && client_.port()) {
                    front_.send_to(asio::buffer(buf, n), client_, 0, ec);
                    last_.assign(buf, buf + n);
                }
            }
        }
    }
    udp::endpoint server_, client_;
    asio::io_context io_;
    udp::socket front_, up_;
    std::mutex m_;
    std::vector<uint8_t> last_;
    std::atomic<bool> running_{true}, change_{false};
    std::thread thread_;
};

}  // namespace

// TLS (pinned and CA-verified) with sealed datagrams: the characters stream
// and the displayed error stays within the quantisation bound, as in plain
// NetLoopback; every datagram opened (nothing malformed), the server
// rejected none.
TEST(NetTls, ClientStreamsOverTlsWithSealedDatagrams) {
    RunningServer s({}, tls_config(true));
    ClientOptions o = s.client(3.0);
    o.tls = true;
    o.pin_sha256 = certificate_sha256(kCert);
    o.ca_file = kCert;  // both: the chain and host name (127.0.0.1 in its SAN), and the pin
    o.verify = true;
    o.snap_to_ticks = true;
    ClientReport r = run_client(o);
    ASSERT_EQ(r.instances.size(), 4u);
    double bound_pct = 0;
    for (const auto& a : default_assets())
        bound_pct = std::max(bound_pct, 100.0 * quantisation_bound(a->format, a->bind_radius, a->max_scale) / rest_diagonal(a->character));
    EXPECT_EQ(r.characters, 4);
    EXPECT_EQ(r.malformed, 0u);
    EXPECT_GE(r.datagrams, 60u);
    EXPECT_GE(r.max_pct, 0.0);
    EXPECT_LE(r.max_pct, bound_pct);
    EXPECT_EQ(s.server->stats().rejected_datagrams, 0u);
    EXPECT_EQ(s.server->stats().tls_failures, 0u);
    std::printf("TLS + sealed: %.1f kbit/s, %llu datagrams, RMS %.5f%%, max %.5f%% (bound %.5f%%)\n", r.rate_kbps,
                (unsigned long long)r.datagrams, r.rms_pct, r.max_pct, bound_pct);
}

TEST(NetTls, WrongPinFailsClearly) {
    RunningServer s({}, tls_config(true));
    ClientConfig cfg = config(s);
    std::string pin = certificate_sha256(kCert);
    pin[5] = pin[5] == 'a' ? 'b' : 'a';
    cfg.pin_sha256 = pin;
    Client c(cfg);
    c.connect("127.0.0.1", s.server->tcp_port());
    ASSERT_EQ(drive(c, 5), ClientState::Failed);
    EXPECT_NE(c.error().find("does not match the pinned " + pin), std::string::npos) << c.error();
    EXPECT_NE(c.error().find(certificate_sha256(kCert)), std::string::npos) << c.error();
}

TEST(NetTls, CaThatDidNotSignFails) {
    RunningServer s({}, tls_config(true));
    const TlsIdentity other = ensure_self_signed(temp_dir("other-ca"));
    ClientConfig cfg = config(s);
    cfg.ca_file = other.cert_path;
    Client c(cfg);
    c.connect("127.0.0.1", s.server->tcp_port());
    ASSERT_EQ(drive(c, 5), ClientState::Failed);
    EXPECT_EQ(c.error().rfind("server certificate not trusted: ", 0), 0u) << c.error();
    fs::remove_all(fs::path(other.cert_path).parent_path());
}

// The CA signed it, but for other names: the host name check refuses it.
TEST(NetTls, CertificateForAnotherHostFails) {
    RunningServer s({}, tls_config(false));
    ClientConfig cfg = config(s);
    cfg.ca_file = kCert;
    Client c(cfg);
    // "127.1" resolves to 127.0.0.1 but is a host name, not one in the certificate.
    c.connect("127.1", s.server->tcp_port());
    ASSERT_EQ(drive(c, 5), ClientState::Failed);
    EXPECT_NE(c.error().find("not trusted: the certificate is not for 127.1"), std::string::npos) << c.error();
}

TEST(NetTls, TlsWithoutAWayToTrustRefusesToConnect) {
    RunningServer s({}, tls_config(true));
    Client c(config(s));
    c.connect("127.0.0.1", s.server->tcp_port());
    EXPECT_EQ(c.state(), ClientState::Failed);
    EXPECT_NE(c.error().find("TLS needs a way to trust"), std::string::npos) << c.error();
    EXPECT_EQ(s.server->stats().sessions_total, 0u);
}

TEST(NetTls, InsecureAcceptsAnyCertificate) {
    RunningServer s({}, tls_config(false));
    ClientConfig cfg = config(s);
    cfg.insecure = true;
    Client c(cfg);
    c.connect("127.0.0.1", s.server->tcp_port());
    EXPECT_EQ(drive(c, 5), ClientState::Streaming) << c.error();
}

// A client pinned to the test certificate whose datagrams go through `relay`.
static ClientConfig pinned_via(const RunningServer& s, const Relay& relay) {
    ClientConfig cfg = config(s);
    cfg.pin_sha256 = certificate_sha256(kCert);
    cfg.udp_via_host = "127.0.0.1";
    cfg.udp_via_port = relay.port();
    return cfg;
}

// Drives the client's game loop for `seconds`.
static void update_for(Client& c, double seconds) {
    const double end = now_seconds() + seconds;
    while (now_seconds() < end) {
        c.update(now_seconds());
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
}

// Datagrams arriving from the stream's own address that are not sealed by
// the server or forged (one byte changed) are dropped and counted in
// stats().malformed; one replayed (the server's sealing, a sequence the
// client already opened) is dropped and counted in stats().duplicates, as
// the network's duplicates are; the stream goes on.
TEST(NetTls, ForgedUnsealedAndReplayedDatagramsAreDropped) {
    RunningServer s({}, tls_config(true));
    Relay relay(s.server->udp_port());
    Client c(pinned_via(s, relay));
    c.connect("127.0.0.1", s.server->tcp_port());
    ASSERT_EQ(drive(c, 5), ClientState::Streaming) << c.error();
    auto run_for = [&](double seconds) { update_for(c, seconds); };
    run_for(0.5);
    const ClientStats before = c.stats();
    ASSERT_GT(before.datagrams, 5u);
    EXPECT_EQ(before.malformed, 0u);
    const std::vector<uint8_t> sealed = relay.last_down();
    ASSERT_GT(sealed.size(), crypto::SEALED_DATAGRAM_OVERHEAD);
    // Unsealed: a well-formed Challenge in the clear.
    flatbuffers::FlatBufferBuilder fbb;
    std::vector<uint8_t> nonce(CHALLENGE_NONCE, 7);
    auto n = fbb.CreateVector(nonce);
    auto ch = wire::CreateChallenge(fbb, crypto::sealed_session_id(sealed), n);
    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Challenge, ch.Union()), wire::DatagramIdentifier());
    relay.inject({fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()});
    // Replayed: the last sealed datagram again (the client already opened it).
    relay.inject(sealed);
    // Forged: one byte of its ciphertext changed.
    std::vector<uint8_t> forged = sealed;
    forged[forged.size() / 2] ^= 1;
    relay.inject(forged);
    // Sealed under another key.
    crypto::Sealer stranger(crypto::random_key());
    std::vector<uint8_t> other;
    crypto::seal_datagram(stranger, crypto::sealed_session_id(sealed), PROTOCOL_VERSION, {fbb.GetBufferPointer(), fbb.GetSize()},
                          other);
    relay.inject(other);
    run_for(0.5);
    const ClientStats after = c.stats();
    EXPECT_EQ(after.malformed - before.malformed, 3u);
    EXPECT_EQ(after.duplicates - before.duplicates, 1u);
    EXPECT_GT(after.datagrams, before.datagrams + 5);
    EXPECT_EQ(c.state(), ClientState::Streaming) << c.error();
    std::printf("dropped 4 injected datagrams: %llu malformed, %llu duplicate; %llu frames opened meanwhile\n",
                (unsigned long long)(after.malformed - before.malformed), (unsigned long long)(after.duplicates - before.duplicates),
                (unsigned long long)(after.datagrams - before.datagrams));
}

// A NAT rebinding in a sealed session: the client's sealed Binds from the
// new address are challenged (sealed) and the stream moves there.
TEST(NetTls, SealedStreamSurvivesNatRebinding) {
    RunningServer s({}, tls_config(true));
    Relay relay(s.server->udp_port());
    Client c(pinned_via(s, relay));
    c.connect("127.0.0.1", s.server->tcp_port());
    ASSERT_EQ(drive(c, 5), ClientState::Streaming) << c.error();
    auto run_for = [&](double seconds) { update_for(c, seconds); };
    run_for(0.5);
    relay.nat_change();
    const uint64_t at_change = c.stats().datagrams;
    run_for(3.0);
    EXPECT_EQ(c.state(), ClientState::Streaming) << c.error();
    EXPECT_GT(c.stats().datagrams - at_change, 30u) << "no frames after the address changed";
    EXPECT_EQ(c.stats().malformed, 0u);
}

// Datagram keys in a Welcome over plain TCP would be readable by anyone on
// the path: the client refuses them (a hand-written plain server sends some).
TEST(NetTls, DatagramKeysOverPlainTcpAreRefused) {
    asio::io_context io;
    asio::ip::tcp::acceptor acc(io, asio::ip::tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
    std::thread fake([&] {
        asio::ip::tcp::socket t(io);
        acc.accept(t);
        uint8_t len[4];
        asio::read(t, asio::buffer(len));  // Hello: read and ignored
        uint32_t n = 0;
        read_length({len, 4}, n);
        std::vector<uint8_t> hello(n);
        asio::read(t, asio::buffer(hello));
        flatbuffers::FlatBufferBuilder fbb;
        std::vector<uint8_t> keys(2 * crypto::KEY_BYTES, 1);
        auto k = fbb.CreateVector(keys);
        wire::WelcomeBuilder wb(fbb);
        wb.add_version(PROTOCOL_VERSION);
        wb.add_session_id(1);
        wb.add_udp_port(9);
        wb.add_tick_rate(30);
        wb.add_datagram_keys(k);
        auto w = wb.Finish();
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Welcome, w.Union()), wire::ControlIdentifier());
        std::vector<uint8_t> msg;
        frame_control(fbb, msg);
        asio::write(t, asio::buffer(msg));
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
    });
    ClientConfig cfg;
    cfg.cache_dir = RunningServer::cache_dir();
    Client c(cfg);
    c.connect("127.0.0.1", acc.local_endpoint().port());
    EXPECT_EQ(drive(c, 3), ClientState::Failed);
    EXPECT_EQ(c.error(), "server sent datagram keys over an unencrypted channel");
    fake.join();
}

// Without TLS on either side nothing changes: the plain session streams.
TEST(NetTls, PlainClientStreamsFromPlainServer) {
    RunningServer s;
    ClientConfig cfg = config(s);
    cfg.tls = false;
    Client c(cfg);
    c.connect("127.0.0.1", s.server->tcp_port());
    EXPECT_EQ(drive(c, 5), ClientState::Streaming) << c.error();
}

TEST(TlsIdentity, GeneratedOnceThenReused) {
    const std::string dir = temp_dir("identity");
    const TlsIdentity a = ensure_self_signed(dir);
    EXPECT_TRUE(a.created);
    EXPECT_EQ(a.sha256_hex.size(), 64u);
    EXPECT_EQ(a.sha256_hex, certificate_sha256(a.cert_path));
    EXPECT_EQ(fs::status(a.key_path).permissions() & (fs::perms::group_all | fs::perms::others_all), fs::perms::none);
    const TlsIdentity b = ensure_self_signed(dir);
    EXPECT_FALSE(b.created);
    EXPECT_EQ(b.sha256_hex, a.sha256_hex);
    EXPECT_EQ(b.cert_path, a.cert_path);
    // A server uses it, and a client trusts it as a CA (SAN 127.0.0.1) and by pin.
    ServerConfig scfg;
    scfg.tls_cert_file = a.cert_path;
    scfg.tls_key_file = a.key_path;
    scfg.seal_datagrams = true;
    RunningServer s({}, scfg);
    ClientConfig cfg = config(s);
    cfg.ca_file = a.cert_path;
    cfg.pin_sha256 = a.sha256_hex;
    Client c(cfg);
    c.connect("127.0.0.1", s.server->tcp_port());
    EXPECT_EQ(drive(c, 5), ClientState::Streaming) << c.error();
    // Half a pair is an error, not silently replaced.
    fs::remove(a.cert_path);
    EXPECT_THROW(ensure_self_signed(dir), Error);
    fs::remove_all(dir);
}
