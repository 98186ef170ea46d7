// The client's pose buffer (client/pose_buffer.h): exact at the ticks it
// received, interpolated between them (cubic where neighbours allow, else
// slerp/lerp) and held after the newest; never interpolated across an epoch;
// inconsistent chunks refused without change; the root block and morph
// weights follow the same rules. Real records from the FrameEncoder on Fox,
// and made-up poses where the exact answer is known.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "error_metric.h"
#include "frame_encoder.h"
#include "pose_buffer.h"
#include "progressive_skin.h"
#include "stream_assets.h"
#include "thresholds.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::thresholds;
using progskin::net::testing::fox_and_cesium;

namespace {

const RecordFormat kFmt{glm::vec3(-10.0f), glm::vec3(10.0f), false};

// A buffer of an n-bone chain over the box of kFmt (pivots at the origin).
PoseBuffer buffer(int n, int morphs = 0) { return PoseBuffer(chain_format(n, kFmt), morphs); }

// Parent-relative records (bone_record.h) of given relative poses: each coded
// against an identity parent, so that the buffer's (relative) pose of a bone
// is the pose given. run(k): the records from the k-th on.
struct Records {
    std::vector<uint8_t> bits;
    std::vector<size_t> at;
    RecordRun run(size_t k = 0) const { return {bits.data(), bits.size(), at[k], false, 0}; }
};
// `n` bones, bone b at translation t + (b, 0, 0), rotated by `angle` about z.
Records records(int n, glm::vec3 t, float angle = 0.0f) {
    const RelativeFormat f = chain_format(n, kFmt);
    Records out;
    BitWriter w(out.bits);
    for (int b = 0; b < n; ++b) {
        BonePose p;
        p.t = t + glm::vec3(float(b), 0, 0);
        p.r = glm::angleAxis(angle, glm::vec3(0, 0, 1));
        RecordInts r;
        EXPECT_TRUE(quantise_record(BonePose{}, p, b, f, r));
        out.at.push_back(w.bits());
        write_record(r, false, w);
    }
    return out;
}
// One record of a bone at translation t.
Records record(glm::vec3 t, float angle = 0.0f) { return records(1, t, angle); }

std::array<uint8_t, ROOT_BYTES> absolute_root(glm::dvec3 p, float angle, uint64_t source_us = 0) {
    RootPose r;
    r.position = p;
    r.rotation = glm::angleAxis(angle, glm::vec3(0, 1, 0));
    r.source_us = source_us;
    std::array<uint8_t, ROOT_BYTES> out{};
    EXPECT_TRUE(encode_root(r, out.data()));
    return out;
}
// A chunk's root block (root_block.h) of that placement, absolute.
std::vector<uint8_t> root_block(glm::dvec3 p, float angle) {
    std::vector<uint8_t> out;
    write_root(absolute_root(p, angle).data(), 0, nullptr, nullptr, out);
    return out;
}

std::vector<uint8_t> morph_block(std::vector<std::pair<int, float>> w) {
    std::vector<uint8_t> out = {uint8_t(w.size())};
    for (auto [m, v] : w) {
        int16_t q = 0;
        EXPECT_TRUE(encode_morph_weight(v, q));
        out.push_back(uint8_t(m));
        out.push_back(uint8_t(uint16_t(q) & 0xFF));
        out.push_back(uint8_t(uint16_t(q) >> 8));
    }
    return out;
}

BonePose pose_of(const PoseBuffer& pb, int b, double d) {
    BonePose p;
    EXPECT_TRUE(pb.pose(b, d, p)) << "bone " << b << " at " << d;
    return p;
}

// The angle between two rotations (well conditioned near 0, unlike acos of the dot product).
double rotation_angle(const glm::quat& a, const glm::quat& b) {
    const glm::dquat x(a), y(glm::dot(a, b) < 0.0f ? -b : b);
    return 4.0 * std::asin(std::min(1.0, glm::length(x - y) / 2.0));
}

}  // namespace

