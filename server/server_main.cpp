// server_main.cpp — progskin-server: hosts a scene and streams it (server.h).
// TLS is on by default (unlike ServerConfig's): with no --tls-cert/--tls-key
// it uses a self-signed pair generated once in the config directory
// (tls_identity.h) and prints the certificate's SHA-256 on stdout
// ("progskin-server: TLS certificate sha256 HEX") for clients to pin; with
// TLS, datagrams are sealed unless --no-seal-datagrams. --no-tls: plain.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <sys/resource.h>
#include <thread>
#include <vector>

#include "cli_args.h"
#include "errors.h"
#include "representable.h"
#include "server.h"
#include "tls_identity.h"
#include "web_files.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;

static const char* kUsage =
    "usage: progskin-server [options]\n"
    "Streams progressive bone packets of a scene of characters to progskin-client.\n"
    "With no --asset, serves the bundled default set (assets/Fox.glb, assets/CesiumMan.glb).\n"
    "\n"
    "  --port P          TCP control port (default 7777; 0 = any free port); UDP uses the\n"
    "                    same number unless --udp-port is given\n"
    "  --udp-port P      UDP frame stream port\n"
    "  --bind ADDR       address to listen on (default 0.0.0.0)\n"
    "  --web P           also serve browsers: a WebSocket endpoint at wss://ADDR:P/ws and the\n"
    "                    browser client's page at https://ADDR:P/ (the control channel's\n"
    "                    certificate), or ws:// and http:// with --no-tls (docs/browser.md)\n"
    "  --web-root DIR    the page's folder (default: share/progskin/web of the installed\n"
    "                    package, else the build tree's web/ from scripts/build_web.sh)\n"
    "  --asset FILE ...  glTF/glb characters (progressive or plain; repeatable): every\n"
    "                    character of FILE, or FILE#N for character N only. Every file is\n"
    "                    checked before anything is built; all problems are listed together\n"
    "  --from-vertices   serve files without a skin (morph-target animation, PC2) by building\n"
    "                    a skin from their vertex animation (as progskin build --from-vertices)\n"
    "  --bones N         bones of such a build (default 16)\n"
    "  --build-strategy rate|auto  how a plain file's progressive skin is built: rate (default)\n"
    "                    as progskin build --strategy rate: reorder, flatten or hierarchy,\n"
    "                    the most error removed per bit of the stream's records; auto as\n"
    "                    progskin build: the lower mean error of reorder and flatten\n"
    "  --build-training clips|range-of-motion  what a plain file's build trains on: its\n"
    "                    clips (default; range-of-motion poses where they do not move the\n"
    "                    skeleton), or range-of-motion poses whatever the clips, for\n"
    "                    avatars a game animates (as progskin build --clip range-of-motion)\n"
    "  --cache DIR       derived files (default $XDG_CACHE_HOME/progskin or ~/.cache/progskin)\n"
    "  --crowd N         lay out N instances over the assets and their clips (default:\n"
    "                    one instance per asset and clip group)\n"
    "  --no-scene        host a catalogue only: no server-driven instances (players spawn\n"
    "                    and publish their own characters: progskin-client --publish)\n"
    "  --play loop|once  clips loop (default) or play once and hold their last frame\n"
    "  --tick-rate HZ    ticks per second (default 30)\n"
    "  --threads N       threads of the tick (its encode, then the per-client work; 1..256; default: the\n"
    "                    machine's cores). With more than 1, connections (TLS handshakes,\n"
    "                    control messages, asset downloads) also get a thread of their own\n"
    "                    and never delay a tick; 1: one thread for everything\n"
    "  --nats URL        join a world of servers on this NATS server (nats://HOST:PORT, or\n"
    "                    tls://HOST:PORT for TLS): this node's characters go on the bus by\n"
    "                    spatial cell, the other nodes' come into this scene (docs/deployment.md)\n"
    "  --nats-ca FILE    TLS to the NATS server, trusting the certificates in this PEM file\n"
    "                    (default with tls://: the system's trust store)\n"
    "  --nats-cert FILE  this node's TLS certificate for a NATS server that verifies its\n"
    "  --nats-key FILE   clients (nats-server --tlsverify); they go together\n"
    "  --node NAME       this node's name in the world's logs (default: node)\n"
    "  --world NAME      the world's name, its bus subjects (default: default)\n"
    "  --world-cell M    side of a bus cell in world units (default 16)\n"
    "  --nats-queue N    bus messages held between two ticks (1..1048576, default 1024);\n"
    "                    beyond, dropped and counted, and the node follows fewer cells\n"
    "  --view-radius M   clients see the characters within M world units of their camera\n"
    "                    (else of their own characters); a world node subscribes only to\n"
    "                    the bus cells within it (default 0: everything)\n"
    "  --max-clients N   (default 256)\n"
    "  --max-kbps N      per-client rate ceiling in kbit/s (default 50000)\n"
    "  Budgets (what one player may cost the others; docs/protocol.md \"Security\"):\n"
    "  --max-per-address N   open connections from one IP address (default 64; 0: none)\n"
    "  --max-characters-per-address N  players' characters from one IP address (default 32)\n"
    "  --owner-share-kbps N  what one session's characters may take of each other client's\n"
    "                    stream (default 256; 0: no limit)\n"
    "  --standalone-records  every bone record coded on its own (no prediction from what\n"
    "                    each client acknowledged): about 2.4 times less CPU per client,\n"
    "                    1.4-1.7 times the bits per bone (docs/deployment.md \"Not done yet\")\n"
    "  --key-samples     (default) a clip whose channels are all linear is sampled at its\n"
    "                    latest key since the tick before, so that clients at full rate follow\n"
    "                    its kinks between ticks (docs/protocol.md \"Key samples\")\n"
    "  --no-key-samples  sample every clip at the ticks (better below the full rate on some\n"
    "                    content: docs/performance.md \"Protocol 8\")\n"
    "  --fair-floor F    each character's own bones go first up to this fraction of its\n"
    "                    part of a client's stream (0..1, default 0.5; 0: greedy only)\n"
    "  --asset-bytes-per-minute N  asset bytes per IP address, across reconnects (default:\n"
    "                    64 x the catalogue's bytes)\n"
    "  --max-handshakes N    connections before Hello at once (default 128; the oldest go)\n"
    "  --connects-per-second N  new connections per IP address (default 32, 8 s of burst)\n"
    "  --token T         require this access token in Hello\n"
    "  --token-public-key HEX  require a connect token signed by the matching secret\n"
    "                    key (progskin token keygen / issue) in Hello\n"
    "  --public-address HOST:PORT  the address connect tokens must name (default: any)\n"
    "  TLS on the control channel is on by default, with a self-signed certificate\n"
    "  generated once (EC P-256, CN progskin-server, SAN 127.0.0.1 and localhost) and\n"
    "  reused; its SHA-256 is printed on stdout for progskin-client --pin:\n"
    "  --tls-dir DIR     where that pair lives (default $XDG_CONFIG_HOME/progskin or\n"
    "                    ~/.config/progskin): server-cert.pem, server-key.pem\n"
    "  --tls-cert FILE --tls-key FILE  use this certificate (chain) and key instead (PEM)\n"
    "  --no-tls          plain TCP control channel, unsealed datagrams (clients: --no-tls)\n"
    "  --seal-datagrams  seal every datagram with per-session keys (default with TLS)\n"
    "  --no-seal-datagrams  TLS without sealed datagrams\n"
    "  --no-repair       never send a lost frame datagram again (default: up to 3 times, a\n"
    "                    lost repair again, while its tick is at most 6 ticks old and the\n"
    "                    client's stream has room)\n"
    "  --duration S      stop after S seconds (default: run until SIGINT/SIGTERM)\n"
    "  --stats-every S   every S seconds a line on stderr of what the last S seconds cost:\n"
    "                    sessions, ticks, mean tick, process CPU, datagrams and kbit/s sent,\n"
    "                    world bus messages and bytes per second each way (key=value pairs)\n"
    "  --verbose         log sessions on stderr\n"
    "  --help\n"
    "Exit codes: 0 ok, 1 runtime error, 2 bad arguments.\n";

