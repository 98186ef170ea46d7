// link_emulator.cpp — see link_emulator.h.
#include "link_emulator.h"

#include <poll.h>

#include <asio.hpp>
#include <chrono>
#include <deque>
#include <map>
#include <mutex>
#include <queue>
#include <random>
#include <vector>

#include "errors.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;
using Clock = std::chrono::steady_clock;

struct LinkEmulator::Impl {
    LinkConfig cfg;
    asio::io_context io;
    udp::socket front{io};
    udp::endpoint target;
    struct Client {
        udp::endpoint addr;
        std::unique_ptr<udp::socket> up;
    };
    std::vector<Client> clients;
    struct Packet {
        Clock::time_point at;
        uint64_t order;
        int client;       // index into clients
        bool downstream;  // server -> client
        std::vector<uint8_t> bytes;
        bool operator>(const Packet& o) const { return at > o.at || (at == o.at && order > o.order); }
    };
    std::priority_queue<Packet, std::vector<Packet>, std::greater<Packet>> queue;
    Clock::time_point link_free[2];
    std::mt19937_64 rng;
    uint64_t order = 0;
    std::thread thread;
    std::atomic<bool> running{false};
    mutable std::mutex stats_mutex;
    LinkStats st;

    // TCP relay (relay_tcp): per accepted connection its upstream one and per
    // direction ([0] client -> server, [1] server -> client) the chunks in
    // flight, each released at `at` (non-decreasing: a stream keeps its order).
    std::unique_ptr<tcp::acceptor> acceptor;
    tcp::endpoint tcp_target;
    struct Chunk {
        Clock::time_point at;
        std::vector<uint8_t> bytes;
        size_t sent = 0;
    };
    struct Conn {
        std::unique_ptr<tcp::socket> front, up;
        std::deque<Chunk> q[2];
        size_t queued[2] = {0, 0};
        Clock::time_point last[2];
        bool eof[2] = {false, false}, shut[2] = {false, false}, dead = false;
        bool blocked[2] = {false, false};  // a due chunk waits for its destination to take it (POLLOUT)
    };
    std::vector<Conn> conns;
    static constexpr size_t kTcpChunk = 4096, kTcpMaxQueued = size_t(1) << 20, kTcpMaxConns = 1024;

    double uniform() { return std::uniform_real_distribution<double>(0.0, 1.0)(rng); }

