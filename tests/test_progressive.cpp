// Progressive skin by collapse: ordering, corrections, error table, influence
// order, round trip through the progressive glTF. Synthetic skeletons and the
// bundled real characters.
#include <gtest/gtest.h>

#include <filesystem>
#include <numeric>

#include "animation.h"
#include "errors.h"
#include "error_metric.h"
#include "gltf_export.h"
#include "gltf_import.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "synthetic.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::thresholds;

namespace {

std::string asset(const char* name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }

ProgressiveSkin build(const Character& c, const FrameSet& f, Strategy s, bool fit = true) {
    BuildOptions o;
    o.strategy = s;
    o.fit_corrections = fit;
    return build_progressive_skin(c, f, o);
}

double mean_rms_pct(const std::vector<LodError>& t) {
    double s = 0;
    for (const auto& e : t) s += e.rms_pct;
    return s / double(t.size());
}

void expect_valid_structure(const ProgressiveSkin& s, int B) {
    ASSERT_EQ(s.bone_count(), B);
    std::vector<int> sorted = s.order;
    std::sort(sorted.begin(), sorted.end());
    for (int b = 0; b < B; ++b) EXPECT_EQ(sorted[b], b) << "order is not a permutation";
    EXPECT_EQ(s.parents[0], -1);
    for (int b = 1; b < B; ++b) {
        EXPECT_GE(s.parents[b], 0);
        EXPECT_LT(s.parents[b], b) << "prefix not closed under parent at bone " << b;
    }
    ASSERT_EQ(int(s.error.size()), B);
    for (int k = 1; k <= B; ++k) EXPECT_EQ(s.error[k - 1].bones, k);
}

// Non-increasing up to float rounding (1e-7 of the diagonal).
void expect_non_increasing(const std::vector<LodError>& t, const char* what) {
    for (size_t k = 1; k < t.size(); ++k)
        EXPECT_LE(t[k].rms_pct, t[k - 1].rms_pct + kTableRoundingPct) << what << ": rms rises from k=" << k << " to " << k + 1;
}

struct AssetCase {
    const char* file;
    const char* clip;  // "" = default training set
};

class CollapseOnAsset : public ::testing::TestWithParam<AssetCase> {};

}  // namespace

TEST(Collapse, SyntheticTreeStructureAndExactAtFullDetail) {
    const Character c = synth::make_tree(3, 3);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    for (Strategy st : {Strategy::Reorder, Strategy::Flatten, Strategy::Hierarchy, Strategy::LeafPrune}) {
        SCOPED_TRACE(strategy_name(st));
        const ProgressiveSkin s = build(c, f, st);
        expect_valid_structure(s, int(c.joint_count()));
        expect_non_increasing(s.error, strategy_name(st));
        EXPECT_LE(s.error.back().max_pct, kLosslessPct) << "all bones must reproduce the original (1e-5 of the diagonal)";
        EXPECT_GT(s.error.front().rms_pct, kOneBoneMinRmsPct) << "one bone cannot follow a wiggling tree";
    }
}

TEST(Collapse, ReorderKeepsArtistAncestry) {
    const Character c = synth::make_tree(4, 2);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    const ProgressiveSkin s = build(c, f, Strategy::Reorder);
    for (int b = 1; b < s.bone_count(); ++b) {
        // The progressive parent is an artist ancestor of the bone.
        const int j = s.order[b], p = s.order[s.parents[b]];
        bool found = false;
        for (int a = c.joint_parent[j]; a >= 0; a = c.joint_parent[a]) found |= (a == p);
        EXPECT_TRUE(found) << "bone " << j << " collapsed into non-ancestor " << p;
    }
}

