// animation.h — clip selection and pose sampling (docs/metrics.md §1).
//
// Pose at time t: each joint's global matrix G_j(t) from the node hierarchy
// (non-joint ancestors included), skinning matrix M_j(t) = G_j(t) * IBM_j, and
// each morph target's weight (default weight unless a Weights channel plays).
// Channels: STEP, LINEAR (quaternions by slerp, shortest path) and CUBICSPLINE
// (Hermite, quaternions normalised), times clamped to the channel's key range.
#pragma once
#include <span>
#include <string>
#include <vector>

#include "character.h"

namespace progskin {

// Which clips play. Several clips play together: each channel of each selected
// clip applies at time t (CesiumMan stores its walk as 19 one-joint clips).
struct ClipSelection {
    std::vector<int> clips;  // indices into Character::clips; empty = rest pose
    float start = 0.0f;      // time range of the selection (min start, max end)
    float end = 0.0f;
    float duration() const { return end - start; }
    // Clip time of a selection played in a loop, t seconds after its start
    // (any t, also negative): start + t wrapped into [0, duration).
    double looped(double t) const;
    // Clip time t seconds after its start, looped, or once: clamped to the
    // selection and held at its end. loops (optional): how many times a
    // looped selection wrapped (0 when played once).
    double played(double t, bool once, int64_t* loops = nullptr) const;
};

// The selection of the given clips (indices into Character::clips, checked
// by the caller) played together: its time range is the union of theirs.
ClipSelection make_selection(const Character& c, std::vector<int> clips);

// Parse a --clip argument: a name, an index, "all" (every clip played
// together), or a comma-separated list. Throws Error naming the unknown clip.
ClipSelection select_clips(const Character& c, const std::string& spec);

// The training set of a build when no --clip is given: "auto" plays all clips
// together when they animate disjoint sets of nodes (CesiumMan), otherwise
// each clip on its own. Returns one selection per independently played group.
std::vector<ClipSelection> default_training_set(const Character& c);

// Skinning matrices M_j(t) of every joint at time t (t in the selection's time
// base, i.e. absolute clip time). out.size() must equal joint_count().
void sample_skinning_matrices(const Character& c, const ClipSelection& sel, double t,
                              std::span<glm::dmat4> out);

// Global matrices of every node at time t (out.size() == nodes.size()).
void sample_node_globals(const Character& c, const ClipSelection& sel, double t,
                         std::span<glm::dmat4> out);

// Global matrices of every node from every node's local matrix (both of
// c.nodes.size()): parents first, whatever the order of the nodes. Throws
// Error on a size mismatch or a cyclic hierarchy. O(nodes).
void compose_node_globals(const Character& c, std::span<const glm::dmat4> locals, std::span<glm::dmat4> globals);

// Morph weights of every morph target at time t (out.size() == morphs.size()):
// what a streamed instance needs per frame besides its bones. Channels clamp to
// their keys like T/R/S; a target without a channel keeps its default weight.
void sample_morph_weights(const Character& c, const ClipSelection& sel, double t, std::span<float> out);

// The key times of a selection whose every channel interpolates linearly
// (its motion is then piecewise linear between them in each node's local
// translation, rotation by slerp, scale and morph weights), sorted, closer
// ones than 1e-6 s merged; empty when a channel is STEP or CUBICSPLINE or
// nothing plays. O(keys log keys).
std::vector<double> linear_key_times(const Character& c, const ClipSelection& sel);

// The latest key in (lo, hi] (keys sorted), or NaN when none. O(log keys).
double latest_key_in(const std::vector<double>& keys, double lo, double hi);

// Frames of one or more selections sampled at fps: frame times run from start
// to end inclusive (floor(duration * fps) + 1 frames, at least 1).
struct FrameSet {
    int joint_count = 0;
    int morph_count = 0;                    // Character::morphs.size() (0: no morph targets)
    std::vector<double> times;              // per frame, absolute clip time
    std::vector<int> selection_of_frame;    // which selection it came from
    std::vector<Mat34> skinning;            // frames * joint_count, row-major per frame
    std::vector<float> morph_weights;       // frames * morph_count (empty when morph_count == 0)
    size_t frame_count() const { return times.size(); }
    const Mat34* frame(size_t f) const { return skinning.data() + f * joint_count; }
    // Morph weights of frame f (morph_count values), empty when the frame set has none.
    std::span<const float> weights(size_t f) const {
        if (morph_weights.size() < (f + 1) * size_t(morph_count)) return {};
        return {morph_weights.data() + f * size_t(morph_count), size_t(morph_count)};
    }
};
// Throws Error when the selections would take more than kMaxSampledFrames.
inline constexpr size_t kMaxSampledFrames = 100000;
FrameSet sample_frames(const Character& c, const std::vector<ClipSelection>& sels, double fps);

// One frame at exactly time t (no rounding of t to a frame rate): what `pose`,
// --verify and the three.js comparison evaluate.
FrameSet sample_pose(const Character& c, const ClipSelection& sel, double t);

}  // namespace progskin
