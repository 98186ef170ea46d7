// libFuzzer driver: the glTF importer, or with PROGSKIN_FUZZ_FRAME_STREAM the
// frame stream, with PROGSKIN_FUZZ_CONTROL the control messages, or with
// PROGSKIN_FUZZ_RECORDS the parent-relative bone records, with
// PROGSKIN_FUZZ_WORLD the world bus's messages
// (scripts/fuzz.sh builds them with clang
// -fsanitize=fuzzer,address,undefined).
#include "fuzz_targets.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
#if defined(PROGSKIN_FUZZ_FRAME_STREAM)
    progskin::fuzz::frame_stream(data, size);
#elif defined(PROGSKIN_FUZZ_RECORDS)
    progskin::fuzz::bone_records(data, size);
#elif defined(PROGSKIN_FUZZ_CONTROL)
    progskin::fuzz::control_message(data, size);
#elif defined(PROGSKIN_FUZZ_WORLD)
    progskin::fuzz::world_message(data, size);
#else
    progskin::fuzz::gltf_import(data, size);
#endif
    return 0;
}
