// client.cpp — see client.h: the shell around ClientSession (session.h).
// The Client owns the sockets and moves bytes: the TCP connection (with
// ClientConfig::tls, TLS from the first byte: asio::ssl::stream over the TCP
// socket, async handshake in the same io_context; the certificate checked
// against ca_file (chain + host name) and/or pin_sha256 (SHA-256 of its DER)
// before the session's Hello), the UDP socket (arrival times from the
// kernel), and what the session puts in its Outbox after each call.
// Everything is driven by update(): one io_context polled, non-blocking
// sockets, no thread.
#include "client.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <cctype>
#include <cstring>

#include <openssl/evp.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <openssl/x509_vfy.h>

#include "crypto.h"
#include "errors.h"
#include "session.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;

namespace {

// Receives one datagram with the kernel's arrival time (SO_TIMESTAMPNS), so
// the per-second rate bins reflect the wire even when the game loop is late.
// Returns -1 when nothing is pending; t is on the now_seconds() clock.
ssize_t receive_stamped(udp::socket& s, uint8_t* buf, size_t cap, udp::endpoint& from, double& t) {
    sockaddr_storage addr{};
    iovec iov{buf, cap};
    alignas(cmsghdr) char control[128];
    msghdr msg{};
    msg.msg_name = &addr;
    msg.msg_namelen = sizeof addr;
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    ssize_t n = ::recvmsg(s.native_handle(), &msg, MSG_DONTWAIT);
    if (n < 0) return -1;
    t = now_seconds();
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            timespec ts;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            timespec rt;
            ::clock_gettime(CLOCK_REALTIME, &rt);
            double age = double(rt.tv_sec - ts.tv_sec) + 1e-9 * double(rt.tv_nsec - ts.tv_nsec);
            if (age > 0 && age < 5.0) t -= age;
        }
    }
    if (addr.ss_family == AF_INET) {
        const auto* in = reinterpret_cast<const sockaddr_in*>(&addr);
        from = udp::endpoint(asio::ip::address_v4(ntohl(in->sin_addr.s_addr)), ntohs(in->sin_port));
    }
    if (msg.msg_flags & MSG_TRUNC) return ssize_t(cap);  // cap > MAX_DATAGRAM: dropped as malformed
    return n;
}

}  // namespace

struct Client::Impl final : DatagramSource {
    ClientConfig cfg;  // the TLS and UDP settings (the session has its copy)
    Outbox out;
    ClientSession session;
    asio::io_context io;
    tcp::socket tcp_sock{io};
    // TLS (cfg.tls): the context outlives the stream, the stream runs over tcp_sock.
    std::unique_ptr<asio::ssl::context> ssl_ctx;
    std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;
    std::string tls_verify_error;  // the first reason the chain or host name was refused
    std::string pin;               // cfg.pin_sha256 normalised: 64 lower-case hex digits, or empty
    udp::socket udp_sock{io};
    udp::endpoint server_udp;
    std::string host;
    uint16_t port = 0;
    // connect()'s list; the server in use; servers tried since the stream was last up
    std::vector<ServerAddress> servers;
    size_t current = 0, tried = 0;
    // Control channel: bytes read, and the batch being written while the
    // session's Outbox::control fills (both keep their capacity).
    std::vector<uint8_t> rx_chunk = std::vector<uint8_t>(65536), tx_inflight;
    bool reading = false, writing = false;
    alignas(16) uint8_t buf[2048];  // one received datagram

    explicit Impl(const ClientConfig& c) : cfg(c), session(c, out) {
        out.datagram_bytes.reserve(8 * 1280);  // what one update sends, without reallocating
        out.datagram_ends.reserve(16);
    }

    // After every call into the session: its datagrams out, its control
    // bytes to the channel; once it has ended, the sockets closed.
    void flush() {
        asio::error_code ig;
        for (size_t i = 0; i < out.datagrams(); ++i)
            udp_sock.send_to(asio::buffer(out.datagram(i).data(), out.datagram(i).size()), server_udp, 0, ig);
        out.clear_datagrams();
        write_next();
        if (!session.running()) {
            tcp_sock.close(ig);
            udp_sock.close(ig);
        }
    }
    void fail(FailReason why, const std::string& text) {
        session.fail(why, text);
        flush();
    }

