// test_animation.cpp — channel interpolation (STEP, LINEAR, CUBICSPLINE), pose
// composition, clip selection and frame sampling on small hand-built characters.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/gtc/matrix_transform.hpp>

#include "animation.h"
#include "errors.h"

using namespace progskin;

namespace {

// Two nodes (root, child 1 unit up), one joint each, identity inverse binds, no clips.
Character two_bones() {
    Character c;
    c.name = "test";
    c.source = "two_bones";
    Node root;
    root.name = "root";
    Node child;
    child.name = "child";
    child.parent = 0;
    child.translation = {0, 1, 0};
    c.nodes = {root, child};
    c.joint_node = {0, 1};
    c.joint_parent = {-1, 0};
    c.inverse_bind = {glm::dmat4(1.0), glm::dmat4(1.0)};
    return c;
}

Channel channel(int node, ChannelPath path, Interpolation interp, std::vector<float> times,
                std::vector<float> values) {
    Channel ch;
    ch.node = node;
    ch.path = path;
    ch.interpolation = interp;
    ch.times = std::move(times);
    ch.values = std::move(values);
    return ch;
}

// Adds a clip with the given channels, start/end from their keys.
int add_clip(Character& c, const std::string& name, std::vector<Channel> channels) {
    Clip clip;
    clip.name = name;
    clip.gltf_index = int(c.clips.size());
    clip.start = 1e30f;
    clip.end = -1e30f;
    for (const Channel& ch : channels) {
        clip.start = std::min(clip.start, ch.times.front());
        clip.end = std::max(clip.end, ch.times.back());
    }
    clip.channels = std::move(channels);
    c.clips.push_back(std::move(clip));
    return int(c.clips.size()) - 1;
}

glm::dmat4 global_at(const Character& c, int clip, double t, int node) {
    std::vector<glm::dmat4> g(c.nodes.size());
    sample_node_globals(c, select_clips(c, std::to_string(clip)), t, g);
    return g[size_t(node)];
}

glm::dvec3 translation_of(const glm::dmat4& m) { return glm::dvec3(m[3]); }

void expect_vec(const glm::dvec3& a, const glm::dvec3& b, double tol = 1e-9) {
    EXPECT_NEAR(a.x, b.x, tol);
    EXPECT_NEAR(a.y, b.y, tol);
    EXPECT_NEAR(a.z, b.z, tol);
}

// Angle of the rotation part about z (the x axis image).
double z_angle_deg(const glm::dmat4& m) { return glm::degrees(std::atan2(m[0][1], m[0][0])); }

}  // namespace

TEST(Interpolation, StepHoldsPreviousKey) {
    Character c = two_bones();
    const int k = add_clip(c, "step", {channel(0, ChannelPath::Translation, Interpolation::Step, {0, 1, 2},
                                               {0, 0, 0, 1, 0, 0, 2, 0, 0})});
    expect_vec(translation_of(global_at(c, k, -1.0, 0)), {0, 0, 0});
    expect_vec(translation_of(global_at(c, k, 0.5, 0)), {0, 0, 0});
    expect_vec(translation_of(global_at(c, k, 0.999, 0)), {0, 0, 0});
    expect_vec(translation_of(global_at(c, k, 1.0, 0)), {1, 0, 0});
    expect_vec(translation_of(global_at(c, k, 1.999, 0)), {1, 0, 0});
    expect_vec(translation_of(global_at(c, k, 2.0, 0)), {2, 0, 0});
    expect_vec(translation_of(global_at(c, k, 9.0, 0)), {2, 0, 0});
    // The child follows its parent.
    expect_vec(translation_of(global_at(c, k, 1.5, 1)), {1, 1, 0});
}

TEST(Interpolation, LinearTranslationAndScale) {
    Character c = two_bones();
    const int k = add_clip(c, "lin", {channel(0, ChannelPath::Translation, Interpolation::Linear, {1, 3},
                                              {0, 0, 0, 4, 2, 0}),
                                      channel(0, ChannelPath::Scale, Interpolation::Linear, {1, 3},
                                              {1, 1, 1, 3, 1, 1})});
    expect_vec(translation_of(global_at(c, k, 0.0, 0)), {0, 0, 0});  // clamped before the first key
    expect_vec(translation_of(global_at(c, k, 1.5, 0)), {1, 0.5, 0});
    expect_vec(translation_of(global_at(c, k, 2.0, 0)), {2, 1, 0});
    EXPECT_NEAR(global_at(c, k, 2.0, 0)[0][0], 2.0, 1e-12);
    // Child: T(root) * S(root) * T(0,1,0) -> scale in x does not move it off the y axis.
    expect_vec(translation_of(global_at(c, k, 2.0, 1)), {2, 2, 0});
}

