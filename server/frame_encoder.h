// frame_encoder.h — once per tick, samples every instance once and encodes all
// its bones once, in progressive order, relative to the instance's root: as
// the absolute records of bone_codec.h (what the world bus carries between
// nodes) and as the frame stream's parent-relative records (bone_record.h,
// closed loop, a bit stream with each bone's bit offset). Clients then only
// select bones and copy these bits (scheduler.h, datagram_packer.h).
//
// Instances live in slots (their wire ids, uint16) that are added and removed
// at run time; a freed id is reused last (first in, first out), and every
// reuse bumps the slot's generation so per-client state keyed by id resets.
// An instance plays a clip selection (looped, or once and held) or shows the
// newest live pose pushed for it (a game server's push_pose, or a player's
// published records, push_records). Every discontinuity of its motion (a
// loop wrap, a teleport, a new publisher epoch) changes its epoch, which the
// chunks carry so that no client interpolates across it. The wrap of a
// seamless loop (last pose = first pose) is no discontinuity and keeps it.
//
// Morph weights: per tick, a clip instance's weights (sample_morph_weights at
// its clip time) quantised for the wire (wire.h encode_morph_weight); a
// weight outside the wire range is refused (kNoWeight, counted), never
// clamped. Live instances carry the weights their publisher sent, if any. At most MAX_MORPHS
// targets per asset are streamed.
//
// Thread-safety: add_instance, remove_instance, push_pose, push_records and
// push_relative and set_root may be called from any thread; encode from one thread.
#pragma once
#include <array>
#include <atomic>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "scene.h"
#include "spatial_grid.h"
#include "tick_pool.h"
#include "wire.h"

namespace progskin::net {

struct EncodedInstance {
    int asset = 0;
    int bone_count = 0;
    int record_size = 12;
    size_t offset = 0;      // into EncodedFrame::bytes
    bool active = false;    // the slot holds an instance
    bool valid = false;     // active and has a pose (false: live instance with no pose pushed yet)
    int model = 0;          // cost model of the scheduler: ServerAsset::Segment index (selection, or live)
    uint32_t generation = 0;  // bumped at every add into this slot
    uint8_t epoch = 0;      // discontinuity counter (Chunk.epoch)
    uint8_t flags = 0;      // Chunk.flags: CHUNK_ROOT when the root block travels, CHUNK_SCALED
    // The chunk's sample byte (wire.h sample_ticks): 0, the pose is the
    // tick's; v >= 1, a key of a linearly keyed clip, (v - 1) / 254 ticks
    // before the tick (docs/protocol.md "Frame").
    uint8_t sample = 0;
    uint64_t owner = 0;     // session that owns it (0: server)
    glm::dvec3 world{0.0};  // current world position (importance)
    std::array<uint8_t, ROOT_BYTES> root{};  // root block (when flags & CHUNK_ROOT)
    // The tick its content (records, root, morph weights) last changed: this
    // tick for clip instances; for live ones the first encode after the newest
    // push_pose / push_records / set_root (a pose sent once and never again
    // costs its observers a refresh per hold, not a frame per tick).
    uint32_t changed_tick = 0;
    int morph_count = 0;    // morph weights this tick (EncodedFrame::morph), 0: none
    size_t morph_offset = 0;  // into EncodedFrame::morph
    size_t rel_offset = 0;  // into EncodedFrame::rel (bytes: the records' bit stream starts there)
    size_t bit_index = 0;   // into EncodedFrame::bit_offsets (bone_count + 1) and ints (bone_count)
};

inline constexpr int32_t kNoWeight = INT32_MIN;  // EncodedFrame::morph: refused this tick (out of range)

// Baselines (docs/protocol.md "Predicted records"): the encoder keeps each
// slot's record integers of the last kBaselineRing ticks, so that a record
// can be predicted from a tick up to kBaselineRing - 1 old (linear: the
// baseline's age a with 2a < kBaselineRing).
inline constexpr int kBaselineRing = 16;
inline constexpr int kPredictedPerSlot = 4;  // baselines coded per slot and tick (the rest: standalone records)

// One slot's records of a tick predicted from one baseline (Chunk.base):
// write_predicted's bits per bone (without the chunk's "predicted" bit).
struct PredictedRecords {
    bool usable = false;  // the baseline ticks were in the ring (else nothing is predicted from it)
    std::vector<uint8_t> bits;
    std::vector<uint32_t> offsets;  // bone_count + 1
    size_t record_bits(int b) const { return size_t(offsets[size_t(b) + 1] - offsets[size_t(b)]); }
};

struct EncodedFrame {
    uint32_t tick = 0;
    std::vector<EncodedInstance> instances;  // one per slot
    // The active instances by ground cell (spatial_grid.h), for the
    // clients' candidate search; not built in a frame made by hand (tests):
    // every client then weighs every slot.
    SpatialGrid grid;
    std::vector<uint8_t> bytes;  // records of every slot, stride bytes each
    std::vector<int32_t> morph;  // quantised morph weights (int16 values, or kNoWeight), morph stride per slot
    std::span<const int32_t> morphs(int i) const {
        return {morph.data() + instances[size_t(i)].morph_offset, size_t(instances[size_t(i)].morph_count)};
    }
    const uint8_t* records(int i) const { return bytes.data() + instances[i].offset; }
    // Parent-relative records (bone_record.h) of every slot: a bit stream per
    // slot (rel_stride bytes each) and each bone's first bit (bone_count + 1
    // offsets per slot, the last the end) and integers.
    std::vector<uint8_t> rel;
    std::vector<uint32_t> bit_offsets;
    std::vector<RecordInts> ints;
    const uint8_t* relative(int i) const { return rel.data() + instances[size_t(i)].rel_offset; }
    // Bits of bones [from, to) of instance i's relative records.
    size_t record_bits(int i, int from, int to) const {
        const uint32_t* o = bit_prefix(i);
        return to > from ? size_t(o[to] - o[from]) : 0;
    }
    // The same as prefix sums: record_bits(i, from, to) = p[to] - p[from].
    const uint32_t* bit_prefix(int i) const { return bit_offsets.data() + instances[size_t(i)].bit_index; }
    uint32_t bit_offset(int i, int b) const { return bit_offsets[instances[size_t(i)].bit_index + size_t(b)]; }

