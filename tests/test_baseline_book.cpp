// The server's record of what one client acknowledged (server/baseline_book.h):
// only bones of acknowledged datagrams become baselines, a lost datagram
// never does, a new occupant of an id starts empty, the first ticks after a
// character's first acknowledgement are a grace; and the plan built from it
// predicts exactly those bones, at the bits the packer then writes.
#include <gtest/gtest.h>

#include <set>

#include "baseline_book.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "frame_reader.h"
#include "net_test_support.h"
#include "pose_buffer.h"
#include "scene.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::frame_of;

TEST(BaselineBook, OnlyAcknowledgedBonesBecomeBaselines) {
    BaselineBook book;
    const uint32_t g = 7;
    // Datagram seq s carries bones 0..9 of instance 3 at tick 100 + s.
    for (uint32_t s = 0; s < 40; ++s) book.carried(s, 100 + s, 3, g, 0, 10);
    // Acks for everything but seq 30 (lost) and 39 (not acked yet).
    book.on_ack(38, ~(1u << 7));  // bit 7: 38 - 1 - 7 = 30
    uint32_t newest = 0;
    ASSERT_TRUE(book.newest(3, g, newest));
    EXPECT_EQ(newest, 138u);
    EXPECT_TRUE(book.acked(3, g, 0, 138));
    EXPECT_TRUE(book.acked(3, g, 9, 137));
    EXPECT_FALSE(book.acked(3, g, 10, 138)) << "a bone not carried";
    EXPECT_FALSE(book.acked(3, g, 0, 130)) << "a lost datagram";
    EXPECT_FALSE(book.acked(3, g, 0, 139)) << "not acknowledged yet";
    EXPECT_FALSE(book.acked(3, g + 1, 0, 138)) << "another occupant of the id";
    EXPECT_FALSE(book.acked(4, g, 0, 138)) << "another instance";
    // Grace: ticks within kGraceTicks of the first acknowledged one are not baselines.
    EXPECT_FALSE(book.acked(3, g, 0, 100 + BaselineBook::kGraceTicks - 1));
    // A new occupant of the id: its first ack starts over (and is in its grace).
    book.carried(40, 140, 3, g + 1, 0, 4);
    book.on_ack(40, 0);
    EXPECT_FALSE(book.newest(3, g, newest));
    EXPECT_FALSE(book.newest(3, g + 1, newest)) << "within the grace";
    EXPECT_FALSE(book.acked(3, g, 0, 138));
    // A late ack of the earlier occupant changes nothing.
    book.carried(41, 141, 3, g, 0, 4);
    book.on_ack(41, 0);
    EXPECT_FALSE(book.acked(3, g, 0, 141));
}

// Loss (BaselineBook::on_ack's `lost`): a datagram left out of an Ack that
// acknowledges a newer one is lost once kLossReorder datagrams followed it,
// or once it was sent loss_delay before the Ack (reordering explains
// neither); each is reported once, and a late acknowledgement still makes
// its bones baselines.
TEST(BaselineBook, LostDatagramsAreReportedOnceByCountOrByTime) {
    BaselineBook book;
    const uint32_t g = 7;
    book.carried(0, 100, 3, g, 0, 10);  // the first acknowledged tick (the grace starts there)
    book.on_ack(0, 0);
    // Datagram s (1..9) carries bones 0..9 of instance 3 at tick 120 + s, sent at 10 ms x s.
    for (uint32_t s = 1; s < 10; ++s) {
        book.carried(s, 120 + s, 3, g, 0, 10);
        if (s == 2) book.carried_morphs(s, 120 + s, 3, g);  // and its morph block
        book.sent_at(s, 10000 * s);
    }
    std::vector<BaselineBook::LostRun> lost;
    // At 55 ms: 5 arrived, 4 and 2 did not. 2 is three before 5 (count);
    // 4, one before and sent 15 ms ago, may still come (loss delay 30 ms).
    book.on_ack(5, ~((1u << 0) | (1u << 2)), &lost, 55000, 30000);
    ASSERT_EQ(lost.size(), 2u);
    EXPECT_EQ(lost[0].tick, 122u);
    EXPECT_EQ(lost[0].instance, 3);
    EXPECT_EQ(lost[0].generation, g);
    EXPECT_EQ(lost[0].first, 0);
    EXPECT_EQ(lost[0].count, 10);
    EXPECT_FALSE(lost[0].morphs);
    EXPECT_TRUE(lost[1].morphs);  // the morph block, with the tick's bones
    EXPECT_EQ(lost[1].tick, 122u);
    EXPECT_EQ(lost[1].count, 0);
    // At 80 ms: 6 arrived, 4 still not: sent 40 ms ago, lost by time; 2 not again.
    lost.clear();
    book.on_ack(6, ~((1u << 1) | (1u << 3)), &lost, 80000, 30000);
    ASSERT_EQ(lost.size(), 1u);
    EXPECT_EQ(lost[0].tick, 124u);
    // Without a time (loss_delay 0) only the count: 7 left out behind 8 is
    // not lost (4 and 2, still left out, were reported already).
    lost.clear();
    book.on_ack(8, ~((1u << 0) | (1u << 3) | (1u << 5)), &lost, 200000, 0);
    EXPECT_TRUE(lost.empty());
    // A late acknowledgement of 4 still makes its bones baselines.
    EXPECT_FALSE(book.acked(3, g, 0, 124));
    book.on_ack(4, 0, &lost, 210000, 30000);
    EXPECT_TRUE(book.acked(3, g, 0, 124));
    EXPECT_FALSE(book.acked(3, g, 0, 122));
    // No `lost`: nothing reported, acknowledgements as before.
    book.on_ack(9, 0);
    EXPECT_TRUE(book.acked(3, g, 0, 129));
}