TEST(Interpolation, LinearRotationSlerpsShortestPath) {
    Character c = two_bones();
    const double s = std::sin(glm::radians(45.0)), co = std::cos(glm::radians(45.0));
    // Identity to 90 degrees about z.
    const int a = add_clip(c, "slerp", {channel(0, ChannelPath::Rotation, Interpolation::Linear, {0, 1},
                                                {0, 0, 0, 1, 0, 0, float(s), float(co)})});
    EXPECT_NEAR(z_angle_deg(global_at(c, a, 0.5, 0)), 45.0, 1e-5);
    EXPECT_NEAR(z_angle_deg(global_at(c, a, 0.25, 0)), 22.5, 1e-5);  // slerp: constant angular speed
    // The same rotation stored negated must not take the long way round.
    const int b = add_clip(c, "negated", {channel(0, ChannelPath::Rotation, Interpolation::Linear, {0, 1},
                                                  {0, 0, 0, 1, 0, 0, -float(s), -float(co)})});
    EXPECT_NEAR(z_angle_deg(global_at(c, b, 0.5, 0)), 45.0, 1e-5);
    // 170 degrees: slerp keeps angular speed uniform where nlerp would not.
    const double h = glm::radians(85.0);
    const int w = add_clip(c, "wide", {channel(0, ChannelPath::Rotation, Interpolation::Linear, {0, 1},
                                               {0, 0, 0, 1, 0, 0, float(std::sin(h)), float(std::cos(h))})});
    EXPECT_NEAR(z_angle_deg(global_at(c, w, 0.25, 0)), 42.5, 1e-4);
}

TEST(Interpolation, CubicSplineHermite) {
    Character c = two_bones();
    // Per key: in-tangent, value, out-tangent. Keys at t = 1 and t = 3 (delta 2).
    const int k = add_clip(c, "cubic", {channel(0, ChannelPath::Translation, Interpolation::CubicSpline, {1, 3},
                                                {9, 9, 9, 0, 1, 0, 1, 0, 0,     // key 0
                                                 0, 0, 3, 0, 2, 0, 7, 7, 7})});  // key 1
    // u = 0.5: h00 = 0.5, h10 = 0.125, h01 = 0.5, h11 = -0.125; tangents times delta 2.
    expect_vec(translation_of(global_at(c, k, 2.0, 0)), {0.25, 1.5, -0.75}, 1e-7);
    // u = 0.25: h00 = 0.84375, h10 = 0.140625, h01 = 0.15625, h11 = -0.046875.
    expect_vec(translation_of(global_at(c, k, 1.5, 0)),
               {0.140625 * 2, 0.84375 + 0.15625 * 2, -0.046875 * 2 * 3}, 1e-7);
    expect_vec(translation_of(global_at(c, k, 1.0, 0)), {0, 1, 0}, 1e-7);
    expect_vec(translation_of(global_at(c, k, 3.0, 0)), {0, 2, 0}, 1e-7);
    expect_vec(translation_of(global_at(c, k, 5.0, 0)), {0, 2, 0}, 1e-7);
}

TEST(Interpolation, CubicSplineRotationIsNormalised) {
    Character c = two_bones();
    const float s = float(std::sin(glm::radians(45.0))), co = float(std::cos(glm::radians(45.0)));
    // Zero tangents: the value eases from identity to 90 degrees; mid-way the raw sum is not unit length.
    const int k = add_clip(c, "cubic_rot", {channel(0, ChannelPath::Rotation, Interpolation::CubicSpline, {0, 1},
                                                    {0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0,
                                                     0, 0, 0, 0, 0, 0, s, co, 0, 0, 0, 0})});
    const glm::dmat4 m = global_at(c, k, 0.5, 0);
    EXPECT_NEAR(glm::length(glm::dvec3(m[0])), 1.0, 1e-9);  // pure rotation: unit axes
    EXPECT_NEAR(glm::determinant(glm::dmat3(m)), 1.0, 1e-9);
    EXPECT_NEAR(z_angle_deg(m), 45.0, 1e-5);  // symmetric ease: half way at u = 0.5
}

TEST(Pose, SkinningMatricesUseInverseBind) {
    Character c = two_bones();
    c.inverse_bind[1] = glm::translate(glm::dmat4(1.0), glm::dvec3(0, -1, 0));
    std::vector<glm::dmat4> m(2);
    sample_skinning_matrices(c, ClipSelection{}, 0.0, m);
    for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) EXPECT_NEAR(m[1][a][b], a == b ? 1.0 : 0.0, 1e-12);
    std::vector<glm::dmat4> wrong(3);
    EXPECT_THROW(sample_skinning_matrices(c, ClipSelection{}, 0.0, wrong), Error);
}

TEST(Pose, MatrixNodesAndUnorderedParents) {
    // Child listed before its parent; the parent has a matrix.
    Character c;
    Node child;
    child.parent = 1;
    child.translation = {0, 1, 0};
    Node parent;
    parent.has_matrix = true;
    parent.matrix = glm::translate(glm::dmat4(1.0), glm::dvec3(5, 0, 0)) * glm::scale(glm::dmat4(1.0), glm::dvec3(2));
    c.nodes = {child, parent};
    c.joint_node = {0};
    c.joint_parent = {-1};
    c.inverse_bind = {glm::dmat4(1.0)};
    std::vector<glm::dmat4> g(2);
    sample_node_globals(c, ClipSelection{}, 0.0, g);
    expect_vec(translation_of(g[0]), {5, 2, 0});
}

