// The Frame layout of protocol version 12 (proto/chunk_head.h,
// proto/frame_reader.h): what the packer writes reads back bone for bone,
// bit for bit, and every malformed chunk is refused before anything is
// applied. The frames of these tests are written field by field from
// docs/protocol.md "Frame" (put_payload), not by the code under test.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <random>

#include "chunk_head.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "frame_reader.h"
#include "net_test_support.h"
#include "scene.h"
#include "scheduler.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;

// Hand{.instance = ..., ...}: the fields not named keep their defaults.
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"

namespace {

// A Frame datagram (tick 7) of the given payload bytes.
std::vector<uint8_t> frame_datagram(const std::vector<uint8_t>& payload) {
    std::vector<uint8_t> d;
    write_frame_datagram(1, 0, 7, false, {}, payload, d);
    return d;
}

// One chunk as written by hand (any values, valid or not).
struct Hand {
    int instance = 0, first = 0, show = 1;
    uint8_t flags = 0, epoch = 0;
    std::vector<int> carried;                 // bones (absolute), increasing
    bool runs = false;                        // the mask as runs (else a bitmap of show - first bits)
    std::vector<std::pair<int, int>> raw_runs;  // with runs: these (gap, length - 1) codes instead of carried's
    int records = -1;                         // identity records written (-1: one per carried bone)
    bool scaled_records = false;
    bool long_first = false;                  // first in its long form even when 0
    bool long_fields = false;                 // show, epoch and flags in their long form even when the same
    bool same_show = false;                   // show written as "the same as the previous chunk's" whatever it is
    std::vector<uint8_t> blocks;              // sample byte, root and morph blocks
};

// The payload of these chunks, field by field (docs/protocol.md "Frame"):
// EG0(n - 1), k, per chunk its head and records, zero padding (or `pad`),
// then the blocks. n: the count written (-1: chunks.size()).
std::vector<uint8_t> put_payload(const std::vector<Hand>& chunks, int k = 3, int n = -1, uint64_t pad = 0) {
    std::vector<uint8_t> out;
    BitWriter w(out);
    w.put_eg(uint32_t((n < 0 ? int(chunks.size()) : n) - 1), 0);
    w.put(uint64_t(k), 4);
    int prev = -1;
    int last_show = 0, last_epoch = 0, last_flags = 0;  // before the first chunk: 0
    // show, epoch, flags: 0 when the same as the previous chunk's, else 1 and 8 bits.
    auto field = [&](int v, int& last, bool long_form, bool same) {
        if (same || (v == last && !long_form)) w.put(0, 1);
        else w.put(1 | uint64_t(uint8_t(v)) << 1, 9);
        if (!same) last = v;
    };
    for (const Hand& h : chunks) {
        const uint32_t d = uint32_t(h.instance - prev - 1);
        if (h.instance > prev && d < (1u << k)) w.put(uint64_t(d) << 1, 1 + k);
        else w.put(1 | uint64_t(uint16_t(h.instance)) << 1, 17);
        prev = h.instance;
        if (h.first || h.long_first) w.put(1 | uint64_t(uint8_t(h.first)) << 1, 9);
        else w.put(0, 1);
        field(h.show, last_show, h.long_fields, h.same_show);
        field(h.epoch, last_epoch, h.long_fields, false);
        field(h.flags, last_flags, h.long_fields, false);
        if (!h.runs) {
            w.put(0, 1);
            for (int j = 0; j < h.show - h.first; ++j)
                w.put(std::find(h.carried.begin(), h.carried.end(), h.first + j) != h.carried.end() ? 1 : 0, 1);
        } else {
            w.put(1, 1);
            std::vector<std::pair<int, int>> codes = h.raw_runs;
            if (codes.empty()) {  // from carried
                int end = 0;
                for (size_t i = 0; i < h.carried.size();) {
                    size_t e = i + 1;
                    while (e < h.carried.size() && h.carried[e] == h.carried[e - 1] + 1) ++e;
                    const int j = h.carried[i] - h.first;
                    codes.push_back({j - end - (i ? 1 : 0), int(e - i) - 1});
                    end = j + int(e - i);
                    i = e;
                }
            }
            w.put_eg(uint32_t(codes.size()), 0);
            for (auto [gap, len] : codes) {
                w.put_eg(uint32_t(gap), 0);
                w.put_eg(uint32_t(len), 0);
            }
        }
        const int records = h.records < 0 ? int(h.carried.size()) : h.records;
        for (int r = 0; r < records; ++r) write_record(RecordInts{}, h.scaled_records, w);
    }
    if (w.bits() % 8) w.put(pad, int(8 - w.bits() % 8));
    for (const Hand& h : chunks) out.insert(out.end(), h.blocks.begin(), h.blocks.end());
    return out;
}

struct ChunkRun {
    int instance, first, count, show;
    size_t offset;  // of the run's first record in the payload, bits
};

// read_frame over a datagram, instances 0..2 known with 12-byte records.
bool read_datagram(const std::vector<uint8_t>& d, std::vector<ChunkRun>& runs) {
    runs.clear();
    FrameDatagram f;
    if (!read_frame_datagram(d, f)) return false;
    const uint8_t* base = f.payload.data();
    const size_t size = f.payload.size();
    return read_frame(
        f, [](uint16_t i) { return i < 3 ? 12 : 0; },
        [&](uint16_t i, int first, int count, int show, const RecordRun& rec) {
            EXPECT_GE(rec.data, base);
            EXPECT_LE(rec.data + rec.bytes, base + size);
            EXPECT_LT(rec.bit + size_t(count), rec.bytes * 8 + 1);
            runs.push_back({i, first, count, show, size_t(rec.data - base) * 8 + rec.bit});
        });
}

}  // namespace

