// scene.cpp — see scene.h.
#include "scene.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "collapse.h"
#include "range_of_motion.h"
#include "cost_tables.h"
#include "errors.h"
#include "error_metric.h"
#include "gltf_export.h"
#include "gltf_import.h"
#include "progressive_asset.h"
#include "progressive_skin.h"
#include "scratch_build.h"
#include "self_contained.h"
#include "skinning.h"
#include "vertex_animation.h"
#include "wire.h"

namespace progskin::net {

namespace fs = std::filesystem;

// The wire record format of an asset's bones: its tables' translation box.
static RecordFormat record_format(const AssetTables& t) {
    RecordFormat f;
    f.t_min = t.t_min;
    f.t_max = t.t_max;
    f.scaled = t.scaled;
    f.scale = t.ref_scale;
    f.t_step = t.t_step;
    return f;
}

static std::vector<uint8_t> read_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open");
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

void finish_server_asset(ServerAsset& a) {
    const ProgressiveSkin& s = a.skin;
    if (s.bone_count() < 1 || s.bone_count() > MAX_BONES)
        throw Error(a.path + ": " + std::to_string(s.bone_count()) + " bones (1.." + std::to_string(MAX_BONES) + " streamable)");
    if (a.selections.empty()) a.selections = default_training_set(a.character);
    if (a.selections.empty()) a.selections.push_back(ClipSelection{});
    static_cast<AssetTables&>(a) = compute_asset_tables(a.character, s, a.selections);
    a.format = record_format(a);
    a.relative = relative_format(a.skin, a.character, a.format);
}

// Morph targets: their importance (the scheduler's value of a weight) and a
// warning for the targets past what the wire carries (uint8 index).
static void prepare_morphs(ServerAsset& a, const std::string& path) {
    a.morph_importance = morph_importance(a.character);
    if (a.character.morphs.size() > size_t(MAX_MORPHS))
        a.warnings.push_back(path + ": " + std::to_string(a.character.morphs.size()) + " morph targets; only the first " +
                             std::to_string(MAX_MORPHS) + " are streamed (the others stay at weight 0)");
}

std::shared_ptr<ServerAsset> load_server_asset(const std::string& path) {
    auto a = std::make_shared<ServerAsset>();
    a->path = path;
    a->name = fs::path(path).filename().string();
    a->bytes = self_contained_glb(path);  // external buffers and images embedded: what every client can load
    a->id = content_hash(a->bytes);
    ProgressiveAsset pa = load_progressive(path);
    a->character = std::move(pa.character);
    a->selections = default_training_set(a->character);
    if (pa.progressive && pa.skin.bone_count() == int(a->character.joint_count())) {
        a->skin = std::move(pa.skin);  // progressive glTF: joints already in progressive order
        a->progressive_file = true;
    } else {
        a->skin = build_best_progressive_skin(a->character, training_frames(a->character, a->selections, 30.0));
    }
    prepare_morphs(*a, path);
    finish_server_asset(*a);
    return a;
}

namespace {

// The stored tables of a (asset_tables_json) into a; false, a unchanged, when they do not fit.
bool read_server_tables(const nlohmann::json& j, ServerAsset& a, std::string* why = nullptr) {
    AssetTables t;
    if (!read_asset_tables(j, a.bone_count(), a.selections.size(), t, why)) return false;
    static_cast<AssetTables&>(a) = std::move(t);
    a.format = record_format(a);
    a.relative = relative_format(a.skin, a.character, a.format);
    return true;
}

nlohmann::json server_tables_json(const ServerAsset& a) { return asset_tables_json(a, a.bone_count(), a.selections.size()); }

}  // namespace

std::string server_cache_dir() {
    if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/progskin";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/progskin";
    return "progskin-cache";
}

namespace {

// An --asset argument split into the file and the character index (-1: all).
// "FILE#N" names character N unless FILE#N itself is an existing file.
std::pair<std::string, int> split_asset_arg(const std::string& arg) {
    const size_t hash = arg.rfind('#');
    if (hash == std::string::npos || hash + 1 == arg.size() || fs::exists(arg)) return {arg, -1};
    const std::string digits = arg.substr(hash + 1);
    if (digits.find_first_not_of("0123456789") != std::string::npos || digits.size() > 6) return {arg, -1};
    return {arg.substr(0, hash), std::stoi(digits)};
}

// Frames the default training set takes at 30 fps (sample_frames' count), without sampling.
double training_frames(const Character& c) {
    double n = 0;
    for (const ClipSelection& sel : default_training_set(c))
        n += std::floor(std::max(0.0, double(sel.end) - double(sel.start)) * 30.0 + 1e-6) + 1.0;
    return n;
}

// Size problems of one imported character ("" when it can be served).
std::string character_problem(const Character& c, const std::string& label) {
    if (c.joint_count() > size_t(MAX_BONES))
        return label + ": " + std::to_string(c.joint_count()) + " joints, at most " + std::to_string(MAX_BONES) +
               " can be streamed";
    if (c.vertex_count() == 0) return label + ": the skinned meshes have no vertices";
    const double frames = training_frames(c);
    if (frames > double(kMaxSampledFrames))
        return label + ": its clips span " + std::to_string(size_t(frames)) + " frames at 30 fps, more than " +
               std::to_string(kMaxSampledFrames);
    return {};
}

// The skins of a character (those its skinned primitives use), in file order.
std::vector<int> skins_of(const Character& c) {
    std::vector<int> skins;
    for (const PrimitiveRange& r : c.primitives)
        if (!r.rigid && r.skin >= 0 && std::find(skins.begin(), skins.end(), r.skin) == skins.end()) skins.push_back(r.skin);
    std::sort(skins.begin(), skins.end());
    return skins;
}

// Checks one --asset argument, appending its characters or its problems.
void check_one(const std::string& arg, const AssetOptions& o, std::vector<PendingAsset>& out,
               std::vector<std::string>& problems) {
    const auto [path, index] = split_asset_arg(arg);
    std::vector<Character> chars;
    try {
        if (!fs::exists(path)) {
            problems.push_back(path + ": no such file");
            return;
        }
        const bool pc2 = path.size() >= 4 && (path.compare(path.size() - 4, 4, ".pc2") == 0 ||
                                               path.compare(path.size() - 4, 4, ".PC2") == 0);
        if (!pc2) {
            external_files(path);  // every external buffer and image can be embedded (else the problem, naming the uri)
            ImportOptions io;
            io.require_skin = false;
            chars = import_gltf(path, io);
        } else if (!o.from_vertices) {
            problems.push_back(path + ": a PC2 point cache has no skin: build one with `progskin build --from-vertices " +
                               path + " -o OUT.glb` and serve OUT.glb, or start progskin-server with --from-vertices");
            return;
        }
    } catch (const std::exception& e) {
        problems.push_back(e.what());
        return;
    }
    const std::string base = fs::path(path).filename().string();
    if (chars.empty()) {
        if (!o.from_vertices) {
            problems.push_back(path + ": no skin (no mesh uses a skin): the server streams skinned characters; build one "
                               "from its vertex animation with `progskin build --from-vertices " + path +
                               " -o OUT.glb` and serve OUT.glb, or start progskin-server with --from-vertices");
            return;
        }
        try {
            const VertexAnimation anim = load_vertex_animation(path);
            if (anim.vertex_count == 0 || anim.frame_count == 0) {
                problems.push_back(path + ": --from-vertices: no vertices or no frames to build a skin from");
                return;
            }
        } catch (const std::exception& e) {
            problems.push_back(std::string(e.what()) + " (--from-vertices)");
            return;
        }
        PendingAsset p;
        p.path = path;
        p.label = base;
        p.from_vertices = true;
        out.push_back(std::move(p));
        return;
    }
    if (index >= int(chars.size())) {
        problems.push_back(path + ": no character " + std::to_string(index) + " (the file has " +
                           std::to_string(chars.size()) + (chars.size() == 1 ? " character)" : " characters)"));
        return;
    }
    for (int i = 0; i < int(chars.size()); ++i) {
        if (index >= 0 && i != index) continue;
        PendingAsset p;
        p.path = path;
        p.character = i;
        p.characters_in_file = int(chars.size());
        p.label = chars.size() > 1 ? base + "#" + std::to_string(i) : base;
        const std::string problem = character_problem(chars[size_t(i)], p.label);
        if (!problem.empty()) {
            problems.push_back(path + (chars.size() > 1 ? " character " + std::to_string(i) : std::string()) + ": " +
                               problem.substr(p.label.size() + 2));
            continue;
        }
        try {
            p.progressive = read_progressive_extension(path, chars[size_t(i)], p.skin, &p.extension_json);
        } catch (const std::exception& e) {
            problems.push_back(e.what());
            continue;
        }
        p.imported = std::move(chars[size_t(i)]);
        out.push_back(std::move(p));
    }
}

}  // namespace

std::vector<std::string> check_server_assets(const std::vector<std::string>& args, const AssetOptions& options,
                                             std::vector<PendingAsset>& out) {
    std::vector<std::string> problems;
    out.clear();
    for (const std::string& arg : args) check_one(arg, options, out, problems);
    return problems;
}

namespace {

// Cache file of a plain file's build: content hash of the file, character,
// table version, build ("b2": the lower-error strategy, build_best_progressive_skin).
std::string cached_build_path(const PendingAsset& p, const std::string& cache, const std::vector<uint8_t>& bytes,
                              const AssetOptions& o) {
    return (fs::path(cache) / (hex64(content_hash(bytes)) + "-c" + std::to_string(p.character) + "-t" +
                               std::to_string(kServerTablesVersion) + "-b2" + (o.build_by_rate ? "r" : "") +
                               (o.range_of_motion ? "m" : "") + ".glb"))
        .string();
}

// Reads a cached build (a progressive copy of the file with the server tables)
// into a: the skin with its order mapped back to the file's joints, the
// tables. False when absent or not matching (then nothing in `a` changed).
bool load_cached_build(const PendingAsset& p, const std::string& cache, const AssetOptions& o, ServerAsset& a) {
    const std::string path = cached_build_path(p, cache, read_file(p.path), o);
    if (!fs::exists(path)) return false;
    try {
        Character cached = import_character(path, p.character);
        ProgressiveSkin skin;
        std::string ext_text;
        if (!read_progressive_extension(path, cached, skin, &ext_text)) return false;
        const nlohmann::json ext = nlohmann::json::parse(ext_text, nullptr, false);
        if (!ext.is_object() || !ext.contains("server")) return false;
        const Character& c = a.character;
        if (cached.joint_count() != c.joint_count() || cached.vertex_count() != c.vertex_count()) return false;
        // Cached joint b (progressive order) is the file's joint with the same node and inverse bind matrix.
        std::vector<int> order(cached.joint_count(), -1);
        std::vector<char> used(c.joint_count(), 0);
        for (size_t b = 0; b < cached.joint_count(); ++b) {
            const int node = cached.nodes[size_t(cached.joint_node[b])].gltf_index;
            for (size_t j = 0; j < c.joint_count() && order[b] < 0; ++j) {
                if (used[j] || c.nodes[size_t(c.joint_node[j])].gltf_index != node) continue;
                double d = 0;
                for (int x = 0; x < 4; ++x)
                    for (int y = 0; y < 4; ++y) d = std::max(d, std::abs(c.inverse_bind[j][x][y] - cached.inverse_bind[b][x][y]));
                if (d > 1e-4 * std::max(1.0, a.diagonal)) continue;
                order[b] = int(j);
                used[j] = 1;
            }
            if (order[b] < 0) return false;
        }
        skin.order = order;
        ServerAsset t = a;
        t.skin = std::move(skin);
        if (!read_server_tables(ext["server"], t)) return false;
        a = std::move(t);
        return true;
    } catch (const std::exception&) {
        return false;  // a damaged cache entry is rebuilt
    }
}

// Writes the build of a plain file to the cache; a failure only costs the next start.
void save_cached_build(const PendingAsset& p, const std::string& cache, const AssetOptions& o, ServerAsset& a) {
    try {
        fs::create_directories(cache);
        nlohmann::json extra;
        extra["server"] = server_tables_json(a);
        save_progressive(a.character, a.skin, cached_build_path(p, cache, read_file(p.path), o),
                         "cached build of " + fs::path(p.path).filename().string(), extra);
    } catch (const std::exception& e) {
        a.warnings.push_back(p.path + ": cannot cache the build in " + cache + ": " + e.what());
    }
}

// The cache directory, created; when it cannot be (a read-only home), a
// per-user directory under the system's temporary directory, with a warning.
std::string usable_cache(const std::string& wanted, std::vector<std::string>& warnings) {
    std::error_code ec;
    fs::create_directories(wanted, ec);
    if (!ec && fs::is_directory(wanted)) return wanted;
    const std::string fallback = (fs::temp_directory_path() / ("progskin-cache-" + std::to_string(::getuid()))).string();
    fs::create_directories(fallback, ec);
    if (ec) throw Error("cannot create the cache directory " + wanted + " nor " + fallback + ": " + ec.message());
    warnings.push_back("cache directory " + wanted + " cannot be created; using " + fallback);
    return fallback;
}

}  // namespace

std::shared_ptr<ServerAsset> build_server_asset(const PendingAsset& p, const AssetOptions& options) {
    auto a = std::make_shared<ServerAsset>();
    const std::string cache = usable_cache(options.cache_dir.empty() ? server_cache_dir() : options.cache_dir, a->warnings);
    a->name = p.label;
    if (p.from_vertices) {
        // Build (or reuse) the progressive file and serve it like any progressive file.
        const uint64_t hash = content_hash(read_file(p.path));
        fs::create_directories(cache);
        const std::string out = (fs::path(cache) / (hex64(hash) + "-scratch" + std::to_string(options.scratch_bones) +
                                                     ".glb")).string();
        if (!fs::exists(out)) {
            ScratchOptions so;
            so.max_bones = options.scratch_bones;
            save_scratch(build_from_vertices(load_vertex_animation(p.path), so), out);
        }
        a->path = out;
        a->bytes = read_file(out);
        ProgressiveAsset pa = load_progressive(out);
        if (!pa.progressive) throw Error(out + ": the built file has no progressive skin");
        a->character = std::move(pa.character);
        a->skin = std::move(pa.skin);
        a->progressive_file = true;
    } else {
        a->path = p.path;
        // Served self-contained: a client downloads one file (external buffers and images embedded).
        a->bytes = self_contained_glb(p.path);
        if (p.character > 0) {
            // A client plays character 0 of what it downloads: serve a copy with this character's skins first
            // (self-contained too: "-sc"; copies cached before images were embedded are not reused).
            fs::create_directories(cache);
            const std::string out = (fs::path(cache) / (hex64(content_hash(read_file(p.path))) + "-character" +
                                                         std::to_string(p.character) + "-sc.glb")).string();
            if (!fs::exists(out)) write_with_skins_first(p.path, skins_of(p.imported), out);
            a->bytes = read_file(out);
        }
        a->character = p.imported;
        if (p.progressive) {
            a->skin = p.skin;
            a->progressive_file = true;
        }
    }
    a->id = content_hash(a->bytes);
    a->selections = default_training_set(a->character);
    if (a->selections.empty()) a->selections.push_back(ClipSelection{});
    std::string why;
    if (a->progressive_file) {
        const nlohmann::json ext = nlohmann::json::parse(p.extension_json, nullptr, false);
        const nlohmann::json* tables = ext.is_object() && ext.contains("server") ? &ext["server"] : nullptr;
        if (!p.from_vertices && !(tables && read_server_tables(*tables, *a, &why))) {
            a->warnings.push_back(p.path + ": " + (why.empty() ? "no stored server tables" : why) +
                                  ": computed at start (rebuild the file with progskin build to store them)");
            finish_server_asset(*a);
        } else if (p.from_vertices) {
            // The scratch file's tables are kept beside it (.tables.json) once computed.
            const std::string side = a->path + ".tables-t" + std::to_string(kServerTablesVersion) + ".json";
            nlohmann::json stored;
            if (std::ifstream in(side); in) stored = nlohmann::json::parse(in, nullptr, false);
            if (!read_server_tables(stored, *a)) {
                finish_server_asset(*a);
                std::ofstream out(side + ".tmp");
                out << server_tables_json(*a).dump();
                out.close();
                std::error_code ec;
                if (out) fs::rename(side + ".tmp", side, ec);
            }
        }
    } else if (!load_cached_build(p, cache, options, *a)) {
        bool range_of_motion = options.range_of_motion;
        const FrameSet frames = options.range_of_motion ? range_of_motion_frames(a->character, 30.0)
                                                        : training_frames(a->character, a->selections, 30.0, &range_of_motion);
        if (range_of_motion && !options.range_of_motion)
            a->warnings.push_back(p.path + ": no clip moves the skeleton: its bones are ordered by " +
                               std::to_string(int(kRangeOfMotionSeconds)) +
                               " s of range-of-motion poses (docs/algorithms.md \"Characters without animation\")");
        BuildOptions bo;
        const Character& c = a->character;
        if (options.build_by_rate) bo.bone_bits = [&](const ProgressiveSkin& s) { return record_bits_per_bone(c, s, frames); };
        a->skin = build_best_progressive_skin(c, frames, bo);
        finish_server_asset(*a);
        save_cached_build(p, cache, options, *a);
    }
    prepare_morphs(*a, p.path);
    return a;
}

std::vector<InstanceSpec> crowd_layout(const std::vector<std::shared_ptr<ServerAsset>>& assets, int n) {
    std::vector<InstanceSpec> out;
    if (assets.empty() || n <= 0) return out;
    double spacing = 0;
    for (const auto& a : assets) spacing = std::max(spacing, a->diagonal);
    int side = int(std::ceil(std::sqrt(double(n))));
    for (int i = 0; i < n; ++i) {
        InstanceSpec s;
        s.asset = i % int(assets.size());
        const auto& a = *assets[s.asset];
        s.selection = (i / int(assets.size())) % int(a.selections.size());
        float dur = a.selections[s.selection].duration();
        s.time_offset = dur > 0 ? std::fmod(0.37f * float(i), dur) : 0.0f;
        s.position = glm::vec3(float((i % side) * spacing), 0.0f, float((i / side) * spacing));
        out.push_back(s);
    }
    return out;
}

std::vector<InstanceSpec> default_instances(const std::vector<std::shared_ptr<ServerAsset>>& assets) {
    std::vector<InstanceSpec> out;
    for (size_t a = 0; a < assets.size(); ++a)
        for (size_t s = 0; s < assets[a]->selections.size(); ++s) {
            InstanceSpec i;
            i.asset = int(a);
            i.selection = int(s);
            i.position = glm::vec3(float(out.size()) * float(assets[a]->diagonal), 0.0f, 0.0f);
            out.push_back(i);
        }
    return out;
}

std::vector<std::string> default_asset_paths(const std::string& hint_dir) {
    std::vector<fs::path> roots;
    fs::path p = hint_dir.empty() ? fs::current_path() : fs::path(hint_dir);
    for (int i = 0; i < 4 && !p.empty(); ++i) {
        roots.push_back(p / "assets");
        if (p == p.parent_path()) break;
        p = p.parent_path();
    }
    roots.push_back(fs::current_path() / "assets");
#ifdef PROGSKIN_ASSETS
    roots.push_back(PROGSKIN_ASSETS);
#endif
    for (const auto& r : roots) {
        if (fs::exists(r / "Fox.glb") && fs::exists(r / "CesiumMan.glb"))
            return {(r / "Fox.glb").string(), (r / "CesiumMan.glb").string()};
    }
    throw Error("default character set not found (assets/Fox.glb, assets/CesiumMan.glb); pass --asset FILE");
}

}  // namespace progskin::net
