#include "renderer.h"

#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/glext.h>

#include <algorithm>
#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include "gl_context.h"

namespace progskin::render {
namespace {

const char* kMeshVS = R"(#version 330 core
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec2 a_uv;
layout(location = 3) in uvec4 a_joints0;
layout(location = 4) in uvec4 a_joints1;
layout(location = 5) in vec4 a_weights0;
layout(location = 6) in vec4 a_weights1;
layout(location = 7) in vec3 a_color;
uniform mat4 u_view_proj;
uniform mat4 u_model;          // placement after skinning
uniform bool u_skin;           // false: a_position is already skinned (CPU)
uniform int u_influences;      // 1..8 slots used
uniform samplerBuffer u_palette;  // 3 RGBA32F texels (rows of a 3x4 matrix) per bone
out vec3 v_normal;
out vec2 v_uv;
out vec3 v_color;
out vec3 v_world;

void add_bone(inout vec4 r0, inout vec4 r1, inout vec4 r2, uint j, float w) {
    int b = int(j) * 3;
    r0 += w * texelFetch(u_palette, b);
    r1 += w * texelFetch(u_palette, b + 1);
    r2 += w * texelFetch(u_palette, b + 2);
}

void main() {
    vec3 p = a_position, n = a_normal;
    if (u_skin) {
        vec4 r0 = vec4(0.0), r1 = vec4(0.0), r2 = vec4(0.0);
        float ws[8] = float[8](a_weights0.x, a_weights0.y, a_weights0.z, a_weights0.w,
                               a_weights1.x, a_weights1.y, a_weights1.z, a_weights1.w);
        uint js[8] = uint[8](a_joints0.x, a_joints0.y, a_joints0.z, a_joints0.w,
                             a_joints1.x, a_joints1.y, a_joints1.z, a_joints1.w);
        float sum = 0.0;
        for (int i = 0; i < u_influences; ++i) sum += ws[i];
        if (sum <= 0.0) { ws[0] = 1.0; sum = 1.0; }
        for (int i = 0; i < u_influences; ++i)
            if (ws[i] != 0.0) add_bone(r0, r1, r2, js[i], ws[i] / sum);
        vec4 h = vec4(p, 1.0);
        p = vec3(dot(r0, h), dot(r1, h), dot(r2, h));
        n = vec3(dot(r0.xyz, n), dot(r1.xyz, n), dot(r2.xyz, n));
    }
    vec4 world = u_model * vec4(p, 1.0);
    v_world = world.xyz;
    v_normal = mat3(u_model) * n;
    v_uv = a_uv;
    v_color = a_color;
    gl_Position = u_view_proj * world;
}
)";

const char* kMeshFS = R"(#version 330 core
in vec3 v_normal;
in vec2 v_uv;
in vec3 v_color;
in vec3 v_world;
uniform vec4 u_base_color;
uniform bool u_use_texture;
uniform bool u_use_color;
uniform sampler2D u_texture;
uniform vec3 u_light_dir;   // towards the light, unit
uniform vec3 u_eye;
uniform bool u_flat;        // no normals in the file: face normals from screen-space derivatives
out vec4 o_color;
void main() {
    vec3 n = u_flat ? cross(dFdx(v_world), dFdy(v_world)) : v_normal;
    n = normalize(n);
    if (!u_flat && !gl_FrontFacing) n = -n;
    if (u_flat && dot(n, u_eye - v_world) < 0.0) n = -n;
    vec3 base = u_base_color.rgb;
    if (u_use_texture) base *= texture(u_texture, v_uv).rgb;
    if (u_use_color) base = v_color;
    float diffuse = max(dot(n, u_light_dir), 0.0);
    vec3 ambient = mix(vec3(0.32, 0.30, 0.28), vec3(0.45, 0.48, 0.55), 0.5 + 0.5 * n.y);
    vec3 v = normalize(u_eye - v_world);
    float spec = pow(max(dot(n, normalize(u_light_dir + v)), 0.0), 32.0) * 0.08;
    vec3 c = base * (ambient + 0.75 * diffuse) + vec3(spec);
    o_color = vec4(pow(clamp(c, 0.0, 1.0), vec3(1.0 / 1.15)), 1.0);
}
)";

