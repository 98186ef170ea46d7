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
};

ProgressiveSkin build_progressive_skin(const Character& c, const FrameSet& frames,
                                       const BuildOptions& options = {});

// The default build (docs/algorithms.md "Choosing the strategy"): builds
// with reorder and with flatten and keeps the one of lower mean RMS error
// over every prefix k = 1..B (the stream may show any; ties: reorder).
// options.strategy is ignored; progress runs once over both builds
// (total = 2 (B - 1)). Twice the cost of one build.
struct StrategyChoice {
    Strategy chosen = Strategy::Reorder;
    double reorder_mean_rms = 0, flatten_mean_rms = 0;  // model units, mean over k of LodError::rms
};
ProgressiveSkin build_best_progressive_skin(const Character& c, const FrameSet& frames, const BuildOptions& options = {},
                                            StrategyChoice* choice = nullptr);
double mean_rms(const std::vector<LodError>& table);  // mean of rms over the rows; 0 for none

}  // namespace progskin
