// cost_model.h — the scheduler's cost model of one asset: what showing and
// refreshing each segment of its progressive skin is worth (docs/protocol.md,
// "Scheduling"). Computed once per asset, offline
// (offline/cost_tables.h: compute_asset_tables), stored in progressive files
// and the server's cache, and read at run time by the server's scheduler.
//
// Segment 0 is bone 0; segment s >= 1 the bones [from, to) of one step of the
// lower convex hull of the squared error table e(k)^2. Each table has one
// entry per clip selection (what an instance plays) and a last one over all
// of them (live poses).
#pragma once
#include <array>
#include <vector>

#include "mat34.h"

namespace progskin {

// Whoever changes what the tables hold or how compute_asset_tables computes
// them must bump this, so that stale stored tables are recomputed, not read.
inline constexpr int kServerTablesVersion = 4;

// One step of a lower convex hull of an error table: going from `from`
// bones to `to` bones removes `gain` of error.
struct HullStep {
    int from = 0, to = 0;
    double gain = 0;
};

struct CostSegment {
    static constexpr int kGapTable = 17;
    int from = 0, to = 1;
    // Squared RMS error (model units^2) the segment removes when shown:
    // e(from)^2 - e(to)^2 over the selection's frames (segment 0:
    // (diagonal + e(1))^2, nothing shown).
    std::vector<double> collapse;
    // gap[m][g]: mean squared vertex error (model units^2) over an
    // interpolation interval of g frames at 30 Hz when only this segment's
    // bones are interpolated between frames g apart as the client does
    // (pose.h interpolate_between, each bone relative to its progressive
    // parent about its pivot, composed down the prefix: the bones below the
    // segment, exact relative to it, carry its error) and every other bone
    // is exact relative to its parent (tables version 4; before, each bone
    // was interpolated in model space and its children stayed exact);
    // gap[m][0] = gap[m][1] = 0. Beyond the table it grows as g^2 (a linear drift).
    std::vector<std::array<double, kGapTable>> gap;
    // gap[model] at a fractional gap g (linear between entries). O(1).
    double gap_at(int model, double g) const;
    // refresh[m][a] = a (a + 1) (G(a + 1) - G(a)) for a = 1..kGapTable-1,
    // the value of a refresh at age a at 30 Hz (scheduler.h); [0] unused.
    std::vector<std::array<double, kGapTable>> refresh;
    // show_value[m] = max over p < kHoldTicks of p (C - G(p)): showing the
    // segment, refreshed every p ticks, saves C - G(p) per tick for the
    // bytes of one refresh every p ticks (scheduler.h).
    std::vector<double> show_value;
};

// What the server derives from an asset before streaming it.
struct AssetTables {
    static constexpr int kGapTable = CostSegment::kGapTable;
    using Segment = CostSegment;
    double diagonal = 1;     // the error metric's normaliser (docs/metrics.md §2)
    double motion = 0;       // RMS vertex motion per second (model units/s)
    double bind_radius = 0;  // max |bind-space position|
    double max_scale = 1;    // of the skinning matrices over the training frames
    // The bone records' translation box (with a margin) and whether any
    // skinning matrix is scaled: the wire's record format (proto/bone_codec.h).
    glm::vec3 t_min{-1.0f}, t_max{1.0f};
    bool scaled = false;
    float ref_scale = 1.0f;  // the records' reference scale (RecordFormat::scale)
    float t_step = 0.0f;     // the relative records' translation step (RecordFormat::t_step)
    std::vector<CostSegment> segments;
};

}  // namespace progskin
