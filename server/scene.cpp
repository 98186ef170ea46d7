// scene.cpp — see scene.h.
#include "scene.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "error.h"
#include "error_metric.h"
#include "gltf_export.h"
#include "gltf_import.h"
#include "progressive_skin.h"
#include "skinning.h"
#include "wire.h"

namespace progskin::net {

namespace fs = std::filesystem;

static std::vector<uint8_t> read_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open");
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

std::vector<HullStep> error_hull(const std::vector<LodError>& error) {
    // Points (k, e(k)) for k = 1..B; lower convex hull from k = 1 (monotone chain).
    std::vector<HullStep> steps;
    const int B = int(error.size());
    if (B <= 1) return steps;
    std::vector<int> h;  // hull vertex ks
    auto e = [&](int k) { return error[k - 1].rms; };
    for (int k = 1; k <= B; ++k) {
        while (h.size() >= 2) {
            int a = h[h.size() - 2], b = h.back();
            // b is above segment a-k (or on it): drop it
            double cross = (b - a) * (e(k) - e(a)) - (k - a) * (e(b) - e(a));
            if (cross <= 0) h.pop_back();
            else break;
        }
        h.push_back(k);
    }
    for (size_t i = 1; i < h.size(); ++i)
        steps.push_back({h[i - 1], h[i], std::max(0.0, e(h[i - 1]) - e(h[i]))});
    return steps;
}

void finish_server_asset(ServerAsset& a) {
    const Character& c = a.character;
    const ProgressiveSkin& s = a.skin;
    if (s.bone_count() < 1 || s.bone_count() > MAX_BONES)
        throw Error(a.path + ": " + std::to_string(s.bone_count()) + " bones (1.." + std::to_string(MAX_BONES) + " streamable)");
    a.diagonal = s.diagonal > 0 ? s.diagonal : rest_diagonal(c);
    if (!(a.diagonal > 0)) a.diagonal = 1;
    a.bind_radius = 0;
    for (const auto& p : c.positions) a.bind_radius = std::max(a.bind_radius, double(glm::length(p)));

    if (a.selections.empty()) a.selections = default_training_set(c);
    if (a.selections.empty()) a.selections.push_back(ClipSelection{});
    FrameSet frames = sample_frames(c, a.selections, 30.0);

    // Translation box and scale range of the skinning matrices.
    glm::vec3 lo(1e30f), hi(-1e30f);
    bool scaled = false;
    a.max_scale = 1;
    for (size_t f = 0; f < frames.frame_count(); ++f) {
        const Mat34* m = frames.frame(f);
        for (int j = 0; j < frames.joint_count; ++j) {
            glm::vec3 t{m[j].m[3], m[j].m[7], m[j].m[11]};
            lo = glm::min(lo, t);
            hi = glm::max(hi, t);
            BonePose p = decompose(m[j]);
            if (std::fabs(p.s - 1.0f) > 1e-4f) scaled = true;
            a.max_scale = std::max(a.max_scale, double(p.s));
        }
    }
    glm::vec3 ext = hi - lo;
    glm::vec3 margin = ext * 0.25f + glm::vec3(float(0.05 * a.diagonal));
    a.format.t_min = lo - margin;
    a.format.t_max = hi + margin;
    a.format.scaled = scaled;

    // RMS vertex motion per second between consecutive frames of one selection.
    std::vector<glm::vec3> p0(c.vertex_count()), p1(c.vertex_count());
    double sum = 0, n = 0;
    for (size_t f = 0; f + 1 < frames.frame_count(); ++f) {
        if (frames.selection_of_frame[f] != frames.selection_of_frame[f + 1]) continue;
        reference_positions(c, frames, f, p0);
        reference_positions(c, frames, f + 1, p1);
        double dt = frames.times[f + 1] - frames.times[f];
        if (!(dt > 0)) continue;
        for (size_t v = 0; v < p0.size(); ++v) {
            double d = glm::length(p1[v] - p0[v]) / dt;
            sum += d * d;
        }
        n += double(p0.size());
        if (n > 2e6) break;  // enough for an estimate
    }
    a.motion = n > 0 ? std::sqrt(sum / n) : 0.0;

    // Interpolation error over gaps of g frames (what a client shows between
    // two frames g ticks apart at 30 Hz), sampled at the middle of the gap.
    a.gap_error.assign(ServerAsset::kGapTable, 0.0);
    {
        std::vector<Mat34> pal(c.joint_count());
        std::vector<glm::vec3> ref(c.vertex_count()), got(c.vertex_count());
        for (int g = 2; g < ServerAsset::kGapTable; ++g) {
            double sq = 0, cnt = 0;
            const size_t stride = std::max<size_t>(1, frames.frame_count() / 24);
            for (size_t f = 0; f + size_t(g) < frames.frame_count(); f += stride) {
                if (frames.selection_of_frame[f] != frames.selection_of_frame[f + g]) continue;
                const int h = g / 2;
                const float alpha = float(h) / float(g);
                for (size_t j = 0; j < c.joint_count(); ++j)
                    pal[j] = compose(interpolate(decompose(frames.frame(f)[j]), decompose(frames.frame(f + g)[j]), alpha));
                reference_positions(c, frames, f + h, ref);
                skinning_job(c, pal, got).run();
                for (size_t v = 0; v < got.size(); ++v) {
                    glm::vec3 d = got[v] - ref[v];
                    sq += double(glm::dot(d, d));
                }
                cnt += double(got.size());
            }
            // Clips shorter than the gap: extrapolate from the motion.
            a.gap_error[g] = cnt > 0 ? std::sqrt(sq / cnt) : a.gap_error[g - 1] + a.motion / 30.0;
        }
    }

    a.hull = error_hull(s.error);
    a.e1 = s.error.empty() ? 0.0 : s.error[0].rms;
}

std::shared_ptr<ServerAsset> load_server_asset(const std::string& path) {
    auto a = std::make_shared<ServerAsset>();
    a->path = path;
    a->name = fs::path(path).filename().string();
    a->bytes = read_file(path);
    a->id = content_hash(a->bytes);
    ProgressiveAsset pa = load_progressive(path);
    a->character = std::move(pa.character);
    a->selections = default_training_set(a->character);
    if (pa.progressive && pa.skin.bone_count() == int(a->character.joint_count())) {
        a->skin = std::move(pa.skin);  // progressive glTF: joints already in progressive order
        a->progressive_file = true;
    } else {
        a->skin = build_progressive_skin(a->character, sample_frames(a->character, a->selections, 30.0));
    }
    finish_server_asset(*a);
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
