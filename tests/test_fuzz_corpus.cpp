// Replays the fuzz corpora (fuzz/corpus/) through the fuzz entry points, and
// mutations of them, so every CI run checks that bad input is refused
// cleanly. scripts/fuzz.sh runs the coverage-guided libFuzzer driver.
#include <gtest/gtest.h>

#include <random>

#include "fuzz_corpus.h"
#include "fuzz_targets.h"

TEST(FuzzCorpus, GltfImportAcceptsOrRefusesEveryInput) {
    const auto inputs = read_corpus("gltf");
    ASSERT_GE(inputs.size(), 10u);
    int accepted = 0;
    for (const auto& in : inputs) accepted += progskin::fuzz::gltf_import(in.data(), in.size());
    EXPECT_GT(accepted, 0);                   // the valid seeds load
    EXPECT_LT(accepted, int(inputs.size()));  // the broken seeds are refused
}

TEST(FuzzCorpus, GltfImportSurvivesMutations) {
    std::mt19937 rng(5);
    const auto inputs = read_corpus("gltf");
    int refused = 0, tried = 0;
    for (int i = 0; i < 3000; ++i) {
        std::vector<uint8_t> d = inputs[size_t(rng()) % inputs.size()];
        if (d.empty()) continue;
        const int edits = 1 + int(rng() % 8);
        for (int k = 0; k < edits; ++k) {
            const size_t at = size_t(rng()) % d.size();
            switch (rng() % 3) {
                case 0: d[at] = uint8_t(rng()); break;                                       // flip a byte
                case 1: d.resize(at + 1); break;                                             // truncate
                default: d.insert(d.begin() + long(at), d.begin(), d.begin() + long(std::min<size_t>(at, 16)));  // splice
            }
            if (d.empty()) break;
        }
        ++tried;
        refused += 1 - progskin::fuzz::gltf_import(d.data(), d.size());  // must return: Error or accepted
    }
    // Reaching here means no crash or hang; the mutations must also reach the
    // error paths (most damaged files are refused, not silently accepted).
    EXPECT_GT(refused, tried / 2);
}
