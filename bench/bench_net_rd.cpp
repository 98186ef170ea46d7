// bench_net_rd.cpp — rate-distortion of progressive streaming against two
// baselines measured in the same run, same scene, same token-bucket pacing,
// same datagram format and same client (interpolation, display delay chosen
// per method to cover its largest update gap, at most 600 ms; then again with
// the delay at most 100 ms for every method, the equal-latency table):
//   progressive: scheduler.h (importance-weighted error removed per byte,
//                deep bones refreshed less often than shallow ones);
//   all_bones:   every update carries all bones of a character; characters
//                are updated round-robin as the budget allows (fewer updates
//                per second when the budget is short). Every method's token
//                bucket holds at least one whole character (this one's
//                smallest useful datagram), so all three are paced alike;
//   leaf_lod:    a static skeleton LOD: the leaf-pruning skin (deepest bones
//                dropped first, plain copy-down), the largest k that fits
//                every character every tick (k = 1 round-robin below that).
// Error: displayed vertices vs the full-detail reference at the display time
// (docs/metrics.md §2), RMS and max over all characters and displayed ticks, % of
// each character's rest diagonal. Rate: docs/metrics.md §3 (payload + 28 per datagram).
//
// usage: bench_net_rd [--asset FILE...] [--clip SPEC] [--crowd N] [--fair-floor F] [--key-samples] [benchmark flags]
//   --asset: characters (default assets/Fox.glb assets/CesiumMan.glb; FILE#N
//   for character N); --clip: the clip selection every asset plays (default:
//   each asset's default training set, one instance per clip group in the
//   first scene); --crowd: instances of the second scene (default 24);
//   --key-samples: the server samples linearly keyed clips at their keys
//   (progskin-server --key-samples).
#include <array>
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <string>

#include "client_palette.h"
#include "client_stream.h"
#include "collapse.h"
#include "error_metric.h"
#include "scene.h"
#include "server_core.h"
#include "wire.h"
#include "../tests/net_test_support.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::apply_frame;
using progskin::net::testing::client_asset;

