// client_main.cpp — progskin-client: connects to a progskin-server, streams
// for a while and reports what it received and displayed (client.h).
#include <cmath>
#include <chrono>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <string>

#include "cli_args.h"
#include "run_client.h"
#include "errors.h"
#include "error_metric.h"
#include "progressive_skin.h"
#include "skinning.h"
#ifdef PROGSKIN_HAVE_RENDER
#include "snapshot.h"
#endif

using namespace progskin;
using namespace progskin::net;

static const char* kUsage =
    "usage: progskin-client [options]\n"
    "Receives progressive bone packets from a progskin-server and displays (CPU-skins) them.\n"
    "\n"
    "  --server HOST:PORT[,HOST:PORT...]\n"
    "                      server control address (default 127.0.0.1:7777); with a list, when\n"
    "                      the server is lost the client connects to the next one, spawns its\n"
    "                      characters again and goes on (the report's \"failover\")\n"
    "  --udp-via HOST:PORT send the frame stream through a relay (progskin-netem)\n"
    "  --max-kbps N        bandwidth cap in kbit/s, docs/metrics.md §3 (default: server maximum)\n"
    "  --view SPEC         camera:X,Y,Z[,FOV_DEG[,HEIGHT_PX]]  or  weights:W0,W1,...\n"
    "                      (importance per instance; default: all characters alike)\n"
    "  --duration S        seconds of streaming (default 10)\n"
    "  --delay-ms N        minimum display delay behind the newest frame (default 100)\n"
    "  --max-delay-ms N    the delay adapts up to N to interpolate across gaps (default 600)\n"
    "  --display-rate HZ   displayed frames per second (default 30)\n"
    "  --blend-frames N    frames to blend a bone on/off (default 8)\n"
    "  --publish ASSET     spawn a character of the server's catalogue (its file name as the\n"
    "                      server lists it, or its index: the index when two share a name)\n"
    "                      and publish its pose, driven here\n"
    "                      by a clip; repeatable. --clip and --walk apply to the last one:\n"
    "  --clip NAME         the clip it plays (name, index, list or all; default all)\n"
    "  --walk RADIUS       its root walks a circle of RADIUS bounding-box diagonals\n"
    "  --publish-rate HZ   poses per second per published character (default 30)\n"
    "  --verify            measure displayed vertices against the reference (error metric);\n"
    "                      remote published characters against what their publisher shows\n"
    "  --verify-every N    verify every N-th displayed frame, the phase moving on by one\n"
    "                      every N verified frames (default 1)\n"
    "  --warmup S          seconds of display left out of bones/error statistics while the\n"
    "                      display delay adapts (default 1; the rate counts from the start)\n"
    "  --snap-to-ticks     display each frame as it came, at its server tick (or its key\n"
    "                      sample's time, docs/protocol.md): isolates quantisation error\n"
    "  --report json|text  final summary format on stdout (default text), written on every\n"
    "                      exit: \"error\" says why a session ended early, \"server_goodbye\"\n"
    "                      whether the server ended it (a clean shutdown: \"shutdown: ...\")\n"
    "  --cache DIR         asset cache directory (default ~/.cache/progskin)\n"
    "  --tls               TLS on the control channel (default); the server's certificate\n"
    "                      must be trusted by --ca and/or --pin (or --insecure)\n"
    "  --no-tls            plain TCP (a progskin-server --no-tls)\n"
    "  --ca FILE           trust certificates signed by these CAs (PEM) for the server's name\n"
    "  --pin SHA256HEX     trust the certificate with this SHA-256 fingerprint (progskin-server\n"
    "                      prints it: \"TLS certificate sha256 ...\")\n"
    "  --insecure          accept any certificate (development only: no protection against\n"
    "                      an active attacker)\n"
    "  --name NAME         client name sent in Hello\n"
    "  --token T           access token\n"
    "  --protocol-version N  claim another protocol version (testing refusals)\n"
    "  --verbose           per-second lines on stderr\n"
    "  --snapshot-every S  every S seconds, render what is displayed to a PNG (off-screen\n"
    "                      OpenGL, GPU-skinned from the client's palettes; needs render/)\n"
    "  --snapshot-dir DIR  where the PNGs go (default snapshots/): snapshot_0000.png, ...\n"
    "  --help\n"
    "Exit codes: 0 ok, 1 runtime error (refused, unreachable, bad data, stream lost, connection\n"
    "closed), 2 bad arguments, 3 the server ended the session with a Goodbye (e.g. it shut down).\n"
    "With a --server list, a lost server that the next one replaced is not a failure (exit 0).\n";