// Hierarchy: only leaves of the active hierarchy collapse, so every bone
// comes after its artist parent in progressive order and that parent is its
// progressive parent (what makes its parent-relative records cheap); the
// error table is still the greedy's (non-increasing, exact at full detail).
TEST(Collapse, HierarchyKeepsEveryBoneUnderItsArtistParent) {
    const Character c = synth::make_tree(4, 2);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    const ProgressiveSkin s = build(c, f, Strategy::Hierarchy);
    expect_valid_structure(s, int(c.joint_count()));
    expect_non_increasing(s.error, "hierarchy");
    EXPECT_LE(s.error.back().max_pct, kLosslessPct);
    for (int b = 1; b < s.bone_count(); ++b) {
        const int j = s.order[size_t(b)];
        ASSERT_GE(c.joint_parent[size_t(j)], 0);
        EXPECT_EQ(s.order[size_t(s.parents[size_t(b)])], c.joint_parent[size_t(j)]) << "bone " << j;
    }
    // Reorder on the same tree puts some bone before its artist parent (else
    // this test shows nothing): the two strategies differ.
    const ProgressiveSkin r = build(c, f, Strategy::Reorder);
    int differ = 0;
    for (int b = 1; b < r.bone_count(); ++b) differ += r.order[size_t(r.parents[size_t(b)])] != c.joint_parent[size_t(r.order[size_t(b)])];
    EXPECT_GT(differ, 0);
}

// rd_area: e(k) held over the bits between k and k + 1 bones, e(1) over bone
// 0's bits, e(B) up to `until`; by hand on three bones.
TEST(Collapse, RateDistortionAreaByHand) {
    std::vector<LodError> t(3);
    t[0].rms = 4.0, t[1].rms = 2.0, t[2].rms = 0.5;
    // bits 10, 20, 30: 4*10 (bone 0 arriving) + 4*20 + 2*30 + 0.5*(100-60)
    EXPECT_DOUBLE_EQ(rd_area(t, {10.0, 20.0, 30.0}, 100.0), 40.0 + 80.0 + 60.0 + 20.0);
    EXPECT_DOUBLE_EQ(rd_area(t, {10.0, 20.0, 30.0}, 0.0), 40.0 + 80.0 + 60.0);  // until below the sum: nothing after
    EXPECT_EQ(rd_area(t, {10.0, 20.0}, 100.0), 0.0);  // sizes differ
}

TEST(Collapse, TrackedTableMatchesIndependentEvaluation) {
    const Character c = synth::make_tree(3, 3);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    for (Strategy st : {Strategy::Reorder, Strategy::Flatten}) {
        const ProgressiveSkin s = build(c, f, st);
        const auto t = evaluate_error_table(c, s, f);
        ASSERT_EQ(t.size(), s.error.size());
        for (size_t k = 0; k < t.size(); ++k) {
            EXPECT_NEAR(t[k].rms_pct, s.error[k].rms_pct, 1e-3 + 1e-3 * s.error[k].rms_pct) << "k=" << k + 1;
            EXPECT_NEAR(t[k].max_pct, s.error[k].max_pct, 1e-3 + 1e-3 * s.error[k].max_pct) << "k=" << k + 1;
            EXPECT_NEAR(t[k].influences, s.error[k].influences, 1e-9);
        }
    }
}

TEST(Collapse, FittedCorrectionsBeatPlainCopyDown) {
    const Character c = synth::make_tree(3, 4);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    const ProgressiveSkin fit = build(c, f, Strategy::Reorder, true);
    const ProgressiveSkin plain = build(c, f, Strategy::Reorder, false);
    EXPECT_LT(mean_rms_pct(fit.error), mean_rms_pct(plain.error));
    for (const Mat34& m : plain.corrections)
        for (int i = 0; i < 12; ++i) EXPECT_EQ(m.m[i], Mat34::identity().m[i]);
}

