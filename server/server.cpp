// server.cpp — see server.h. The shell around ServerCore (server_core.h):
// the io_context, the acceptor, each connection's TCP stream (TLS over it
// when ServerConfig::tls_cert_file is set, from the first byte, the handshake
// within hello_timeout), the UDP socket and the tick timer. The protocol —
// the session state machine (client_stream.h), datagram routing, the tick —
// is the core's: this file moves bytes between sockets and cores. Nothing
// blocks: every TCP write is asynchronous (the core caps each session's
// queued output), a failed accept backs off 100 ms, and an exception in one
// session's handler closes that session only.
#include "server.h"

#include <pthread.h>
#include <sys/socket.h>

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "errors.h"
#include "server_core.h"
#include "world_bus.h"
#include "web_endpoint.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;

namespace {

// The local port of a bound socket (0 when it cannot be read).
uint16_t port_of(int fd) {
    sockaddr_storage ss{};
    socklen_t n = sizeof ss;
    if (::getsockname(fd, reinterpret_cast<sockaddr*>(&ss), &n) != 0) return 0;
    if (ss.ss_family == AF_INET) return ntohs(reinterpret_cast<const sockaddr_in*>(&ss)->sin_port);
    if (ss.ss_family == AF_INET6) return ntohs(reinterpret_cast<const sockaddr_in6*>(&ss)->sin6_port);
    return 0;
}

PeerAddress peer_of(const asio::ip::address& a, uint16_t port) {
    PeerAddress p;
    p.port = port;
    if (a.is_v4()) {
        const auto b = a.to_v4().to_bytes();
        std::copy(b.begin(), b.end(), p.ip.begin());
    } else {
        const asio::ip::address_v6 v6 = a.to_v6();
        const auto b = v6.to_bytes();
        std::copy(b.begin(), b.end(), p.ip.begin());
        p.scope = uint32_t(v6.scope_id());
        p.v6 = true;
    }
    return p;
}

udp::endpoint endpoint_of(const PeerAddress& p) {
    if (!p.v6) {
        asio::ip::address_v4::bytes_type b;
        std::copy_n(p.ip.begin(), b.size(), b.begin());
        return {asio::ip::address_v4(b), p.port};
    }
    asio::ip::address_v6::bytes_type b;
    std::copy_n(p.ip.begin(), b.size(), b.begin());
    return {asio::ip::address_v6(b, p.scope), p.port};
}

// The UDP socket as the cores' datagram sink (a failed send is a lost
// datagram). Thread-safe: sendto(2) on the socket's descriptor, which the
// tick's workers call at once (asio's socket objects are not safe to share
// between threads; the descriptor is, and it stays open while a tick runs:
// it is closed on the tick thread, between ticks).
// Datagrams to a WebSocket session's synthetic address go to its connection
// (WebEndpoint::send_datagram) instead.
class UdpSink final : public DatagramSink {
public:
    void set_descriptor(int fd) { fd_ = fd; }
    void set_web(WebEndpoint* web) { web_ = web; }
    void send(std::span<const uint8_t> d, const PeerAddress& to) override {
        if (web_ && WebEndpoint::is_web(to)) return web_->send_datagram(d, to);
        const udp::endpoint ep = endpoint_of(to);
        (void)::sendto(fd_, d.data(), d.size(), MSG_DONTWAIT | MSG_NOSIGNAL, ep.data(), socklen_t(ep.size()));
    }

private:
    int fd_ = -1;
    WebEndpoint* web_ = nullptr;
};

// The thread's name as top -H and debuggers show it (at most 15 characters).
void name_thread(const char* name) {
#if defined(__GLIBC__)
    ::pthread_setname_np(::pthread_self(), name);
#else
    (void)name;
#endif
}

// Runs `io` until it is stopped; a handler's exception stops io.run() only:
// logged, and the loop goes on serving.
void run_io(asio::io_context& io) {
    for (;;) {
        try {
            io.run();
            return;
        } catch (const std::exception& e) {
            std::fprintf(stderr, "progskin-server: error: %s\n", e.what());
        }
    }
}

// TLS 1.2+ (OpenSSL through asio::ssl) with the configured pair; null without TLS.
std::unique_ptr<asio::ssl::context> make_tls_context(const ServerConfig& cfg) {
    if (cfg.tls_cert_file.empty()) return nullptr;
    auto ctx = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_server);
    ctx->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 | asio::ssl::context::no_sslv3 |
                     asio::ssl::context::no_tlsv1 | asio::ssl::context::no_tlsv1_1 | asio::ssl::context::single_dh_use);
    asio::error_code ec;
    ctx->use_certificate_chain_file(cfg.tls_cert_file, ec);
    if (ec) throw Error("server: TLS certificate " + cfg.tls_cert_file + ": " + ec.message());
    ctx->use_private_key_file(cfg.tls_key_file, asio::ssl::context::pem, ec);
    if (ec) throw Error("server: TLS private key " + cfg.tls_key_file + ": " + ec.message());
    // Each connection's read and write buffers (about 34 KB) are freed while
    // it has nothing buffered: thousands of idle handshakes do not hold them.
    SSL_CTX_set_mode(ctx->native_handle(), SSL_MODE_RELEASE_BUFFERS);
    return ctx;
}

}  // namespace

