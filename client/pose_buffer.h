// pose_buffer.h — the client's newest bones of one instance: decoded frame
// chunks (datagram.fbs Chunk) merged per tick into a short history, and the
// pose at any display time by interpolation per bone between the two frames
// around it that carry that bone (cubic Hermite when a further frame on each
// side carries it too, else slerp/lerp; slerp/lerp between the samples of
// adjacent ticks of a linearly keyed clip, taken at its keys: add_chunk's
// sample), holding the newest value when
// nothing newer arrived. The server refreshes deep bones less often than shallow ones
// (scheduler.h): a bone stays shown for HOLD_TICKS after its newest frame.
// Frames carry the instance's epoch (datagram.fbs Chunk): nothing is
// interpolated between frames of different epochs (a clip wrap, a teleport,
// a spawn), the older side is held until the newer one's frame time. Frames
// may carry the instance's root block (world placement), interpolated the
// same way, and morph weights (a frame's morph block, sparse: a weight a frame
// does not carry keeps the value of the newest earlier frame that did, the
// server sending only the weights that changed). Weights are interpolated
// linearly between the frames around the display time within one epoch.
#pragma once
#include <cstdint>
#include <span>
#include <vector>

#include "bone_codec.h"
#include "bone_record.h"
#include "frame_reader.h"
#include "root_block.h"
#include "wire.h"

namespace progskin::net {

class PoseBuffer {
public:
    static constexpr int kHistory = 48;  // frames kept per instance (>= HOLD_TICKS + the largest display delay)

    PoseBuffer() = default;
    // fmt: the asset's parent-relative record format (bone_record.h; its
    // bone count); morph_count: the asset's morph targets (weights start at 0).
    explicit PoseBuffer(RelativeFormat fmt, int morph_count = 0);

    // Decodes count parent-relative records (bone_record.h, from `records`)
    // of bones first.. of the frame at `tick` whose prefix has `total` bones,
    // of which the server wants `show` shown from this tick on (total <= show
    // <= B; 0: total). A predicted record (records.base) is decoded from this
    // buffer's records of the same bone at the baseline ticks. Returns false
    // (and changes nothing) when the chunk is inconsistent, a record does not
    // decode, or a baseline record is not here (counted: missing_baselines).
    // epoch: Chunk.epoch; root: the chunk's root block (root_block.h, empty
    // when none), a predicted one decoded from this buffer's roots at its
    // baseline ticks (refused and counted like a record's when one is not
    // here). Stores each bone's pose relative to its progressive parent
    // (bone_record.h).
    // sample: the chunk's sample byte (wire.h sample_ticks): the bones (and
    // morph weights) of this tick were sampled that long before it, at a key
    // of a linearly keyed clip (interpolated linearly to the samples of the
    // adjacent ticks); the chunks of one tick must agree on it.
    bool add_chunk(uint32_t tick, int first, int count, int total, const RecordRun& records, int show = 0,
                   uint8_t epoch = 0, std::span<const uint8_t> root = {}, uint8_t sample = 0);
    // Records (and root blocks) refused because their baseline was not here
    // (never expected: the server predicts only from frames this client
    // acknowledged).
    uint64_t missing_baselines() const { return missing_baselines_; }
    uint64_t predicted() const { return predicted_; }  // records decoded from a baseline

    // Applies a chunk's morph block (proto/frame_reader.h: count byte, then
    // entries) to the frame at `tick` (total, show, epoch as in add_chunk; the
    // frame is created when the chunk carries no bone). Returns false (and
    // changes nothing) when an index is not below morph_count() or the chunk is
    // inconsistent. O(entries), no allocation.
    bool add_morphs(uint32_t tick, int total, int show, uint8_t epoch, const uint8_t* block, uint8_t sample = 0);
    int morph_count() const { return morphs_; }
    // Morph weights at display tick d (out.size() == morph_count()): per
    // weight, its value at the frames around d (same epoch), lerped; held
    // from the newest frame at or before d when none follows. 0 for weights
    // never received. O(kHistory x (morph_count + kHistory)), no allocation.
    void weights_at(double d, std::span<float> out) const;

