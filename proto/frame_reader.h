// frame_reader.h — the chunk layout of a Frame (datagram.fbs, protocol
// version 4), written by server/datagram_packer.cpp and read here by every
// receiver (client, tests, benchmarks, fuzz target).
//
// Frame.payload holds, per chunk in chunk order, the root block (ROOT_BYTES,
// when chunk.flags & CHUNK_ROOT), the morph block (when chunk.flags &
// CHUNK_MORPH: uint8 n >= 1, then n entries of MORPH_ENTRY_BYTES: uint8 morph
// index, strictly increasing, and int16 little-endian weight, wire.h
// decode_morph_weight), a bone mask of mask_bytes(first, show)
// bytes (bit j of byte j / 8, least significant bit first: bone first + j is
// carried), then one record per set bit, in increasing bone order; records
// are 14 bytes when flags & CHUNK_SCALED, else 12.
//
// read_frame(frame, record_size, run[, on_chunk]) checks every length and
// index of a verified Frame before anything is applied:
//   record_size(instance) -> int: the record bytes of that instance's asset,
//       0 when the instance is unknown (its chunks are skipped: an instance
//       may be announced on the control channel after its first frames);
//   on_chunk(chunk, root, morph): once per chunk of a known instance, before
//       its runs (root: the ROOT_BYTES block, or nullptr; morph: the morph
//       block from its count byte on, or nullptr);
//   run(instance, first, count, show, records): called for every run of
//       consecutive bones carried, in payload order (records: count records).
// Returns false, having called nothing, when a chunk's record size differs
// from its known instance's, has show == 0 or first >= show, unknown flag
// bits, a root, morph block or mask runs past the payload, a morph block has
// n == 0 or indices not strictly increasing, the mask has bits set at or past
// show, the chunk carries neither a bone nor a morph weight, its records run past the payload, or when bytes are
// left over after the last chunk. Whether show fits the asset's bone count is
// the receiver's check (PoseBuffer::add_chunk), and so is whether a morph
// index is below the asset's morph target count (PoseBuffer::add_morphs). O(payload bytes), no allocation.
#pragma once
#include <bit>
#include <cstddef>
#include <cstdint>

#include "datagram_generated.h"
#include "wire.h"

namespace progskin::net {

// Bytes of the bone mask of a chunk covering bones first..show-1.
constexpr size_t mask_bytes(int first, int show) { return show > first ? size_t(show - first + 7) / 8 : 0; }

template <class RecordSize, class Run, class OnChunk>
bool read_frame(const wire::Frame& frame, RecordSize&& record_size, Run&& run, OnChunk&& on_chunk) {
    const auto* chunks = frame.chunks();
    const auto* payload = frame.payload();
    const uint8_t* data = payload ? payload->data() : nullptr;
    const size_t size = payload ? payload->size() : 0;
    // Pass 0 checks everything; pass 1 calls run.
    for (int pass = 0; pass < 2; ++pass) {
        size_t at = 0;
        if (chunks) {
            for (const wire::Chunk* c : *chunks) {
                const int known = record_size(c->instance());
                const int rs = (c->flags() & CHUNK_SCALED) ? 14 : 12;
                const int first = c->first(), show = c->show();
                if ((known > 0 && known != rs) || first >= show ||
                    (c->flags() & ~(CHUNK_ROOT | CHUNK_SCALED | CHUNK_MORPH)))
                    return false;
                const uint8_t* root = nullptr;
                if (c->flags() & CHUNK_ROOT) {
                    if (size - at < ROOT_BYTES) return false;
                    root = data + at;
                    at += ROOT_BYTES;
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
                if ((carried == 0 && !morph) || (size - at) / size_t(rs) < carried) return false;
                if (pass == 1 && known > 0) {
                    on_chunk(*c, root, morph);
                    const uint8_t* rec = data + at;
                    int j = 0;
                    while (j < bits) {
                        if (!(mask[j / 8] >> (j % 8) & 1)) {
                            ++j;
                            continue;
                        }
                        int e = j + 1;
                        while (e < bits && (mask[e / 8] >> (e % 8) & 1)) ++e;
                        run(c->instance(), first + j, e - j, show, rec);
                        rec += size_t(e - j) * size_t(rs);
                        j = e;
                    }
                }
                at += carried * size_t(rs);
            }
        }
        if (at != size) return false;
    }
    return true;
}

template <class RecordSize, class Run>
bool read_frame(const wire::Frame& frame, RecordSize&& record_size, Run&& run) {
    return read_frame(frame, record_size, run, [](const wire::Chunk&, const uint8_t*, const uint8_t*) {});
}

}  // namespace progskin::net
