// libFuzzer driver for the glTF importer (scripts/fuzz.sh builds it with
// clang -fsanitize=fuzzer,address,undefined).
#include "fuzz_targets.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    progskin::fuzz::gltf_import(data, size);
    return 0;
}