    static Clock::duration millis(double ms) {
        return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::milli>(ms));
    }

    // Whether direction `down` of the rate cap has more queued than queue_ms
    // (a datagram is dropped, TCP stops reading).
    bool backlogged(bool down, Clock::time_point now) const {
        if (!(cfg.rate_kbps > 0) || !(down || cfg.both_ways)) return false;
        return link_free[down ? 1 : 0] - now > millis(cfg.queue_ms);
    }

    // The rate cap: when wire_bytes entering direction `down` now have left it
    // (now when that direction is not capped); datagrams and TCP share it.
    Clock::time_point serialise(bool down, size_t wire_bytes, Clock::time_point now) {
        if (!(cfg.rate_kbps > 0) || !(down || cfg.both_ways)) return now;
        auto& free = link_free[down ? 1 : 0];
        if (free < now) free = now;
        free += millis(wire_bytes * 8.0 / cfg.rate_kbps);  // kbit/s = bit/ms
        return free;
    }

    // Whether the relay reads direction dir of c now.
    bool reads(const Conn& c, int dir, Clock::time_point now) const {
        return !c.eof[dir] && !c.dead && c.queued[dir] < kTcpMaxQueued && !backlogged(dir == 1, now);
    }

    void tcp_enqueue(Conn& c, int dir, const uint8_t* data, size_t n) {
        const bool down = dir == 1, impaired = down || cfg.both_ways;
        std::lock_guard lock(stats_mutex);
        auto at = serialise(down, n + 40, Clock::now());
        at += millis(cfg.delay_ms + (impaired ? cfg.jitter_ms * uniform() : 0.0));
        if (at < c.last[dir]) at = c.last[dir];
        c.last[dir] = at;
        c.q[dir].push_back({at, std::vector<uint8_t>(data, data + n), 0});
        c.queued[dir] += n;
        (down ? st.tcp_bytes_down : st.tcp_bytes_up) += n;
    }

    void tcp_accept() {
        for (;;) {
            asio::error_code ec;
            auto s = std::make_unique<tcp::socket>(io);
            acceptor->accept(*s, ec);
            if (ec) return;  // would block (or a transient error)
            if (conns.size() >= kTcpMaxConns) continue;
            Conn c;
            c.front = std::move(s);
            c.up = std::make_unique<tcp::socket>(io);
            c.up->connect(tcp_target, ec);  // the client sees the connection closed if the server is not there
            if (ec) continue;
            c.front->non_blocking(true);
            c.up->non_blocking(true);
            c.front->set_option(tcp::no_delay(true), ec);
            c.up->set_option(tcp::no_delay(true), ec);
            c.last[0] = c.last[1] = Clock::now();
            conns.push_back(std::move(c));
            std::lock_guard lock(stats_mutex);
            ++st.tcp_connections;
        }
    }

    // Reads what is available (unless the link or the connection is backlogged),
    // writes what is due, half-closes a direction once its EOF is delivered.
    void tcp_pump(Conn& c, std::vector<uint8_t>& buf) {
        const auto now = Clock::now();
        for (int dir = 0; dir < 2; ++dir) {
            tcp::socket& from = dir == 0 ? *c.front : *c.up;
            tcp::socket& to = dir == 0 ? *c.up : *c.front;
            while (reads(c, dir, now)) {
                asio::error_code ec;
                const size_t n = from.read_some(asio::buffer(buf.data(), kTcpChunk), ec);
                if (ec == asio::error::would_block || ec == asio::error::try_again) break;
                if (ec == asio::error::eof) c.eof[dir] = true;
                else if (ec) c.dead = true;
                else tcp_enqueue(c, dir, buf.data(), n);
            }
            c.blocked[dir] = false;
            while (!c.dead && !c.q[dir].empty() && c.q[dir].front().at <= now) {
                Chunk& ch = c.q[dir].front();
                asio::error_code ec;
                const size_t n = to.write_some(asio::buffer(ch.bytes.data() + ch.sent, ch.bytes.size() - ch.sent), ec);
                if (ec == asio::error::would_block || ec == asio::error::try_again) {
                    c.blocked[dir] = true;
                    break;
                }
                if (ec) {
                    c.dead = true;
                    break;
                }
                ch.sent += n;
                c.queued[dir] -= n;
                if (ch.sent == ch.bytes.size()) c.q[dir].pop_front();
            }
            if (c.eof[dir] && c.q[dir].empty() && !c.shut[dir]) {
                asio::error_code ec;
                to.shutdown(tcp::socket::shutdown_send, ec);
                c.shut[dir] = true;
            }
        }
        if (c.shut[0] && c.shut[1]) c.dead = true;
    }

    void enqueue(int client, bool down, std::vector<uint8_t> bytes) {
        const bool impaired = down || cfg.both_ways;
        auto now = Clock::now();
        std::lock_guard lock(stats_mutex);
        if (impaired && uniform() < cfg.loss) {
            ++st.dropped;
            return;
        }
        if (backlogged(down, now)) {
            ++st.queue_drops;
            return;
        }
        auto at = serialise(down, bytes.size() + 28, now);
        double ms = cfg.delay_ms;
        if (impaired) {
            ms += cfg.jitter_ms * uniform();
            if (uniform() < cfg.reorder) {
                ms += cfg.jitter_ms + 10.0 + 20.0 * uniform();
                ++st.reordered;
            }
        }
        at += millis(ms);
        bool dup = impaired && uniform() < cfg.duplicate;
        if (dup) {
            ++st.duplicated;
            queue.push({at + std::chrono::milliseconds(1), order++, client, down, bytes});
        }
        queue.push({at, order++, client, down, std::move(bytes)});
    }

    void loop() {
        std::vector<uint8_t> buf(65536);
        while (running) {
            std::vector<pollfd> fds;
            fds.push_back({front.native_handle(), POLLIN, 0});
            for (auto& c : clients) fds.push_back({c.up->native_handle(), POLLIN, 0});
            auto next = Clock::now() + std::chrono::milliseconds(5);
            if (!queue.empty()) next = std::min(next, queue.top().at);
            if (acceptor) {
                const auto now = Clock::now();
                fds.push_back({acceptor->native_handle(), POLLIN, 0});
                for (const Conn& c : conns)
                    for (int dir = 0; dir < 2; ++dir) {
                        // Socket `dir` (0 front, 1 up) reads direction dir and writes direction 1 - dir.
                        const short ev = short((reads(c, dir, now) ? POLLIN : 0) | (c.blocked[1 - dir] ? POLLOUT : 0));
                        fds.push_back({(dir == 0 ? c.front : c.up)->native_handle(), ev, 0});
                        if (!c.q[dir].empty() && !c.blocked[dir]) next = std::min(next, c.q[dir].front().at);
                    }
            }
            const int timeout = int(std::clamp<long long>(
                std::chrono::ceil<std::chrono::milliseconds>(next - Clock::now()).count(), 0, 5));
            ::poll(fds.data(), fds.size(), timeout);
            asio::error_code ec;
            for (;;) {  // client -> server
                udp::endpoint from;
                size_t n = front.receive_from(asio::buffer(buf), from, 0, ec);
                if (ec) break;
                int idx = -1;
                for (size_t i = 0; i < clients.size(); ++i)
                    if (clients[i].addr == from) idx = int(i);
                if (idx < 0) {
                    if (clients.size() >= 4096) continue;
                    Client c{from, std::make_unique<udp::socket>(io)};
                    c.up->open(udp::v4());
                    c.up->bind(udp::endpoint(udp::v4(), 0));
                    c.up->non_blocking(true);
                    clients.push_back(std::move(c));
                    idx = int(clients.size() - 1);
                }
                enqueue(idx, false, std::vector<uint8_t>(buf.begin(), buf.begin() + long(n)));
            }
            for (size_t i = 0; i < clients.size(); ++i) {  // server -> client
                for (;;) {
                    udp::endpoint from;
                    size_t n = clients[i].up->receive_from(asio::buffer(buf), from, 0, ec);
                    if (ec) break;
                    enqueue(int(i), true, std::vector<uint8_t>(buf.begin(), buf.begin() + long(n)));
                }
            }
            if (acceptor) {
                tcp_accept();
                for (Conn& c : conns) tcp_pump(c, buf);
                std::erase_if(conns, [](const Conn& c) { return c.dead; });
            }
            auto now = Clock::now();
            while (!queue.empty() && queue.top().at <= now) {
                const Packet& p = queue.top();
                if (p.downstream) front.send_to(asio::buffer(p.bytes), clients[p.client].addr, 0, ec);
                else clients[p.client].up->send_to(asio::buffer(p.bytes), target, 0, ec);
                {
                    std::lock_guard lock(stats_mutex);
                    ++st.forwarded;
                }
                queue.pop();
            }
        }
    }
};

