// test_net_codec.cpp — the bone record (bone_codec.h): round trips, and the
// error it costs measured with the error metric against the reference.
#include <gtest/gtest.h>

#include <random>

#include "bone_codec.h"
#include "error_metric.h"
#include "scene.h"
#include "progressive_skin.h"
#include "skinning.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::thresholds;

TEST(NetCodec, QuaternionRoundTripWithinBound) {
    std::mt19937 rng(7);
    std::normal_distribution<float> n;
    RecordFormat fmt;
    fmt.t_min = glm::vec3(-2);
    fmt.t_max = glm::vec3(3);
    fmt.scaled = true;
    uint8_t rec[14];
    double worst_angle = 0, worst_t = 0, worst_s = 0;
    for (int i = 0; i < 20000; ++i) {
        BonePose p;
        p.r = glm::normalize(glm::quat(n(rng), n(rng), n(rng), n(rng)));
        p.t = glm::vec3(n(rng), n(rng), n(rng));
        p.t = glm::clamp(p.t, fmt.t_min, fmt.t_max);
        p.s = std::exp(0.3f * n(rng));
        encode_bone(p, fmt, rec);
        BonePose q = decode_bone(rec, fmt);
        glm::dquat pr(p.r), qr(q.r);
        if (glm::dot(pr, qr) < 0) qr = -qr;
        worst_angle = std::max(worst_angle, 4.0 * std::asin(std::min(1.0, glm::length(pr - qr) / 2.0)));
        worst_t = std::max(worst_t, double(glm::length(p.t - q.t)));
        worst_s = std::max(worst_s, double(std::fabs(q.s / p.s - 1.0f)));
    }
    EXPECT_LT(worst_angle, 1.5e-4);
    EXPECT_LT(worst_t, glm::length(glm::vec3(5)) / 131070.0 * 1.01 + 1e-6);
    EXPECT_LT(worst_s, 1.8e-4);
}

TEST(NetCodec, ComposeDecomposeIsExactForRigidMatrices) {
    BonePose p;
    p.r = glm::normalize(glm::quat(0.3f, -0.5f, 0.2f, 0.7f));
    p.t = {1, 2, 3};
    BonePose q = decompose(compose(p));
    EXPECT_NEAR(std::fabs(glm::dot(p.r, q.r)), 1.0f, 1e-6f);
    EXPECT_NEAR(glm::length(p.t - q.t), 0.0f, 1e-6f);
    EXPECT_NEAR(q.s, 1.0f, 1e-5f);
}

// Skins every training frame with quantised records and compares with the reference.
static void measure(const std::string& file) {
    auto a = load_server_asset(std::string(PROGSKIN_ASSETS) + "/" + file);
    const Character& c = a->character;
    FrameSet frames = sample_frames(c, a->selections, 30.0);
    std::vector<glm::vec3> ref(c.vertex_count()), got(c.vertex_count()), exact(c.vertex_count());
    std::vector<Mat34> pal(c.joint_count()), pal_exact(c.joint_count());
    ErrorAccumulator quant(rest_diagonal(c)), decomp(rest_diagonal(c));
    uint8_t rec[14];
    for (size_t f = 0; f < frames.frame_count(); f += 3) {
        reference_positions(c, frames, f, ref);
        for (size_t j = 0; j < c.joint_count(); ++j) {
            pal_exact[j] = compose(decompose(frames.frame(f)[j]));
            encode_bone(decompose(frames.frame(f)[j]), a->format, rec);
            pal[j] = compose(decode_bone(rec, a->format));
        }
        for (auto* p : {&pal, &pal_exact}) {
            const SkinningJob job = skinning_job(c, *p, p == &pal ? got : exact);
            ASSERT_TRUE(job.validate());
            job.run();
        }
        quant.add(ref, got);
        decomp.add(ref, exact);
    }
    ErrorStats q = quant.stats(), d = decomp.stats();
    double bound = quantisation_bound(a->format, a->bind_radius, a->max_scale);
    std::printf("%s: record %d bytes, decomposition RMS %.5f%% max %.5f%%; quantised RMS %.5f%% max %.5f%% "
                "(bound %.5f%% of diagonal)\n",
                file.c_str(), a->format.size(), d.rms_pct, d.max_pct, q.rms_pct, q.max_pct, 100.0 * bound / rest_diagonal(c));
    EXPECT_LE(q.max, bound);
    EXPECT_LT(q.max_pct, kQuantisationMaxPct);
}

TEST(NetCodec, FoxQuantisationErrorWithinBound) { measure("Fox.glb"); }
TEST(NetCodec, CesiumManQuantisationErrorWithinBound) { measure("CesiumMan.glb"); }
