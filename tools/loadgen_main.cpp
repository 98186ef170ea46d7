// loadgen_main.cpp — progskin-loadgen: N simulated players in one process
// against a progskin-server or a world of nodes (tools/loadgen.h). The
// table goes to stderr, the report (--report json|text) to stdout, written
// on every exit after the arguments were read.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <string>

#include "cli_args.h"
#include "errors.h"
#include "loadgen.h"

using namespace progskin;
using namespace progskin::net;

static const char* kUsage =
    "usage: progskin-loadgen --server HOST:PORT[,HOST:PORT...] [options]\n"
    "Simulates N players in one process (--threads threads): each connects as progskin-client does\n"
    "(TLS control channel, UDP stream), spawns a character of the server's catalogue, walks it\n"
    "around its own spot of a square grid, publishes its pose every tick, receives, acknowledges\n"
    "and decodes the frames (no skinning). With several servers (a world), players go to them\n"
    "round-robin. Reports per-player rate, bones, latency from a publisher's send to another\n"
    "player's receipt and display (same node and cross-node apart), starved players, errors.\n"
    "\n"
    "  --server LIST        one node, or the nodes of a world (default 127.0.0.1:7777)\n"
    "  --players N          simulated players (1..4000, default 20)\n"
    "  --threads N          threads, each with its own players (1..64, default 1; one turn of\n"
    "                       a player at 256 kbit/s takes about 55 us of a core)\n"
    "  --duration S         measurement window in seconds (default 10)\n"
    "  --settle S           seconds after the last player joined before measuring (default 2)\n"
    "  --max-kbps N         each player's rate cap in kbit/s (default 256; 0: the server's)\n"
    "  --delay-ms N         display delay (default 100; fixed: the max delay is the same)\n"
    "  --tick-rate HZ       updates and poses per second per player (default 30)\n"
    "  --asset NAME|INDEX   the character every player spawns (default 0, the first)\n"
    "  --clip NAME          its clip (name, index, list or all; default all)\n"
    "  --walk R             walk a circle of R bounding-box diagonals (default 0.5; 0: stand)\n"
    "  --spacing D          grid step between players' spots, in diagonals (default 2)\n"
    "  --see K              each player's nearest K others must reach it (starved; default 100)\n"
    "  --placement P        round-robin (default: player i on node i mod nodes) or bands (the\n"
    "                       grid's rows cut in one band per node, neighbours mostly on one node)\n"
    "  --starve-s S         a nearest character silent longer than S starves (default 1)\n"
    "  --connect-rate N     players started per second (default 100)\n"
    "  --addresses N        source addresses 127.0.0.2..127.0.0.(N+1), players spread over them\n"
    "                       (1..250; default with loopback servers: one per 16 players, which\n"
    "                       keeps within the server's per-address limits; 0: the system's)\n"
    "  --tls / --no-tls     TLS control channel (default) or plain TCP (a server --no-tls)\n"
    "  --pin SHA256HEX      trust the server certificate with this fingerprint\n"
    "  --ca FILE            trust certificates signed by these CAs for the server's name\n"
    "  --insecure           accept any certificate (development only)\n"
    "  --token T            access token\n"
    "  --cache DIR          asset cache (default ~/.cache/progskin); the first player\n"
    "                       downloads, the others start once it has\n"
    "  --connect-timeout S  per player (default 20)\n"
    "  --retries N          a player that fails before it streams starts again up to N times\n"
    "                       (after 0.5, 1, 2, ... s), as a game client would (0..10, default 2)\n"
    "  --progress S         a progress line on stderr every S seconds (default 5; 0: none)\n"
    "  --report json|text   the report on stdout (default text), written even on failure\n"
    "  --help\n"
    "Exit codes: 0 every player joined and streamed to the end, 1 not (the report says\n"
    "why), 2 bad arguments.\n";

static std::atomic<bool> g_stop{false};
static void on_signal(int) { g_stop = true; }