LinkEmulator::LinkEmulator(const LinkConfig& cfg, const std::string& host, uint16_t port, const std::string& listen_address,
                           uint16_t listen_port)
    : impl_(std::make_unique<Impl>()) {
    impl_->cfg = cfg;
    impl_->rng.seed(cfg.seed);
    udp::resolver res(impl_->io);
    asio::error_code ec;
    auto r = res.resolve(udp::v4(), host, std::to_string(port), ec);
    if (ec || r.empty()) throw Error("netem: cannot resolve " + host + ": " + ec.message());
    impl_->target = *r.begin();
    impl_->front.open(udp::v4());
    impl_->front.bind(udp::endpoint(asio::ip::make_address(listen_address), listen_port), ec);
    if (ec) throw Error("netem: cannot bind " + listen_address + ":" + std::to_string(listen_port) + ": " + ec.message());
    impl_->front.non_blocking(true);
}

LinkEmulator::~LinkEmulator() { stop(); }

uint16_t LinkEmulator::port() const { return impl_->front.local_endpoint().port(); }

void LinkEmulator::relay_tcp(uint16_t tcp_port) {
    if (impl_->running) throw Error("netem: relay_tcp() after start()");
    impl_->tcp_target = tcp::endpoint(impl_->target.address(), tcp_port);
    const udp::endpoint local = impl_->front.local_endpoint();
    const tcp::endpoint here(local.address(), local.port());
    auto a = std::make_unique<tcp::acceptor>(impl_->io);
    asio::error_code ec;
    a->open(tcp::v4(), ec);
    if (!ec) a->set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) a->bind(here, ec);
    if (!ec) a->listen(asio::socket_base::max_listen_connections, ec);
    if (!ec) a->non_blocking(true, ec);
    if (ec)
        throw Error("netem: cannot listen on TCP " + here.address().to_string() + ":" + std::to_string(here.port()) + ": " +
                    ec.message());
    impl_->acceptor = std::move(a);
}

void LinkEmulator::start() {
    if (impl_->running.exchange(true)) return;
    impl_->thread = std::thread([this] { impl_->loop(); });
}

void LinkEmulator::stop() {
    if (!impl_->running.exchange(false)) return;
    if (impl_->thread.joinable()) impl_->thread.join();
}

LinkStats LinkEmulator::stats() const {
    std::lock_guard lock(impl_->stats_mutex);
    return impl_->st;
}

}  // namespace progskin::net
