// root_block.h — the root block of a frame chunk (protocol version 7,
// docs/protocol.md "Root block"): an instance's world placement (RootPose,
// bone_codec.h: 26 bytes when absolute), coded absolute or predicted from
// the instance's root at ticks the client acknowledged.
//
// Bit layout (least significant bit first), padded with zero bits to a byte:
//   4 bits  age a (0: absolute; 1..15: predicted from the root a ticks ago)
//   1 bit   linear (a >= 1 only): predicted from the roots a and 2a ago
//   absolute: position x, y, z as 32-bit two's complement millimetres,
//             rotation as 2 bits index + three 15-bit components (the bone
//             record's smallest three), source time as 64 bits
//             (212 bits: 27 bytes).
//   predicted: 2 bits selecting an order from kRootPosOrders, three
//             Exp-Golomb codes (bone_record.h) of the zigzagged position
//             residuals; 1 bit "same rotation index": 2 bits selecting
//             from kDeltaOrders and three codes of the component residuals,
//             else the absolute rotation (2 + 45 bits); 2 bits selecting
//             from kRootTimeOrders and one code of the time residual.
// Prediction of the integers at tick T from the roots b1 (T - a) and, when
// linear, b2 (T - 2a): position and time b1 + (b1 - b2) (time modulo 2^64),
// else b1; rotation components the same when b2 has b1's index, else b1's.
// A walking character's root costs 5 to 8 bytes instead of 26. Decoding
// needs the baselines (RootRing); a predicted root whose baseline a receiver
// lacks is refused (never expected: the server predicts only from ticks the
// client acknowledged), and a position outside int32 or a component outside
// 0..32767 is refused, never clamped.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "wire.h"  // ROOT_BYTES

namespace progskin::net {

inline constexpr int kRootPosOrders[4] = {0, 3, 6, 10};
inline constexpr int kRootTimeOrders[4] = {6, 10, 14, 18};
inline constexpr size_t kRootAbsoluteBytes = 27;  // an absolute root block
inline constexpr size_t kRootMaxBytes = 64;       // no root block is longer (checked when read)

// Writes the root block of `now` (an absolute ROOT_BYTES block, encode_root's)
// to out (appended, byte-aligned): predicted from b1 (age a = base & 0x3F,
// 1..15) and, when base & 0x40 (linear), b2, or absolute when base is 0, a
// baseline is nullptr, or the prediction would not be shorter. Returns the
// bytes appended. O(1).
size_t write_root(const uint8_t* now, uint8_t base, const uint8_t* b1, const uint8_t* b2, std::vector<uint8_t>& out);

// The length in bytes of the root block at data (avail bytes), checking its
// syntax only: codes within bounds, linear only with an age, padding zero.
// 0 when it is malformed or runs past avail. O(1).
size_t root_size(const uint8_t* data, size_t avail);
// A root block's baseline: its age | 0x40 when linear (0: absolute).
uint8_t root_base(const uint8_t* block);

// Decodes a root block (size bytes, root_size's) into an absolute ROOT_BYTES
// block, given the roots at its baseline ticks (b1, and b2 when linear;
// ignored when absolute). False when a needed baseline is nullptr or a
// value is out of bounds (above). O(1).
bool read_root(const uint8_t* block, size_t size, const uint8_t* b1, const uint8_t* b2, uint8_t* out);

// A receiver's roots of one instance over the last 16 ticks (what a
// predicted root may refer to), by tick.
class RootRing {
public:
    // The absolute root at `tick`; nullptr when not held.
    const uint8_t* at(uint32_t tick) const;
    // Keeps `root` (absolute) as the root of `tick` unless a newer tick holds its place.
    void put(uint32_t tick, const uint8_t* root);
    // Decodes `block` (size bytes) of a chunk at `tick` into out (absolute);
    // false when malformed or its baseline is not held (*missing set).
    bool resolve(uint32_t tick, const uint8_t* block, size_t size, uint8_t* out, bool* missing = nullptr) const;
    // Prefetches the entries of `tick` and of the `back` ticks before it
    // (what resolve and put of a chunk at `tick` read and write, for the
    // usual baseline ages): a caller that knows its next chunks early
    // overlaps their cache misses. No effect on the contents.
    void prefetch(uint32_t tick, int back = 4) const {
        for (int k = 0; k <= back && k < int(ring_.size()); ++k) __builtin_prefetch(&ring_[(tick - uint32_t(k)) % ring_.size()]);
    }
    void clear();

private:
    struct Entry {
        uint32_t tick = 0;
        bool valid = false;
        std::array<uint8_t, ROOT_BYTES> root{};
    };
    std::array<Entry, 16> ring_{};
};

}  // namespace progskin::net