    // The ring of each slot's integers (kBaselineRing ticks): entry k of slot
    // i holds tick hist_tick (valid when hist_gen is the slot's generation).
    size_t ring_bones = 0;  // integers per ring entry (the largest asset's bones)
    std::vector<RecordInts> hist;
    std::vector<uint32_t> hist_tick, hist_gen;
    std::vector<std::array<uint8_t, ROOT_BYTES>> hist_root;  // per ring entry: the root block (absolute)
    std::vector<uint8_t> hist_has_root;                     // per ring entry: the chunks carried a root
    std::vector<uint8_t> hist_sample;                       // per ring entry: EncodedInstance::sample
    // Instance i's integers at `tick`, or nullptr when the ring does not hold them.
    const RecordInts* ints_at(int i, uint32_t tick) const;
    // Instance i's root block (absolute) at `tick`, or nullptr when the ring
    // does not hold that tick or its chunks carried no root.
    const uint8_t* root_at(int i, uint32_t tick) const;
    // Instance i's sample byte at `tick` (EncodedInstance::sample; 0 when the
    // ring does not hold that tick).
    uint8_t sample_at(int i, uint32_t tick) const;
    // Instance i's records predicted from baseline `base` (Chunk.base, non-zero),
    // coded once per tick and slot on first use and shared by every client
    // (thread-safe); nullptr when kPredictedPerSlot other baselines took the slot's room.
    const PredictedRecords* predicted(int i, uint8_t base) const;
    // Bone b of instance i predicted from a baseline of its own (`base`:
    // age | kBaseLinear, as RecordPlan's Own records): the prediction (false
    // when the ring lacks a baseline tick), and its length in bits
    // (SIZE_MAX: not predictable). own_bits codes each (slot, bone, base)
    // once per tick on first use and shares it between clients and threads
    // (OwnCache: lock-free, direct-mapped; a collision only codes again).
    bool own_prediction(int i, int b, uint8_t base, RecordInts& pred) const;
    // Instance i's baseline ticks for `base` (Chunk.base syntax): their
    // integers (b2 only when linear) and ages along the samples' times
    // (sample_age); what predicted() and own_prediction() predict from.
    struct Baseline {
        const RecordInts *b1 = nullptr, *b2 = nullptr;
        uint32_t a1 = 0, a2 = 0;
        RecordInts predict(int b) const { return b2 ? predict_record(b1[b], a1, &b2[b], a2) : predict_record(b1[b], a1); }
    };
    bool baseline(int i, uint8_t base, Baseline& out) const;  // false when the ring lacks a tick of it
    size_t own_bits(int i, int b, uint8_t base) const;
    void own_prefetch(int i, int b, uint8_t base) const;  // a hint: own_bits(i, b, base) comes soon
    // Instance i's root block predicted from `base` (root_block.h: age |
    // kBaseLinear, the roots at tick - age and tick - 2 age; 0: absolute):
    // write_root_block appends it to out and returns its bytes;
    // root_block_bytes is that length, coded once per (slot, base) and tick
    // on first use and shared like own_bits (the OwnCache under bone 255,
    // which no bone has: MAX_BONES). A client plans every candidate's root
    // but writes only those of the characters it sends.
    size_t write_root_block(int i, uint8_t base, std::vector<uint8_t>& out) const;
    size_t root_block_bytes(int i, uint8_t base) const;
    // Each entry: the tick's epoch (20 bits), slot (16), bone (8; 255: the
    // root block), base index (5: (age - 1) * 2 + linear) and bits (12; all
    // ones: not predictable; the root block: its bytes). The encoder bumps
    // the epoch every tick and clears the table when the epoch's 20 bits wrap.
    struct OwnCache {
        static constexpr size_t kEntries = size_t(1) << 18;
        std::unique_ptr<std::atomic<uint64_t>[]> entries = std::make_unique<std::atomic<uint64_t>[]>(kEntries);
    };
    uint32_t epoch = 0;
    std::shared_ptr<OwnCache> own_cache = std::make_shared<OwnCache>();
    mutable std::vector<PredictedRecords> predicted_;  // kPredictedPerSlot per slot
    // The base predicted_[k] holds this tick (0: free), stored with release
    // once its records are coded (under the slot's lock): predicted() finds
    // a coded baseline without the lock (every client's plan asks for each
    // of its characters). A copy of the frame copies the values.
    struct PublishedBases {
        std::unique_ptr<std::atomic<uint8_t>[]> v;
        size_t n = 0;
        PublishedBases() = default;
        PublishedBases(const PublishedBases& o) { *this = o; }
        PublishedBases& operator=(const PublishedBases& o);
        PublishedBases(PublishedBases&&) noexcept = default;
        PublishedBases& operator=(PublishedBases&&) noexcept = default;
        void resize(size_t m);  // keeps the first min(n, m) values, the others 0
    };
    mutable PublishedBases published_;
    std::shared_ptr<std::array<std::mutex, 64>> predicted_locks = std::make_shared<std::array<std::mutex, 64>>();
};

struct EncoderStats {
    uint64_t poses_out_of_range = 0;  // live poses refused by the codec's range (never clamped)
    uint64_t stale_poses = 0;         // published records older than the newest (dropped)
    uint64_t morphs_out_of_range = 0;  // morph weights outside the wire range (refused, never clamped)
    uint64_t records_refused = 0;      // poses the relative record cannot code (quantise_record false): not sent that tick
};

class FrameEncoder {
public:
    FrameEncoder(std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
                 float tick_rate);
    // Clip instances whose selection is linearly keyed, keys at least a tick
    // apart, are sampled at the latest key since the tick before (else half
    // a tick before the tick), with the offset in EncodedInstance::sample; off: at every
    // tick (sample 0).
    void set_key_samples(bool on) { key_samples_ = on; }
    // Samples and encodes every active instance at `tick`. No allocation
    // after the first call unless instances were added past the capacity.
    // With a pool (set_pool) of more than one thread and at least
    // kPoolFrom slots, the slots are spread over its threads, a run of
    // kPoolRun at a time; what each slot encodes to does not depend on the
    // thread (the frame is the same bit for bit).
    const EncodedFrame& encode(uint32_t tick);
    // The threads encode() may use (nullptr: the caller's alone). The pool
    // must outlive the encoder's use of it, and nobody else may run it
    // during encode() (ServerCore: the tick thread encodes, then ticks the
    // clients on the same pool).
    void set_pool(TickPool* pool);
    static constexpr size_t kPoolFrom = 64, kPoolRun = 16;
    const EncodedFrame& frame() const { return frame_; }