const char* kGroundVS = R"(#version 330 core
layout(location = 0) in vec2 a_xz;   // -1..1
uniform mat4 u_view_proj;
uniform vec3 u_center;
uniform float u_extent;
uniform float u_height;
out vec3 v_world;
void main() {
    v_world = vec3(u_center.x + a_xz.x * u_extent, u_height, u_center.z + a_xz.y * u_extent);
    gl_Position = u_view_proj * vec4(v_world, 1.0);
}
)";

const char* kGroundFS = R"(#version 330 core
in vec3 v_world;
uniform vec3 u_center;
uniform float u_extent;
uniform float u_spacing;
uniform vec3 u_background;
out vec4 o_color;
float grid(vec2 p, float s) {
    vec2 g = abs(fract(p / s - 0.5) - 0.5) / fwidth(p / s);
    return 1.0 - min(min(g.x, g.y), 1.0);
}
void main() {
    vec2 p = v_world.xz;
    vec3 c = vec3(0.80, 0.81, 0.83);
    c = mix(c, vec3(0.62, 0.63, 0.66), grid(p, u_spacing));
    c = mix(c, vec3(0.45, 0.46, 0.50), grid(p, u_spacing * 5.0));
    float d = length(p - u_center.xz) / u_extent;
    o_color = vec4(mix(c, u_background, smoothstep(0.35, 1.0, d)), 1.0);
}
)";

GLuint compile(GLenum type, const char* src, std::string* error) {
    GLuint s = glCreateShader(type);
    glShaderSource(s, 1, &src, nullptr);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[4096];
        glGetShaderInfoLog(s, sizeof log, nullptr, log);
        if (error) *error = std::string("shader: ") + log;
        glDeleteShader(s);
        return 0;
    }
    return s;
}

GLuint link(const char* vs, const char* fs, std::string* error) {
    GLuint v = compile(GL_VERTEX_SHADER, vs, error);
    if (!v) return 0;
    GLuint f = compile(GL_FRAGMENT_SHADER, fs, error);
    if (!f) return 0;
    GLuint p = glCreateProgram();
    glAttachShader(p, v);
    glAttachShader(p, f);
    glLinkProgram(p);
    glDeleteShader(v);
    glDeleteShader(f);
    GLint ok = 0;
    glGetProgramiv(p, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[4096];
        glGetProgramInfoLog(p, sizeof log, nullptr, log);
        if (error) *error = std::string("link: ") + log;
        glDeleteProgram(p);
        return 0;
    }
    return p;
}

struct GpuMesh {
    GLuint vao = 0, ibo = 0;
    GLuint vbo_pos = 0, vbo_nrm = 0, vbo_uv = 0, vbo_joints = 0, vbo_weights = 0;
    GLuint vbo_dyn_pos = 0, vbo_dyn_nrm = 0, vbo_color = 0;
    size_t vertices = 0;
    int influences = 4;
    uint16_t max_joint = 0;
    bool has_uv = false;
    bool flat = false;
    std::vector<MeshPart> parts;
    std::vector<GLuint> textures;
};

}  // namespace

struct Renderer::Impl {
    std::unique_ptr<GlContext> ctx;
    std::string description;
    GLuint mesh_prog = 0, ground_prog = 0;
    GLuint ground_vao = 0, ground_vbo = 0;
    GLuint palette_buf = 0, palette_tex = 0;
    GLuint white_tex = 0;
    GLuint fbo_ms = 0, rb_color_ms = 0, rb_depth_ms = 0, fbo = 0, rb_color = 0;
    int w = 0, h = 0, samples = 4;
    Camera cam;
    std::vector<GpuMesh> meshes;
    std::vector<float> scratch;

