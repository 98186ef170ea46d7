// fuzz_targets.h — entry points for fuzzing the parts that read bytes from
// outside: glTF files (the importer and the pose sampler) and protocol
// buffers (the FlatBuffers verifiers of both channels). Each must return
// normally for every input: bad input is a progskin::Error or a rejected
// buffer, never a crash, a hang or an unbounded allocation.
//
// libFuzzer drivers: fuzz/fuzz_main.cpp (scripts/fuzz.sh). Their corpora live
// in fuzz/corpus/ and tests/test_fuzz_corpus.cpp replays them in every CI run.
#pragma once
#include <cstddef>
#include <cstdint>

namespace progskin::fuzz {

// Writes the bytes to a temporary .glb (when they start with the GLB magic) or
// .gltf file, imports every character, samples a few poses. Returns 1 when the
// file was accepted, 0 when it was refused with an Error.
int gltf_import(const uint8_t* data, size_t size);

}  // namespace progskin::fuzz