TEST(Pose, ClipsPlayTogether) {
    Character c = two_bones();
    add_clip(c, "a", {channel(0, ChannelPath::Translation, Interpolation::Linear, {0, 1}, {0, 0, 0, 1, 0, 0})});
    add_clip(c, "b", {channel(1, ChannelPath::Translation, Interpolation::Linear, {0.5f, 2}, {0, 1, 0, 0, 4, 0})});
    const ClipSelection both = select_clips(c, "all");
    EXPECT_FLOAT_EQ(both.start, 0.0f);
    EXPECT_FLOAT_EQ(both.end, 2.0f);
    std::vector<glm::dmat4> g(2);
    sample_node_globals(c, both, 1.0, g);
    expect_vec(translation_of(g[1]), {1, 1 + 3.0 / 1.5 * 0.5, 0});
    // Disjoint node sets: one selection of both clips.
    const auto training = default_training_set(c);
    ASSERT_EQ(training.size(), 1u);
    EXPECT_EQ(training[0].clips, (std::vector<int>{0, 1}));
}

TEST(ClipSelectionTest, OverlappingClipsTrainSeparately) {
    Character c = two_bones();
    add_clip(c, "walk", {channel(0, ChannelPath::Translation, Interpolation::Linear, {0, 1}, {0, 0, 0, 1, 0, 0})});
    add_clip(c, "run", {channel(0, ChannelPath::Rotation, Interpolation::Linear, {0, 2}, {0, 0, 0, 1, 0, 0, 0, 1})});
    const auto training = default_training_set(c);
    ASSERT_EQ(training.size(), 2u);
    EXPECT_EQ(training[0].clips, std::vector<int>{0});
    EXPECT_EQ(training[1].clips, std::vector<int>{1});
    EXPECT_FLOAT_EQ(training[1].end, 2.0f);
    EXPECT_EQ(select_clips(c, "run,walk").clips, (std::vector<int>{1, 0}));
    EXPECT_EQ(select_clips(c, " 1 ").clips, std::vector<int>{1});
    EXPECT_THROW(select_clips(c, "walk,jump"), Error);
    EXPECT_THROW(select_clips(c, ""), Error);
}

TEST(ClipSelectionTest, NoClipsGivesRestPose) {
    const Character c = two_bones();
    const auto training = default_training_set(c);
    ASSERT_EQ(training.size(), 1u);
    EXPECT_TRUE(training[0].clips.empty());
    const FrameSet fs = sample_frames(c, training, 30.0);
    EXPECT_EQ(fs.frame_count(), 1u);
}

TEST(Frames, CountTimesAndLayout) {
    Character c = two_bones();
    add_clip(c, "a", {channel(1, ChannelPath::Translation, Interpolation::Linear, {0.5f, 1.5f},
                              {0, 1, 0, 0, 3, 0})});
    add_clip(c, "b", {channel(1, ChannelPath::Translation, Interpolation::Linear, {0, 0.1f}, {0, 1, 0, 0, 1, 0})});
    const FrameSet fs = sample_frames(c, {select_clips(c, "a"), select_clips(c, "b")}, 10.0);
    // a: 0.5 .. 1.5 at 10 Hz -> 11 frames; b: 0 .. 0.1 -> 2 frames.
    ASSERT_EQ(fs.frame_count(), 13u);
    EXPECT_EQ(fs.joint_count, 2);
    EXPECT_EQ(fs.skinning.size(), 13u * 2u);
    EXPECT_DOUBLE_EQ(fs.times[0], 0.5);
    EXPECT_NEAR(fs.times[10], 1.5, 1e-9);
    EXPECT_EQ(fs.selection_of_frame[10], 0);
    EXPECT_EQ(fs.selection_of_frame[11], 1);
    EXPECT_DOUBLE_EQ(fs.times[11], 0.0);
    // Frame 5 (t = 1.0): child at y = 2; Mat34 is row-major with translation in column 3.
    const Mat34* m = fs.frame(5);
    EXPECT_NEAR(m[1].m[7], 2.0, 1e-6);
    EXPECT_NEAR(m[1].m[0], 1.0, 1e-6);
    EXPECT_THROW(sample_frames(c, {select_clips(c, "a")}, 0.0), Error);
}

// Key times come from the file: a clip spanning days is refused with a clear
// error instead of sampling millions of frames.
TEST(Frames, HugeClipSpanIsRefused) {
    Character c = two_bones();
    c.source = "long.gltf";
    add_clip(c, "forever", {channel(1, ChannelPath::Translation, Interpolation::Linear, {0.0f, 86400.0f},
                                    {0, 1, 0, 0, 3, 0})});
    try {
        sample_frames(c, {select_clips(c, "forever")}, 30.0);
        FAIL() << "expected an error";
    } catch (const Error& e) {
        EXPECT_NE(std::string(e.what()).find("long.gltf"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("limit"), std::string::npos) << e.what();
    }
    EXPECT_EQ(sample_frames(c, {select_clips(c, "forever")}, 1.0).frame_count(), 86401u);
}
