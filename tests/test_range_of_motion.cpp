// test_range_of_motion.cpp — characters without animation (offline/range_of_motion.h):
// a skeleton that no clip moves trains on range-of-motion poses, whose bone
// order holds up on motion the build never saw; any rigid pose of such a
// skeleton fits the records' translation box.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>

#include <glm/gtc/matrix_transform.hpp>

#include "animation.h"
#include "collapse.h"
#include "cost_tables.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "pose.h"
#include "range_of_motion.h"

using namespace progskin;

namespace {

Character import_asset(const std::string& name) { return import_gltf(std::string(PROGSKIN_ASSETS) + "/" + name).at(0); }

Character without_clips(Character c) {
    c.clips.clear();
    return c;
}

double mean_rms_pct(const std::vector<LodError>& t) {
    double s = 0;
    for (const LodError& e : t) s += e.rms_pct;
    return t.empty() ? 0 : s / double(t.size());
}

bool same(const std::vector<Mat34>& a, const std::vector<Mat34>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(Mat34)) == 0;
}

// Skinning matrices of a pose that turns every joint by a uniformly random
// rotation (any angle, any axis) from its rest rotation.
std::vector<Mat34> random_rigid_pose(const Character& c, std::mt19937& rng) {
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<glm::dmat4> locals(c.nodes.size()), globals(c.nodes.size());
    std::vector<char> joint(c.nodes.size(), 0);
    for (int n : c.joint_node) joint[size_t(n)] = 1;
    for (size_t i = 0; i < c.nodes.size(); ++i) {
        const Node& n = c.nodes[i];
        glm::dquat q(1.0, 0.0, 0.0, 0.0);
        if (joint[i]) {  // uniform on SO(3) (Shoemake)
            const double a = u(rng), b = 2 * M_PI * u(rng), d = 2 * M_PI * u(rng);
            q = glm::dquat(std::sqrt(a) * std::cos(d), std::sqrt(1 - a) * std::sin(b), std::sqrt(1 - a) * std::cos(b),
                           std::sqrt(a) * std::sin(d));
        }
        locals[i] = n.has_matrix ? n.matrix * glm::mat4_cast(q)
                                 : glm::translate(glm::dmat4(1.0), n.translation) * glm::mat4_cast(n.rotation * q) *
                                       glm::scale(glm::dmat4(1.0), n.scale);
    }
    compose_node_globals(c, locals, globals);
    std::vector<Mat34> out;
    for (size_t j = 0; j < c.joint_count(); ++j) out.push_back(Mat34::from_glm(globals[size_t(c.joint_node[j])] * c.inverse_bind[j]));
    return out;
}

}  // namespace

// Clips that move the skeleton are what a build trains on; without them the
// range-of-motion poses stand in: smooth, every joint moving, deterministic.
TEST(RangeOfMotion, StandsInOnlyWhereNoClipMovesTheSkeleton) {
    const Character fox = import_asset("Fox.glb");
    bool rom = true;
    const FrameSet clips = training_frames(fox, default_training_set(fox), 30.0, &rom);
    EXPECT_FALSE(rom);
    EXPECT_TRUE(same(clips.skinning, sample_frames(fox, default_training_set(fox), 30.0).skinning));

    const Character still = without_clips(fox);
    EXPECT_FALSE(skeleton_moves(sample_frames(still, default_training_set(still), 30.0)));
    const FrameSet f = training_frames(still, default_training_set(still), 30.0, &rom);
    EXPECT_TRUE(rom);
    ASSERT_EQ(f.frame_count(), size_t(std::floor(kRangeOfMotionSeconds * 30.0)) + 1);
    EXPECT_TRUE(skeleton_moves(f));
    EXPECT_TRUE(same(f.skinning, range_of_motion_frames(still, 30.0).skinning)) << "not deterministic";
    EXPECT_FALSE(same(f.skinning, range_of_motion_frames(still, 30.0, 2).skinning)) << "the seed changes nothing";
    // Every joint turns relative to its parent joint, and smoothly: between
    // frames 1/30 s apart no joint turns by more than its two sines allow,
    // 2 x 2 pi x 1.2 Hz x 30 degrees / 30 = 0.26 rad (poses drawn apart
    // would jump by a radian and more).
    const size_t J = still.joint_count();
    for (size_t j = 0; j < J; ++j) {
        const int p = still.joint_parent[j];
        double most = 0, step = 0;
        for (size_t i = 0; i < f.frame_count(); ++i) {
            auto local = [&](size_t frame) {
                const glm::dquat m(decompose(f.frame(frame)[j]).r);
                return p < 0 ? m : glm::inverse(glm::dquat(decompose(f.frame(frame)[size_t(p)]).r)) * m;
            };
            const glm::dquat q0 = local(0), qi = local(i);
            most = std::max(most, 2.0 * std::acos(std::min(1.0, std::abs(glm::dot(q0, qi)))));
            if (i > 0) step = std::max(step, 2.0 * std::acos(std::min(1.0, std::abs(glm::dot(local(i - 1), qi)))));
        }
        EXPECT_GT(most, 0.3) << "joint " << j << " hardly moves";
        EXPECT_LT(step, 0.27) << "joint " << j << " jumps";
    }
}