// Records of a Fox clip instance every tick: at a received tick the pose is
// that frame's decoded record; half-way between ticks the skinned mesh is
// within the quantisation threshold plus the interpolation error of the
// clip sampled at the half tick.
TEST(PoseBuffer, ExactAtTicksAndCloseBetweenThemOnARealClip) {
    const auto& assets = fox_and_cesium();
    const ServerAsset& a = *assets[0];
    InstanceSpec spec;
    spec.selection = 0;
    FrameEncoder enc(assets, {spec}, 30.0f);
    PoseBuffer pb(a.relative);
    const int B = a.bone_count();
    std::vector<std::vector<RecordInts>> kept;
    const uint32_t first = 10, last = 40;
    for (uint32_t t = first; t <= last; ++t) {
        const EncodedFrame& f = enc.encode(t);
        const RecordRun run{f.relative(0), (f.bit_offset(0, B) + 7) / 8, f.bit_offset(0, 0), a.relative.scaled, 0};
        ASSERT_TRUE(pb.add_chunk(t, 0, B, B, run, B, f.instances[0].epoch));
        kept.emplace_back(f.ints.begin(), f.ints.begin() + long(B));  // slot 0's integers
    }
    EXPECT_EQ(pb.newest_tick(), last);
    EXPECT_EQ(pb.bones_at(last), B);
    EXPECT_EQ(pb.last_gap(), 1);
    for (uint32_t t = first; t <= last; t += 5)
        for (int b = 0; b < B; ++b) {
            const BonePose want = dequantise_record(kept[t - first][size_t(b)], b, a.relative);
            const BonePose got = pose_of(pb, b, t);
            EXPECT_LT(glm::length(got.t - want.t), 1e-5f * float(a.diagonal)) << "bone " << b << " tick " << t;
            EXPECT_LT(rotation_angle(got.r, want.r), 1e-5) << "bone " << b << " tick " << t;
        }
    // Half-way: skin the interpolated pose (composed down the progressive
    // parents) and the clip at the half tick.
    const Character& c = a.character;
    const ClipSelection& sel = a.selections[0];
    ErrorAccumulator between(rest_diagonal(c));
    std::vector<glm::dmat4> m(c.joint_count());
    std::vector<Mat34> ref_pal(c.joint_count()), pal(c.joint_count());
    std::vector<BonePose> model(static_cast<size_t>(B));
    std::vector<glm::vec3> ref(c.vertex_count()), got(c.vertex_count());
    for (uint32_t t = first + 1; t + 1 < last; ++t) {
        const double d = t + 0.5;
        sample_skinning_matrices(c, sel, enc.clip_time(0, d), m);
        for (size_t j = 0; j < m.size(); ++j) ref_pal[j] = Mat34::from_glm(m[j]);
        for (int b = 0; b < B; ++b) {
            const int p = a.skin.parents[size_t(b)];
            model[size_t(b)] = compose_relative(p >= 0 ? model[size_t(p)] : BonePose{}, pose_of(pb, b, d));
            pal[size_t(a.skin.order[size_t(b)])] = compose(model[size_t(b)]);
        }
        skinning_job(c, ref_pal, ref).run();
        skinning_job(c, pal, got).run();
        between.add(ref, got);
    }
    std::printf("Fox clip, half-way between 30 Hz ticks: RMS %.5f %% max %.5f %% of the diagonal\n",
                between.stats().rms_pct, between.stats().max_pct);
    EXPECT_GT(between.stats().max, 0.0);
    EXPECT_LT(between.stats().rms_pct, kStreamRmsPctUnlimited);
}