// The server's Goodbye ended the session (a clean shutdown, a timeout, an eviction): not a crash.
static constexpr int kExitServerGoodbye = 3;

static std::vector<float> floats(const std::string& s) {
    std::vector<float> v;
    size_t p = 0;
    while (p <= s.size()) {
        size_t q = s.find(',', p);
        if (q == std::string::npos) q = s.size();
        v.push_back(float(cli::to_number(s, s.substr(p, q - p))));
        p = q + 1;
    }
    return v;
}

namespace {

// The command line: the session's options, the report format, the snapshot folder.
struct Args {
    ClientOptions opt;
    std::string report = "text";
    std::string snapshot_dir = "snapshots";
};

// --view camera:X,Y,Z[,FOV_DEG[,HEIGHT_PX]] or weights:W0,W1,...
void parse_view(const std::string& v, ViewSpec& view) {
    if (v.rfind("camera:", 0) == 0) {
        auto f = floats(v.substr(7));
        if (f.size() < 3) throw std::invalid_argument("--view camera:X,Y,Z[,FOV_DEG[,HEIGHT_PX]]");
        view.camera = {f[0], f[1], f[2]};
        view.has_camera = true;
        if (f.size() > 3) view.fov_y = f[3] * float(M_PI / 180.0);
        if (f.size() > 4) view.viewport_height = f[4];
    } else if (v.rfind("weights:", 0) == 0) {
        auto f = floats(v.substr(8));
        for (size_t k = 0; k < f.size(); ++k) view.weights.emplace_back(int(k), f[k]);
    } else {
        throw std::invalid_argument("--view camera:... or weights:...");
    }
}

// The options that name where to connect and what to publish; false when
// `a` is none of them. val() takes the option's value.
template <class Value>
bool parse_session_option(const std::string& a, Value&& val, ClientOptions& opt) {
    if (a == "--server") {
        std::vector<ServerAddress> list;
        const std::string v = val();
        try {
            list = parse_server_list(v);
        } catch (const Error& e) {
            throw cli::UsageError("--server: " + std::string(e.what()));
        }
        opt.host = list[0].host;
        opt.port = list[0].port;
        opt.failover.assign(list.begin() + 1, list.end());
    } else if (a == "--udp-via") {
        const cli::HostPort hp = cli::host_port(a, val());
        opt.udp_via_host = hp.host;
        opt.udp_via_port = hp.port;
    } else if (a == "--max-kbps") opt.max_kbps = cli::to_number(a, val());
    else if (a == "--view") {
        parse_view(val(), opt.view);
        opt.send_view = true;
    } else if (a == "--publish") {
        PublishOptions p;
        p.asset = val();
        opt.publish.push_back(p);
    } else if (a == "--clip" || a == "--walk") {
        if (opt.publish.empty()) throw std::invalid_argument(a + " applies to a --publish before it");
        if (a == "--clip") opt.publish.back().clip = val();
        else opt.publish.back().walk = cli::to_number(a, val());
        if (!(opt.publish.back().walk >= 0)) throw std::invalid_argument("--walk must be >= 0");
    } else if (a == "--publish-rate") opt.publish_rate = cli::to_number(a, val());
    else if (a == "--tls") opt.tls = true;
    else if (a == "--no-tls") opt.tls = false;
    else if (a == "--ca") opt.ca_file = val();
    else if (a == "--pin") opt.pin_sha256 = val();
    else if (a == "--insecure") opt.insecure = true;
    else if (a == "--name") opt.name = val();
    else if (a == "--token") opt.token = val();
    else if (a == "--protocol-version") opt.protocol_version = cli::to_u16(a, val());
    else return false;
    return true;
}

// The options of the display, the measurements and the output.
template <class Value>
bool parse_display_option(const std::string& a, Value&& val, Args& args) {
    ClientOptions& opt = args.opt;
    if (a == "--duration") opt.duration = cli::to_number(a, val());
    else if (a == "--delay-ms") opt.delay_ms = cli::to_number(a, val());
    else if (a == "--max-delay-ms") opt.max_delay_ms = cli::to_number(a, val());
    else if (a == "--display-rate") opt.display_rate = cli::to_number(a, val());
    else if (a == "--blend-frames") opt.blend_frames = cli::to_int(a, val());
    else if (a == "--verify") opt.verify = true;
    else if (a == "--warmup") opt.warmup = cli::to_number(a, val());
    else if (a == "--verify-every") opt.verify_every = cli::to_int(a, val());
    else if (a == "--snap-to-ticks") opt.snap_to_ticks = true;
    else if (a == "--report") {
        args.report = val();
        if (args.report != "json" && args.report != "text") throw std::invalid_argument("--report json|text");
    } else if (a == "--cache") opt.cache_dir = val();
    else if (a == "--verbose") opt.verbose = true;
    else if (a == "--snapshot-every") opt.snapshot_every = cli::to_number(a, val());
    else if (a == "--snapshot-dir") args.snapshot_dir = val();
    else return false;
    return true;
}

// Throws std::invalid_argument for a combination or value out of range.
void check_args(const ClientOptions& opt) {
    if (!opt.tls && (!opt.ca_file.empty() || !opt.pin_sha256.empty() || opt.insecure))
        throw std::invalid_argument("--ca, --pin and --insecure need TLS (not --no-tls)");
    if (opt.tls && opt.ca_file.empty() && opt.pin_sha256.empty() && !opt.insecure)
        throw std::invalid_argument("TLS (the default) needs --pin SHA256HEX (printed by progskin-server), --ca FILE, "
                                    "or --insecure (development only); --no-tls for a plain server");
    if (opt.snapshot_every < 0) throw std::invalid_argument("--snapshot-every must be positive");
#ifndef PROGSKIN_HAVE_RENDER
    if (opt.snapshot_every > 0) throw std::invalid_argument("--snapshot-every: this build has no renderer (render/)");
#endif
    if (!opt.pin_sha256.empty()) {
        int hex = 0;
        for (char ch : opt.pin_sha256)
            if (std::isxdigit(static_cast<unsigned char>(ch))) ++hex;
            else if (ch != ':') hex = -1000;
        if (hex != 64)
            throw std::invalid_argument("--pin: '" + opt.pin_sha256 + "' is not a SHA-256 fingerprint (64 hex digits, "
                                        "colons allowed; progskin-server prints it)");
    }
    auto range = [](bool ok, const char* what) {
        if (!ok) throw std::invalid_argument(what);
    };
    range(opt.duration > 0, "--duration must be > 0 seconds");
    range(opt.display_rate > 0, "--display-rate must be > 0");
    range(opt.max_kbps >= 0, "--max-kbps must be >= 0 (0: the server's maximum)");
    range(opt.max_kbps == 0 || opt.max_kbps >= 1, "--max-kbps: the wire carries whole kbit/s; give 0 (the server's maximum) or >= 1");
    range(opt.blend_frames >= 1, "--blend-frames must be >= 1");
    range(opt.verify_every >= 1, "--verify-every must be >= 1");
    range(opt.publish_rate > 0 && opt.publish_rate <= 240, "--publish-rate must be in (0, 240] Hz");
}

// Parses the command line into args; true for --help (printed). Throws
// std::invalid_argument for a bad argument.
bool parse_args(int argc, char** argv, Args& args) {
    args.opt.tls = true;  // the program's default (ClientOptions/ClientConfig default to plain)
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto val = [&]() -> std::string {
            if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
            return argv[++i];
        };
        if (a == "--help" || a == "-h") {
            std::fputs(kUsage, stdout);
            return true;
        }
        if (!parse_session_option(a, val, args.opt) && !parse_display_option(a, val, args))
            throw std::invalid_argument("unknown argument " + a);
    }
    check_args(args.opt);
    return false;
}

