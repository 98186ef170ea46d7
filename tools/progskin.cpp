// progskin — the offline tool: build, inspect and pose progressive skins.
//
// Exit codes: 0 success, 1 bad input or failed work (message on stderr),
// 2 bad command line.
#include <chrono>
#include <cstdio>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <unistd.h>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "animation.h"
#include "cli_args.h"
#include "errors.h"
#include "error_metric.h"
#include "collapse.h"
#include "range_of_motion.h"
#include "cost_tables.h"
#include "gltf_export.h"
#include "gltf_import.h"
#include "plot.h"
#include "progressive_asset.h"
#include "progressive_skin.h"
#include "representable.h"
#ifdef PROGSKIN_HAVE_NET
#include "bone_record.h"
#include "crypto.h"
#endif
#include "scratch_build.h"
#include "self_contained.h"
#include "vertex_animation.h"

using namespace progskin;
using nlohmann::json;
using progskin::cli::Args;
using progskin::cli::parse;
using progskin::cli::to_int;
using progskin::cli::to_number;
using progskin::cli::UsageError;

#ifdef PROGSKIN_HAVE_RENDER
int render_command(int argc, char** argv);  // render/render_command.cpp
#endif

namespace {

const char* kUsage = R"(progskin — progressive skinning, offline tool

usage:
  progskin build IN -o OUT.glb [--strategy auto|rate|reorder|flatten|hierarchy|leaf_prune] [--clip SPEC]
                 [--fps 30] [--character N] [--plain-copy] [--quiet]
      Build a progressive skin by collapsing IN's skin and write a standard
      glTF 2.0 file (joints in progressive order, weights reordered, animations
      kept, PROGSKIN_progressive_skin extension on the skin). OUT ending in
      .gltf is written as JSON with embedded buffers, anything else as .glb.
      OUT is self-contained: images IN keeps in files beside it are embedded
      (a missing or refused one is an error, before anything is built).
      --strategy rate (default; auto in a build without the streaming library)
      builds reorder, flatten and hierarchy (every bone after its artist
      parent: cheaper parent-relative records) and keeps the one that removes
      the most error per bit of the stream's records (docs/algorithms.md
      "Choosing the strategy"; three times the time), as progskin-server
      builds a plain file. --strategy auto builds reorder and flatten and
      keeps the one of lower mean RMS error over k = 1..B, saying which.
  progskin build --from-vertices IN -o OUT.glb [--bones N] [--max-error PERCENT]
                 [--rest-frame F] [--similarity] [--method auto|collapse|hybrid|top-down]
                 [--clip SPEC] [--fps 30] [--quiet]
      Build a progressive skin from scratch for a vertex animation: IN is a
      glTF with morph-target animation, a PC2 point cache (.pc2), or any
      skinned glTF evaluated as vertices (its skeleton then forgotten; --clip
      as above). Up to N bones (default 16), fewer once the RMS error is at
      most PERCENT % of the bounding-box diagonal. --method collapse fits a
      full-detail skin (motion clustering, then alternating rigid transforms,
      weights and bind positions) and orders its bones by greedy collapse with
      least-squares corrections; top-down adds bones one at a time; hybrid
      adds bones one at a time, each the best of a region-grown bone and the
      collapse's full-detail bones; auto (default) builds collapse and hybrid
      and keeps the lower mean log error over k. Bind
      pose: per-vertex mean over frames, or frame F. --similarity lets bones
      scale uniformly. The output plays in any glTF viewer (rigid TRS joint
      animation) and carries the error table (strategy "scratch").
  progskin inspect FILE [--json] [--clip SPEC] [--fps 30] [--character N] [--plot OUT.svg]
      Lists every character of FILE (one per skeleton); for character N
      (default 0): joints, vertices, clips, morph targets and the error table k -> RMS / max error (units
      and % of the rest bounding-box diagonal) and mean distinct influences per
      vertex. For a plain glTF it builds and compares the strategies reorder,
      flatten, hierarchy and leaf_prune (naive baseline: deepest bones first,
      plain copy). For a progressive file it lists the table stored in it,
      or with --clip the stored skin measured on those clips.
      --plot draws error against bones per strategy with gnuplot (.svg/.png/.pdf).
  progskin pose FILE --time T [--clip SPEC] [--bones K|all] [--character N]
                [--max-influences M] [--json | -o OUT.bin]
      World-space skinned vertex positions at time T with K bones active, in
      glTF order (mesh nodes by node index, then primitives, then accessor
      order). -o writes little-endian float32 x,y,z per vertex.
  progskin render FILE -o OUT.png [--clip SPEC] [--time T] [--bones 1,2,4,all] [--heatmap]
      One image, a panel per LOD, rendered off screen with OpenGL (GPU skinning);
      see progskin render --help and docs/rendering.md.
  progskin token keygen
      A new Ed25519 key pair for connect tokens: prints "public HEX" (give it
      to progskin-server --token-public-key) and "secret HEX" (keep it on the
      backend that issues tokens).
  progskin token issue --secret-key HEX --client-id N --server HOST:PORT [--seconds 30]
      A connect token for one client and server, valid SECONDS from now, for
      progskin-client --token (docs/protocol.md "Security").