// SIGINT/SIGTERM only set this flag; serve's watcher thread stops the
// server. (Server::stop posts to the io_contexts, which takes their
// mutex: called from the handler while the interrupted thread held it, the
// server deadlocked and never exited.)
static volatile std::sig_atomic_t g_stop_requested = 0;
static void on_signal(int) { g_stop_requested = 1; }

// The command line (see kUsage).
struct Options {
    ServerConfig cfg;
    std::vector<std::string> asset_paths;
    AssetOptions asset_options;
    int crowd = 0;
    int threads = -1;  // -1: not given (the machine's cores)
    double duration = 0;
    double stats_every = 0;  // 0: no periodic stats line
    bool no_scene = false, once = false;
    bool no_tls = false, seal = true, seal_asked = false;
    std::string tls_dir;
    std::string web_root;  // --web-root
    // The command line's defaults where they differ from the library's:
    // plain files built by rate, linearly keyed clips sampled at their keys.
    Options() {
        asset_options.build_by_rate = true;
        cfg.key_samples = true;
    }
};

// Reads argv into `o`. Returns -1 to go on, else the exit code (0: --help, 2: bad arguments).
static int parse_options(int argc, char** argv, Options& o) {
    o.cfg.port = 7777;
    ServerConfig& cfg = o.cfg;
    auto need = [&](int& i) -> const char* {
        if (i + 1 >= argc) {
            std::fprintf(stderr, "progskin-server: %s needs a value\n%s", argv[i], kUsage);
            std::exit(2);
        }
        return argv[++i];
    };
    try {
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            if (a == "--help" || a == "-h") {
                std::fputs(kUsage, stdout);
                return 0;
            } else if (a == "--port") cfg.port = cli::to_port(a, need(i));
            else if (a == "--udp-port") cfg.udp_port = cli::to_port(a, need(i));
            else if (a == "--web") cfg.web_port = cli::to_port(a, need(i));
            else if (a == "--web-root") o.web_root = need(i);
            else if (a == "--bind") cfg.bind_address = need(i);
            else if (a == "--asset") {
                o.asset_paths.push_back(need(i));
                while (i + 1 < argc && argv[i + 1][0] != '-') o.asset_paths.push_back(argv[++i]);  // --asset A B C
            }
            else if (a == "--from-vertices") o.asset_options.from_vertices = true;
            else if (a == "--bones") o.asset_options.scratch_bones = cli::to_int(a, need(i));
            else if (a == "--cache") o.asset_options.cache_dir = need(i);
            else if (a == "--crowd") o.crowd = cli::to_int(a, need(i));
            else if (a == "--no-scene") o.no_scene = true;
            else if (a == "--build-strategy") o.asset_options.build_by_rate = cli::one_of(a, need(i), "auto", "rate") == "rate";
            else if (a == "--build-training")
                o.asset_options.range_of_motion = cli::one_of(a, need(i), "clips", "range-of-motion") == "range-of-motion";
            else if (a == "--play") o.once = cli::one_of(a, need(i), "loop", "once") == "once";
            else if (a == "--tick-rate") cfg.tick_rate = float(cli::to_number(a, need(i)));
            else if (a == "--threads") o.threads = cli::to_int(a, need(i));
            else if (a == "--nats") cfg.nats_url = need(i);
            else if (a == "--nats-ca") cfg.nats_ca_file = need(i);
            else if (a == "--nats-cert") cfg.nats_cert_file = need(i);
            else if (a == "--nats-key") cfg.nats_key_file = need(i);
            else if (a == "--node") cfg.world_node = need(i);
            else if (a == "--world") cfg.world_name = need(i);
            else if (a == "--world-cell") cfg.world_cell = cli::to_number(a, need(i));
            else if (a == "--nats-queue") cfg.world_queue = size_t(std::max(0, cli::to_int(a, need(i))));
            else if (a == "--view-radius") cfg.view_radius = cli::to_number(a, need(i));
            else if (a == "--max-clients") cfg.max_clients = cli::to_int(a, need(i));
            else if (a == "--max-kbps") cfg.max_kbps = cli::to_number(a, need(i));
            else if (a == "--max-per-address") cfg.max_per_address = cli::to_int(a, need(i));
            else if (a == "--max-characters-per-address") cfg.max_characters_per_address = cli::to_int(a, need(i));
            else if (a == "--owner-share-kbps") cfg.owner_share_kbps = cli::to_number(a, need(i));
            else if (a == "--fair-floor") cfg.fair_floor = cli::to_number(a, need(i));
            else if (a == "--standalone-records") cfg.predict_records = false;
            else if (a == "--key-samples") cfg.key_samples = true;
            else if (a == "--no-key-samples") cfg.key_samples = false;
            else if (a == "--asset-bytes-per-minute") cfg.asset_bytes_per_minute = cli::to_number(a, need(i));
            else if (a == "--max-handshakes") cfg.max_handshakes = cli::to_int(a, need(i));
            else if (a == "--connects-per-second") cfg.connects_per_second = cli::to_number(a, need(i));
            else if (a == "--token") cfg.token = need(i);
            else if (a == "--token-public-key") cfg.token_public_key = need(i);
            else if (a == "--public-address") cfg.public_address = need(i);
            else if (a == "--tls-cert") cfg.tls_cert_file = need(i);
            else if (a == "--tls-key") cfg.tls_key_file = need(i);
            else if (a == "--seal-datagrams") o.seal = o.seal_asked = true;
            else if (a == "--no-seal-datagrams") o.seal = false;
            else if (a == "--no-repair") cfg.repair_lost = false;
            else if (a == "--no-tls") o.no_tls = true;
            else if (a == "--tls-dir") o.tls_dir = need(i);
            else if (a == "--duration") o.duration = cli::to_number(a, need(i));
            else if (a == "--stats-every") o.stats_every = cli::to_number(a, need(i));
            else if (a == "--verbose") cfg.verbose = true;
            else {
                std::fprintf(stderr, "progskin-server: unknown argument %s\n%s", a.c_str(), kUsage);
                return 2;
            }
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-server: %s\n%s", e.what(), kUsage);
        return 2;
    }
    return -1;
}