struct Server::Impl {
    // One TCP connection and the session it carries.
    struct Connection {
        std::shared_ptr<ClientStream> stream;
        tcp::socket sock;
        std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;  // over `sock` when TLS is on
        uint8_t len_buf[4];
        std::vector<uint8_t> body;
        bool writing = false;  // the stream's oldest output is being written
        bool closed = false;   // the socket is closed (the session Closed, or stop())
        explicit Connection(tcp::socket s) : sock(std::move(s)) {}
    };

    ServerCore core;
    std::unique_ptr<WorldBus> bus;  // ServerConfig::nats_url: this node's world (docs/deployment.md)
    // ServerCore::tick's `encoded`: the bus publishes the node's cells (empty without a bus).
    std::function<void(const EncodedFrame&)> on_encoded;
    const int threads;                               // tick_threads(config)
    asio::io_context io;                             // control (everything when threads == 1)
    std::unique_ptr<asio::io_context> own_tick_io;   // threads > 1: the UDP socket and the tick
    asio::io_context& tick_io;                       // own_tick_io, else io
    std::unique_ptr<TickPool> pool;                  // threads > 1
    tcp::acceptor acceptor{io};
    udp::socket udp_sock{tick_io};
    UdpSink sink;
    asio::steady_timer timer{tick_io};
    asio::steady_timer accept_timer{io};
    asio::steady_timer stop_timer{io};               // finish_stop
    std::unique_ptr<WebEndpoint> web;                // ServerConfig::web_port >= 0 (control thread)
    bool stopping = false;                           // stop() ran (control thread)
    uint16_t tcp_port = 0, udp_port = 0;             // as bound (read from any thread)
    std::atomic<bool> pump_posted{false};            // a pump_all waits in io
    std::unique_ptr<asio::ssl::context> tls_ctx;  // set when ServerConfig::tls_cert_file is
    std::chrono::steady_clock::time_point next_tick;
    std::map<uint64_t, std::shared_ptr<Connection>> conns;
    alignas(16) std::array<uint8_t, 2048> udp_buf;   // the pending async receive's
    alignas(16) std::array<uint8_t, 2048> drain_buf;  // drain_udp's
    udp::endpoint udp_from, drain_from;
    size_t closed_since_trim = 0;
    double trimmed_at = 0;

    Impl(ServerConfig c, std::vector<std::shared_ptr<ServerAsset>> a, std::vector<InstanceSpec> inst, BoundPorts ports)
        : core(std::move(c), std::move(a), std::move(inst)),
          threads(tick_threads(core.config())),
          own_tick_io(threads > 1 ? std::make_unique<asio::io_context>() : nullptr),
          tick_io(own_tick_io ? *own_tick_io : io),
          pool(threads > 1 ? std::make_unique<TickPool>(threads) : nullptr),
          tls_ctx(make_tls_context(core.config())) {
        listen(std::move(ports));
        tcp_port = acceptor.local_endpoint().port();
        udp_port = udp_sock.local_endpoint().port();
        sink.set_descriptor(udp_sock.native_handle());
        core.set_udp_port(udp_port);
        core.set_pool(pool.get());
        if (const ServerConfig& cfg = core.config(); !cfg.nats_url.empty()) {
            bus = std::make_unique<WorldBus>(WorldConfig{cfg.nats_url, cfg.nats_ca_file, cfg.nats_cert_file, cfg.nats_key_file,
                                                         cfg.world_node, cfg.world_name, cfg.world_cell, cfg.world_queue},
                                             core);
            on_encoded = [this](const EncodedFrame& f) { bus->publish(f); };
        }
        if (core.config().web_port >= 0) {
            web = std::make_unique<WebEndpoint>(io, core, sink, core.config().bind_address, uint16_t(core.config().web_port),
                                                core.config().web_root, tls_ctx.get());
            sink.set_web(web.get());
        }
    }