// The Frame datagram's header (version 13), byte by byte as docs/protocol.md
// "Frame" writes it: flags, seq, send time, tick (little-endian), the pose
// acks (count, then instance and pose_seq each), then the payload.
TEST(NetFrame, FrameDatagramHeaderIsTheProtocolsBytes) {
    const std::vector<uint8_t> payload = {0xAA, 0xBB, 0xCC};
    const std::vector<wire::PoseAck> acks = {wire::PoseAck(0x0102, 0x03040506), wire::PoseAck(7, 0xFFFFFFFF)};
    std::vector<uint8_t> d;
    write_frame_datagram(0x11223344, 0x55667788, 0x99AABBCC, true, acks, payload, d);
    const std::vector<uint8_t> expect = {0x07,                                      // kind, sampled, acks
                                         0x44, 0x33, 0x22, 0x11,                    // seq
                                         0x88, 0x77, 0x66, 0x55,                    // send_time_us
                                         0xCC, 0xBB, 0xAA, 0x99,                    // tick
                                         2,                                         // two pose acks
                                         0x02, 0x01, 0x06, 0x05, 0x04, 0x03,        // instance 0x0102, pose 0x03040506
                                         7, 0, 0xFF, 0xFF, 0xFF, 0xFF,              // instance 7, pose 0xFFFFFFFF
                                         0xAA, 0xBB, 0xCC};                         // payload
    EXPECT_EQ(d, expect);
    FrameDatagram f;
    ASSERT_TRUE(is_frame_datagram(d));
    ASSERT_TRUE(read_frame_datagram(d, f));
    EXPECT_EQ(f.seq, 0x11223344u);
    EXPECT_EQ(f.send_time_us, 0x55667788u);
    EXPECT_EQ(f.tick, 0x99AABBCCu);
    EXPECT_TRUE(f.sampled);
    ASSERT_EQ(f.pose_ack_count(), 2u);
    EXPECT_EQ(f.pose_ack(0).instance(), 0x0102);
    EXPECT_EQ(f.pose_ack(0).pose_seq(), 0x03040506u);
    EXPECT_EQ(f.pose_ack(1).instance(), 7);
    EXPECT_EQ(f.pose_ack(1).pose_seq(), 0xFFFFFFFFu);
    EXPECT_EQ(std::vector<uint8_t>(f.payload.begin(), f.payload.end()), payload);
    // No acks, not sampled: the 13-byte header and the payload.
    write_frame_datagram(1, 2, 3, false, {}, payload, d);
    ASSERT_EQ(d.size(), FRAME_HEADER_BYTES + payload.size());
    EXPECT_EQ(d[0], 0x01);
    ASSERT_TRUE(read_frame_datagram(d, f));
    EXPECT_FALSE(f.sampled);
    EXPECT_EQ(f.pose_ack_count(), 0u);
    EXPECT_EQ(f.payload.size(), payload.size());
    // A FlatBuffers datagram is not a Frame datagram, and the other way round.
    flatbuffers::FlatBufferBuilder fbb;
    build_bind(fbb, 1, 2);
    const std::span<const uint8_t> bind(fbb.GetBufferPointer(), fbb.GetSize());
    EXPECT_FALSE(is_frame_datagram(bind));
    EXPECT_FALSE(read_frame_datagram(bind, f));
    EXPECT_NE(verify_datagram(bind), nullptr);
    EXPECT_EQ(verify_datagram(d), nullptr);
}

