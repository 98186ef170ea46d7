// test_threejs_reference.cpp — the importer and sampler against an independent glTF
// implementation: world-space skinned vertices computed by three.js
// (scripts/threejs_reference/generate.mjs, stored in tests/data/threejs/) must
// match ours to 1e-4 of the rest-pose bounding-box diagonal.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "animation.h"
#include "gltf_import.h"

using namespace progskin;

namespace {

// v = sum_i w_i * M_j(i) * v_bind for every vertex: the reference skinning loop.
std::vector<glm::dvec3> skin(const Character& c, const Mat34* m) {
    std::vector<glm::dvec3> out(c.vertex_count());
    const size_t k = size_t(c.influences);
    for (size_t v = 0; v < out.size(); ++v) {
        glm::dvec3 sum(0.0);
        for (size_t i = 0; i < k; ++i) {
            const float w = c.weights[v * k + i];
            if (w == 0.0f) continue;
            const float* r = m[c.joints[v * k + i]].m;
            const glm::dvec3 p(c.positions[v]);
            sum += double(w) * glm::dvec3(r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3],
                                          r[4] * p.x + r[5] * p.y + r[6] * p.z + r[7],
                                          r[8] * p.x + r[9] * p.y + r[10] * p.z + r[11]);
        }
        out[v] = sum;
    }
    return out;
}

// Diagonal of the bounding box of the vertices skinned at rest pose (GUIDE.md §2).
double rest_diagonal_of(const Character& c) {
    const FrameSet rest = sample_frames(c, {ClipSelection{}}, 30.0);
    glm::dvec3 lo(1e300), hi(-1e300);
    for (const glm::dvec3& p : skin(c, rest.frame(0))) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    return glm::length(hi - lo);
}

// Max deviation from the three.js positions, as a fraction of the diagonal, over all stored times.
double max_relative_deviation(const std::string& asset, const std::string& reference) {
    const Character c = import_character(std::string(PROGSKIN_ASSETS) + "/" + asset);
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
        const std::vector<glm::dvec3> ours = skin(c, fs.frame(0));
        const auto& theirs = frame["positions"];
        EXPECT_EQ(theirs.size(), 3 * ours.size());
        double frame_worst = 0.0;
        for (size_t v = 0; v < ours.size() && 3 * v + 2 < theirs.size(); ++v) {
            const glm::dvec3 p(theirs[3 * v].get<double>(), theirs[3 * v + 1].get<double>(),
                               theirs[3 * v + 2].get<double>());
            frame_worst = std::max(frame_worst, glm::length(p - ours[v]));
        }
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
