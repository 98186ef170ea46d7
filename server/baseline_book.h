// baseline_book.h — what one client has acknowledged of each character's
// bones, and from it the record plan of a tick: the baseline each
// character's chunks predict from (Chunk.base), which bones are predicted
// and what each record costs (docs/protocol.md "Predicted records").
//
// The rule: a record is predicted only from ticks whose datagram carrying
// that bone this client acknowledged (Ack / ack_bits), never from one it may
// not have; with none, the record stands alone. So a lost datagram can never
// corrupt a later frame: at worst a record costs its standalone bits.
//
// BaselineBook keeps, per datagram sent (the last kSentRing), the runs of
// bones it carried (instance, generation, tick); on an Ack it marks those
// bones acknowledged: per character the newest acknowledged tick and, per
// bone, a 16-bit mask of the acknowledged ticks at and before it. A new
// occupant of an instance id (generation) starts empty, and the first
// kGraceTicks after a character's first acknowledgement are not used as
// baselines (its frames may have reached the client before the control
// channel announced it, and been skipped).
//
// plan() chooses per character the newest acknowledged tick as the chunk's
// baseline (age a = tick - newest, 1 <= a <= 15), linear when every bone
// acknowledged there is also acknowledged at 2a (2a < kBaselineRing), and
// takes the shared predicted records of that baseline (EncodedFrame::
// predicted). A bone not acknowledged there (refreshed at other ticks) is
// predicted from its own newest acknowledged tick when that is shorter than
// standalone (its length coded once per tick for every client planning it,
// EncodedFrame::own_bits; the record written only when it goes). Cost:
// O(bones) per character and tick; memory 2 bytes per bone of every
// character this client was sent.
#pragma once
#include <bit>
#include <cstdint>
#include <span>
#include <vector>

#include "frame_encoder.h"
#include "root_block.h"

namespace progskin::net {

class BaselineBook {
public:
    static constexpr size_t kSentRing = 128;  // datagrams remembered until acknowledged
    static constexpr uint32_t kGraceTicks = 15;

    // The packer: datagram `seq` (frame tick `tick`) carries bones
    // [first, first + count) of `instance`.
    void carried(uint32_t seq, uint32_t tick, int instance, uint32_t generation, int first, int count);
    // ... and the instance's morph block (only reported lost, never a baseline).
    void carried_morphs(uint32_t seq, uint32_t tick, int instance, uint32_t generation);
    // A datagram is taken as lost when an Ack leaves it out while it
    // acknowledges a newer one and either kLossReorder or more datagrams
    // were sent after it, or it was sent at least `loss_delay_us` before
    // the Ack arrived (QUIC's rules, RFC 9002 6.1: a later datagram arrived
    // and this one is later than reordering explains); within the Ack's
    // window (32).
    static constexpr uint32_t kLossReorder = 3;
    // The bones of a datagram taken as lost: [first, first + count) of
    // `instance` (generation), sent at frame tick `tick`; or (morphs) its
    // morph block (count 0).
    struct LostRun {
        uint32_t seq = 0;  // the datagram
        uint32_t tick = 0, generation = 0;
        int instance = 0, first = 0, count = 0;
        bool morphs = false;
    };
    // Datagram `seq` (its runs given to carried) left at `send_us`.
    void sent_at(uint32_t seq, uint32_t send_us);
    // The share of frame datagrams lost on their first send, before any
    // repair: a moving average (weight kFirstLossWeight) over each
    // datagram's first outcome, its first acknowledgement (0) or its first
    // report as lost (1); a repaired datagram acknowledged later counts
    // once. 0 until the first outcome. (The rate's loss, RateController::
    // loss, is what stays lost after the repairs.)
    double first_loss() const { return first_loss_; }
    static constexpr double kFirstLossWeight = 1.0 / 64;
    // Whether datagram seq (its runs given to carried, among the last
    // kSentRing) is still unacknowledged.
    bool unacked(uint32_t seq) const {
        const Sent& s = sent_[seq % kSentRing];
        return s.valid && s.seq == seq;
    }
    // When datagram seq first left (sent_at), acknowledged or not; false
    // when not known.
    bool sent_time(uint32_t seq, uint32_t& us) const {
        const Sent& s = sent_[seq % kSentRing];
        if (s.seq != seq || !s.timed) return false;
        us = s.send_us;
        return true;
    }
    // An Ack: datagram `ack` and those of ack_bits (bit i: ack - 1 - i).
    // lost (optional): the runs of the datagrams this Ack shows lost
    // (kLossReorder; by time from now_us when loss_delay_us > 0) are
    // appended, each datagram's once; an Ack arriving later for one of them
    // still marks its bones acknowledged. O(32 + runs); no allocation once
    // `lost` has grown.
    void on_ack(uint32_t ack, uint32_t bits, std::vector<LostRun>* lost = nullptr, uint32_t now_us = 0,
                uint32_t loss_delay_us = 0);
    // Whether the client acknowledged bone b of instance (generation) at tick t.
    bool acked(int instance, uint32_t generation, int b, uint32_t t) const;
    // The newest acknowledged tick of any bone of the instance usable as a
    // baseline (past the grace); false when none.
    bool newest(int instance, uint32_t generation, uint32_t& tick) const;
    // Whether the client acknowledged any bone of instance (generation) at
    // tick t, past the grace: it holds that tick's root block (every chunk
    // of a tick carries it).
    bool acked_any(int instance, uint32_t generation, uint32_t t) const;
    // The newest acknowledged tick of bone b (past the grace); false when none.
    bool newest_of(int instance, uint32_t generation, int b, uint32_t& tick) const;
    void clear();

