// Runtime: palette builder (copy-down with corrections), on/off blending
// without pops, CPU skinning (scalar and packed).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "animation.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "palette.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "skinning.h"
#include "synthetic.h"

using namespace progskin;

namespace {

std::string asset(const char* name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }

double max_dist(const std::vector<glm::vec3>& a, const std::vector<glm::vec3>& b) {
    double m = 0;
    for (size_t i = 0; i < a.size(); ++i) m = std::max(m, double(glm::length(a[i] - b[i])));
    return m;
}

// Skins frame f of a progressive skin with the given own bones and presence.
std::vector<glm::vec3> skin_frame(const Character& c, const ProgressiveSkin& s, const FrameSet& fr, size_t f,
                                  int n, std::span<const float> presence) {
    std::vector<Mat34> own(static_cast<size_t>(n)), pal(static_cast<size_t>(s.bone_count()));
    for (int b = 0; b < n; ++b) own[b] = fr.frame(f)[s.order[b]];
    PaletteJob pj{s.parents, s.corrections, own, presence, pal};
    EXPECT_TRUE(pj.validate());
    pj.run();
    std::vector<glm::vec3> out(c.vertex_count());
    SkinningJob sj{c.positions, {}, s.joints, s.weights, s.influences, s.influences, pal, out, {}};
    EXPECT_TRUE(sj.validate());
    sj.run();
    return out;
}

}  // namespace

TEST(Palette, CopyDownWithCorrections) {
    // Chain 0 <- 1 <- 2, corrections translate by +1 in x each.
    std::vector<int16_t> parents = {-1, 0, 1};
    Mat34 t = Mat34::identity();
    t.m[3] = 1.0f;
    std::vector<Mat34> corr = {Mat34::identity(), t, t};
    Mat34 root = Mat34::identity();
    root.m[7] = 5.0f;
    std::vector<Mat34> own = {root}, out(3);
    PaletteJob pj{parents, corr, own, {}, out};
    ASSERT_TRUE(pj.validate());
    pj.run();
    EXPECT_FLOAT_EQ(out[1].m[3], 1.0f);
    EXPECT_FLOAT_EQ(out[2].m[3], 2.0f);
    EXPECT_FLOAT_EQ(out[2].m[7], 5.0f);
    // Presence 0.5 for bone 1 blends its own matrix with its stand-in.
    Mat34 b1 = Mat34::identity();
    b1.m[3] = 3.0f;
    std::vector<Mat34> own2 = {root, b1};
    std::vector<float> presence = {1.0f, 0.5f};
    PaletteJob pj2{parents, corr, own2, presence, out};
    ASSERT_TRUE(pj2.validate());
    pj2.run();
    EXPECT_FLOAT_EQ(out[1].m[3], 2.0f);  // (1 + 3) / 2
    EXPECT_FLOAT_EQ(out[2].m[3], 3.0f);  // child follows the blended parent
}

TEST(Palette, ValidateRejectsBadInput) {
    std::vector<Mat34> own = {Mat34::identity()}, out(3), corr(3, Mat34::identity());
    std::vector<int16_t> cyclic = {-1, 2, 1};
    EXPECT_FALSE((PaletteJob{cyclic, corr, own, {}, out}.validate()));
    std::vector<int16_t> parents = {-1, 0, 0};
    std::vector<Mat34> small(2);
    EXPECT_FALSE((PaletteJob{parents, corr, own, {}, small}.validate()));
    std::vector<Mat34> none;
    EXPECT_FALSE((PaletteJob{parents, corr, none, {}, out}.validate()));
    std::vector<float> bad_presence = {1.0f, 1.0f};
    EXPECT_FALSE((PaletteJob{parents, corr, own, bad_presence, out}.validate()));
}

TEST(LodBlender, RampsOverBlendFrames) {
    LodBlender bl(10, 4, 2);
    EXPECT_EQ(bl.needed(), 2);
    bl.set_target(5);
    bl.step();
    EXPECT_EQ(bl.needed(), 5);
    EXPECT_FLOAT_EQ(bl.presence()[4], 0.25f);
    for (int i = 0; i < 3; ++i) bl.step();
    EXPECT_TRUE(bl.settled());
    bl.set_target(1);
    bl.step();
    EXPECT_EQ(bl.needed(), 5);  // fading out, still needs its own matrix
    EXPECT_FLOAT_EQ(bl.presence()[4], 0.75f);
    for (int i = 0; i < 3; ++i) bl.step();
    EXPECT_EQ(bl.needed(), 1);
}