TEST(Collapse, InfluenceOrderDropsCheapestFirst) {
    // Compare dropping to 1 and 2 influences in the built order against the
    // usual order (largest weight first), on the full skeleton.
    const Character c = import_character(asset("Fox.glb"));
    const FrameSet f = sample_frames(c, {select_clips(c, "Survey")}, 10.0);
    const ProgressiveSkin s = build(c, f, Strategy::Reorder);
    const int B = s.bone_count(), I = s.influences;
    for (int keep : {1, 2}) {
        ProgressiveSkin ours = s, by_weight = s;
        for (size_t v = 0; v < c.vertex_count(); ++v) {
            std::vector<std::pair<float, uint16_t>> slots;
            for (int i = 0; i < I; ++i) slots.push_back({s.weights[v * I + i], s.joints[v * I + i]});
            std::stable_sort(slots.begin(), slots.end(), [](auto& a, auto& b) { return a.first > b.first; });
            for (int i = 0; i < I; ++i) {
                by_weight.weights[v * I + i] = slots[i].first;
                by_weight.joints[v * I + i] = slots[i].second;
            }
            for (ProgressiveSkin* p : {&ours, &by_weight}) {
                float sum = 0;
                for (int i = 0; i < I; ++i) {
                    if (i >= keep) p->weights[v * I + i] = 0;
                    sum += p->weights[v * I + i];
                }
                for (int i = 0; i < I; ++i) p->weights[v * I + i] /= sum;
            }
        }
        const double e_ours = evaluate_error_table(c, ours, f)[B - 1].rms;
        const double e_weight = evaluate_error_table(c, by_weight, f)[B - 1].rms;
        EXPECT_LE(e_ours, e_weight * 1.0001) << "keeping " << keep << " influences";
    }
}

TEST(Collapse, RejectsMismatchedFrames) {
    const Character c = synth::make_tree(2, 2);
    FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    f.joint_count += 1;
    EXPECT_THROW(build_progressive_skin(c, f), Error);
}

TEST_P(CollapseOnAsset, StrategiesBeatLeafPruneAndReproduceOriginal) {
    const AssetCase ac = GetParam();
    const Character c = import_character(asset(ac.file));
    const auto sets = *ac.clip ? std::vector<ClipSelection>{select_clips(c, ac.clip)} : default_training_set(c);
    const FrameSet f = sample_frames(c, sets, 15.0);
    const int B = int(c.joint_count());
    const ProgressiveSkin naive = build(c, f, Strategy::LeafPrune);
    expect_valid_structure(naive, B);
    for (Strategy st : {Strategy::Reorder, Strategy::Flatten}) {
        SCOPED_TRACE(strategy_name(st));
        const ProgressiveSkin s = build(c, f, st);
        expect_valid_structure(s, B);
        expect_non_increasing(s.error, strategy_name(st));
        EXPECT_LE(s.error.back().max_pct, kLosslessPct);
        if (B > 2) {
            EXPECT_LT(mean_rms_pct(s.error), mean_rms_pct(naive.error));
        }
        for (int k = 0; k < B; ++k) EXPECT_LE(s.error[k].rms, naive.error[k].rms * 1.0001 + 1e-9) << "k=" << k + 1;
        // Mean distinct influences grows with k and ends at the file's own count.
        EXPECT_NEAR(s.error.front().influences, 1.0, 1e-9);
        for (int k = 1; k < B; ++k) EXPECT_GE(s.error[k].influences + 1e-9, s.error[k - 1].influences);
    }
}

// The default build keeps whichever of reorder and flatten has the lower
// mean RMS over k, and says so; progress covers both builds once.
TEST_P(CollapseOnAsset, DefaultBuildKeepsTheLowerErrorStrategy) {
    const AssetCase ac = GetParam();
    const Character c = import_character(asset(ac.file));
    const auto sets = *ac.clip ? std::vector<ClipSelection>{select_clips(c, ac.clip)} : default_training_set(c);
    const FrameSet f = sample_frames(c, sets, 15.0);
    const ProgressiveSkin reorder = build(c, f, Strategy::Reorder), flatten = build(c, f, Strategy::Flatten);
    BuildOptions opt;
    int last = 0, total = 0;
    bool monotonic = true;
    opt.progress = [&](int s, int t) {
        monotonic = monotonic && s >= last;
        last = s;
        total = t;
    };
    StrategyChoice ch;
    const ProgressiveSkin best = build_best_progressive_skin(c, f, opt, &ch);
    EXPECT_DOUBLE_EQ(ch.reorder_mean_rms, mean_rms(reorder.error));
    EXPECT_DOUBLE_EQ(ch.flatten_mean_rms, mean_rms(flatten.error));
    EXPECT_EQ(ch.chosen, ch.flatten_mean_rms < ch.reorder_mean_rms ? Strategy::Flatten : Strategy::Reorder);
    EXPECT_EQ(best.strategy, ch.chosen);
    EXPECT_DOUBLE_EQ(mean_rms(best.error), std::min(ch.reorder_mean_rms, ch.flatten_mean_rms));
    if (c.joint_count() > 1) {
        EXPECT_TRUE(monotonic);
        EXPECT_EQ(total, 2 * (int(c.joint_count()) - 1));
        EXPECT_EQ(last, total);
    }
}

