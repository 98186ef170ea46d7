// The error metric (common/error_metric.h, docs/metrics.md §2): RMS and max
// of the vertex distance, in model units and in % of the rest-pose diagonal;
// the rest diagonal itself; morph targets applied before skinning.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "animation.h"
#include "error_metric.h"
#include "gltf_import.h"

using namespace progskin;

namespace {

std::string asset(const char* name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }
std::string test_data(const char* name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }

// A unit cube (8 corners) skinned rigidly to one joint whose node sits at
// `translation` with `scale`, inverse bind identity: its rest pose is the
// cube moved and scaled by the node's rest transform.
Character unit_cube(glm::dvec3 translation = glm::dvec3(0.0), double scale = 1.0) {
    Character c;
    c.name = "unit cube";
    Node n;
    n.name = "root";
    n.translation = translation;
    n.scale = glm::dvec3(scale);
    c.nodes.push_back(n);
    c.joint_node = {0};
    c.joint_parent = {-1};
    c.inverse_bind = {glm::dmat4(1.0)};
    c.influences = 4;
    for (int i = 0; i < 8; ++i) {
        c.positions.emplace_back(float(i & 1), float((i >> 1) & 1), float((i >> 2) & 1));
        c.joints.insert(c.joints.end(), {0, 0, 0, 0});
        c.weights.insert(c.weights.end(), {1.0f, 0.0f, 0.0f, 0.0f});
    }
    PrimitiveRange pr;
    pr.count = 8;
    c.primitives.push_back(pr);
    return c;
}

// Reference vertices of Fox at a few frames of its default training set.
struct FoxFrames {
    Character c = import_character(asset("Fox.glb"));
    FrameSet frames = sample_frames(c, default_training_set(c), 10.0);
    double diagonal = rest_diagonal(c);
    std::vector<glm::vec3> at(size_t f) const {
        std::vector<glm::vec3> out(c.vertex_count());
        reference_positions(c, frames, f, out);
        return out;
    }
};
const FoxFrames& fox() {
    static const FoxFrames f;
    return f;
}

}  // namespace

TEST(ErrorMetric, IdenticalInputsGiveZero) {
    const FoxFrames& fx = fox();
    ASSERT_GT(fx.frames.frame_count(), 10u);
    ErrorAccumulator acc(fx.diagonal);
    for (size_t f = 0; f < fx.frames.frame_count(); f += 7) {
        const auto v = fx.at(f);
        acc.add(v, v);
    }
    const ErrorStats s = acc.stats();
    EXPECT_GT(s.samples, 0.0);
    EXPECT_EQ(s.rms, 0.0);
    EXPECT_EQ(s.max, 0.0);
    EXPECT_EQ(s.rms_pct, 0.0);
    EXPECT_EQ(s.max_pct, 0.0);
}

TEST(ErrorMetric, EmptyAccumulatorReportsNothing) {
    const ErrorStats s = ErrorAccumulator(2.0).stats();
    EXPECT_EQ(s.samples, 0.0);
    EXPECT_EQ(s.rms, 0.0);
    EXPECT_EQ(s.max, 0.0);
}

// Every vertex moved by the same vector of length d: RMS = max = d, and the
// percentages are 100 d / diagonal.
TEST(ErrorMetric, ConstantOffsetGivesItsLengthEverywhere) {
    const FoxFrames& fx = fox();
    const glm::vec3 dir = glm::normalize(glm::vec3(1.0f, -2.0f, 0.5f));
    for (const double d : {0.001 * fx.diagonal, 0.05 * fx.diagonal, 1.0}) {
        SCOPED_TRACE(d);
        ErrorAccumulator acc(fx.diagonal);
        size_t vertices = 0;
        for (size_t f = 0; f < fx.frames.frame_count(); f += 5) {
            const auto ref = fx.at(f);
            std::vector<glm::vec3> moved(ref);
            for (auto& v : moved) v += float(d) * dir;
            acc.add(ref, moved);
            vertices += ref.size();
        }
        const ErrorStats s = acc.stats();
        // Float positions: the offset survives to about 1e-7 of the coordinates.
        const double tol = 1e-6 * fx.diagonal;
        EXPECT_EQ(s.samples, double(vertices));
        EXPECT_NEAR(s.rms, d, tol);
        EXPECT_NEAR(s.max, d, tol);
        EXPECT_NEAR(s.rms_pct, 100.0 * d / fx.diagonal, 100.0 * tol / fx.diagonal);
        EXPECT_NEAR(s.max_pct, 100.0 * d / fx.diagonal, 100.0 * tol / fx.diagonal);
    }
}