    void resize(int nw, int nh) {
        if (nw == w && nh == h && fbo) return;
        if (fbo) {
            glDeleteFramebuffers(1, &fbo_ms);
            glDeleteFramebuffers(1, &fbo);
            GLuint rbs[3] = {rb_color_ms, rb_depth_ms, rb_color};
            glDeleteRenderbuffers(3, rbs);
        }
        w = nw;
        h = nh;
        GLint max_samples = 0;
        glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
        samples = std::min(4, std::max(0, int(max_samples)));
        glGenRenderbuffers(1, &rb_color_ms);
        glBindRenderbuffer(GL_RENDERBUFFER, rb_color_ms);
        glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_RGBA8, w, h);
        glGenRenderbuffers(1, &rb_depth_ms);
        glBindRenderbuffer(GL_RENDERBUFFER, rb_depth_ms);
        glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_DEPTH_COMPONENT24, w, h);
        glGenFramebuffers(1, &fbo_ms);
        glBindFramebuffer(GL_FRAMEBUFFER, fbo_ms);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, rb_color_ms);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, rb_depth_ms);
        glGenRenderbuffers(1, &rb_color);
        glBindRenderbuffer(GL_RENDERBUFFER, rb_color);
        glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, w, h);
        glGenFramebuffers(1, &fbo);
        glBindFramebuffer(GL_FRAMEBUFFER, fbo);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, rb_color);
    }
};

Renderer::Renderer() : impl_(std::make_unique<Impl>()) {}

Renderer::~Renderer() {
    if (!impl_ || !impl_->ctx) return;
    impl_->ctx->make_current();
    for (GpuMesh& m : impl_->meshes) {
        glDeleteVertexArrays(1, &m.vao);
        GLuint b[9] = {m.ibo, m.vbo_pos, m.vbo_nrm, m.vbo_uv, m.vbo_joints, m.vbo_weights,
                       m.vbo_dyn_pos, m.vbo_dyn_nrm, m.vbo_color};
        glDeleteBuffers(9, b);
        if (!m.textures.empty()) glDeleteTextures(GLsizei(m.textures.size()), m.textures.data());
    }
    glDeleteProgram(impl_->mesh_prog);
    glDeleteProgram(impl_->ground_prog);
    impl_->meshes.clear();
}

const std::string& Renderer::description() const { return impl_->description; }

std::unique_ptr<Renderer> Renderer::create(std::string* error) {
    std::unique_ptr<Renderer> r(new Renderer());
    Impl& I = *r->impl_;
    I.ctx = GlContext::create(error);
    if (!I.ctx) return nullptr;
    I.description = I.ctx->renderer() + " via " + I.ctx->platform();
    I.mesh_prog = link(kMeshVS, kMeshFS, error);
    I.ground_prog = link(kGroundVS, kGroundFS, error);
    if (!I.mesh_prog || !I.ground_prog) return nullptr;

    const float quad[12] = {-1, -1, 1, -1, 1, 1, -1, -1, 1, 1, -1, 1};
    glGenVertexArrays(1, &I.ground_vao);
    glBindVertexArray(I.ground_vao);
    glGenBuffers(1, &I.ground_vbo);
    glBindBuffer(GL_ARRAY_BUFFER, I.ground_vbo);
    glBufferData(GL_ARRAY_BUFFER, sizeof quad, quad, GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 2, GL_FLOAT, GL_FALSE, 0, nullptr);
    glBindVertexArray(0);

    glGenBuffers(1, &I.palette_buf);
    glGenTextures(1, &I.palette_tex);
    const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    glBindBuffer(GL_TEXTURE_BUFFER, I.palette_buf);
    glBufferData(GL_TEXTURE_BUFFER, sizeof identity, identity, GL_DYNAMIC_DRAW);
    glBindTexture(GL_TEXTURE_BUFFER, I.palette_tex);
    glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32F, I.palette_buf);

    const uint8_t white[4] = {255, 255, 255, 255};
    glGenTextures(1, &I.white_tex);
    glBindTexture(GL_TEXTURE_2D, I.white_tex);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, 1, 1, 0, GL_RGBA, GL_UNSIGNED_BYTE, white);
    if (glGetError() != GL_NO_ERROR) {
        if (error) *error = "OpenGL setup failed";
        return nullptr;
    }
    return r;
}

