// renderer.h — off-screen OpenGL 3.3 rendering of skinned characters.
//
// Standard matrix-palette skinning in the vertex shader: per vertex up to 8
// joint indices (u16, integer attributes) and weights; the palette is the same
// array of row-major 3x4 matrices (Mat34) the CPU path uses, uploaded as a
// texture buffer (RGBA32F, three texels = three rows per bone), so any bone
// count fits. v' = (sum_i w_i * palette[j_i]) * v, normals by the blended 3x3,
// renormalised — the contract of skinning.h. The alternative input is vertices
// already skinned on the CPU (same shader, skinning switched off), which the
// tests compare against.
//
// Shading: one directional light plus a sky/ground ambient, base colour factor
// times base colour texture when the mesh has one (or per-vertex colours, for
// heat maps), a ground plane with a grid, 4x MSAA. Frames go into framebuffer
// objects and are read back into an Image (image.h).
#pragma once
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "image.h"
#include "mat34.h"
#include "mesh_data.h"

namespace progskin::render {

class GlContext;

struct Camera {
    glm::mat4 view{1.0f}, proj{1.0f};
    glm::vec3 eye{0.0f}, target{0.0f};
};

// Camera looking at the box [lo, hi] from azimuth (degrees about +Y, 0 = from
// +Z, the glTF front) and elevation (degrees above the horizon), at the
// distance where the box's corners fill about `fill` of the image's smaller
// half-extent. Y is up (glTF).
Camera frame_bounds(const Bounds& b, float aspect, float azimuth_deg = 35.0f, float elevation_deg = 15.0f,
                    float fov_y_deg = 30.0f, float fill = 0.9f);
// The same, framing the points themselves (tighter): their projected box is
// centred and fills `fill` of the view's larger relative extent.
Camera frame_points(std::span<const glm::vec3> points, float aspect, float azimuth_deg = 35.0f,
                    float elevation_deg = 15.0f, float fov_y_deg = 30.0f, float fill = 0.9f);

struct Ground {
    float height = 0.0f;             // y of the plane
    glm::vec3 center{0.0f};          // grid centre (x, z used)
    float extent = 10.0f;            // half size of the plane
    float spacing = 1.0f;            // grid line spacing
};
// A ground under the box: at its lowest y, extent a few times its size, spacing a 1-2-5 step.
Ground ground_under(const Bounds& b);

struct DrawParams {
    std::span<const Mat34> palette;         // GPU skinning from this palette (indices as in the mesh)
    std::span<const glm::vec3> positions;   // or: vertices skinned on the CPU (used when palette is empty)
    std::span<const glm::vec3> normals;     // with positions (empty: the mesh's bind normals)
    std::span<const glm::vec3> colors;      // per-vertex colours replacing the material (heat map), or empty
    Mat34 model = Mat34::identity();        // placement applied after skinning
    bool textured = true;                   // use base colour textures when the mesh has them
};

class Renderer {
public:
    // Creates the GL context (gl_context.h) and the shaders; nullptr and *error on failure.
    static std::unique_ptr<Renderer> create(std::string* error = nullptr);
    ~Renderer();

    const std::string& description() const;  // GL renderer and EGL platform

    // Uploads a mesh; returns its handle (valid for the Renderer's life).
    int add_mesh(const MeshData& mesh);

    // Starts a frame of w x h pixels: clears to `background`, draws the ground if given.
    void begin(int w, int h, const Camera& cam, const Ground* ground,
               glm::vec3 background = {0.93f, 0.94f, 0.96f});
    // Draws mesh `handle`. False (nothing drawn) when a span has the wrong size.
    bool draw(int handle, const DrawParams& p);
    // Resolves the multisampled frame and reads it back (top row first).
    Image finish();

private:
    Renderer();
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace progskin::render
