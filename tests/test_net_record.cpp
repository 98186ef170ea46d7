// test_net_record.cpp — the parent-relative bone record (bone_record.h):
// bit coding round trips, hostile bits, and the error and size it costs on
// real characters against the absolute 12-byte record (bone_codec.h),
// measured with the error metric against the reference.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "bone_codec.h"
#include "asset_cache.h"
#include "bone_record.h"
#include "error_metric.h"
#include "progressive_skin.h"
#include "scene.h"
#include "skinning.h"

using namespace progskin;
using namespace progskin::net;

// append_bits (the packer's copy of a run of records) against a bit-by-bit
// copy: every start bit in the output and the source, runs from 1 bit to
// several windows, the source's bytes past the run never read (the run ends
// at the buffer's end), the output's unused high bits zero.
TEST(NetRecord, AppendBitsCopiesAnyRunBitForBit) {
    std::mt19937 rng(11);
    auto bit = [](const std::vector<uint8_t>& v, size_t i) { return (v[i / 8] >> (i % 8)) & 1; };
    for (int trial = 0; trial < 4000; ++trial) {
        const size_t lead = rng() % 70, from = rng() % 20;
        const size_t count = trial % 4 == 0 ? 1 + rng() % 8 : 1 + rng() % 300;
        std::vector<uint8_t> src((from + count + 7) / 8);  // exactly the bytes the run touches
        for (uint8_t& b : src) b = uint8_t(rng());
        std::vector<uint8_t> lead_bits(lead);
        for (uint8_t& b : lead_bits) b = uint8_t(rng() & 1);
        std::vector<uint8_t> out;
        BitWriter w(out);
        for (uint8_t b : lead_bits) w.put(b, 1);
        w.append_bits(src.data(), from, count);
        ASSERT_EQ(w.bits(), lead + count);
        ASSERT_EQ(out.size(), (lead + count + 7) / 8);
        for (size_t i = 0; i < lead; ++i) ASSERT_EQ(bit(out, i), lead_bits[i]) << trial;
        for (size_t i = 0; i < count; ++i) ASSERT_EQ(bit(out, lead + i), bit(src, from + i)) << trial << " bit " << i;
        for (size_t i = lead + count; i < out.size() * 8; ++i) ASSERT_EQ(bit(out, i), 0) << trial;
        w.put(1, 1);  // the writer goes on where the run ended
        ASSERT_EQ(bit(out, lead + count), 1);
    }
}

TEST(NetRecord, ExpGolombRoundTripsEveryOrderAndWidth) {
    std::vector<uint8_t> bytes;
    BitWriter w(bytes);
    std::mt19937 rng(3);
    std::vector<std::pair<uint32_t, int>> values;
    for (int i = 0; i < 5000; ++i) {
        const int k = int(rng() % 13);
        const uint32_t u = uint32_t(rng()) >> (rng() % 32);
        if (std::bit_width(uint64_t(u) + (uint64_t(1) << k)) - 1 - k > kMaxPrefix) continue;
        values.push_back({u, k});
        w.put_eg(u, k);
        w.put(rng() & 7, 3);
    }
    BitReader r(bytes.data(), bytes.size());
    for (auto [u, k] : values) {
        uint64_t got = 0, pad = 0;
        ASSERT_TRUE(r.get_eg(k, got));
        EXPECT_EQ(got, u);
        ASSERT_TRUE(r.get(3, pad));
    }
    EXPECT_LT(r.size() - r.at(), 8u);
    // Codes longer than the reader's 57-bit window (a writer's 32-bit values
    // never make one; a hostile stream may): z = kMaxPrefix zeros, order up
    // to 12, at every bit offset, in the middle of a buffer and at its end.
    for (int k = 0; k <= 12; ++k)
        for (int lead = 0; lead < 8; ++lead)
            for (int tail = 0; tail < 2; ++tail) {
                std::vector<uint8_t> b;
                BitWriter lw(b);
                lw.put(0x55, lead);
                const int z = kMaxPrefix;
                const uint64_t rest = (uint64_t(0x9E3779B97F4A7C15) >> (64 - (z + k))) | 1;
                lw.put(0, z);
                lw.put(1, 1);
                lw.put(rest, z + k);
                if (tail) lw.put(0xABCDEF, 24);
                BitReader lr(b.data(), b.size());
                uint64_t pad = 0, got = 0;
                ASSERT_TRUE(lr.get(lead, pad));
                ASSERT_TRUE(lr.get_eg(k, got)) << k << " " << lead;
                EXPECT_EQ(got, (uint64_t(1) << (z + k)) + rest - (uint64_t(1) << k)) << k << " " << lead;
                EXPECT_EQ(lr.at(), size_t(lead + 2 * z + k + 1));
                // Cut one bit short: refused, nothing read.
                if (!tail && (lead + 2 * z + k + 1) % 8 == 0) {
                    BitReader cut(b.data(), b.size() - 1);
                    ASSERT_TRUE(cut.get(lead, pad));
                    EXPECT_FALSE(cut.get_eg(k, got));
                    EXPECT_EQ(cut.at(), size_t(lead));
                }
            }
}