// Every header a receiver refuses (docs/protocol.md "Frame"), before the payload is read.
TEST(NetFrame, FrameDatagramRefusesMalformedHeaders) {
    const std::vector<uint8_t> payload(20, 0);
    const std::vector<wire::PoseAck> one = {wire::PoseAck(1, 2)};
    std::vector<uint8_t> good;
    write_frame_datagram(5, 6, 7, false, one, payload, good);
    FrameDatagram f;
    ASSERT_TRUE(read_frame_datagram(good, f));
    auto refused = [&](std::vector<uint8_t> d, const char* why) {
        EXPECT_FALSE(read_frame_datagram(d, f)) << why;
    };
    refused({}, "empty");
    refused(std::vector<uint8_t>(good.begin(), good.begin() + 12), "shorter than the header");
    for (int bit = 3; bit < 8; ++bit) {
        std::vector<uint8_t> d = good;
        d[0] |= uint8_t(1 << bit);
        refused(d, "a reserved flag bit");
    }
    {
        std::vector<uint8_t> d = good;
        d[0] &= uint8_t(~FRAME_KIND);
        refused(d, "not a frame (bit 0 clear)");
    }
    {
        std::vector<uint8_t> d(good.begin(), good.begin() + 13);
        d[0] |= FRAME_ACKS;
        refused(d, "acks announced, no count");
        d.push_back(0);
        refused(d, "an ack count of 0");
    }
    {
        std::vector<uint8_t> d = good;
        d[13] = uint8_t(MAX_SPAWNED + 1);
        d.resize(14 + POSE_ACK_BYTES * size_t(MAX_SPAWNED + 1));
        refused(d, "more acks than a player has characters");
        d[13] = 4;
        d.resize(14 + POSE_ACK_BYTES * 3 + 5);
        refused(d, "acks past the end");
    }
    {
        std::vector<uint8_t> d = good;
        d.resize(MAX_DATAGRAM + 1);
        refused(d, "longer than MAX_DATAGRAM");
        d.resize(MAX_DATAGRAM);
        EXPECT_TRUE(read_frame_datagram(d, f)) << "MAX_DATAGRAM itself";
    }
    // The FlatBuffers Frame table of version 12 and before is refused as well.
    flatbuffers::FlatBufferBuilder fbb;
    auto fr = wire::CreateFrame(fbb, 7, fbb.CreateVector(payload));
    fbb.Finish(wire::CreateDatagram(fbb, 1, 0, wire::DatagramBody::Frame, fr.Union()), wire::DatagramIdentifier());
    const std::span<const uint8_t> old(fbb.GetBufferPointer(), fbb.GetSize());
    EXPECT_EQ(verify_datagram(old), nullptr);
    EXPECT_FALSE(read_frame_datagram(old, f));
}