    // One character's acknowledgements at once (the queries above, without
    // finding the character again for each bone): RecordPlan::plan's view.
    struct View {
        uint32_t newest = 0, first = 0;
        uint16_t ticks = 0;
        std::span<const uint16_t> mask;  // per bone: bit k, tick newest - k acknowledged
        // Tick t past the grace and within the 16 ticks kept: its bit, else -1.
        int bit(uint32_t t) const {
            const uint32_t d = newest - t;
            return d >= 16 || int32_t(t - first) < int32_t(kGraceTicks) ? -1 : int(d);
        }
        bool acked(int b, uint32_t t) const {
            const int d = bit(t);
            return d >= 0 && size_t(b) < mask.size() && ((mask[size_t(b)] >> d) & 1);
        }
        bool acked_any(uint32_t t) const {
            const int d = bit(t);
            return d >= 0 && ((ticks >> d) & 1);
        }
        // The newest acknowledged tick of bone b past the grace; false when none.
        bool newest_of(int b, uint32_t& t) const {
            if (size_t(b) >= mask.size() || mask[size_t(b)] == 0) return false;
            t = newest - uint32_t(std::countr_zero(mask[size_t(b)]));
            return int32_t(t - first) >= int32_t(kGraceTicks);
        }
    };
    // False when nothing of instance (generation) was acknowledged.
    bool view(int instance, uint32_t generation, View& v) const;
    // A hint: instance's acknowledgements will be read soon (view).
    void prefetch(int instance) const {
        if (instance < 0 || size_t(instance) >= acks_.size()) return;
        const std::vector<uint16_t>& m = acks_[size_t(instance)].mask;
        for (size_t k = 0; k < m.size(); k += 32) __builtin_prefetch(m.data() + k);  // each 64-byte line
    }

private:
    struct Run {
        uint16_t instance = 0;
        uint8_t first = 0, count = 0;  // count 0: the morph block
        uint32_t generation = 0;
    };
    struct Sent {
        uint32_t seq = 0, tick = 0;
        uint32_t send_us = 0;
        bool valid = false;
        bool timed = false;  // send_us set
        bool lost = false;   // reported lost (on_ack)
        std::vector<Run> runs;
    };
    struct Acks {
        uint32_t generation = 0;
        bool any = false;
        uint32_t newest = 0;  // newest acknowledged tick of any bone
        uint32_t first = 0;   // the first acknowledged tick (the grace starts there)
        uint16_t ticks = 0;   // bit k set: some bone acknowledged at tick newest - k
        std::vector<uint16_t> mask;  // per bone: bit k set, tick newest - k acknowledged
    };
    void mark(const Sent& s);
    Sent& slot(uint32_t seq, uint32_t tick);  // datagram seq's entry, started afresh for a new seq
    double first_loss_ = 0;                    // first_loss()
    std::vector<Sent> sent_ = std::vector<Sent>(kSentRing);
    std::vector<Acks> acks_;  // by instance id
};

// A client's record choices for one tick, for the instances it may be sent.
class RecordPlan {
public:
    // Plans instance i of the frame (valid, bone_count bones) from the book.
    void plan(const EncodedFrame& frame, int i, const BaselineBook& book);
    void begin(const EncodedFrame& frame);  // forgets the previous tick's choices
    // Chunk.base of instance i (0: standalone records, no "predicted" bits).
    uint8_t base(int i) const;
    // Bits of bones [from, to) of instance i as planned (the "predicted" bits included).
    size_t bits(const EncodedFrame& frame, int i, int from, int to) const;
    // The same as prefix sums (bits(from, to) = p[to] - p[from], bone_count + 1 of them).
    const uint32_t* bit_prefix(const EncodedFrame& frame, int i) const {
        if (i >= 0 && size_t(i) < entry_of_.size() && entry_of_[size_t(i)] >= 0)
            return prefix_.data() + entries_[size_t(entry_of_[size_t(i)])].prefix;
        return frame.bit_prefix(i);
    }
    // How bone b of instance i goes: its prefix (RecordPrefix: standalone,
    // from the chunk's baseline, or from its own), and its records.
    RecordPrefix prefix(int i, int b) const;
    const PredictedRecords* records(int i) const;
    // Writes bone b's own-baseline record (prefix Own) to w: priced when
    // planned (EncodedFrame::own_bits), written only when it goes. Returns the bits.
    size_t write_own(const EncodedFrame& frame, int i, int b, BitWriter& w) const;
    // Instance i's root block for this client (root_block.h), predicted from
    // its root at the newest tick the client acknowledged (linear when the
    // tick as far before that is acknowledged too), written to out (cleared)
    // and returned; empty when not planned (the packer writes it absolute).
    // root_bytes: its size, or kRootAbsoluteBytes when not planned (0 when
    // the instance has no root). The plan keeps only the block's baseline
    // and length (EncodedFrame::root_block_bytes, shared between clients):
    // the block is written for the characters that go.
    std::span<const uint8_t> root(const EncodedFrame& frame, int i, std::vector<uint8_t>& out) const;
    size_t root_bytes(const EncodedFrame& frame, int i) const;

private:
    struct Entry {
        uint8_t base = 0;
        const PredictedRecords* records = nullptr;
        size_t at = 0;      // into flags_ (bone_count)
        size_t prefix = 0;  // into prefix_ (bone_count + 1)
        uint8_t root_base = 0;  // the root block's baseline (root_block.h)
        uint32_t root_len = 0;  // its bytes (0: no root)
    };
    // plan()'s steps: the chunk's baseline and the bones predicted from it;
    // the other acknowledged bones' own baselines; the root block's.
    void chunk_baseline(const EncodedFrame& frame, int i, const BaselineBook::View& v, Entry& en);
    void own_baselines(const EncodedFrame& frame, int i, const BaselineBook::View& v, const Entry& en);
    void root_baseline(const EncodedFrame& frame, int i, const BaselineBook::View& v, Entry& en) const;
    std::vector<int32_t> entry_of_;  // per instance: index into entries_, -1 none
    std::vector<Entry> entries_;
    std::vector<uint32_t> prefix_;
    // Per bone of the planned instances, [0, bones_) used this tick; the
    // arrays only grow (no clearing per tick), and plan() writes a bone's
    // entries before anything reads them (own_*: only for Own bones).
    size_t bones_ = 0;
    std::vector<uint8_t> flags_;       // per bone: RecordPrefix::Kind
    std::vector<uint8_t> own_base_;    // per bone: its own baseline (Own)
    std::vector<uint32_t> own_len_;      // per bone: its own-baseline record's bits (EncodedFrame::own_bits)
    std::vector<std::pair<uint8_t, uint8_t>> own_try_;  // plan()'s scratch: (bone, own baseline) to price
};

}  // namespace progskin::net
