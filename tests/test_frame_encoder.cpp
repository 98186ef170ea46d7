// The frame encoder (server/frame_encoder.h): a clip instance's records at
// tick t decode to the clip sampled at its clip time, within the codec's
// quantisation (the error metric of docs/metrics.md §2 on the skinned
// vertices); live poses outside the codec's range are refused and counted,
// never clamped; the newest live pose wins; every add into a slot bumps its
// generation and every discontinuity its epoch.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "error_metric.h"
#include "errors.h"
#include "frame_encoder.h"
#include "progressive_skin.h"
#include "stream_assets.h"
#include "thresholds.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::thresholds;
using progskin::net::testing::fox_and_cesium;

namespace {

// Skinning matrices (Character joint order) decoded from instance i's records.
std::vector<Mat34> decoded_palette(const EncodedFrame& f, int i, const ServerAsset& a) {
    std::vector<Mat34> pal(a.character.joint_count(), Mat34::identity());
    const size_t rs = size_t(a.format.size());
    for (int b = 0; b < a.bone_count(); ++b)
        pal[size_t(a.skin.order[size_t(b)])] = compose(decode_bone(f.records(i) + size_t(b) * rs, a.format));
    return pal;
}

std::vector<Mat34> sampled_palette(const ServerAsset& a, const ClipSelection& sel, double t) {
    std::vector<glm::dmat4> m(a.character.joint_count());
    sample_skinning_matrices(a.character, sel, t, m);
    std::vector<Mat34> pal(m.size());
    for (size_t j = 0; j < m.size(); ++j) pal[j] = Mat34::from_glm(m[j]);
    return pal;
}

std::vector<glm::vec3> skinned(const Character& c, const std::vector<Mat34>& pal) {
    std::vector<glm::vec3> out(c.vertex_count());
    const SkinningJob job = skinning_job(c, pal, out);
    EXPECT_TRUE(job.validate());
    job.run();
    return out;
}

// A pose far outside any asset's translation box.
std::vector<Mat34> out_of_range_pose(const ServerAsset& a) {
    std::vector<Mat34> pose = sampled_palette(a, a.selections[0], 0.1);
    pose[size_t(a.skin.order[3])].m[3] = 1e6f;
    return pose;
}

}  // namespace

// Every instance of a crowd (both assets, every clip selection, time offsets,
// one at speed 1.7 and one played once) over ticks spanning loop wraps:
// the records decode to the clip at clip_time(i, t) within the codec's
// bound (model units) and the named quantisation threshold (% of diagonal).
TEST(FrameEncoder, ClipRecordsMatchTheSampledClipWithinQuantisation) {
    const auto& assets = fox_and_cesium();
    std::vector<InstanceSpec> specs = crowd_layout(assets, 8);
    specs[2].speed = 1.7f;
    specs[3].once = true;
    FrameEncoder enc(assets, specs, 30.0f);
    std::vector<ErrorAccumulator> acc;
    for (const auto& a : assets) acc.emplace_back(rest_diagonal(a->character));
    for (uint32_t t = 0; t <= 150; t += 7) {
        const EncodedFrame& f = enc.encode(t);
        EXPECT_EQ(f.tick, t);
        for (int i = 0; i < int(specs.size()); ++i) {
            const EncodedInstance& e = f.instances[size_t(i)];
            const ServerAsset& a = *assets[size_t(specs[size_t(i)].asset)];
            ASSERT_TRUE(e.valid);
            EXPECT_EQ(e.bone_count, a.bone_count());
            EXPECT_EQ(e.record_size, a.format.size());
            const ClipSelection& sel = a.selections[size_t(specs[size_t(i)].selection)];
            const double want_t = sel.played(specs[size_t(i)].time_offset + t / 30.0 * specs[size_t(i)].speed, specs[size_t(i)].once);
            const double clip_t = enc.clip_time(i, t);
            EXPECT_NEAR(clip_t, want_t, 1e-6) << "instance " << i << " tick " << t;
            const auto ref = skinned(a.character, sampled_palette(a, sel, clip_t));
            const auto got = skinned(a.character, decoded_palette(f, i, a));
            ErrorAccumulator one(rest_diagonal(a.character));
            one.add(ref, got);
            EXPECT_LE(one.stats().max, quantisation_bound(a.format, a.bind_radius, a.max_scale))
                << "instance " << i << " tick " << t;
            acc[size_t(specs[size_t(i)].asset)].add(ref, got);
        }
    }
    for (size_t a = 0; a < assets.size(); ++a) {
        const ErrorStats s = acc[a].stats();
        std::printf("%s: encoded against sampled, RMS %.5f %% max %.5f %% of the diagonal\n", assets[a]->name.c_str(),
                    s.rms_pct, s.max_pct);
        EXPECT_GT(s.max, 0.0);  // quantised: not bit-exact
        EXPECT_LT(s.max_pct, kQuantisationMaxPct) << assets[a]->name;
    }
    // The once-played instance holds its last frame.
    const ClipSelection& once_sel = assets[size_t(specs[3].asset)]->selections[size_t(specs[3].selection)];
    EXPECT_NEAR(enc.clip_time(3, 100000), once_sel.end, 1e-6);
    EXPECT_EQ(enc.stats().poses_out_of_range, 0u);
}