namespace {

using Assets = std::vector<std::shared_ptr<ServerAsset>>;

// The command line's scene (see the usage above).
struct Options {
    std::vector<std::string> assets = {std::string(PROGSKIN_ASSETS) + "/Fox.glb",
                                       std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb"};
    std::string clip;  // empty: each asset's default training set
    int crowd = 24;
    double fair_floor = ServerConfig{}.fair_floor;  // --fair-floor: the server's per-character floor
    bool key_samples = false;                       // --key-samples: ServerConfig::key_samples
};
Options g_options;

// The assets as the server loads them (check first, then build), with --clip applied.
const Assets& progressive_assets() {
    static Assets a = [] {
        AssetOptions o;
        std::vector<PendingAsset> pending;
        const std::vector<std::string> problems = check_server_assets(g_options.assets, o, pending);
        if (!problems.empty()) {
            for (const std::string& p : problems) std::fprintf(stderr, "bench_net_rd: %s\n", p.c_str());
            std::exit(1);
        }
        Assets out;
        for (const PendingAsset& p : pending) {
            auto x = build_server_asset(p, o);
            if (!g_options.clip.empty()) {
                x->selections = {select_clips(x->character, g_options.clip)};
                finish_server_asset(*x);
            }
            out.push_back(x);
        }
        return out;
    }();
    return a;
}

const Assets& leaf_assets() {
    static Assets a = [] {
        Assets out;
        for (const auto& p : progressive_assets()) {
            auto x = std::make_shared<ServerAsset>(*p);
            BuildOptions o;
            o.strategy = Strategy::LeafPrune;
            o.fit_corrections = false;
            x->skin = build_progressive_skin(x->character, sample_frames(x->character, x->selections, 30.0), o);
            finish_server_asset(*x);
            out.push_back(x);
        }
        return out;
    }();
    return a;
}


enum class Method { Progressive, AllBones, LeafLod };

struct Result {
    double rate_kbps = 0, bones = 0, rms = 0, max = 0, delay_ms = 0;
    double header_pct = 0;  // share of the wire bytes in chunk structs and bone masks
    std::map<std::string, double> character_rms;   // per character (label: asset, clip group in the first scene)
    std::map<std::string, double> character_kbps;  // its chunks' bytes (header and records), per instance
};

// The label a character's error is reported under: its asset and clip group
// in the first scene (one instance each), its asset in the crowd.
std::string character_label(const Assets& assets, const InstanceSpec& s, bool crowd) {
    const auto& a = *assets[size_t(s.asset)];
    if (crowd || a.selections.size() < 2) return a.name;
    return a.name + " group " + std::to_string(s.selection);
}

// max_delay: the display delay in ticks at most (18 = 600 ms; 3 = 100 ms for
// the equal-latency table).
// The baselines' picks (Method::AllBones, Method::LeafLod): round-robin,
// fixed k per character (leaf_k for the leaf LOD), every morph weight, as
// many characters as fit the budget; `rr` is the next character's turn.
void baseline_picks(Method m, const Assets& assets, const std::vector<InstanceSpec>& specs, int leaf_k, const EncodedFrame& f,
                    const RecordPlan& plan, size_t budget, size_t& rr, std::vector<Pick>& picks) {
    picks.clear();
    const size_t n = specs.size();
    size_t payload = 0;
    for (size_t c = 0; c < n; ++c) {
        size_t i = (rr + c) % n;
        const auto& a = *assets[specs[i].asset];
        int k = m == Method::AllBones ? a.bone_count() : std::min(leaf_k, a.bone_count());
        // Baselines send every morph weight with the bones (no sparse scheduling).
        std::array<uint64_t, 4> morphs{};
        const auto q = f.morphs(int(i));
        for (size_t w = 0; w < q.size(); ++w)
            if (q[w] != kNoWeight) morphs[w / 64] |= uint64_t(1) << (w % 64);
        size_t b = WireCost::header(a.bone_count()) + (plan.bits(f, int(i), 0, k) + 7) / 8 + morph_block_bytes(morphs);
        if (WireCost::wire(payload + b) > budget) break;
        payload += b;
        picks.push_back({int(i), k});
        picks.back().morphs = morphs;
    }
    rr = (rr + picks.size()) % n;
}

// max_delay: the display delay in ticks at most (18 = 600 ms; 3 = 100 ms for
// the equal-latency table).
// fixed_k: the leaf LOD's k (0: the largest whose stream fits 94 % of the
// cap, found by short runs of each k); rate_only: only the rate is measured.
Result simulate(Method m, const std::vector<InstanceSpec>& specs, double cap_kbps, int ticks, int warm, int max_delay = 18,
                bool crowd = false, int fixed_k = 0, bool rate_only = false) {
    const Assets& assets = m == Method::LeafLod ? leaf_assets() : progressive_assets();
    // The server's session core without sockets: the same tick (importance,
    // selection or a baseline's picks, packing, rate), at a fixed rate.
    ServerConfig config;
    config.fair_floor = g_options.fair_floor;
    config.key_samples = g_options.key_samples;
    ServerCore core(config, assets, specs);
    auto client = ClientStream::detached(core, 1, cap_kbps);
    // The all-bones baseline needs room for one whole character per datagram:
    // the baselines get that bucket depth. The progressive stream is paced as
    // progskin-server paces it (its own depth). Every bucket keeps any one
    // second's wire bytes within 1.04 x the cap (RateController).
    double min_depth = 0;
    for (const auto& a : progressive_assets())
        min_depth = std::max(min_depth, double(WireCost::wire(WireCost::header(a->bone_count()) + size_t(a->bone_count()) * a->format.size())));
    client->rate() = RateController(cap_kbps, cap_kbps, m == Method::Progressive ? 0.0 : min_depth);
    const size_t n = specs.size();
    // Static LOD: the largest k with every character every tick within the
    // rate, as its records really cost (standalone or predicted).
    int leaf_k = fixed_k > 0 ? fixed_k : 1;
    if (m == Method::LeafLod && fixed_k == 0) {
        int kmax = 255;
        for (const auto& a : assets) kmax = std::min(kmax, a->bone_count());
        for (int k = kmax; k >= 1; --k)
            if (simulate(m, specs, 1e6, 60, 20, max_delay, crowd, k, true).rate_kbps <= 0.94 * cap_kbps) {
                leaf_k = k;
                break;
            }
    }
    size_t rr = 0;
    if (m != Method::Progressive)
        client->set_selector([&](const EncodedFrame& f, size_t budget, std::vector<Pick>& picks) {
            baseline_picks(m, assets, specs, leaf_k, f, client->plan(), budget, rr, picks);
        });
    std::vector<std::vector<std::vector<uint8_t>>> log(size_t(ticks) + 1);
    // The display delay covers, as the client's does (client.cpp), the largest
    // gap after warm-up between updates of an instance and between refreshes
    // of one bone (at most HOLD_TICKS: a longer one is a bone shown again).
    std::vector<std::vector<int>> bone_tick(n);
    std::vector<int> instance_tick(n, 0);
    for (size_t i = 0; i < n; ++i) bone_tick[i].assign(size_t(assets[size_t(specs[i].asset)]->bone_count()), 0);
    int gap = 1;
    size_t wire_total = 0;
    std::vector<double> inst_bytes(n, 0.0);
    std::vector<int> header_tick(n, -1);
    DatagramCollector sink;
    for (int t = 1; t <= ticks; ++t) {
        const EncodedFrame& f = core.encoder().encode(uint32_t(t));
        sink.sent.clear();
        const TickResult r = client->tick(f, t / 30.0, 1.0 / 30.0, sink);
        // A lossless client acknowledging each datagram before the next tick
        // (a round trip under 33 ms, as on loopback): baselines one tick old.
        FrameDatagram last;
        if (!sink.sent.empty() && read_frame_datagram(sink.sent.back().bytes, last)) client->acknowledge(last.seq, ~0u);
        for (auto& d : sink.sent) log[size_t(t)].push_back(std::move(d.bytes));
        if (t > warm) wire_total += r.wire_bytes;
        for (const Pick& p : client->picks()) {
            const auto& pa = *assets[size_t(specs[size_t(p.instance)].asset)];
            // One chunk header per instance and tick, however many ranges
            // of it the tick carries (the packer's chunk and bone mask).
            if (t > warm) {
                const bool first = header_tick[size_t(p.instance)] != t;
                header_tick[size_t(p.instance)] = t;
                inst_bytes[size_t(p.instance)] += double((first ? WireCost::header(pa.bone_count()) : 0) +
                                                         (client->plan().bits(f, p.instance, p.first, std::max(p.first, p.k)) + 7) / 8);
            }
            int& last_update = instance_tick[size_t(p.instance)];
            if (t > warm && last_update > 0) gap = std::max(gap, t - last_update);
            last_update = t;
            for (int b = p.first; b < p.k; ++b) {
                int& last = bone_tick[size_t(p.instance)][size_t(b)];
                if (t > warm && last > 0 && t - last <= HOLD_TICKS) gap = std::max(gap, t - last);
                last = t;
            }
        }
    }
    if (rate_only) {
        Result r;
        r.rate_kbps = double(wire_total) * 8 / 1000 / (double(ticks - warm) / 30.0);
        return r;
    }
    // Display delay covering the largest gap after warm-up (as the client adapts it).
    const int delay = std::min(max_delay, gap + 1);

    std::vector<std::unique_ptr<InstanceView>> views;
    for (const auto& s : specs) {
        ClipInfo ci;
        ci.selection = assets[s.asset]->selections[s.selection];
        ci.time_offset = s.time_offset;
        ci.speed = s.speed;
        views.push_back(std::make_unique<InstanceView>(client_asset(*assets[s.asset]), ci, 8));
    }
    double sq = 0, cnt = 0, mx = 0, bones = 0, frames = 0;
    std::vector<double> inst_sq(n, 0.0), inst_cnt(n, 0.0);
    size_t header_bytes = 0;
    std::vector<glm::vec3> shown, ref;
    for (int t = 1; t <= ticks; ++t) {
        for (const auto& d : log[size_t(t)]) {
            FrameDatagram fr;
            if (!read_frame_datagram(d, fr)) continue;
            const size_t records = apply_frame(fr, views).record_bits / 8;  // the heads, blocks and padding: header
            if (t > warm) header_bytes += fr.payload.size() - records;
        }
        const double d = double(t - delay);
        if (t - delay <= warm) continue;
        for (size_t i = 0; i < n; ++i) {
            InstanceView& v = *views[i];
            if (!v.buffer().covers(d) || !v.display(d)) continue;
            bones += v.target_bones();
            frames += 1;
            // Every displayed tick is verified: a stream that sends every
            // second tick, verified every other tick, would be measured only
            // at its sent ticks (or only between them), by the parity of its
            // sends (docs/performance.md "Every displayed tick verified").
            v.skin(shown);
            v.reference(v.clip().clip_time(d, 30.0), ref);
            const double s = 100.0 / v.asset().diagonal;
            for (size_t j = 0; j < shown.size(); ++j) {
                double e = glm::length(shown[j] - ref[j]) * s;
                sq += e * e;
                inst_sq[i] += e * e;
                mx = std::max(mx, e);
            }
            cnt += double(shown.size());
            inst_cnt[i] += double(shown.size());
        }
    }
    Result r;
    r.rate_kbps = double(wire_total) * 8 / 1000 / (double(ticks - warm) / 30.0);
    r.bones = frames > 0 ? bones / frames : 0;
    r.rms = cnt > 0 ? std::sqrt(sq / cnt) : 0;
    r.max = mx;
    r.delay_ms = delay * 1000.0 / 30.0;
    r.header_pct = wire_total ? 100.0 * double(header_bytes) / double(wire_total) : 0;
    std::map<std::string, std::array<double, 4>> by_label;  // squared error, vertices, bytes, instances
    for (size_t i = 0; i < n; ++i) {
        auto& v = by_label[character_label(progressive_assets(), specs[i], crowd)];
        v[0] += inst_sq[i];
        v[1] += inst_cnt[i];
        v[2] += inst_bytes[i];
        v[3] += 1;
    }
    for (const auto& [label, v] : by_label) {
        r.character_rms[label] = v[1] > 0 ? std::sqrt(v[0] / v[1]) : 0;
        r.character_kbps[label] = v[2] * 8 / 1000 / (double(ticks - warm) / 30.0) / v[3];
    }
    return r;
}

// Per (scene, cap): the three methods, then the three with the display delay
// at most 100 ms.
std::map<std::pair<int, int>, std::array<Result, 6>>& table() {
    static std::map<std::pair<int, int>, std::array<Result, 6>> t;
    return t;
}

// Per character: progressive RMS over the better baseline's RMS for that
// character (the static levels it could have been given); the worst of them.
double character_ratio(const Result* r, const std::string& label) {
    const double best = std::min(r[1].character_rms.at(label), r[2].character_rms.at(label));
    return r[0].character_rms.at(label) / std::max(1e-9, best);
}
double worst_character_ratio(const Result* r) {
    double worst = 0;
    for (const auto& [label, rms] : r[0].character_rms) worst = std::max(worst, character_ratio(r, label));
    return worst;
}

void BM_RateDistortion(benchmark::State& st) {
    const int scene = int(st.range(0)), cap = int(st.range(1));
    std::vector<InstanceSpec> specs;
    if (scene == 0) {
        for (size_t a = 0; a < progressive_assets().size(); ++a)
            for (size_t s = 0; s < progressive_assets()[a]->selections.size(); ++s) {
                InstanceSpec i;
                i.asset = int(a);
                i.selection = int(s);
                specs.push_back(i);
            }
    } else {
        specs = crowd_layout(progressive_assets(), g_options.crowd);
    }
    std::array<Result, 6> r;
    for (auto _ : st) {
        const bool crowd = scene != 0;
        r[0] = simulate(Method::Progressive, specs, cap, 330, 30, 18, crowd);
        r[1] = simulate(Method::AllBones, specs, cap, 330, 30, 18, crowd);
        r[2] = simulate(Method::LeafLod, specs, cap, 330, 30, 18, crowd);
        r[3] = simulate(Method::Progressive, specs, cap, 330, 30, 3, crowd);
        r[4] = simulate(Method::AllBones, specs, cap, 330, 30, 3, crowd);
        r[5] = simulate(Method::LeafLod, specs, cap, 330, 30, 3, crowd);
    }
    table()[{scene, cap}] = r;
    st.counters["rate_kbps"] = r[0].rate_kbps;
    st.counters["prog_rms_pct"] = r[0].rms;
    st.counters["all_bones_rms_pct"] = r[1].rms;
    st.counters["leaf_lod_rms_pct"] = r[2].rms;
    st.counters["prog_vs_best_baseline"] = r[0].rms / std::max(1e-9, std::min(r[1].rms, r[2].rms));
    st.counters["prog_vs_best_baseline_100ms"] = r[3].rms / std::max(1e-9, std::min(r[4].rms, r[5].rms));
    st.counters["worst_character_vs_best_baseline"] = worst_character_ratio(r.data());
    st.SetLabel(scene == 0 ? "one per asset and clip group (" + std::to_string(specs.size()) + ")"
                           : "crowd of " + std::to_string(specs.size()));
}
BENCHMARK(BM_RateDistortion)
    ->ArgsProduct({{0}, {16, 32, 64, 128, 256}})
    ->ArgsProduct({{1}, {64, 256, 1000, 2000}})
    ->Iterations(1)
    ->Unit(benchmark::kSecond);

}  // namespace

// Parses --asset/--clip/--crowd (what benchmark::Initialize left); false on a bad command line.
bool parse_options(int argc, char** argv) {
    bool assets_given = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--asset" && i + 1 < argc) {
            if (!assets_given) g_options.assets.clear();
            assets_given = true;
            g_options.assets.push_back(argv[++i]);
            while (i + 1 < argc && argv[i + 1][0] != '-') g_options.assets.push_back(argv[++i]);
        } else if (a == "--clip" && i + 1 < argc) {
            g_options.clip = argv[++i];
        } else if (a == "--fair-floor" && i + 1 < argc) {
            char* end = nullptr;
            const double f = std::strtod(argv[++i], &end);
            if (*end || !(f >= 0 && f <= 1)) {
                std::fprintf(stderr, "bench_net_rd: --fair-floor needs a number in [0, 1] (got %s)\n", argv[i]);
                return false;
            }
            g_options.fair_floor = f;
        } else if (a == "--key-samples") {
            g_options.key_samples = true;
        } else if (a == "--crowd" && i + 1 < argc) {
            char* end = nullptr;
            const long n = std::strtol(argv[++i], &end, 10);
            if (*end || n < 1 || n > 100000) {
                std::fprintf(stderr, "bench_net_rd: --crowd needs a whole number in 1..100000 (got %s)\n", argv[i]);
                return false;
            }
            g_options.crowd = int(n);
        } else {
            std::fprintf(stderr, "bench_net_rd: unknown or incomplete argument %s\n", a.c_str());
            return false;
        }
    }
    return true;
}

