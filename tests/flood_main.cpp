// flood_main.cpp — progskin-flood: a connection flood against a
// progskin-server on this machine while one connected client watches its
// frame stream (issue 26: "a connection flood does not stall streaming").
// New TLS connections (handshake, Hello, Welcome, close) at a fixed rate from
// the loopback addresses 127.0.0.2 onwards; the watcher (127.0.0.1) notes
// when each Frame arrives and reports the largest gap between two and the
// 100 ms windows without one. Built from the hardening tests' attacker
// (tests/net_attacker.h); a test tool, not installed (scripts/flood.sh).
#include <algorithm>
#include <atomic>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "cli_args.h"
#include "net_attacker.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

static const char* kUsage =
    "usage: progskin-flood --server 127.0.0.1:PORT [options]\n"
    "Opens new TLS connections to a progskin-server on this machine at a fixed rate\n"
    "(handshake, Hello, Welcome, close) from 127.0.0.2 onwards while one client\n"
    "streams from it, and reports the largest gap between two of its frames.\n"
    "\n"
    "  --server 127.0.0.1:PORT  the server's TCP port\n"
    "  --rate N           new connections per second (default 200)\n"
    "  --duration S       seconds of flood (default 10)\n"
    "  --addresses N      source addresses 127.0.0.2 .. 127.0.0.(N+1) (default 100)\n"
    "  --flooders N       threads opening connections (default 8)\n"
    "  --window MS        the window that must hold a frame (default 100)\n"
    "  --no-tls           the server speaks plain TCP (--no-tls)\n"
    "  --help\n"
    "Prints a JSON summary on stdout. Exit codes: 0 every window had a frame, 1 the\n"
    "watcher could not join or some window had none, 2 bad arguments.\n";

namespace {

struct Options {
    uint16_t port = 0;
    double rate = 200, duration = 10;
    int addresses = 100, flooders = 8, window_ms = 100;
    bool tls = true;
};

int parse(int argc, char** argv, Options& o) {
    try {
        for (int i = 1; i < argc; ++i) {
            const std::string a = argv[i];
            auto need = [&]() -> std::string {
                if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
                return argv[++i];
            };
            if (a == "--help" || a == "-h") {
                std::fputs(kUsage, stdout);
                return 0;
            } else if (a == "--server") {
                o.port = loopback_port(a, need(), "the flood runs on loopback");
            } else if (a == "--rate") o.rate = cli::to_number(a, need());
            else if (a == "--duration") o.duration = cli::to_number(a, need());
            else if (a == "--addresses") o.addresses = cli::to_int(a, need());
            else if (a == "--flooders") o.flooders = cli::to_int(a, need());
            else if (a == "--window") o.window_ms = cli::to_int(a, need());
            else if (a == "--no-tls") o.tls = false;
            else throw std::invalid_argument("unknown argument " + a);
        }
        if (o.port == 0) throw std::invalid_argument("--server is required");
        if (!(o.duration > 0 && o.duration <= 3600)) throw std::invalid_argument("--duration must be in (0, 3600]");
        if (!(o.rate > 0 && o.rate <= 10000)) throw std::invalid_argument("--rate must be in (0, 10000]");
        if (o.addresses < 1 || o.addresses > 250) throw std::invalid_argument("--addresses must be 1..250");
        if (o.flooders < 1 || o.flooders > 64) throw std::invalid_argument("--flooders must be 1..64");
        if (o.window_ms < 10 || o.window_ms > 10000) throw std::invalid_argument("--window must be 10..10000");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-flood: %s\n%s", e.what(), kUsage);
        return 2;
    }
    return -1;
}

struct FloodCounts {
    std::atomic<uint64_t> opened{0}, welcomed{0}, failed{0};
};

// Flooder `t` of `o.flooders`: connection j of all goes out at start + j / rate.
void flood(const Options& o, int t, double start, double end, FloodCounts& c) {
    std::vector<std::unique_ptr<Attacker>> from;
    for (int a = t; a < o.addresses; a += o.flooders)
        from.push_back(std::make_unique<Attacker>("127.0.0." + std::to_string(2 + a), o.port, 0, o.tls));
    if (from.empty()) from.push_back(std::make_unique<Attacker>("127.0.0." + std::to_string(2 + t % o.addresses), o.port, 0, o.tls));
    for (uint64_t j = uint64_t(t), k = 0;; j += uint64_t(o.flooders), ++k) {
        const double at = start + double(j) / o.rate;
        if (at >= end) break;
        const double wait = at - now_seconds();
        if (wait > 0) std::this_thread::sleep_for(std::chrono::duration<double>(wait));
        Attacker& a = *from[k % from.size()];
        ++c.opened;
        if (a.join(2000, "flood")) ++c.welcomed;
        else ++c.failed;
        a.disconnect();
    }
}

struct Watch {
    uint64_t frames = 0;
    double largest_gap = 0;
    int windows = 0, empty_windows = 0;
};

// The watcher: streams until `end`, acking every 50 ms; frames' arrival times.
Watch watch(Attacker& w, double start, double end, double window) {
    Watch r;
    double last = -1, acked = 0;
    std::vector<uint8_t> seen(size_t((end - start) / window) + 1, 0);
    while (now_seconds() < end) {
        const size_t n = w.read_frames(2);
        const double now = now_seconds();
        if (n > 0) {
            r.frames += n;
            if (last >= 0) r.largest_gap = std::max(r.largest_gap, now - last);
            last = now;
            if (now >= start) seen[std::min(seen.size() - 1, size_t((now - start) / window))] = 1;
        }
        if (now - acked > 0.05) {
            w.ack();
            acked = now;
        }
    }
    r.windows = int(seen.size()) - 1;  // the last is partial
    for (int i = 0; i < r.windows; ++i) r.empty_windows += seen[size_t(i)] ? 0 : 1;
    return r;
}

}  // namespace

int main(int argc, char** argv) {
    Options o;
    if (int rc = parse(argc, argv, o); rc >= 0) return rc;
    Attacker watcher("127.0.0.1", o.port, 0, o.tls);
    if (!watcher.join(5000, "watcher") || !watcher.bind(3000)) {
        std::fprintf(stderr, "progskin-flood: the watching client could not join: %s%s\n", watcher.refused().c_str(),
                     watcher.error().c_str());
        return 1;
    }
    watcher.read_frames(500);  // streaming before the flood starts
    const double start = now_seconds() + 0.2, end = start + o.duration;
    FloodCounts c;
    std::vector<std::thread> ts;
    for (int t = 0; t < o.flooders; ++t) ts.emplace_back([&, t] { flood(o, t, start, end, c); });
    const Watch w = watch(watcher, start, end, o.window_ms / 1000.0);
    for (auto& t : ts) t.join();
    std::printf("{\"rate\": %.0f, \"seconds\": %.1f, \"opened\": %llu, \"welcomed\": %llu, \"failed\": %llu, "
                "\"frames\": %llu, \"largest_gap_ms\": %.1f, \"windows\": %d, \"windows_without_frames\": %d}\n",
                o.rate, o.duration, (unsigned long long)c.opened.load(), (unsigned long long)c.welcomed.load(),
                (unsigned long long)c.failed.load(), (unsigned long long)w.frames, 1000.0 * w.largest_gap, w.windows,
                w.empty_windows);
    return w.empty_windows == 0 && w.frames > 0 ? 0 : 1;
}
