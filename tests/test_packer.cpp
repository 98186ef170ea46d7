// The datagram packer (server/datagram_packer.h): picks of one tick become
// frame-stream datagrams of at most MAX_DATAGRAM bytes that read back
// (proto/frame_reader.h) to exactly the picked bones, byte for byte, with
// their root and morph blocks; the wire bytes it returns are the datagrams'
// sizes plus UDP_IP_OVERHEAD each (docs/metrics.md §3). Frames from the real
// FrameEncoder on Fox and CesiumMan and tests/data/skinned_morph.gltf.
#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <map>
#include <set>
#include <vector>

#include "bone_codec.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "frame_reader.h"
#include "scheduler.h"
#include "stream_assets.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::fox_and_cesium;

namespace {

// What a receiver reads from a tick's datagrams.
struct ReadBack {
    std::map<std::pair<int, int>, std::vector<uint8_t>> records;  // (instance, bone) -> record
    std::map<std::pair<int, int>, int> copies;                    // (instance, bone) -> times carried
    std::map<int, std::set<int>> shows;                           // instance -> show values seen
    std::map<int, std::set<int>> epochs;
    std::map<int, std::vector<std::vector<uint8_t>>> roots;       // instance -> root blocks, one per chunk with one
    std::map<int, std::map<int, int16_t>> morphs;                 // instance -> morph index -> quantised weight
    std::map<int, int> morph_blocks;                              // instance -> chunks carrying a morph block
    size_t datagrams = 0, bytes = 0;
    std::set<uint32_t> seqs;
};

// Bits [from, from + n) of data, one per element.
std::vector<uint8_t> bits_of(const uint8_t* data, size_t bytes, size_t from, size_t n) {
    BitReader in(data, bytes, from);
    std::vector<uint8_t> out(n);
    for (auto& b : out) {
        uint64_t v = 0;
        EXPECT_TRUE(in.get(1, v));
        b = uint8_t(v);
    }
    return out;
}
// Bone b's record as the encoder coded it.
std::vector<uint8_t> encoded_bits(const EncodedFrame& f, int i, int b) {
    return bits_of(f.relative(i), (f.bit_offset(i, b + 1) + 7) / 8, f.bit_offset(i, b), f.record_bits(i, b, b + 1));
}

ReadBack read_back(const EncodedFrame& f, const std::vector<std::vector<uint8_t>>& out) {
    ReadBack r;
    for (const auto& d : out) {
        EXPECT_LE(d.size(), MAX_DATAGRAM);
        FrameDatagram fd;
        const bool reads = read_frame_datagram(d, fd);
        EXPECT_TRUE(reads);
        if (!reads) continue;
        const FrameDatagram* fr = &fd;
        EXPECT_EQ(fr->tick, f.tick);
        r.seqs.insert(fr->seq);
        ++r.datagrams;
        r.bytes += d.size();
        auto record_size = [&](uint16_t i) { return i < f.instances.size() ? f.instances[i].record_size : 0; };
        const bool ok = read_frame(
            *fr, record_size,
            [&](uint16_t i, int first, int count, int show, const RecordRun& rec) {
                r.shows[i].insert(show);
                BitReader in(rec.data, rec.bytes, rec.bit);
                for (int b = first; b < first + count; ++b) {
                    const size_t at = in.at();
                    EXPECT_TRUE(skip_record(in, rec.scaled, (rec.base & kBaseAgeMask) != 0));
                    r.records[{i, b}] = bits_of(rec.data, rec.bytes, at, in.at() - at);
                    ++r.copies[{i, b}];
                }
            },
            [&](const wire::Chunk& c, uint8_t, std::span<const uint8_t> root, const uint8_t* morph) {
                r.epochs[c.instance()].insert(c.epoch());
                r.shows[c.instance()].insert(c.show());
                if (!root.empty()) {  // absolute without a plan (root_block.h)
                    std::vector<uint8_t> abs(ROOT_BYTES);
                    EXPECT_TRUE(read_root(root.data(), root.size(), nullptr, nullptr, abs.data()));
                    r.roots[c.instance()].push_back(abs);
                }
                if (morph) {
                    ++r.morph_blocks[c.instance()];
                    for (int e = 0; e < morph[0]; ++e) {
                        const uint8_t* x = morph + 1 + size_t(e) * MORPH_ENTRY_BYTES;
                        r.morphs[c.instance()][x[0]] = int16_t(uint16_t(x[1] | (x[2] << 8)));
                    }
                }
            });
        EXPECT_TRUE(ok) << "a packed frame the reader refuses";
    }
    return r;
}

// Checks a packing against its picks: exactly the picked bones, each once
// and byte-identical to the encoder's record, the picks' show per instance,
// the frame's epoch, the datagrams' sizes summing to the returned wire bytes,
// one sequence number per datagram.
void expect_exact(const EncodedFrame& f, const std::vector<Pick>& picks, const std::vector<std::vector<uint8_t>>& out,
                  size_t wire, uint32_t seq_before, uint32_t seq_after) {
    const ReadBack r = read_back(f, out);
    std::set<std::pair<int, int>> want;
    std::map<int, int> show;
    for (const Pick& p : picks) {
        for (int b = p.first; b < p.k; ++b) want.insert({p.instance, b});
        show[p.instance] = std::max(show[p.instance], std::max(p.show, p.k));
    }
    EXPECT_EQ(r.records.size(), want.size());
    for (const auto& key : want) {
        const auto it = r.records.find(key);
        ASSERT_NE(it, r.records.end()) << "instance " << key.first << " bone " << key.second << " missing";
        EXPECT_EQ(it->second, encoded_bits(f, key.first, key.second)) << "instance " << key.first << " bone " << key.second;
        EXPECT_EQ(r.copies.at(key), 1) << "instance " << key.first << " bone " << key.second << " carried twice";
    }
    for (const auto& [i, s] : r.shows) {
        EXPECT_EQ(s, std::set<int>{show[i]}) << "instance " << i;
        EXPECT_EQ(r.epochs.at(i), std::set<int>{f.instances[size_t(i)].epoch}) << "instance " << i;
    }
    EXPECT_EQ(r.datagrams, out.size());
    EXPECT_EQ(wire, r.bytes + out.size() * UDP_IP_OVERHEAD);
    EXPECT_EQ(seq_after - seq_before, uint32_t(out.size()));
    EXPECT_EQ(r.seqs.size(), out.size());
}

struct Scene {
    std::vector<std::shared_ptr<ServerAsset>> assets = fox_and_cesium();
    std::vector<InstanceSpec> specs;
    FrameEncoder enc;
    explicit Scene(int n) : specs(crowd_layout(assets, n)), enc(assets, specs, 30.0f) {}
};

}  // namespace

