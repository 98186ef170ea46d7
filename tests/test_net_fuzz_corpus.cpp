// Replays the frame-stream fuzz corpus (fuzz/corpus/frame, real datagrams of
// the default character set written by fuzz/make_frame_corpus.cpp) and
// mutations of it through the fuzz entry point, in every CI run.
// scripts/fuzz.sh frame runs the coverage-guided libFuzzer driver.
#include <gtest/gtest.h>

#include <random>

#include "fuzz_corpus.h"
#include "fuzz_targets.h"

TEST(NetFuzzCorpus, FrameStreamAcceptsEverySeedAndSurvivesTheFoundInputs) {
    const auto seeds = read_corpus("frame", false);  // the real datagrams, not the found inputs
    ASSERT_GE(seeds.size(), 10u);
    for (const auto& in : seeds) EXPECT_EQ(progskin::fuzz::frame_stream(in.data(), in.size()), 1) << "a seed of " << in.size() << " bytes";
    int accepted = 0;  // the found inputs: each accepted or dropped, none crashes
    const auto all = read_corpus("frame");
    for (const auto& in : all) accepted += progskin::fuzz::frame_stream(in.data(), in.size());
    EXPECT_LT(accepted, int(all.size()));
}

TEST(NetFuzzCorpus, FrameStreamSurvivesMutations) {
    std::mt19937 rng(17);
    const auto inputs = read_corpus("frame");
    int dropped = 0, tried = 0;
    for (int i = 0; i < 100000; ++i) {
        std::vector<uint8_t> d = inputs[size_t(rng()) % inputs.size()];
        const int edits = 1 + int(rng() % 4);
        for (int k = 0; k < edits && !d.empty(); ++k) {
            const size_t at = size_t(rng()) % d.size();
            switch (rng() % 4) {
                case 0: d[at] = uint8_t(rng()); break;            // any byte
                case 1: d[at] ^= uint8_t(1u << (rng() % 8)); break;  // one bit
                case 2: d.resize(at); break;                       // truncate
                default: d.insert(d.begin() + long(at), uint8_t(rng())); break;
            }
        }
        ++tried;
        dropped += 1 - progskin::fuzz::frame_stream(d.data(), d.size());
    }
    // No crash or hang; damaged datagrams must reach the drop paths.
    EXPECT_GT(dropped, tried / 4);
    std::printf("frame stream: %d of %d mutated datagrams dropped\n", dropped, tried);
}

// 50,000 mutations of the seeds (1-4 edits: a byte replaced, or cut there)
// through an entry point; how many it refused.
static int refused_mutations(const std::vector<std::vector<uint8_t>>& seeds, unsigned seed,
                             int (*entry)(const uint8_t*, size_t)) {
    std::mt19937 rng(seed);
    int refused = 0;
    for (int i = 0; i < 50000; ++i) {
        std::vector<uint8_t> d = seeds[size_t(rng()) % seeds.size()];
        for (int k = 0, edits = 1 + int(rng() % 4); k < edits && !d.empty(); ++k) {
            const size_t at = size_t(rng()) % d.size();
            if (rng() % 3) d[at] = uint8_t(rng());
            else d.resize(at);
        }
        refused += 1 - entry(d.data(), d.size());
    }
    return refused;
}

// The control messages of players' characters (fuzz/corpus/control, written
// by make_frame_corpus) through the control-message entry point, and
// mutations of them: each accepted or refused, none crashes.
TEST(NetFuzzCorpus, ControlMessagesAcceptEverySeedAndSurviveMutations) {
    const auto seeds = read_corpus("control");
    ASSERT_GE(seeds.size(), 5u);
    for (const auto& in : seeds) EXPECT_EQ(progskin::fuzz::control_message(in.data(), in.size()), 1);
    const int refused = refused_mutations(seeds, 23, progskin::fuzz::control_message);
    EXPECT_GT(refused, 0);
}

// Parent-relative bone records (fuzz/corpus/records, written by
// make_frame_corpus) through the records entry point, and mutations of them:
// each accepted or refused, none crashes or reads past its bytes.
TEST(NetFuzzCorpus, BoneRecordsAcceptEverySeedAndSurviveMutations) {
    const auto seeds = read_corpus("records");
    ASSERT_GE(seeds.size(), 4u);
    for (const auto& in : seeds) EXPECT_EQ(progskin::fuzz::bone_records(in.data(), in.size()), 1);
    const int refused = refused_mutations(seeds, 29, progskin::fuzz::bone_records);
    EXPECT_GT(refused, 50000 / 4);
    std::printf("bone records: %d of 50000 mutated streams refused\n", refused);
}

// Another node's messages on the world bus (fuzz/corpus/world, written by
// make_frame_corpus, and the inputs of a libFuzzer run, fuzz-*) through the world-message entry point, and mutations of
// them: each accepted or refused whole, none crashes.
TEST(NetFuzzCorpus, WorldMessagesAcceptEverySeedAndSurviveMutations) {
    const auto seeds = read_corpus("world", false);  // the messages written, not the found inputs
    ASSERT_GE(seeds.size(), 3u);
    for (const auto& in : seeds) EXPECT_EQ(progskin::fuzz::world_message(in.data(), in.size()), 1);
    const auto all = read_corpus("world");  // the found inputs (fuzz-*): each accepted or refused
    int accepted = 0;
    for (const auto& in : all) accepted += progskin::fuzz::world_message(in.data(), in.size());
    EXPECT_LT(accepted, int(all.size()));
    const int refused = refused_mutations(seeds, 29, progskin::fuzz::world_message);
    EXPECT_GT(refused, 50000 / 4);
    std::printf("world messages: %d of 50000 mutations refused\n", refused);
}