TEST(NetRecord, RandomPosesRoundTripWithinTheirSteps) {
    std::mt19937 rng(11);
    std::normal_distribution<float> n;
    RecordFormat box;
    box.t_min = glm::vec3(-2);
    box.t_max = glm::vec3(3);
    box.scaled = true;
    RelativeFormat f;
    f.parents = {-1};
    f.pivots = {glm::vec3(0.3f, 1.0f, -0.2f)};
    f.t_step = 5.0f / 65535.0f;
    f.scaled = true;
    double worst_angle = 0, worst_t = 0, worst_s = 0;
    for (int i = 0; i < 20000; ++i) {
        BonePose parent, m;
        parent.r = glm::normalize(glm::quat(n(rng), n(rng), n(rng), n(rng)));
        parent.t = glm::vec3(n(rng), n(rng), n(rng));
        parent.s = std::exp(0.2f * n(rng));
        m.r = glm::normalize(glm::quat(n(rng), n(rng), n(rng), n(rng)));
        m.t = glm::vec3(n(rng), n(rng), n(rng));
        m.s = std::exp(0.2f * n(rng));
        RecordInts ri;
        ASSERT_TRUE(quantise_record(parent, m, 0, f, ri));
        std::vector<uint8_t> bytes;
        BitWriter w(bytes);
        const size_t bits = write_record(ri, true, w);
        ASSERT_LE(bits, size_t(kMaxRecordBits));
        BitReader r(bytes.data(), bytes.size());
        RecordInts back;
        ASSERT_TRUE(read_record(r, true, back));
        EXPECT_EQ(r.at(), bits);
        const BonePose d = compose_relative(parent, dequantise_record(back, 0, f));
        glm::dquat a(m.r), b(d.r);
        if (glm::dot(a, b) < 0) b = -b;
        worst_angle = std::max(worst_angle, 4.0 * std::asin(std::min(1.0, glm::length(a - b) / 2.0)));
        worst_t = std::max(worst_t, double(glm::length(m.t - d.t)) / double(parent.s));
        worst_s = std::max(worst_s, double(std::fabs(d.s / m.s - 1.0f)));
    }
    EXPECT_LT(worst_angle, 2.0 * std::sqrt(3.0) * ROT_STEP * 1.05);
    EXPECT_LT(worst_t, std::sqrt(3.0) * (kTransDeadZone + 0.5) * f.t_step + 1e-5);
    EXPECT_LT(worst_s, 1.8e-4);
}

TEST(NetRecord, HostileBitsAreRefusedNeverMisread) {
    // Every prefix of a valid stream but the whole fails; random bytes either
    // fail or give integers within the bounds.
    RecordInts ri;
    ri.rot[0] = 30000;
    ri.rot[1] = -12;
    ri.has_trans = true;
    ri.trans[2] = -70000;
    std::vector<uint8_t> bytes;
    BitWriter w(bytes);
    const size_t bits = write_record(ri, false, w);
    for (size_t cut = 0; cut < bits; ++cut) {
        BitReader r(bytes.data(), (cut + 7) / 8);
        RecordInts out;
        if (cut / 8 * 8 == cut || (cut + 7) / 8 * 8 < bits) {
            EXPECT_FALSE(read_record(r, false, out)) << cut;
        }
    }
    // All-zero bits: a prefix longer than kMaxPrefix.
    std::vector<uint8_t> zeros(64, 0);
    BitReader z(zeros.data(), zeros.size());
    RecordInts out;
    EXPECT_FALSE(read_record(z, false, out));
    // Rotation integers whose norm exceeds |p| <= 1.
    RecordInts far;
    far.rot[0] = far.rot[1] = 40000;  // each within kMaxRotInt, the norm past it
    std::vector<uint8_t> fb;
    BitWriter fw(fb);
    write_record(far, false, fw);
    BitReader fr(fb.data(), fb.size());
    EXPECT_FALSE(read_record(fr, false, out));
    std::mt19937 rng(5);
    int accepted = 0;
    for (int i = 0; i < 20000; ++i) {
        std::vector<uint8_t> junk(1 + rng() % 24);
        for (auto& b : junk) b = uint8_t(rng());
        BitReader r(junk.data(), junk.size());
        if (!read_record(r, rng() & 1, out)) continue;
        ++accepted;
        const int64_t n2 = int64_t(out.rot[0]) * out.rot[0] + int64_t(out.rot[1]) * out.rot[1] + int64_t(out.rot[2]) * out.rot[2];
        ASSERT_LE(n2, int64_t(kMaxRotInt) * kMaxRotInt);
        for (int a = 0; a < 3; ++a) ASSERT_LE(std::abs(out.trans[a]), kMaxTransInt);
        ASSERT_LE(std::abs(out.scale), kMaxScaleInt);
    }
    EXPECT_GT(accepted, 0);
}