TEST(Packer, NothingPickedSendsNothing) {
    Scene s(3);
    const EncodedFrame& f = s.enc.encode(1);
    DatagramPacker packer;
    uint32_t seq = 5;
    std::vector<std::vector<uint8_t>> out;
    EXPECT_EQ(packer.pack(f, {}, seq, out), 0u);
    EXPECT_TRUE(out.empty());
    EXPECT_EQ(seq, 5u);
}

// Every bone of 24 characters (about 7 kB of records): several datagrams,
// each within MAX_DATAGRAM, the chunks split across them with Chunk.first.
TEST(Packer, EverythingReadsBackExactlyOverManyDatagrams) {
    Scene s(24);
    const EncodedFrame& f = s.enc.encode(17);
    std::vector<Pick> picks;
    size_t payload = 0;
    for (int i = 0; i < int(s.specs.size()); ++i) {
        const EncodedInstance& e = f.instances[size_t(i)];
        picks.push_back({i, e.bone_count, e.bone_count, 0});
        payload += WireCost::header(e) + (f.record_bits(i, 0, e.bone_count) + 7) / 8;
    }
    DatagramPacker packer;
    uint32_t seq = 100;
    std::vector<std::vector<uint8_t>> out;
    const size_t wire = packer.pack(f, picks, seq, out);
    EXPECT_GE(out.size(), payload / MAX_DATAGRAM + 1);
    expect_exact(f, picks, out, wire, 100, seq);
    EXPECT_LE(wire, WireCost::wire(payload));  // the scheduler's estimate bounds the packing
    for (size_t x = 0; x + 1 < out.size(); ++x)
        EXPECT_GT(out[x].size(), MAX_DATAGRAM - 100) << "datagram " << x << " not filled before the next starts";
}

// Several disjoint ranges per instance (what the scheduler picks under a
// tight budget: refreshes of shown segments and new ones), show past them.
TEST(Packer, DisjointRangesReadBackWithTheirShow) {
    Scene s(6);
    const EncodedFrame& f = s.enc.encode(3);
    std::vector<Pick> picks;
    for (int i = 0; i < int(s.specs.size()); ++i) {
        const int B = f.instances[size_t(i)].bone_count;
        if (i % 3 == 0) {
            picks.push_back({i, 1, B - 2, 0});
            picks.push_back({i, 7, B - 2, 4});
            picks.push_back({i, B - 2, B - 2, B - 4});
        } else if (i % 3 == 1) {
            picks.push_back({i, B / 2, 0, 0});  // show 0: the carried prefix
        } else {
            picks.push_back({i, B, B, B - 1});  // the last bone alone
        }
    }
    DatagramPacker packer;
    uint32_t seq = 0;
    std::vector<std::vector<uint8_t>> out;
    const size_t wire = packer.pack(f, picks, seq, out);
    expect_exact(f, picks, out, wire, 0, seq);
}

// The scheduler's own picks at budgets from one datagram to many, over ticks:
// always within MAX_DATAGRAM, exact, and within the scheduler's estimate.
TEST(Packer, SchedulerPicksReadBackExactly) {
    Scene s(16);
    const std::vector<float> imp = compute_importance(ViewSpec{}, s.specs, s.assets);
    for (size_t budget : {300u, 1200u, 2600u, 9000u}) {
        SCOPED_TRACE(budget);
        Scheduler sched;
        DatagramPacker packer;
        uint32_t seq = 0;
        for (uint32_t t = 1; t <= 30; ++t) {
            const EncodedFrame& f = s.enc.encode(t);
            std::vector<Pick> picks;
            const size_t est = sched.select(f, s.assets, imp, budget, 30.0f, picks);
            std::vector<std::vector<uint8_t>> out;
            const uint32_t before = seq;
            const size_t wire = packer.pack(f, picks, seq, out);
            expect_exact(f, picks, out, wire, before, seq);
            EXPECT_LE(wire, est) << "tick " << t;
            sched.sent(picks, t);
        }
    }
}