// Ranges and combinations parse_options cannot see alone; 2 when wrong, else -1.
static int check_options(const Options& o) {
    const ServerConfig& cfg = o.cfg;
    if (!(o.stats_every >= 0 && o.stats_every <= 3600)) {
        std::fprintf(stderr, "progskin-server: --stats-every must be in [0, 3600]\n%s", kUsage);
        return 2;
    }
    if (o.threads != -1 && (o.threads < 1 || o.threads > 256)) {
        std::fprintf(stderr, "progskin-server: --threads must be in [1, 256]\n%s", kUsage);
        return 2;
    }
    const std::pair<const char*, bool> ranges[] = {
        {"--tick-rate must be in (0, 240]", cfg.tick_rate > 0 && cfg.tick_rate <= 240},
        {"--crowd must be >= 0", o.crowd >= 0},
        {"--max-clients must be >= 1", cfg.max_clients >= 1},
        {"--max-kbps must be > 0", cfg.max_kbps > 0},
        {"--fair-floor must be in [0, 1]", cfg.fair_floor >= 0 && cfg.fair_floor <= 1},
        {"--view-radius must be >= 0", cfg.view_radius >= 0},
        {"--world-cell must be > 0", cfg.world_cell > 0},
        {"--nats-queue must be in [1, 1048576]", cfg.world_queue >= 1 && cfg.world_queue <= (size_t(1) << 20)},
        {"--bones must be in [1, 255]", o.asset_options.scratch_bones >= 1 && o.asset_options.scratch_bones <= MAX_BONES}};
    for (const auto& [what, ok] : ranges)
        if (!ok) {
            std::fprintf(stderr, "progskin-server: %s\n%s", what, kUsage);
            return 2;
        }
    const std::pair<const char*, double> budgets[] = {
        {"--max-per-address", cfg.max_per_address},   {"--max-characters-per-address", cfg.max_characters_per_address},
        {"--owner-share-kbps", cfg.owner_share_kbps}, {"--asset-bytes-per-minute", cfg.asset_bytes_per_minute},
        {"--max-handshakes", cfg.max_handshakes},     {"--connects-per-second", cfg.connects_per_second}};
    for (const auto& [name, v] : budgets)
        if (!(v >= 0)) {
            std::fprintf(stderr, "progskin-server: %s must be >= 0\n%s", name, kUsage);
            return 2;
        }
    if (o.no_tls && (!cfg.tls_cert_file.empty() || !cfg.tls_key_file.empty() || o.seal_asked || !o.tls_dir.empty())) {
        std::fprintf(stderr, "progskin-server: --no-tls excludes --tls-cert, --tls-key, --tls-dir and --seal-datagrams\n%s", kUsage);
        return 2;
    }
    if (!o.web_root.empty() && cfg.web_port < 0) {
        std::fprintf(stderr, "progskin-server: --web-root needs --web\n%s", kUsage);
        return 2;
    }
    if (!o.web_root.empty() && !std::filesystem::is_regular_file(std::filesystem::path(o.web_root) / "index.html")) {
        std::fprintf(stderr, "progskin-server: --web-root %s: no index.html there (scripts/build_web.sh builds build/web)\n",
                     o.web_root.c_str());
        return 2;
    }
    if (cfg.tls_cert_file.empty() != cfg.tls_key_file.empty()) {
        std::fprintf(stderr, "progskin-server: --tls-cert and --tls-key go together\n%s", kUsage);
        return 2;
    }
    if (cfg.nats_cert_file.empty() != cfg.nats_key_file.empty()) {
        std::fprintf(stderr, "progskin-server: --nats-cert and --nats-key go together\n%s", kUsage);
        return 2;
    }
    if (cfg.nats_url.empty() && !(cfg.nats_ca_file.empty() && cfg.nats_cert_file.empty())) {
        std::fprintf(stderr, "progskin-server: --nats-ca, --nats-cert and --nats-key need --nats\n%s", kUsage);
        return 2;
    }
    // Checked before any asset is built (a missing file found after a long build wastes it).
    for (const auto& [name, file] : {std::pair<const char*, const std::string&>{"--nats-ca", cfg.nats_ca_file},
                                     {"--nats-cert", cfg.nats_cert_file}, {"--nats-key", cfg.nats_key_file}})
        if (!file.empty() && !std::filesystem::is_regular_file(file)) {
            std::fprintf(stderr, "progskin-server: %s %s: no such file\n", name, file.c_str());
            return 2;
        }
    return -1;
}

