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

}  // namespace progskin
