// netem_main.cpp — progskin-netem: a link emulator in front of a
// progskin-server's frame stream (UDP) and, with --tcp, its control channel
// (link_emulator.h).
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "cli_args.h"
#include "link_emulator.h"

using namespace progskin::net;
namespace cli = progskin::cli;

static const char* kUsage =
    "usage: progskin-netem --to HOST:UDPPORT [options]\n"
    "Relays the UDP frame stream between clients and a progskin-server, emulating a link.\n"
    "Point clients at it with: progskin-client --server HOST:TCPPORT --udp-via HOST:LISTENPORT\n"
    "With --tcp the control channel goes through it too (rate cap, delay and jitter; a TCP\n"
    "stream is never dropped, reordered or duplicated):\n"
    "  progskin-client --server HOST:LISTENPORT --udp-via HOST:LISTENPORT\n"
    "\n"
    "  --to HOST:PORT    the server's UDP port (by default the same number as its TCP port)\n"
    "  --listen PORT     UDP (and with --tcp TCP) port to listen on (default 7778; 0 = any)\n"
    "  --tcp             also relay TCP to the server's control port\n"
    "  --tcp-port N      the server's TCP port (default: the --to port)\n"
    "  --bind ADDR       listen address (default 127.0.0.1)\n"
    "  --rate-kbps N     link rate cap (0 = unlimited)\n"
    "  --delay-ms N      one-way delay\n"
    "  --jitter-ms N     uniform extra delay 0..N\n"
    "  --loss P          loss probability (0..1)\n"
    "  --reorder P       probability of holding a datagram back (reordering)\n"
    "  --duplicate P     duplication probability\n"
    "  --queue-ms N      rate-cap queue limit (default 200)\n"
    "  --both-ways       impair client -> server too (default: delay only)\n"
    "  --seed N          random seed (default 1)\n"
    "  --duration S      stop after S seconds (default: until SIGINT/SIGTERM)\n"
    "Exit codes: 0 ok, 1 runtime error, 2 bad arguments.\n";

static volatile std::sig_atomic_t g_stop = 0;
static void on_signal(int) { g_stop = 1; }

int main(int argc, char** argv) {
    LinkConfig cfg;
    cli::HostPort to;
    std::string bind = "127.0.0.1";
    uint16_t listen = 7778, tcp_port = 0;
    bool tcp = false;
    double duration = 0;
    try {
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            auto val = [&]() -> std::string {
                if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
                return argv[++i];
            };
            if (a == "--help" || a == "-h") {
                std::fputs(kUsage, stdout);
                return 0;
            } else if (a == "--to") to = cli::host_port(a, val());
            else if (a == "--listen") listen = cli::to_port(a, val());
            else if (a == "--bind") bind = val();
            else if (a == "--tcp") tcp = true;
            else if (a == "--tcp-port") tcp_port = cli::to_port(a, val());
            else if (a == "--rate-kbps") cfg.rate_kbps = cli::to_number(a, val());
            else if (a == "--delay-ms") cfg.delay_ms = cli::to_number(a, val());
            else if (a == "--jitter-ms") cfg.jitter_ms = cli::to_number(a, val());
            else if (a == "--loss") cfg.loss = cli::to_number(a, val());
            else if (a == "--reorder") cfg.reorder = cli::to_number(a, val());
            else if (a == "--duplicate") cfg.duplicate = cli::to_number(a, val());
            else if (a == "--queue-ms") cfg.queue_ms = cli::to_number(a, val());
            else if (a == "--both-ways") cfg.both_ways = true;
            else if (a == "--seed") cfg.seed = uint64_t(cli::to_int(a, val()));
            else if (a == "--duration") duration = cli::to_number(a, val());
            else throw std::invalid_argument("unknown argument " + a);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-netem: %s\n%s", e.what(), kUsage);
        return 2;
    }
    if (to.host.empty()) {
        std::fprintf(stderr, "progskin-netem: --to HOST:PORT is required\n%s", kUsage);
        return 2;
    }
    if (!tcp_port) tcp_port = to.port;  // the server's TCP port: by default the UDP port's number
    try {
        for (double p : {cfg.loss, cfg.reorder, cfg.duplicate})
            if (!(p >= 0 && p <= 1)) throw cli::UsageError("--loss, --reorder and --duplicate are probabilities (0..1)");
        if (cfg.rate_kbps < 0 || cfg.delay_ms < 0 || cfg.jitter_ms < 0 || cfg.queue_ms < 0 || duration < 0)
            throw cli::UsageError("rates, times and durations must not be negative");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-netem: %s\n%s", e.what(), kUsage);
        return 2;
    }
    try {
        LinkEmulator link(cfg, to.host, to.port, bind, listen);
        std::signal(SIGINT, on_signal);
        std::signal(SIGTERM, on_signal);
        if (tcp) link.relay_tcp(tcp_port);
        link.start();
        std::printf("progskin-netem: listening on UDP %s:%u -> %s:%u\n", bind.c_str(), link.port(), to.host.c_str(),
                    unsigned(to.port));
        if (tcp)
            std::printf("progskin-netem: listening on TCP %s:%u -> %s:%u\n", bind.c_str(), link.port(), to.host.c_str(),
                        unsigned(tcp_port));
        std::fflush(stdout);
        auto t0 = std::chrono::steady_clock::now();
        while (!g_stop) {
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            if (duration > 0 && std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(duration)) break;
        }
        link.stop();
        LinkStats s = link.stats();
        std::fprintf(stderr, "progskin-netem: forwarded %llu, dropped %llu, queue drops %llu, duplicated %llu, reordered %llu\n",
                     (unsigned long long)s.forwarded, (unsigned long long)s.dropped, (unsigned long long)s.queue_drops,
                     (unsigned long long)s.duplicated, (unsigned long long)s.reordered);
        if (tcp)
            std::fprintf(stderr, "progskin-netem: TCP connections %llu, bytes to clients %llu, to the server %llu\n",
                         (unsigned long long)s.tcp_connections, (unsigned long long)s.tcp_bytes_down,
                         (unsigned long long)s.tcp_bytes_up);
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-netem: %s\n", e.what());
        return 1;
    }
}