    // ------------------------------------------------------------ control --
    void write_next() {
        if (writing || out.control.empty() || !tcp_sock.is_open()) return;
        writing = true;
        std::swap(out.control, tx_inflight);
        auto done = [this](asio::error_code ec, size_t) {
            writing = false;
            if (ec) return fail(FailReason::ChannelLost, "control channel: " + ec.message());
            tx_inflight.clear();
            write_next();
        };
        if (tls) asio::async_write(*tls, asio::buffer(tx_inflight), done);
        else asio::async_write(tcp_sock, asio::buffer(tx_inflight), done);
    }
    void read_more() {
        if (reading) return;
        reading = true;
        auto done = [this](asio::error_code ec, size_t n) {
            reading = false;
            if (!session.running()) return;
            if (ec == asio::error::eof || ec == asio::ssl::error::stream_truncated) session.on_channel_closed();
            else if (ec) session.fail(FailReason::ChannelLost, "control channel: " + ec.message());
            else session.on_control_bytes({rx_chunk.data(), n}, now_seconds());
            flush();
            if (session.running()) read_more();
        };
        if (tls) tls->async_read_some(asio::buffer(rx_chunk), done);
        else tcp_sock.async_read_some(asio::buffer(rx_chunk), done);
    }
    // TCP connected (and the TLS handshake and pin checked): Hello, then read.
    void channel_ready() {
        session.on_channel_ready();
        flush();
        read_more();
    }