clip SPEC: a clip name, an index, a comma-separated list, or "all" (played
together). Default for build/inspect: "auto" (all clips together when they
animate disjoint nodes, as CesiumMan's 19 one-joint clips; else each clip on
its own, frames concatenated). Default for pose: "auto" as well. Files whose
clips do not move the skeleton train on range-of-motion poses (every joint
turning smoothly, up to 30 degrees); build/inspect --clip range-of-motion
trains on them whatever the clips (an avatar whose clips say little of how a
game will drive it).

exit codes: 0 ok, 1 bad input or failure, 2 bad command line
)";

std::vector<ClipSelection> training_set(const Character& c, const std::string& spec) {
    if (spec.empty() || spec == "auto") return default_training_set(c);
    return {select_clips(c, spec)};
}

// The frames a build or inspect trains on for --clip SPEC: "range-of-motion"
// (range_of_motion.h, whatever the clips), else the clips of SPEC, or the
// range of motion where they do not move the skeleton. *rom: which.
FrameSet spec_frames(const Character& c, const std::string& spec, double fps, bool* rom) {
    if (spec == "range-of-motion") {
        *rom = true;
        return range_of_motion_frames(c, fps);
    }
    return training_frames(c, training_set(c, spec), fps, rom);
}

json table_json(const std::vector<LodError>& t) {
    json a = json::array();
    for (size_t i = 0; i < t.size(); ++i) {
        const LodError& e = t[i];
        json row = {{"bones", e.bones}, {"rms", e.rms},         {"max", e.max},
                    {"rms_pct", e.rms_pct}, {"max_pct", e.max_pct}, {"influences", e.influences}};
        if (e.distortion_pct >= 0) row["distortion_pct"] = e.distortion_pct;
        a.push_back(row);
    }
    return a;
}

void print_table(const std::string& title, const std::vector<LodError>& t, double diag) {
    std::printf("\n%s (error against the full skin; diagonal %.4g)\n", title.c_str(), diag);
    std::printf("  %5s  %12s  %9s  %12s  %9s  %10s\n", "bones", "rms", "rms %", "max", "max %", "influences");
    for (const LodError& e : t)
        std::printf("  %5d  %12.6g  %9.4f  %12.6g  %9.4f  %10.3f\n", e.bones, e.rms, e.rms_pct, e.max, e.max_pct,
                    e.influences);
}

// Progress of a build on stderr: on a terminal one line rewritten (\r) at
// most every 250 ms; in a log (stderr not a terminal) one line every 2 s.
// The estimate weighs each collapse by the bones left in its round, squared
// (a collapse with r bones left tries r candidates, each refitted over the
// vertices they move), and counts from the first step reported (the set-up
// before it says nothing of the rest); none before two steps and 1 s.
class Progress {
public:
    Progress(bool quiet, std::string what, int rounds = 1)
        : quiet_(quiet), tty_(::isatty(STDERR_FILENO) == 1), rounds_(std::max(1, rounds)), what_(std::move(what)) {}
    void operator()(int step, int total) {
        if (quiet_ || total <= 0) return;
        const auto now = std::chrono::steady_clock::now();
        if (first_step_ < 0) {
            first_step_ = step;
            first_ = now;
        }
        if (step < total && now - last_ < std::chrono::milliseconds(tty_ ? 250 : 2000)) return;
        last_ = now;
        const double el = std::chrono::duration<double>(now - start_).count();
        const double since = std::chrono::duration<double>(now - first_).count();
        const double done = work(first_step_, step, total);
        char eta[64] = "";
        if (step < total && step - first_step_ >= 2 && since >= 1.0 && done > 0)
            std::snprintf(eta, sizeof eta, ", about %.1f s left", since * work(step, total, total) / done);
        std::fprintf(stderr, tty_ ? "\r%s: %d/%d collapses, %.1f s%s      " : "%s: %d/%d collapses, %.1f s%s\n",
                     what_.c_str(), step, total, el, eta);
        if (tty_ && step >= total) std::fprintf(stderr, "\n");
    }

private:
    // The weight of steps [from, to) of `total` (rounds_ builds one after another).
    double work(int from, int to, int total) const {
        const int n = std::max(1, total / rounds_);
        double w = 0;
        for (int i = from; i < to; ++i) {
            const double r = double(n - i % n + 1);
            w += r * r;
        }
        return w;
    }
    bool quiet_, tty_;
    int rounds_;
    std::string what_;
    int first_step_ = -1;
    std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now(), first_{}, last_{};
};

ProgressiveSkin build_with_progress(const Character& c, const FrameSet& frames, Strategy st, bool fit, bool quiet) {
    BuildOptions opt;
    opt.strategy = st;
    opt.fit_corrections = fit;
    Progress p(quiet, std::string("build ") + strategy_name(st));
    opt.progress = [&p](int s, int t) { p(s, t); };
    return build_progressive_skin(c, frames, opt);
}

// The character with what its bone records cannot carry added to its notes
// (common/representable.h): build and inspect print the notes.
Character with_stream_notes(Character c) {
    for (std::string& n : representability_notes(c)) c.notes.push_back(std::move(n));
    return c;
}

