// test_root_block.cpp — the chunk's root block (proto/root_block.h):
// absolute and predicted blocks decode to the very block sent, a walking
// character's predicted root is a few bytes, and malformed or out-of-bound
// blocks are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "bone_codec.h"
#include "bone_record.h"
#include "root_block.h"

using namespace progskin::net;

namespace {

std::array<uint8_t, ROOT_BYTES> absolute(glm::dvec3 p, float yaw, uint64_t source_us) {
    RootPose r;
    r.position = p;
    r.rotation = glm::angleAxis(yaw, glm::vec3(0, 1, 0));
    r.source_us = source_us;
    std::array<uint8_t, ROOT_BYTES> out{};
    EXPECT_TRUE(encode_root(r, out.data()));
    return out;
}

// A walk around a circle of radius 3 m at 1.4 m/s, sampled at 30 Hz with the
// publisher's clock jittering by up to 4 ms.
std::vector<std::array<uint8_t, ROOT_BYTES>> walk(int ticks, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> jitter(-4000, 4000);
    std::vector<std::array<uint8_t, ROOT_BYTES>> out;
    for (int t = 0; t < ticks; ++t) {
        const uint64_t us = 5'000'000'000ull + uint64_t(t) * 33'333u + uint64_t(int64_t(jitter(rng)) + 4000);
        const double s = double(us) * 1e-6, a = s * 1.4 / 3.0;
        out.push_back(absolute({3.0 * std::cos(a) + 100.0, 0.02 * std::sin(7.0 * s), 3.0 * std::sin(a) - 40.0},
                               float(-a), us));
    }
    return out;
}

}  // namespace

TEST(RootBlock, AbsoluteBlocksRoundTrip) {
    const auto r = absolute({-2147483.0, 2147483.0, 0.5}, 2.5f, ~uint64_t(0) - 7);
    std::vector<uint8_t> block;
    EXPECT_EQ(write_root(r.data(), 0, nullptr, nullptr, block), kRootAbsoluteBytes);
    EXPECT_EQ(root_size(block.data(), block.size()), kRootAbsoluteBytes);
    EXPECT_EQ(root_base(block.data()), 0);
    std::array<uint8_t, ROOT_BYTES> back{};
    ASSERT_TRUE(read_root(block.data(), block.size(), nullptr, nullptr, back.data()));
    EXPECT_EQ(back, r);
    // A baseline given for nothing changes nothing: base 0 is absolute.
    block.clear();
    write_root(r.data(), 0, r.data(), r.data(), block);
    EXPECT_EQ(block.size(), kRootAbsoluteBytes);
}

// Delta and linear prediction over a walk: every block decodes to the very
// block sent, and the mean size is a fraction of the absolute 27 bytes.
TEST(RootBlock, PredictedBlocksDecodeExactlyAndAreSmall) {
    const auto roots = walk(300, 1);
    for (const uint32_t age : {1u, 2u, 4u, 7u}) {
        for (const bool linear : {false, true}) {
            size_t bytes = 0, n = 0;
            for (size_t t = 2 * age; t < roots.size(); ++t) {
                const uint8_t* b1 = roots[t - age].data();
                const uint8_t* b2 = linear ? roots[t - 2 * age].data() : nullptr;
                const uint8_t base = uint8_t(age | (linear ? kBaseLinear : 0));
                std::vector<uint8_t> block = {0xAB};  // appended after what is there
                const size_t w = write_root(roots[t].data(), base, b1, b2, block);
                ASSERT_EQ(w, block.size() - 1);
                const uint8_t* at = block.data() + 1;
                ASSERT_EQ(root_size(at, w), w);
                EXPECT_EQ(root_base(at), base);
                std::array<uint8_t, ROOT_BYTES> back{};
                ASSERT_TRUE(read_root(at, w, b1, b2, back.data())) << "tick " << t;
                ASSERT_EQ(back, roots[t]) << "tick " << t << " age " << age << " linear " << linear;
                // Without its baseline it does not decode.
                EXPECT_FALSE(read_root(at, w, nullptr, b2, back.data()));
                bytes += w;
                ++n;
            }
            const double mean = double(bytes) / double(n);
            std::printf("age %u %s: %.2f bytes per root block\n", age, linear ? "linear" : "delta ", mean);
            EXPECT_LT(mean, linear ? 9.0 : 13.0) << "age " << age;
        }
    }
}

// A turn that changes the rotation's largest component, a teleport and a
// clock jump: still exact (absolute rotation, or the whole block absolute).
TEST(RootBlock, LargeChangesStayExact) {
    const auto a = absolute({0, 0, 0}, 0.0f, 1000), b = absolute({0, 0, 0}, 3.0f, 1100),
               far = absolute({2000000.0, -2000000.0, 5.0}, 3.0f, 1200), late = absolute({0, 0, 0}, 3.0f, uint64_t(1) << 62);
    for (const auto* now : {&b, &far, &late}) {
        std::vector<uint8_t> block;
        write_root(now->data(), 1, a.data(), nullptr, block);
        ASSERT_GT(root_size(block.data(), block.size()), 0u);
        std::array<uint8_t, ROOT_BYTES> back{};
        ASSERT_TRUE(read_root(block.data(), block.size(), a.data(), nullptr, back.data()));
        EXPECT_EQ(back, *now);
    }
}

