// link_emulator.cpp — see link_emulator.h.
#include "link_emulator.h"

#include <poll.h>

#include <asio.hpp>
#include <chrono>
#include <map>
#include <mutex>
#include <queue>
#include <random>
#include <vector>

#include "error.h"

namespace progskin::net {

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

    double uniform() { return std::uniform_real_distribution<double>(0.0, 1.0)(rng); }

    void enqueue(int client, bool down, std::vector<uint8_t> bytes) {
        const bool impaired = down || cfg.both_ways;
        auto now = Clock::now();
        std::lock_guard lock(stats_mutex);
        if (impaired && uniform() < cfg.loss) {
            ++st.dropped;
            return;
        }
        auto at = now;
        if (impaired && cfg.rate_kbps > 0) {
            auto& free = link_free[down ? 1 : 0];
            if (free < now) free = now;
            if (free - now > std::chrono::duration<double, std::milli>(cfg.queue_ms)) {
                ++st.queue_drops;
                return;
            }
            free += std::chrono::duration_cast<Clock::duration>(
                std::chrono::duration<double>((bytes.size() + 28) * 8.0 / (cfg.rate_kbps * 1000.0)));
            at = free;
        }
        double ms = cfg.delay_ms;
        if (impaired) {
            ms += cfg.jitter_ms * uniform();
            if (uniform() < cfg.reorder) {
                ms += cfg.jitter_ms + 10.0 + 20.0 * uniform();
                ++st.reordered;
            }
        }
        at += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::milli>(ms));
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
            int timeout = 5;
            if (!queue.empty()) {
                auto d = std::chrono::duration_cast<std::chrono::milliseconds>(queue.top().at - Clock::now()).count();
                timeout = int(std::clamp<long long>(d, 0, 5));
            }
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
