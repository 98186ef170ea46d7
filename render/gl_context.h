// gl_context.h — a headless OpenGL 3.3 core context through EGL, no display.
//
// Tried in order: Mesa's surfaceless platform (llvmpipe software rasteriser, or
// the GPU's Mesa driver), EGL devices (EGL_EXT_device_enumeration: a real GPU,
// e.g. NVIDIA's EGL), then the default display with a 1x1 pbuffer. Rendering
// goes into framebuffer objects (renderer.h), so no window surface is needed.
// One context per process is enough; create() makes it current on the calling
// thread. LIBGL_ALWAYS_SOFTWARE=1 forces llvmpipe on a Mesa GPU driver.
#pragma once
#include <memory>
#include <string>

namespace progskin::render {

class GlContext {
public:
    // nullptr (and *error set) when no context can be created.
    static std::unique_ptr<GlContext> create(std::string* error = nullptr);
    ~GlContext();
    GlContext(const GlContext&) = delete;
    GlContext& operator=(const GlContext&) = delete;

    bool make_current();
    const std::string& renderer() const { return renderer_; }  // GL_RENDERER, e.g. "llvmpipe (LLVM 15...)"
    const std::string& platform() const { return platform_; }  // which EGL path was taken

private:
    GlContext() = default;
    void* display_ = nullptr;
    void* context_ = nullptr;
    void* surface_ = nullptr;
    std::string renderer_, platform_;
};

}  // namespace progskin::render
