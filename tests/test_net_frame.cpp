// The Frame layout of protocol version 5 (proto/frame_reader.h): what the
// packer writes reads back bone for bone, bit for bit, and every malformed
// chunk is refused before anything is applied.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <random>

#include "datagram_packer.h"
#include "frame_encoder.h"
#include "frame_reader.h"
#include "net_test_support.h"
#include "scene.h"
#include "scheduler.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;

namespace {

// A Datagram with one Frame of the given chunks and payload bytes.
std::vector<uint8_t> frame_datagram(const std::vector<wire::Chunk>& chunks, const std::vector<uint8_t>& payload) {
    flatbuffers::FlatBufferBuilder fbb;
    auto ch = fbb.CreateVectorOfStructs(chunks.data(), chunks.size());
    auto pl = fbb.CreateVector(payload.data(), payload.size());
    auto fr = wire::CreateFrame(fbb, 7, ch, pl);
    fbb.Finish(wire::CreateDatagram(fbb, 1, 0, wire::DatagramBody::Frame, fr.Union()), wire::DatagramIdentifier());
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

// A chunk without root block or baseline.
wire::Chunk ch(int instance, int first, int show, uint8_t flags = 0, uint8_t epoch = 0) {
    return wire::Chunk(uint16_t(instance), uint8_t(first), uint8_t(show), epoch, flags);
}

// n records of the identity (bone_record.h: 12 bits each, 13 scaled), padded to a byte.
std::vector<uint8_t> identity_records(int n, bool scaled = false) {
    std::vector<uint8_t> out;
    BitWriter w(out);
    for (int k = 0; k < n; ++k) write_record(RecordInts{}, scaled, w);
    return out;
}
void append(std::vector<uint8_t>& to, const std::vector<uint8_t>& more) { to.insert(to.end(), more.begin(), more.end()); }

struct ChunkRun {
    int instance, first, count, show;
    size_t offset;  // of the run's first record in the payload, bits
};

// read_frame over a datagram, instances 0..2 known with 12-byte records.
bool read_datagram(const std::vector<uint8_t>& d, std::vector<ChunkRun>& runs) {
    runs.clear();
    const wire::Datagram* g = verify_datagram(d);
    if (!g || !g->body_as_Frame()) return false;
    const wire::Frame& f = *g->body_as_Frame();
    const uint8_t* base = f.payload() ? f.payload()->data() : nullptr;
    const size_t size = f.payload() ? f.payload()->size() : 0;
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

TEST(NetFrame, ReadsMaskRunsAndRecords) {
    // Instance 1, bones 3..12 of show 13 with bones 3,4,5, 9, 11 carried;
    // instance 0, bone 0 of show 1.
    // Mask over bones 3..12 (10 bits, 2 bytes): bones 3,4,5 -> bits 0,1,2;
    // bone 9 -> bit 6; bone 11 -> bit 8.
    // Records: 12 bits each (the identity), 5 of them in 8 bytes.
    std::vector<uint8_t> pl = {0b01000111, 0b00000001};
    append(pl, identity_records(5));
    pl.push_back(0b1);
    append(pl, identity_records(1));
    std::vector<ChunkRun> runs;
    ASSERT_TRUE(read_datagram(frame_datagram({ch(1, 3, 13), ch(0, 0, 1)}, pl), runs));
    ASSERT_EQ(runs.size(), 4u);
    EXPECT_EQ(runs[0].first, 3);
    EXPECT_EQ(runs[0].count, 3);
    EXPECT_EQ(runs[0].offset, 16u);
    EXPECT_EQ(runs[1].first, 9);
    EXPECT_EQ(runs[1].count, 1);
    EXPECT_EQ(runs[1].offset, 16u + 36);
    EXPECT_EQ(runs[2].first, 11);
    EXPECT_EQ(runs[2].offset, 16u + 48);
    EXPECT_EQ(runs[2].show, 13);
    EXPECT_EQ(runs[3].instance, 0);
    EXPECT_EQ(runs[3].first, 0);
    EXPECT_EQ(runs[3].offset, (2u + 8 + 1) * 8);
}

TEST(NetFrame, RefusesEveryMalformedChunkBeforeApplyingAny) {
    std::vector<uint8_t> good = {0b00000101};  // bones 0 and 2 of show 3
    append(good, identity_records(2));            // 24 bits
    std::vector<ChunkRun> runs;
    ASSERT_TRUE(read_datagram(frame_datagram({ch(0, 0, 3)}, good), runs));
    EXPECT_EQ(runs.size(), 2u);

    struct Case {
        const char* what;
        std::vector<wire::Chunk> chunks;
        std::vector<uint8_t> payload;
    };
    std::vector<uint8_t> bits_past_show = good;
    bits_past_show[0] |= 0b1000;  // bone 3 with show 3
    std::vector<uint8_t> empty_mask = good;
    empty_mask[0] = 0;
    std::vector<uint8_t> short_records(good.begin(), good.end() - 1);
    std::vector<uint8_t> trailing = good;
    trailing.push_back(0);
    std::vector<uint8_t> two = good;  // a good chunk, then a bad one: nothing applied
    two.insert(two.end(), good.begin(), good.end());
    std::vector<uint8_t> padding = {0b00000001};  // bone 0: 12 bits, then 4 padding bits not zero
    append(padding, identity_records(1));
    padding.back() |= 0x80;
    std::vector<uint8_t> long_code = {0b00000001, 0, 0, 0, 0, 0, 0, 0};  // a code whose zero prefix is too long
    const std::vector<Case> cases = {
        {"record size differs from the instance's", {ch(0, 0, 3, CHUNK_SCALED)}, good},
        {"linear baseline without an age", {ch(0, 0, 3, CHUNK_LINEAR)}, good},
        {"root block past the payload", {ch(0, 0, 3, CHUNK_ROOT)}, good},
        {"show 0", {ch(0, 0, 0)}, good},
        {"first >= show", {ch(0, 3, 3)}, good},
        {"mask bits at or past show", {ch(0, 0, 3)}, bits_past_show},
        {"no bone carried", {ch(0, 0, 3)}, empty_mask},
        {"records past the payload", {ch(0, 0, 3)}, short_records},
        {"bytes left over", {ch(0, 0, 3)}, trailing},
        {"mask past the payload", {ch(0, 0, 200)}, {}},
        {"second chunk bad", {ch(0, 0, 3), ch(0, 0, 3, CHUNK_SCALED)}, two},
        {"unknown instance's chunk malformed", {ch(9, 0, 3), ch(0, 0, 3)}, trailing},
        {"chunks without payload", {ch(0, 0, 3)}, {}},
        {"padding bits not zero", {ch(0, 0, 1)}, padding},
        {"a code past its longest prefix", {ch(0, 0, 1)}, long_code},
    };
    for (const Case& c : cases) {
        EXPECT_FALSE(read_datagram(frame_datagram(c.chunks, c.payload), runs)) << c.what;
        EXPECT_TRUE(runs.empty()) << c.what;
    }
}

// A chunk of an instance the receiver does not know yet (announced on the
// control channel after its first frames) is walked by its flags (the
// records are self-delimiting) and skipped; the known instance's chunk after
// it still applies.
TEST(NetFrame, SkipsChunksOfUnknownInstances) {
    std::vector<uint8_t> pl = {0b00000011};  // unknown instance 9: bones 0, 1 of scaled records (26 bits, 4 bytes)
    append(pl, identity_records(2, true));
    ASSERT_EQ(pl.size(), 5u);
    const std::vector<uint8_t> root(kRootAbsoluteBytes, 0);
    pl.insert(pl.end(), root.begin(), root.end());  // instance 0: root block, bone 0 of show 1
    pl.push_back(0b1);
    append(pl, identity_records(1));
    std::vector<ChunkRun> runs;
    ASSERT_TRUE(read_datagram(frame_datagram({ch(9, 0, 2, CHUNK_SCALED), ch(0, 0, 1, CHUNK_ROOT)}, pl), runs));
    ASSERT_EQ(runs.size(), 1u);
    EXPECT_EQ(runs[0].instance, 0);
    EXPECT_EQ(runs[0].offset, (5u + kRootAbsoluteBytes + 1) * 8);
}

TEST(NetFrame, RandomFramesAreRefusedOrReadInBounds) {
    std::mt19937 rng(3);
    int accepted = 0;
    std::vector<ChunkRun> runs;
    for (int i = 0; i < 20000; ++i) {
        std::vector<wire::Chunk> chunks(rng() % 4);
        for (auto& c : chunks) c = ch(int(rng() % 4), int(rng() % 8), int(rng() % 24), uint8_t(rng() % 4 | (rng() % 3 ? 0 : rng() & 0xF8)));
        std::vector<uint8_t> pl(rng() % 80);
        for (auto& b : pl) b = uint8_t(rng() % 3 ? rng() % 4 : rng());
        accepted += read_datagram(frame_datagram(chunks, pl), runs);  // bounds checked in read_datagram()
    }
    EXPECT_GT(accepted, 0);
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
        const wire::Datagram* g = verify_datagram(d);
        ASSERT_NE(g, nullptr);
        const wire::Frame& fr = *g->body_as_Frame();
        EXPECT_EQ(fr.tick(), 5u);
        std::map<int, int> chunks_of;
        for (const wire::Chunk* c : *fr.chunks()) ++chunks_of[c->instance()];
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
    const wire::Datagram* g = verify_datagram(d);
    if (!g || !g->body_as_Frame()) return false;
    return read_frame(
        *g->body_as_Frame(), [](uint16_t i) { return i < 3 ? 12 : 0; },
        [&](uint16_t i, int first, int count, int show, const RecordRun&) { runs.push_back({i, first, count, show, 0}); },
        [&](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t* morph) { blocks.push_back(morph); });
}
}  // namespace

// The morph block (CHUNK_MORPH): after the root block, before the mask;
// a chunk may carry weights and no bone; every malformed block is refused.
TEST(NetFrame, ReadsAndChecksMorphBlocks) {
    int16_t q = 0;
    ASSERT_TRUE(encode_morph_weight(0.75f, q));
    const uint8_t lo = uint8_t(uint16_t(q) & 0xFF), hi = uint8_t(uint16_t(q) >> 8);
    // Instance 0: root block, morph block {1: 0.75, 4: 0.75}, bone 0 of show 2.
    std::vector<uint8_t> pl(kRootAbsoluteBytes, 0);
    const std::vector<uint8_t> block = {2, 1, lo, hi, 4, lo, hi};
    pl.insert(pl.end(), block.begin(), block.end());
    pl.push_back(0b01);
    append(pl, identity_records(1));
    // Instance 1: weights only (first = show - 1, an empty mask).
    const std::vector<uint8_t> only = {1, 0, lo, hi, 0b0};
    std::vector<uint8_t> both = pl;
    both.insert(both.end(), only.begin(), only.end());
    std::vector<ChunkRun> runs;
    std::vector<const uint8_t*> blocks;
    ASSERT_TRUE(read_morphs(frame_datagram({ch(0, 0, 2, CHUNK_ROOT | CHUNK_MORPH), ch(1, 1, 2, CHUNK_MORPH)}, both), runs, blocks));
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

    std::vector<uint8_t> n0 = only;
    n0[0] = 0;
    n0.erase(n0.begin() + 1, n0.begin() + 4);
    std::vector<uint8_t> not_increasing = {2, 3, lo, hi, 3, lo, hi, 0b0};
    std::vector<uint8_t> past_payload = {3, 0, lo, hi, 1, lo, hi};
    std::vector<uint8_t> no_flag = only;
    std::vector<uint8_t> empty_no_morph = {0b0};
    struct Case {
        const char* what;
        std::vector<wire::Chunk> chunks;
        std::vector<uint8_t> payload;
    };
    const std::vector<Case> cases = {
        {"morph count 0", {ch(0, 1, 2, CHUNK_MORPH)}, n0},
        {"morph indices not increasing", {ch(0, 1, 2, CHUNK_MORPH)}, not_increasing},
        {"morph block past the payload", {ch(0, 1, 2, CHUNK_MORPH)}, past_payload},
        {"morph block without its flag", {ch(0, 1, 2)}, no_flag},
        {"neither bone nor weight", {ch(0, 1, 2)}, empty_no_morph},
        {"good chunk, then a bad morph block", {ch(0, 0, 2, CHUNK_ROOT | CHUNK_MORPH), ch(1, 1, 2, CHUNK_MORPH)},
         [&] {
             std::vector<uint8_t> x = pl;
             x.insert(x.end(), not_increasing.begin(), not_increasing.end());
             return x;
         }()},
    };
    for (const Case& c : cases) {
        EXPECT_FALSE(read_morphs(frame_datagram(c.chunks, c.payload), runs, blocks)) << c.what;
        EXPECT_TRUE(runs.empty() && blocks.empty()) << c.what;
    }
}