#ifdef PROGSKIN_HAVE_RENDER
// --snapshot-every: each DisplaySnapshot rendered to DIR/snapshot_NNNN.png.
struct SnapshotWriter {
    std::string dir;
    bool verbose = false;
    int written = 0;

    void write(const DisplaySnapshot& s) {
        std::vector<render::SnapshotCharacter> chars;
        std::vector<std::vector<glm::vec3>> morphed(s.characters.size());  // per snapshot, not per frame
        for (size_t i = 0; i < s.characters.size(); ++i) chars.push_back(character(s.characters[i], morphed[i]));
        render::SnapshotOptions so;
        char title[160];
        std::snprintf(title, sizeof title, "progskin-client  t = %.1f s  %.1f kbit/s", s.seconds, s.rate_kbps);
        so.title = title;
        char name[64];
        std::snprintf(name, sizeof name, "/snapshot_%04d.png", written);
        std::string err;
        if (render::render_snapshot(chars, dir + name, so, &err)) {
            ++written;
            if (verbose) std::fprintf(stderr, "progskin-client: wrote %s%s\n", dir.c_str(), name);
        } else {
            std::fprintf(stderr, "progskin-client: snapshot failed: %s\n", err.c_str());
        }
    }

    // One displayed character as the renderer takes it; `morphed` holds its
    // CPU-skinned positions when it has morph targets.
    static render::SnapshotCharacter character(const DisplayedCharacter& d, std::vector<glm::vec3>& morphed) {
        render::SnapshotCharacter c;
        c.character = d.character;
        c.skin = d.skin;
        c.stream = d.stream;
        c.palette = d.palette;
        if (!d.morph_weights.empty() && d.morph_weights.size() == d.character->morphs.size()) {
            // Morph targets before skinning: CPU-skinned positions instead of the palette.
            std::vector<glm::vec3> bind(d.character->vertex_count());
            morph_positions(*d.character, d.morph_weights, bind);
            morphed.resize(bind.size());
            SkinningJob job = skinning_job(*d.character, *d.skin, d.palette, morphed);
            job.positions = bind;
            job.normals = {};
            job.out_normals = {};
            if (job.validate()) {
                job.run();
                c.positions = morphed;
                c.palette = {};
            }
        }
        Mat34 place = Mat34::identity();
        place.m[3] = d.position.x, place.m[7] = d.position.y, place.m[11] = d.position.z;
        c.placement = place;
        c.bones_received = d.bones;
        c.label = "#" + std::to_string(d.instance);
        return c;
    }
};
#endif