int Renderer::add_mesh(const MeshData& md) {
    Impl& I = *impl_;
    GpuMesh m;
    m.vertices = md.positions.size();
    m.influences = std::clamp(md.influences, 1, 8);
    m.parts = md.parts;
    m.has_uv = md.uvs.size() == m.vertices;
    m.flat = md.flat_shaded;
    const size_t n = m.vertices;

    glGenVertexArrays(1, &m.vao);
    glBindVertexArray(m.vao);
    auto buffer = [](GLuint& b, const void* data, size_t bytes, GLenum usage) {
        glGenBuffers(1, &b);
        glBindBuffer(GL_ARRAY_BUFFER, b);
        glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(bytes), data, usage);
    };
    buffer(m.vbo_pos, md.positions.data(), n * 12, GL_STATIC_DRAW);
    buffer(m.vbo_nrm, md.normals.data(), n * 12, GL_STATIC_DRAW);
    buffer(m.vbo_dyn_pos, nullptr, n * 12, GL_STREAM_DRAW);
    buffer(m.vbo_dyn_nrm, nullptr, n * 12, GL_STREAM_DRAW);
    buffer(m.vbo_color, nullptr, n * 12, GL_STREAM_DRAW);

    std::vector<glm::vec2> uv = m.has_uv ? md.uvs : std::vector<glm::vec2>(n, glm::vec2(0.0f));
    buffer(m.vbo_uv, uv.data(), n * 8, GL_STATIC_DRAW);
    glEnableVertexAttribArray(2);
    glVertexAttribPointer(2, 2, GL_FLOAT, GL_FALSE, 0, nullptr);

    // Joints and weights padded to 8 slots per vertex (attributes 3,4 and 5,6).
    std::vector<uint16_t> j(n * 8, 0);
    std::vector<float> w(n * 8, 0.0f);
    for (size_t v = 0; v < n; ++v)
        for (int i = 0; i < m.influences; ++i) {
            const size_t src = v * size_t(md.influences) + size_t(i);
            if (src < md.joints.size()) j[v * 8 + size_t(i)] = md.joints[src];
            if (src < md.weights.size()) w[v * 8 + size_t(i)] = md.weights[src];
            m.max_joint = std::max(m.max_joint, j[v * 8 + size_t(i)]);
        }
    buffer(m.vbo_joints, j.data(), j.size() * 2, GL_STATIC_DRAW);
    glEnableVertexAttribArray(3);
    glVertexAttribIPointer(3, 4, GL_UNSIGNED_SHORT, 16, nullptr);
    glEnableVertexAttribArray(4);
    glVertexAttribIPointer(4, 4, GL_UNSIGNED_SHORT, 16, reinterpret_cast<void*>(8));
    buffer(m.vbo_weights, w.data(), w.size() * 4, GL_STATIC_DRAW);
    glEnableVertexAttribArray(5);
    glVertexAttribPointer(5, 4, GL_FLOAT, GL_FALSE, 32, nullptr);
    glEnableVertexAttribArray(6);
    glVertexAttribPointer(6, 4, GL_FLOAT, GL_FALSE, 32, reinterpret_cast<void*>(16));

    glGenBuffers(1, &m.ibo);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, m.ibo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, GLsizeiptr(md.triangles.size() * 4), md.triangles.data(), GL_STATIC_DRAW);
    glBindVertexArray(0);

    for (const Texture& t : md.textures) {
        GLuint tex = 0;
        glGenTextures(1, &tex);
        glBindTexture(GL_TEXTURE_2D, tex);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, t.width, t.height, 0, GL_RGBA, GL_UNSIGNED_BYTE, t.rgba.data());
        glGenerateMipmap(GL_TEXTURE_2D);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        m.textures.push_back(tex);
    }
    I.meshes.push_back(std::move(m));
    return int(I.meshes.size()) - 1;
}

