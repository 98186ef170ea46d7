// frame_reader.h — the chunk layout of a Frame (datagram.fbs, protocol
// version 8), written by server/datagram_packer.cpp and read here by every
// receiver (client, tests, benchmarks, fuzz target).
//
// Frame.payload holds, per chunk in chunk order, the sample byte (version 8,
// only when frame.sampled(): wire.h sample_ticks), the root block (root_block.h:
// absolute or predicted, self-delimiting; when chunk.flags & CHUNK_ROOT), the morph block (when chunk.flags &
// CHUNK_MORPH: uint8 n >= 1, then n entries of MORPH_ENTRY_BYTES: uint8 morph
// index, strictly increasing, and int16 little-endian weight, wire.h
// decode_morph_weight), a bone mask of mask_bytes(first, show)
// bytes (bit j of byte j / 8, least significant bit first: bone first + j is
// carried), then the records of the carried bones in increasing bone order
// as one bit stream (bone_record.h: parent-relative, each record opening with
// a "predicted" bit when the chunk has a baseline, flags bits 3-6; scale
// fields when flags & CHUNK_SCALED), padded with zero bits to a whole byte.
//
// read_frame(frame, record_size, run[, on_chunk]) checks every length and
// index of a verified Frame before anything is applied:
//   record_size(instance) -> int: the absolute record bytes of that
//       instance's asset (12, or 14 when it is scaled), 0 when the instance
//       is unknown (its chunks are walked by their flags and skipped: an
//       instance may be announced on the control channel after its first
//       frames);
//   on_chunk(chunk, sample, root, morph): once per chunk of a known
//       instance, before its runs (sample: its sample byte, 0 when the frame
//       has none; root: the chunk's root block, root_block.h, empty when
//       none; morph: the morph block from its count byte on, or nullptr);
//   run(instance, first, count, show, RecordRun): called for every run of
//       consecutive bones carried, in payload order (the run's first record
//       at RecordRun.bit of its bytes).
// Returns false, having called nothing, when a chunk's scale flag differs
// from its known instance's, has show == 0 or first >= show, a linear
// baseline without an age (Chunk.flags bits 3-7), a root block breaks its
// syntax (root_block.h root_size), a root, morph block or mask runs past
// the payload, a morph block has n == 0 or indices not
// strictly increasing, the mask has bits set at or past show, the chunk
// carries neither a bone nor a morph weight, a record breaks its syntax or
// runs past the payload (bone_record.h skip_record), the padding is not
// zero, or when bytes are left over after the last chunk. Whether show fits
// the asset's bone count is the receiver's check (PoseBuffer::add_chunk), so
// are a predicted record's or root's baseline and sums, and whether a morph index is
// below the asset's morph target count (PoseBuffer::add_morphs). O(payload
// bits), no allocation.
#pragma once
#include <bit>
#include <cstddef>
#include <cstdint>

#include <span>

#include "bone_record.h"
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

// Bytes of the bone mask of a chunk covering bones first..show-1.
constexpr size_t mask_bytes(int first, int show) { return show > first ? size_t(show - first + 7) / 8 : 0; }

template <class RecordSize, class Run, class OnChunk>
bool read_frame(const wire::Frame& frame, RecordSize&& record_size, Run&& run, OnChunk&& on_chunk) {
    const auto* chunks = frame.chunks();
    const auto* payload = frame.payload();
    const uint8_t* data = payload ? payload->data() : nullptr;
    const size_t size = payload ? payload->size() : 0;
    const bool sampled = frame.sampled();
    // Pass 0 checks everything; pass 1 calls run.
    for (int pass = 0; pass < 2; ++pass) {
        size_t at = 0;
        if (chunks) {
            for (const wire::Chunk* c : *chunks) {
                const int known = record_size(c->instance());
                const bool scaled = (c->flags() & CHUNK_SCALED) != 0;
                const int rs = scaled ? RecordFormat::kScaledSize : RecordFormat::kPlainSize;
                const int first = c->first(), show = c->show();
                const uint8_t base = base_from_flags(c->flags());
                if ((known > 0 && known != rs) || first >= show || ((base & kBaseLinear) && !(base & kBaseAgeMask)))
                    return false;
                uint8_t sample = 0;  // version 8: when frame.sampled(), each chunk opens with its sample byte
                if (sampled) {
                    if (at >= size) return false;
                    sample = data[at++];
                }
                std::span<const uint8_t> root;
                if (c->flags() & CHUNK_ROOT) {
                    const size_t n = at < size ? root_size(data + at, size - at) : 0;
                    if (n == 0) return false;
                    root = {data + at, n};
                    at += n;
                }
                const uint8_t* morph = nullptr;
                if (c->flags() & CHUNK_MORPH) {
                    if (size - at < 1) return false;
                    const size_t n = data[at];
                    if (n == 0 || (size - at - 1) / MORPH_ENTRY_BYTES < n) return false;
                    for (size_t m = 1; m < n; ++m)
                        if (data[at + 1 + m * MORPH_ENTRY_BYTES] <= data[at + 1 + (m - 1) * MORPH_ENTRY_BYTES]) return false;
                    morph = data + at;
                    at += 1 + n * MORPH_ENTRY_BYTES;
                }
                const size_t mb = mask_bytes(first, show);
                if (size - at < mb) return false;
                const uint8_t* mask = data + at;
                at += mb;
                const int bits = show - first;
                if (bits % 8 != 0 && (mask[mb - 1] >> (bits % 8)) != 0) return false;
                size_t carried = 0;
                for (size_t i = 0; i < mb; ++i) carried += size_t(std::popcount(mask[i]));
                if (carried == 0 && !morph) return false;
                // The records: walked (pass 0) to find where the chunk ends.
                const uint8_t* rec = data + at;
                const size_t avail = size - at;
                BitReader walk(rec, avail);
                const bool with_base = (base & kBaseAgeMask) != 0;
                if (pass == 0) {
                    for (size_t k = 0; k < carried; ++k)
                        if (!skip_record(walk, scaled, with_base)) return false;
                    const size_t pad = (8 - walk.at() % 8) % 8;
                    uint64_t zero = 0;
                    if (pad && (!walk.get(int(pad), zero) || zero != 0)) return false;
                } else {
                    for (size_t k = 0; k < carried; ++k) skip_record(walk, scaled, with_base);
                }
                const size_t rec_bytes = (walk.at() + 7) / 8;
                if (pass == 1 && known > 0) {
                    on_chunk(*c, sample, root, morph);
                    BitReader runs(rec, rec_bytes);
                    int j = 0;
                    while (j < bits) {
                        if (!(mask[j / 8] >> (j % 8) & 1)) {
                            ++j;
                            continue;
                        }
                        int e = j + 1;
                        while (e < bits && (mask[e / 8] >> (e % 8) & 1)) ++e;
                        const size_t from = runs.at();
                        for (int k = j; k < e; ++k) skip_record(runs, scaled, with_base);
                        run(c->instance(), first + j, e - j, show, RecordRun{rec, rec_bytes, from, scaled, base, runs.at() - from});
                        j = e;
                    }
                }
                at += rec_bytes;
            }
        }
        if (at != size) return false;
    }
    return true;
}

template <class RecordSize, class Run>
bool read_frame(const wire::Frame& frame, RecordSize&& record_size, Run&& run) {
    return read_frame(frame, record_size, run, [](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t*) {});
}

}  // namespace progskin::net