TEST(NetFrame, ReadsMaskRunsAndRecords) {
    // Instance 0, bone 0 of show 1; instance 1, bones 3..12 of show 13 with
    // bones 3, 4, 5, 9 and 11 carried; instance 2, the same as runs.
    Hand a{.instance = 0, .show = 1, .carried = {0}};
    Hand b{.instance = 1, .first = 3, .show = 13, .epoch = 7, .carried = {3, 4, 5, 9, 11}};
    Hand c = b;
    c.instance = 2;
    c.runs = true;
    std::vector<ChunkRun> runs;
    ASSERT_TRUE(read_datagram(frame_datagram(put_payload({a, b, c})), runs));
    ASSERT_EQ(runs.size(), 7u);
    // EG0(2) = 3 bits, k = 3 in 4 bits; instance 0: 1 + 3 bits, first 1
    // bit, show 1 + 8 (not the 0 before the first chunk), epoch and flags 1
    // each (0 as before), mode 1, bitmap 1 bit.
    const size_t a_records = 3 + 4 + 4 + 1 + 9 + 1 + 1 + 1 + 1;
    EXPECT_EQ(runs[0].instance, 0);
    EXPECT_EQ(runs[0].first, 0);
    EXPECT_EQ(runs[0].offset, a_records);
    // Bones 3, 4, 5, 9 and 11 of show 13, as three runs from `at` on.
    auto expect_runs = [&](size_t at, int instance, size_t records) {
        EXPECT_EQ(runs[at].instance, instance);
        EXPECT_EQ(runs[at].first, 3);
        EXPECT_EQ(runs[at].count, 3);
        EXPECT_EQ(runs[at].offset, records);
        EXPECT_EQ(runs[at + 1].first, 9);
        EXPECT_EQ(runs[at + 1].count, 1);
        EXPECT_EQ(runs[at + 1].offset, records + 36);
        EXPECT_EQ(runs[at + 2].first, 11);
        EXPECT_EQ(runs[at + 2].offset, records + 48);
        EXPECT_EQ(runs[at + 2].show, 13);
    };
    // instance 1: 4 + 9 (first 3) + show 13 and epoch 7 in 9 bits each,
    // flags 1 (0 as before) + 1 + 10 bitmap bits after instance 0's record.
    const size_t b_records = a_records + 12 + 4 + 9 + 9 + 9 + 1 + 1 + 10;
    expect_runs(1, 1, b_records);
    // instance 2: show, epoch and flags as instance 1's (1 bit each); runs
    // EG0(3) = 5 bits, (gap 0, length - 1 = 2) 1 + 3, (2, 0) 3 + 1, (0, 0) 1 + 1: 15 bits.
    const size_t c_records = b_records + 60 + 4 + 9 + 3 + 1 + 15;
    expect_runs(4, 2, c_records);

    // The library's writer codes the same chunks in no more bits (it takes
    // the shorter mask and the best k) and they read back the same.
    std::vector<uint8_t> records;
    BitWriter w(records);
    for (int r = 0; r < 11; ++r) write_record(RecordInts{}, false, w);
    std::vector<ChunkOut> outs(3);
    outs[0].head = ChunkHead{0, 0, 1, 0, 0, {1}};
    outs[0].rec_bits = 12;
    for (int i : {1, 2}) {
        outs[size_t(i)].head = ChunkHead{uint16_t(i), 3, 13, 7, 0, {0b101000111}};
        outs[size_t(i)].rec_from = 12 + 60 * size_t(i - 1);
        outs[size_t(i)].rec_bits = 60;
    }
    HeadCodes codes;
    for (const ChunkOut& o : outs) codes.add(o.head);
    std::vector<uint8_t> pl;
    ASSERT_TRUE(write_frame_payload(outs, codes.best_order(), records.data(), nullptr, pl));
    EXPECT_LE(pl.size(), put_payload({a, b, c}).size());
    std::vector<ChunkRun> again;
    ASSERT_TRUE(read_datagram(frame_datagram(pl), again));
    ASSERT_EQ(again.size(), runs.size());
    for (size_t i = 0; i < runs.size(); ++i) {
        EXPECT_EQ(again[i].instance, runs[i].instance);
        EXPECT_EQ(again[i].first, runs[i].first);
        EXPECT_EQ(again[i].count, runs[i].count);
    }
    // The fields in their long form read the same.
    Hand c_long = c;
    c_long.long_fields = true;
    ASSERT_TRUE(read_datagram(frame_datagram(put_payload({a, b, c_long})), again));
    ASSERT_EQ(again.size(), runs.size());
    EXPECT_EQ(again[4].show, 13);
    EXPECT_EQ(again[4].offset, c_records + 24);
    // Not sorted, or an instance twice: the writer refuses.
    std::swap(outs[0], outs[1]);
    EXPECT_FALSE(write_frame_payload(outs, codes.best_order(), records.data(), nullptr, pl));
}