    // The core's lock (server_core.h): held for every call into the core.
    std::unique_lock<std::mutex> hold() { return std::unique_lock(core.mutex()); }

    // The sockets: those bound beforehand (bind_ports), else bound now; the
    // UDP socket belongs to tick_io.
    void listen(BoundPorts ports) {
        if (ports.tcp_fd < 0 || ports.udp_fd < 0) ports = bind_ports(core.config());
        const bool v6 = asio::ip::make_address(core.config().bind_address).is_v6();
        acceptor.assign(v6 ? tcp::v6() : tcp::v4(), std::exchange(ports.tcp_fd, -1));
        udp_sock.assign(udp::v4(), std::exchange(ports.udp_fd, -1));
        udp_sock.non_blocking(true);
        udp_sock.set_option(asio::socket_base::send_buffer_size(4 << 20));
        udp_sock.set_option(asio::socket_base::receive_buffer_size(4 << 20));
    }

    void count_error(uint64_t ServerStats::*counter) {
        core.count([counter](ServerStats& st) { ++(st.*counter); });
    }

    // ---------------------------------------------------------------- TCP --
    void accept() {
        acceptor.async_accept([this](asio::error_code ec, tcp::socket s) {
            if (ec == asio::error::operation_aborted) return;
            if (ec) {
                // Out of descriptors (EMFILE, ENFILE) or memory: the pending
                // connection stays queued and accept() would fail again at
                // once; wait before trying again instead of spinning.
                count_error(&ServerStats::accept_errors);
                if (ec == asio::error::connection_aborted) {
                    accept();
                    return;
                }
                core.log("accept: " + ec.message() + "; retrying in 100 ms");
                accept_timer.expires_after(std::chrono::milliseconds(100));
                accept_timer.async_wait([this](asio::error_code e) {
                    if (!e) accept();
                });
                return;
            }
            try {
                admit(std::move(s));
            } catch (const std::exception& e) {
                count_error(&ServerStats::handler_errors);
                core.log(std::string("accept: ") + e.what());
            }
            accept();
        });
    }

    void admit(tcp::socket s) {
        asio::error_code ig;
        s.set_option(tcp::no_delay(true), ig);
        const asio::ip::address remote = s.remote_endpoint(ig).address();
        if (ig) return;  // already gone
        auto c = std::make_shared<Connection>(std::move(s));
        auto lock = hold();
        c->stream = core.open(peer_of(remote, 0), now_seconds());
        conns[c->stream->id()] = c;
        pump(c);  // refused (too many from this address): its Refuse, or closed
        if (c->stream->state() != SessionState::AwaitHello) return;
        if (!tls_ctx) return read_header(c);
        // The handshake runs under hello_timeout like the rest of AwaitHello.
        c->tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(c->sock, *tls_ctx);
        c->tls->async_handshake(asio::ssl::stream_base::server, [this, c](asio::error_code ec) {
            auto lock = hold();
            if (gone(*c)) return;
            if (ec) {
                count_error(&ServerStats::tls_failures);
                c->stream->close("TLS handshake: " + ec.message());
                return pump(c);
            }
            read_header(c);
        });
    }

    // The connection's byte stream: TLS over the socket when configured, else the socket.
    template <class Buffers, class Handler>
    void read_exactly(const std::shared_ptr<Connection>& c, const Buffers& b, Handler&& h) {
        if (c->tls) asio::async_read(*c->tls, b, std::forward<Handler>(h));
        else asio::async_read(c->sock, b, std::forward<Handler>(h));
    }
    template <class Buffers, class Handler>
    void write_all(const std::shared_ptr<Connection>& c, const Buffers& b, Handler&& h) {
        if (c->tls) asio::async_write(*c->tls, b, std::forward<Handler>(h));
        else asio::async_write(c->sock, b, std::forward<Handler>(h));
    }