// Motion along a straight line at constant speed: any interpolation of the
// ticks reproduces it, so the pose at any display time is the line's point
// (to the codec's step); with only two frames the buffer lerps, with more
// it uses the cubic, both exact here. After the newest frame it holds.
TEST(PoseBuffer, InterpolatesLinearMotionExactly) {
    PoseBuffer pb = buffer(3);
    auto at = [](double tick) { return glm::vec3(-5.0f + 0.25f * float(tick - 100), 1.0f, 0.5f); };
    ASSERT_TRUE(pb.add_chunk(100, 0, 3, 3, records(3, at(100), 0.1f).run()));
    ASSERT_TRUE(pb.add_chunk(102, 0, 3, 3, records(3, at(102), 0.3f).run()));
    const float step = 20.0f / 65535.0f;  // translation step of the record over [-10, 10]
    for (double d : {100.0, 100.5, 101.0, 101.75, 102.0}) {
        for (int b = 0; b < 3; ++b) {
            const BonePose p = pose_of(pb, b, d);
            EXPECT_LT(glm::length(p.t - (at(d) + glm::vec3(float(b), 0, 0))), 2 * step) << "lerp, d " << d << " bone " << b;
            EXPECT_NEAR(rotation_angle(p.r, glm::angleAxis(float(0.1 + 0.1 * (d - 100)), glm::vec3(0, 0, 1))), 0.0, 1e-3);
        }
    }
    for (uint32_t t : {98u, 104u, 106u}) ASSERT_TRUE(pb.add_chunk(t, 0, 3, 3, records(3, at(t), float(0.1 + 0.1 * (t - 100.0))).run()));
    for (double d : {98.5, 101.25, 103.0, 104.5}) {
        const BonePose p = pose_of(pb, 1, d);
        EXPECT_LT(glm::length(p.t - (at(d) + glm::vec3(1, 0, 0))), 2 * step) << "cubic, d " << d;
    }
    // Held after the newest frame (106), also far after it.
    double held_at = 0;
    BonePose p;
    ASSERT_TRUE(pb.pose(2, 110.0, p, &held_at));
    EXPECT_EQ(held_at, 106.0);
    EXPECT_LT(glm::length(p.t - (at(106) + glm::vec3(2, 0, 0))), 2 * step);
}

// bones_recorded counts the bones whose records of the ticks around the
// display time are here: a chunk of bones 0..1 only at tick 101 leaves bone
// 2 interpolated across 100..102 there.
TEST(PoseBuffer, BonesRecordedCountsTheBonesOfTheTicksAroundTheDisplay) {
    PoseBuffer pb = buffer(3);
    EXPECT_EQ(pb.bones_recorded(100.0, 3), 0);  // nothing yet
    const glm::vec3 t0(0.5f, 1.0f, 0.25f);
    ASSERT_TRUE(pb.add_chunk(100, 0, 3, 3, records(3, t0, 0.1f).run()));
    ASSERT_TRUE(pb.add_chunk(101, 0, 2, 3, records(2, t0, 0.2f).run()));
    ASSERT_TRUE(pb.add_chunk(102, 0, 3, 3, records(3, t0, 0.3f).run()));
    EXPECT_EQ(pb.bones_recorded(100.0, 3), 3);
    EXPECT_EQ(pb.bones_recorded(101.0, 3), 2);
    EXPECT_EQ(pb.bones_recorded(101.0, 2), 2);
    EXPECT_EQ(pb.bones_recorded(102.0, 3), 3);
    EXPECT_EQ(pb.bones_recorded(100.5, 3), 2);  // ticks 100 and 101
    EXPECT_EQ(pb.bones_recorded(101.5, 3), 2);  // ticks 101 and 102
    EXPECT_EQ(pb.bones_recorded(102.5, 3), 0);  // no frame of tick 103
    EXPECT_EQ(pb.bones_recorded(99.0, 3), 0);   // before the first frame
}