TEST(NetFrame, RefusesEveryMalformedChunkBeforeApplyingAny) {
    const Hand good{.instance = 0, .show = 3, .carried = {0, 2}};  // bones 0 and 2 of show 3
    std::vector<ChunkRun> runs;
    ASSERT_TRUE(read_datagram(frame_datagram(put_payload({good})), runs));
    EXPECT_EQ(runs.size(), 2u);
    auto with = [&](auto change) {
        Hand h = good;
        change(h);
        return put_payload({h});
    };
    std::vector<uint8_t> short_records = put_payload({good});
    short_records.pop_back();
    std::vector<uint8_t> trailing = put_payload({good});
    trailing.push_back(0);
    Hand unknown = good;
    unknown.instance = 9;  // after instance 0, unknown (skipped when well formed)
    std::vector<uint8_t> long_code = put_payload({Hand{.instance = 0, .show = 1, .carried = {0}, .records = 0}});
    for (int i = 0; i < 8; ++i) long_code.push_back(0);  // the record: a code whose zero prefix is too long
    struct Case {
        const char* what;
        std::vector<uint8_t> payload;
    };
    const std::vector<Case> cases = {
        {"record size differs from the instance's", with([](Hand& h) { h.flags = CHUNK_SCALED; })},
        {"linear baseline without an age", with([](Hand& h) { h.flags = CHUNK_LINEAR; })},
        {"root block past the payload", with([](Hand& h) { h.flags = CHUNK_ROOT; })},
        {"show 0", with([](Hand& h) { h.show = 0, h.carried = {}; })},
        {"first >= show", with([](Hand& h) { h.first = 3, h.carried = {}; })},
        {"first 0 in its long form", with([](Hand& h) { h.long_first = true; })},
        {"the first chunk's show as before it (0)", with([](Hand& h) { h.same_show = true; })},
        {"a run at or past show", with([](Hand& h) { h.runs = true, h.raw_runs = {{0, 0}, {1, 0}}; })},
        {"more runs than bones", with([](Hand& h) {
             h.runs = true;
             h.raw_runs = {{0, 0}, {0, 0}, {0, 0}, {0, 0}};
         })},
        {"no bone carried", with([](Hand& h) { h.carried = {}; })},
        {"records past the payload", short_records},
        {"bytes left over", trailing},
        {"more chunks than written", put_payload({good}, 3, 2)},
        {"instances not increasing", put_payload({good, good})},
        {"second chunk bad", put_payload({good, Hand{.instance = 1, .show = 3, .flags = CHUNK_SCALED, .carried = {0}}})},
        {"unknown instance's chunk malformed", put_payload({good, Hand{.instance = 9, .show = 3, .carried = {0}, .records = 0}})},
        {"padding bits not zero", put_payload({good}, 3, -1, 1)},
        {"a code past its longest prefix", long_code},
    };
    for (const Case& c : cases) {
        EXPECT_FALSE(read_datagram(frame_datagram(c.payload), runs)) << c.what;
        EXPECT_TRUE(runs.empty()) << c.what;
    }
    // The same unknown instance well formed is skipped.
    ASSERT_TRUE(read_datagram(frame_datagram(put_payload({good, unknown})), runs));
    EXPECT_EQ(runs.size(), 2u);
}

// A chunk of an instance the receiver does not know yet (announced on the
// control channel after its first frames) is walked by its flags (the
// records are self-delimiting) and skipped; the known instance's chunk after
// it still applies, its blocks found after the unknown one's.
TEST(NetFrame, SkipsChunksOfUnknownInstances) {
    const std::vector<uint8_t> root(kRootAbsoluteBytes, 0);
    Hand known{.instance = 0, .show = 1, .flags = CHUNK_ROOT, .carried = {0}, .blocks = root};
    Hand unknown{.instance = 9, .show = 2, .flags = CHUNK_SCALED | CHUNK_ROOT, .carried = {0, 1}, .scaled_records = true,
                 .blocks = root};
    std::vector<ChunkRun> runs;
    const auto d = frame_datagram(put_payload({known, unknown}, 4));
    ASSERT_TRUE(read_datagram(d, runs));
    ASSERT_EQ(runs.size(), 1u);
    EXPECT_EQ(runs[0].instance, 0);
    EXPECT_EQ(runs[0].offset, 3u + 4 + 5 + 1 + 9 + 1 + 9 + 1 + 1);  // show and flags long, epoch 0 as before
    // Its root block handed over is its own (the first of the two).
    FrameDatagram f;
    ASSERT_TRUE(read_frame_datagram(d, f));
    std::span<const uint8_t> got;
    ASSERT_TRUE(read_frame(
        f, [](uint16_t i) { return i < 3 ? 12 : 0; }, [](uint16_t, int, int, int, const RecordRun&) {},
        [&](const wire::Chunk&, uint8_t, std::span<const uint8_t> r, const uint8_t*) { got = r; }));
    EXPECT_EQ(got.data(), f.payload.data() + f.payload.size() - 2 * kRootAbsoluteBytes);
    EXPECT_EQ(got.size(), size_t(kRootAbsoluteBytes));
}