INSTANTIATE_TEST_SUITE_P(Assets, CollapseOnAsset,
                         ::testing::Values(AssetCase{"RiggedSimple.gltf", ""}, AssetCase{"Fox.glb", "Survey"},
                                           AssetCase{"CesiumMan.glb", "all"}),
                         [](const auto& info) {
                             std::string n = info.param.file;
                             return n.substr(0, n.find('.'));
                         });

TEST(ProgressiveGltf, RoundTripKeepsSkinAndFullDetailPose) {
    namespace fs = std::filesystem;
    for (const char* file : {"Fox.glb", "RiggedSimple.gltf", "CesiumMan.glb"}) {
        SCOPED_TRACE(file);
        const Character c = import_character(asset(file));
        const FrameSet f = sample_frames(c, default_training_set(c), 10.0);
        const ProgressiveSkin s = build(c, f, Strategy::Flatten);
        const fs::path out = fs::temp_directory_path() / (std::string("progskin_rt_") + file + ".glb");
        save_progressive(c, s, out.string());
        const ProgressiveAsset back = load_progressive(out.string());
        ASSERT_TRUE(back.progressive);
        const Character& c2 = back.character;
        ASSERT_EQ(c2.joint_count(), c.joint_count());
        ASSERT_EQ(c2.vertex_count(), c.vertex_count());
        ASSERT_EQ(c2.clips.size(), c.clips.size());
        EXPECT_EQ(back.skin.parents, s.parents);
        EXPECT_EQ(back.skin.strategy, s.strategy);
        ASSERT_EQ(back.skin.error.size(), s.error.size());
        for (size_t k = 0; k < s.error.size(); ++k) EXPECT_DOUBLE_EQ(back.skin.error[k].rms, s.error[k].rms);
        for (int b = 0; b < s.bone_count(); ++b)
            for (int i = 0; i < 12; ++i) EXPECT_EQ(back.skin.corrections[b].m[i], s.corrections[b].m[i]);
        // Progressive order: joint b of the file is bone b.
        for (int b = 0; b < s.bone_count(); ++b)
            EXPECT_EQ(c2.nodes[c2.joint_node[b]].gltf_index, c.nodes[c.joint_node[s.order[b]]].gltf_index);
        // A viewer plays the file exactly as the input, and every LOD matches.
        const FrameSet f2 = sample_frames(c2, default_training_set(c2), 10.0);
        ASSERT_EQ(f2.frame_count(), f.frame_count());
        const double diag = rest_diagonal(c);
        std::vector<glm::vec3> r1(c.vertex_count()), r2(c.vertex_count());
        for (size_t fr = 0; fr < f.frame_count(); fr += 3) {
            reference_positions(c, f, fr, r1);
            reference_positions(c2, f2, fr, r2);
            ErrorAccumulator acc(diag);
            acc.add(r1, r2);
            EXPECT_LE(acc.stats().max_pct, kLosslessPct) << "frame " << fr;
            for (int k : {1, 2, s.bone_count() / 2 + 1}) {
                lod_positions(c, s, f, fr, k, r1);
                lod_positions(c2, back.skin, f2, fr, k, r2);
                ErrorAccumulator a2(diag);
                a2.add(r1, r2);
                EXPECT_LE(a2.stats().max_pct, kLosslessPct) << "frame " << fr << " k " << k;
            }
        }
        fs::remove(out);
    }
}

TEST(ProgressiveGltf, WriteFailureLeavesNoFile) {
    const Character c = import_character(asset("RiggedSimple.gltf"));
    const FrameSet f = sample_frames(c, default_training_set(c), 10.0);
    const ProgressiveSkin s = build(c, f, Strategy::Reorder);
    const std::string out = "/nonexistent-dir/progskin.glb";
    EXPECT_THROW(save_progressive(c, s, out), Error);
    EXPECT_FALSE(std::filesystem::exists(out));
}