// The order a clip-less character gets holds up on motion it never saw: the
// Fox without its clips, built on the range of motion, against the same
// character built on its rest pose (what a build did before), both measured on
// the Fox's own clips. Printed: the mean RMS over k of both and of the build
// that trained on the clips themselves.
TEST(RangeOfMotion, AClipLessBuildOrdersBonesForMotionItNeverSaw) {
    const Character fox = import_asset("Fox.glb");
    const Character still = without_clips(fox);
    const FrameSet clips = sample_frames(fox, default_training_set(fox), 30.0);
    const ProgressiveSkin rest = build_best_progressive_skin(still, sample_frames(still, default_training_set(still), 30.0));
    const ProgressiveSkin rom = build_best_progressive_skin(still, training_frames(still, default_training_set(still), 30.0));
    const ProgressiveSkin seen = build_best_progressive_skin(fox, clips);
    const double e_rest = mean_rms_pct(evaluate_error_table(fox, rest, clips));
    const double e_rom = mean_rms_pct(evaluate_error_table(fox, rom, clips));
    const double e_seen = mean_rms_pct(evaluate_error_table(fox, seen, clips));
    std::printf("Fox's clips, mean RMS over k (%% of the diagonal): rest-pose build %.3f, range-of-motion build %.3f, "
                "build on the clips %.3f\n", e_rest, e_rom, e_seen);
    EXPECT_LT(e_rom, 0.7 * e_rest);
}

// Any rigid pose of the skeleton (every joint turned anywhere) fits the
// translation box of the server's tables: a game may drive a character far
// beyond its clips. Checked on a clip-less character (its tables see only the
// range of motion) and on one with clips.
TEST(RangeOfMotion, AnyRigidPoseFitsTheTranslationBox) {
    std::mt19937 rng(7);
    for (const char* name : {"CesiumMan.glb", "Fox.glb"}) {
        for (int variant : {0, 1, 2}) {
            const bool clips = variant == 1;
            Character c = clips ? import_asset(name) : without_clips(import_asset(name));
            if (variant == 2) {
                // Modelled far from the origin of its bind space (a thousand
                // diagonals away): the box grows far past the clips', and the
                // step with it (at most 2^22 steps across).
                const glm::dvec3 o(1000.0 * rest_diagonal(c), 0.0, 0.0);
                for (glm::vec3& p : c.positions) p += glm::vec3(o);
                for (glm::dmat4& ib : c.inverse_bind) ib = ib * glm::translate(glm::dmat4(1.0), -o);
            }
            const auto sel = default_training_set(c);
            const ProgressiveSkin s = build_best_progressive_skin(c, training_frames(c, sel, 30.0));
            const AssetTables t = compute_asset_tables(c, s, sel);
            const glm::vec3 pad = (t.t_max - t.t_min) / 65535.0f;
            int outside = 0;
            for (int i = 0; i < 200; ++i)
                for (const Mat34& m : random_rigid_pose(c, rng)) {
                    const glm::vec3 x{m.m[3], m.m[7], m.m[11]};
                    outside += glm::any(glm::lessThan(x, t.t_min - pad)) || glm::any(glm::greaterThan(x, t.t_max + pad));
                }
            EXPECT_EQ(outside, 0) << name << " variant " << variant;
            EXPECT_TRUE(translation_step_fits(t.t_min, t.t_max, t.t_step));
            EXPECT_GT(t.t_step, 0.0f);
            // The live model values refreshes: the tables saw motion.
            ASSERT_GE(t.segments.size(), 2u);
            EXPECT_GT(t.segments[1].gap.back()[4], 0.0) << name;
        }
    }
}