TEST(BaselineBook, PlanPredictsAcknowledgedBonesAndThePackerWritesThem) {
    const auto& assets = progskin::net::testing::default_assets();
    std::vector<InstanceSpec> specs(1);
    FrameEncoder enc(assets, specs, 30.0f);
    BaselineBook book;
    RecordPlan plan;
    DatagramPacker packer;
    uint32_t seq = 0;
    const int B = assets[0]->bone_count();
    std::vector<std::vector<uint8_t>> out;
    size_t standalone_bits = 0, planned_bits = 0;
    for (uint32_t t = 1; t <= 40; ++t) {
        const EncodedFrame& f = enc.encode(t);
        plan.begin(f);
        plan.plan(f, 0, book);
        const Pick all{0, B, B, 0};
        out.clear();
        const uint32_t first = seq;
        packer.pack(f, std::span(&all, 1), seq, out, &plan, &book);
        if (t > 20) {
            standalone_bits += f.record_bits(0, 0, B);
            planned_bits += plan.bits(f, 0, 0, B);
            EXPECT_NE(plan.base(0), 0) << "tick " << t << ": acknowledged every tick, past the grace";
            EXPECT_EQ(plan.base(0) & kBaseAgeMask, 1) << "acknowledged at once: the previous tick";
        }
        // Every datagram reads back; the chunk's base is the plan's.
        for (const auto& d : out) {
            const std::optional<FrameDatagram> fr = frame_of(d);
            ASSERT_TRUE(fr);
            EXPECT_TRUE(for_each_chunk_head(*fr, [&](const ChunkHead& h) { EXPECT_EQ(base_from_flags(h.flags), plan.base(0)); }));
            EXPECT_TRUE(read_frame(*fr, [&](uint16_t) { return assets[0]->format.size(); },
                                   [](uint16_t, int, int, int, const RecordRun&) {}));
        }
        book.on_ack(seq - 1, seq - first >= 2 ? ~0u : 0u);  // the client acknowledges at once
    }
    std::printf("Fox clip, every bone every tick: %.1f bits per bone standalone, %.1f predicted\n",
                double(standalone_bits) / (20.0 * B), double(planned_bits) / (20.0 * B));
    EXPECT_LT(planned_bits, standalone_bits * 9 / 10);
}