// Encodes every third training frame of a character closed loop, decodes it
// from the bits as a receiver would, skins, and compares the error and the
// size with the absolute record's.
struct Measured {
    double bits_per_bone = 0, rms_pct = 0, max_pct = 0;
    RecordFormat format;
};
static void measure(const std::string& path, Measured& m) {
    auto a = load_server_asset(path);
    const std::string file = path.substr(path.find_last_of('/') + 1);
    const Character& c = a->character;
    const ProgressiveSkin& s = a->skin;
    const int B = s.bone_count();
    const size_t nb = size_t(B);
    const RelativeFormat f = relative_format(s, c, a->format);
    FrameSet frames = sample_frames(c, a->selections, 30.0);
    std::vector<glm::vec3> ref(c.vertex_count()), got(c.vertex_count()), old(c.vertex_count());
    std::vector<Mat34> pal(c.joint_count()), pal_old(c.joint_count());
    std::vector<BonePose> model(nb), decoded(nb), received(nb);
    std::vector<uint32_t> offsets(nb + 1);
    ErrorAccumulator rel(rest_diagonal(c)), abs_(rest_diagonal(c));
    size_t bits = 0, records = 0, predicted_bits = 0;
    std::vector<RecordInts> ints(nb), prev(nb);
    uint8_t rec[14];
    for (size_t fr = 0; fr < frames.frame_count(); fr += 3) {
        reference_positions(c, frames, fr, ref);
        for (int b = 0; b < B; ++b) model[size_t(b)] = decompose(frames.frame(fr)[size_t(s.order[size_t(b)])]);
        std::vector<uint8_t> stream;
        ASSERT_TRUE(encode_pose(model, f, stream, offsets, decoded, ints));
        bits += offsets[size_t(B)];
        if (fr > 0) {  // predicted from the frame 3 ticks older: decodes to the same integers
            std::vector<uint8_t> pbits;
            BitWriter pw(pbits);
            for (size_t b = 0; b < nb; ++b) write_predicted(ints[b], predict_record(prev[b], 3), f.scaled, pw);
            predicted_bits += pw.bits();
            BitReader pr(pbits.data(), pbits.size());
            for (size_t b = 0; b < nb; ++b) {
                RecordInts back;
                ASSERT_TRUE(read_predicted(pr, predict_record(prev[b], 3), f.scaled, back));
                for (int x = 0; x < 3; ++x) {
                    ASSERT_EQ(back.rot[x], ints[b].rot[x]);
                    ASSERT_EQ(back.has_trans ? back.trans[x] : 0, ints[b].has_trans ? ints[b].trans[x] : 0);
                }
            }
        } else {
            predicted_bits += offsets[size_t(B)];
        }
        prev = ints;
        records += size_t(B);
        BitReader r(stream.data(), stream.size());
        for (int b = 0; b < B; ++b) {
            RecordInts ri;
            ASSERT_EQ(r.at(), offsets[size_t(b)]);
            ASSERT_TRUE(read_record(r, f.scaled, ri));
            const int p = f.parents[size_t(b)];
            received[size_t(b)] = compose_relative(p >= 0 ? received[size_t(p)] : BonePose{}, dequantise_record(ri, b, f));
            ASSERT_LT(glm::length(received[size_t(b)].t - decoded[size_t(b)].t), 1e-5f * (1.0f + glm::length(decoded[size_t(b)].t)));
            const int j = s.order[size_t(b)];
            pal[size_t(j)] = compose(received[size_t(b)]);
            encode_bone(model[size_t(b)], a->format, rec);
            pal_old[size_t(j)] = compose(decode_bone(rec, a->format));
        }
        for (auto* p : {&pal, &pal_old}) {
            const SkinningJob job = skinning_job(c, *p, p == &pal ? got : old);
            ASSERT_TRUE(job.validate());
            job.run();
        }
        rel.add(ref, got);
        abs_.add(ref, old);
    }
    const ErrorStats e = rel.stats(), o = abs_.stats();
    const double bound = relative_bound(f, a->bind_radius, a->max_scale);
    const double rel_bits = double(bits) / double(records), pred_bits = double(predicted_bits) / double(records);
    std::printf("%s: predicted from 3 ticks before %.1f bits/bone\n", file.c_str(), pred_bits);
    std::printf("%s: relative %.1f bits/bone RMS %.5f%% max %.5f%% (bound %.5f%%); absolute %d bits RMS %.5f%% max %.5f%%\n",
                file.c_str(), double(bits) / double(records), e.rms_pct, e.max_pct, 100.0 * bound / rest_diagonal(c),
                a->format.size() * 8, o.rms_pct, o.max_pct);
    m.bits_per_bone = rel_bits;
    m.rms_pct = e.rms_pct;
    m.max_pct = e.max_pct;
    m.format = a->format;
    EXPECT_LE(e.max, bound);
    EXPECT_LE(e.rms_pct, o.rms_pct);   // the same or lower error than the absolute record
    EXPECT_LE(e.max_pct, o.max_pct);
    EXPECT_LT(rel_bits, 0.8 * a->format.size() * 8);  // smaller on its own (measured: 0.55 and 0.76)
    EXPECT_LT(pred_bits, 0.9 * rel_bits);             // and smaller still predicted
}