// TLS unless --no-tls: the given pair, or the self-signed one (generated
// once); sets the configuration's files and sealing and returns the lines
// printed with the listening line. Throws on failure.
static std::string setup_tls(Options& o) {
    ServerConfig& cfg = o.cfg;
    if (o.no_tls) return {};
    std::string tls_line;
    if (cfg.tls_cert_file.empty()) {
        const TlsIdentity id = ensure_self_signed(o.tls_dir.empty() ? default_tls_dir() : o.tls_dir);
        cfg.tls_cert_file = id.cert_path;
        cfg.tls_key_file = id.key_path;
        tls_line = "progskin-server: TLS certificate sha256 " + id.sha256_hex + "\nprogskin-server: TLS certificate " +
                   id.cert_path + ", key " + id.key_path + (id.created ? " (generated)" : " (reused)") + "\n";
    } else {
        tls_line = "progskin-server: TLS certificate sha256 " + certificate_sha256(cfg.tls_cert_file) +
                   "\nprogskin-server: TLS certificate " + cfg.tls_cert_file + ", key " + cfg.tls_key_file + "\n";
    }
    cfg.seal_datagrams = o.seal;
    return tls_line;
}

// Checks every asset file first (cheap), so that one bad file is reported at
// once, together with every other problem, before minutes of building; then
// builds them, logging each. False (problems printed) when any file is bad.
static bool load_assets(Options& o, const char* argv0, std::vector<std::shared_ptr<ServerAsset>>& assets) {
    if (o.asset_paths.empty()) {
        std::string exe = argv0;
        auto slash = exe.rfind('/');
        o.asset_paths = default_asset_paths(slash == std::string::npos ? "." : exe.substr(0, slash));
    }
    std::vector<PendingAsset> pending;
    const std::vector<std::string> problems = check_server_assets(o.asset_paths, o.asset_options, pending);
    if (!problems.empty()) {
        for (const std::string& p : problems) std::fprintf(stderr, "progskin-server: error: %s\n", p.c_str());
        std::fprintf(stderr, "progskin-server: %zu problem%s in the assets; nothing was built\n", problems.size(),
                     problems.size() == 1 ? "" : "s");
        return false;
    }
    std::fprintf(stderr, "progskin-server: plain files built --build-strategy %s --build-training %s; clips %s\n",
                 o.asset_options.build_by_rate ? "rate" : "auto", o.asset_options.range_of_motion ? "range-of-motion" : "clips",
                 o.cfg.key_samples ? "of linear keys sampled at their keys (--key-samples)" : "sampled at the ticks (--no-key-samples)");
    for (const auto& p : pending) {
        std::fprintf(stderr, "progskin-server: loading %s%s%s\n", p.path.c_str(),
                     p.characters_in_file > 1 ? (" character " + std::to_string(p.character)).c_str() : "",
                     p.from_vertices ? " (building a skin from its vertex animation)" : "");
        assets.push_back(build_server_asset(p, o.asset_options));
        const auto& a = *assets.back();
        std::fprintf(stderr, "progskin-server:   %s: %d bones, %zu vertices, %zu clip groups, id %s, %zu bytes\n",
                     a.name.c_str(), a.bone_count(), a.character.vertex_count(), a.selections.size(),
                     hex64(a.id).c_str(), a.bytes.size());
        for (const std::string& w : a.warnings) std::fprintf(stderr, "progskin-server: warning: %s\n", w.c_str());
        // The importer's notes: renormalised weights, decomposed matrices,
        // what a bone record cannot carry (common/representable.h).
        for (const std::string& n : a.character.notes) std::fprintf(stderr, "progskin-server:   %s: note: %s\n", a.name.c_str(), n.c_str());
        for (const std::string& n : representability_notes(a.character))
            std::fprintf(stderr, "progskin-server:   %s: note: %s\n", a.name.c_str(), n.c_str());
    }
    // Two files of one name (every Sketchfab download is scene.gltf): clients
    // that pick an asset by name (progskin-client --publish NAME) get the
    // first. Said, with the catalogue indices, so that one can be renamed.
    for (size_t i = 0; i < assets.size() && assets.size() == pending.size(); ++i)
        for (size_t j = i + 1; j < assets.size(); ++j)
            if (assets[i]->name == assets[j]->name)
                std::fprintf(stderr,
                             "progskin-server: warning: assets %zu and %zu are both named %s (%s, %s): a client that picks "
                             "an asset by name gets asset %zu; rename one file to tell them apart\n",
                             i, j, assets[i]->name.c_str(), pending[i].path.c_str(), pending[j].path.c_str(), i);
    return true;
}