// Deep bones refreshed every fourth tick, shallow ones every tick, every
// datagram acknowledged at once: the deep bones go predicted from their own
// baselines (not standalone), and a client's pose buffer decodes every record
// to exactly the encoder's integers, none from a baseline it lacks.
// The same with key samples (FrameEncoder::set_key_samples): the linear
// predictions run along the samples' times (sample_age), the client's as
// the server's.
TEST(BaselineBook, PartialRefreshesPredictFromTheirOwnBaselinesAndDecodeExactly) {
  for (bool keyed : {false, true}) {
    SCOPED_TRACE(keyed ? "key samples" : "tick samples");
    const auto& assets = progskin::net::testing::default_assets();
    std::vector<InstanceSpec> specs(1);
    FrameEncoder enc(assets, specs, 30.0f);
    enc.set_key_samples(keyed);
    const ServerAsset& a = *assets[0];
    const int B = a.bone_count(), shallow = 10;
    BaselineBook book;
    RecordPlan plan;
    DatagramPacker packer;
    PoseBuffer client(a.relative);
    uint32_t seq = 0;
    uint64_t own = 0, standalone_deep = 0;
    std::vector<std::vector<uint8_t>> out;
    for (uint32_t t = 1; t <= 60; ++t) {
        const EncodedFrame& f = enc.encode(t);
        plan.begin(f);
        plan.plan(f, 0, book);
        const bool deep = t % 4 == 0;
        const Pick pick{0, deep ? B : shallow, B, 0};
        if (t > 30 && deep)
            for (int b = shallow; b < B; ++b) {
                own += plan.prefix(0, b).kind == RecordPrefix::Own;
                standalone_deep += plan.prefix(0, b).kind == RecordPrefix::Standalone;
            }
        out.clear();
        packer.pack(f, std::span(&pick, 1), seq, out, &plan, &book);
        for (const auto& d : out) {
            const std::optional<FrameDatagram> fr = frame_of(d);
            ASSERT_TRUE(fr);
            uint8_t sample = 0, epoch = 0;
            ASSERT_TRUE(read_frame(
                *fr, [&](uint16_t) { return a.format.size(); },
                [&](uint16_t, int first, int count, int show, const RecordRun& rec) {
                    ASSERT_TRUE(client.add_chunk(t, first, count, show, rec, show, epoch, {}, sample));
                },
                [&](const wire::Chunk& c, uint8_t s, std::span<const uint8_t>, const uint8_t*) {
                    sample = s;
                    epoch = c.epoch();
                }));
            if (keyed) {
                EXPECT_EQ(sample, f.instances[0].sample);
                EXPECT_GE(sample, 1);
            }
        }
        book.on_ack(seq - 1, ~0u);
        // Every bone this tick decodes to the encoder's integers (pose() at
        // the tick is the frame's own: the newest, held past its sample).
        for (int b = 0; b < pick.k; ++b) {
            BonePose got;
            ASSERT_TRUE(client.pose(b, double(t), got));
            const BonePose want = dequantise_record(f.ints[size_t(b)], b, a.relative);
            ASSERT_LT(glm::length(got.t - want.t), 1e-4f * float(a.diagonal)) << "tick " << t << " bone " << b;
        }
    }
    EXPECT_EQ(client.missing_baselines(), 0u);
    EXPECT_GT(client.predicted(), 0u);
    std::printf("deep bones at their refresh: %llu from their own baseline, %llu standalone\n", (unsigned long long)own,
                (unsigned long long)standalone_deep);
    EXPECT_GT(own, standalone_deep);
  }
}