// --strategy auto: reorder and flatten, the lower mean RMS kept; --strategy
// rate: reorder, flatten and hierarchy, the lowest rate-distortion area
// against the stream's record bits kept (offline/collapse.h).
ProgressiveSkin build_best_with_progress(const Character& c, const FrameSet& frames, bool fit, bool quiet, bool by_rate,
                                         StrategyChoice& chosen) {
    BuildOptions opt;
    opt.fit_corrections = fit;
    Progress p(quiet, by_rate ? "build reorder, flatten, then hierarchy" : "build reorder, then flatten", by_rate ? 3 : 2);
    opt.progress = [&p](int s, int t) { p(s, t); };
#ifdef PROGSKIN_HAVE_NET
    if (by_rate) opt.bone_bits = [&](const ProgressiveSkin& s) { return progskin::net::record_bits_per_bone(c, s, frames); };
#else
    if (by_rate) throw UsageError("--strategy rate needs the wire library (a build with PROGSKIN_BUILD_NET)");
#endif
    return build_best_progressive_skin(c, frames, opt, &chosen);
}

// The server's tables of a built skin (offline/cost_tables.h), stored in the
// extension so that progskin-server reads instead of computing them.
json server_tables(const Character& c, const ProgressiveSkin& s) {
    std::vector<ClipSelection> selections = default_training_set(c);
    if (selections.empty()) selections.push_back(ClipSelection{});
    json extra;
    extra["server"] = asset_tables_json(compute_asset_tables(c, s, selections), s.bone_count(), selections.size());
    return extra;
}

// Throws UsageError unless `out` can be written, before any work is done:
// its folder exists and is writable, and `out` is not a folder.
void check_output_path(const std::string& out) {
    namespace fs = std::filesystem;
    const fs::path p(out);
    const fs::path dir = p.parent_path().empty() ? fs::path(".") : p.parent_path();
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) throw UsageError("-o " + out + ": the folder " + dir.string() + " does not exist");
    if (fs::is_directory(p, ec)) throw UsageError("-o " + out + ": is a folder");
    if (::access(dir.c_str(), W_OK) != 0) throw UsageError("-o " + out + ": the folder " + dir.string() + " is not writable");
}

int character_arg(const Args& a) { return a.has("--character") ? to_int("--character", a.get("--character")) : 0; }

// What to run for a file without a skin (the server's message says the same).
std::string from_vertices_hint(const std::string& path) {
    return "build a progressive skin from its vertex animation with `progskin build --from-vertices " + path +
           " -o OUT.glb [--bones N]`";
}

// import_character, with the --from-vertices hint on a file that has no skin.
Character import_or_hint(const std::string& path, int character) {
    try {
        return import_character(path, character);
    } catch (const Error& e) {
        const std::string what = e.what();
        if (what.find(": no skin") == std::string::npos) throw;
        throw Error(what + ": " + from_vertices_hint(path));
    }
}

int cmd_build_from_vertices(const Args& a) {
    if (a.positional.size() != 1) throw UsageError("build --from-vertices needs exactly one input file");
    if (!a.has("-o")) throw UsageError("build needs -o OUT.glb");
    check_output_path(a.get("-o"));
    if (a.has("--strategy") || a.has("--plain-copy")) throw UsageError("--strategy/--plain-copy do not apply to --from-vertices");
    VertexAnimationOptions vo;
    vo.fps = a.has("--fps") ? to_number("--fps", a.get("--fps")) : 30.0;
    if (vo.fps <= 0 || vo.fps > 1000) throw UsageError("--fps must be in (0, 1000]");
    vo.clip = a.get("--clip", "auto");
    vo.character = character_arg(a);
    ScratchOptions so;
    so.max_bones = a.has("--bones") ? to_int("--bones", a.get("--bones")) : 16;
    if (so.max_bones < 1 || so.max_bones > 1024) throw UsageError("--bones must be in 1..1024");
    if (a.has("--max-error")) {
        so.max_error_pct = to_number("--max-error", a.get("--max-error"));
        if (so.max_error_pct < 0) throw UsageError("--max-error must be >= 0");
        if (!a.has("--bones")) so.max_bones = 256;
    }
    so.rest_frame = a.has("--rest-frame") ? to_int("--rest-frame", a.get("--rest-frame")) : -1;
    so.similarity = a.has("--similarity");
    if (a.has("--method")) {
        const std::string m = a.get("--method");
        if (m == "auto") so.method = ScratchMethod::Auto;
        else if (m == "collapse") so.method = ScratchMethod::Collapse;
        else if (m == "top-down" || m == "topdown") so.method = ScratchMethod::TopDown;
        else if (m == "hybrid") so.method = ScratchMethod::Hybrid;
        else throw UsageError("--method must be auto, collapse, hybrid or top-down");
    }
    const bool quiet = a.has("--quiet");
    const VertexAnimation anim = load_vertex_animation(a.positional[0], vo);
    if (!quiet)
        std::fprintf(stderr, "%s: %zu vertices, %zu frames at %g fps\n", a.positional[0].c_str(), anim.vertex_count,
                     anim.frame_count, anim.fps);
    const auto start = std::chrono::steady_clock::now();
    auto last = start - std::chrono::seconds(1);
    so.progress = [&](int step, int total) {
        if (quiet || total <= 0) return;
        const auto now = std::chrono::steady_clock::now();
        if (step < total && now - last < std::chrono::milliseconds(250)) return;
        last = now;
        const double el = std::chrono::duration<double>(now - start).count();
        // Later bones cost about as much as earlier ones: linear estimate.
        const double eta = step > 0 ? el * (total - step) / step : 0.0;
        std::fprintf(stderr, "\rbuild scratch: step %d/%d, %.1f s, about %.1f s left   ", step, total, el, eta);
        if (step >= total) std::fprintf(stderr, "\n");
    };
    const ScratchResult r = build_from_vertices(anim, so);
    save_scratch(r, a.get("-o"));
    if (!quiet) {
        print_table("progressive skin, strategy scratch", r.skin.error, r.skin.diagonal);
        std::printf("  distortion %%:");
        for (const LodError& e : r.skin.error) std::printf(" %.3g", e.distortion_pct);
        std::printf("\n\nwrote %s (%d bones)\n", a.get("-o").c_str(), r.skin.bone_count());
    }
    return 0;
}

