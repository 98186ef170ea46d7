// bone_record.h — the parent-relative, entropy-coded bone record of the frame
// stream (protocol version 5, docs/protocol.md "Bone record").
//
// A character's bones travel relative to their progressive parent (parent[b]
// < b; bone 0 relative to the character's root). For bone b with skinning
// matrix M_b (model space, docs/metrics.md §1) and its parent's *decoded*
// pose D_p (closed loop: quantisation error never adds down the chain), the
// relative transform R = D_p^-1 M_b is sent as integers:
//   rotation     Q of R as modified Rodrigues parameters p = v / (1 + w) of
//                its quaternion (w, v) with w >= 0, |p| <= 1, each component
//                round(p / ROT_STEP), ROT_STEP = 1/49152 (an error of half a
//                step per component turns the bone by at most 2 sqrt3
//                ROT_STEP = 7.0e-5 rad near identity, half that at 180°).
//   translation  the residual of R's translation after the prediction of a
//                rigid joint turning about its bind pivot j_b (the joint's
//                bind position in model space): t_R - (s0 j_b - s Q j_b),
//                s the record's scale (s0 when none is sent), in
//                steps of RelativeFormat::trans_step(b): bone 0 the asset's
//                translation step (its box's largest extent / 65535), the
//                others that step / s_ref, their parent's units; residuals
//                within +-kTransDeadZone steps on every axis are not sent
//                (the prediction stands).
//   scale        (scaled assets) round(log2(s_R / s0) * 2048), 0 not sent;
//                s0 = s_ref for bone 0, 1 for the others.
// s_ref is the asset's reference scale (RecordFormat::scale, most often 1):
// a skin whose matrices all carry one scale (an armature node turning
// centimetres into metres) codes as the same skin unscaled, with no scale
// field (not `scaled`).
// The decoded pose is D_b = D_p * R^ (pose.h composition).
//
// Bit layout (least significant bit first, docs/protocol.md): 2 bits
// selecting the rotation's Exp-Golomb order from kRotOrders, three
// Exp-Golomb codes of the zigzagged rotation integers; 1 bit "translation
// follows": 2 bits selecting from kTransOrders, three codes; scaled assets: 1
// bit "scale follows", one order-4 code. An Exp-Golomb code of order k for
// u >= 0: z zero bits, a one bit, then z + k bits f (LSB first), with u =
// 2^(z+k) + f - 2^k; z <= kMaxPrefix. A record is self-delimiting, so a
// receiver can walk a chunk's records without knowing the asset (only the
// chunk's CHUNK_SCALED flag). No state outside the record: any record decodes
// on its own (given its parent's pose), so a lost datagram loses only itself.
#pragma once
#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

#include "bone_codec.h"  // RecordFormat (the translation box), BonePose

namespace progskin {
struct Character;
struct FrameSet;
struct ProgressiveSkin;
}  // namespace progskin