// Key samples (set_key_samples): a linearly keyed clip (the bundled ones:
// 24 Hz keys) is sampled at its latest key since the tick before, else at
// half a tick before the tick; EncodedInstance::sample says where (wire.h sample_ticks), and the
// records are the clip at that time. Keys closer than a tick apart (a clip
// played 1.7 times as fast) and key samples off: the tick, sample 0.
TEST(FrameEncoder, KeySamplesLandOnTheClipsKeys) {
    const auto& assets = fox_and_cesium();
    std::vector<InstanceSpec> specs = crowd_layout(assets, 8);
    specs[2].speed = 1.7f;
    FrameEncoder plain(assets, specs, 30.0f);
    FrameEncoder enc(assets, specs, 30.0f);
    enc.set_key_samples(true);
    int at_keys = 0, between = 0;
    for (uint32_t t = 1; t <= 90; ++t) {
        const EncodedFrame& p = plain.encode(t);
        for (const EncodedInstance& e : p.instances) EXPECT_EQ(e.sample, 0);
        const EncodedFrame& f = enc.encode(t);
        for (int i = 0; i < int(specs.size()); ++i) {
            const InstanceSpec& sp = specs[size_t(i)];
            const EncodedInstance& e = f.instances[size_t(i)];
            const ServerAsset& a = *assets[size_t(sp.asset)];
            const ClipSelection& sel = a.selections[size_t(sp.selection)];
            if (sp.speed > 1.5f) {
                EXPECT_EQ(e.sample, 0) << "keys closer than a tick";
                continue;
            }
            ASSERT_GE(e.sample, 1) << "instance " << i << " tick " << t;
            const double st = double(t) - sample_ticks(e.sample);
            const double clip_t = sel.played(sp.time_offset + st / 30.0 * sp.speed, false);
            const std::vector<double> keys = linear_key_times(a.character, sel);
            ASSERT_FALSE(keys.empty());
            double nearest = 1e9;
            for (double k : keys) nearest = std::min(nearest, std::fabs(k - clip_t));
            if (nearest < 1.0 / 508 / 30.0 * sp.speed + 1e-6) {
                ++at_keys;
            } else {
                // No key since the tick before: half a tick before the tick.
                ++between;
                EXPECT_EQ(e.sample, 128) << "instance " << i << " tick " << t;
                const double t0 = sel.played(sp.time_offset + (t - 1) / 30.0 * sp.speed, false);
                const double t1 = sel.played(sp.time_offset + t / 30.0 * sp.speed, false);
                if (t1 > t0) {
                    EXPECT_TRUE(std::isnan(latest_key_in(keys, t0, t1))) << "instance " << i << " tick " << t;
                }
            }
            // The records are the clip at the sample's time.
            const auto ref = skinned(a.character, sampled_palette(a, sel, clip_t));
            const auto got = skinned(a.character, decoded_palette(f, i, a));
            ErrorAccumulator one(rest_diagonal(a.character));
            one.add(ref, got);
            EXPECT_LE(one.stats().max, quantisation_bound(a.format, a.bind_radius, a.max_scale) * 1.5)
                << "instance " << i << " tick " << t;
        }
    }
    // 24 keys a second at 30 ticks: four ticks in five have a key since the
    // tick before (Fox's Run has a longer gap between two of its keys).
    EXPECT_GT(at_keys, 3 * between);
    EXPECT_GT(between, 0);
}

