#include "gl_context.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/gl.h>

#include <cstdio>
#include <vector>

namespace progskin::render {
namespace {

bool has_extension(const char* list, const char* name) {
    if (!list) return false;
    const std::string l = std::string(" ") + list + " ";
    return l.find(std::string(" ") + name + " ") != std::string::npos;
}

// Initialises `d` and creates a 3.3 core context; on success fills out.
bool try_display(EGLDisplay d, bool need_pbuffer, EGLContext& ctx, EGLSurface& surf) {
    if (d == EGL_NO_DISPLAY) return false;
    EGLint major = 0, minor = 0;
    if (!eglInitialize(d, &major, &minor)) return false;
    if (!eglBindAPI(EGL_OPENGL_API)) {
        eglTerminate(d);
        return false;
    }
    const EGLint cfg_attr[] = {EGL_SURFACE_TYPE,    EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                               EGL_RED_SIZE,        8,               EGL_GREEN_SIZE,      8,
                               EGL_BLUE_SIZE,       8,               EGL_NONE};
    EGLConfig cfg = nullptr;
    EGLint n = 0;
    eglChooseConfig(d, cfg_attr, &cfg, 1, &n);
    const bool no_config_ok = has_extension(eglQueryString(d, EGL_EXTENSIONS), "EGL_KHR_no_config_context");
    if (n < 1 && (need_pbuffer || !no_config_ok)) {
        eglTerminate(d);
        return false;
    }
    const EGLint ctx_attr[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
                               EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    ctx = eglCreateContext(d, n > 0 ? cfg : EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, ctx_attr);
    if (ctx == EGL_NO_CONTEXT) {
        eglTerminate(d);
        return false;
    }
    surf = EGL_NO_SURFACE;
    if (need_pbuffer) {
        const EGLint pb[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
        surf = eglCreatePbufferSurface(d, cfg, pb);
        if (surf == EGL_NO_SURFACE) {
            eglDestroyContext(d, ctx);
            eglTerminate(d);
            return false;
        }
    }
    if (!eglMakeCurrent(d, surf, surf, ctx)) {
        if (surf != EGL_NO_SURFACE) eglDestroySurface(d, surf);
        eglDestroyContext(d, ctx);
        eglTerminate(d);
        return false;
    }
    return true;
}

}  // namespace

std::unique_ptr<GlContext> GlContext::create(std::string* error) {
    std::unique_ptr<GlContext> g(new GlContext());
    const char* client_ext = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    auto get_platform_display =
        reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT"));
    EGLContext ctx = EGL_NO_CONTEXT;
    EGLSurface surf = EGL_NO_SURFACE;
    EGLDisplay d = EGL_NO_DISPLAY;
    bool ok = false;

    if (!ok && get_platform_display && has_extension(client_ext, "EGL_MESA_platform_surfaceless")) {
        d = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
        ok = try_display(d, false, ctx, surf);
        if (ok) g->platform_ = "EGL surfaceless (Mesa)";
    }
    if (!ok && get_platform_display && has_extension(client_ext, "EGL_EXT_platform_device")) {
        auto query_devices = reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
        EGLint count = 0;
        if (query_devices && query_devices(0, nullptr, &count) && count > 0) {
            std::vector<EGLDeviceEXT> devices(static_cast<size_t>(count));
            query_devices(count, devices.data(), &count);
            for (EGLint i = 0; i < count && !ok; ++i) {
                d = get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[size_t(i)], nullptr);
                ok = try_display(d, false, ctx, surf) || try_display(d, true, ctx, surf);
                if (ok) g->platform_ = "EGL device " + std::to_string(i);
            }
        }
    }
    if (!ok) {
        d = eglGetDisplay(EGL_DEFAULT_DISPLAY);
        ok = try_display(d, true, ctx, surf);
        if (ok) g->platform_ = "EGL default display (pbuffer)";
    }
    if (!ok) {
        if (error) *error = "no EGL display gave an OpenGL 3.3 core context (EGL error 0x" +
                            [] {
                                char b[16];
                                std::snprintf(b, sizeof b, "%x", unsigned(eglGetError()));
                                return std::string(b);
                            }() +
                            ")";
        return nullptr;
    }
    g->display_ = d;
    g->context_ = ctx;
    g->surface_ = surf;
    const char* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    const char* v = reinterpret_cast<const char*>(glGetString(GL_VERSION));
    g->renderer_ = std::string(r ? r : "?") + " | " + (v ? v : "?");
    return g;
}

bool GlContext::make_current() {
    return eglMakeCurrent(display_, static_cast<EGLSurface>(surface_), static_cast<EGLSurface>(surface_),
                          static_cast<EGLContext>(context_));
}

GlContext::~GlContext() {
    if (!display_) return;
    EGLDisplay d = static_cast<EGLDisplay>(display_);
    eglMakeCurrent(d, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    if (surface_) eglDestroySurface(d, static_cast<EGLSurface>(surface_));
    eglDestroyContext(d, static_cast<EGLContext>(context_));
    eglTerminate(d);
}

}  // namespace progskin::render