// RMS pools the squares of every sample; max is the largest single one.
TEST(ErrorMetric, RmsAndMaxOfKnownDistances) {
    const std::vector<glm::vec3> ref(4, glm::vec3(0.0f));
    const std::vector<glm::vec3> got = {{3, 0, 0}, {0, 4, 0}, {0, 0, 0}, {0, 0, 0}};
    ErrorAccumulator acc(10.0);
    acc.add(ref, got);
    const ErrorStats s = acc.stats();
    EXPECT_DOUBLE_EQ(s.rms, std::sqrt((9.0 + 16.0) / 4.0));
    EXPECT_DOUBLE_EQ(s.max, 4.0);
    EXPECT_DOUBLE_EQ(s.rms_pct, 10.0 * std::sqrt(25.0 / 4.0));
    EXPECT_DOUBLE_EQ(s.max_pct, 40.0);
    EXPECT_EQ(s.samples, 4.0);
}

// Accumulating frame by frame, vertex range by vertex range, or through
// add_squared gives the figures of one add over everything.
TEST(ErrorMetric, AccumulatingInPartsEqualsAtOnce) {
    const FoxFrames& fx = fox();
    std::vector<glm::vec3> all_ref, all_got;
    ErrorAccumulator per_frame(fx.diagonal), per_half(fx.diagonal), squared(fx.diagonal);
    for (size_t f = 0; f + 1 < fx.frames.frame_count(); f += 6) {
        const auto ref = fx.at(f), got = fx.at(f + 1);  // the next frame: a real, uneven error
        per_frame.add(ref, got);
        const size_t h = ref.size() / 3;
        per_half.add(std::span(ref).first(h), std::span(got).first(h));
        per_half.add(std::span(ref).subspan(h), std::span(got).subspan(h));
        double sum = 0, mx = 0;
        for (size_t v = 0; v < ref.size(); ++v) {
            const double e = glm::length(glm::dvec3(ref[v]) - glm::dvec3(got[v]));
            sum += e * e;
            mx = std::max(mx, e);
        }
        squared.add_squared(sum, mx, double(ref.size()));
        all_ref.insert(all_ref.end(), ref.begin(), ref.end());
        all_got.insert(all_got.end(), got.begin(), got.end());
    }
    ErrorAccumulator once(fx.diagonal);
    once.add(all_ref, all_got);
    const ErrorStats o = once.stats();
    ASSERT_GT(o.rms, 0.0);
    for (const ErrorAccumulator* acc : {&per_frame, &per_half, &squared}) {
        const ErrorStats p = acc->stats();
        EXPECT_EQ(p.samples, o.samples);
        EXPECT_NEAR(p.rms, o.rms, 1e-12 * o.rms);
        EXPECT_NEAR(p.max, o.max, 1e-6 * o.max);
        EXPECT_NEAR(p.rms_pct, o.rms_pct, 1e-12 * o.rms_pct);
    }
}

// The diagonal is that of the vertices skinned at every node's rest
// transform: a unit cube's is sqrt(3), moved by its joint's node it is the
// same, scaled by 2 it doubles.
TEST(ErrorMetric, RestDiagonalOfAUnitCube) {
    EXPECT_NEAR(rest_diagonal(unit_cube()), std::sqrt(3.0), 1e-6);
    EXPECT_NEAR(rest_diagonal(unit_cube(glm::dvec3(5.0, -2.0, 1.0))), std::sqrt(3.0), 1e-5);
    EXPECT_NEAR(rest_diagonal(unit_cube(glm::dvec3(0.0), 2.0)), 2.0 * std::sqrt(3.0), 1e-6);
    const auto p = rest_pose_positions(unit_cube(glm::dvec3(5.0, -2.0, 1.0)));
    ASSERT_EQ(p.size(), 8u);
    EXPECT_NEAR(p[7].x, 6.0f, 1e-6f);
    EXPECT_NEAR(p[7].y, -1.0f, 1e-6f);
    EXPECT_NEAR(p[7].z, 2.0f, 1e-6f);
    // A diagonal of 0 (no extent) reports percentages of one model unit.
    ErrorAccumulator flat(0.0);
    flat.add(std::vector<glm::vec3>{{0, 0, 0}}, std::vector<glm::vec3>{{0.5f, 0, 0}});
    EXPECT_DOUBLE_EQ(flat.stats().max_pct, 50.0);
}

// tests/data/basic.glb: a 1 x 2 quad on two joints, at rest as in its file.
TEST(ErrorMetric, RestDiagonalOfTheBasicFixture) {
    const Character c = import_character(test_data("basic.glb"));
    EXPECT_NEAR(rest_diagonal(c), std::sqrt(5.0), 1e-6);
}