Camera frame_points(std::span<const glm::vec3> pts, float aspect, float azimuth_deg, float elevation_deg,
                    float fov_y_deg, float fill) {
    Bounds b;
    b.add(pts);
    const glm::vec3 lo = b.valid() ? b.lo : glm::vec3(-1.0f), hi = b.valid() ? b.hi : glm::vec3(1.0f);
    glm::vec3 target = 0.5f * (lo + hi);
    const float radius = std::max(0.5f * glm::length(hi - lo), 1e-6f);
    const float az = glm::radians(azimuth_deg), el = glm::radians(elevation_deg);
    const glm::vec3 dir(std::sin(az) * std::cos(el), std::sin(el), std::cos(az) * std::cos(el));
    const float fov = glm::radians(fov_y_deg);
    const float tan_y = std::tan(fov * 0.5f), tan_x = tan_y * aspect;
    float dist = radius / std::sin(std::min(std::atan(tan_x), fov * 0.5f));
    // Refine: centre the points' projected box and move in until it fills `fill` of the view.
    for (int it = 0; it < 6 && !pts.empty(); ++it) {
        const glm::mat4 view = glm::lookAt(target + dir * dist, target, glm::vec3(0, 1, 0));
        glm::vec2 mn(1e30f), mx(-1e30f);
        float nearest = 1e30f;
        for (const glm::vec3& p : pts) {
            const glm::vec3 q = glm::vec3(view * glm::vec4(p, 1.0f));
            const float depth = -q.z;
            if (depth <= 1e-6f * dist) {
                mn = glm::vec2(-1e30f);
                break;
            }
            nearest = std::min(nearest, depth);
            const glm::vec2 ndc(q.x / (depth * tan_x), q.y / (depth * tan_y));
            mn = glm::min(mn, ndc);
            mx = glm::max(mx, ndc);
        }
        if (mn.x < -1e29f) {  // a point behind the camera: back off
            dist *= 2.0f;
            continue;
        }
        const glm::vec2 c = 0.5f * (mn + mx), half = 0.5f * (mx - mn);
        // Shift the target sideways / up so the box is centred (at the target's depth).
        const glm::vec3 right(view[0][0], view[1][0], view[2][0]), up(view[0][1], view[1][1], view[2][1]);
        target += right * (c.x * dist * tan_x) + up * (c.y * dist * tan_y);
        const float ratio = std::max(half.x, half.y) / fill;
        if (std::abs(ratio - 1.0f) < 0.005f && glm::length(c) < 0.005f) break;
        // Projected size ~ 1/depth; scale the distance of the nearest point.
        const float near_gap = dist - nearest;
        dist = std::max(near_gap + (dist - near_gap) * ratio, 1e-6f);
    }
    Camera cam;
    cam.target = target;
    cam.eye = target + dir * dist;
    cam.view = glm::lookAt(cam.eye, target, glm::vec3(0, 1, 0));
    cam.proj = glm::perspective(fov, aspect, std::max(dist - radius * 3.0f, dist * 0.02f), dist + radius * 12.0f);
    return cam;
}

Camera frame_bounds(const Bounds& b, float aspect, float azimuth_deg, float elevation_deg, float fov_y_deg,
                    float fill) {
    std::vector<glm::vec3> corners;
    if (b.valid())
        for (int k = 0; k < 8; ++k)
            corners.emplace_back((k & 1) ? b.hi.x : b.lo.x, (k & 2) ? b.hi.y : b.lo.y, (k & 4) ? b.hi.z : b.lo.z);
    return frame_points(corners, aspect, azimuth_deg, elevation_deg, fov_y_deg, fill);
}