// A walking character's root block: predicted from the ticks the client
// acknowledged once past the grace, a few bytes instead of 27; with every
// third datagram lost (neither received nor acknowledged) the client decodes
// every root it receives to the encoder's very block and never lacks a
// baseline, and the scheduler's header counts the root at its planned size.
TEST(BaselineBook, RootBlocksArePredictedFromAcknowledgedTicksOnly) {
    const auto& assets = progskin::net::testing::default_assets();
    std::vector<InstanceSpec> specs(1);
    FrameEncoder enc(assets, specs, 30.0f);
    const ServerAsset& a = *assets[0];
    const int B = a.bone_count();
    BaselineBook book;
    RecordPlan plan;
    DatagramPacker packer;
    PoseBuffer client(a.relative);
    uint32_t seq = 0;
    size_t root_bytes = 0, roots = 0, received = 0;
    std::vector<std::vector<uint8_t>> out;
    for (uint32_t t = 1; t <= 90; ++t) {
        RootPose r;
        r.position = {3.0 * std::cos(0.05 * t), 0.0, 3.0 * std::sin(0.05 * t)};
        r.rotation = glm::angleAxis(-0.05f * float(t), glm::vec3(0, 1, 0));
        r.source_us = 1'000'000 + uint64_t(t) * 33'333 + (t % 5) * 900;
        ASSERT_TRUE(enc.set_root(0, r, false));
        const EncodedFrame& f = enc.encode(t);
        plan.begin(f);
        plan.plan(f, 0, book);
        const Pick pick{0, B, B, 0};
        out.clear();
        packer.pack(f, std::span(&pick, 1), seq, out, &plan, &book);
        if (t > 30) {
            root_bytes += plan.root_bytes(f, 0);
            ++roots;
        }
        if (t % 3 == 0) continue;  // lost: not received, not acknowledged
        for (const auto& d : out) {
            const std::optional<FrameDatagram> fr = frame_of(d);
            ASSERT_TRUE(fr);
            std::span<const uint8_t> root;
            uint8_t epoch = 0;
            // The block sent is as long as planned (EncodedFrame::root_block_bytes, shared between clients).
            const auto sent_as_planned = [&] { EXPECT_EQ(root.size(), plan.root_bytes(f, 0)) << "tick " << t; };
            ASSERT_TRUE(read_frame(
                *fr, [&](uint16_t) { return a.format.size(); },
                [&](uint16_t, int first, int count, int show, const RecordRun& rec) {
                    ASSERT_TRUE(client.add_chunk(t, first, count, show, rec, show, epoch, root))
                        << "tick " << t;
                },
                [&](const wire::Chunk& c, uint8_t, std::span<const uint8_t> block, const uint8_t*) {
                    ASSERT_FALSE(block.empty());
                    root = block;
                    epoch = c.epoch();
                }));
            sent_as_planned();
        }
        ++received;
        RootPose got;
        ASSERT_TRUE(client.root(double(t), got));
        const RootPose want = decode_root(f.instances[0].root.data());
        EXPECT_EQ(got.position, want.position) << "tick " << t;
        EXPECT_EQ(got.source_us, want.source_us) << "tick " << t;
        book.on_ack(seq - 1, 0);  // only this datagram: the lost ones never are
    }
    EXPECT_EQ(client.missing_baselines(), 0u);
    const double mean = double(root_bytes) / double(roots);
    std::printf("walking root, a third of the datagrams lost: %.1f bytes per root block (absolute %zu)\n", mean,
                kRootAbsoluteBytes);
    EXPECT_LT(mean, 12.0);
}

// EncodedFrame::own_bits, the length of a bone's record predicted from a
// baseline of its own, coded once per tick and shared between clients
// through a direct-mapped table: equal to the length of the record written
// from own_prediction for every slot, bone and baseline (age 1-15, linear or
// not), on first use and again from the table, tick after tick (an entry of
// an earlier tick, or of another key in the same entry, never answers);
// SIZE_MAX exactly when the ring lacks a baseline tick.
TEST(BaselineBook, SharedOwnBaselineLengthsAreTheRecordsWritten) {
    const auto& assets = progskin::net::testing::default_assets();
    std::vector<InstanceSpec> specs(3);
    for (size_t k = 0; k < specs.size(); ++k) {
        specs[k].asset = int(k % assets.size());
        specs[k].position = glm::vec3(float(k) * 2.0f, 0.0f, 0.0f);
    }
    FrameEncoder enc(assets, specs, 30.0f);
    size_t predictable = 0, not_predictable = 0;
    std::vector<uint8_t> bytes;
    for (uint32_t t = 1; t <= 24; ++t) {
        const EncodedFrame& f = enc.encode(t);
        for (int pass = 0; pass < 2; ++pass)
            for (int i = 0; i < int(specs.size()); ++i) {
                const EncodedInstance& e = f.instances[size_t(i)];
                ASSERT_TRUE(e.valid);
                for (int b = 0; b < e.bone_count; ++b)
                    for (uint32_t age = 1; age <= kMaxBaseAge; ++age)
                        for (const uint8_t linear : {uint8_t(0), kBaseLinear}) {
                            const uint8_t base = uint8_t(age) | linear;
                            RecordInts pred;
                            size_t want = SIZE_MAX;
                            if (f.own_prediction(i, b, base, pred)) {
                                bytes.clear();
                                BitWriter w(bytes);
                                want = write_predicted(f.ints[size_t(i) * f.ring_bones + size_t(b)], pred,
                                                       (e.flags & CHUNK_SCALED) != 0, w);
                            }
                            const size_t got = f.own_bits(i, b, base);
                            if (got != want) {
                                ADD_FAILURE() << "tick " << t << " pass " << pass << " instance " << i << " bone " << b
                                              << " base " << int(base) << ": " << got << " bits, written " << want;
                                return;
                            }
                            (want == SIZE_MAX ? not_predictable : predictable) += 1;
                        }
            }
    }
    EXPECT_GT(predictable, 10000u);
    EXPECT_GT(not_predictable, 1000u) << "the first ticks lack the older baselines";
}