int main(int argc, char** argv) {
    for (int i = 1; i < argc; ++i)
        if (!std::strcmp(argv[i], "--help")) {
            std::printf("usage: bench_net_rd [--asset FILE...] [--clip SPEC] [--crowd N] [--fair-floor F] [--key-samples] [--benchmark_* flags]\n"
                        "  --asset  characters (default assets/Fox.glb assets/CesiumMan.glb; FILE#N: character N)\n"
                        "  --clip   clip selection every asset plays (default: each asset's clip groups)\n"
                        "  --crowd  instances of the crowd scene (default 24)\n"
                        "  --fair-floor  the scheduler's per-character floor, 0..1 (default: the server's)\n"
                        "  --key-samples  linearly keyed clips sampled at their keys (progskin-server --key-samples)\n");
            return 0;
        }
    benchmark::Initialize(&argc, argv);
    if (!parse_options(argc, argv)) return 2;
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    if (table().empty()) return 0;
    const char* names[3] = {"progressive", "all bones, fewer updates", "static leaf LOD"};
    size_t groups = 0;
    for (const auto& a : progressive_assets()) groups += a->selections.size();
    const bool defaults = g_options.assets == Options{}.assets && g_options.clip.empty();
    const std::string scene_name[2] = {(defaults ? "default (" : "assets (") + std::to_string(groups) + ")",
                                       "crowd (" + std::to_string(g_options.crowd) + ")"};
    for (int part = 0; part < 2; ++part) {
        std::printf(part == 0 ? "\nDisplay delay: each method's largest update gap (at most 600 ms)\n"
                              : "\nEqual latency: display delay at most 100 ms for every method\n");
        std::printf("\n| scene | cap kbit/s | method | rate kbit/s | bones/char | RMS %% diag | max %% diag | delay ms | chunk headers %% of bytes |\n");
        std::printf("|---|---|---|---|---|---|---|---|---|\n");
        for (const auto& [key, rr] : table()) {
            const Result* r = rr.data() + 3 * part;
            for (int m = 0; m < 3; ++m)
                std::printf("| %s | %d | %s | %.1f | %.1f | %.4f | %.3f | %.0f | %.1f |\n", scene_name[key.first].c_str(),
                            key.second, names[m], r[m].rate_kbps, r[m].bones, r[m].rms, r[m].max, r[m].delay_ms, r[m].header_pct);
            std::printf("| | | progressive / best baseline RMS | | | **%.2f** | | | |\n",
                        r[0].rms / std::max(1e-9, std::min(r[1].rms, r[2].rms)));
        }
    }
    // Per character: the scheduler against the static choices it had (issue:
    // never worse than a baseline for any character at any cap).
    std::printf("\nPer character (display delay as in the first table): RMS %% diag, progressive / better baseline\n");
    std::printf("\n| scene | cap kbit/s | character | progressive | all bones | static leaf LOD | ratio | kbit/s per instance: progressive / all bones / leaf |\n|---|---|---|---|---|---|---|---|\n");
    int worse = 0;
    for (const auto& [key, rr] : table())
        for (const auto& [label, rms] : rr[0].character_rms) {
            const double ratio = character_ratio(rr.data(), label);
            worse += ratio > 1.0;
            std::printf("| %s | %d | %s | %.4f | %.4f | %.4f | %s%.2f%s | %.1f / %.1f / %.1f |\n", scene_name[key.first].c_str(),
                        key.second, label.c_str(), rms, rr[1].character_rms.at(label), rr[2].character_rms.at(label),
                        ratio > 1.0 ? "**" : "", ratio, ratio > 1.0 ? "** worse" : "", rr[0].character_kbps.at(label),
                        rr[1].character_kbps.at(label), rr[2].character_kbps.at(label));
        }
    std::printf("\n%d character-cap rows where progressive is worse than a baseline\n", worse);
    return 0;
}
