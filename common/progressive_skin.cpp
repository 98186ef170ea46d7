// progressive_skin.cpp — see progressive_skin.h. The build (Eigen least
// squares) is offline: offline/collapse.cpp.
#include "progressive_skin.h"

#include <algorithm>
#include <cmath>

#include "errors.h"
#include "error_metric.h"
#include "palette.h"
#include "skinning.h"

namespace progskin {

const char* strategy_name(Strategy s) {
    switch (s) {
        case Strategy::Reorder: return "reorder";
        case Strategy::Flatten: return "flatten";
        case Strategy::LeafPrune: return "leaf_prune";
        case Strategy::Scratch: return "scratch";
        case Strategy::Hierarchy: return "hierarchy";
    }
    return "?";
}

Strategy parse_strategy(const std::string& s) {
    if (s == "reorder") return Strategy::Reorder;
    if (s == "flatten") return Strategy::Flatten;
    if (s == "leaf_prune" || s == "leaf-prune") return Strategy::LeafPrune;
    if (s == "scratch") return Strategy::Scratch;
    if (s == "hierarchy") return Strategy::Hierarchy;
    throw Error("unknown strategy '" + s + "' (expected reorder, flatten, hierarchy or leaf_prune)");
}

namespace {
SkinningJob make_job(const Character& c, std::span<const uint16_t> joints, std::span<const float> weights,
                     int influences, std::span<const Mat34> palette, std::span<glm::vec3> out_positions) {
    SkinningJob j;
    j.positions = c.positions;
    j.joints = joints;
    j.weights = weights;
    j.influences = influences;
    j.max_influences = influences;
    j.palette = palette;
    j.out_positions = out_positions;
    return j;
}
}  // namespace

SkinningJob skinning_job(const Character& c, const ProgressiveSkin& s, std::span<const Mat34> palette,
                         std::span<glm::vec3> out_positions) {
    return make_job(c, s.joints, s.weights, s.influences, palette, out_positions);
}

SkinningJob skinning_job(const Character& c, std::span<const Mat34> palette, std::span<glm::vec3> out_positions) {
    return make_job(c, c.joints, c.weights, c.influences, palette, out_positions);
}

void lod_positions(const Character& c, const ProgressiveSkin& s, const FrameSet& frames, size_t f, int k,
                   std::span<glm::vec3> out) {
    const int B = s.bone_count();
    k = std::clamp(k, 1, B);
    std::vector<Mat34> own(static_cast<size_t>(k)), palette(static_cast<size_t>(B));
    const Mat34* Sf = frames.frame(f);
    for (int b = 0; b < k; ++b) own[b] = Sf[s.order[b]];
    PaletteJob pj{s.parents, s.corrections, own, {}, palette};
    if (!pj.validate()) throw Error("lod_positions: invalid progressive skin");
    pj.run();
    SkinningJob sj = skinning_job(c, s, palette, out);
    thread_local std::vector<glm::vec3> morphed;
    if (!c.morphs.empty()) {  // glTF order: morph targets at the frame's weights, then skinning
        morphed.resize(c.vertex_count());
        morph_positions(c, frames.weights(f), morphed);
        sj.positions = morphed;
    }
    if (!sj.validate()) throw Error("lod_positions: invalid skinning data");
    sj.run();
}

std::vector<LodError> evaluate_error_table(const Character& c, const ProgressiveSkin& s, const FrameSet& frames) {
    const int B = s.bone_count();
    const double diag = s.diagonal > 0 ? s.diagonal : rest_diagonal(c);
    std::vector<LodError> table;
    std::vector<glm::vec3> ref(c.vertex_count()), rec(c.vertex_count());
    for (int k = 1; k <= B; ++k) {
        ErrorAccumulator acc(diag);
        for (size_t f = 0; f < frames.frame_count(); ++f) {
            reference_positions(c, frames, f, ref);
            lod_positions(c, s, frames, f, k, rec);
            acc.add(ref, rec);
        }
        const ErrorStats st = acc.stats();
        // Distinct nearest-active-ancestor bones per vertex.
        std::vector<int> up(static_cast<size_t>(B));
        for (int b = 0; b < B; ++b) up[b] = b < k ? b : up[s.parents[b]];
        double owners = 0;
        for (size_t v = 0; v < c.vertex_count(); ++v) {
            int seen[8];
            int n = 0;
            for (int i = 0; i < s.influences; ++i) {
                if (s.weights[v * s.influences + i] == 0.0f) continue;
                const int o = up[s.joints[v * s.influences + i]];
                if (std::find(seen, seen + n, o) == seen + n) seen[n++] = o;
            }
            owners += n;
        }
        table.push_back({k, st.rms, st.max, st.rms_pct, st.max_pct,
                         c.vertex_count() ? owners / double(c.vertex_count()) : 0.0});
    }
    return table;
}

}  // namespace progskin