static double process_cpu_seconds() {
    rusage u{};
    ::getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// --stats-every: one line of what the last `dt` seconds cost (a and b: the
// stats at its ends; cpu: process CPU seconds in it).
static void stats_line(const ServerStats& a, const ServerStats& b, double dt, double cpu) {
    const double ticks = double(b.ticks - a.ticks);
    std::fprintf(stderr,
                 "progskin-server: stats seconds=%.2f sessions=%llu ticks_per_s=%.2f mean_tick_ms=%.3f cpu_share=%.3f "
                 "datagrams_per_s=%.1f sent_kbps=%.1f poses_per_s=%.1f world_out_msgs_per_s=%.1f world_out_bytes_per_s=%.0f "
                 "world_in_msgs_per_s=%.1f world_in_bytes_per_s=%.0f world_dropped=%llu world_foreign=%d\n",
                 dt, (unsigned long long)b.sessions_active, ticks / dt,
                 ticks > 0 ? 1000.0 * (b.tick_seconds - a.tick_seconds) / ticks : 0.0, cpu / dt,
                 double(b.datagrams_sent - a.datagrams_sent) / dt, double(b.wire_bytes_sent - a.wire_bytes_sent) * 8 / 1000 / dt,
                 double(b.poses_received - a.poses_received) / dt, double(b.world_messages_out - a.world_messages_out) / dt,
                 double(b.world_bytes_out - a.world_bytes_out) / dt, double(b.world_messages_in - a.world_messages_in) / dt,
                 double(b.world_bytes_in - a.world_bytes_in) / dt, (unsigned long long)(b.world_dropped - a.world_dropped),
                 b.world_foreign);
}

// Serves until SIGINT/SIGTERM (on_signal, installed by the caller before it
// announces the server; seen here within 20 ms) or `duration` seconds (0:
// no limit); with stats_every, a stats line that often.
static void serve(Server& server, double duration, double stats_every) {
    std::atomic<bool> done{false};
    std::thread stopper([&server, &done, duration, stats_every] {
        using clock = std::chrono::steady_clock;
        const auto start = clock::now();
        auto end = start + std::chrono::duration<double>(duration > 0 ? duration : 1e9);
        auto next = start + std::chrono::duration<double>(stats_every);
        ServerStats last = server.stats();
        double last_cpu = process_cpu_seconds();
        auto last_at = start;
        while (!done && !g_stop_requested && clock::now() < end) {
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
            if (stats_every > 0 && clock::now() >= next) {
                const auto now = clock::now();
                const ServerStats st = server.stats();
                const double cpu = process_cpu_seconds();
                stats_line(last, st, std::chrono::duration<double>(now - last_at).count(), cpu - last_cpu);
                last = st;
                last_cpu = cpu;
                last_at = now;
                next += std::chrono::duration<double>(stats_every);
            }
        }
        if (!done) server.stop();
    });
    server.run();
    done = true;
    stopper.join();
}

static void report(const ServerStats& st) {
    std::fprintf(stderr,
                 "progskin-server: %llu sessions, %llu datagrams sent (%llu repairs), %llu malformed + %llu rejected + %llu late + %llu stale datagrams, "
                 "%llu poses received (%llu stale, %llu over the rate limit, %llu out of range, %llu without their baseline), "
                 "mean tick %.3f ms\n",
                 (unsigned long long)st.sessions_total, (unsigned long long)st.datagrams_sent,
                 (unsigned long long)st.datagrams_repaired, (unsigned long long)st.malformed_datagrams, (unsigned long long)st.rejected_datagrams,
                 (unsigned long long)st.late_datagrams, (unsigned long long)st.stale_datagrams,
                 (unsigned long long)st.poses_received, (unsigned long long)st.poses_stale,
                 (unsigned long long)st.poses_rate_limited, (unsigned long long)st.poses_out_of_range,
                 (unsigned long long)st.poses_missing_baseline, st.ticks ? 1000.0 * st.tick_seconds / double(st.ticks) : 0.0);
    std::string cells = st.world_cells < 0 ? "all" : std::to_string(st.world_cells);
    if (st.world_cells_shed > 0) cells += " (" + std::to_string(st.world_cells_shed) + " shed: behind)";
    if (st.world_messages_out + st.world_messages_in > 0)
        std::fprintf(stderr,
                     "progskin-server: world bus: %llu messages (%llu bytes) out, %llu (%llu bytes) in, %llu dropped, "
                     "%llu superseded, "
                     "%llu malformed, %llu of another catalogue, %llu publish failures, %d foreign characters now, "
                     "cells subscribed %s\n",
                     (unsigned long long)st.world_messages_out, (unsigned long long)st.world_bytes_out,
                     (unsigned long long)st.world_messages_in, (unsigned long long)st.world_bytes_in,
                     (unsigned long long)st.world_dropped, (unsigned long long)st.world_superseded,
                     (unsigned long long)st.world_malformed, (unsigned long long)st.world_refused, (unsigned long long)st.world_publish_failed, st.world_foreign,
                     cells.c_str());
    std::string refusals;
    for (const auto& [reason, n] : st.refusals) refusals += " " + reason + " " + std::to_string(n);
    std::fprintf(stderr, "progskin-server: refusals:%s\n", refusals.empty() ? " none" : refusals.c_str());
}

int main(int argc, char** argv) {
    Options o;
    if (int rc = parse_options(argc, argv, o); rc >= 0) return rc;
    if (int rc = check_options(o); rc >= 0) return rc;
    if (o.cfg.web_port >= 0) o.cfg.web_root = WebFiles::find_root(o.web_root, "/proc/self/exe");
    std::string tls_line;  // printed with the listening line
    try {
        tls_line = setup_tls(o);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-server: TLS: %s\n", e.what());
        return 1;
    }
    try {
        // The ports first: one in use is reported before any asset is built.
        BoundPorts ports;
        try {
            ports = bind_ports(o.cfg);
        } catch (const std::exception& e) {
            std::fprintf(stderr, "progskin-server: %s\n", e.what());
            return 1;
        }
        std::vector<std::shared_ptr<ServerAsset>> assets;
        if (!load_assets(o, argv[0], assets)) return 1;
        std::vector<InstanceSpec> instances;
        if (o.no_scene) {
            // players bring the characters
        } else if (o.crowd > 0) {
            instances = crowd_layout(assets, o.crowd);
        } else {
            instances = default_instances(assets);
        }
        for (auto& s : instances) s.once = o.once;
        o.cfg.threads = std::max(0, o.threads);
        Server server(o.cfg, assets, instances, std::move(ports));
        std::signal(SIGINT, on_signal);
        std::signal(SIGTERM, on_signal);
        std::fputs(tls_line.c_str(), stdout);
        std::printf("progskin-server: listening on TCP %u, UDP %u, %zu instances, %.0f Hz%s\n", server.tcp_port(),
                    server.udp_port(), instances.size(), double(o.cfg.tick_rate),
                    o.no_tls ? ", plain TCP (no TLS)" : o.cfg.seal_datagrams ? ", TLS, sealed datagrams" : ", TLS");
        if (server.web_port()) {
            const char* s = o.no_tls ? "" : "s";
            std::printf("progskin-server: WebSocket endpoint ws%s://%s:%u/ws\n", s, o.cfg.bind_address.c_str(), server.web_port());
            if (!o.cfg.web_root.empty())
                std::printf("progskin-server: browser page http%s://%s:%u/ from %s\n", s, o.cfg.bind_address.c_str(),
                            server.web_port(), o.cfg.web_root.c_str());
            else
                std::printf("progskin-server: no browser page to serve (scripts/build_web.sh builds it; --web-root DIR)\n");
        }
        std::printf("progskin-server: %d tick thread%s%s\n", tick_threads(o.cfg), tick_threads(o.cfg) == 1 ? "" : "s",
                    tick_threads(o.cfg) == 1 ? " (connections on the same thread)" : " + 1 for connections");
        std::fflush(stdout);
        serve(server, o.duration, o.stats_every);
        report(server.stats());
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-server: %s\n", e.what());
        return 1;
    }
}