    // Adds an instance; returns its id. Throws Error for a bad asset or clip
    // selection, or when every id (MAX_INSTANCES) is taken.
    int add_instance(const InstanceSpec& spec);
    // Removes an instance (no-op for an id that is not active).
    void remove_instance(int id);
    bool active(int id) const;
    // A copy of an active instance's spec (throws Error for an inactive id).
    InstanceSpec spec(int id) const;
    // Copies an active instance's spec; false when the id is not active.
    bool spec_if_active(int id, InstanceSpec& out) const;
    // Per slot: its generation when active, else 0 (out resized to capacity()).
    void generations(std::vector<uint32_t>& out) const;
    // Ids of the active instances, in increasing order.
    std::vector<int> active_ids() const;
    size_t capacity() const;  // slots (largest id + 1)

    // Clip time of an instance at a tick: start + offset + tick/rate*speed,
    // wrapped (looped) or held at the end (once). loops (optional): how many
    // times the loop wrapped.
    double clip_time(int instance, double tick, int64_t* loops = nullptr) const;
    // Live pose: skinning matrices in the Character's joint order, relative
    // to the root; used from the next encode() on instead of the clip.
    // Returns false (the previous pose stays) when a matrix is outside the
    // codec's range (counted in stats). Throws Error for a bad id or size.
    bool push_pose(int instance, std::span<const Mat34> skinning);
    // A player's pose, already as records (progressive order, bones
    // first..first+n-1) and a root block; kept when pose_seq is newer than
    // the newest kept (else counted stale and dropped). The caller checked
    // ownership, sizes and ranges (client_stream.cpp on_pose). Returns false when stale.
    // morphs (optional, may be empty: the last ones stay): every morph
    // weight of the character, quantised (wire.h encode_morph_weight).
    bool push_records(int instance, uint32_t pose_seq, uint8_t epoch, int first, std::span<const uint8_t> records,
                      std::span<const uint8_t, ROOT_BYTES> root, std::span<const int16_t> morphs = {});
    // The same with a player's Pose records as parent-relative integers
    // (bone_record.h, bones first..first+n-1, decoded and checked by the
    // caller): at the next encode they are composed down the progressive
    // parents into model space (a bone outside the asset's box refuses the
    // pose that tick, counted poses_out_of_range) and coded like any pose.
    // sample: the pose's sample byte (EncodedInstance::sample: 0, the
    // tick's; a key's otherwise), which the world bus carries from the node
    // that sampled a clip at its keys; a player's poses are the tick's.
    bool push_relative(int instance, uint32_t pose_seq, uint8_t epoch, int first, std::span<const RecordInts> records,
                       std::span<const uint8_t, ROOT_BYTES> root, std::span<const int16_t> morphs = {}, uint8_t sample = 0);
    // Places an instance in the world; teleport: a discontinuity (new epoch).
    // Returns false when the root is outside the root block's range.
    bool set_root(int instance, const RootPose& root, bool teleport);

