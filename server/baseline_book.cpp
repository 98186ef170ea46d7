// baseline_book.cpp — see baseline_book.h.
#include "baseline_book.h"

#include <bit>

namespace progskin::net {

static bool newer(uint32_t a, uint32_t b) { return int32_t(a - b) > 0; }

BaselineBook::Sent& BaselineBook::slot(uint32_t seq, uint32_t tick) {
    Sent& s = sent_[seq % kSentRing];
    if (!s.valid || s.seq != seq) {
        s.seq = seq;
        s.tick = tick;
        s.valid = true;
        s.timed = false;
        s.lost = false;
        s.runs.clear();  // capacity kept
    }
    return s;
}

void BaselineBook::carried(uint32_t seq, uint32_t tick, int instance, uint32_t generation, int first, int count) {
    if (instance < 0 || instance > 0xFFFF || first < 0 || count < 1 || first + count > MAX_BONES) return;
    slot(seq, tick).runs.push_back({uint16_t(instance), uint8_t(first), uint8_t(count), generation});
}

void BaselineBook::carried_morphs(uint32_t seq, uint32_t tick, int instance, uint32_t generation) {
    if (instance < 0 || instance > 0xFFFF) return;
    slot(seq, tick).runs.push_back({uint16_t(instance), 0, 0, generation});
}

void BaselineBook::sent_at(uint32_t seq, uint32_t send_us) {
    Sent& s = sent_[seq % kSentRing];
    if (!s.valid || s.seq != seq) return;
    s.send_us = send_us;
    s.timed = true;
}

void BaselineBook::on_ack(uint32_t ack, uint32_t bits, std::vector<LostRun>* lost, uint32_t now_us, uint32_t loss_delay_us) {
    auto take = [&](uint32_t seq) {
        Sent& s = sent_[seq % kSentRing];
        if (!s.valid || s.seq != seq) return;
        if (!s.lost) first_loss_ *= 1.0 - kFirstLossWeight;  // its first outcome (a lost one counted when reported)
        mark(s);
        s.valid = false;  // once
    };
    take(ack);
    for (uint32_t i = 0; i < 32; ++i)
        if (bits & (1u << i)) take(ack - 1 - i);
    if (!lost) return;
    for (uint32_t i = 0; i < 32; ++i) {  // datagram ack - 1 - i
        if (bits & (1u << i)) continue;
        const uint32_t seq = ack - 1 - i;
        Sent& s = sent_[seq % kSentRing];
        if (!s.valid || s.seq != seq || s.lost) continue;
        const bool by_count = i + 1 >= kLossReorder;
        const bool by_time = loss_delay_us > 0 && s.timed && int32_t(now_us - s.send_us) >= int32_t(loss_delay_us);
        if (!by_count && !by_time) continue;
        s.lost = true;
        first_loss_ = (1.0 - kFirstLossWeight) * first_loss_ + kFirstLossWeight;
        for (const Run& r : s.runs) lost->push_back({s.seq, s.tick, r.generation, int(r.instance), int(r.first), int(r.count), r.count == 0});
    }
}

void BaselineBook::mark(const Sent& s) {
    for (const Run& r : s.runs) {
        if (r.count == 0) continue;  // a morph block: no baseline
        if (acks_.size() <= r.instance) acks_.resize(size_t(r.instance) + 1);
        Acks& a = acks_[r.instance];
        if (!a.any || newer(r.generation, a.generation)) {  // a new occupant of the id
            a.generation = r.generation;
            a.any = true;
            a.newest = a.first = s.tick;
            a.ticks = 0;
            std::fill(a.mask.begin(), a.mask.end(), 0);
        } else if (r.generation != a.generation) {
            continue;  // a late datagram of an earlier occupant
        }
        if (newer(s.tick, a.newest)) {
            const uint32_t shift = s.tick - a.newest;
            for (uint16_t& m : a.mask) m = shift >= 16 ? 0 : uint16_t(m << shift);
            a.ticks = shift >= 16 ? 0 : uint16_t(a.ticks << shift);
            a.newest = s.tick;
        }
        if (newer(a.first, s.tick)) a.first = s.tick;
        const uint32_t d = a.newest - s.tick;
        if (d >= 16) continue;
        a.ticks |= uint16_t(1u << d);
        if (a.mask.size() < size_t(r.first) + r.count) a.mask.resize(size_t(r.first) + r.count, 0);
        for (int b = r.first; b < r.first + r.count; ++b) a.mask[size_t(b)] |= uint16_t(1u << d);
    }
}

bool BaselineBook::view(int instance, uint32_t generation, View& v) const {
    if (instance < 0 || size_t(instance) >= acks_.size()) return false;
    const Acks& a = acks_[size_t(instance)];
    if (!a.any || a.generation != generation) return false;
    v.newest = a.newest;
    v.first = a.first;
    v.ticks = a.ticks;
    v.mask = a.mask;
    return true;
}

bool BaselineBook::acked(int instance, uint32_t generation, int b, uint32_t t) const {
    View v;
    return b >= 0 && view(instance, generation, v) && v.acked(b, t);
}

bool BaselineBook::acked_any(int instance, uint32_t generation, uint32_t t) const {
    View v;
    return view(instance, generation, v) && v.acked_any(t);
}

bool BaselineBook::newest(int instance, uint32_t generation, uint32_t& tick) const {
    View v;
    if (!view(instance, generation, v) || int32_t(v.newest - v.first) < int32_t(kGraceTicks)) return false;
    tick = v.newest;
    return true;
}

bool BaselineBook::newest_of(int instance, uint32_t generation, int b, uint32_t& tick) const {
    View v;
    return b >= 0 && view(instance, generation, v) && v.newest_of(b, tick);
}

void BaselineBook::clear() {
    for (Sent& s : sent_) s.valid = false;
    first_loss_ = 0;
    acks_.clear();
}

void RecordPlan::begin(const EncodedFrame& frame) {
    entry_of_.assign(frame.instances.size(), -1);
    entries_.clear();
    bones_ = 0;
    prefix_.clear();
}

void RecordPlan::plan(const EncodedFrame& frame, int i, const BaselineBook& book) {
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] >= 0) return;
    const EncodedInstance& e = frame.instances[size_t(i)];
    BaselineBook::View v;
    // Nothing acknowledged past the grace: no entry, every record standalone
    // (bits() falls back to the frame's).
    if (!e.valid || !book.view(i, e.generation, v) || int32_t(v.newest - v.first) < int32_t(BaselineBook::kGraceTicks)) return;
    const int B = e.bone_count;
    Entry en;
    en.at = bones_;
    bones_ += size_t(B);
    if (flags_.size() < bones_) {  // grown, never shrunk: the per-bone arrays are written before they are read
        flags_.resize(bones_);
        own_base_.resize(bones_);
        own_len_.resize(bones_);
    }
    uint8_t* flags = flags_.data() + en.at;
    std::fill(flags, flags + B, uint8_t(RecordPrefix::Standalone));
    chunk_baseline(frame, i, v, en);
    if (en.base == 0) std::fill(flags, flags + B, uint8_t(RecordPrefix::Standalone));
    else own_baselines(frame, i, v, en);
    // Prefix sums of the planned bits: bone b at [prefix[b], prefix[b + 1]).
    const size_t pat = prefix_.size();
    prefix_.resize(pat + size_t(B) + 1);
    uint32_t* prefix = prefix_.data() + pat;
    prefix[0] = 0;
    for (int b = 0; b < B; ++b) {
        const size_t abs_bits = frame.record_bits(i, b, b + 1);
        size_t bits = abs_bits;
        if (en.base) {
            switch (flags[b]) {
                case RecordPrefix::Chunk: bits = kChunkPrefixBits + en.records->record_bits(b); break;
                case RecordPrefix::Own: bits = kOwnPrefixBits + own_len_[en.at + size_t(b)]; break;
                default: bits = kStandalonePrefixBits + abs_bits; break;
            }
        }
        prefix[b + 1] = prefix[b] + uint32_t(bits);
    }
    en.prefix = pat;
    if (e.flags & CHUNK_ROOT) root_baseline(frame, i, v, en);
    entry_of_[size_t(i)] = int32_t(entries_.size());
    entries_.push_back(en);
}