// A placed instance's chunks each carry its root block (also the
// continuation of a split chunk); others carry none.
TEST(Packer, RootBlockTravelsWithEveryChunkOfAPlacedInstance) {
    Scene s(12);
    RootPose root;
    root.position = glm::dvec3(1.5, -2.0, 30.25);
    root.rotation = glm::angleAxis(0.7f, glm::normalize(glm::vec3(0.2f, 1.0f, 0.1f)));
    root.source_us = 123456789;
    ASSERT_TRUE(s.enc.set_root(5, root, false));
    const EncodedFrame& f = s.enc.encode(9);
    ASSERT_TRUE(f.instances[5].flags & CHUNK_ROOT);
    std::vector<Pick> picks;
    for (int i = 0; i < int(s.specs.size()); ++i) picks.push_back({i, f.instances[size_t(i)].bone_count, 0, 0});
    DatagramPacker packer;
    uint32_t seq = 0;
    std::vector<std::vector<uint8_t>> out;
    const size_t wire = packer.pack(f, picks, seq, out);
    expect_exact(f, picks, out, wire, 0, seq);
    const ReadBack r = read_back(f, out);
    ASSERT_EQ(r.roots.size(), 1u);
    ASSERT_EQ(r.roots.count(5), 1u);
    std::array<uint8_t, ROOT_BYTES> want{};
    ASSERT_TRUE(encode_root(root, want.data()));
    for (const auto& block : r.roots.at(5)) EXPECT_EQ(0, std::memcmp(block.data(), want.data(), ROOT_BYTES));
    const RootPose back = decode_root(r.roots.at(5)[0].data());
    EXPECT_NEAR(glm::length(back.position - root.position), 0.0, 1e-3);  // millimetres
    EXPECT_EQ(back.source_us, root.source_us);
}

// Morph weights: the picks' mask goes in the instance's first chunk, with
// the encoder's quantised values; a pick with no bone (k <= first) sends
// its weights in a chunk of their own; weights the encoder refused (kNoWeight)
// are left out.
TEST(Packer, MorphBlocksCarryThePickedWeights) {
    const std::vector<std::shared_ptr<ServerAsset>> assets = {progskin::net::testing::skinned_morph_asset()};
    InstanceSpec spec;
    spec.selection = progskin::net::testing::selection_of_clip(*assets[0], "talk");
    ASSERT_GE(spec.selection, 0);
    FrameEncoder enc(assets, {spec, spec, spec}, 30.0f);
    EncodedFrame f = enc.encode(20);  // a copy: one weight is refused below
    const int B = f.instances[0].bone_count;
    const auto q = f.morphs(0);
    ASSERT_EQ(q.size(), 4u);
    for (int32_t v : q) ASSERT_NE(v, kNoWeight);
    std::vector<Pick> picks;
    Pick a{0, B, B, 0};
    a.morphs[0] = 0b1011;  // weights 0, 1, 3 with every bone
    Pick b{1, 0, B, 0};
    b.morphs[0] = 0b0100;  // weight 2 alone, no bone
    Pick c{2, 2, B, 0};
    c.morphs[0] = 0b0011;  // weight 1 refused by the encoder: only 0 goes
    f.morph[f.instances[2].morph_offset + 1] = kNoWeight;
    picks = {a, b, c};
    DatagramPacker packer;
    uint32_t seq = 0;
    std::vector<std::vector<uint8_t>> out;
    const size_t wire = packer.pack(f, picks, seq, out);
    expect_exact(f, picks, out, wire, 0, seq);
    const ReadBack r = read_back(f, out);
    auto weights_of = [&](int i, std::initializer_list<int> ms) {
        std::map<int, int16_t> w;
        for (int m : ms) w[m] = int16_t(f.morphs(i)[size_t(m)]);
        return w;
    };
    EXPECT_EQ(r.morphs.at(0), weights_of(0, {0, 1, 3}));
    EXPECT_EQ(r.morphs.at(1), weights_of(1, {2}));
    EXPECT_EQ(r.morphs.at(2), weights_of(2, {0}));
    for (int i = 0; i < 3; ++i) EXPECT_EQ(r.morph_blocks.at(i), 1) << "one morph block per instance and tick";
    EXPECT_EQ(r.records.count({1, 0}), 0u);  // the weights-only chunk carries no bone
    // Morph blocks are counted in the wire bytes like any payload.
    size_t payload = 0;
    for (const Pick& p : picks)
        payload += WireCost::header(B) + size_t(std::max(0, p.k - p.first)) * 12 + morph_block_bytes(p.morphs);
    EXPECT_LE(wire, WireCost::wire(payload));
}