// Morph weights of a clip instance: the clip's weights at its clip time,
// quantised for the wire (encode_morph_weight).
TEST(FrameEncoder, ClipMorphWeightsAreTheSampledWeightsQuantised) {
    const std::vector<std::shared_ptr<ServerAsset>> assets = {progskin::net::testing::skinned_morph_asset()};
    InstanceSpec spec;
    spec.selection = progskin::net::testing::selection_of_clip(*assets[0], "talk");
    ASSERT_GE(spec.selection, 0);
    FrameEncoder enc(assets, {spec}, 30.0f);
    const Character& c = assets[0]->character;
    std::vector<float> w(c.morphs.size());
    size_t nonzero = 0;
    for (uint32_t t = 0; t < 60; t += 3) {
        const EncodedFrame& f = enc.encode(t);
        const auto q = f.morphs(0);
        ASSERT_EQ(q.size(), c.morphs.size());
        sample_morph_weights(c, assets[0]->selections[size_t(spec.selection)], enc.clip_time(0, t), w);
        for (size_t m = 0; m < w.size(); ++m) {
            int16_t want = 0;
            ASSERT_TRUE(encode_morph_weight(w[m], want));
            EXPECT_EQ(q[m], want) << "tick " << t << " weight " << m;
            nonzero += q[m] != 0;
        }
    }
    EXPECT_GT(nonzero, 0u);
    EXPECT_EQ(enc.stats().morphs_out_of_range, 0u);
}

// push_pose: a pose the codec cannot represent is refused (false), counted,
// and the previous pose stays; wrong sizes and ids throw.
TEST(FrameEncoder, OutOfRangeLivePoseIsRefusedAndCounted) {
    const auto& assets = fox_and_cesium();
    const ServerAsset& a = *assets[0];
    InstanceSpec live;
    live.selection = -1;
    FrameEncoder enc(assets, {live}, 30.0f);
    EXPECT_FALSE(enc.encode(1).instances[0].valid);  // no pose yet: nothing to send
    const std::vector<Mat34> good = sampled_palette(a, a.selections[0], 0.5);
    ASSERT_TRUE(enc.push_pose(0, good));
    const EncodedFrame& f1 = enc.encode(2);
    ASSERT_TRUE(f1.instances[0].valid);
    const std::vector<uint8_t> before(f1.records(0), f1.records(0) + size_t(a.bone_count() * a.format.size()));

    EXPECT_FALSE(enc.push_pose(0, out_of_range_pose(a)));
    EXPECT_EQ(enc.stats().poses_out_of_range, 1u);
    std::vector<Mat34> nan_pose = good;
    nan_pose[0].m[5] = std::nanf("");
    EXPECT_FALSE(enc.push_pose(0, nan_pose));
    EXPECT_EQ(enc.stats().poses_out_of_range, 2u);
    const EncodedFrame& f2 = enc.encode(3);
    ASSERT_TRUE(f2.instances[0].valid);
    EXPECT_EQ(0, std::memcmp(f2.records(0), before.data(), before.size())) << "the refused pose changed the records";

    const std::vector<Mat34> short_pose(good.begin(), good.end() - 1);
    EXPECT_THROW(enc.push_pose(0, short_pose), Error);
    EXPECT_THROW(enc.push_pose(7, good), Error);
    EXPECT_EQ(enc.stats().poses_out_of_range, 2u);  // size and id errors are not range refusals
}