    const std::vector<std::shared_ptr<ServerAsset>>& assets() const { return assets_; }
    EncoderStats stats() const;

private:
    struct Slot {
        InstanceSpec spec;
        bool active = false;
        uint32_t generation = 0;
        // live pose
        bool live = false, has_pose = false;
        std::vector<uint8_t> records;  // B records (progressive order)
        bool relative = false;         // the live pose is rel (push_relative), records follow from it
        std::vector<RecordInts> rel;   // B parent-relative records (push_relative)
        // push_pose's bones as given (B, progressive order): the relative
        // records code them, not the box-quantised records (whose 16-bit
        // steps over a box of every rigid pose are coarser); empty: decode
        // the records (push_records, the world bus).
        std::vector<BonePose> exact;
        std::vector<int16_t> morphs;   // published morph weights (quantised), empty: none
        uint32_t pose_seq = 0;
        uint8_t live_epoch = 0, teleports = 0;
        uint8_t sample = 0;         // push_relative's sample byte
        bool has_root = false;
        std::array<uint8_t, ROOT_BYTES> root{};
        bool changed = true;        // pushed to since the last encode
        bool rel_ready = false;     // a live pose's relative records are in the frame (unchanged since)
        uint32_t changed_tick = 0;  // EncodedInstance::changed_tick
    };
    std::vector<std::shared_ptr<ServerAsset>> assets_;
    float tick_rate_;
    size_t stride_ = 0;             // bytes per slot (the largest asset's records)
    size_t rel_stride_ = 0;         // relative record bytes per slot (the largest asset's worst case)
    size_t max_bones_ = 0;          // bones of the largest asset
    // encode's scratch, one per thread that encodes (work_[0]: the caller's;
    // then the pool's workers): each slot is encoded by one thread with its own.
    struct Work {
        std::vector<uint8_t> bits;            // encode_pose's
        std::vector<BonePose> model, decoded;
        std::vector<glm::dmat4> mats;         // a clip's skinning matrices
        std::vector<float> weights;           // sample_morph_weights'
        EncoderStats stats;                   // added to stats_ after the tick
    };
    std::vector<Work> work_;
    TickPool* pool_ = nullptr;
    // Samples (or takes the live pose of) slot i and encodes it into frame_.
    void encode_slot(size_t i, uint32_t tick, Work& w);
    // The slot a player's pose (sequence pose_seq, weights morphs) goes into,
    // mutex_ held: nullptr when the instance is not active, the pose is older
    // than the kept one (counted stale) or the weights are not one per target.
    Slot* pose_slot(int instance, uint32_t pose_seq, std::span<const int16_t> morphs);
    // A pushed pose's root block, weights, sequence and epoch into the slot.
    void take_pose(Slot& slot, uint32_t pose_seq, uint8_t epoch, std::span<const uint8_t, ROOT_BYTES> root,
                   std::span<const int16_t> morphs, bool relative);
    // A push_relative pose composed into model_ and the slot's absolute
    // records; false (counted) when a bone leaves the asset's box.
    bool compose_live(Slot& slot, const ServerAsset& a, Work& w);
    // Codes slot i's poses (w.model) as relative records into the frame; false when refused.
    bool encode_relative(size_t i, const ServerAsset& a, Work& w);
    // Keeps slot i's integers of this tick in the baseline ring.
    void keep_baseline(size_t i, uint32_t tick, uint32_t generation);
    // Per asset and clip selection: the loop is seamless (its last pose is
    // its first, to 1e-4 of the diagonal), so a wrap is no discontinuity.
    std::vector<std::vector<uint8_t>> seamless_;
    // Per asset and clip selection: its key times when every channel is
    // linear (linear_key_times) and their median spacing in seconds, else
    // empty: a tick samples the selection at its latest key since the tick
    // before (key_sample) when keys are at least a tick apart.
    struct Keys {
        std::vector<double> times;
        double spacing = 0;
    };
    std::vector<std::vector<Keys>> keys_;
    bool key_samples_ = false;
    // The clip time to sample instance spec s at `tick` (clip time t, loops
    // as played) and its sample byte (EncodedInstance::sample).
    double key_sample(const InstanceSpec& s, const ClipSelection& sel, const Keys& keys, uint32_t tick, double t,
                      int64_t loops, uint8_t& sample) const;
    EncodedFrame frame_;
    size_t morph_stride_ = 0;       // weights per slot (the largest streamed morph count)
    size_t max_joints_ = 0, max_morphs_ = 0;  // the largest asset's (Work's sizes)
    mutable std::mutex mutex_;      // slots_, free_, stats_, pushed_
    std::vector<BonePose> pushed_;  // push_pose's bones before its range check (swapped into the slot)
    uint32_t world_tag_ = 0;        // random, 24 bits, nonzero: the high bits of this encoder's world ids
    std::vector<Slot> slots_;
    std::deque<int> free_;
    EncoderStats stats_;
};

}  // namespace progskin::net