// predicted_bits prices a predicted record without writing it (a client's
// plan prices every bone, the packer writes the ones that go): it must be
// the length write_predicted writes, for residuals from none to the
// integers' bounds, with and without translation and scale, and the record
// it prices must read back as the one written.
TEST(NetRecord, PredictedBitsIsTheLengthWritten) {
    std::mt19937 rng(11);
    auto value = [&](int32_t bound) -> int32_t {
        switch (rng() % 4) {
            case 0: return 0;
            case 1: return int32_t(rng() % 5) - 2;
            case 2: return int32_t(rng() % 401) - 200;
            default: return int32_t(rng() % (2 * uint32_t(bound) + 1)) - bound;
        }
    };
    auto record = [&] {
        RecordInts r;
        for (int a = 0; a < 3; ++a) r.rot[a] = value(kMaxRotInt / 2);
        r.has_trans = rng() % 2;
        if (r.has_trans)
            for (int a = 0; a < 3; ++a) r.trans[a] = value(1 << 20);  // residuals within an Exp-Golomb prefix of kMaxPrefix
        r.has_scale = rng() % 3 == 0;
        if (r.has_scale) r.scale = value(kMaxScaleInt);
        return r;
    };
    int same = 0;
    for (int i = 0; i < 20000; ++i) {
        const RecordInts now = record();
        RecordInts pred = rng() % 4 == 0 ? now : record();
        if (rng() % 3 == 0) pred.rot[rng() % 3] = now.rot[0];
        const bool scaled = rng() % 2;
        std::vector<uint8_t> bits;
        BitWriter w(bits);
        const size_t written = write_predicted(now, pred, scaled, w);
        ASSERT_EQ(predicted_bits(now, pred, scaled), written) << "record " << i;
        same += written == 1;
        BitReader r(bits.data(), bits.size());
        RecordInts back;
        ASSERT_TRUE(read_predicted(r, pred, scaled, back)) << "record " << i;
        EXPECT_EQ(r.at(), written);
        for (int a = 0; a < 3; ++a) {
            EXPECT_EQ(back.rot[a], now.rot[a]);
            EXPECT_EQ(back.trans[a], now.has_trans ? now.trans[a] : 0);
        }
        EXPECT_EQ(back.scale, scaled && now.has_scale ? now.scale : 0);
    }
    EXPECT_GT(same, 1000);  // the one-bit "as predicted" record was among them
}

