// root_block.cpp — see root_block.h.
#include "root_block.h"

#include <algorithm>
#include <bit>

#include "bone_record.h"  // BitWriter, BitReader, kDeltaOrders, kMaxPrefix

namespace progskin::net {
namespace {

struct RootInts {
    int64_t pos[3] = {0, 0, 0};
    int index = 0;
    int64_t comp[3] = {0, 0, 0};
    uint64_t time = 0;
};

RootInts unpack(const uint8_t* in) {
    RootInts r;
    for (int a = 0; a < 3; ++a) {
        uint32_t u = 0;
        for (int i = 0; i < 4; ++i) u |= uint32_t(in[4 * a + i]) << (8 * i);
        r.pos[a] = int32_t(u);
    }
    uint64_t rot = 0;
    for (int i = 0; i < 6; ++i) rot |= uint64_t(in[12 + i]) << (8 * i);
    r.index = int(rot & 3);
    for (int c = 0; c < 3; ++c) r.comp[c] = int64_t((rot >> (2 + 15 * c)) & 0x7FFF);
    for (int i = 0; i < 8; ++i) r.time |= uint64_t(in[18 + i]) << (8 * i);
    return r;
}

// False when a value does not fit the absolute block.
bool pack(const RootInts& r, uint8_t* out) {
    for (int a = 0; a < 3; ++a)
        if (r.pos[a] < INT32_MIN || r.pos[a] > INT32_MAX) return false;
    for (int c = 0; c < 3; ++c)
        if (r.comp[c] < 0 || r.comp[c] > 0x7FFF) return false;
    if (r.index < 0 || r.index > 3) return false;
    for (int a = 0; a < 3; ++a)
        for (int i = 0; i < 4; ++i) out[4 * a + i] = uint8_t(uint32_t(int32_t(r.pos[a])) >> (8 * i));
    uint64_t rot = uint64_t(r.index);
    for (int c = 0; c < 3; ++c) rot |= uint64_t(r.comp[c]) << (2 + 15 * c);
    for (int i = 0; i < 6; ++i) out[12 + i] = uint8_t(rot >> (8 * i));
    for (int i = 0; i < 8; ++i) out[18 + i] = uint8_t(r.time >> (8 * i));
    return true;
}

RootInts predict(const RootInts& b1, const RootInts* b2) {
    RootInts p = b1;
    if (!b2) return p;
    for (int a = 0; a < 3; ++a) p.pos[a] = 2 * b1.pos[a] - b2->pos[a];
    p.time = b1.time + (b1.time - b2->time);
    if (b2->index == b1.index)
        for (int c = 0; c < 3; ++c) p.comp[c] = 2 * b1.comp[c] - b2->comp[c];
    return p;
}

uint64_t zigzag64(int64_t v) { return (uint64_t(v) << 1) ^ uint64_t(v >> 63); }
int64_t unzigzag64(uint64_t u) { return int64_t(u >> 1) ^ -int64_t(u & 1); }
int eg_bits(uint64_t u, int k) { return 2 * int(std::bit_width(u + (uint64_t(1) << k))) - 1 - k; }
constexpr uint64_t kMaxResidual = 0xFFFFFFFFull;  // zigzagged residuals BitWriter::put_eg takes

// The order of `orders` coding n values in the fewest bits.
int best_order(const uint64_t* u, int n, const int (&orders)[4], int& bits) {
    int best = 0;
    bits = 1 << 30;
    for (int s = 0; s < 4; ++s) {
        int b = 0;
        for (int i = 0; i < n; ++i) b += eg_bits(u[i], orders[s]);
        if (b < bits) bits = b, best = s;
    }
    return best;
}

void write_absolute(const RootInts& r, BitWriter& w) {
    w.put(0, 5);
    for (int a = 0; a < 3; ++a) w.put(uint32_t(int32_t(r.pos[a])), 32);
    w.put(uint64_t(r.index), 2);
    for (int c = 0; c < 3; ++c) w.put(uint64_t(r.comp[c]), 15);
    w.put(r.time & 0xFFFFFFFFu, 32);
    w.put(r.time >> 32, 32);
}

// Reads the fields after the 5-bit header; pred: nullptr for absolute.
bool read_fields(BitReader& in, const RootInts* pred, RootInts& out) {
    uint64_t v = 0;
    if (!pred) {
        for (int a = 0; a < 3; ++a) {
            if (!in.get(32, v)) return false;
            out.pos[a] = int32_t(uint32_t(v));
        }
        if (!in.get(2, v)) return false;
        out.index = int(v);
        for (int c = 0; c < 3; ++c) {
            if (!in.get(15, v)) return false;
            out.comp[c] = int64_t(v);
        }
        uint64_t lo = 0, hi = 0;
        if (!in.get(32, lo) || !in.get(32, hi)) return false;
        out.time = lo | (hi << 32);
        return true;
    }
    if (!in.get(2, v)) return false;
    const int kp = kRootPosOrders[v];
    for (int a = 0; a < 3; ++a) {
        if (!in.get_eg(kp, v)) return false;
        out.pos[a] = pred->pos[a] + unzigzag64(v);
    }
    uint64_t same = 0;
    if (!in.get(1, same)) return false;
    if (same) {
        if (!in.get(2, v)) return false;
        const int kr = kDeltaOrders[v];
        out.index = pred->index;
        for (int c = 0; c < 3; ++c) {
            if (!in.get_eg(kr, v)) return false;
            out.comp[c] = pred->comp[c] + unzigzag64(v);
        }
    } else {
        if (!in.get(2, v)) return false;
        out.index = int(v);
        for (int c = 0; c < 3; ++c) {
            if (!in.get(15, v)) return false;
            out.comp[c] = int64_t(v);
        }
    }
    if (!in.get(2, v)) return false;
    const int kt = kRootTimeOrders[v];
    if (!in.get_eg(kt, v)) return false;
    out.time = pred->time + uint64_t(unzigzag64(v));
    return true;
}

// Reads the header; false for a linear flag without an age or bits 5+ of a malformed header.
bool read_header(BitReader& in, uint32_t& age, bool& linear) {
    uint64_t v = 0;
    if (!in.get(5, v)) return false;
    age = uint32_t(v & 15);
    linear = (v & 16) != 0;
    return age != 0 || !linear;
}

// The padding up to the byte's end is zero; returns the block's bytes or 0.
size_t finish(BitReader& in, const uint8_t* data) {
    const size_t end = (in.at() + 7) / 8;
    const int pad = int(end * 8 - in.at());
    if (pad > 0 && (data[end - 1] >> (8 - pad)) != 0) return 0;
    return end;
}

}  // namespace

size_t write_root(const uint8_t* now, uint8_t base, const uint8_t* b1, const uint8_t* b2, std::vector<uint8_t>& out) {
    const size_t start = out.size();
    BitWriter w(out);
    const RootInts n = unpack(now);
    const uint32_t age = base & kBaseAgeMask;
    const bool linear = (base & kBaseLinear) != 0;
    if (age >= 1 && age <= 15 && b1 && (!linear || b2)) {
        const RootInts r1 = unpack(b1), r2 = linear ? unpack(b2) : RootInts{};
        const RootInts p = predict(r1, linear ? &r2 : nullptr);
        uint64_t up[3], ur[3], ut = 0;
        bool fits = true;
        for (int a = 0; a < 3; ++a) {
            up[a] = zigzag64(n.pos[a] - p.pos[a]);
            ur[a] = zigzag64(n.comp[a] - p.comp[a]);
            fits = fits && up[a] <= kMaxResidual;
        }
        ut = zigzag64(int64_t(n.time - p.time));
        fits = fits && ut <= kMaxResidual;
        const bool same = n.index == p.index;
        int bp = 0, br = 0, bt = 0;
        const int sp = best_order(up, 3, kRootPosOrders, bp);
        const int sr = same ? best_order(ur, 3, kDeltaOrders, br) : 0;
        const int st = best_order(&ut, 1, kRootTimeOrders, bt);
        const int bits = 5 + 2 + bp + 1 + (same ? 2 + br : 47) + 2 + bt;
        if (fits && (bits + 7) / 8 < int(kRootAbsoluteBytes)) {
            w.put(age | (linear ? 16u : 0u), 5);
            w.put(uint64_t(sp), 2);
            for (int a = 0; a < 3; ++a) w.put_eg(uint32_t(up[a]), kRootPosOrders[sp]);
            w.put(same ? 1 : 0, 1);
            if (same) {
                w.put(uint64_t(sr), 2);
                for (int c = 0; c < 3; ++c) w.put_eg(uint32_t(ur[c]), kDeltaOrders[sr]);
            } else {
                w.put(uint64_t(n.index), 2);
                for (int c = 0; c < 3; ++c) w.put(uint64_t(n.comp[c]), 15);
            }
            w.put(uint64_t(st), 2);
            w.put_eg(uint32_t(ut), kRootTimeOrders[st]);
            return out.size() - start;  // the writer's padding bits are zero
        }
    }
    write_absolute(n, w);
    return out.size() - start;
}

uint8_t root_base(const uint8_t* block) {
    return uint8_t((block[0] & 15) | ((block[0] & 16) ? kBaseLinear : 0));
}

size_t root_size(const uint8_t* data, size_t avail) {
    BitReader in(data, std::min(avail, kRootMaxBytes));
    uint32_t age = 0;
    bool linear = false;
    if (!read_header(in, age, linear)) return 0;
    RootInts zero, out;
    if (!read_fields(in, age ? &zero : nullptr, out)) return 0;
    return finish(in, data);
}

bool read_root(const uint8_t* block, size_t size, const uint8_t* b1, const uint8_t* b2, uint8_t* out) {
    BitReader in(block, size);
    uint32_t age = 0;
    bool linear = false;
    if (!read_header(in, age, linear)) return false;
    RootInts r;
    if (age == 0) {
        if (!read_fields(in, nullptr, r)) return false;
    } else {
        if (!b1 || (linear && !b2)) return false;
        const RootInts r1 = unpack(b1), r2 = linear ? unpack(b2) : RootInts{};
        const RootInts p = predict(r1, linear ? &r2 : nullptr);
        if (!read_fields(in, &p, r)) return false;
    }
    if (finish(in, block) != size) return false;
    return pack(r, out);
}

const uint8_t* RootRing::at(uint32_t tick) const {
    const Entry& e = ring_[tick % ring_.size()];
    return e.valid && e.tick == tick ? e.root.data() : nullptr;
}

void RootRing::put(uint32_t tick, const uint8_t* root) {
    Entry& e = ring_[tick % ring_.size()];
    if (e.valid && int32_t(e.tick - tick) > 0) return;  // a newer tick holds the place
    e.tick = tick;
    e.valid = true;
    std::copy(root, root + ROOT_BYTES, e.root.begin());
}

bool RootRing::resolve(uint32_t tick, const uint8_t* block, size_t size, uint8_t* out, bool* missing) const {
    if (missing) *missing = false;
    if (size == 0) return false;
    const uint8_t base = root_base(block);
    const uint32_t age = base & kBaseAgeMask;
    const uint8_t* b1 = age ? at(tick - age) : nullptr;
    const uint8_t* b2 = age && (base & kBaseLinear) ? at(tick - 2 * age) : nullptr;
    if (age && (!b1 || ((base & kBaseLinear) && !b2))) {
        if (missing) *missing = true;
        return false;
    }
    return read_root(block, size, b1, b2, out);
}

void RootRing::clear() {
    for (Entry& e : ring_) e.valid = false;
}

}  // namespace progskin::net