// needed_from (the display delay's reach for a frame that comes after a
// newer one): the sample time of the second newest kept frame before it
// carrying the bone (the cubic's span it is the outer neighbour of), of the
// newest when there is no second within HOLD_TICKS and the same epoch, else
// the frame's own tick.
TEST(PoseBuffer, NeededFromReachesTheFrameBeforeWithinTheHoldAndTheEpoch) {
    PoseBuffer pb = buffer(2);
    const glm::vec3 t0(0.5f, 1.0f, 0.25f);
    ASSERT_TRUE(pb.add_chunk(100, 0, 2, 2, records(2, t0, 0.1f).run()));
    ASSERT_TRUE(pb.add_chunk(101, 0, 1, 2, records(1, t0, 0.1f).run(), 2));  // bone 0 only
    ASSERT_TRUE(pb.add_chunk(104, 0, 2, 2, records(2, t0, 0.2f).run()));
    ASSERT_TRUE(pb.add_chunk(103, 0, 2, 2, records(2, t0, 0.2f).run()));  // late
    EXPECT_DOUBLE_EQ(pb.needed_from(103, 0), 100.0);  // the span 100-101 takes 103 as its outer neighbour
    EXPECT_DOUBLE_EQ(pb.needed_from(103, 1), 100.0);  // bone 1: only one frame before
    ASSERT_TRUE(pb.add_chunk(130, 0, 2, 2, records(2, t0, 0.3f).run()));
    ASSERT_TRUE(pb.add_chunk(125, 0, 2, 2, records(2, t0, 0.3f).run()));  // 21 ticks after 104: shown again
    EXPECT_DOUBLE_EQ(pb.needed_from(125, 0), 125.0);
    ASSERT_TRUE(pb.add_chunk(133, 0, 2, 2, records(2, t0, 0.3f).run(), 2, 1));  // a new epoch (a wrap)
    ASSERT_TRUE(pb.add_chunk(132, 0, 2, 2, records(2, t0, 0.3f).run(), 2, 1));  // late, epoch 1; 130 is epoch 0
    EXPECT_DOUBLE_EQ(pb.needed_from(132, 0), 132.0);
    ASSERT_TRUE(pb.add_chunk(131, 0, 2, 2, records(2, t0, 0.3f).run()));  // late, epoch 0
    EXPECT_DOUBLE_EQ(pb.needed_from(131, 0), 125.0);  // the span 125-130 of epoch 0
    ASSERT_TRUE(pb.add_chunk(160, 0, 2, 2, records(2, t0, 0.3f).run()));
    ASSERT_TRUE(pb.add_chunk(158, 0, 2, 2, records(2, t0, 0.3f).run()));  // 27 ticks after 131
    ASSERT_TRUE(pb.add_chunk(159, 0, 2, 2, records(2, t0, 0.3f).run()));  // late
    EXPECT_DOUBLE_EQ(pb.needed_from(159, 0), 158.0) << "131-158 is past the hold: no span before 158";
}

// A piecewise linear motion (a linearly keyed clip) sampled at its keys
// (sample bytes, wire.h sample_ticks): between the samples of adjacent ticks
// the buffer interpolates linearly at the samples' times and follows the
// kinks exactly; the same samples without their sample bytes (taken as the
// ticks') do not. Chunks of one tick that disagree on the sample are refused.
TEST(PoseBuffer, KeyedSamplesInterpolateLinearlyAtTheirTimes) {
    // Keys every 1.25 ticks from tick 100 on (24 Hz keys at 30 Hz), x
    // alternating between -2 and 2: kinks at every key.
    auto key_x = [](int k) { return k % 2 ? 2.0 : -2.0; };
    auto truth = [&](double tick) {
        const double u = (tick - 100.0) / 1.25;
        const int k = int(std::floor(u));
        return key_x(k) + (key_x(k + 1) - key_x(k)) * (u - k);
    };
    const float step = 20.0f / 65535.0f;
    for (bool keyed : {true, false}) {
        PoseBuffer pb = buffer(1);
        for (uint32_t t = 101; t <= 112; ++t) {
            // The latest key in (t - 1, t], else t itself (FrameEncoder::key_sample).
            const double k = 100.0 + 1.25 * std::floor((t - 100.0) / 1.25);
            const int q = k > t - 1.0 ? int(std::lround((t - k) * 254)) : 0;
            const double at = double(t) - q / 254.0;
            ASSERT_TRUE(pb.add_chunk(t, 0, 1, 1, record(glm::vec3(float(truth(at)), 0, 0)).run(), 1, 0, {},
                                     keyed ? uint8_t(1 + q) : uint8_t(0)));
        }
        double worst = 0;
        for (double d = 103.0; d <= 110.0; d += 0.05) worst = std::max(worst, std::fabs(pose_of(pb, 0, d).t.x - truth(d)));
        // A sample lands within 1/508 tick of its key (its time is kept to
        // 1/254 tick): the line misses the kink by the slope's change (6.4
        // per tick here) times that.
        if (keyed)
            EXPECT_LT(worst, 3 * step + 6.4 / 508) << "linear between key samples follows the kinks";
        else
            EXPECT_GT(worst, 0.1) << "the same samples taken as the ticks' miss the kinks";
    }
    PoseBuffer pb = buffer(2);
    ASSERT_TRUE(pb.add_chunk(100, 0, 1, 2, record(glm::vec3(0.0f)).run(), 2, 0, {}, 10));
    EXPECT_FALSE(pb.add_chunk(100, 1, 1, 2, record(glm::vec3(0.0f)).run(), 2, 0, {}, 11)) << "one tick, two samples";
    EXPECT_TRUE(pb.add_chunk(100, 1, 1, 2, record(glm::vec3(0.0f)).run(), 2, 0, {}, 10));
}