TEST(NetRecord, FoxSmallerAtNoMoreError) {
    Measured m;
    measure(std::string(PROGSKIN_ASSETS) + "/Fox.glb", m);
}
TEST(NetRecord, CesiumManSmallerAtNoMoreError) {
    Measured m;
    measure(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb", m);
}

// A skin under an armature node that turns centimetres into metres (every
// skinning matrix scaled 0.01, as exporters from centimetre scenes write
// it) codes as the same character in metres: the reference scale takes the
// 0.01, no record carries a scale, the translations step in their parent's
// units. Before the reference scale its records carried a scale each and
// stepped their translations 100 times finer than the metre file's.
TEST(NetRecord, AnArmatureScaleCodesAsTheSameSkinInMetres) {
    Measured cm, m;
    measure(std::string(PROGSKIN_TEST_DATA) + "/armature_cm.gltf", cm);
    measure(std::string(PROGSKIN_TEST_DATA) + "/armature_m.gltf", m);
    EXPECT_NEAR(cm.format.scale, 0.01f, 0.01f * 1e-4f);
    EXPECT_FALSE(cm.format.scaled);
    EXPECT_EQ(m.format.scale, 1.0f);
    EXPECT_FALSE(m.format.scaled);
    EXPECT_NEAR(cm.bits_per_bone, m.bits_per_bone, 0.02 * m.bits_per_bone);
    EXPECT_NEAR(cm.rms_pct, m.rms_pct, 0.1 * m.rms_pct);
    EXPECT_LE(cm.max_pct, 1.1 * m.max_pct);
}

// Protocol 10: the translation box covers every rigid pose of the skeleton
// (live poses beyond the clips), and the relative records step at the clips'
// own box (Asset.t_step), so that clips stream as finely as before the box
// grew. A step that would take more than 2^22 steps across the box, or is not
// finite and positive (0: the box's own), is refused.
TEST(NetRecord, TheTranslationStepIsTheClipsWhateverTheBox) {
    const auto a = load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb");
    const glm::vec3 ext = a->format.t_max - a->format.t_min;
    const float box_step = std::max({ext.x, ext.y, ext.z}) / 65535.0f;
    EXPECT_GT(a->format.t_step, 0.0f);
    EXPECT_LT(a->format.t_step, 0.8f * box_step) << "the box did not grow past the clips'";
    EXPECT_FLOAT_EQ(a->relative.t_step, a->format.t_step);
    RecordFormat f = a->format;
    f.t_step = 0;
    EXPECT_FLOAT_EQ(relative_format(a->skin, a->character, f).t_step, box_step);

    const glm::vec3 lo(-1.0f), hi(1.0f);
    EXPECT_TRUE(translation_step_fits(lo, hi, 0.0f));
    EXPECT_TRUE(translation_step_fits(lo, hi, 2.0f / 65535.0f));
    EXPECT_TRUE(translation_step_fits(lo, hi, 2.0f / float(1 << 22)));
    EXPECT_FALSE(translation_step_fits(lo, hi, 2.0f / float(1 << 23)));
    EXPECT_FALSE(translation_step_fits(lo, hi, -1e-3f));
    EXPECT_FALSE(translation_step_fits(lo, hi, std::nanf("")));
    EXPECT_FALSE(translation_step_fits(lo, hi, INFINITY));
    EXPECT_FALSE(translation_step_fits(lo, glm::vec3(INFINITY), 1e-3f));
}

// The client reads an Asset's record format before any download
// (read_asset_format, the fuzz target's Welcome case too): a translation step
// too fine for its box, or a bad reference scale, is refused with a reason.
TEST(NetRecord, AWelcomeAssetWithABadStepOrScaleIsRefused) {
    auto asset = [](float scale, float step) {
        flatbuffers::FlatBufferBuilder fbb;
        const wire::Vec3 lo(-1.0f, -1.0f, -1.0f), hi(1.0f, 1.0f, 1.0f);
        fbb.Finish(wire::CreateAsset(fbb, 1, 0, 0, 1, false, 0, 0, 0, 0, 1.0f, &lo, &hi, 0.0f, scale, step));
        return std::vector<uint8_t>(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
    };
    RecordFormat f;
    auto read = [&](const std::vector<uint8_t>& b) { return read_asset_format(*flatbuffers::GetRoot<wire::Asset>(b.data()), f); };
    EXPECT_EQ(read(asset(1.0f, 0.0f)), "");
    EXPECT_EQ(read(asset(0.01f, 2.0f / 65535.0f)), "");
    EXPECT_FLOAT_EQ(f.t_step, 2.0f / 65535.0f);
    EXPECT_FLOAT_EQ(f.scale, 0.01f);
    EXPECT_EQ(read(asset(1.0f, 2.0f / float(1 << 23))), "a bad translation step");
    EXPECT_EQ(read(asset(1.0f, -1.0f)), "a bad translation step");
    EXPECT_EQ(read(asset(0.0f, 0.0f)), "a bad reference scale");
}