TEST(NetFrame, RandomFramesAreRefusedOrReadInBounds) {
    std::mt19937 rng(3);
    int accepted = 0;
    std::vector<ChunkRun> runs;
    for (int i = 0; i < 20000; ++i) {
        std::vector<Hand> chunks(1 + rng() % 3);
        int instance = 0;
        for (auto& c : chunks) {
            c.instance = instance += int(rng() % 3);
            c.first = int(rng() % 4);
            c.show = int(rng() % 12);
            c.flags = uint8_t(rng() % 4 | (rng() % 3 ? 0 : rng() & 0xF8));
            c.epoch = uint8_t(rng() % 3 ? 0 : rng());
            c.long_fields = rng() % 4 == 0;
            c.same_show = rng() % 8 == 0;
            c.runs = rng() % 2;
            for (int b = c.first; b < c.show; ++b)
                if (rng() % 2) c.carried.push_back(b);
            c.records = rng() % 4 ? -1 : int(rng() % 4);
            c.blocks.resize(rng() % 3 ? 0 : rng() % 30);
            for (auto& x : c.blocks) x = uint8_t(rng());
        }
        std::vector<uint8_t> pl = put_payload(chunks, int(rng() % 5));
        for (int m = int(rng() % 3); m > 0 && !pl.empty(); --m) pl[rng() % pl.size()] ^= uint8_t(1u << (rng() % 8));
        accepted += read_datagram(frame_datagram(pl), runs);  // bounds checked in read_datagram()
    }
    EXPECT_GT(accepted, 0);
}

// HeadCodes (the packer's count of a datagram's size as it fills) is exact
// whatever the order the heads join in: bits_with before an add is bits()
// after it, and the payload written at best_order() takes exactly the bits
// counted, no more than at any other order.
TEST(NetFrame, HeadCodesCountTheWrittenBitsExactly) {
    std::mt19937 rng(11);
    for (int trial = 0; trial < 2000; ++trial) {
        const int n = 1 + int(rng() % 40);
        std::vector<ChunkOut> chunks;
        std::vector<uint16_t> used;
        std::vector<uint8_t> records;
        BitWriter rw(records);
        while (int(chunks.size()) < n) {
            const uint16_t instance = uint16_t(rng() % (trial % 2 ? 60 : 4000));
            if (std::find(used.begin(), used.end(), instance) != used.end()) continue;
            used.push_back(instance);
            ChunkOut c;
            c.head.instance = instance;
            c.head.show = uint8_t(1 + rng() % (rng() % 2 ? 3 : 70));
            c.head.first = uint8_t(rng() % 3 ? 0 : rng() % c.head.show);
            c.head.epoch = uint8_t(rng() % 4 ? 1 : rng());
            c.head.flags = uint8_t(rng() % 3 ? CHUNK_ROOT : rng() % 8);  // (no baseline: identity records below)
            for (int j = 0; j < c.head.show - c.head.first; ++j)
                if (rng() % 3) c.head.carry(j);
            c.rec_from = rw.bits();
            for (int r = c.head.carried(); r > 0; --r) write_record(RecordInts{}, (c.head.flags & CHUNK_SCALED) != 0, rw);
            c.rec_bits = rw.bits() - c.rec_from;
            chunks.push_back(c);
        }
        HeadCodes codes;
        size_t rest = 0;  // first, mode bits and masks
        for (const ChunkOut& c : chunks) {
            const size_t with = codes.bits_with(c.head);
            codes.add(c.head);
            ASSERT_EQ(codes.bits(), with);
            rest += head_fixed_bits(c.head.first) + mask_bits(c.head) + c.rec_bits;
        }
        std::sort(chunks.begin(), chunks.end(), [](const ChunkOut& x, const ChunkOut& y) { return x.head.instance < y.head.instance; });
        std::vector<uint8_t> pl;
        ASSERT_TRUE(write_frame_payload(chunks, codes.best_order(), records.data(), nullptr, pl));
        ASSERT_EQ(pl.size(), (codes.bits() + rest + 7) / 8) << "trial " << trial;
        for (int k = 0; k < kInstanceOrders; k += 5) {
            std::vector<uint8_t> other;
            ASSERT_TRUE(write_frame_payload(chunks, k, records.data(), nullptr, other));
            EXPECT_GE(other.size(), pl.size());
        }
        // And it reads back head for head.
        size_t i = 0;
        ASSERT_NE(walk_chunk_heads(pl.data(), pl.size(), [&](size_t, const ChunkHead& h, size_t, size_t) {
                      const ChunkHead& w = chunks[i++].head;
                      EXPECT_EQ(h.instance, w.instance);
                      EXPECT_EQ(h.first, w.first);
                      EXPECT_EQ(h.show, w.show);
                      EXPECT_EQ(h.epoch, w.epoch);
                      EXPECT_EQ(h.flags, w.flags);
                      EXPECT_EQ(h.mask, w.mask);
                      return true;
                  }),
                  0u);
        EXPECT_EQ(i, chunks.size());
    }
}