// Frames of different epochs are never interpolated: between the last frame
// of epoch 0 and the first of epoch 1 the older one is held (no boundary
// known), and the newer one shows from its tick on.
TEST(PoseBuffer, EpochChangePreventsInterpolatingAcrossADiscontinuity) {
    const glm::vec3 here(1, 2, 3), there(-4, 7, -6);
    for (bool new_epoch : {false, true}) {
        SCOPED_TRACE(new_epoch);
        PoseBuffer pb = buffer(2);
        ASSERT_TRUE(pb.add_chunk(50, 0, 2, 2, records(2, here).run(), 2, 3));
        ASSERT_TRUE(pb.add_chunk(51, 0, 2, 2, records(2, here).run(), 2, 3));
        ASSERT_TRUE(pb.add_chunk(53, 0, 2, 2, records(2, there).run(), 2, new_epoch ? 4 : 3));
        for (double d : {51.5, 52.0, 52.9}) {
            const BonePose p = pose_of(pb, 0, d);
            if (new_epoch) {
                EXPECT_LT(glm::length(p.t - here), 1e-3f) << "held, not interpolated, at " << d;
            } else {
                const float u = float(d - 51.0) / 2.0f;
                EXPECT_LT(glm::length(p.t - (here + u * (there - here))), 1e-2f) << d;
            }
        }
        EXPECT_LT(glm::length(pose_of(pb, 0, 53.0).t - there), 1e-3f);
    }
}

// A known boundary (a looping clip's wrap at tick 52.5) whose next epoch has
// not arrived yet (its first frames lost or late): before the boundary the
// newest frame is held as ever; past it, the newest frame is handed to the
// caller as an anchor to carry along the clip across the wrap (InstanceView),
// not held as if the old epoch went on. Without a boundary function, or
// without the caller asking for an anchor, it is held.
TEST(PoseBuffer, PastAKnownBoundaryWithNothingNewerTheNewestFrameIsAnAnchor) {
    const glm::vec3 here(1, 2, 3);
    PoseBuffer pb = buffer(2);
    ASSERT_TRUE(pb.add_chunk(50, 0, 2, 2, records(2, here).run(), 2, 3));
    ASSERT_TRUE(pb.add_chunk(51, 0, 2, 2, records(2, here).run(), 2, 3));
    BonePose p;
    double anchor = 0;
    ASSERT_TRUE(pb.pose(0, 53.0, p, nullptr, &anchor));
    EXPECT_TRUE(std::isnan(anchor)) << "no boundary known: held";
    auto wrap = [](const void*, double ta, double tc) { return ta < 52.5 && tc >= 52.5 ? 52.5 : std::nan(""); };
    pb.set_boundary(wrap, nullptr);
    ASSERT_TRUE(pb.pose(0, 52.0, p, nullptr, &anchor));
    EXPECT_TRUE(std::isnan(anchor)) << "before the boundary: held";
    for (double d : {52.5, 53.0, 55.0}) {
        ASSERT_TRUE(pb.pose(0, d, p, nullptr, &anchor));
        EXPECT_EQ(anchor, 51.0) << "past the boundary at " << d;
        EXPECT_LT(glm::length(p.t - here), 1e-3f);
    }
    double held = 0;
    ASSERT_TRUE(pb.pose(0, 53.0, p, &held));  // no anchor asked for: held
    EXPECT_EQ(held, 51.0);
    // Once the next epoch's first frame is here, it is used from its tick on.
    const glm::vec3 there(-4, 7, -6);
    ASSERT_TRUE(pb.add_chunk(54, 0, 2, 2, records(2, there).run(), 2, 4));
    ASSERT_TRUE(pb.pose(0, 54.0, p, nullptr, &anchor));
    EXPECT_LT(glm::length(p.t - there), 1e-3f);
}

