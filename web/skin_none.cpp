// skin_none.cpp — the CPU skinning kernels of common/skinning.h for the
// WebAssembly build, which has no Highway (common/skinning_simd.cpp): the
// page skins on the GPU (three.js SkinnedMesh from the streamed palette), so
// these only refuse. InstanceView::skin (the native client's --verify) is
// not used in the browser.
#include "skinning.h"

namespace progskin {

bool skin_stream(const SkinStream&, std::span<const Mat34>, std::span<glm::vec3>, std::span<glm::vec3>,
                 const SkinRunOptions&) {
    return false;
}
bool skin_many(std::span<const SkinTask> tasks) { return tasks.empty(); }
const char* skin_simd_target() { return "none (WebAssembly build: the GPU skins)"; }

}  // namespace progskin
