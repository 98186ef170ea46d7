// collapse.h — building a progressive skin by greedy collapse of an existing
// skin (docs/algorithms.md). Offline: Eigen least squares over every vertex
// and training frame; cost O(B^2 * V * F) in the worst case.
#pragma once
#include <functional>

#include "animation.h"
#include "character.h"
#include "progressive_skin.h"

namespace progskin {

struct BuildOptions {
    Strategy strategy = Strategy::Reorder;
    bool fit_corrections = true;  // false: plain copy-down (C = identity)
    // Progress callback: (step, total); may be empty.
    std::function<void(int, int)> progress;
    // build_best_progressive_skin only: the mean bits per frame of each
    // bone's record (progressive order) as the stream codes a skin's bones
    // (parent-relative, predicted; server/scene.h record_bits_per_bone). When
    // set, the strategy is chosen by rate-distortion (rd_area); else by mean RMS.
    std::function<std::vector<double>(const ProgressiveSkin&)> bone_bits;
};

ProgressiveSkin build_progressive_skin(const Character& c, const FrameSet& frames,
                                       const BuildOptions& options = {});

// The default build (docs/algorithms.md "Choosing the strategy"): builds
// with reorder and with flatten and keeps the one of lower mean RMS error
// over every prefix k = 1..B (the stream may show any; ties: reorder), or,
// with options.bone_bits, builds hierarchy too and keeps the one of the
// three of lowest rate-distortion area (rd_area: error against the bits the
// stream spends on the prefix; ties: reorder, flatten, hierarchy).
// options.strategy is ignored; progress runs once over the builds (total =
// 2 or 3 (B - 1)). Two or three times the cost of one build.
struct StrategyChoice {
    Strategy chosen = Strategy::Reorder;
    double reorder_mean_rms = 0, flatten_mean_rms = 0;  // model units, mean over k of LodError::rms
    bool by_rate = false;                               // chosen by rd_area (options.bone_bits)
    double hierarchy_mean_rms = 0;                      // (by_rate)
    double reorder_area = 0, flatten_area = 0, hierarchy_area = 0;  // rd_area of each (by_rate)
    double reorder_bits = 0, flatten_bits = 0, hierarchy_bits = 0;  // bits per frame of all bones of each (by_rate)
};
// The area under a skin's rate-distortion curve: its error e(k) (model
// units, LodError::rms) against the bits of its first k bones' records,
// e(k) held from the bits of k bones to those of k + 1, e(1) from 0 bits,
// e(B) up to `until` bits (>= the sum of bits): sum over k of e(k) times
// the bits between, in model units x bits. Of two skins, the lower area
// removes more error per bit over the range both cover. O(B).
double rd_area(const std::vector<LodError>& table, const std::vector<double>& bits, double until);
ProgressiveSkin build_best_progressive_skin(const Character& c, const FrameSet& frames, const BuildOptions& options = {},
                                            StrategyChoice* choice = nullptr);
double mean_rms(const std::vector<LodError>& table);  // mean of rms over the rows; 0 for none

}  // namespace progskin