// Inconsistent chunks are refused (false) and change nothing; a chunk older
// than every kept frame is dropped without effect.
TEST(PoseBuffer, RefusesInconsistentChunksAndIgnoresStaleOnes) {
    PoseBuffer pb = buffer(4);
    const auto r4 = records(4, glm::vec3(1, 1, 1));
    struct Case {
        const char* what;
        int first, count, total, show;
    };
    const Case bad[] = {
        {"total past the bone count", 0, 1, 5, 5},
        {"total 0", 0, 1, 0, 0},
        {"first < 0", -1, 1, 2, 2},
        {"count 0", 0, 0, 2, 2},
        {"bones past total", 1, 2, 2, 2},
        {"show below total", 0, 2, 3, 2},
        {"show past the bone count", 0, 2, 2, 5},
    };
    for (const Case& c : bad) {
        EXPECT_FALSE(pb.add_chunk(7, c.first, c.count, c.total, r4.run(), c.show)) << c.what;
        EXPECT_TRUE(pb.empty()) << c.what;
    }
    BonePose p;
    EXPECT_FALSE(pb.pose(0, 7.0, p));  // never received
    EXPECT_EQ(pb.bones_at(7.0), 0);

    ASSERT_TRUE(pb.add_chunk(7, 0, 2, 4, r4.run(), 4, 0));
    // The same tick with another total, show or epoch: refused, the frame unchanged.
    const auto moved = records(4, glm::vec3(5, 5, 5));
    EXPECT_FALSE(pb.add_chunk(7, 2, 1, 3, moved.run(), 4, 0));
    EXPECT_FALSE(pb.add_chunk(7, 2, 2, 4, moved.run(), 4, 1));
    EXPECT_FALSE(pb.pose(2, 7.0, p));  // none of the refused bones landed
    EXPECT_TRUE(pb.add_chunk(7, 2, 2, 4, moved.run(2), 4, 0));  // the rest of the frame
    EXPECT_LT(glm::length(pose_of(pb, 2, 7.0).t - glm::vec3(7, 5, 5)), 1e-3f);

    // Fill the history with newer frames; a chunk older than all of them changes nothing.
    for (uint32_t t = 8; t < 8 + PoseBuffer::kHistory; ++t) ASSERT_TRUE(pb.add_chunk(t, 0, 4, 4, r4.run()));
    const uint32_t newest = pb.newest_tick();
    const BonePose before = pose_of(pb, 0, 30.0);
    pb.add_chunk(5, 0, 4, 4, moved.run());
    EXPECT_EQ(pb.newest_tick(), newest);
    EXPECT_LT(glm::length(pose_of(pb, 0, 30.0).t - before.t), 1e-6f);
    EXPECT_LT(glm::length(pose_of(pb, 0, 5.0).t - glm::vec3(1, 1, 1)), 1e-3f) << "the stale frame was kept";
}

// The bones shown: the newest frame's show, limited to bones ever received;
// a bone a frame does not carry is interpolated between its own frames.
TEST(PoseBuffer, ShowAndPerBoneFrames) {
    PoseBuffer pb = buffer(6);
    ASSERT_TRUE(pb.add_chunk(20, 0, 6, 6, records(6, glm::vec3(0, 0, 0)).run()));
    // Tick 22: bones 0..2 carried, 4 shown: bone 3 comes from tick 20, bone 4-5 hidden.
    ASSERT_TRUE(pb.add_chunk(22, 0, 3, 3, records(3, glm::vec3(0, 2, 0)).run(), 4));
    EXPECT_EQ(pb.bones_at(22.0), 4);
    EXPECT_EQ(pb.bones_at(21.0), 6);
    // Tick 24: bone 3 alone (a refresh), show 4.
    ASSERT_TRUE(pb.add_chunk(24, 3, 1, 4, record(glm::vec3(3, 4, 0)).run(), 4));
    EXPECT_LT(glm::length(pose_of(pb, 3, 22.0).t - glm::vec3(3, 2, 0)), 1e-2f) << "bone 3 between its frames 20 and 24";
    EXPECT_LT(glm::length(pose_of(pb, 1, 21.0).t - glm::vec3(1, 1, 0)), 1e-2f);
    EXPECT_TRUE(pb.covers(20.0));
    EXPECT_FALSE(pb.covers(19.0));
}

