// fuzz_corpus.h — reads a fuzz corpus directory (fuzz/corpus/SUB) for the
// replay tests (test_fuzz_corpus.cpp, test_net_fuzz_corpus.cpp). found =
// false leaves out the inputs libFuzzer found (files named fuzz-*), keeping
// the hand-made or generated seeds.
#pragma once
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

inline std::vector<std::vector<uint8_t>> read_corpus(const std::string& sub, bool found = true) {
    std::vector<std::vector<uint8_t>> out;
    for (const auto& e : std::filesystem::directory_iterator(std::filesystem::path(PROGSKIN_FUZZ_CORPUS) / sub)) {
        if (!found && e.path().filename().string().rfind("fuzz-", 0) == 0) continue;
        std::ifstream f(e.path(), std::ios::binary);
        out.emplace_back(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    }
    return out;
}