// The chunk's baseline: the newest acknowledged tick t0. Every bone
// acknowledged at t0 (bit 0 of its mask: t0 is the newest) goes from it
// (flags: Chunk); linear when each of them is acknowledged at t0 - age too.
// en.base stays 0 when t0 is too old, no bone was acknowledged there, or
// the frame cannot predict from it.
void RecordPlan::chunk_baseline(const EncodedFrame& frame, int i, const BaselineBook::View& v, Entry& en) {
    const uint32_t t0 = v.newest, age = frame.tick - t0;
    if (age < 1 || age > kMaxBaseAge) return;
    uint8_t* flags = flags_.data() + en.at;
    const size_t acked_bones = std::min(size_t(frame.instances[size_t(i)].bone_count), v.mask.size());
    const int d2 = 2 * age < uint32_t(kBaselineRing) ? v.bit(t0 - age) : -1;
    const int shift = std::max(d2, 0);
    uint32_t all_at_d2 = 1, covered = 0;
    static_assert(RecordPrefix::Standalone == 0 && RecordPrefix::Chunk == 1);
    for (size_t b = 0; b < acked_bones; ++b) {  // without branches (the bits are unpredictable)
        const uint32_t m = v.mask[b], c = m & 1;
        flags[b] = uint8_t(c);
        covered += c;
        all_at_d2 &= (m >> shift) | (c ^ 1);
    }
    const bool linear = d2 >= 0 && (all_at_d2 & 1);
    if (covered == 0) return;
    en.base = uint8_t(age | (linear ? kBaseLinear : 0));
    en.records = frame.predicted(i, en.base);
    if (!en.records || !en.records->usable) en.base = 0, en.records = nullptr;
}