TEST(RootBlock, MalformedBlocksAreRefused) {
    const auto roots = walk(10, 2);
    std::vector<uint8_t> good;
    write_root(roots[5].data(), 1 | kBaseLinear, roots[4].data(), roots[3].data(), good);
    ASSERT_GT(good.size(), 1u);
    std::array<uint8_t, ROOT_BYTES> back{};
    // Truncated: every shorter prefix is refused by the syntax walk.
    for (size_t n = 0; n < good.size(); ++n) EXPECT_EQ(root_size(good.data(), n), 0u) << n;
    // Linear without an age.
    std::vector<uint8_t> abs;
    write_root(roots[5].data(), 0, nullptr, nullptr, abs);
    abs[0] |= 16;
    EXPECT_EQ(root_size(abs.data(), abs.size()), 0u);
    EXPECT_FALSE(read_root(abs.data(), abs.size(), nullptr, nullptr, back.data()));
    // A padding bit set (the absolute block's last 4 bits are padding).
    abs[0] &= uint8_t(~16);
    abs.back() |= 0x80;
    EXPECT_EQ(root_size(abs.data(), abs.size()), 0u);
    EXPECT_FALSE(read_root(abs.data(), abs.size(), nullptr, nullptr, back.data()));
    // A size other than the block's own.
    std::vector<uint8_t> longer = good;
    longer.push_back(0);
    EXPECT_FALSE(read_root(longer.data(), longer.size(), roots[4].data(), roots[3].data(), back.data()));
    // Random bytes: refused, or read within their bounds.
    std::mt19937 rng(7);
    int read = 0;
    for (int k = 0; k < 20000; ++k) {
        std::vector<uint8_t> junk(1 + rng() % 40);
        for (auto& x : junk) x = uint8_t(rng());
        const size_t n = root_size(junk.data(), junk.size());
        ASSERT_LE(n, junk.size());
        if (n && read_root(junk.data(), n, roots[4].data(), roots[3].data(), back.data())) ++read;
    }
    EXPECT_GT(read, 0);
}

// A residual that would put a value outside its bound is refused, never
// clamped: a position past int32 millimetres, a rotation component past 15 bits.
TEST(RootBlock, OutOfBoundValuesAreRefused) {
    const auto edge = absolute({2147483.647, 0, 0}, 0.0f, 0);
    const auto near_edge = absolute({2147483.600, 0, 0}, 0.0f, 0);
    // Written against near_edge (+47 mm), read against edge: 2^31 mm, past int32.
    std::vector<uint8_t> block;
    write_root(edge.data(), 1, near_edge.data(), nullptr, block);
    std::array<uint8_t, ROOT_BYTES> back{};
    ASSERT_TRUE(read_root(block.data(), block.size(), near_edge.data(), nullptr, back.data()));
    EXPECT_FALSE(read_root(block.data(), block.size(), edge.data(), nullptr, back.data()));
    // A rotation residual taking a component past 0x7FFF.
    auto high = absolute({0, 0, 0}, 0.0f, 0), higher = high;
    high[12] = 0xFF, high[13] = 0xFF, high[14] = 0x01;    // index 3 (w largest), component 0 = 0x7FFF - ...
    higher = high;
    higher[12] = uint8_t(high[12] & ~0x04);                // component 0 one step lower in `higher`
    block.clear();
    write_root(high.data(), 1, higher.data(), nullptr, block);  // +1 on component 0
    ASSERT_TRUE(read_root(block.data(), block.size(), higher.data(), nullptr, back.data()));
    EXPECT_EQ(back, high);
    EXPECT_FALSE(read_root(block.data(), block.size(), high.data(), nullptr, back.data()));
}

TEST(RootBlock, RingResolvesFromHeldTicksOnly) {
    const auto roots = walk(40, 3);
    RootRing ring;
    for (uint32_t t = 0; t < 20; ++t) ring.put(100 + t, roots[t].data());
    ring.put(90, roots[30].data());  // older than the tick holding its place: ignored
    EXPECT_EQ(ring.at(90), nullptr);
    ASSERT_NE(ring.at(106), nullptr);
    std::vector<uint8_t> block;
    write_root(roots[20].data(), 4 | kBaseLinear, roots[16].data(), roots[12].data(), block);
    std::array<uint8_t, ROOT_BYTES> back{};
    bool missing = true;
    ASSERT_TRUE(ring.resolve(120, block.data(), block.size(), back.data(), &missing));
    EXPECT_FALSE(missing);
    EXPECT_EQ(back, roots[20]);
    // At tick 140, age 15: tick 125 was never received.
    block.clear();
    write_root(roots[20].data(), 15, roots[5].data(), nullptr, block);
    EXPECT_FALSE(ring.resolve(140, block.data(), block.size(), back.data(), &missing));
    EXPECT_TRUE(missing);
}