int cmd_build(int argc, char** argv) {
    Args a = parse(argc, argv, 2, {"--plain-copy", "--quiet", "--help", "--from-vertices", "--similarity"},
                   {"-o", "--strategy", "--clip", "--fps", "--character", "--bones", "--max-error", "--rest-frame",
                    "--method"});
    if (a.has("--help")) {
        std::fputs(kUsage, stdout);
        return 0;
    }
    if (a.has("--from-vertices")) return cmd_build_from_vertices(a);
    for (const char* k : {"--bones", "--max-error", "--rest-frame", "--similarity", "--method"})
        if (a.has(k)) throw UsageError(std::string(k) + " needs --from-vertices");
    if (a.positional.size() != 1) throw UsageError("build needs exactly one input file");
    if (!a.has("-o")) throw UsageError("build needs -o OUT.glb");
    check_output_path(a.get("-o"));
    const double fps = a.has("--fps") ? to_number("--fps", a.get("--fps")) : 30.0;
    if (fps <= 0 || fps > 1000) throw UsageError("--fps must be in (0, 1000]");
    // The default is the server's (--build-strategy rate): a file built here
    // streams as the same file served plain would (key samples need every
    // bone's progressive parent to be its artist parent: hierarchy).
#ifdef PROGSKIN_HAVE_NET
    const std::string strategy = a.get("--strategy", "rate");
#else
    const std::string strategy = a.get("--strategy", "auto");
#endif
    const bool by_rate = strategy == "rate", choose = strategy == "auto" || by_rate;
    if (!choose && strategy != "reorder" && strategy != "flatten" && strategy != "hierarchy" && strategy != "leaf_prune")
        throw UsageError("--strategy must be auto, rate, reorder, flatten, hierarchy or leaf_prune, not '" + strategy + "'");
    const Strategy st = choose ? Strategy::Reorder : parse_strategy(strategy);
    const bool quiet = a.has("--quiet");
    // The output embeds the images the input keeps beside it: every one is checked before the build.
    external_files(a.positional[0]);
    const Character c = with_stream_notes(import_or_hint(a.positional[0], character_arg(a)));
    bool range_of_motion = false;
    const FrameSet frames = spec_frames(c, a.get("--clip"), fps, &range_of_motion);
    if (!quiet)
        std::fprintf(stderr, "%s: %zu joints, %zu vertices, %zu frames at %g fps\n", a.positional[0].c_str(),
                     c.joint_count(), c.vertex_count(), frames.frame_count(), fps);
    // The importer's notes and what the stream cannot carry (also in
    // `inspect`), quiet or not: the user's to know.
    for (const std::string& n : c.notes) std::fprintf(stderr, "%s: note: %s\n", a.positional[0].c_str(), n.c_str());
    if (range_of_motion && !quiet)
        std::fprintf(stderr,
                     "%s: %s: trained on %g s of range-of-motion poses (every joint turning up to %g degrees; "
                     "docs/algorithms.md \"Characters without animation\")\n",
                     a.positional[0].c_str(),
                     a.get("--clip") == "range-of-motion" ? "--clip range-of-motion" : "no clip moves the skeleton",
                     kRangeOfMotionSeconds, kRangeOfMotionDegrees);
    if (!c.morphs.empty() && !quiet)
        std::fprintf(stderr,
                     "%s: %zu morph targets: kept in the output and evaluated before skinning; the error table is "
                     "the skinning error on the morphed mesh\n",
                     a.positional[0].c_str(), c.morphs.size());
    StrategyChoice chosen;
    const ProgressiveSkin s = choose ? build_best_with_progress(c, frames, !a.has("--plain-copy"), quiet, by_rate, chosen)
                                     : build_with_progress(c, frames, st, !a.has("--plain-copy"), quiet);
    if (!quiet) std::fprintf(stderr, "%s: computing the server's tables (bone costs and importance)\n", a.positional[0].c_str());
    json extra = server_tables(c, s);
    if (choose) {
        extra["strategy_choice"] = {{"chosen", strategy_name(chosen.chosen)},
                                    {"by", chosen.by_rate ? "rate-distortion" : "mean RMS"},
                                    {"reorder_mean_rms_pct", 100.0 * chosen.reorder_mean_rms / s.diagonal},
                                    {"flatten_mean_rms_pct", 100.0 * chosen.flatten_mean_rms / s.diagonal}};
        if (chosen.by_rate) {
            extra["strategy_choice"]["reorder_bits_per_frame"] = chosen.reorder_bits;
            extra["strategy_choice"]["flatten_bits_per_frame"] = chosen.flatten_bits;
            extra["strategy_choice"]["hierarchy_bits_per_frame"] = chosen.hierarchy_bits;
            extra["strategy_choice"]["reorder_rd_area"] = chosen.reorder_area;
            extra["strategy_choice"]["flatten_rd_area"] = chosen.flatten_area;
            extra["strategy_choice"]["hierarchy_rd_area"] = chosen.hierarchy_area;
            extra["strategy_choice"]["hierarchy_mean_rms_pct"] = 100.0 * chosen.hierarchy_mean_rms / s.diagonal;
        }
        if (!quiet)
            std::fprintf(stderr, "%s: strategy %s: mean RMS over k %.4f %% of the diagonal (reorder %.4f %%, flatten %.4f %%)\n",
                         a.positional[0].c_str(), strategy_name(chosen.chosen),
                         100.0 * mean_rms(s.error) / s.diagonal,
                         100.0 * chosen.reorder_mean_rms / s.diagonal, 100.0 * chosen.flatten_mean_rms / s.diagonal);
        if (!quiet && chosen.by_rate)
            std::fprintf(stderr,
                         "%s: chosen by rate-distortion: records of every bone %.0f / %.0f / %.0f bits per frame (reorder / "
                         "flatten / hierarchy), error x bits area %.4g / %.4g / %.4g (docs/algorithms.md \"Choosing the strategy\")\n",
                         a.positional[0].c_str(), chosen.reorder_bits, chosen.flatten_bits, chosen.hierarchy_bits, chosen.reorder_area,
                         chosen.flatten_area, chosen.hierarchy_area);
    }
    // What the error table was measured on (docs/metrics.md §2: a table is only comparable with its frames).
    extra["fps"] = fps;
    extra["clips"] = a.get("--clip", "auto");
    extra["training"] = json::array();
    for (const ClipSelection& sel : range_of_motion ? std::vector<ClipSelection>{} : training_set(c, a.get("--clip"))) {
        json names = json::array();
        for (int i : sel.clips) names.push_back(c.clips[size_t(i)].name);
        extra["training"].push_back(names);
    }
    if (range_of_motion) extra["training"] = "range of motion";
    extra["frames"] = frames.frame_count();
    extra["source"] = std::filesystem::path(a.positional[0]).filename().string();
    if (!quiet) std::fprintf(stderr, "%s: writing %s\n", a.positional[0].c_str(), a.get("-o").c_str());
    save_progressive(c, s, a.get("-o"), "", extra);
    if (!quiet) {
        print_table(std::string("progressive skin, strategy ") + strategy_name(s.strategy), s.error, s.diagonal);
        std::printf("\nwrote %s\n", a.get("-o").c_str());
    }
    return 0;
}