// Several poses pushed between two encodes: the last one goes. Published
// records (push_records) go by pose_seq: an older one is dropped as stale.
TEST(FrameEncoder, NewestLivePoseWins) {
    const auto& assets = fox_and_cesium();
    const ServerAsset& a = *assets[1];
    InstanceSpec live;
    live.asset = 1;
    live.selection = -1;
    FrameEncoder enc(assets, {live, live}, 30.0f);
    const ClipSelection& sel = a.selections[0];
    const auto pose_a = sampled_palette(a, sel, 0.2), pose_b = sampled_palette(a, sel, 1.1);
    ASSERT_TRUE(enc.push_pose(0, pose_a));
    ASSERT_TRUE(enc.push_pose(0, pose_b));
    const EncodedFrame& f = enc.encode(1);
    const auto want = skinned(a.character, pose_b), other = skinned(a.character, pose_a);
    const auto got = skinned(a.character, decoded_palette(f, 0, a));
    ErrorAccumulator to_b(rest_diagonal(a.character)), to_a(rest_diagonal(a.character));
    to_b.add(want, got);
    to_a.add(other, got);
    EXPECT_LE(to_b.stats().max, quantisation_bound(a.format, a.bind_radius, a.max_scale));
    EXPECT_GT(to_a.stats().max, 10 * to_b.stats().max);  // the two poses differ far more than the codec's step

    // push_records: newer sequence numbers replace, older ones are stale.
    const size_t rs = size_t(a.format.size()), bytes = size_t(a.bone_count()) * rs;
    auto records_of = [&](const std::vector<Mat34>& pose) {
        std::vector<uint8_t> r(bytes);
        for (int b = 0; b < a.bone_count(); ++b)
            encode_bone(decompose(pose[size_t(a.skin.order[size_t(b)])]), a.format, r.data() + size_t(b) * rs);
        return r;
    };
    const std::vector<uint8_t> ra = records_of(pose_a), rb = records_of(pose_b);
    std::array<uint8_t, ROOT_BYTES> root{};
    ASSERT_TRUE(encode_root(RootPose{}, root.data()));
    EXPECT_TRUE(enc.push_records(1, 5, 0, 0, ra, root));
    EXPECT_FALSE(enc.push_records(1, 4, 0, 0, rb, root));
    EXPECT_EQ(enc.stats().stale_poses, 1u);
    EXPECT_EQ(0, std::memcmp(enc.encode(2).records(1), ra.data(), bytes));
    EXPECT_TRUE(enc.push_records(1, 6, 0, 0, rb, root));
    const EncodedFrame& g = enc.encode(3);
    EXPECT_EQ(0, std::memcmp(g.records(1), rb.data(), bytes));
    EXPECT_TRUE(g.instances[1].flags & CHUNK_ROOT);  // published poses carry their placement
    EXPECT_EQ(enc.stats().stale_poses, 1u);
}