// Download progress on stderr, at most once a second per asset (and when
// it completes, if it took a line before): a slow link can take minutes.
struct DownloadProgress {
    std::chrono::steady_clock::time_point last_line{};
    std::string last_name;
    bool printed = false;

    void update(const std::string& name, uint64_t got, uint64_t size) {
        const auto now = std::chrono::steady_clock::now();
        if (name != last_name) {
            last_name = name;
            last_line = now;
            printed = false;
        }
        if ((got < size && now - last_line >= std::chrono::seconds(1)) || (got == size && printed)) {
            std::fprintf(stderr, "progskin-client: downloading %s: %llu of %llu KiB (%.0f %%)\n", name.c_str(),
                         (unsigned long long)(got / 1024), (unsigned long long)(size / 1024), 100.0 * double(got) / double(size));
            last_line = now;
            printed = true;
        }
    }
};

}  // namespace

int main(int argc, char** argv) {
    Args args;
    try {
        if (parse_args(argc, argv, args)) return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-client: %s (see progskin-client --help)\n", e.what());
        return 2;
    }
    ClientOptions& opt = args.opt;
#ifdef PROGSKIN_HAVE_RENDER
    SnapshotWriter snapshots{args.snapshot_dir, opt.verbose};
    if (opt.snapshot_every > 0) {
        std::error_code ec;
        std::filesystem::create_directories(args.snapshot_dir, ec);
        opt.on_snapshot = [&snapshots](const DisplaySnapshot& s) { snapshots.write(s); };
    }
#endif
    DownloadProgress progress;
    opt.on_download = [&progress](const std::string& name, uint64_t got, uint64_t size) { progress.update(name, got, size); };
    if (opt.tls && opt.insecure)
        std::fprintf(stderr, "progskin-client: --insecure: the server's certificate is not verified\n");
    // The report is written on every exit (with "error" when the session ended early).
    auto write_report = [&args](const ClientReport& r) {
        if (args.report == "json") std::printf("%s\n", report_json(r).c_str());
        else if (r.error.empty()) std::fputs(report_text(r).c_str(), stdout);
        else if (r.seconds > 0) std::fprintf(stdout, "until it ended: %s", report_text(r).c_str());
        std::fflush(stdout);
    };
    try {
        write_report(run_client(opt));
        return 0;
    } catch (const ClientRunError& e) {
        std::fprintf(stderr, "progskin-client: %s\n", e.what());
        write_report(e.report);
        return e.report.server_goodbye ? kExitServerGoodbye : 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-client: %s\n", e.what());
        ClientReport r;
        r.error = e.what();
        write_report(r);
        return 1;
    }
}