    static bool gone(const Connection& c) { return c.closed || c.stream->state() == SessionState::Closed; }

    // After the core acted on a session: a Closed session's connection is
    // closed (and forgotten once its pending handlers ran), else its queued
    // output is written, one message at a time. Control thread, core held.
    void pump(const std::shared_ptr<Connection>& c) {
        if (c->closed) return;
        if (c->stream->state() == SessionState::Closed) {
            c->closed = true;
            ++closed_since_trim;
            asio::error_code ig;
            c->sock.shutdown(tcp::socket::shutdown_both, ig);
            c->sock.close(ig);
            asio::post(io, [this, id = c->stream->id()] {
                conns.erase(id);
                auto lock = hold();
                core.erase(id, now_seconds());
            });
            return;
        }
        if (!c->writing && !c->stream->output().empty()) write_next(c);
    }

    void write_next(const std::shared_ptr<Connection>& c) {
        c->writing = true;
        // The message stays put while it is written: the core only appends to
        // output() (the tick thread too) and only on_written removes it.
        write_all(c, asio::buffer(c->stream->output().front()), [this, c](asio::error_code ec, size_t) {
            auto lock = hold();
            c->writing = false;
            if (gone(*c)) return;
            if (ec) c->stream->close("write: " + ec.message());
            else c->stream->on_written();
            pump(c);
        });
    }

    void read_header(const std::shared_ptr<Connection>& c) {
        read_exactly(c, asio::buffer(c->len_buf, 4), [this, c](asio::error_code ec, size_t) {
            auto lock = hold();
            if (c->stream->state() == SessionState::Closing) return;  // nothing more is read once the last message is queued
            if (ec || gone(*c)) {
                c->stream->close(ec ? ec.message() : "closed");
                return pump(c);
            }
            uint32_t n = 0;
            read_length({c->len_buf, 4}, n);
            if (!c->stream->accept_length(n)) return pump(c);
            c->body.resize(n);
            read_exactly(c, asio::buffer(c->body), [this, c](asio::error_code ec2, size_t) {
                auto lock2 = hold();
                read_body(c, ec2);
            });
        });
    }

    void read_body(const std::shared_ptr<Connection>& c, asio::error_code ec) {  // core held
        if (c->stream->state() == SessionState::Closing) return;
        if (ec || gone(*c)) {
            c->stream->close(ec ? ec.message() : "closed");
            return pump(c);
        }
        bool more = false;
        try {
            more = c->stream->on_control(c->body, now_seconds());
        } catch (const std::exception& e) {  // one session's failure never reaches io.run()
            count_error(&ServerStats::handler_errors);
            c->stream->close(std::string("error: ") + e.what());
        }
        pump(c);
        if (more && c->stream->is_open()) read_header(c);
    }

    // ---------------------------------------------------------------- UDP --
    void receive() {
        udp_sock.async_receive_from(asio::buffer(udp_buf), udp_from, [this](asio::error_code ec, size_t n) {
            if (ec == asio::error::operation_aborted) return;
            if (!ec) on_datagram({udp_buf.data(), n}, udp_from);
            drain_udp();  // whatever else waits, in the same turn
            receive();
        });
    }

    void on_datagram(std::span<const uint8_t> bytes, const udp::endpoint& from) {
        auto lock = hold();
        try {
            core.on_datagram(bytes, peer_of(from.address(), from.port()), now_seconds(), sink);
        } catch (const std::exception& e) {
            count_error(&ServerStats::handler_errors);
            core.log(std::string("datagram: ") + e.what());
        }
    }

    // Reads the datagrams waiting in the socket (at most kDrainMax, a few
    // tens of ms of work); when the queue is found empty every Ack sent until
    // now has been accounted: the core's liveness clock (input_drained).
    void drain_udp() {
        constexpr int kDrainMax = 16384;
        for (int i = 0; i < kDrainMax; ++i) {
            asio::error_code ec;
            const size_t n = udp_sock.receive_from(asio::buffer(drain_buf), drain_from, 0, ec);
            if (ec == asio::error::would_block || ec == asio::error::try_again) {
                auto lock = hold();
                core.input_drained(now_seconds());
                return;
            }
            if (ec == asio::error::bad_descriptor || ec == asio::error::operation_aborted) return;
            if (!ec) on_datagram({drain_buf.data(), n}, drain_from);  // else an ICMP error for an earlier send: go on
        }
    }

