// datagram_packer.cpp — see datagram_packer.h.
#include "datagram_packer.h"

#include <algorithm>
#include <array>
#include <cassert>

#include "errors.h"
#include "baseline_book.h"
#include "bone_record.h"
#include "frame_reader.h"
#include "root_block.h"
#include "wire.h"

namespace progskin::net {

void DatagramPacker::flush(uint32_t tick, uint32_t& seq, std::vector<std::vector<uint8_t>>& out, size_t& wire) {
    if (chunks_.empty() && acks_.empty()) return;
    sorted_.assign(chunks_.begin(), chunks_.end());
    std::sort(sorted_.begin(), sorted_.end(), [](const ChunkOut& x, const ChunkOut& y) { return x.head.instance < y.head.instance; });
    payload_.clear();
    const size_t expect = chunks_.empty() ? 0 : payload_bytes(codes_.bits(), 0);
    if (!write_frame_payload(sorted_, codes_.best_order(), recs_.data(), blocks_.data(), payload_) || payload_.size() != expect)
        throw Error("datagram_packer: a payload of " + std::to_string(payload_.size()) + " bytes, " + std::to_string(expect) +
                    " expected");
    out.emplace_back();
    write_frame_datagram(seq++, now_us32(), tick, sampled_, acks_, payload_, out.back());
    const size_t size = out.back().size();
    // The room the packer leaves (WireCost::kFrameOverhead) must hold the header; the tests check it.
    if (size > MAX_DATAGRAM || size != payload_.size() + ack_bytes_ + WireCost::kFrameOverhead)
        throw Error("datagram_packer: a frame datagram of " + std::to_string(size) + " bytes for a payload of " +
                    std::to_string(payload_.size()));
    wire += size + UDP_IP_OVERHEAD;
    chunks_.clear();
    codes_.clear();
    head_bits_ = 0;
    recw_.clear();
    blocks_.clear();
    acks_ = {};  // in the first datagram only
    ack_bytes_ = 0;
}

// One instance's adjacent picks being packed: its bones in increasing order
// across the picks' ranges [first, k) (sorted, disjoint, as the scheduler
// emits them), and how its records go.
struct DatagramPacker::Group {
    const EncodedFrame& frame;
    std::span<const Pick> picks;
    const RecordPlan* plan;
    int instance;
    const EncodedInstance& e;
    uint8_t base;                   // Chunk.base (0: standalone records)
    const PredictedRecords* pred;   // the records predicted from it
    size_t p = 0;                   // the pick next_bone is in
    int bone = -1;                  // the next bone to go (-1: none left)
    int next_bone() {
        for (; p < picks.size(); ++p) {
            const int lo = std::clamp(picks[p].first, 0, e.bone_count), hi = std::min(picks[p].k, e.bone_count);
            const int b = std::max(bone + 1, lo);
            if (b < hi) return b;
        }
        return -1;
    }
    size_t bits_of(int b) const { return plan ? plan->bits(frame, instance, b, b + 1) : frame.record_bits(instance, b, b + 1); }
};

size_t DatagramPacker::pack(const EncodedFrame& frame, std::span<const Pick> picks, uint32_t& seq,
                            std::vector<std::vector<uint8_t>>& out, const RecordPlan* plan, BaselineBook* book,
                            std::span<const wire::PoseAck> acks) {
    size_t wire = 0;
    chunks_.clear();
    codes_.clear();
    head_bits_ = 0;
    recw_.clear();
    blocks_.clear();
    // FRAME_SAMPLED: every chunk opens with its sample byte when one of the
    // tick's instances was sampled at a key (a byte per chunk then).
    sampled_ = false;
    for (const Pick& p : picks) sampled_ = sampled_ || frame.instances[size_t(p.instance)].sample != 0;
    acks_ = acks;
    ack_bytes_ = acks.empty() ? 0 : pose_ack_bytes(acks.size());
    // Adjacent picks of one instance (the scheduler's ranges of it) share a chunk.
    for (size_t g = 0; g < picks.size();) {
        const int instance = picks[g].instance;
        size_t g_end = g + 1;
        while (g_end < picks.size() && picks[g_end].instance == instance) ++g_end;
        const uint8_t base = plan ? plan->base(instance) : 0;
        Group group{frame, picks.subspan(g, g_end - g), plan, instance, frame.instances[size_t(instance)], base,
                    base ? plan->records(instance) : nullptr};
        pack_group(group, seq, out, wire, book);
        g = g_end;
    }
    flush(frame.tick, seq, out, wire);
    return wire;
}

// The group's morph weights that can go (only those the encoder has and did
// not refuse), as a mask.
static std::array<uint64_t, 4> group_morphs(std::span<const Pick> picks, std::span<const int32_t> weights) {
    std::array<uint64_t, 4> morphs{};
    for (const Pick& q : picks)
        for (size_t w = 0; w < morphs.size(); ++w) morphs[w] |= q.morphs[w];
    for (size_t m = 0; m < 256; ++m)
        if ((morphs[m / 64] >> (m % 64) & 1) && (m >= weights.size() || weights[m] == kNoWeight))
            morphs[m / 64] &= ~(uint64_t(1) << (m % 64));
    return morphs;
}

void DatagramPacker::pack_group(Group& grp, uint32_t& seq, std::vector<std::vector<uint8_t>>& out, size_t& wire,
                                BaselineBook* book) {
    const EncodedFrame& frame = grp.frame;
    const EncodedInstance& e = grp.e;
    const size_t room = MAX_DATAGRAM - WireCost::kFrameOverhead;
    int show = 0;
    for (const Pick& q : grp.picks) show = std::max(show, std::clamp(std::max(q.show, q.k), 0, e.bone_count));
    grp.bone = grp.next_bone();
    // The root block: this client's (predicted, RecordPlan::root), else absolute.
    const bool root = (e.flags & CHUNK_ROOT) != 0;
    std::span<const uint8_t> planned = grp.plan && root ? grp.plan->root(frame, grp.instance, root_) : std::span<const uint8_t>{};
    if (root && planned.empty()) {
        root_.clear();
        frame.write_root_block(grp.instance, 0, root_);  // absolute
        planned = root_;
    }
    const size_t root_bytes = planned.size();
    // Morph weights of the group: in its first chunk (a chunk of their own,
    // first = show - 1 and an empty mask, when no bone goes).
    const std::span<const int32_t> weights = frame.morphs(grp.instance);
    const std::array<uint64_t, 4> morphs = group_morphs(grp.picks, weights);
    size_t morph_bytes = morph_block_bytes(morphs);
    if (morph_bytes > 0 && grp.bone < 0 && show < 1) morph_bytes = 0;  // no chunk can carry them (never picked so)
    while (grp.bone >= 0 || morph_bytes > 0) {
        const int first = grp.bone >= 0 ? grp.bone : show - 1;
        const uint16_t instance = uint16_t(grp.instance);
        // One chunk per instance and datagram: a group that continues goes on in the next.
        if (codes_.contains(instance)) {
            flush(frame.tick, seq, out, wire);
            continue;
        }
        // The head, its mask at its largest (a bitmap), and the blocks.
        ChunkOut c;
        c.head = ChunkHead{instance, uint8_t(first), uint8_t(show), e.epoch, uint8_t(e.flags | base_to_flags(grp.base)), {}};
        if (morph_bytes > 0) c.head.flags |= CHUNK_MORPH;
        const size_t head = head_fixed_bits(first) + size_t(show - first);
        const size_t codes = codes_.bits_with(c.head);  // the instance codes and fields, exact
        const size_t blocks = (sampled_ ? 1 : 0) + root_bytes + morph_bytes;
        const size_t fixed = ack_bytes_ + blocks;
        const size_t used = payload_bytes(codes, head) + fixed;
        if (used > room || (grp.bone >= 0 && payload_bytes(codes, head + grp.bits_of(grp.bone)) + fixed > room)) {
            flush(frame.tick, seq, out, wire);
            continue;
        }
        c.block_from = blocks_.size();
        if (sampled_) blocks_.push_back(e.sample);
        blocks_.insert(blocks_.end(), planned.begin(), planned.end());
        if (morph_bytes > 0) {
            if (book) book->carried_morphs(seq, frame.tick, grp.instance, e.generation);
            blocks_.push_back(uint8_t((morph_bytes - 1) / MORPH_ENTRY_BYTES));
            for (size_t m = 0; m < weights.size(); ++m)
                if (morphs[m / 64] >> (m % 64) & 1) {
                    const uint16_t v = uint16_t(int16_t(weights[m]));
                    blocks_.push_back(uint8_t(m));
                    blocks_.push_back(uint8_t(v & 0xFF));
                    blocks_.push_back(uint8_t(v >> 8));
                }
            morph_bytes = 0;
        }
        c.block_bytes = blocks_.size() - c.block_from;
        // The records: what the room leaves after the head at its largest.
        const size_t room_bits = (room - ack_bytes_ - blocks_.size()) * 8 -
                                 (codes + head_bits_ + recw_.bits() + head);
        c.rec_from = recw_.bits();
        write_records(grp, c.head, room_bits, seq, book);
        c.rec_bits = recw_.bits() - c.rec_from;
        codes_.add(c.head);
        head_bits_ += head_fixed_bits(first) + mask_bits(c.head);
        chunks_.push_back(c);
    }
}

// Records onto the datagram's record stream: as many of the group's bones
// from grp.bone on as fit room_bits, each set in the head's mask (bone -
// first), each run of consecutive bones told to the book.
void DatagramPacker::write_records(Group& grp, ChunkHead& head, size_t room_bits, uint32_t seq, BaselineBook* book) {
    const EncodedFrame& frame = grp.frame;
    const int instance = grp.instance;
    const uint8_t* src = frame.relative(instance);
    size_t rec_bits = 0;
    BitWriter& w = recw_;
    const int first = head.first;
    int run_first = -1, run_end = -1;  // the run of consecutive bones being written (for the book)
    auto end_run = [&] {
        if (book && run_first >= 0) book->carried(seq, frame.tick, instance, grp.e.generation, run_first, run_end - run_first);
        run_first = -1;
    };
    // Absolute records of consecutive bones lie one after another in
    // the frame's bits: they are copied as one run.
    size_t copy_from = 0, copy_count = 0;
    auto copy_run = [&] {
        copy_bits(src, copy_from, copy_count, w);
        copy_count = 0;
    };
    for (size_t nbits; grp.bone >= 0 && rec_bits + (nbits = grp.bits_of(grp.bone)) <= room_bits;) {
        const int bone = grp.bone;
        head.carry(bone - first);
        if (grp.base) {
            const RecordPrefix how = grp.plan->prefix(instance, bone);
            write_prefix(how, w);
            if (how.kind == RecordPrefix::Chunk) copy_bits(grp.pred->bits.data(), grp.pred->offsets[size_t(bone)], grp.pred->record_bits(bone), w);
            else if (how.kind == RecordPrefix::Own) grp.plan->write_own(frame, instance, bone, w);
            else copy_bits(src, frame.bit_offset(instance, bone), frame.record_bits(instance, bone, bone + 1), w);
        } else {
            const size_t at = frame.bit_offset(instance, bone);
            if (copy_count > 0 && copy_from + copy_count != at) copy_run();
            if (copy_count == 0) copy_from = at;
            copy_count += frame.record_bits(instance, bone, bone + 1);
        }
        rec_bits += nbits;
        if (bone != run_end) end_run(), run_first = bone;
        run_end = bone + 1;
        grp.bone = grp.next_bone();
    }
    if (copy_count > 0) copy_run();
    end_run();
}

}  // namespace progskin::net