// Slots: ids are handed out in order, a removed id is reused only after many
// others were freed (first freed, first reused), and every add bumps the
// slot's generation and its epoch, so per-client state keyed by id resets.
TEST(FrameEncoder, AddAndRemoveBumpGenerations) {
    const auto& assets = fox_and_cesium();
    FrameEncoder enc(assets, crowd_layout(assets, 2), 30.0f);
    std::vector<uint32_t> gen;
    enc.generations(gen);
    ASSERT_EQ(gen.size(), 2u);
    EXPECT_EQ(gen[0], 1u);
    EXPECT_EQ(gen[1], 1u);
    InstanceSpec spec;
    const int id = enc.add_instance(spec);
    EXPECT_EQ(id, 2);
    EXPECT_EQ(enc.capacity(), 3u);
    EXPECT_EQ(enc.active_ids(), (std::vector<int>{0, 1, 2}));
    const uint8_t epoch_before = enc.encode(1).instances[0].epoch;

    enc.remove_instance(0);
    enc.remove_instance(0);  // no-op
    enc.remove_instance(99);  // no-op
    EXPECT_FALSE(enc.active(0));
    EXPECT_THROW(enc.spec(0), Error);
    InstanceSpec out;
    EXPECT_FALSE(enc.spec_if_active(0, out));
    enc.generations(gen);
    EXPECT_EQ(gen[0], 0u);  // inactive
    const EncodedFrame& f = enc.encode(2);
    EXPECT_FALSE(f.instances[0].active);
    EXPECT_FALSE(f.instances[0].valid);
    EXPECT_TRUE(f.instances[1].valid);

    // Free more than 64 ids, then add: the first freed (0) comes back, one generation on.
    std::vector<int> ids;
    for (int i = 0; i < 70; ++i) ids.push_back(enc.add_instance(spec));
    EXPECT_EQ(ids.front(), 3);  // ids are not reused while few are free
    for (int i = 0; i < 66; ++i) enc.remove_instance(ids[size_t(i)]);
    const int again = enc.add_instance(spec);
    EXPECT_EQ(again, 0);
    enc.generations(gen);
    EXPECT_EQ(gen[0], 2u);
    const EncodedFrame& g = enc.encode(3);
    EXPECT_EQ(g.instances[0].generation, 2u);
    EXPECT_TRUE(g.instances[0].valid);
    EXPECT_NE(g.instances[0].epoch, epoch_before);  // a new occupant is a discontinuity
    EXPECT_EQ(g.instances[1].generation, 1u);       // the others keep theirs

    // Bad specs throw.
    InstanceSpec bad;
    bad.asset = 5;
    EXPECT_THROW(enc.add_instance(bad), Error);
    bad.asset = 0;
    bad.selection = 99;
    EXPECT_THROW(enc.add_instance(bad), Error);
    bad.selection = 0;
    bad.speed = std::nanf("");
    EXPECT_THROW(enc.add_instance(bad), Error);
}

// A teleport (set_root with teleport) is a discontinuity: the epoch changes;
// moving without one keeps it.
TEST(FrameEncoder, TeleportChangesTheEpoch) {
    const auto& assets = fox_and_cesium();
    InstanceSpec s;
    s.asset = 1;
    FrameEncoder enc(assets, {s}, 30.0f);
    const uint8_t e0 = enc.encode(1).instances[0].epoch;
    RootPose r;
    r.position = glm::dvec3(3, 0, 1);
    ASSERT_TRUE(enc.set_root(0, r, false));
    const EncodedFrame& f = enc.encode(2);
    EXPECT_EQ(f.instances[0].epoch, e0);
    EXPECT_NEAR(glm::length(f.instances[0].world - r.position), 0.0, 1e-3);
    r.position = glm::dvec3(300, 0, 1);
    ASSERT_TRUE(enc.set_root(0, r, true));
    EXPECT_NE(enc.encode(3).instances[0].epoch, e0);
    r.position = glm::dvec3(1e10, 0, 0);  // outside the root block's +-2147 km
    EXPECT_FALSE(enc.set_root(0, r, false));
}