    // glibc keeps freed memory (thousands of closed handshakes) in its arenas;
    // give it back once many connections closed (at most every 5 s).
    void trim_memory() {
#if defined(__GLIBC__)
        const double now = now_seconds();
        if (closed_since_trim < 256 || now - trimmed_at < 5.0) return;
        closed_since_trim = 0;
        trimmed_at = now;
        ::malloc_trim(0);
#endif
    }

    // ---------------------------------------------------------------- stop --
    // After stop() queued the Goodbyes: every 10 ms, once no connection is
    // still writing (or at `deadline`), closes what is left and stops io.
    void finish_stop(std::chrono::steady_clock::time_point deadline) {
        bool writing = false;
        {
            auto lock = hold();
            for (auto& [id, c] : conns) writing = writing || (!c->closed && (c->writing || !c->stream->output().empty()));
            writing = writing || (web && web->writing());
        }
        if (writing && std::chrono::steady_clock::now() < deadline) {
            stop_timer.expires_after(std::chrono::milliseconds(10));
            stop_timer.async_wait([this, deadline](asio::error_code) { finish_stop(deadline); });
            return;
        }
        asio::error_code ig;
        for (auto& [id, c] : conns) {
            c->closed = true;
            c->sock.close(ig);
        }
        if (web) web->close_all();
        io.stop();
    }

    // --------------------------------------------------------------- tick --
    // Tick thread.
    void schedule_tick() {
        next_tick += std::chrono::microseconds(int64_t(1e6 / core.config().tick_rate));
        auto now = std::chrono::steady_clock::now();
        if (next_tick < now - std::chrono::milliseconds(200)) next_tick = now;  // fell far behind: skip
        timer.expires_at(next_tick);
        timer.async_wait([this](asio::error_code ec) {
            if (ec) return;
            drain_udp();  // Acks accounted before the tick's work
            if (bus) bus->before_tick(now_seconds());  // other nodes' poses go out with this tick
            {
                auto lock = hold();
                core.tick(now_seconds(), sink, on_encoded);
            }
            // Goodbyes, instance announcements, evictions, closes: at once with
            // one thread, else on the control thread.
            if (!own_tick_io) pump_all();
            else if (!pump_posted.exchange(true)) asio::post(io, [this] {
                pump_posted = false;
                pump_all();
            });
            schedule_tick();
        });
    }

    // Control thread: every connection's output and closes, after a tick.
    void pump_all() {
        {
            auto lock = hold();
            for (auto& [id, c] : conns) pump(c);
            if (web) web->pump_all();
        }
        trim_memory();
    }

    // --------------------------------------------------------------- stop --
    void stop_ticking() {  // tick thread
        asio::error_code ig;
        udp_sock.close(ig);
        timer.cancel();
        if (own_tick_io) own_tick_io->stop();
    }
    // Control thread: every session is told (Goodbye "shutdown: ..."), so
    // that a client tells a clean stop from a crash; then finish_stop.
    void begin_stop() {
        if (stopping) return;
        stopping = true;
        asio::error_code ig;
        acceptor.close(ig);
        accept_timer.cancel();
        {
            auto lock = hold();
            const double now = now_seconds();
            for (auto& [id, c] : conns) {
                c->stream->goodbye(kShutdownReason, now);
                pump(c);
            }
            if (web) web->goodbye_all(kShutdownReason, now);
        }
        finish_stop(std::chrono::steady_clock::now() + std::chrono::milliseconds(int(kShutdownLingerSeconds * 1000)));
    }
};

Server::Server(ServerConfig config, std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
               BoundPorts ports)
    : impl_(std::make_unique<Impl>(std::move(config), std::move(assets), std::move(instances), std::move(ports))) {}

BoundPorts::~BoundPorts() {
    if (tcp_fd >= 0) ::close(tcp_fd);
    if (udp_fd >= 0) ::close(udp_fd);
}
BoundPorts& BoundPorts::operator=(BoundPorts&& o) noexcept {
    if (this != &o) {
        this->~BoundPorts();
        tcp_fd = std::exchange(o.tcp_fd, -1);
        udp_fd = std::exchange(o.udp_fd, -1);
    }
    return *this;
}
uint16_t BoundPorts::tcp_port() const { return tcp_fd < 0 ? 0 : port_of(tcp_fd); }