bool is_pc2(const std::string& path) {
    std::string ext = std::filesystem::path(path).extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    return ext == ".pc2";
}

// inspect of a file without a skin (morph-target animation, PC2 point
// cache): its vertices and frames, the clips and morph targets of a glTF,
// and the command that builds a skin from it. Exit 0.
int inspect_unskinned(const std::string& path, bool as_json) {
    const VertexAnimation anim = load_vertex_animation(path);
    json out;
    out["file"] = path;
    out["skinned"] = false;
    out["vertices"] = anim.vertex_count;
    out["frames"] = anim.frame_count;
    out["fps"] = anim.fps;
    out["clips"] = json::array();
    out["morph_targets"] = json::array();
    const json g = is_pc2(path) ? json() : read_gltf_json(path);
    if (g.is_object()) {
        const json& acc = g.value("accessors", json::array());
        for (const json& an : g.value("animations", json::array())) {
            double start = 0, end = 0;
            bool first = true;
            int weights = 0;
            for (const json& s : an.value("samplers", json::array())) {
                const size_t in = s.value("input", size_t(0));
                if (in >= acc.size() || !acc[in].contains("min") || !acc[in].contains("max")) continue;
                const double lo = acc[in]["min"][0].get<double>(), hi = acc[in]["max"][0].get<double>();
                start = first ? lo : std::min(start, lo);
                end = first ? hi : std::max(end, hi);
                first = false;
            }
            for (const json& ch : an.value("channels", json::array()))
                weights += ch.contains("target") && ch["target"].value("path", std::string()) == "weights";
            out["clips"].push_back({{"name", an.value("name", std::string())}, {"start", start}, {"end", end},
                                    {"channels", an.value("channels", json::array()).size()}, {"weights_channels", weights}});
        }
        const json& meshes = g.value("meshes", json::array());
        for (size_t m = 0; m < meshes.size(); ++m) {
            const json& prims = meshes[m].value("primitives", json::array());
            const size_t n = prims.empty() ? 0 : prims[0].value("targets", json::array()).size();
            const json names = meshes[m].contains("extras") ? meshes[m]["extras"].value("targetNames", json::array()) : json::array();
            for (size_t t = 0; t < n; ++t)
                out["morph_targets"].push_back({{"mesh", m},
                                                {"mesh_name", meshes[m].value("name", std::string())},
                                                {"target", t},
                                                {"name", t < names.size() && names[t].is_string() ? names[t].get<std::string>() : ""}});
        }
    }
    out["hint"] = from_vertices_hint(path);
    if (as_json) {
        std::cout << out.dump(2) << "\n";
        return 0;
    }
    std::printf("%s\n  no skin: a vertex animation (%s), %zu vertices, %zu frames at %g fps\n", path.c_str(),
                is_pc2(path) ? "PC2 point cache" : "morph targets", anim.vertex_count, anim.frame_count, anim.fps);
    std::printf("  clips:");
    for (const json& c : out["clips"])
        std::printf(" \"%s\" (%.3g-%.3g s, %d weights channels)", c["name"].get<std::string>().c_str(),
                    c["start"].get<double>(), c["end"].get<double>(), c["weights_channels"].get<int>());
    std::printf("%s\n", out["clips"].empty() ? " none" : "");
    std::printf("  morph targets: %zu\n", out["morph_targets"].size());
    for (const json& t : out["morph_targets"])
        std::printf("    mesh %d \"%s\" target %d \"%s\"\n", t["mesh"].get<int>(), t["mesh_name"].get<std::string>().c_str(),
                    t["target"].get<int>(), t["name"].get<std::string>().c_str());
    std::printf("  %s\n", out["hint"].get<std::string>().c_str());
    return 0;
}