    // ---------------------------------------------------------------- TLS --
    // Sets up the TLS context before connecting; false (and Failed) when the
    // configuration trusts nothing or the CA file cannot be read.
    bool setup_tls() {
        if (!cfg.pin_sha256.empty()) {
            for (char ch : cfg.pin_sha256)
                if (ch != ':') pin.push_back(char(std::tolower(static_cast<unsigned char>(ch))));
            if (pin.size() != 64 || pin.find_first_not_of("0123456789abcdef") != std::string::npos) {
                fail(FailReason::Config, "the pinned certificate fingerprint must be 64 hex digits (SHA-256), not \"" + cfg.pin_sha256 + "\"");
                return false;
            }
        }
        if (cfg.ca_file.empty() && pin.empty() && !cfg.insecure) {
            fail(FailReason::Config, "TLS needs a way to trust the server's certificate: a CA file, a pinned SHA-256 fingerprint, "
                 "or insecure mode (development only)");
            return false;
        }
        ssl_ctx = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_client);
        ssl_ctx->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 |
                             asio::ssl::context::no_sslv3 | asio::ssl::context::no_tlsv1 | asio::ssl::context::no_tlsv1_1);
        asio::error_code ec;
        if (!cfg.ca_file.empty()) {
            ssl_ctx->load_verify_file(cfg.ca_file, ec);
            if (ec) {
                fail(FailReason::Config, "cannot read the CA file " + cfg.ca_file + ": " + ec.message());
                return false;
            }
            ssl_ctx->set_verify_mode(asio::ssl::verify_peer);
        } else {
            ssl_ctx->set_verify_mode(asio::ssl::verify_none);  // pinned or insecure: checked after the handshake
        }
        tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(tcp_sock, *ssl_ctx);
        if (!cfg.ca_file.empty()) {
            asio::ssl::host_name_verification by_name(host);
            tls->set_verify_callback([this, by_name](bool preverified, asio::ssl::verify_context& vc) {
                X509_STORE_CTX* x = vc.native_handle();
                if (!preverified) {
                    if (tls_verify_error.empty()) tls_verify_error = X509_verify_cert_error_string(X509_STORE_CTX_get_error(x));
                    return false;
                }
                if (!by_name(preverified, vc)) {
                    if (tls_verify_error.empty()) tls_verify_error = "the certificate is not for " + host;
                    return false;
                }
                return true;
            });
        }
        // SNI for servers hosting several names (not for a numeric address).
        asio::error_code not_ip;
        asio::ip::make_address(host, not_ip);
        if (not_ip) SSL_set_tlsext_host_name(tls->native_handle(), host.c_str());
        return true;
    }

    // After the handshake: the pinned fingerprint, when there is one.
    bool check_pin() {
        if (pin.empty()) return true;
        X509* cert = SSL_get1_peer_certificate(tls->native_handle());
        if (!cert) {
            fail(FailReason::TlsUntrusted, "the server sent no certificate");
            return false;
        }
        unsigned char md[EVP_MAX_MD_SIZE];
        unsigned int len = 0;
        const int ok = X509_digest(cert, EVP_sha256(), md, &len);
        X509_free(cert);
        if (!ok) {
            fail(FailReason::TlsUntrusted, "cannot compute the server certificate's fingerprint");
            return false;
        }
        const std::string got = crypto::to_hex({md, len});
        if (got != pin) {
            fail(FailReason::TlsUntrusted, "server certificate fingerprint " + got + " does not match the pinned " + pin);
            return false;
        }
        return true;
    }
    // ---------------------------------------------------------------- UDP --
    // Once welcomed: a local port, the server's (or the relay's) address.
    bool open_udp() {
        udp_sock.open(udp::v4());
        udp_sock.bind(udp::endpoint(udp::v4(), 0));
        udp_sock.non_blocking(true);
        asio::error_code ig;
        udp_sock.set_option(asio::socket_base::receive_buffer_size(4 << 20), ig);
        int on = 1;
        ::setsockopt(udp_sock.native_handle(), SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
        udp::resolver r(io);
        asio::error_code ec;
        const std::string h = cfg.udp_via_host.empty() ? host : cfg.udp_via_host;
        const uint16_t p = cfg.udp_via_host.empty() ? session.udp_port() : cfg.udp_via_port;
        auto res = r.resolve(udp::v4(), h, std::to_string(p), ec);
        if (ec || res.empty()) {
            fail(FailReason::Unreachable, "cannot resolve " + h + ": " + ec.message());
            return false;
        }
        server_udp = *res.begin();
        return true;
    }
    // DatagramSource: what the session's update reads.
    bool next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) override {
        udp::endpoint from;
        const ssize_t got = receive_stamped(udp_sock, buf, sizeof buf, from, arrival);
        if (got < 0) return false;
        bytes = {buf, size_t(got)};
        from_server = from == server_udp;
        return true;
    }

    void update(double now) {
        session.clear_events();
        if (session.running()) {
            io.poll();
            io.restart();
        }
        if (!session.welcomed() || udp_sock.is_open() || open_udp()) {
            session.update(now, this);
            flush();
        }
        if (session.phase() == SessionPhase::Streaming) tried = 0;
        fail_over(now);
    }

    // ------------------------------------------------------------ connect --
    // Starts the channel to servers[current] (session started or restarted).
    void open_channel() {
        tcp::resolver r(io);
        asio::error_code ec;
        auto res = r.resolve(host, std::to_string(port), ec);
        if (ec) return fail(FailReason::Unreachable, "cannot resolve " + host + ": " + ec.message());
        if (cfg.tls && !setup_tls()) return;  // Failed: see error()
        asio::async_connect(tcp_sock, res, [this](asio::error_code e, const tcp::endpoint&) {
            if (!session.running()) return;
            if (e) return fail(FailReason::Unreachable, "cannot connect to " + host + ":" + std::to_string(port) + ": " + e.message());
            asio::error_code ig;
            tcp_sock.set_option(tcp::no_delay(true), ig);
            if (!tls) return channel_ready();
            session.on_transport_connected();
            tls->async_handshake(asio::ssl::stream_base::client, [this](asio::error_code he) {
                if (!session.running()) return;
                if (he) {
                    if (!tls_verify_error.empty()) return fail(FailReason::TlsUntrusted, "server certificate not trusted: " + tls_verify_error);
                    return fail(FailReason::TlsHandshake,
                                "TLS handshake with " + host + ":" + std::to_string(port) + " failed: " + he.message());
                }
                if (check_pin()) channel_ready();
            });
        });
    }

    // The server was lost and another of the list may carry on: the old
    // sockets closed (their handlers run now, on a Failed session: no-ops),
    // the session restarted toward the next server.
    void fail_over(double now) {
        if (servers.size() < 2 || !session.can_fail_over() || ++tried >= servers.size()) return;
        asio::error_code ig;
        tcp_sock.close(ig);
        udp_sock.close(ig);
        io.poll();
        io.restart();
        tls.reset();
        ssl_ctx.reset();
        tls_verify_error.clear();
        pin.clear();
        reading = writing = false;
        tx_inflight.clear();
        out.control.clear();
        out.clear_datagrams();
        current = (current + 1) % servers.size();
        host = servers[current].host;
        port = servers[current].port;
        session.restart(now, host + ":" + std::to_string(port));
        open_channel();
        flush();
    }
};