int main(int argc, char** argv) {
    LoadOptions o;
    std::string report = "text", servers = "127.0.0.1:7777";
    try {
        for (int i = 1; i < argc; ++i) {
            const std::string a = argv[i];
            auto need = [&]() -> std::string {
                if (i + 1 >= argc) throw cli::UsageError(a + " needs a value");
                return argv[++i];
            };
            if (a == "--help" || a == "-h") {
                std::fputs(kUsage, stdout);
                return 0;
            } else if (a == "--server") servers = need();
            else if (a == "--players") o.players = cli::to_int(a, need());
            else if (a == "--duration") o.duration = cli::to_number(a, need());
            else if (a == "--settle") o.settle = cli::to_number(a, need());
            else if (a == "--max-kbps") o.max_kbps = cli::to_number(a, need());
            else if (a == "--delay-ms") o.delay_ms = cli::to_number(a, need());
            else if (a == "--tick-rate") o.tick_rate = cli::to_number(a, need());
            else if (a == "--asset") o.asset = need();
            else if (a == "--clip") o.clip = need();
            else if (a == "--walk") o.walk = cli::to_number(a, need());
            else if (a == "--spacing") o.spacing = cli::to_number(a, need());
            else if (a == "--see") o.see = cli::to_int(a, need());
            else if (a == "--placement") o.bands = cli::one_of(a, need(), "round-robin", "bands") == "bands";
            else if (a == "--starve-s") o.starve_s = cli::to_number(a, need());
            else if (a == "--connect-rate") o.connect_rate = cli::to_number(a, need());
            else if (a == "--addresses") o.addresses = cli::to_int(a, need());
            else if (a == "--tls") o.tls = true;
            else if (a == "--no-tls") o.tls = false;
            else if (a == "--pin") o.pin_sha256 = need();
            else if (a == "--ca") o.ca_file = need();
            else if (a == "--insecure") o.insecure = true;
            else if (a == "--token") o.token = need();
            else if (a == "--cache") o.cache_dir = need();
            else if (a == "--connect-timeout") o.connect_timeout = cli::to_number(a, need());
            else if (a == "--retries") o.retries = cli::to_int(a, need());
            else if (a == "--threads") o.threads = cli::to_int(a, need());
            else if (a == "--progress") o.progress_s = cli::to_number(a, need());
            else if (a == "--report") report = cli::one_of(a, need(), "json", "text");
            else throw cli::UsageError("unknown argument " + a);
        }
        o.servers = parse_server_list(servers);
        if (o.players < 1 || o.players > LoadOptions::kMaxPlayers)
            throw cli::UsageError("--players must be in 1.." + std::to_string(LoadOptions::kMaxPlayers));
        if (!(o.duration > 0 && o.duration <= 86400)) throw cli::UsageError("--duration must be in (0, 86400]");
        if (!(o.settle >= 0 && o.settle <= 600)) throw cli::UsageError("--settle must be in [0, 600]");
        if (!(o.tick_rate > 0 && o.tick_rate <= 240)) throw cli::UsageError("--tick-rate must be in (0, 240]");
        if (!(o.connect_rate > 0 && o.connect_rate <= 10000)) throw cli::UsageError("--connect-rate must be in (0, 10000]");
        if (!(o.delay_ms <= 5000)) throw cli::UsageError("--delay-ms must be at most 5000");
        if (!(o.walk <= 1000) || !(o.spacing > 0 && o.spacing <= 1000)) throw cli::UsageError("--walk in [0, 1000], --spacing in (0, 1000]");
        if (!(o.starve_s > 0 && o.starve_s <= 600)) throw cli::UsageError("--starve-s must be in (0, 600]");
        if (o.see > LoadOptions::kMaxPlayers) throw cli::UsageError("--see must be at most 4000");
        if (o.addresses > 250) throw cli::UsageError("--addresses must be at most 250");
        if (!(o.connect_timeout > 0 && o.connect_timeout <= 600)) throw cli::UsageError("--connect-timeout must be in (0, 600]");
        if (o.retries < 0 || o.retries > 10) throw cli::UsageError("--retries must be in 0..10");
        if (o.threads < 1 || o.threads > LoadOptions::kMaxThreads)
            throw cli::UsageError("--threads must be in 1.." + std::to_string(LoadOptions::kMaxThreads));
        if (!(o.progress_s <= 3600)) throw cli::UsageError("--progress must be at most 3600");
        if (!o.tls && (!o.pin_sha256.empty() || !o.ca_file.empty() || o.insecure))
            throw cli::UsageError("--no-tls excludes --pin, --ca and --insecure");
        if (o.tls && o.pin_sha256.empty() && o.ca_file.empty() && !o.insecure)
            throw cli::UsageError("TLS needs a way to trust the server's certificate: --pin, --ca or --insecure (or --no-tls)");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-loadgen: %s\n%s", e.what(), kUsage);
        return 2;
    }
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    LoadReport r;
    try {
        r = run_loadgen(o, &g_stop);
    } catch (const std::exception& e) {
        r.ok = false;
        r.error = e.what();
        r.players = o.players;
        r.nodes = int(o.servers.size());
        std::fprintf(stderr, "progskin-loadgen: %s\n", e.what());
    }
    const std::string table = report_table(r, o);
    if (report == "json") {
        std::fputs(table.c_str(), stderr);
        std::fputs(report_json(r, o).c_str(), stdout);
    } else {
        std::fputs(table.c_str(), stdout);
    }
    return r.ok ? 0 : 1;
}