int cmd_inspect(int argc, char** argv) {
    Args a = parse(argc, argv, 2, {"--json", "--help", "--quiet"}, {"--clip", "--fps", "--character", "--plot"});
    if (a.has("--help")) {
        std::fputs(kUsage, stdout);
        return 0;
    }
    if (a.positional.size() != 1) throw UsageError("inspect needs exactly one file");
    const bool as_json = a.has("--json");
    const double fps = a.has("--fps") ? to_number("--fps", a.get("--fps")) : 30.0;
    if (fps <= 0 || fps > 1000) throw UsageError("--fps must be in (0, 1000]");
    // Every character of the file (listed), the one of --character (default 0) in detail;
    // a file without a skin: what it has and how to build a skin from it.
    if (is_pc2(a.positional[0])) return inspect_unskinned(a.positional[0], as_json);
    ImportOptions io;
    io.require_skin = false;
    std::vector<Character> all = import_gltf(a.positional[0], io);
    if (all.empty()) return inspect_unskinned(a.positional[0], as_json);
    const int index = character_arg(a);
    if (index < 0 || size_t(index) >= all.size())
        throw Error(a.positional[0] + ": no character " + std::to_string(index) + " (the file has " +
                    std::to_string(all.size()) + (all.size() == 1 ? " character)" : " characters)"));
    json characters = json::array();
    for (size_t i = 0; i < all.size(); ++i)
        characters.push_back({{"index", i},
                              {"name", all[i].name},
                              {"joints", all[i].joint_count()},
                              {"vertices", all[i].vertex_count()},
                              {"clips", all[i].clips.size()},
                              {"morph_targets", all[i].morphs.size()}});
    ProgressiveAsset asset;
    asset.character = with_stream_notes(std::move(all[size_t(index)]));
    std::string ext_text;
    asset.progressive = read_progressive_extension(a.positional[0], asset.character, asset.skin, &ext_text);
    const json ext = asset.progressive ? json::parse(ext_text, nullptr, false) : json();
    const Character& c = asset.character;
    // One diagonal: the one the table's percentages use (a progressive file's
    // stored diagonal; for --from-vertices outputs that of the vertex animation).
    const double rest_diag = rest_diagonal(c);
    const double diag = asset.progressive && asset.skin.diagonal > 0 ? asset.skin.diagonal : rest_diag;
    json out;
    out["file"] = a.positional[0];
    out["character"] = index;
    out["characters"] = characters;
    out["joints"] = c.joint_count();
    out["vertices"] = c.vertex_count();
    out["diagonal"] = diag;
    out["rest_diagonal"] = rest_diag;
    if (asset.progressive) {  // what the stored table was measured on, when the file says
        for (const char* key : {"fps", "clips", "training", "frames", "source"})
            if (ext.contains(key)) out["table_" + std::string(key)] = ext[key];
    }
    out["influences_per_vertex"] = c.influences;
    out["clips"] = json::array();
    for (const Clip& cl : c.clips)
        out["clips"].push_back({{"name", cl.name}, {"start", cl.start}, {"end", cl.end},
                                {"channels", cl.channels.size()}});
    out["renormalised_vertices"] = c.renormalised_vertices;
    out["morph_targets_ignored"] = false;  // evaluated by import, pose and the error tables
    out["morph_targets_streamed"] = true;  // their weights travel in the morph block (docs/protocol.md), the first 255
    out["morph_targets"] = json::array();
    const std::vector<double> importance = morph_importance(c);
    for (size_t m = 0; m < c.morphs.size(); ++m)
        out["morph_targets"].push_back({{"name", c.morphs[m].name},
                                        {"node", c.morphs[m].gltf_node},
                                        {"target", c.morphs[m].target},
                                        {"default_weight", c.morphs[m].default_weight},
                                        {"vertices", c.morphs[m].vertices.size()},
                                        {"importance", importance[m]}});
    out["notes"] = c.notes;
    out["progressive"] = asset.progressive;
    out["strategies"] = json::object();
    std::vector<std::pair<std::string, std::vector<LodError>>> tables;
    if (asset.progressive && a.has("--clip")) {
        // The stored skin measured on the clips asked for (what it was built
        // on is in its table; another clip or a grafted animation is not).
        bool range_of_motion = false;
        const std::string spec = a.get("--clip");
        const FrameSet frames =
            spec == "range-of-motion" ? spec_frames(c, spec, fps, &range_of_motion) : sample_frames(c, training_set(c, spec), fps);
        out["frames"] = frames.frame_count();
        out["table_measured_on"] = spec;
        tables.push_back({strategy_name(asset.skin.strategy), evaluate_error_table(c, asset.skin, frames)});
    } else if (asset.progressive) {
        tables.push_back({strategy_name(asset.skin.strategy), asset.skin.error});
    } else {
        bool range_of_motion = false;
        const FrameSet frames = spec_frames(c, a.get("--clip"), fps, &range_of_motion);
        out["frames"] = frames.frame_count();
        out["range_of_motion"] = range_of_motion;
        const bool quiet = as_json || a.has("--quiet");
        for (Strategy st : {Strategy::Reorder, Strategy::Flatten, Strategy::Hierarchy, Strategy::LeafPrune})
            tables.push_back({strategy_name(st), build_with_progress(c, frames, st, true, quiet).error});
        tables.push_back(
            {"reorder_plain_copy", build_with_progress(c, frames, Strategy::Reorder, false, quiet).error});
    }
    for (const auto& [name, t] : tables) out["strategies"][name] = table_json(t);
    if (a.has("--plot")) {
        std::string err;
        const std::string file = std::filesystem::path(a.positional[0]).filename().string();
        if (!plot_error_tables(tables, a.get("--plot"), file + ": error against bones", &err)) throw Error(err);
    }
    if (as_json) {
        std::cout << out.dump(2) << "\n";
        return 0;
    }
    std::printf("%s\n", a.positional[0].c_str());
    if (characters.size() > 1) {
        std::printf("  %zu characters (--character N picks one; progskin-server serves FILE#N):\n", characters.size());
        for (const json& ch : characters)
            std::printf("  %s #%d \"%s\": %d joints, %d vertices, %d clips, %d morph targets\n",
                        ch["index"].get<int>() == index ? "*" : " ", ch["index"].get<int>(),
                        ch["name"].get<std::string>().c_str(), ch["joints"].get<int>(), ch["vertices"].get<int>(),
                        ch["clips"].get<int>(), ch["morph_targets"].get<int>());
        std::printf("  character %d:\n", index);
    }
    std::printf("  joints %zu, vertices %zu, %d influence slots per vertex, diagonal %.6g\n", c.joint_count(),
                c.vertex_count(), c.influences, diag);
    std::printf("  clips:");
    for (const Clip& cl : c.clips) std::printf(" \"%s\" (%.3g-%.3g s)", cl.name.c_str(), cl.start, cl.end);
    std::printf("\n");
    for (const std::string& n : c.notes) std::printf("  note: %s\n", n.c_str());
    if (!c.morphs.empty()) {
        std::printf("  morph targets: %zu (evaluated before skinning in pose and the error tables; the server "
                    "streams their weights)\n",
                    c.morphs.size());
        for (size_t m = 0; m < c.morphs.size(); ++m)
            std::printf("    \"%s\" node %d target %d: default weight %g, %zu vertices, importance %.4g (RMS units "
                        "per unit weight)\n",
                        c.morphs[m].name.c_str(), c.morphs[m].gltf_node, c.morphs[m].target,
                        double(c.morphs[m].default_weight), c.morphs[m].vertices.size(), importance[m]);
    }
    std::printf("  %s\n", asset.progressive ? "progressive skin (PROGSKIN_progressive_skin)" : "plain glTF skin");
    if (ext.contains("fps") && ext.contains("training"))
        std::printf("  stored table measured on %s at %g fps (%s frames)\n", ext["training"].dump().c_str(),
                    ext["fps"].get<double>(), ext.contains("frames") ? ext["frames"].dump().c_str() : "?");
    if (out.contains("table_measured_on"))
        std::printf("  the table below: the stored skin measured on --clip %s (%s frames)\n",
                    out["table_measured_on"].get<std::string>().c_str(), out["frames"].dump().c_str());
    if (out.value("range_of_motion", false))
        std::printf("  the tables below: built and measured on %g s of range-of-motion poses (%s)\n", kRangeOfMotionSeconds,
                    a.get("--clip") == "range-of-motion" ? "--clip range-of-motion" : "no clip moves the skeleton");
    for (const auto& [name, t] : tables) print_table("strategy " + name, t, diag);
    return 0;
}