std::vector<ServerAddress> parse_server_list(const std::string& list) {
    std::vector<ServerAddress> out;
    size_t at = 0;
    for (;;) {
        const size_t comma = list.find(',', at);
        const std::string item = list.substr(at, comma == std::string::npos ? std::string::npos : comma - at);
        const size_t colon = item.rfind(':');
        std::string host = colon == std::string::npos ? std::string() : item.substr(0, colon);
        if (host.size() > 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
        const std::string digits = colon == std::string::npos ? std::string() : item.substr(colon + 1);
        const bool numeric = !digits.empty() && digits.size() <= 5 && digits.find_first_not_of("0123456789") == std::string::npos;
        const long p = numeric ? std::stol(digits) : 0;
        if (host.empty() || p < 1 || p > 65535) throw Error("server list: '" + item + "' is not HOST:PORT with a port in 1..65535");
        out.push_back({host, uint16_t(p)});
        if (comma == std::string::npos) return out;
        at = comma + 1;
    }
}

Client::Client(ClientConfig config) : impl_(std::make_unique<Impl>(config)) {}
Client::~Client() {
    if (impl_ && impl_->session.running()) close();
}

void Client::connect(const std::string& host, uint16_t port) {
    const ServerAddress one{host, port};
    connect(std::span<const ServerAddress>(&one, 1));
}

void Client::connect(std::span<const ServerAddress> servers) {
    Impl& m = *impl_;
    if (m.session.phase() != SessionPhase::Idle) throw Error("connect: the client is already connected");
    if (servers.empty()) throw Error("connect: no server given");
    m.servers.assign(servers.begin(), servers.end());
    m.host = servers[0].host;
    m.port = servers[0].port;
    const double started = now_seconds();
    {   // the first server's name must resolve (a typo is the caller's error, not a failover)
        tcp::resolver r(m.io);
        asio::error_code ec;
        r.resolve(m.host, std::to_string(m.port), ec);
        if (ec) throw Error("cannot resolve " + m.host + ": " + ec.message());
    }
    m.session.start(started, m.host + ":" + std::to_string(m.port));
    m.open_channel();
}

void Client::update(double now) { impl_->update(now); }

void Client::close(const std::string& reason) {
    Impl& m = *impl_;
    if (!m.session.running()) return;
    const bool idle = !m.writing && m.out.control.empty();
    m.session.close(reason);  // the Goodbye, when the channel is up
    if (!m.out.control.empty()) {
        // Best effort, without waiting: Goodbye is small and the socket's
        // buffer takes it unless the server stopped reading.
        asio::error_code ec;
        m.tcp_sock.non_blocking(true, ec);
        if (idle) {
            if (m.tls) m.tls->write_some(asio::buffer(m.out.control), ec);  // one TLS record; would_block: dropped
            else m.tcp_sock.write_some(asio::buffer(m.out.control), ec);
        }
        m.out.control.clear();
    }
    m.flush();  // closes the sockets
}

ClientState Client::state() const { return impl_->session.state(); }
const std::string& Client::error() const { return impl_->session.error(); }
FailReason Client::fail_reason() const { return impl_->session.fail_reason(); }
std::span<const ClientEvent> Client::events() const { return impl_->session.events(); }
std::span<const RemoteCharacter> Client::characters() const { return impl_->session.characters(); }
const RemoteCharacter* Client::character(int instance) const { return impl_->session.character(instance); }
const std::vector<std::shared_ptr<ClientAsset>>& Client::assets() const { return impl_->session.assets(); }
const std::vector<std::string>& Client::asset_names() const { return impl_->session.asset_names(); }
double Client::tick_rate() const { return impl_->session.tick_rate(); }
ClientStats Client::stats() const { return impl_->session.stats(now_seconds()); }
void Client::set_view(const ViewSpec& view) { impl_->session.set_view(view); }
void Client::set_max_kbps(double kbps) { impl_->session.set_max_kbps(kbps); }

int Client::spawn(const SpawnSpec& spec) {
    const int handle = impl_->session.spawn(spec);
    impl_->flush();
    return handle;
}

bool Client::publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport,
                     std::span<const float> morph_weights) {
    const bool sent = impl_->session.publish(handle, root, skinning, teleport, morph_weights);
    impl_->flush();
    return sent;
}

void Client::despawn(int handle) {
    impl_->session.despawn(handle);
    impl_->flush();
}

int Client::instance_of(int handle) const { return impl_->session.instance_of(handle); }

}  // namespace progskin::net