// Switching from 2 bones to all and back, mid-animation. Without blending the
// switch frame jumps by the whole LOD gap; with blending over n frames the
// per-frame change stays within the motion itself plus gap / n, and is smaller
// than the pop. Measured figures are printed.
TEST(LodBlender, SwitchingDoesNotPop) {
    const Character c = import_character(asset("Fox.glb"));
    const FrameSet fr = sample_frames(c, {select_clips(c, "Survey")}, 30.0);
    BuildOptions opt;
    const ProgressiveSkin s = build_progressive_skin(c, fr, opt);
    const int B = s.bone_count(), lo = 2, n = 8;
    const size_t on_at = 30, off_at = 60, end = 90;
    ASSERT_GT(fr.frame_count(), end);
    std::vector<float> ones(static_cast<size_t>(B), 1.0f);
    double motion = 0, gap = 0, pop = 0, blended = 0;
    std::vector<glm::vec3> prev_full, prev_pop, prev_blend;
    LodBlender bl(B, n, lo);
    for (size_t f = on_at - 5; f < end; ++f) {
        const auto full = skin_frame(c, s, fr, f, B, ones);
        const auto low = skin_frame(c, s, fr, f, lo, std::span<const float>(ones.data(), lo));
        gap = std::max(gap, max_dist(full, low));
        const bool high = f >= on_at && f < off_at;
        const auto popping = high ? full : low;
        bl.set_target(high ? B : lo);
        bl.step();
        const auto blend = skin_frame(c, s, fr, f, bl.needed(), bl.presence());
        if (!prev_full.empty()) {
            motion = std::max({motion, max_dist(full, prev_full), max_dist(low, skin_frame(c, s, fr, f - 1, lo, std::span<const float>(ones.data(), lo)))});
            pop = std::max(pop, max_dist(popping, prev_pop));
            blended = std::max(blended, max_dist(blend, prev_blend));
        }
        prev_full = full;
        prev_pop = popping;
        prev_blend = blend;
    }
    const double diag = rest_diagonal(c);
    std::printf("per-frame max vertex change (%% of diagonal): motion %.3f, LOD gap %.3f, "
                "switch without blending %.3f, with %d-frame blending %.3f\n",
                100 * motion / diag, 100 * gap / diag, 100 * pop / diag, n, 100 * blended / diag);
    EXPECT_GT(pop, motion + 0.5 * gap);             // the unblended switch pops
    EXPECT_LE(blended, motion + gap / n + 1e-4 * diag);  // the blended one moves smoothly
    EXPECT_LT(blended, 0.5 * pop);
}

TEST(Skinning, StreamMatchesScalarForEveryInfluenceCount) {
    const Character c = import_character(asset("CesiumMan.glb"));
    const FrameSet fr = sample_frames(c, {select_clips(c, "all")}, 5.0);
    std::span<const Mat34> pal(fr.frame(3), c.joint_count());
    for (int m : {1, 2, 3, 4}) {
        std::vector<glm::vec3> p1(c.vertex_count()), n1(c.vertex_count()), p2(c.vertex_count()),
            n2(c.vertex_count());
        SkinningJob sj{c.positions, c.normals, c.joints, c.weights, c.influences, m, pal, p1, n1};
        ASSERT_TRUE(sj.validate());
        sj.run();
        SkinStream st;
        ASSERT_TRUE(build_skin_stream(st, sj, SkinWeightFormat::F32));
        SkinRunOptions o;
        o.renormalize = true;  // SkinningJob::run renormalises normals
        ASSERT_TRUE(skin_stream(st, pal, p2, n2, o));
        const double diag = rest_diagonal(c);
        EXPECT_LE(max_dist(p1, p2), 1e-6 * diag) << m << " influences";
        EXPECT_LE(max_dist(n1, n2), 1e-4) << m << " influences";
    }
}

TEST(Skinning, RejectsOutOfRangeJointsAndSizes) {
    std::vector<glm::vec3> pos(2, glm::vec3(1)), out(2);
    std::vector<uint16_t> joints = {0, 0, 0, 0, 5, 0, 0, 0};
    std::vector<float> w = {1, 0, 0, 0, 1, 0, 0, 0};
    std::vector<Mat34> pal(2, Mat34::identity());
    EXPECT_FALSE((SkinningJob{pos, {}, joints, w, 4, 4, pal, out, {}}.validate()));
    joints[4] = 1;
    EXPECT_TRUE((SkinningJob{pos, {}, joints, w, 4, 4, pal, out, {}}.validate()));
    std::vector<glm::vec3> short_out(1);
    EXPECT_FALSE((SkinningJob{pos, {}, joints, w, 4, 4, pal, short_out, {}}.validate()));
    SkinStream st;
    ASSERT_TRUE(build_skin_stream(st, SkinningJob{pos, {}, joints, w, 4, 4, pal, out, {}}));
    std::vector<Mat34> tiny(1);
    EXPECT_FALSE(skin_stream(st, tiny, out));
}

TEST(Skinning, InfluenceLimitRenormalises) {
    std::vector<glm::vec3> pos = {{1, 0, 0}}, out(1);
    std::vector<uint16_t> joints = {0, 1, 0, 0};
    std::vector<float> w = {0.75f, 0.25f, 0, 0};
    Mat34 shift = Mat34::identity();
    shift.m[3] = 4.0f;
    std::vector<Mat34> pal = {Mat34::identity(), shift};
    SkinningJob sj{pos, {}, joints, w, 4, 2, pal, out, {}};
    sj.run();
    EXPECT_FLOAT_EQ(out[0].x, 2.0f);
    sj.max_influences = 1;
    sj.run();
    EXPECT_FLOAT_EQ(out[0].x, 1.0f);
}