namespace progskin::net {

inline constexpr double ROT_STEP = 1.0 / 49152.0;  // modified Rodrigues parameter step
inline constexpr int kTransDeadZone = 1;           // translation residual steps not sent
inline constexpr int kRotOrders[4] = {2, 5, 8, 11};
inline constexpr int kTransOrders[4] = {0, 4, 8, 12};
inline constexpr int kScaleOrder = 4;
inline constexpr int kMaxPrefix = 24;               // Exp-Golomb zero prefix bound (values < 2^36)
inline constexpr int32_t kMaxRotInt = 49203;        // |rotation integer| (|p| <= 1, rounding slack)
inline constexpr int32_t kMaxTransInt = 1 << 24;    // |translation residual| in steps
inline constexpr int32_t kMaxScaleInt = 32767;      // |log2 scale * 2048|
// The longest record read_record accepts (an order-k code is at most 2 kMaxPrefix + k + 1 bits).
inline constexpr int kMaxRecordBits = 2 + 3 * (2 * kMaxPrefix + 12) + 3 + 3 * (2 * kMaxPrefix + 13) + 1 +
                                      (2 * kMaxPrefix + kScaleOrder + 1);

// What both ends know of an asset to code its records: the progressive
// parents, each bone's bind pivot (model space), the translation step, and
// whether scale travels. Built from the skin the client downloads (asset
// file) and the translation box of Welcome (RecordFormat).
struct RelativeFormat {
    std::vector<int16_t> parents;   // progressive parent per bone, -1 for bone 0
    std::vector<glm::vec3> pivots;  // bind position of each bone's joint (model space)
    float t_step = 1.0f;            // translation step (model units)
    bool scaled = false;
    float s_ref = 1.0f;             // reference scale (RecordFormat::scale)
    int bone_count() const { return int(parents.size()); }
    // Bone b's scale unit s0 and translation step (the record's units, above).
    double scale_unit(int b) const { return b == 0 ? double(s_ref) : 1.0; }
    double trans_step(int b) const { return b > 0 ? double(t_step) / double(s_ref) : double(t_step); }
};
// (reference_scale and its bounds: pose.h)
// parents: ProgressiveSkin::parents; inverse_binds: each bone's inverse bind
// matrix in progressive order (the joint of bone b is inverse_binds[b]^-1's
// translation). Throws std::invalid_argument when the sizes differ or a
// parent is not below its bone.
RelativeFormat relative_format(std::span<const int16_t> parents, std::span<const Mat34> inverse_binds,
                               const RecordFormat& box);
// A chain of `bones` bones (parent b - 1) turning about the origin: for
// tools and tests that have no asset (the fuzz targets, pose buffer tests).
RelativeFormat chain_format(int bones, const RecordFormat& box);
// The same for a character's progressive skin (bone b is joint skin.order[b]).
RelativeFormat relative_format(const ProgressiveSkin& skin, const Character& c, const RecordFormat& box);

// The integers of one record.
struct RecordInts {
    int32_t rot[3] = {0, 0, 0};
    int32_t trans[3] = {0, 0, 0};  // residual; all 0 and !has_trans: the prediction
    int32_t scale = 0;
    bool has_trans = false, has_scale = false;
};

// Quantises bone b's model-space pose m against its parent's decoded pose
// (identity for bone 0), closed loop. Returns false when a value is not
// finite or outside the integers' bounds (nothing written). O(1).
bool quantise_record(const BonePose& parent_decoded, const BonePose& m, int b, const RelativeFormat& f, RecordInts& out);
// The relative pose R^ of bone b's record (about f.pivots[b]). O(1).
BonePose dequantise_record(const RecordInts& r, int b, const RelativeFormat& f);
// D_p * R^ (pose.h composition, normalised rotation).
BonePose compose_relative(const BonePose& parent, const BonePose& rel);

// Bit-level writer and reader (least significant bit first).
class BitWriter {
public:
    explicit BitWriter(std::vector<uint8_t>& out) : out_(out) {}
    void put(uint64_t bits, int n);  // n <= 57
    void put_eg(uint32_t u, int k);  // Exp-Golomb of order k
    // Appends bits [from, from + count) of src (bytes past (from + count + 7) / 8 are not read).
    void append_bits(const uint8_t* src, size_t from, size_t count);
    size_t bits() const { return out_.size() * 8 - size_t(free_); }
    void clear() {  // empties the output and starts again at its first bit
        out_.clear();
        free_ = 0;
    }
private:
    std::vector<uint8_t>& out_;
    int free_ = 0;  // unused high bits of out_.back()
};
class BitReader {
public:
    BitReader(const uint8_t* data, size_t bytes, size_t bit = 0) : data_(data), bits_(bytes * 8), at_(bit) {}
    // Moves to bit `bit` of the stream (a position an earlier read reached).
    void seek(size_t bit) { at_ = std::min(bit, bits_); }
    // n <= 57; false past the end. Inline (every field of every record):
    // one unaligned 8-byte load where 8 bytes remain, else the tail byte by byte.
    bool get(int n, uint64_t& v) {
        if (size_t(n) > bits_ - at_) return false;
        if (n == 0) {
            v = 0;
            return true;
        }
        v = (window(at_ / 8) >> (at_ % 8)) & (n >= 64 ? ~uint64_t(0) : (uint64_t(1) << n) - 1);
        at_ += size_t(n);
        return true;
    }
    // Exp-Golomb of order k (0 <= k <= 33); false past the end or a prefix
    // over kMaxPrefix. Inline; one window when the code (2z + k + 1 bits
    // for z zeros) fits its 57 bits, as nearly every one does.
    bool get_eg(int k, uint64_t& u) {
        const size_t left = bits_ - at_;
        if (left == 0) return false;
        const uint64_t w = window(at_ / 8) >> (at_ % 8);
        const size_t look = std::min<size_t>(size_t(kMaxPrefix) + 1, left);
        const uint64_t peek = w & ((uint64_t(1) << look) - 1);
        if (peek == 0) return false;  // past the end, or a prefix longer than kMaxPrefix
        const int z = std::countr_zero(peek);
        const size_t n = size_t(2 * z + k + 1);
        if (n > left) return false;
        const size_t p = at_ + size_t(z) + 1;  // the code's bits after its one
        const uint64_t rest = (n <= 57 ? w >> (z + 1) : window(p / 8) >> (p % 8)) & ((uint64_t(1) << (z + k)) - 1);
        at_ += n;
        u = (uint64_t(1) << (z + k)) + rest - (uint64_t(1) << k);
        return true;
    }
    size_t at() const { return at_; }
    size_t size() const { return bits_; }
private:
    // The 8 bytes from byte b0, little-endian; bytes past the end read as 0.
    uint64_t window(size_t b0) const {
        const size_t bytes = bits_ / 8;
        uint64_t w = 0;
        if (b0 + 8 <= bytes) {
            std::memcpy(&w, data_ + b0, 8);
            if constexpr (std::endian::native == std::endian::big) w = __builtin_bswap64(w);
            return w;
        }
        for (size_t i = 0; b0 + i < bytes; ++i) w |= uint64_t(data_[b0 + i]) << (8 * i);
        return w;
    }
    const uint8_t* data_;
    size_t bits_, at_;
};

// Appends a record's bits; returns the bits written.
size_t write_record(const RecordInts& r, bool scaled, BitWriter& w);
// Reads one record; false when it runs past the end, a code is too long, or
// an integer is outside its bound (|rot| <= kMaxRotInt and the three
// rotation integers' norm within kMaxRotInt, |trans| <= kMaxTransInt, |scale|
// <= kMaxScaleInt). O(record bits).
bool read_record(BitReader& in, bool scaled, RecordInts& r);

// Prediction (protocol: "Predicted record"). A receiver holding a bone's
// records at earlier ticks predicts the integers of the record at tick T:
// from one baseline at age a1 >= 1 (tick T - a1), the baseline itself; from
// two (a2 > a1, linear): b1 + (b1 - b2) * a1 / (a2 - a1), C++ integer
// division (toward zero), per integer. Absent translation / scale are 0.
RecordInts predict_record(const RecordInts& b1, uint32_t a1, const RecordInts* b2 = nullptr, uint32_t a2 = 0);
// The ages predict_record takes, in 1/254 tick, from the sample of the
// record's tick (its chunk's sample byte `now`, wire.h sample_ticks) to the
// sample of a baseline `age` ticks older (its sample byte `base`): 254 age
// when neither was sampled before its tick, so that the linear prediction
// extrapolates along the samples' real times (keys of a clip).
constexpr uint32_t sample_age(uint32_t age, uint8_t now, uint8_t base) {
    return 254 * age - (now ? now - 1u : 0u) + (base ? base - 1u : 0u);
}
inline constexpr int kDeltaOrders[4] = {0, 2, 5, 8};
// A predicted record: 1 bit "equal to the prediction" (then nothing else);
// else 2 bits selecting the Exp-Golomb order (kDeltaOrders) and three codes
// of the zigzagged rotation residuals, 1 bit "translation residuals follow"
// (2 + three codes), scaled assets 1 bit "scale residual follows" (one
// order-kScaleOrder code). The received integers are prediction + residual,
// has_trans / has_scale when any is non-zero, within read_record's bounds.
size_t write_predicted(const RecordInts& now, const RecordInts& pred, bool scaled, BitWriter& w);
// The bits write_predicted would write, without writing them (a plan prices
// every bone and writes only the ones that go). O(1).
size_t predicted_bits(const RecordInts& now, const RecordInts& pred, bool scaled);
bool read_predicted(BitReader& in, const RecordInts& pred, bool scaled, RecordInts& out);

// The records of a frame chunk (docs/protocol.md "Frame"): with a baseline
// (Chunk.base != 0) each record opens with 1 bit, set when it is predicted
// from the baseline (then write_predicted's syntax), clear when it stands
// alone (write_record's); without one every record is write_record's.
// The baseline byte used here ("base"): bits 0-5 the baseline's age a (0: no
// baseline), bit 6 linear (predicted from the records a and 2a ticks old);
// on the wire in Chunk.flags (base_to_flags: age 1..15 in bits 3-6, linear
// bit 7).
inline constexpr uint8_t kBaseAgeMask = 0x3F, kBaseLinear = 0x40;
inline constexpr uint32_t kMaxBaseAge = 15;  // what Chunk.flags can carry (bits 3-6)
// A chunk's baseline in Chunk.flags (wire.h CHUNK_AGE, CHUNK_LINEAR) and back.
inline uint8_t base_to_flags(uint8_t base) {
    return uint8_t(((base & kBaseAgeMask) << 3) & 0x78) | ((base & kBaseLinear) ? 0x80 : 0);
}
inline uint8_t base_from_flags(uint8_t flags) { return uint8_t(((flags & 0x78) >> 3) | ((flags & 0x80) ? kBaseLinear : 0)); }
// In a chunk with a baseline each record opens with a prefix: 1 bit set:
// predicted from the chunk's baseline; else 1 bit set: predicted from a
// baseline of its own, then 4 bits its age (1..15) and 1 bit linear; else
// (two clear bits) a standalone record.
struct RecordPrefix {
    enum Kind : uint8_t { Standalone, Chunk, Own } kind = Standalone;
    uint8_t base = 0;  // Own: the record's baseline (age | kBaseLinear)
};
bool read_prefix(BitReader& in, RecordPrefix& out);  // false past the end or an own age of 0
void write_prefix(const RecordPrefix& p, BitWriter& w);
inline constexpr int kOwnPrefixBits = 7, kChunkPrefixBits = 1, kStandalonePrefixBits = 2;

// Walks one chunk record without its baseline: the syntax, code lengths and
// a standalone record's bounds. False when it runs past the end or breaks
// them (the frame is refused before anything is applied). O(record bits).
bool skip_record(BitReader& in, bool scaled, bool with_base);

// Encodes a whole pose (B model-space poses, progressive order) closed loop:
// appends each bone's record to `bits` (a fresh byte-aligned stream is not
// needed: records are concatenated bit-wise) and writes bone b's first bit
// offset to offsets[b] and offsets[B] = the end (offsets: B + 1 entries).
// decoded (B entries): the poses a receiver of every record will compose.
// ints (optional, B entries): each record's integers (the baselines of
// later predicted records). Returns false (bits and offsets partly written) when a bone cannot be
// quantised (quantise_record). O(B).
bool encode_pose(std::span<const BonePose> model, const RelativeFormat& f, std::vector<uint8_t>& bits,
                 std::span<uint32_t> offsets, std::span<BonePose> decoded, std::span<RecordInts> ints = {});

// The records of a Pose datagram (docs/protocol.md "Pose"): out.size()
// records, bit-packed from the first bit of `bytes`, then zero bits to the
// byte's end; standalone (write_record's syntax) when pred is empty, else
// record i predicted from pred[i] (write_predicted's). False when a record
// does not read (read_record's bounds), bytes are left over or a padding
// bit is set. O(bytes), no allocation.
bool read_pose_records(std::span<const uint8_t> bytes, bool scaled, std::span<const RecordInts> pred, std::span<RecordInts> out);

// The mean bits per frame of each bone's record (progressive order) when
// every bone of every frame of `frames` (the character's skinning matrices)
// is coded as the stream codes it at full rate with prompt acknowledgements:
// parent-relative, closed loop, predicted from the frame before (delta; the
// first frame standalone). The translation box is the frames' own (every
// bone's model-space translation), scale when any bone scales. What the
// strategy choice weighs (offline/collapse.h BuildOptions::bone_bits).
// O(frames x B).
std::vector<double> record_bits_per_bone(const Character& c, const ProgressiveSkin& s, const FrameSet& frames);

// Copies `count` bits starting at bit `from` of src to the end of w.
void copy_bits(const uint8_t* src, size_t from, size_t count, BitWriter& w);

// Worst-case vertex error (model units) of one record for vertices within
// bind_radius of the origin and scale at most max_scale: rotation angle
// error about the bone's pivot (at most 2 * bind_radius from a vertex) plus
// the translation dead zone and rounding.
double relative_bound(const RelativeFormat& f, double bind_radius, double max_scale = 1.0);

}  // namespace progskin::net