// morph_positions: bind positions plus sum_m w_m delta_m (tests/data/skinned_morph.gltf:
// 4 targets, dense and sparse); empty weights mean the file's default weights.
TEST(ErrorMetric, MorphPositionsApplyTheWeights) {
    const Character c = import_character(test_data("skinned_morph.gltf"));
    const size_t n = c.vertex_count(), M = c.morphs.size();
    ASSERT_EQ(M, 4u);
    std::vector<glm::vec3> out(n);
    // Zero weights: the bind positions.
    const std::vector<float> zero(M, 0.0f);
    morph_positions(c, zero, out);
    for (size_t v = 0; v < n; ++v) EXPECT_EQ(out[v], c.positions[v]) << v;
    // One unit weight: exactly that target's deltas on its listed vertices, nothing elsewhere.
    for (size_t m = 0; m < M; ++m) {
        SCOPED_TRACE(c.morphs[m].name);
        std::vector<float> w(M, 0.0f);
        w[m] = 1.0f;
        morph_positions(c, w, out);
        std::vector<glm::vec3> delta(n, glm::vec3(0.0f));
        for (size_t i = 0; i < c.morphs[m].vertices.size(); ++i)
            delta[c.morphs[m].vertices[i]] = c.morphs[m].position_deltas[i];
        size_t moved = 0;
        for (size_t v = 0; v < n; ++v) {
            EXPECT_NEAR(glm::length(out[v] - (c.positions[v] + delta[v])), 0.0f, 1e-6f) << v;
            moved += out[v] != c.positions[v];
        }
        EXPECT_GT(moved, 0u);
    }
    // Linear: weights (0.5, -1.25, 0, 2) move each vertex by that sum of deltas.
    const std::vector<float> w = {0.5f, -1.25f, 0.0f, 2.0f};
    morph_positions(c, w, out);
    std::vector<glm::vec3> want(c.positions);
    for (size_t m = 0; m < M; ++m)
        for (size_t i = 0; i < c.morphs[m].vertices.size(); ++i)
            want[c.morphs[m].vertices[i]] += w[m] * c.morphs[m].position_deltas[i];
    for (size_t v = 0; v < n; ++v) EXPECT_NEAR(glm::length(out[v] - want[v]), 0.0f, 1e-5f) << v;
    // Empty weights: every target at its default weight, as the explicit list.
    std::vector<float> defaults(M);
    for (size_t m = 0; m < M; ++m) defaults[m] = c.morphs[m].default_weight;
    ASSERT_NE(defaults, zero);  // the fixture has non-zero defaults (0.25 puff, 0.2 hat)
    std::vector<glm::vec3> by_default(n);
    morph_positions(c, {}, by_default);
    morph_positions(c, defaults, out);
    for (size_t v = 0; v < n; ++v) EXPECT_EQ(by_default[v], out[v]) << v;
}

// The reference of a frame with morph targets is the morphed mesh skinned;
// the unmorphed skinned mesh differs by the morph error, which the metric
// measures and morph_importance predicts per unit weight.
TEST(ErrorMetric, MorphImportanceIsTheRmsOfAUnitWeight) {
    const Character c = import_character(test_data("skinned_morph.gltf"));
    const std::vector<double> imp = morph_importance(c);
    ASSERT_EQ(imp.size(), c.morphs.size());
    std::vector<glm::vec3> out(c.vertex_count());
    for (size_t m = 0; m < c.morphs.size(); ++m) {
        std::vector<float> w(c.morphs.size(), 0.0f);
        w[m] = 1.0f;
        morph_positions(c, w, out);
        ErrorAccumulator acc(1.0);
        acc.add(c.positions, out);
        EXPECT_GT(imp[m], 0.0) << m;
        EXPECT_NEAR(acc.stats().rms, imp[m], 1e-6) << m;
    }
}

// Full detail against itself through the two reference paths: a character
// without morph targets skins the same with and without them.
TEST(ErrorMetric, ReferenceWithoutMorphsIsTheSkinnedBind) {
    const FoxFrames& fx = fox();
    ASSERT_TRUE(fx.c.morphs.empty());
    std::vector<glm::vec3> a(fx.c.vertex_count()), b(fx.c.vertex_count());
    ErrorAccumulator acc(fx.diagonal);
    for (size_t f = 0; f < fx.frames.frame_count(); f += 9) {
        reference_positions(fx.c, fx.frames, f, a);
        skinned_bind_positions(fx.c, fx.frames, f, b);
        acc.add(a, b);
    }
    EXPECT_GT(acc.stats().samples, 0.0);
    EXPECT_EQ(acc.stats().max, 0.0);
}