// EncodedFrame::root_block_bytes, a root block's length from each baseline,
// coded once per tick and shared between clients: the length of the block
// write_root_block writes, on first use and from the cache, at every
// baseline age, linear or not.
TEST(BaselineBook, SharedRootLengthsAreTheBlocksWritten) {
    const auto& assets = progskin::net::testing::default_assets();
    std::vector<InstanceSpec> specs(3);
    FrameEncoder enc(assets, specs, 30.0f);
    size_t predicted = 0, absolute = 0;
    std::vector<uint8_t> block;
    for (uint32_t t = 1; t <= 40; ++t) {
        for (int i = 0; i < int(specs.size()); ++i) {
            RootPose r;
            r.position = {double(i) + 2.0 * std::cos(0.07 * t), 0.0, 2.0 * std::sin(0.07 * t)};
            r.rotation = glm::angleAxis(0.03f * float(t * (i + 1)), glm::vec3(0, 1, 0));
            r.source_us = 1'000'000 + uint64_t(t) * 33'333;
            ASSERT_TRUE(enc.set_root(i, r, false));
        }
        const EncodedFrame& f = enc.encode(t);
        for (int pass = 0; pass < 2; ++pass)
            for (int i = 0; i < int(specs.size()); ++i)
                for (uint32_t age = 1; age <= kMaxBaseAge; ++age)
                    for (const uint8_t linear : {uint8_t(0), kBaseLinear}) {
                        const uint8_t base = uint8_t(age) | linear;
                        block.clear();
                        const size_t want = f.write_root_block(i, base, block);
                        ASSERT_EQ(want, block.size());
                        ASSERT_EQ(f.root_block_bytes(i, base), want)
                            << "tick " << t << " pass " << pass << " instance " << i << " base " << int(base);
                        (want < kRootAbsoluteBytes ? predicted : absolute) += 1;
                    }
    }
    EXPECT_GT(predicted, 1000u);
    EXPECT_GT(absolute, 100u) << "the first ticks lack the older roots";
}

// The first loss: each frame datagram's first outcome, once. 1,000
// datagrams, each tenth reported lost (then acknowledged as repaired, which
// does not count again): the average reads about 0.1; acknowledged ones
// alone bring it back towards 0.
TEST(BaselineBook, FirstLossCountsEachDatagramsFirstOutcomeOnce) {
    BaselineBook book;
    EXPECT_EQ(book.first_loss(), 0.0);
    std::vector<BaselineBook::LostRun> lost;
    std::set<uint32_t> held;  // what the client holds
    size_t reported = 0;
    for (uint32_t seq = 1; seq <= 1000; ++seq) {
        book.carried(seq, seq, 0, 1, 0, 4);
        if (seq % 10 != 3) held.insert(seq);
        uint32_t bits = 0;
        for (uint32_t i = 0; i < 32; ++i)
            if (held.count(seq - 1 - i)) bits |= 1u << i;
        lost.clear();
        if (held.count(seq)) book.on_ack(seq, bits, &lost);
        reported += lost.size();
        if (seq % 10 == 6) held.insert(seq - 3);  // its repair arrived: acknowledged from the next Ack on
    }
    EXPECT_GT(reported, 90u);
    EXPECT_NEAR(book.first_loss(), 0.1, 0.03);
    for (uint32_t seq = 1001; seq <= 1400; ++seq) {  // a clean link
        book.carried(seq, seq, 0, 1, 0, 4);
        book.on_ack(seq, 0xffffffffu, &lost);
    }
    EXPECT_LT(book.first_loss(), 0.01);
}