// The root block: lerp of the position and slerp of the rotation between
// frames of one epoch, held across an epoch change; absent without blocks.
TEST(PoseBuffer, RootInterpolatesWithinAnEpoch) {
    PoseBuffer pb = buffer(2);
    const auto rec = records(2, glm::vec3(0));
    RootPose r;
    ASSERT_TRUE(pb.add_chunk(10, 0, 2, 2, rec.run()));
    EXPECT_FALSE(pb.root(10.0, r));
    const auto a = root_block({0, 0, 0}, 0.0f), b = root_block({4, 0, -2}, 1.0f), c = root_block({100, 0, 0}, 0.0f);
    ASSERT_TRUE(pb.add_chunk(12, 0, 2, 2, rec.run(), 2, 0, a));
    ASSERT_TRUE(pb.add_chunk(14, 0, 2, 2, rec.run(), 2, 0, b));
    ASSERT_TRUE(pb.add_chunk(16, 0, 2, 2, rec.run(), 2, 1, c));
    ASSERT_TRUE(pb.root(13.0, r));
    EXPECT_NEAR(glm::length(r.position - glm::dvec3(2, 0, -1)), 0.0, 2e-3);
    EXPECT_NEAR(rotation_angle(r.rotation, glm::angleAxis(0.5f, glm::vec3(0, 1, 0))), 0.0, 1e-3);
    ASSERT_TRUE(pb.root(15.0, r));  // between epochs: held
    EXPECT_NEAR(glm::length(r.position - glm::dvec3(4, 0, -2)), 0.0, 2e-3);
    ASSERT_TRUE(pb.root(16.0, r));
    EXPECT_NEAR(r.position.x, 100.0, 2e-3);
}

// Past the newest root, the root carries on along its two newest frames for
// at most kRootExtrapolationTicks, then holds; never toward a frame of
// another epoch (a teleport).
TEST(PoseBuffer, RootCarriesOnBrieflyPastTheNewestFrame) {
    PoseBuffer pb = buffer(2);
    const auto rec = records(2, glm::vec3(0));
    ASSERT_TRUE(pb.add_chunk(10, 0, 2, 2, rec.run(), 2, 0, root_block({0, 0, 0}, 0.0f)));
    ASSERT_TRUE(pb.add_chunk(12, 0, 2, 2, rec.run(), 2, 0, root_block({2, 0, 0}, 0.0f)));  // 1 unit per tick
    RootPose r;
    ASSERT_TRUE(pb.root(13.0, r));
    EXPECT_NEAR(r.position.x, 3.0, 2e-3);
    const double cap = 2.0 + PoseBuffer::kRootExtrapolationTicks;
    ASSERT_TRUE(pb.root(20.0, r));
    EXPECT_NEAR(r.position.x, cap, 2e-3) << "held after kRootExtrapolationTicks";
    pb.set_root_extrapolation(0);
    ASSERT_TRUE(pb.root(13.0, r));
    EXPECT_NEAR(r.position.x, 2.0, 2e-3) << "held at once";
    pb.set_root_extrapolation(PoseBuffer::kRootExtrapolationTicks);
    ASSERT_TRUE(pb.add_chunk(16, 0, 2, 2, rec.run(), 2, 1, root_block({-50, 0, 0}, 0.0f)));  // a teleport
    ASSERT_TRUE(pb.root(13.0, r));
    EXPECT_NEAR(r.position.x, 2.0, 2e-3) << "held until the next epoch";
}