// Bones refreshed at other ticks: from their own newest acknowledged tick,
// when shorter than standalone (only in a chunk with a baseline). First
// each candidate bone's own baseline (the shared table's entries fetched
// meanwhile), then their lengths.
void RecordPlan::own_baselines(const EncodedFrame& frame, int i, const BaselineBook::View& v, const Entry& en) {
    uint8_t* flags = flags_.data() + en.at;
    const size_t acked_bones = std::min(size_t(frame.instances[size_t(i)].bone_count), v.mask.size());
    own_try_.clear();
    for (size_t b = 0; b < acked_bones; ++b) {
        if (flags[b] != RecordPrefix::Standalone) continue;
        uint32_t tb = 0;
        if (!v.newest_of(int(b), tb)) continue;
        const uint32_t age = frame.tick - tb;
        if (age < 1 || age > kMaxBaseAge) continue;
        // Linear when the tick as far before tb is acknowledged and in the ring too.
        const bool linear = 2 * age < uint32_t(kBaselineRing) && v.acked(int(b), tb - age) && frame.ints_at(i, tb - age);
        const uint8_t own = uint8_t(age | (linear ? kBaseLinear : 0));
        frame.own_prefetch(i, int(b), own);
        own_try_.emplace_back(uint8_t(b), own);
    }
    for (const auto& [b, own] : own_try_) {
        const size_t n = frame.own_bits(i, int(b), own);  // shared between clients (EncodedFrame::own_bits)
        if (n == SIZE_MAX || n + kOwnPrefixBits >= frame.record_bits(i, int(b), int(b) + 1) + kStandalonePrefixBits) continue;
        flags[b] = RecordPrefix::Own;
        own_base_[en.at + b] = own;
        own_len_[en.at + b] = uint32_t(n);
    }
}

// The root block, predicted from the root at t0 (and, linear, at t0 -
// age): its baseline, and its length (shared between clients); written
// when it goes (root()).
void RecordPlan::root_baseline(const EncodedFrame& frame, int i, const BaselineBook::View& v, Entry& en) const {
    const uint32_t t0 = v.newest, age = frame.tick - t0;
    uint8_t base = 0;
    if (age >= 1 && age <= kMaxBaseAge && frame.root_at(i, t0)) {
        base = uint8_t(age);
        if (2 * age < uint32_t(kBaselineRing) && v.acked_any(t0 - age) && frame.root_at(i, t0 - age)) base |= kBaseLinear;
    }
    en.root_base = base;
    en.root_len = uint32_t(base ? frame.root_block_bytes(i, base) : kRootAbsoluteBytes);
}

uint8_t RecordPlan::base(int i) const {
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return 0;
    return entries_[size_t(entry_of_[size_t(i)])].base;
}

size_t RecordPlan::bits(const EncodedFrame& frame, int i, int from, int to) const {
    if (to <= from) return 0;
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return frame.record_bits(i, from, to);
    const Entry& en = entries_[size_t(entry_of_[size_t(i)])];
    return size_t(prefix_[en.prefix + size_t(to)] - prefix_[en.prefix + size_t(from)]);
}

RecordPrefix RecordPlan::prefix(int i, int b) const {
    RecordPrefix p;
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return p;
    const Entry& en = entries_[size_t(entry_of_[size_t(i)])];
    if (en.base == 0) return p;
    p.kind = RecordPrefix::Kind(flags_[en.at + size_t(b)]);
    if (p.kind == RecordPrefix::Own) p.base = own_base_[en.at + size_t(b)];
    return p;
}

size_t RecordPlan::write_own(const EncodedFrame& frame, int i, int b, BitWriter& w) const {
    const Entry& en = entries_[size_t(entry_of_[size_t(i)])];
    RecordInts pred;
    if (!frame.own_prediction(i, b, own_base_[en.at + size_t(b)], pred)) return 0;  // (planned: it was predictable)
    const RecordInts* now = frame.ints.data() + size_t(i) * frame.ring_bones;
    return write_predicted(now[b], pred, (frame.instances[size_t(i)].flags & CHUNK_SCALED) != 0, w);
}

std::span<const uint8_t> RecordPlan::root(const EncodedFrame& frame, int i, std::vector<uint8_t>& out) const {
    out.clear();
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return {};
    const Entry& en = entries_[size_t(entry_of_[size_t(i)])];
    if (en.root_len == 0) return {};
    frame.write_root_block(i, en.root_base, out);
    return out;
}

size_t RecordPlan::root_bytes(const EncodedFrame& frame, int i) const {
    if (!(frame.instances[size_t(i)].flags & CHUNK_ROOT)) return 0;
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return kRootAbsoluteBytes;
    const size_t n = entries_[size_t(entry_of_[size_t(i)])].root_len;
    return n ? n : kRootAbsoluteBytes;
}

const PredictedRecords* RecordPlan::records(int i) const {
    if (i < 0 || size_t(i) >= entry_of_.size() || entry_of_[size_t(i)] < 0) return nullptr;
    return entries_[size_t(entry_of_[size_t(i)])].records;
}

}  // namespace progskin::net
