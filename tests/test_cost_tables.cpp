// test_cost_tables.cpp — the scheduler's cost model (offline/cost_tables.h):
// its gap tables interpolate as the client does, each bone relative to its
// progressive parent and composed down the prefix (docs/protocol.md
// "Scheduling"), so that a segment's interpolation error carries to the
// bones below it and a bone that keeps still relative to its parent costs
// nothing to interpolate.
#include <gtest/gtest.h>

#include <cmath>

#include "animation.h"
#include "collapse.h"
#include "cost_tables.h"
#include "gltf_import.h"

using namespace progskin;

// A chain whose root joint alone turns, back and forth (keys of uneven
// angles, so that interpolating between frames a gap apart misses them):
// every other joint keeps still relative to its parent. As the client
// interpolates, only bone 0's segment errs; in model space (the tables
// before version 4) every bone moves, and every segment erred.
TEST(CostTables, OnlyTheSegmentThatMovesRelativeToItsParentErs) {
    Character c = import_gltf(std::string(PROGSKIN_TEST_DATA) + "/armature_m.gltf").at(0);
    ASSERT_GE(c.joint_count(), 4u);
    ASSERT_LT(c.joint_parent[0], 0);
    Clip clip;
    clip.name = "root turns";
    Channel ch;
    ch.node = c.joint_node[0];
    ch.path = ChannelPath::Rotation;
    const double angles[] = {0, 40, 10, 70, 5, 50, 0};
    for (int k = 0; k < 7; ++k) {
        ch.times.push_back(0.25f * float(k));
        const double a = angles[k] * M_PI / 180.0 / 2.0;
        for (float v : {0.0f, 0.0f, float(std::sin(a)), float(std::cos(a))}) ch.values.push_back(v);  // x y z w about z
    }
    clip.channels = {ch};
    clip.start = 0.0f;
    clip.end = 1.5f;
    c.clips = {clip};
    const auto sel = default_training_set(c);
    const ProgressiveSkin s = build_best_progressive_skin(c, sample_frames(c, sel, 30.0));
    const AssetTables t = compute_asset_tables(c, s, sel);
    ASSERT_GE(t.segments.size(), 2u);
    for (size_t m = 0; m < t.segments[0].gap.size(); ++m) {
        const double root = t.segments[0].gap[m][8];
        EXPECT_GT(root, 0.0) << "model " << m;
        for (size_t q = 1; q < t.segments.size(); ++q)
            EXPECT_LT(t.segments[q].gap[m][8], 1e-6 * root) << "segment " << q << " (bones " << t.segments[q].from << ".."
                                                             << t.segments[q].to - 1 << ") model " << m;
    }
}
