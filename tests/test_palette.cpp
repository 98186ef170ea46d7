// The runtime palette (common/palette.h, docs/metrics.md §1 "LOD k"): with
// every bone active it is the input; an inactive bone stands in as its
// nearest active ancestor's matrix times the corrections down to it; a bone
// switched on or off by the LodBlender moves continuously; malformed jobs are
// refused by validate(). On Fox's progressive skin (fitted corrections).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "animation.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "palette.h"
#include "collapse.h"
#include "progressive_skin.h"

using namespace progskin;

namespace {

struct FoxSkin {
    Character c = import_character(std::string(PROGSKIN_ASSETS) + "/Fox.glb");
    FrameSet frames = sample_frames(c, {select_clips(c, "Survey")}, 10.0);
    ProgressiveSkin s = build_progressive_skin(c, frames);
    double diagonal = rest_diagonal(c);
    int B() const { return s.bone_count(); }
    // Own matrices of bones 0..n-1 at frame f (progressive order).
    std::vector<Mat34> own(size_t f, int n) const {
        std::vector<Mat34> o(static_cast<size_t>(n));
        for (int b = 0; b < n; ++b) o[size_t(b)] = frames.frame(f)[s.order[size_t(b)]];
        return o;
    }
    // Palette at frame f with n own bones and the given presence (empty: all 1).
    std::vector<Mat34> palette(size_t f, int n, std::span<const float> presence = {}) const {
        const std::vector<Mat34> o = own(f, n);
        std::vector<Mat34> out(static_cast<size_t>(B()));
        const PaletteJob job{s.parents, s.corrections, o, presence, out};
        EXPECT_TRUE(job.validate());
        job.run();
        return out;
    }
    std::vector<glm::vec3> skin(const std::vector<Mat34>& pal) const {
        std::vector<glm::vec3> out(c.vertex_count());
        const SkinningJob job = skinning_job(c, s, pal, out);
        EXPECT_TRUE(job.validate());
        job.run();
        return out;
    }
};
const FoxSkin& fox() {
    static const FoxSkin f;
    return f;
}

double max_abs_diff(const Mat34& a, const Mat34& b) {
    double m = 0;
    for (int i = 0; i < 12; ++i) m = std::max(m, double(std::fabs(a.m[i] - b.m[i])));
    return m;
}

double max_dist(const std::vector<glm::vec3>& a, const std::vector<glm::vec3>& b) {
    double m = 0;
    for (size_t i = 0; i < a.size(); ++i) m = std::max(m, double(glm::length(a[i] - b[i])));
    return m;
}

}  // namespace

TEST(PaletteJob, AllBonesGiveTheInputMatrices) {
    const FoxSkin& fx = fox();
    ASSERT_GT(fx.B(), 8);
    for (size_t f : {size_t(0), fx.frames.frame_count() / 2}) {
        const std::vector<Mat34> in = fx.own(f, fx.B());
        const std::vector<Mat34> out = fx.palette(f, fx.B());
        for (int b = 0; b < fx.B(); ++b)
            for (int i = 0; i < 12; ++i) EXPECT_EQ(out[size_t(b)].m[i], in[size_t(b)].m[i]) << "bone " << b;
        // Presence 1 everywhere is the same as no presence.
        const std::vector<float> ones(size_t(fx.B()), 1.0f);
        const std::vector<Mat34> with = fx.palette(f, fx.B(), ones);
        for (int b = 0; b < fx.B(); ++b) EXPECT_EQ(max_abs_diff(with[size_t(b)], in[size_t(b)]), 0.0) << b;
    }
}

// With k bones: bones below k are their own matrix; an inactive bone b is
// M_a * C_{b_1} * ... * C_b, a its nearest active ancestor and b_1 .. b the
// inactive bones on the progressive path from a down to b.
TEST(PaletteJob, InactiveBonesStandInFromTheirNearestActiveAncestor) {
    const FoxSkin& fx = fox();
    const size_t f = fx.frames.frame_count() / 3;
    size_t corrected = 0;
    for (int k : {1, 2, 5, fx.B() / 2, fx.B() - 1}) {
        SCOPED_TRACE(k);
        const std::vector<Mat34> in = fx.own(f, fx.B());
        const std::vector<Mat34> out = fx.palette(f, k);
        for (int b = 0; b < fx.B(); ++b) {
            if (b < k) {
                EXPECT_EQ(max_abs_diff(out[size_t(b)], in[size_t(b)]), 0.0) << "active bone " << b;
                continue;
            }
            std::vector<int> path;  // b, its inactive ancestors, up to (excluding) the active one
            int a = b;
            while (a >= k) {
                path.push_back(a);
                a = fx.s.parents[size_t(a)];
                ASSERT_GE(a, 0);
            }
            Mat34 want = in[size_t(a)];
            for (auto it = path.rbegin(); it != path.rend(); ++it) want = mul(want, fx.s.corrections[size_t(*it)]);
            EXPECT_LT(max_abs_diff(out[size_t(b)], want), 1e-4) << "bone " << b << " from " << a;
            corrected += max_abs_diff(fx.s.corrections[size_t(b)], Mat34::identity()) > 1e-3;
        }
    }
    EXPECT_GT(corrected, 0u);  // the fitted corrections are not all identity: the products matter
}

