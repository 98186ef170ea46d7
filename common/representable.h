// representable.h — what a bone record can carry, checked on a character's
// own poses.
//
// A bone record (docs/protocol.md "Bone records") codes each skinning matrix
// as rotation, one positive uniform scale and translation (pose.h
// decompose/compose). A mirrored joint (negative determinant), one scaled to
// zero, or one with non-uniform scale or shear is therefore shown off its
// pose, and an importer cannot clamp that away silently: this check samples
// the rest pose and every clip and says, per joint, how far off the stream
// would show it, so that `progskin build`, `inspect` and progskin-server tell
// the user when they load a file. Not part of the import: a client loading
// an asset has no one to tell, and would pay for the sampling.
#pragma once
#include <string>
#include <vector>

#include "character.h"

namespace progskin {

// Notes, worst first (at most max_notes, then one line saying how many more),
// for each joint whose decompose/compose round trip moves one of its
// vertices by more than threshold_pct of the bind diagonal, at the rest pose
// or at any frame of any clip sampled at fps (each clip on its own; at most
// 20,000 frames in all, the rate lowered for longer clips), naming
// the joint, the kind (mirrored / scaled to zero / non-uniform scale or
// shear), the clip and time of the worst frame and the distance; and one note
// per clip with STEP channels (clients interpolate between ticks, so a step
// shows blended over one tick). Empty when every pose is carried.
// Cost: O((rest + clip frames) * (nodes + joints)) plus one pass over the
// vertices.
std::vector<std::string> representability_notes(const Character& c, double fps = 30.0, double threshold_pct = 0.01,
                                                size_t max_notes = 6);

}  // namespace progskin