    bool empty() const { return !any_; }
    uint32_t newest_tick() const { return newest_; }
    // True once a frame at or before display tick d has been received (the
    // display starts `delay` after the first frame, not before it).
    bool covers(double d) const { return any_ && d >= double(int32_t(first_ - newest_)) + double(newest_); }
    // Bones shown at display tick d: the `show` of the newest kept frame at or
    // before d (before the first frame, that frame's), limited to the bones
    // received so far; each bone is interpolated between its own frames.
    int bones_at(double d) const;
    // Of bones 0..bones-1, those whose records of the ticks around display
    // tick d are here: of tick floor(d) and, when d is not a tick, of
    // floor(d) + 1 (the others are interpolated across a longer gap or
    // held). O(kHistory + bones), no allocation.
    int bones_recorded(double d, int bones) const;
    // The display time of tick t's own sample: the time its bones were
    // sampled (sample byte, add_chunk), or t when no frame of tick t is here
    // or it was sampled at the tick (a display snapped to ticks shows each
    // frame as it came: ClientSession --snap-to-ticks).
    double sample_of(uint32_t t) const;
    // For a frame of `tick` that came after a newer one (late, or a repair):
    // the display tick from which the display needed it: the sample time of
    // the second newest kept frame before it that carries bone b (the cubic
    // between those two takes it as its outer neighbour), of the newest when
    // there is no such second one within HOLD_TICKS of it and of its epoch;
    // tick when the newest is more than HOLD_TICKS older, of another epoch,
    // or none. O(kHistory).
    double needed_from(uint32_t tick, int b) const;
    // The largest gap (ticks) between a bone's previous frame and the frame
    // of the last accepted chunk, over the chunk's bones, counting gaps of at
    // most HOLD_TICKS (longer ones are a bone shown again, not a refresh); 0
    // when none. The client's display delay covers it.
    int last_gap() const { return last_gap_; }
    // Pose of bone b relative to its progressive parent (bone 0: to the
    // character's root) at display tick d, interpolated about the bone's
    // pivot (its joint turns in place between frames, as a clip's keys do);
    // false if bone b was never received.
    // held_at (optional): the tick of the frame whose value is held when no
    // frame after d carries bone b yet, else a value > d.
    // anchor_at (optional): when d falls in a known boundary gap (below),
    // out is the pose of the nearest frame on d's side of the boundary and
    // *anchor_at its tick, so that the caller can carry it to d along the
    // clip (InstanceView); when d is past a known boundary and no frame of
    // the next epoch carries bone b yet (lost or late), out is the newest
    // frame's pose and *anchor_at its tick, carried across the boundary the
    // same way; else *anchor_at is NaN.
    bool pose(int b, double d, BonePose& out, double* held_at = nullptr, double* anchor_at = nullptr) const;
    // When the display falls between the last frame of one epoch (a) and
    // the first of the next (c), the boundary function tells the display
    // tick of the discontinuity between them (a clip's wrap: the client
    // knows the clip), or NaN when unknown (a teleport). Before it, the
    // older epoch's motion is extrapolated from its last two frames; from
    // it on, the newer epoch's backwards from its first two (or the caller
    // carries the nearest one along the clip: anchor_at); unknown: the
    // older frame is held until the newer one's tick.
    void set_boundary(double (*boundary)(const void* ctx, double ta, double tc), const void* ctx) {
        boundary_ = boundary;
        boundary_ctx_ = ctx;
    }
    int bone_count() const { return bones_; }
    // Past the root's newest frame, within its epoch: the motion of its two
    // newest frames (at most HOLD_TICKS apart) carried on for at most
    // `ticks` (0: held at once), then held. Bones are not carried on that
    // way (tried: no gain; docs/performance.md "Protocol 7").
    static constexpr double kRootExtrapolationTicks = 2.0;
    void set_root_extrapolation(double ticks) { root_extrapolation_ = ticks; }
    // World placement at display tick d from the frames that carried a root
    // block (same epoch rules as pose, extrapolated a little past the
    // newest: set_root_extrapolation); false when none did.
    bool root(double d, RootPose& out) const;

private:
    struct Frame {
        uint32_t tick = 0;
        int total = 0;     // bones chosen for this tick
        int show = 0;      // bones to show from this tick on
        int count = 0;     // bones received (not necessarily a prefix)
        bool used = false;
        uint8_t epoch = 0;
        uint8_t sample = 0;  // the chunks' sample byte (add_chunk)
        bool has_root = false;
        RootPose root;
        std::vector<BonePose> bones;     // relative to the progressive parent
        std::vector<RecordInts> ints;    // the records' integers (baselines of predicted records)
        std::vector<uint8_t> have;
        bool has_weights = false;       // carried a morph block
        std::vector<float> weights;     // per morph target (valid where whave)
        std::vector<uint8_t> whave;
    };
    // The frame for `tick` (found or created, the oldest evicted); nullptr
    // when it is older than every kept frame (*too_old) or inconsistent.
    Frame* frame_for(uint32_t tick, int total, int show, uint8_t epoch, uint8_t sample, bool* too_old);
    double tick_time(uint32_t tick) const;     // display tick of a tick (roots)
    double sample_time(const Frame& f) const;  // ... of its bones' and weights' sample
    const Frame* frame_at(uint32_t tick) const;
    // pose() with the translation as the image of the bone's pivot (how frames keep it).
    bool pose_about_pivot(int b, double d, BonePose& out, double* held_at, double* anchor_at) const;
    std::vector<RecordInts> scratch_;   // a chunk's decoded records
    uint64_t missing_baselines_ = 0, predicted_ = 0;
    double root_extrapolation_ = kRootExtrapolationTicks;
    RootRing roots_;                     // the roots received, by tick (baselines of predicted roots)
    // Weight m as of frame f: the newest frame at or before f carrying it, else held_.
    float weight_as_of(const Frame& f, int m) const;
    int morphs_ = 0;
    std::vector<float> held_w_;         // weights of evicted frames (newest per weight)
    std::vector<uint32_t> held_w_tick_;
    std::vector<uint8_t> held_w_have_;
    int bones_ = 0;
    RelativeFormat fmt_;
    std::vector<Frame> frames_;
    std::vector<BonePose> last_;        // newest value of every bone
    std::vector<uint32_t> last_tick_;
    std::vector<uint8_t> last_have_;
    uint32_t newest_ = 0, first_ = 0;
    int last_gap_ = 0;
    bool any_ = false;
    double (*boundary_)(const void*, double, double) = nullptr;
    const void* boundary_ctx_ = nullptr;
};

}  // namespace progskin::net