// The stand-in is what the error table measures: the palette with k bones,
// skinned, has the table's error e(k) over the training frames.
TEST(PaletteJob, PaletteOfKBonesReproducesTheErrorTable) {
    const FoxSkin& fx = fox();
    for (int k : {1, 3, fx.B() / 2, fx.B()}) {
        ErrorAccumulator acc(fx.diagonal);
        std::vector<glm::vec3> ref(fx.c.vertex_count());
        for (size_t f = 0; f < fx.frames.frame_count(); ++f) {
            reference_positions(fx.c, fx.frames, f, ref);
            acc.add(ref, fx.skin(fx.palette(f, k)));
        }
        const LodError& e = fx.s.error[size_t(k - 1)];
        EXPECT_NEAR(acc.stats().rms_pct, e.rms_pct, 1e-3 + 1e-3 * e.rms_pct) << "k=" << k;
        EXPECT_NEAR(acc.stats().max_pct, e.max_pct, 1e-3 + 1e-3 * e.max_pct) << "k=" << k;
    }
    EXPECT_GT(fx.s.error.front().rms_pct, fx.s.error.back().rms_pct);
}

// Presence p of an own bone blends its stand-in and its own matrix linearly.
TEST(PaletteJob, PresenceBlendsStandInAndOwnMatrix) {
    const FoxSkin& fx = fox();
    const size_t f = 4;
    const int k = 6;
    const std::vector<Mat34> off = fx.palette(f, k - 1), on = fx.palette(f, k);
    ASSERT_GT(max_abs_diff(off[size_t(k - 1)], on[size_t(k - 1)]), 1e-4);  // the bone's stand-in is not its pose
    for (float p : {0.0f, 0.25f, 0.5f, 1.0f}) {
        std::vector<float> presence(size_t(k), 1.0f);
        presence[size_t(k - 1)] = p;
        const std::vector<Mat34> mid = fx.palette(f, k, presence);
        const Mat34 want = lerp(off[size_t(k - 1)], on[size_t(k - 1)], p);
        EXPECT_LT(max_abs_diff(mid[size_t(k - 1)], want), 1e-5) << p;
        for (int b = 0; b < k - 1; ++b) EXPECT_EQ(max_abs_diff(mid[size_t(b)], on[size_t(b)]), 0.0) << b;
    }
}

// validate() refuses every malformed job, the output span of the wrong size first.
TEST(PaletteJob, ValidateRefusesMalformedJobs) {
    const FoxSkin& fx = fox();
    const size_t B = size_t(fx.B());
    const std::vector<Mat34> own = fx.own(0, 4);
    const std::vector<float> presence(4, 1.0f);
    std::vector<Mat34> out(B), short_out(B - 1), long_out(B + 1);
    const PaletteJob good{fx.s.parents, fx.s.corrections, own, presence, out};
    ASSERT_TRUE(good.validate());
    EXPECT_TRUE((PaletteJob{fx.s.parents, {}, own, {}, out}.validate()));  // plain copy-down, no presence

    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, own, presence, short_out}.validate()));
    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, own, presence, long_out}.validate()));
    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, own, presence, {}}.validate()));
    const std::vector<Mat34> short_corr(fx.s.corrections.begin(), fx.s.corrections.end() - 1);
    EXPECT_FALSE((PaletteJob{fx.s.parents, short_corr, own, presence, out}.validate()));
    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, {}, {}, out}.validate()));  // no own bone
    const std::vector<Mat34> too_many(B + 1, Mat34::identity());
    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, too_many, {}, out}.validate()));
    const std::vector<float> presence3(3, 1.0f);
    EXPECT_FALSE((PaletteJob{fx.s.parents, fx.s.corrections, own, presence3, out}.validate()));
    std::vector<int16_t> parents = fx.s.parents;
    parents[0] = 0;
    EXPECT_FALSE((PaletteJob{parents, fx.s.corrections, own, presence, out}.validate()));
    parents = fx.s.parents;
    parents[B - 1] = int16_t(B - 1);  // parent not before the bone
    EXPECT_FALSE((PaletteJob{parents, fx.s.corrections, own, presence, out}.validate()));
    parents[B - 1] = -1;  // a second root
    EXPECT_FALSE((PaletteJob{parents, fx.s.corrections, own, presence, out}.validate()));
}

