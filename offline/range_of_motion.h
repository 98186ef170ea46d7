// range_of_motion.h — training poses for a skeleton that no clip moves
// (docs/algorithms.md "Characters without animation").
//
// An avatar exported without animation, for a game to drive, trains its
// progressive order on the rest pose alone: there every collapse costs
// nothing, so the order is arbitrary (fingers may come before the spine) and
// the server's tables see no motion to value. A build then trains on these
// poses instead: every joint turns smoothly from its rest rotation about two
// random axes, each by up to kRangeOfMotionDegrees in a sine of its own
// frequency (0.4-1.2 Hz) and phase, all joints at once, for
// kRangeOfMotionSeconds. Deterministic: the same character gives the same
// frames. Morph weights stay at their defaults.
#pragma once
#include <cstdint>
#include <vector>

#include "animation.h"
#include "character.h"

namespace progskin {

inline constexpr double kRangeOfMotionSeconds = 8.0;
inline constexpr double kRangeOfMotionDegrees = 30.0;

// The range-of-motion frames of c sampled at fps (floor(seconds * fps) + 1
// frames, one selection: selection_of_frame 0). Cost: O(frames * nodes).
FrameSet range_of_motion_frames(const Character& c, double fps, uint64_t seed = 1);

// Whether some joint's skinning matrix differs between two frames of
// `frames` by more than `tolerance` (any of its 12 entries; translations in
// model units). O(frames * joints).
bool skeleton_moves(const FrameSet& frames, double tolerance = 1e-6);

// The frames a build and the server's tables train on: the selections
// sampled at fps, or, when those do not move the skeleton (no clip, or
// clips of morph weights only), range_of_motion_frames(c, fps) with
// *range_of_motion set (else cleared).
FrameSet training_frames(const Character& c, const std::vector<ClipSelection>& selections, double fps,
                         bool* range_of_motion = nullptr);

}  // namespace progskin
