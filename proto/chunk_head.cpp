// chunk_head.cpp — see chunk_head.h.
#include "chunk_head.h"

#include <algorithm>
#include <cstdint>

namespace progskin::net {

void HeadCodes::clear() {
    sorted_.clear();
    total_.fill(0);
    fields_ = 0;
}

// Where instance is, or would go, in the heads sorted by instance.
static std::vector<HeadCodes::Fields>::const_iterator place_of(const std::vector<HeadCodes::Fields>& sorted, uint16_t instance) {
    return std::lower_bound(sorted.begin(), sorted.end(), instance,
                            [](const HeadCodes::Fields& x, uint16_t y) { return x.instance < y; });
}

bool HeadCodes::contains(uint16_t instance) const {
    const auto at = place_of(sorted_, instance);
    return at != sorted_.end() && at->instance == instance;
}

// Bits of a head's show, epoch and flags after a head with prev's.
static size_t field_bits(const HeadCodes::Fields& h, const HeadCodes::Fields& prev) {
    return 3 + (h.show != prev.show ? 8u : 0u) + (h.epoch != prev.epoch ? 8u : 0u) + (h.flags != prev.flags ? 8u : 0u);
}

// The change of each order's total (f(k, bits)) and of the fields' bits
// (returned) when h joins at `at` (place_of): its own codes, and its
// successor's now after it.
template <class F>
static size_t with_added(const std::vector<HeadCodes::Fields>& sorted, std::vector<HeadCodes::Fields>::const_iterator at,
                         const HeadCodes::Fields& h, F&& f) {
    const HeadCodes::Fields none{};  // before the first chunk: show, epoch and flags 0
    const HeadCodes::Fields& prev = at == sorted.begin() ? none : *(at - 1);
    const int prev_instance = at == sorted.begin() ? -1 : int(prev.instance);
    const bool has_next = at != sorted.end();
    for (int k = 0; k < kInstanceOrders; ++k) {
        size_t d = instance_code_bits(uint32_t(int(h.instance) - prev_instance - 1), k);
        if (has_next)
            d = d + instance_code_bits(uint32_t(int(at->instance) - int(h.instance) - 1), k) -
                instance_code_bits(uint32_t(int(at->instance) - prev_instance - 1), k);
        f(k, d);
    }
    size_t fields = field_bits(h, prev);
    if (has_next) fields = fields + field_bits(*at, h) - field_bits(*at, prev);
    return fields;
}

static HeadCodes::Fields fields_of(const ChunkHead& h) { return {h.instance, h.show, h.epoch, h.flags}; }

void HeadCodes::add(const ChunkHead& h) {
    const auto at = place_of(sorted_, h.instance);
    fields_ += with_added(sorted_, at, fields_of(h), [&](int k, size_t d) { total_[size_t(k)] += d; });
    sorted_.insert(at, fields_of(h));
}

size_t HeadCodes::bits_with(const ChunkHead& h) const {
    size_t best = SIZE_MAX;
    const size_t fields = with_added(sorted_, place_of(sorted_, h.instance), fields_of(h),
                                     [&](int k, size_t d) { best = std::min(best, total_[size_t(k)] + d); });
    return eg0_bits(uint32_t(sorted_.size())) + 4 + best + fields_ + fields;
}

int HeadCodes::best_order() const {
    return int(std::min_element(total_.begin(), total_.end()) - total_.begin());
}

size_t HeadCodes::bits() const {
    if (sorted_.empty()) return 0;
    return eg0_bits(uint32_t(sorted_.size() - 1)) + 4 + total_[size_t(best_order())] + fields_;
}

namespace {

// Calls f(gap, length) for each run of carried bones (gap as coded: bones
// skipped, minus one after the first run); returns the runs.
template <class F>
int for_each_run(const ChunkHead& h, F&& f) {
    int runs = 0, end = 0;  // end: where the previous run ended
    for_each_carried_run(h, [&](int j, int e) {
        f(uint32_t(j - end - (runs ? 1 : 0)), uint32_t(e - j - 1));
        ++runs;
        end = e;
    });
    return runs;
}

size_t run_bits(const ChunkHead& h) {
    size_t n = 0;
    const int runs = for_each_run(h, [&](uint32_t gap, uint32_t len) { n += eg0_bits(gap) + eg0_bits(len); });
    return n + eg0_bits(uint32_t(runs));
}

}  // namespace

size_t mask_bits(const ChunkHead& h) {
    const size_t bitmap = size_t(std::max(0, int(h.show) - int(h.first)));
    return std::min(bitmap, run_bits(h));
}

// One of show, epoch, flags: 0 when the same as the previous chunk's, else 1 and its 8 bits.
static void put_field(BitWriter& w, uint8_t v, uint8_t prev) {
    if (v == prev) w.put(0, 1);
    else w.put(1 | uint64_t(v) << 1, 9);
}

static void write_head(BitWriter& w, const ChunkHead& h, const ChunkHead& before, int prev, int k) {
    const uint32_t d = uint32_t(int(h.instance) - prev - 1);
    if (d < (uint32_t(1) << k)) w.put(uint64_t(d) << 1, 1 + k);
    else w.put(1 | (uint64_t(h.instance) << 1), 17);
    if (h.first) w.put(1 | (uint64_t(h.first) << 1), 9);
    else w.put(0, 1);
    put_field(w, h.show, before.show);
    put_field(w, h.epoch, before.epoch);
    put_field(w, h.flags, before.flags);
    const int bits = int(h.show) - int(h.first);
    if (size_t(bits) <= run_bits(h)) {
        w.put(0, 1);
        for (int j = 0; j < bits; j += 56) {
            const int n = std::min(56, bits - j);
            uint64_t v = 0;
            for (int i = 0; i < n; ++i) v |= uint64_t(h.carries(j + i)) << i;
            w.put(v, n);
        }
    } else {
        w.put(1, 1);
        std::array<uint32_t, 2 * 128> codes;  // at most 128 runs of 255 bones
        size_t c = 0;
        const int runs = for_each_run(h, [&](uint32_t gap, uint32_t len) {
            codes[c++] = gap;
            codes[c++] = len;
        });
        w.put_eg(uint32_t(runs), 0);
        for (size_t i = 0; i < c; ++i) w.put_eg(codes[i], 0);
    }
}

bool write_frame_payload(std::span<const ChunkOut> chunks, int k, const uint8_t* records, const uint8_t* blocks,
                         std::vector<uint8_t>& out) {
    if (chunks.empty()) return true;
    if (chunks.size() > kMaxChunks || k < 0 || k >= kInstanceOrders) return false;
    for (size_t i = 0; i < chunks.size(); ++i) {
        const ChunkHead& h = chunks[i].head;
        if ((i && chunks[i - 1].head.instance >= h.instance) || h.first >= h.show) return false;
    }
    BitWriter w(out);
    w.put_eg(uint32_t(chunks.size() - 1), 0);
    w.put(uint64_t(k), 4);
    int prev = -1;
    ChunkHead before;  // show, epoch and flags 0
    for (const ChunkOut& c : chunks) {
        write_head(w, c.head, before, prev, k);
        prev = c.head.instance;
        before = c.head;
        copy_bits(records, c.rec_from, c.rec_bits, w);
    }
    for (const ChunkOut& c : chunks) out.insert(out.end(), blocks + c.block_from, blocks + c.block_from + c.block_bytes);
    return true;
}

static bool get_field(BitReader& in, uint8_t prev, uint8_t& v) {
    uint64_t x = 0;
    if (!in.get(1, x)) return false;
    if (x == 0) {
        v = prev;
        return true;
    }
    if (!in.get(8, x)) return false;
    v = uint8_t(x);
    return true;
}

bool read_head(BitReader& in, const ChunkHead* before, int k, ChunkHead& h) {
    // (before may be h itself: what is needed of it is read first)
    const int prev = before ? int(before->instance) : -1;
    const uint8_t last_show = before ? before->show : 0, last_epoch = before ? before->epoch : 0,
                  last_flags = before ? before->flags : 0;
    uint8_t show = 0, epoch = 0, flags = 0;
    h = ChunkHead{};
    uint64_t v = 0;
    if (!in.get(1, v)) return false;
    if (v == 0) {
        uint64_t d = 0;
        if (!in.get(k, d) || int64_t(d) + prev + 1 > 0xFFFF) return false;
        h.instance = uint16_t(int64_t(d) + prev + 1);
    } else {
        if (!in.get(16, v) || int(v) <= prev) return false;
        h.instance = uint16_t(v);
    }
    if (!in.get(1, v)) return false;
    if (v) {
        if (!in.get(8, v) || v == 0) return false;
        h.first = uint8_t(v);
    }
    if (!get_field(in, last_show, show) || !get_field(in, last_epoch, epoch) || !get_field(in, last_flags, flags)) return false;
    h.show = show, h.epoch = epoch, h.flags = flags;
    if (h.first >= h.show) return false;
    const int bits = int(h.show) - int(h.first);
    if (!in.get(1, v)) return false;
    if (v == 0) {
        for (int j = 0; j < bits; j += 56) {
            const int n = std::min(56, bits - j);
            if (!in.get(n, v)) return false;
            for (int i = 0; i < n; ++i)
                if ((v >> i) & 1) h.carry(j + i);
        }
        return true;
    }
    uint64_t runs = 0;
    if (!in.get_eg(0, runs) || runs > uint64_t(bits)) return false;
    int end = 0;
    for (uint64_t r = 0; r < runs; ++r) {
        uint64_t gap = 0, len = 0;
        if (!in.get_eg(0, gap) || !in.get_eg(0, len)) return false;
        const uint64_t from = uint64_t(end) + gap + (r ? 1 : 0);
        if (from + len + 1 > uint64_t(bits)) return false;
        for (uint64_t j = from; j <= from + len; ++j) h.carry(int(j));
        end = int(from + len + 1);
    }
    return true;
}

}  // namespace progskin::net