int cmd_pose(int argc, char** argv) {
    Args a = parse(argc, argv, 2, {"--json", "--help"},
                   {"--time", "--clip", "--bones", "--character", "--max-influences", "-o"});
    if (a.has("--help")) {
        std::fputs(kUsage, stdout);
        return 0;
    }
    if (a.positional.size() != 1) throw UsageError("pose needs exactly one file");
    if (!a.has("--time")) throw UsageError("pose needs --time T");
    if (a.has("--json") == a.has("-o")) throw UsageError("pose needs exactly one of --json or -o OUT.bin");
    const double t = to_number("--time", a.get("--time"));
    ProgressiveAsset asset = load_progressive(a.positional[0], character_arg(a));
    const Character& c = asset.character;
    const int B = int(c.joint_count());
    const std::string bones = a.get("--bones", "all");
    const int k = bones == "all" ? B : to_int("--bones", bones);
    if (k < 1 || k > B) throw UsageError("--bones must be in 1.." + std::to_string(B) + " or all");
    const std::string spec = a.get("--clip", "auto");
    ClipSelection sel;
    if (spec == "auto") {
        const auto sets = default_training_set(c);
        if (!sets.empty()) sel = sets[0];
    } else {
        sel = select_clips(c, spec);
    }
    const FrameSet one = sample_pose(c, sel, t);  // bones and morph weights at exactly t
    if (!asset.progressive && k < B) {
        StrategyChoice ignored;
        asset.skin = build_best_with_progress(c, training_frames(c, default_training_set(c), 30.0), true, true, false, ignored);
        asset.progressive = true;
    }
    std::vector<glm::vec3> pos(c.vertex_count());
    if (!asset.progressive) {
        reference_positions(c, one, 0, pos);
    } else {
        ProgressiveSkin s = asset.skin;
        if (a.has("--max-influences")) {
            const int mi = to_int("--max-influences", a.get("--max-influences"));
            if (mi < 1) throw UsageError("--max-influences must be at least 1");
            // Drop the last slots, renormalising the kept weights.
            for (size_t v = 0; v < c.vertex_count(); ++v) {
                float sum = 0;
                for (int i = 0; i < s.influences; ++i) {
                    float& w = s.weights[v * s.influences + i];
                    if (i >= mi) w = 0.0f;
                    sum += w;
                }
                for (int i = 0; i < s.influences && sum > 0; ++i) s.weights[v * s.influences + i] /= sum;
            }
        }
        lod_positions(c, s, one, 0, k, pos);
    }
    if (a.has("--json")) {
        json out;
        out["count"] = pos.size();
        out["time"] = t;
        out["bones"] = k;
        json p = json::array();
        for (const auto& v : pos) p.push_back({v.x, v.y, v.z});
        out["positions"] = std::move(p);
        std::cout << out.dump() << "\n";
    } else {
        const std::string path = a.get("-o");
        const std::string tmp = path + ".tmp";
        {
            std::ofstream f(tmp, std::ios::binary);
            for (const auto& v : pos) f.write(reinterpret_cast<const char*>(&v.x), 12);
            if (!f) throw Error(path + ": cannot write");
        }
        if (std::rename(tmp.c_str(), path.c_str()) != 0) throw Error(path + ": cannot write");
    }
    return 0;
}

