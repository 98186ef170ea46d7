// frame_reader.h — the payload layout of a Frame datagram (wire.h
// FrameDatagram, protocol version 13: proto/chunk_head.h), written by
// server/datagram_packer.cpp and read here by every receiver (client, tests,
// benchmarks, fuzz target).
//
// The payload is one bit stream of chunk heads (instance, first, show,
// epoch, flags, bone mask: chunk_head.h), each followed by the records of
// its carried bones in increasing bone order (bone_record.h:
// parent-relative, each record opening with a "predicted" bit when the chunk
// has a baseline, flags bits 3-6; scale fields when flags & CHUNK_SCALED),
// padded with zero bits to a whole byte; then per chunk, in the same order,
// its byte blocks: the sample byte (version 8, only when frame.sampled:
// wire.h sample_ticks), the root block (root_block.h: absolute or predicted,
// self-delimiting; when flags & CHUNK_ROOT), the morph block (when flags &
// CHUNK_MORPH: uint8 n >= 1, then n entries of MORPH_ENTRY_BYTES: uint8
// morph index, strictly increasing, and int16 little-endian weight, wire.h
// decode_morph_weight).
//
// read_frame(frame, record_size, run[, on_chunk]) checks every length and
// index of a Frame datagram (read_frame_datagram) before anything is applied:
//   record_size(instance) -> int: the absolute record bytes of that
//       instance's asset (12, or 14 when it is scaled), 0 when the instance
//       is unknown (its chunks are walked by their flags and skipped: an
//       instance may be announced on the control channel after its first
//       frames); asked once per chunk, in the check pass, before any call
//       below;
//   on_chunk(chunk, sample, root, morph): once per chunk of a known
//       instance, before its runs (chunk: its head as a wire::Chunk; sample:
//       its sample byte, 0 when the frame has none; root: the chunk's root
//       block, root_block.h, empty when none; morph: the morph block from its
//       count byte on, or nullptr);
//   run(instance, first, count, show, RecordRun): called for every run of
//       consecutive bones carried, in payload order (the run's first record
//       at RecordRun.bit of its bytes).
// Returns false, having called nothing, when a head breaks its syntax
// (chunk_head.h read_head: instances strictly increasing, first < show, the
// mask within show), a chunk's scale flag differs from its known
// instance's, a linear baseline has no age (flags bits 3-7), a record
// breaks its syntax or runs past the payload (bone_record.h skip_record), the
// padding is not zero, a root block breaks its syntax (root_block.h
// root_size), a root or morph block runs past the payload, a morph block has
// n == 0 or indices not strictly increasing, the chunk carries neither a
// bone nor a morph weight, or when bytes are left over after the last
// block. Whether show fits the asset's bone count is the receiver's check
// (PoseBuffer::add_chunk), so are a predicted record's or root's baseline and
// sums, and whether a morph index is below the asset's morph target count
// (PoseBuffer::add_morphs). O(payload bits), no allocation.
#pragma once
#include <bit>
#include <cstddef>
#include <cstdint>

#include <span>
#include <utility>

#include "bone_record.h"
#include "chunk_head.h"
#include "datagram_generated.h"
#include "root_block.h"
#include "wire.h"