// set_pool: a tick's slots spread over several threads encode to the same
// frame, bit for bit, as on one thread: clip instances (some with morph
// weights), live instances posed every tick, some every few ticks, some
// never, instances added and removed between ticks; and the counters add
// up alike (a refused pose counted once, whichever thread met it).
TEST(FrameEncoder, APoolEncodesTheSameFrameAsOneThread) {
    std::vector<std::shared_ptr<ServerAsset>> assets = fox_and_cesium();
    assets.push_back(progskin::net::testing::skinned_morph_asset());
    std::vector<InstanceSpec> specs;
    for (int k = 0; k < 150; ++k) {
        InstanceSpec s;
        s.asset = k % 3;
        s.selection = k % 5 == 0 ? -1 : int(k % int(assets[size_t(s.asset)]->selections.size()));
        s.position = glm::vec3(float(k), 0.0f, float(k % 9));
        s.time_offset = 0.1f * float(k);
        specs.push_back(s);
    }
    FrameEncoder one(assets, specs, 30.0f), many(assets, specs, 30.0f);
    TickPool pool(3);
    many.set_pool(&pool);
    size_t compared = 0;
    for (uint32_t tick = 1; tick <= 40; ++tick) {
        for (FrameEncoder* enc : {&one, &many}) {
            for (int k = 0; k < 150; k += 5) {  // the live ones
                if ((k / 5) % 4 == 3 || tick % (1 + (k / 5) % 3) != 0) continue;  // some never, some every few ticks
                const ServerAsset& a = *assets[size_t(k % 3)];
                ASSERT_TRUE(enc->push_pose(k, sampled_palette(a, a.selections[0], 0.05 * tick + 0.01 * k)));
            }
            if (tick == 10) {
                enc->remove_instance(7);
                enc->remove_instance(8);
            }
            if (tick == 20) {
                InstanceSpec s = specs[3];
                s.position = glm::vec3(-5.0f, 0.0f, 2.0f);
                enc->add_instance(s);
            }
            if (tick == 25 && enc->push_pose(0, out_of_range_pose(*assets[0]))) ADD_FAILURE() << "an out-of-range pose was taken";
        }
        const EncodedFrame& a = one.encode(tick);
        const EncodedFrame& b = many.encode(tick);
        ASSERT_EQ(a.instances.size(), b.instances.size());
        for (size_t i = 0; i < a.instances.size(); ++i) {
            const EncodedInstance &x = a.instances[i], &y = b.instances[i];
            ASSERT_EQ(x.active, y.active) << "tick " << tick << " slot " << i;
            ASSERT_EQ(x.valid, y.valid) << "tick " << tick << " slot " << i;
            if (!x.valid) continue;
            ++compared;
            EXPECT_EQ(x.epoch, y.epoch);
            EXPECT_EQ(x.changed_tick, y.changed_tick);
            EXPECT_EQ(x.sample, y.sample);
            EXPECT_EQ(x.morph_count, y.morph_count);
            ASSERT_EQ(0, std::memcmp(a.records(int(i)), b.records(int(i)), size_t(x.bone_count * x.record_size)))
                << "tick " << tick << " slot " << i;
            ASSERT_EQ(a.record_bits(int(i), 0, x.bone_count), b.record_bits(int(i), 0, y.bone_count));
            const size_t bits = a.record_bits(int(i), 0, x.bone_count);
            ASSERT_EQ(0, std::memcmp(a.relative(int(i)), b.relative(int(i)), bits / 8)) << "tick " << tick << " slot " << i;
            for (int m = 0; m < x.morph_count; ++m) EXPECT_EQ(a.morphs(int(i))[size_t(m)], b.morphs(int(i))[size_t(m)]);
        }
    }
    EXPECT_GT(compared, 4000u);
    EXPECT_EQ(one.stats().poses_out_of_range, many.stats().poses_out_of_range);
    EXPECT_EQ(one.stats().records_refused, many.stats().records_refused);
}

// A pose given whole (push_pose, a game server driving a character) is coded
// from the bones as given, exactly as a clip instance at the same pose: not
// from the box's 16-bit records, whose steps over a box of every rigid pose
// are coarser than the relative records' (Asset.t_step).
TEST(FrameEncoder, APushedPoseCodesAsTheClipAtThatPose) {
    const auto& assets = fox_and_cesium();
    for (int asset : {0, 1}) {
        const ServerAsset& a = *assets[size_t(asset)];
        InstanceSpec clip, live;
        clip.asset = live.asset = asset;
        live.selection = -1;
        FrameEncoder enc(assets, {clip, live}, 30.0f);
        int differ = 0;
        for (uint32_t t = 1; t <= 30; ++t) {
            ASSERT_TRUE(enc.push_pose(1, sampled_palette(a, a.selections[0], enc.clip_time(0, t))));
            const EncodedFrame& f = enc.encode(t);
            const RecordInts* x = f.ints_at(0, t);
            const RecordInts* y = f.ints_at(1, t);
            ASSERT_TRUE(x && y);
            for (int b = 0; b < a.bone_count(); ++b)
                differ += std::memcmp(x[b].rot, y[b].rot, sizeof x[b].rot) != 0 || x[b].has_trans != y[b].has_trans ||
                          (x[b].has_trans && std::memcmp(x[b].trans, y[b].trans, sizeof x[b].trans) != 0);
        }
        EXPECT_EQ(differ, 0) << a.name << ": bones coded otherwise than the clip's";
    }
}