#ifdef PROGSKIN_HAVE_NET
int cmd_token(int argc, char** argv) {
    using namespace progskin::net::crypto;
    if (argc < 3) throw UsageError("token needs keygen or issue");
    const std::string sub = argv[2];
    if (sub == "keygen") {
        if (argc != 3) throw UsageError("token keygen takes no arguments");
        PublicKey pk;
        SecretKey sk;
        signing_keypair(pk, sk);
        std::printf("public %s\nsecret %s\n", to_hex(pk).c_str(), to_hex(sk).c_str());
        return 0;
    }
    if (sub != "issue") throw UsageError("unknown token command '" + sub + "'");
    std::string key_hex, server;
    uint64_t client_id = 0, seconds = 30;
    bool have_id = false;
    for (int i = 3; i < argc; ++i) {
        const std::string a = argv[i];
        auto val = [&]() -> std::string {
            if (i + 1 >= argc) throw UsageError(a + " needs a value");
            return argv[++i];
        };
        if (a == "--secret-key") key_hex = val();
        else if (a == "--client-id") {
            const std::string v = val();
            char* end = nullptr;
            client_id = std::strtoull(v.c_str(), &end, 10);
            if (v.empty() || *end || v[0] == '-') throw UsageError("--client-id needs an unsigned integer");
            have_id = true;
        } else if (a == "--server") server = val();
        else if (a == "--seconds") {
            const int v = progskin::cli::to_int(a, val());
            if (v < 1) throw UsageError("--seconds must be at least 1");
            seconds = uint64_t(v);
        } else throw UsageError("unknown argument " + a);
    }
    if (key_hex.empty() || !have_id || server.empty()) throw UsageError("token issue needs --secret-key, --client-id and --server");
    SecretKey sk;
    if (!from_hex(key_hex, sk)) throw UsageError("--secret-key must be 128 hex digits");
    std::printf("%s\n", issue_connect_token(sk, client_id, unix_now(), seconds, server).c_str());
    return 0;
}
#endif

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h") ||
        !std::strcmp(argv[1], "help")) {
        std::fputs(kUsage, argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const std::string cmd = argv[1];
    try {
        if (cmd == "build") return cmd_build(argc, argv);
        if (cmd == "inspect") return cmd_inspect(argc, argv);
        if (cmd == "pose") return cmd_pose(argc, argv);
#ifdef PROGSKIN_HAVE_NET
        if (cmd == "token") return cmd_token(argc, argv);
#endif
#ifdef PROGSKIN_HAVE_RENDER
        if (cmd == "render") return render_command(argc, argv);
#endif
        throw UsageError("unknown command '" + cmd + "'");
    } catch (const UsageError& e) {
        std::fprintf(stderr, "progskin: %s (see progskin --help)\n", e.what());
        return 2;
    } catch (const Error& e) {
        std::fprintf(stderr, "progskin: %s\n", e.what());
        return 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin: %s\n", e.what());
        return 1;
    }
}