// The packer's datagrams carry exactly the picked bones, each record
// bit-identical to the encoder's, one chunk per instance and datagram, and
// no more wire bytes than the scheduler's estimate (WireCost).
TEST(NetFrame, PackerRoundTripsPicksOverSeveralDatagrams) {
    const auto& assets = progskin::net::testing::default_assets();
    const auto specs = crowd_layout(assets, 12);
    FrameEncoder enc(assets, specs, 30.0f);
    const EncodedFrame& f = enc.encode(5);
    std::vector<Pick> picks;
    std::map<std::pair<int, int>, bool> want;
    size_t est = 0;
    for (int i = 0; i < int(specs.size()); ++i) {
        const int B = f.instances[size_t(i)].bone_count;
        est += WireCost::header(f.instances[size_t(i)]);
        // Three disjoint ranges for even instances, everything for odd ones.
        std::vector<std::pair<int, int>> ranges = i % 2 ? std::vector<std::pair<int, int>>{{0, B}}
                                                        : std::vector<std::pair<int, int>>{{0, 2}, {5, 9}, {B - 3, B}};
        for (auto [a, b] : ranges) {
            picks.push_back({i, b, B, a});
            for (int x = a; x < b; ++x) want[{i, x}] = true;
            est += (f.record_bits(i, a, b) + 7) / 8;
        }
    }
    DatagramPacker packer;
    uint32_t seq = 0;
    std::vector<std::vector<uint8_t>> out;
    const size_t wire = packer.pack(f, picks, seq, out);
    ASSERT_GE(out.size(), 2u);  // the picks do not fit one datagram
    EXPECT_LE(wire, WireCost::wire(est));
    std::map<std::pair<int, int>, int> got;
    for (const auto& d : out) {
        ASSERT_LE(d.size(), MAX_DATAGRAM);
        FrameDatagram fr;
        ASSERT_TRUE(read_frame_datagram(d, fr));
        EXPECT_EQ(fr.tick, 5u);
        std::map<int, int> chunks_of;
        ASSERT_TRUE(for_each_chunk_head(fr, [&](const ChunkHead& h) { ++chunks_of[h.instance]; }));
        for (auto [i, n] : chunks_of) EXPECT_EQ(n, 1) << "instance " << i;
        auto size_of = [&](uint16_t i) { return i < specs.size() ? f.instances[i].record_size : 0; };
        ASSERT_TRUE(read_frame(fr, size_of, [&](uint16_t i, int first, int count, int show, const RecordRun& rec) {
            EXPECT_EQ(show, f.instances[i].bone_count);
            BitReader in(rec.data, rec.bytes, rec.bit);
            for (int x = first; x < first + count; ++x) {
                ++got[{i, x}];
                const size_t n = f.record_bits(i, x, x + 1);
                BitReader want(f.relative(i), (f.bit_offset(i, x + 1) + 7) / 8, f.bit_offset(i, x));
                for (size_t k = 0; k < n; ++k) {
                    uint64_t a = 0, b = 0;
                    ASSERT_TRUE(in.get(1, a));
                    ASSERT_TRUE(want.get(1, b));
                    ASSERT_EQ(a, b) << "instance " << i << " bone " << x << " bit " << k;
                }
            }
        }));
    }
    EXPECT_EQ(got.size(), want.size());
    for (const auto& [key, n] : got) {
        EXPECT_EQ(n, 1);
        EXPECT_TRUE(want.count(key)) << key.first << " " << key.second;
    }
}

namespace {
// read_frame with on_chunk: the morph blocks handed over (count byte first).
bool read_morphs(const std::vector<uint8_t>& d, std::vector<ChunkRun>& runs, std::vector<const uint8_t*>& blocks) {
    runs.clear();
    blocks.clear();
    FrameDatagram f;
    if (!read_frame_datagram(d, f)) return false;
    return read_frame(
        f, [](uint16_t i) { return i < 3 ? 12 : 0; },
        [&](uint16_t i, int first, int count, int show, const RecordRun&) { runs.push_back({i, first, count, show, 0}); },
        [&](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t* morph) { blocks.push_back(morph); });
}
}  // namespace

