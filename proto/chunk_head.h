// chunk_head.h — the chunk heads of a Frame's payload (protocol version 12,
// docs/protocol.md "Frame"): which instance, which bones, epoch and flags,
// coded in bits in front of each chunk's records. Written by the server's
// packer (server/datagram_packer.cpp: write_frame_payload) and read by
// proto/frame_reader.h.
//
// A payload with chunks is one bit stream (least significant bit first) and
// then the chunks' byte blocks:
//   EG0(n - 1)                    n chunks, n >= 1 (an empty payload has none)
//   4 bits k                      the order of the instance codes below
//   n times, instances strictly increasing:
//     instance: 0 and k bits of d = instance - previous - 1 (previous: -1
//               before the first chunk), or 1 and 16 bits of the instance
//     first:    0 (first = 0), or 1 and 8 bits (1..254)
//     show, epoch, flags (Chunk.flags), in that order, each: 0 (the same
//               as the previous chunk's; before the first chunk all three
//               are 0), or 1 and 8 bits (version 12; first < show)
//     mask:     0 and show - first bits (bit j: bone first + j carried), or
//               1, EG0(r) runs, and per run EG0(gap) (bones skipped: before
//               the first run from `first`; gap - 1 after the others, so runs
//               never touch) and EG0(length - 1); runs end at or before show
//     records:  one per carried bone, in increasing bone order (bone_record.h)
//   zero bits to a whole byte
//   per chunk, in the same order: its sample byte (Frame.sampled), root
//   block (flags & CHUNK_ROOT), morph block (flags & CHUNK_MORPH).
// Cost: O(bones) per head to code or read; no allocation.
#pragma once
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "bone_record.h"
#include "datagram_generated.h"

namespace progskin::net {

struct ChunkHead {
    uint16_t instance = 0;
    uint8_t first = 0, show = 0, epoch = 0, flags = 0;
    std::array<uint64_t, 4> mask{};  // bit j: bone first + j carried (j < show - first)

    bool carries(int j) const { return (mask[size_t(j) / 64] >> (j % 64)) & 1; }
    void carry(int j) { mask[size_t(j) / 64] |= uint64_t(1) << (j % 64); }
    int carried() const {
        int n = 0;
        for (uint64_t w : mask) n += std::popcount(w);
        return n;
    }
    wire::Chunk chunk() const { return wire::Chunk(instance, first, show, epoch, flags); }
};

// Calls f(j, e) for each run [j, e) of consecutive carried bones (relative
// to first), in increasing order. O(show - first).
template <class F>
void for_each_carried_run(const ChunkHead& h, F&& f) {
    const int bits = int(h.show) - int(h.first);
    for (int j = 0; j < bits;) {
        if (!h.carries(j)) {
            ++j;
            continue;
        }
        int e = j + 1;
        while (e < bits && h.carries(e)) ++e;
        f(j, e);
        j = e;
    }
}

inline constexpr int kInstanceOrders = 16;  // k = 0..15
inline constexpr size_t kMaxChunks = 1024;  // a reader refuses more heads in one payload

// Bits of the instance code of d = instance - previous - 1 at order k.
constexpr size_t instance_code_bits(uint32_t d, int k) { return d < (uint32_t(1) << k) ? size_t(1 + k) : 17; }
// Bits of EG0(u).
constexpr size_t eg0_bits(uint32_t u) { return size_t(2 * (std::bit_width(uint64_t(u) + 1) - 1) + 1); }

// Bits of a head but its instance code, its show, epoch and flags
// (HeadCodes counts those) and its mask: first and the mask's mode bit.
constexpr size_t head_fixed_bits(int first) { return (first ? 9u : 1u) + 1; }

// The heads of one payload, kept in increasing order of instance as they
// are added (in any order), with the exact bits of their instance codes at
// the best order (what a writer picks) and of their fields, each after the
// head before it. O(n) per add (n <= kMaxChunks), no allocation after
// warm-up.
class HeadCodes {
public:
    void clear();
    bool contains(uint16_t instance) const;
    void add(const ChunkHead& h);                  // instance not already contained
    size_t bits_with(const ChunkHead& h) const;    // bits() once h (instance not contained) is added
    size_t size() const { return sorted_.size(); }
    int best_order() const;       // the k of the fewest bits
    // The instance codes at best_order() and the fields, plus EG0(n - 1) and
    // the 4 bits of k (not first, the mode bits nor the masks).
    size_t bits() const;
    // What a head's count depends on (its show, epoch and flags take 1 bit
    // each when they are the head before's, else 9).
    struct Fields {
        uint16_t instance = 0;
        uint8_t show = 0, epoch = 0, flags = 0;
    };
private:
    std::vector<Fields> sorted_;
    std::array<size_t, kInstanceOrders> total_{};  // the instance codes' bits at each order
    size_t fields_ = 0;                            // the fields' bits
};

// Bits of a head's mask as written: the shorter of its bitmap and its runs (the mode bit: head_fixed_bits).
size_t mask_bits(const ChunkHead& h);

// One chunk to write: its head, its records (bits [rec_from, rec_from +
// rec_bits) of `records`), its byte blocks (sample byte, root block, morph
// block, in that order: [block_from, block_from + block_bytes) of `blocks`).
struct ChunkOut {
    ChunkHead head;
    size_t rec_from = 0, rec_bits = 0;
    size_t block_from = 0, block_bytes = 0;
};
// Appends the payload of these chunks (sorted by increasing instance, each
// instance once) to `out`, the instances coded at order k (any 0..15 is
// valid; HeadCodes::best_order of the same heads takes the fewest
// bits); nothing when there are none. Returns false (out unchanged) when
// they are not sorted, a head is out of range or k is.
bool write_frame_payload(std::span<const ChunkOut> chunks, int k, const uint8_t* records, const uint8_t* blocks,
                         std::vector<uint8_t>& out);

// Reads the next head (prev: the previous chunk's head, nullptr for the
// first). False when the stream ends, the instance is not above prev's, first
// is 0 in its long form or not below show, or a run leaves the mask.
bool read_head(BitReader& in, const ChunkHead* prev, int k, ChunkHead& h);

}  // namespace progskin::net