Ground ground_under(const Bounds& b) {
    Ground g;
    const glm::vec3 lo = b.valid() ? b.lo : glm::vec3(-1.0f), hi = b.valid() ? b.hi : glm::vec3(1.0f);
    const float size = std::max(glm::length(hi - lo), 1e-6f);
    g.height = lo.y;
    g.center = 0.5f * (lo + hi);
    g.extent = size * 3.0f;
    const float raw = size / 10.0f;
    const float p10 = std::pow(10.0f, std::floor(std::log10(raw)));
    const float m = raw / p10;
    g.spacing = p10 * (m < 1.5f ? 1.0f : m < 3.5f ? 2.0f : m < 7.5f ? 5.0f : 10.0f);
    return g;
}

void Renderer::begin(int w, int h, const Camera& cam, const Ground* ground, glm::vec3 bg) {
    Impl& I = *impl_;
    I.ctx->make_current();
    I.resize(w, h);
    I.cam = cam;
    glBindFramebuffer(GL_FRAMEBUFFER, I.fbo_ms);
    glViewport(0, 0, w, h);
    glEnable(GL_DEPTH_TEST);
    glDisable(GL_CULL_FACE);
    if (I.samples > 0) glEnable(GL_MULTISAMPLE);
    glClearColor(bg.r, bg.g, bg.b, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    if (ground) {
        const glm::mat4 vp = cam.proj * cam.view;
        glUseProgram(I.ground_prog);
        glUniformMatrix4fv(glGetUniformLocation(I.ground_prog, "u_view_proj"), 1, GL_FALSE, glm::value_ptr(vp));
        glUniform3fv(glGetUniformLocation(I.ground_prog, "u_center"), 1, glm::value_ptr(ground->center));
        glUniform1f(glGetUniformLocation(I.ground_prog, "u_extent"), ground->extent);
        glUniform1f(glGetUniformLocation(I.ground_prog, "u_height"), ground->height);
        glUniform1f(glGetUniformLocation(I.ground_prog, "u_spacing"), ground->spacing);
        glUniform3fv(glGetUniformLocation(I.ground_prog, "u_background"), 1, glm::value_ptr(bg));
        // Slightly behind the characters in depth so feet on the plane do not flicker.
        glEnable(GL_POLYGON_OFFSET_FILL);
        glPolygonOffset(1.0f, 1.0f);
        glBindVertexArray(I.ground_vao);
        glDrawArrays(GL_TRIANGLES, 0, 6);
        glDisable(GL_POLYGON_OFFSET_FILL);
    }
}

bool Renderer::draw(int handle, const DrawParams& p) {
    Impl& I = *impl_;
    if (handle < 0 || size_t(handle) >= I.meshes.size()) return false;
    GpuMesh& m = I.meshes[size_t(handle)];
    const bool gpu_skin = !p.palette.empty();
    if (gpu_skin && p.palette.size() <= m.max_joint) return false;
    if (!gpu_skin && p.positions.size() != m.vertices) return false;
    if (!p.normals.empty() && p.normals.size() != m.vertices) return false;
    if (!p.colors.empty() && p.colors.size() != m.vertices) return false;

    glUseProgram(I.mesh_prog);
    glBindVertexArray(m.vao);
    const GLsizeiptr bytes = GLsizeiptr(m.vertices * 12);
    auto attrib = [](GLuint loc, GLuint buf) {
        glBindBuffer(GL_ARRAY_BUFFER, buf);
        glEnableVertexAttribArray(loc);
        glVertexAttribPointer(loc, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
    };
    if (gpu_skin) {
        attrib(0, m.vbo_pos);
        attrib(1, m.vbo_nrm);
        I.scratch.resize(p.palette.size() * 12);
        for (size_t b = 0; b < p.palette.size(); ++b)
            std::copy_n(p.palette[b].m, 12, I.scratch.data() + b * 12);
        glBindBuffer(GL_TEXTURE_BUFFER, I.palette_buf);
        glBufferData(GL_TEXTURE_BUFFER, GLsizeiptr(I.scratch.size() * 4), I.scratch.data(), GL_STREAM_DRAW);
    } else {
        glBindBuffer(GL_ARRAY_BUFFER, m.vbo_dyn_pos);
        glBufferSubData(GL_ARRAY_BUFFER, 0, bytes, p.positions.data());
        attrib(0, m.vbo_dyn_pos);
        if (!p.normals.empty()) {
            glBindBuffer(GL_ARRAY_BUFFER, m.vbo_dyn_nrm);
            glBufferSubData(GL_ARRAY_BUFFER, 0, bytes, p.normals.data());
            attrib(1, m.vbo_dyn_nrm);
        } else {
            attrib(1, m.vbo_nrm);
        }
    }
    if (!p.colors.empty()) {
        glBindBuffer(GL_ARRAY_BUFFER, m.vbo_color);
        glBufferSubData(GL_ARRAY_BUFFER, 0, bytes, p.colors.data());
        attrib(7, m.vbo_color);
    } else {
        glDisableVertexAttribArray(7);
        glVertexAttrib3f(7, 1.0f, 1.0f, 1.0f);
    }

    const GLuint prog = I.mesh_prog;
    const glm::mat4 vp = I.cam.proj * I.cam.view;
    const glm::mat4 model = p.model.to_glm();
    glUniformMatrix4fv(glGetUniformLocation(prog, "u_view_proj"), 1, GL_FALSE, glm::value_ptr(vp));
    glUniformMatrix4fv(glGetUniformLocation(prog, "u_model"), 1, GL_FALSE, glm::value_ptr(model));
    glUniform1i(glGetUniformLocation(prog, "u_skin"), gpu_skin ? 1 : 0);
    glUniform1i(glGetUniformLocation(prog, "u_influences"), m.influences);
    glUniform1i(glGetUniformLocation(prog, "u_palette"), 1);
    glUniform1i(glGetUniformLocation(prog, "u_texture"), 0);
    glUniform1i(glGetUniformLocation(prog, "u_use_color"), p.colors.empty() ? 0 : 1);
    glUniform1i(glGetUniformLocation(prog, "u_flat"), m.flat ? 1 : 0);
    const glm::vec3 light = glm::normalize(glm::vec3(-0.45f, 0.85f, 0.55f));
    glUniform3fv(glGetUniformLocation(prog, "u_light_dir"), 1, glm::value_ptr(light));
    glUniform3fv(glGetUniformLocation(prog, "u_eye"), 1, glm::value_ptr(I.cam.eye));
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_BUFFER, I.palette_tex);
    glActiveTexture(GL_TEXTURE0);
    for (const MeshPart& part : m.parts) {
        if (part.index_count == 0) continue;
        const bool tex = p.textured && m.has_uv && part.texture >= 0 && size_t(part.texture) < m.textures.size();
        glBindTexture(GL_TEXTURE_2D, tex ? m.textures[size_t(part.texture)] : I.white_tex);
        glUniform1i(glGetUniformLocation(prog, "u_use_texture"), tex ? 1 : 0);
        glUniform4fv(glGetUniformLocation(prog, "u_base_color"), 1, glm::value_ptr(part.base_color));
        glDrawElements(GL_TRIANGLES, GLsizei(part.index_count), GL_UNSIGNED_INT,
                       reinterpret_cast<void*>(size_t(part.first_index) * 4));
    }
    glBindVertexArray(0);
    return glGetError() == GL_NO_ERROR;
}

Image Renderer::finish() {
    Impl& I = *impl_;
    glBindFramebuffer(GL_READ_FRAMEBUFFER, I.fbo_ms);
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, I.fbo);
    glBlitFramebuffer(0, 0, I.w, I.h, 0, 0, I.w, I.h, GL_COLOR_BUFFER_BIT, GL_NEAREST);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, I.fbo);
    Image img(I.w, I.h);
    std::vector<uint8_t> rows(img.rgba.size());
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, I.w, I.h, GL_RGBA, GL_UNSIGNED_BYTE, rows.data());
    const size_t stride = size_t(I.w) * 4;
    for (int y = 0; y < I.h; ++y)  // GL's first row is the bottom one
        std::copy_n(rows.data() + size_t(I.h - 1 - y) * stride, stride, img.rgba.data() + size_t(y) * stride);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    return img;
}

}  // namespace progskin::render