namespace progskin::net {

// Where a run's records are: bit `bit` of data[0..bytes) (the chunk's record
// stream), coded with the chunk's scale flag and baseline.
struct RecordRun {
    const uint8_t* data = nullptr;
    size_t bytes = 0;
    size_t bit = 0;
    bool scaled = false;
    uint8_t base = 0;  // the chunk's baseline (bone_record.h base_from_flags)
    size_t bits = 0;   // the run's records take bits [bit, bit + bits)
};

// Walks the heads of a payload's bit stream: for each chunk i, after its
// head, calls chunk(i, h, in, scaled, with_base), which reads past the
// chunk's h.carried() records from `in` (false when one breaks its syntax).
// Returns the bytes of the bit stream (its padding included, checked to be
// zero), or 0 when it breaks its syntax or chunk returned false. An empty
// payload has no chunks (returns 0 as well; callers check the size first).
template <class Chunk>
size_t walk_chunks(const uint8_t* data, size_t size, Chunk&& chunk) {
    BitReader in(data, size);
    uint64_t n = 0, k = 0;
    if (!in.get_eg(0, n) || n >= kMaxChunks || !in.get(4, k)) return 0;
    ChunkHead h;
    for (size_t i = 0; i <= n; ++i) {
        if (!read_head(in, i ? &h : nullptr, int(k), h)) return 0;
        const uint8_t base = base_from_flags(h.flags);
        if ((base & kBaseLinear) && !(base & kBaseAgeMask)) return 0;
        if (!chunk(i, std::as_const(h), in, (h.flags & CHUNK_SCALED) != 0, (base & kBaseAgeMask) != 0)) return 0;
    }
    const size_t pad = (8 - in.at() % 8) % 8;
    uint64_t zero = 0;
    if (pad && (!in.get(int(pad), zero) || zero != 0)) return 0;
    return in.at() / 8;
}

// walk_chunks calling head(i, h, rec_bit, rec_bits) for each chunk i after
// its records (rec_bit: where they start).
template <class Head>
size_t walk_chunk_heads(const uint8_t* data, size_t size, Head&& head) {
    return walk_chunks(data, size, [&](size_t i, const ChunkHead& h, BitReader& in, bool scaled, bool with_base) {
        const size_t from = in.at();
        for (int c = h.carried(); c > 0; --c)
            if (!skip_record(in, scaled, with_base)) return false;
        return bool(head(i, h, from, in.at() - from));
    });
}

// Calls f(const ChunkHead&) for every chunk of the frame (the stream's
// syntax checked as read_frame does, the blocks not); false when it breaks.
template <class F>
bool for_each_chunk_head(const FrameDatagram& frame, F&& f) {
    if (frame.payload.empty()) return true;
    return walk_chunk_heads(frame.payload.data(), frame.payload.size(), [&](size_t, const ChunkHead& h, size_t, size_t) {
               f(h);
               return true;
           }) != 0;
}

// unknown (optional): set, when the frame reads, to its chunks of unknown instances.
template <class RecordSize, class Run, class OnChunk>
bool read_frame(const FrameDatagram& frame, RecordSize&& record_size, Run&& run, OnChunk&& on_chunk, int* unknown = nullptr) {
    const uint8_t* data = frame.payload.data();
    const size_t size = frame.payload.size();
    if (size == 0) return true;
    const bool sampled = frame.sampled;
    // Pass 0: the heads and records (and, for pass 1, each chunk's flags
    // and whether its instance is known, and where each run's records end:
    // the first kMaxRunEnds runs; the others pass 1 walks again).
    std::array<uint8_t, kMaxChunks> flags;
    std::array<bool, kMaxChunks> known_chunk;
    constexpr size_t kMaxRunEnds = 512;
    std::array<uint32_t, kMaxRunEnds> run_end;
    size_t chunks = 0, runs = 0;
    int unknowns = 0;
    const size_t stream = walk_chunks(data, size, [&](size_t i, const ChunkHead& h, BitReader& in, bool scaled, bool with_base) {
        const int known = record_size(h.instance);
        const int rs = (h.flags & CHUNK_SCALED) ? RecordFormat::kScaledSize : RecordFormat::kPlainSize;
        if ((known > 0 && known != rs) || (h.carried() == 0 && !(h.flags & CHUNK_MORPH))) return false;
        unknowns += known <= 0;
        flags[i] = h.flags;
        known_chunk[i] = known > 0;
        chunks = i + 1;
        bool ok = true;
        for_each_carried_run(h, [&](int j, int e) {
            for (int c = j; c < e && ok; ++c) ok = skip_record(in, scaled, with_base);
            if (runs < kMaxRunEnds) run_end[runs] = uint32_t(in.at());
            ++runs;
        });
        return ok;
    });
    if (stream == 0) return false;
    // The blocks: where each chunk's are, checked.
    struct Blocks {
        uint8_t sample = 0;
        std::span<const uint8_t> root;
        const uint8_t* morph = nullptr;
    };
    auto block = [&](size_t& at, uint8_t f, Blocks& b) {
        if (sampled) {
            if (at >= size) return false;
            b.sample = data[at++];
        }
        if (f & CHUNK_ROOT) {
            const size_t n = at < size ? root_size(data + at, size - at) : 0;
            if (n == 0) return false;
            b.root = {data + at, n};
            at += n;
        }
        if (f & CHUNK_MORPH) {
            if (size - at < 1) return false;
            const size_t n = data[at];
            if (n == 0 || (size - at - 1) / MORPH_ENTRY_BYTES < n) return false;
            for (size_t m = 1; m < n; ++m)
                if (data[at + 1 + m * MORPH_ENTRY_BYTES] <= data[at + 1 + (m - 1) * MORPH_ENTRY_BYTES]) return false;
            b.morph = data + at;
            at += 1 + n * MORPH_ENTRY_BYTES;
        }
        return true;
    };
    size_t at = stream;
    for (size_t i = 0; i < chunks; ++i) {
        Blocks b;
        if (!block(at, flags[i], b)) return false;
    }
    if (at != size) return false;
    if (unknown) *unknown = unknowns;
    // Pass 1: the calls; each run's records are not walked again where pass
    // 0 noted their end.
    at = stream;
    size_t r = 0;
    walk_chunks(data, size, [&](size_t i, const ChunkHead& h, BitReader& in, bool scaled, bool with_base) {
        Blocks b;
        block(at, h.flags, b);
        const bool known = known_chunk[i];
        if (known) on_chunk(h.chunk(), b.sample, b.root, b.morph);
        const uint8_t base = base_from_flags(h.flags);
        for_each_carried_run(h, [&](int j, int e) {
            const size_t from = in.at();
            if (r < kMaxRunEnds) in.seek(run_end[r]);
            else
                for (int c = j; c < e; ++c) skip_record(in, scaled, with_base);
            ++r;
            if (known) run(h.instance, int(h.first) + j, e - j, int(h.show), RecordRun{data, stream, from, scaled, base, in.at() - from});
        });
        return true;
    });
    return true;
}

template <class RecordSize, class Run>
bool read_frame(const FrameDatagram& frame, RecordSize&& record_size, Run&& run) {
    return read_frame(frame, record_size, run, [](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t*) {});
}

}  // namespace progskin::net