// The morph block (CHUNK_MORPH): after the root block among the chunk's blocks;
// a chunk may carry weights and no bone; every malformed block is refused.
TEST(NetFrame, ReadsAndChecksMorphBlocks) {
    int16_t q = 0;
    ASSERT_TRUE(encode_morph_weight(0.75f, q));
    const uint8_t lo = uint8_t(uint16_t(q) & 0xFF), hi = uint8_t(uint16_t(q) >> 8);
    // Instance 0: root block, morph block {1: 0.75, 4: 0.75}, bone 0 of show 2.
    std::vector<uint8_t> root(kRootAbsoluteBytes, 0);
    const std::vector<uint8_t> block = {2, 1, lo, hi, 4, lo, hi};
    root.insert(root.end(), block.begin(), block.end());
    const Hand with_bone{.instance = 0, .show = 2, .flags = CHUNK_ROOT | CHUNK_MORPH, .carried = {0}, .blocks = root};
    // Instance 1: weights only (first = show - 1, an empty mask).
    const std::vector<uint8_t> only = {1, 0, lo, hi};
    const Hand weights_only{.instance = 1, .first = 1, .show = 2, .flags = CHUNK_MORPH, .blocks = only};
    const std::vector<uint8_t> both = put_payload({with_bone, weights_only});
    std::vector<ChunkRun> runs;
    std::vector<const uint8_t*> blocks;
    ASSERT_TRUE(read_morphs(frame_datagram(both), runs, blocks));
    ASSERT_EQ(runs.size(), 1u);
    EXPECT_EQ(runs[0].instance, 0);
    ASSERT_EQ(blocks.size(), 2u);
    ASSERT_NE(blocks[0], nullptr);
    EXPECT_EQ(blocks[0][0], 2);
    EXPECT_EQ(blocks[0][4], 4);
    EXPECT_FLOAT_EQ(decode_morph_weight(int16_t(uint16_t(blocks[0][5] | blocks[0][6] << 8))), 0.75f);
    ASSERT_NE(blocks[1], nullptr);
    EXPECT_EQ(blocks[1][0], 1);

    // Quantisation: 1/16384 steps over [-2, 2 - 1/16384]; outside refused, not clamped.
    EXPECT_TRUE(encode_morph_weight(-2.0f, q));
    EXPECT_EQ(q, -32768);
    EXPECT_FALSE(encode_morph_weight(2.0f, q));
    EXPECT_FALSE(encode_morph_weight(-2.001f, q));
    EXPECT_FALSE(encode_morph_weight(std::nanf(""), q));
    for (float w : {0.0f, 0.1234567f, 1.0f, -0.5f, 1.9999f}) {
        ASSERT_TRUE(encode_morph_weight(w, q));
        EXPECT_LE(std::fabs(decode_morph_weight(q) - w), 0.5f / 16384.0f + 1e-7f) << w;
    }

    auto weights = [&](std::vector<uint8_t> block, uint8_t flags = CHUNK_MORPH) {
        Hand h = weights_only;
        h.instance = 0;
        h.blocks = std::move(block);
        h.flags = flags;
        return h;
    };
    struct Case {
        const char* what;
        std::vector<uint8_t> payload;
    };
    const std::vector<uint8_t> not_increasing = {2, 3, lo, hi, 3, lo, hi};
    const std::vector<Case> cases = {
        {"morph count 0", put_payload({weights({0})})},
        {"morph indices not increasing", put_payload({weights(not_increasing)})},
        {"morph block past the payload", put_payload({weights({3, 0, lo, hi, 1, lo, hi})})},
        {"morph block without its flag", put_payload({weights(only, 0)})},
        {"neither bone nor weight", put_payload({weights({}, 0)})},
        {"good chunk, then a bad morph block", [&] {
             Hand bad = weights_only;
             bad.blocks = not_increasing;
             return put_payload({with_bone, bad});
         }()},
    };
    for (const Case& c : cases) {
        EXPECT_FALSE(read_morphs(frame_datagram(c.payload), runs, blocks)) << c.what;
        EXPECT_TRUE(runs.empty() && blocks.empty()) << c.what;
    }
}