// Binds TCP, then UDP on the same number when possible.
BoundPorts bind_ports(const ServerConfig& cfg) {
    asio::io_context io;
    tcp::acceptor acceptor(io);
    udp::socket udp_sock(io);
    asio::error_code ec;
    const auto addr = asio::ip::make_address(cfg.bind_address, ec);
    if (ec) throw Error("cannot listen on " + cfg.bind_address + ": not an IP address");
    for (int attempt = 0;; ++attempt) {
        tcp::endpoint ep(addr, cfg.port);
        acceptor = tcp::acceptor(io);
        acceptor.open(ep.protocol());
        acceptor.set_option(tcp::acceptor::reuse_address(true));
        acceptor.bind(ep, ec);
        if (ec) throw Error("cannot listen on " + cfg.bind_address + ":" + std::to_string(cfg.port) + ": " + ec.message());
        acceptor.listen(asio::socket_base::max_listen_connections);
        uint16_t want = cfg.udp_port ? cfg.udp_port : acceptor.local_endpoint().port();
        udp_sock = udp::socket(io);
        udp_sock.open(udp::v4());
        udp_sock.bind(udp::endpoint(addr, want), ec);
        if (!ec) break;
        if (cfg.udp_port) throw Error("cannot bind UDP port " + std::to_string(cfg.udp_port) + ": " + ec.message());
        if (cfg.port != 0 || attempt > 20) {
            udp_sock.bind(udp::endpoint(addr, 0), ec);  // any free port; announced in Welcome
            if (ec) throw Error("cannot bind UDP: " + ec.message());
            break;
        }
    }
    BoundPorts p;
    p.tcp_fd = acceptor.release();
    p.udp_fd = udp_sock.release();
    return p;
}

Server::~Server() = default;

int tick_threads(const ServerConfig& cfg) {
    if (cfg.threads > 0) return cfg.threads;
    return std::clamp(int(std::thread::hardware_concurrency()), 1, TickPool::kMaxThreads);
}

uint16_t Server::tcp_port() const { return impl_->tcp_port; }
uint16_t Server::udp_port() const { return impl_->udp_port; }
uint16_t Server::web_port() const { return impl_->web ? impl_->web->port() : 0; }

void Server::run() {
    Impl& m = *impl_;
    m.accept();
    m.receive();
    if (m.web) m.web->start();
    m.next_tick = std::chrono::steady_clock::now();
    m.schedule_tick();  // the tick thread's first work, armed before it starts
    std::thread ticker;
    if (m.own_tick_io)
        ticker = std::thread([&m] {
            name_thread("progskin-tick");
            run_io(*m.own_tick_io);
        });
    run_io(m.io);
    if (ticker.joinable()) {
        asio::post(*m.own_tick_io, [&m] { m.stop_ticking(); });  // already, unless io ran out of work
        ticker.join();
    }
}

// The tick's part first: with one io_context (threads == 1) it runs before
// stop_control stops it.
void Server::stop() {
    asio::post(impl_->tick_io, [this] { impl_->stop_ticking(); });
    asio::post(impl_->io, [this] { impl_->begin_stop(); });
}

bool Server::push_pose(int instance, std::span<const Mat34> m) { return impl_->core.encoder().push_pose(instance, m); }
bool Server::set_root(int instance, const RootPose& root, bool teleport) {
    return impl_->core.encoder().set_root(instance, root, teleport);
}
int Server::add_instance(const InstanceSpec& spec) { return impl_->core.add_instance(spec); }
void Server::remove_instance(int instance) { impl_->core.remove_instance(instance); }
ServerStats Server::stats() const {
    ServerStats st = impl_->core.stats();
    if (impl_->bus) {
        const WorldStats w = impl_->bus->stats();
        st.world_messages_out = w.messages_out;
        st.world_bytes_out = w.bytes_out;
        st.world_messages_in = w.messages_in;
        st.world_bytes_in = w.bytes_in;
        st.world_dropped = w.dropped;
        st.world_superseded = w.superseded;
        st.world_malformed = w.malformed;
        st.world_refused = w.refused;
        st.world_publish_failed = w.publish_failed;
        st.world_foreign = w.foreign;
        st.world_cells = w.cells;
        st.world_cells_shed = w.cells_shed;
        st.world_connected = w.connected;
    }
    return st;
}

}  // namespace progskin::net