// Predicted root blocks (root_block.h) decode from the roots this buffer
// received at their baseline ticks, delta and linear, to the very integers
// sent; one whose baseline is not here is refused and counted, and nothing
// of its chunk is applied.
TEST(PoseBuffer, PredictedRootsDecodeFromTheirBaselineTicks) {
    PoseBuffer pb = buffer(2);
    const auto rec = records(2, glm::vec3(0));
    const auto r10 = absolute_root({1.0, 0.0, 2.0}, 0.10f, 1'000'000), r12 = absolute_root({1.1, 0.0, 2.05}, 0.12f, 1'066'700),
               r14 = absolute_root({1.2, 0.0, 2.1}, 0.14f, 1'133'300), r16 = absolute_root({1.31, 0.0, 2.16}, 0.16f, 1'200'050);
    std::vector<uint8_t> block;
    write_root(r10.data(), 0, nullptr, nullptr, block);
    ASSERT_TRUE(pb.add_chunk(10, 0, 2, 2, rec.run(), 2, 0, block));
    block.clear();
    write_root(r12.data(), 2, r10.data(), nullptr, block);  // from tick 10
    EXPECT_EQ(root_base(block.data()), 2);
    EXPECT_LT(block.size(), 12u);
    ASSERT_TRUE(pb.add_chunk(12, 0, 2, 2, rec.run(), 2, 0, block));
    block.clear();
    write_root(r14.data(), 2 | kBaseLinear, r12.data(), r10.data(), block);  // from ticks 12 and 10
    EXPECT_EQ(root_base(block.data()), 2 | kBaseLinear);
    EXPECT_LT(block.size(), 9u);
    ASSERT_TRUE(pb.add_chunk(14, 0, 2, 2, rec.run(), 2, 0, block));
    RootPose r;
    ASSERT_TRUE(pb.root(14.0, r));
    const RootPose want = decode_root(r14.data());
    EXPECT_EQ(r.position, want.position);  // exact: the same integers
    EXPECT_EQ(r.source_us, want.source_us);
    EXPECT_EQ(rotation_angle(r.rotation, want.rotation), 0.0);
    // Tick 16 predicted from tick 13, which this buffer never received.
    block.clear();
    write_root(r16.data(), 3, r12.data(), nullptr, block);
    const uint64_t missing = pb.missing_baselines();
    EXPECT_FALSE(pb.add_chunk(16, 0, 2, 2, rec.run(), 2, 0, block));
    EXPECT_EQ(pb.missing_baselines(), missing + 1);
    EXPECT_EQ(pb.newest_tick(), 14u);  // nothing applied
}

// Morph weights: lerped between frames of one epoch, a weight a frame does
// not carry keeps its earlier value, never interpolated across an epoch;
// indices past the morph count are refused.
TEST(PoseBuffer, MorphWeightsLerpWithinAnEpoch) {
    PoseBuffer pb = buffer(2, 3);
    ASSERT_EQ(pb.morph_count(), 3);
    std::array<float, 3> w{};
    ASSERT_TRUE(pb.add_morphs(8, 2, 2, 0, morph_block({{0, 0.5f}}).data()));
    pb.weights_at(8.0, w);
    EXPECT_FLOAT_EQ(w[1], 0.0f) << "a weight never received is 0";
    ASSERT_TRUE(pb.add_morphs(10, 2, 2, 0, morph_block({{0, 0.0f}, {1, 1.0f}, {2, -0.5f}}).data()));
    ASSERT_TRUE(pb.add_morphs(14, 2, 2, 0, morph_block({{0, 1.0f}}).data()));
    EXPECT_FALSE(pb.add_morphs(15, 2, 2, 0, morph_block({{3, 1.0f}}).data()));
    pb.weights_at(11.0, w);
    EXPECT_NEAR(w[0], 0.25f, 1e-4f);
    EXPECT_NEAR(w[1], 1.0f, 1e-4f);  // not carried at 14: kept
    EXPECT_NEAR(w[2], -0.5f, 1e-4f);
    ASSERT_TRUE(pb.add_morphs(18, 2, 2, 1, morph_block({{0, -1.0f}}).data()));
    pb.weights_at(16.0, w);
    EXPECT_NEAR(w[0], 1.0f, 1e-4f) << "interpolated across the epoch change";
    pb.weights_at(18.0, w);
    EXPECT_NEAR(w[0], -1.0f, 1e-4f);
    pb.weights_at(30.0, w);  // held after the newest
    EXPECT_NEAR(w[0], -1.0f, 1e-4f);
}
