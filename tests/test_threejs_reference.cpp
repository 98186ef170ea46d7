// test_threejs_reference.cpp — the importer and sampler against an independent glTF
// implementation: world-space skinned vertices computed by three.js
// (scripts/threejs_reference/generate.mjs, stored in tests/data/threejs/) must
// match ours to 1e-4 of the rest-pose bounding-box diagonal. skinned_morph.gltf
// (tests/data/make_gltf_fixtures.py) checks morph targets and their weight
// animation (glTF order: morphs, then skinning; common/error_metric.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "animation.h"
#include "error_metric.h"
#include "gltf_import.h"

using namespace progskin;

namespace {

// v = sum_i w_i * M_j(i) * v_bind for every vertex: the reference skinning loop,
// over the bind positions with the morph targets at `weights` (empty: defaults).
std::vector<glm::dvec3> skin(const Character& c, const Mat34* m, std::span<const float> weights = {}) {
    std::vector<glm::vec3> bind(c.vertex_count());
    morph_positions(c, weights, bind);
    std::vector<glm::dvec3> out(c.vertex_count());
    const size_t k = size_t(c.influences);
    for (size_t v = 0; v < out.size(); ++v) {
        glm::dvec3 sum(0.0);
        for (size_t i = 0; i < k; ++i) {
            const float w = c.weights[v * k + i];
            if (w == 0.0f) continue;
            const float* r = m[c.joints[v * k + i]].m;
            const glm::dvec3 p(bind[v]);
            sum += double(w) * glm::dvec3(r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3],
                                          r[4] * p.x + r[5] * p.y + r[6] * p.z + r[7],
                                          r[8] * p.x + r[9] * p.y + r[10] * p.z + r[11]);
        }
        out[v] = sum;
    }
    return out;
}

// Diagonal of the bounding box of the vertices skinned at rest pose, morph targets at
// their default weights (docs/metrics.md §2).
double rest_diagonal_of(const Character& c) {
    const FrameSet rest = sample_frames(c, {ClipSelection{}}, 30.0);
    glm::dvec3 lo(1e300), hi(-1e300);
    for (const glm::dvec3& p : skin(c, rest.frame(0))) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    return glm::length(hi - lo);
}

// Max deviation from the three.js positions, as a fraction of the diagonal, over all stored
// times. without_morphs: the same with every morph weight 0 (what ignoring morphs costs).
double max_relative_deviation(const std::string& asset, const std::string& reference, double* without_morphs = nullptr,
                              const std::string& dir = PROGSKIN_ASSETS) {
    const Character c = import_character(dir + "/" + asset);
    std::ifstream in(std::string(PROGSKIN_TEST_DATA) + "/threejs/" + reference);
    EXPECT_TRUE(in.good()) << reference;
    const nlohmann::json ref = nlohmann::json::parse(in);
    EXPECT_EQ(ref["vertex_count"].get<size_t>(), c.vertex_count());
    const ClipSelection sel = select_clips(c, ref["clip"].get<std::string>());
    const double diagonal = rest_diagonal_of(c);
    double worst = 0.0;
    for (const auto& frame : ref["frames"]) {
        const double t = frame["time"].get<double>();
        ClipSelection at_t = sel;
        at_t.start = at_t.end = float(t);  // one frame at exactly t
        const FrameSet fs = sample_frames(c, {at_t}, 30.0);
        EXPECT_EQ(fs.frame_count(), 1u);
        EXPECT_DOUBLE_EQ(fs.times[0], double(float(t)));
        const std::vector<glm::dvec3> ours = skin(c, fs.frame(0), fs.weights(0));
        const std::vector<float> zero(c.morphs.size(), 0.0f);
        const std::vector<glm::dvec3> unmorphed = skin(c, fs.frame(0), zero);
        const auto& theirs = frame["positions"];
        EXPECT_EQ(theirs.size(), 3 * ours.size());
        double frame_worst = 0.0, frame_unmorphed = 0.0;
        for (size_t v = 0; v < ours.size() && 3 * v + 2 < theirs.size(); ++v) {
            const glm::dvec3 p(theirs[3 * v].get<double>(), theirs[3 * v + 1].get<double>(),
                               theirs[3 * v + 2].get<double>());
            frame_worst = std::max(frame_worst, glm::length(p - ours[v]));
            frame_unmorphed = std::max(frame_unmorphed, glm::length(p - unmorphed[v]));
        }
        if (without_morphs) *without_morphs = std::max(*without_morphs, frame_unmorphed / diagonal);
        std::printf("%s t=%.4f: max deviation %.3g (%.3g of diagonal %.4g)\n", asset.c_str(), t, frame_worst,
                    frame_worst / diagonal, diagonal);
        worst = std::max(worst, frame_worst / diagonal);
    }
    return worst;
}

}  // namespace

TEST(ThreeJsReference, RiggedSimple) {
    EXPECT_LE(max_relative_deviation("RiggedSimple.gltf", "RiggedSimple.json"), 1e-4);
}

TEST(ThreeJsReference, CesiumManAllClipsTogether) {
    EXPECT_LE(max_relative_deviation("CesiumMan.glb", "CesiumMan.json"), 1e-4);
}

TEST(ThreeJsReference, FoxSurvey) {
    EXPECT_LE(max_relative_deviation("Fox.glb", "Fox.json"), 1e-4);
}

TEST(ThreeJsReference, SkinnedMorphTalk) {
    // Weights animated by a CUBICSPLINE channel together with a joint, a sparse
    // target, two primitives, mesh and node default weights, a rigid mesh's target.
    double without_morphs = 0.0;
    const double with_morphs = max_relative_deviation("skinned_morph.gltf", "skinned_morph.json", &without_morphs,
                                                      PROGSKIN_TEST_DATA);
    std::printf("skinned_morph talk: max deviation %.3g of the diagonal with morphs, %.3g ignoring them\n",
                with_morphs, without_morphs);
    EXPECT_LE(with_morphs, 1e-4);
    EXPECT_GT(without_morphs, 1e-2);  // the fixture's morphs are visible: ignoring them would fail
}

TEST(ThreeJsReference, SkinnedMorphCommonReference) {
    // reference_positions (what pose, --verify and the error metric use) is the loop above.
    const Character c = import_character(std::string(PROGSKIN_TEST_DATA) + "/skinned_morph.gltf");
    const FrameSet fs = sample_pose(c, select_clips(c, "talk"), 0.37);
    std::vector<glm::vec3> ref(c.vertex_count());
    reference_positions(c, fs, 0, ref);
    const std::vector<glm::dvec3> loop = skin(c, fs.frame(0), fs.weights(0));
    for (size_t v = 0; v < ref.size(); ++v) EXPECT_LT(glm::length(glm::dvec3(ref[v]) - loop[v]), 1e-5) << v;
}