TEST(LodBlender, MovesPresenceByOneStepPerFrame) {
    LodBlender bl(10, 4, 3);
    EXPECT_EQ(bl.target(), 3);
    EXPECT_EQ(bl.needed(), 3);
    EXPECT_TRUE(bl.settled());
    bl.set_target(5);
    EXPECT_FALSE(bl.settled());
    for (int step = 1; step <= 4; ++step) {
        bl.step();
        ASSERT_EQ(bl.needed(), 5);
        EXPECT_FLOAT_EQ(bl.presence()[3], 0.25f * float(step));
        EXPECT_FLOAT_EQ(bl.presence()[4], 0.25f * float(step));
        EXPECT_FLOAT_EQ(bl.presence()[2], 1.0f);
    }
    EXPECT_TRUE(bl.settled());
    bl.set_target(1);
    bl.step();
    EXPECT_EQ(bl.needed(), 5);  // bones fading out still need their own matrix
    EXPECT_FLOAT_EQ(bl.presence()[0], 1.0f);  // bone 0 never fades
    EXPECT_FLOAT_EQ(bl.presence()[1], 0.75f);
    for (int i = 0; i < 3; ++i) bl.step();
    EXPECT_EQ(bl.needed(), 1);
    EXPECT_TRUE(bl.settled());
    // The target is clamped to 1..B.
    bl.set_target(0);
    EXPECT_EQ(bl.target(), 1);
    bl.set_target(99);
    EXPECT_EQ(bl.target(), 10);
}

// A fixed pose, LOD switched from k to B and back: without blending every
// vertex jumps by up to the LOD gap in one frame; with an n-frame blend the
// palette starts and ends at the two LODs exactly and no frame moves a vertex
// by more than a bounded multiple of gap / n (the chained stand-ins of bones
// blending together are not linear in the presence), so doubling n roughly
// halves the largest step.
TEST(LodBlender, SwitchingIsContinuous) {
    const FoxSkin& fx = fox();
    const size_t f = fx.frames.frame_count() / 2;
    const int lo = 2;
    const auto low = fx.skin(fx.palette(f, lo)), full = fx.skin(fx.palette(f, fx.B()));
    const double gap = max_dist(low, full);
    ASSERT_GT(gap, 0.01 * fx.diagonal);
    auto largest_step = [&](int n) {
        LodBlender bl(fx.B(), n, lo);
        std::vector<glm::vec3> prev = fx.skin(fx.palette(f, bl.needed(), bl.presence()));
        EXPECT_LT(max_dist(prev, low), 1e-6 * fx.diagonal);
        double worst = 0;
        for (int target : {fx.B(), lo}) {
            bl.set_target(target);
            int steps = 0;
            while (!bl.settled()) {
                bl.step();
                ++steps;
                const auto now = fx.skin(fx.palette(f, bl.needed(), bl.presence()));
                worst = std::max(worst, max_dist(now, prev));
                prev = now;
            }
            EXPECT_EQ(steps, n);
            EXPECT_LT(max_dist(prev, target == lo ? low : full), 1e-6 * fx.diagonal) << "target " << target;
        }
        return worst;
    };
    const double s8 = largest_step(8), s16 = largest_step(16);
    std::printf("Fox LOD %d <-> %d: gap %.4f %% of the diagonal; largest step with 8 frames %.4f %%, 16 frames %.4f %%\n",
                lo, fx.B(), 100 * gap / fx.diagonal, 100 * s8 / fx.diagonal, 100 * s16 / fx.diagonal);
    EXPECT_LT(s8, 0.5 * gap);
    EXPECT_LE(s8, 3.0 * gap / 8);
    EXPECT_LE(s16, 3.0 * gap / 16);
    EXPECT_LT(s16, 0.75 * s8);
}
