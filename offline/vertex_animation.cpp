// vertex_animation.cpp — loaders of vertex animations (see vertex_animation.h).
#include "vertex_animation.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <unordered_map>

#include <glm/gtc/matrix_inverse.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>

#include "animation.h"
#include "errors.h"
#include "error_metric.h"
#include "gltf_accessor.h"
#include "gltf_import.h"
#include "hash.h"

namespace progskin {

void VertexAnimation::validate() const {
    if (vertex_count == 0) throw Error(source + ": no vertices");
    if (frame_count == 0) throw Error(source + ": no frames");
    if (positions.size() != vertex_count * frame_count)
        throw Error(source + ": " + std::to_string(positions.size()) + " positions for " +
                    std::to_string(vertex_count) + " vertices x " + std::to_string(frame_count) + " frames");
    if (!normals.empty() && normals.size() != vertex_count)
        throw Error(source + ": " + std::to_string(normals.size()) + " normals for " + std::to_string(vertex_count) +
                    " vertices");
    if (triangles.size() % 3) throw Error(source + ": triangle index count is not a multiple of 3");
    for (uint32_t i : triangles)
        if (i >= vertex_count) throw Error(source + ": triangle index " + std::to_string(i) + " out of range");
    if (!(fps > 0) || !std::isfinite(fps)) throw Error(source + ": frame rate must be positive");
    for (size_t i = 0; i < positions.size(); ++i) {
        const glm::vec3& p = positions[i];
        if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
            throw Error(source + ": position of vertex " + std::to_string(i % vertex_count) + " in frame " +
                        std::to_string(i / vertex_count) + " is not finite");
    }
}

double frame_diagonal(const VertexAnimation& a, size_t f) {
    if (a.vertex_count == 0 || f >= a.frame_count) return 0.0;
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    const glm::vec3* p = a.frame(f);
    for (size_t v = 0; v < a.vertex_count; ++v) {
        lo = glm::min(lo, glm::dvec3(p[v]));
        hi = glm::max(hi, glm::dvec3(p[v]));
    }
    return glm::length(hi - lo);
}

VertexAnimation join_coincident(const VertexAnimation& a, std::vector<uint32_t>* representative) {
    const size_t V = a.vertex_count, F = a.frame_count;
    if (F == 0) throw Error(a.source + ": no frames");
    if (a.positions.size() != V * F) throw Error(a.source + ": positions do not match vertices x frames");
    // A position's bit patterns with -0 made +0, so equal floats compare equal.
    auto bits = [](const glm::vec3& p) {
        const glm::vec3 q = p + glm::vec3(0.0f);
        std::array<uint8_t, sizeof q> b;
        std::memcpy(b.data(), &q, sizeof q);
        return b;
    };
    auto key = [&](size_t v) {  // hash of the whole trajectory
        uint64_t h = FNV1A64_BASIS;
        for (size_t f = 0; f < F; ++f) h = fnv1a64(bits(a.frame(f)[v]), h);
        return h;
    };
    auto same = [&](size_t u, size_t v) {
        for (size_t f = 0; f < F; ++f)
            if (bits(a.frame(f)[u]) != bits(a.frame(f)[v])) return false;
        return true;
    };
    // Buckets by a hash of the whole trajectory, then a full comparison with
    // the bucket's kept vertices (more than one only on a hash collision).
    std::unordered_map<uint64_t, std::vector<uint32_t>> buckets;
    std::vector<uint32_t> rep(V), kept;
    for (size_t v = 0; v < V; ++v) {
        std::vector<uint32_t>& b = buckets[key(v)];
        uint32_t r = uint32_t(-1);
        for (uint32_t k : b)
            if (same(kept[k], v)) {
                r = k;
                break;
            }
        if (r == uint32_t(-1)) {
            r = uint32_t(kept.size());
            kept.push_back(uint32_t(v));
            b.push_back(r);
        }
        rep[v] = r;
    }
    VertexAnimation j;
    j.source = a.source;
    j.fps = a.fps;
    j.diagonal = a.diagonal;
    j.vertex_count = kept.size();
    j.frame_count = F;
    j.positions.reserve(kept.size() * F);
    for (size_t f = 0; f < F; ++f)
        for (uint32_t v : kept) j.positions.push_back(a.frame(f)[v]);
    if (a.normals.size() == V)
        for (uint32_t v : kept) j.normals.push_back(a.normals[v]);
    for (size_t t = 0; t + 2 < a.triangles.size(); t += 3) {
        const uint32_t i = a.triangles[t], k = a.triangles[t + 1], m = a.triangles[t + 2];
        if (i >= V || k >= V || m >= V) throw Error(a.source + ": triangle index out of range");
        const uint32_t x = rep[i], y = rep[k], z = rep[m];
        if (x != y && y != z && x != z) j.triangles.insert(j.triangles.end(), {x, y, z});
    }
    if (representative) *representative = std::move(rep);
    return j;
}

// ---------------------------------------------------------------------------
// PC2

namespace {

constexpr char kPc2Magic[12] = {'P', 'O', 'I', 'N', 'T', 'C', 'A', 'C', 'H', 'E', '2', '\0'};
constexpr size_t kPc2Header = 12 + 4 + 4 + 4 + 4 + 4;

template <typename T>
T get_le(const unsigned char* p) {
    T v;
    std::memcpy(&v, p, sizeof(T));  // the project targets little-endian machines
    return v;
}

std::vector<unsigned char> read_bytes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(path + ": cannot open file");
    std::vector<unsigned char> b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw Error(path + ": read error");
    return b;
}

bool ends_with_ci(const std::string& s, const std::string& suffix) {
    if (s.size() < suffix.size()) return false;
    for (size_t i = 0; i < suffix.size(); ++i)
        if (std::tolower((unsigned char)s[s.size() - suffix.size() + i]) != suffix[i]) return false;
    return true;
}

}  // namespace

VertexAnimation load_pc2(const std::string& path) {
    const std::vector<unsigned char> b = read_bytes(path);
    if (b.size() < kPc2Header) throw Error(path + ": not a PC2 file (" + std::to_string(b.size()) + " bytes, header needs 32)");
    if (std::memcmp(b.data(), kPc2Magic, 12) != 0) throw Error(path + ": not a PC2 file (no POINTCACHE2 signature)");
    const int32_t version = get_le<int32_t>(&b[12]);
    const int32_t points = get_le<int32_t>(&b[16]);
    const float start = get_le<float>(&b[20]);
    const float rate = get_le<float>(&b[24]);
    const int32_t samples = get_le<int32_t>(&b[28]);
    if (version != 1) throw Error(path + ": PC2 version " + std::to_string(version) + " (only 1 is supported)");
    if (points <= 0) throw Error(path + ": PC2 file has " + std::to_string(points) + " points (no vertices)");
    if (samples <= 0) throw Error(path + ": PC2 file has " + std::to_string(samples) + " samples (no frames)");
    if (!std::isfinite(start)) throw Error(path + ": PC2 start frame is not finite");
    if (!std::isfinite(rate) || !(rate > 0)) throw Error(path + ": PC2 sample rate must be positive (got " + std::to_string(rate) + ")");
    const uint64_t need = uint64_t(points) * uint64_t(samples) * 12u;
    const uint64_t have = b.size() - kPc2Header;
    if (have < need)
        throw Error(path + ": PC2 file truncated: " + std::to_string(have) + " data bytes for " + std::to_string(points) +
                    " points x " + std::to_string(samples) + " samples (" + std::to_string(need) + " needed)");
    if (have > need)
        throw Error(path + ": PC2 file has " + std::to_string(have - need) + " bytes after " + std::to_string(samples) +
                    " samples of " + std::to_string(points) + " points");
    VertexAnimation a;
    a.source = path;
    a.vertex_count = size_t(points);
    a.frame_count = size_t(samples);
    // sampleRate is the frame step between samples; assume 30 frames per second.
    a.fps = 30.0 / double(rate);
    a.positions.resize(a.vertex_count * a.frame_count);
    std::memcpy(a.positions.data(), &b[kPc2Header], size_t(need));
    a.validate();
    return a;
}

void save_pc2(const VertexAnimation& a, const std::string& path, float start_frame) {
    a.validate();
    std::string out(kPc2Magic, 12);
    auto put = [&](const void* p, size_t n) { out.append(static_cast<const char*>(p), n); };
    const int32_t version = 1, points = int32_t(a.vertex_count), samples = int32_t(a.frame_count);
    const float rate = float(30.0 / a.fps);
    put(&version, 4);
    put(&points, 4);
    put(&start_frame, 4);
    put(&rate, 4);
    put(&samples, 4);
    put(a.positions.data(), a.positions.size() * 12);
    const std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::binary);
        f.write(out.data(), std::streamsize(out.size()));
        if (!f) throw Error(path + ": cannot write");
    }
    if (std::rename(tmp.c_str(), path.c_str()) != 0) throw Error(path + ": cannot write");
}

// ---------------------------------------------------------------------------
// glTF morph targets

namespace {

struct Gltf {
    tinygltf::Model m;
    std::string path;
    [[noreturn]] void fail(const std::string& what) const { throw Error(path + ": " + what); }
};

void load(Gltf& g) { gltf::load_model(g.path, g.m); }

// Accessor `index` decoded to doubles (count * components), with its component count checked.
std::vector<double> read_acc(const Gltf& g, int index, int components, const std::string& what) {
    return gltf::read_accessor(g.path, g.m, index, components, what);
}

glm::dmat4 local_of(const tinygltf::Node& n) {
    if (n.matrix.size() == 16) {
        glm::dmat4 m;
        for (int c = 0; c < 4; ++c)
            for (int r = 0; r < 4; ++r) m[c][r] = n.matrix[size_t(c * 4 + r)];
        return m;
    }
    glm::dmat4 m(1.0);
    if (n.translation.size() == 3) m = glm::translate(m, glm::dvec3(n.translation[0], n.translation[1], n.translation[2]));
    if (n.rotation.size() == 4)
        m = m * glm::mat4_cast(glm::normalize(glm::dquat(n.rotation[3], n.rotation[0], n.rotation[1], n.rotation[2])));
    if (n.scale.size() == 3) m = glm::scale(m, glm::dvec3(n.scale[0], n.scale[1], n.scale[2]));
    return m;
}

// Morph weights of a node at time t from one channel.
struct WeightTrack {
    std::vector<double> times;
    std::vector<double> values;  // keys * (3 if cubic) * targets
    int interp = 1;              // 0 step, 1 linear, 2 cubic
    size_t targets = 0;
    void sample(double t, std::vector<double>& out) const {
        const size_t K = times.size(), T = targets;
        const size_t per = interp == 2 ? 3 : 1, off = interp == 2 ? T : 0;
        auto val = [&](size_t k) { return values.data() + k * per * T + off; };
        out.assign(T, 0.0);
        if (K == 0) return;
        if (K == 1 || t <= times.front()) return std::copy(val(0), val(0) + T, out.begin()), void();
        if (t >= times.back()) return std::copy(val(K - 1), val(K - 1) + T, out.begin()), void();
        const size_t k = size_t(std::upper_bound(times.begin(), times.end(), t) - times.begin()) - 1;
        const double t0 = times[k], t1 = times[k + 1];
        if (interp == 0 || t1 <= t0) return std::copy(val(k), val(k) + T, out.begin()), void();
        const double u = std::clamp((t - t0) / (t1 - t0), 0.0, 1.0);
        const double* a = val(k);
        const double* b = val(k + 1);
        if (interp == 1) {
            for (size_t i = 0; i < T; ++i) out[i] = a[i] + (b[i] - a[i]) * u;
            return;
        }
        const double d = t1 - t0, u2 = u * u, u3 = u2 * u;
        const double h00 = 2 * u3 - 3 * u2 + 1, h10 = u3 - 2 * u2 + u, h01 = -2 * u3 + 3 * u2, h11 = u3 - u2;
        const double* out_tan = a + T;  // key k: in, value, out
        const double* in_tan = b - T;   // key k+1
        for (size_t i = 0; i < T; ++i) out[i] = h00 * a[i] + h10 * d * out_tan[i] + h01 * b[i] + h11 * d * in_tan[i];
    }
};

struct MorphPrim {
    glm::dmat4 world;
    std::vector<double> base;                  // 3 * count
    std::vector<double> normals;               // 3 * count or empty
    std::vector<std::vector<double>> targets;  // per target, 3 * count (zero when absent)
    std::vector<double> default_weights;
    const WeightTrack* track = nullptr;
    size_t first = 0, count = 0;
};

}  // namespace

VertexAnimation load_gltf_morph_animation(const std::string& path, double fps) {
    if (!(fps > 0) || !std::isfinite(fps)) throw Error(path + ": fps must be positive");
    Gltf g;
    g.path = path;
    load(g);
    const auto& m = g.m;
    // Parents and world matrices of all nodes (rest transforms).
    std::vector<int> parent(m.nodes.size(), -1);
    for (size_t i = 0; i < m.nodes.size(); ++i)
        for (int c : m.nodes[i].children) {
            if (c < 0 || size_t(c) >= m.nodes.size()) g.fail("node " + std::to_string(i) + " has a bad child index");
            if (parent[size_t(c)] >= 0) g.fail("node " + std::to_string(c) + " has two parents");
            parent[size_t(c)] = int(i);
        }
    std::vector<glm::dmat4> world(m.nodes.size());
    for (size_t i = 0; i < m.nodes.size(); ++i) {
        glm::dmat4 w = local_of(m.nodes[i]);
        size_t depth = 0;
        for (int p = parent[i]; p >= 0; p = parent[size_t(p)]) {
            if (++depth > m.nodes.size()) g.fail("cyclic node hierarchy");
            w = local_of(m.nodes[size_t(p)]) * w;
        }
        world[i] = w;
    }
    // Weight tracks per node: every animation's `weights` channels, played together.
    std::vector<WeightTrack> tracks;
    std::vector<int> track_of(m.nodes.size(), -1);
    double t_start = std::numeric_limits<double>::infinity(), t_end = -t_start;
    for (size_t ai = 0; ai < m.animations.size(); ++ai) {
        const auto& an = m.animations[ai];
        for (const auto& ch : an.channels) {
            if (ch.target_path != "weights") continue;
            if (ch.target_node < 0 || size_t(ch.target_node) >= m.nodes.size()) g.fail("animation channel targets a bad node");
            if (ch.sampler < 0 || size_t(ch.sampler) >= an.samplers.size()) g.fail("animation channel has a bad sampler");
            const auto& s = an.samplers[size_t(ch.sampler)];
            WeightTrack t;
            t.times = read_acc(g, s.input, 1, "animation input");
            t.interp = s.interpolation == "STEP" ? 0 : s.interpolation == "CUBICSPLINE" ? 2 : 1;
            for (size_t k = 1; k < t.times.size(); ++k)
                if (!(t.times[k] > t.times[k - 1])) g.fail("animation key times are not strictly increasing");
            if (t.times.empty()) continue;
            t.values = read_acc(g, s.output, 1, "morph weights");
            const size_t per = t.interp == 2 ? 3 : 1;
            if (t.values.size() % (t.times.size() * per)) g.fail("morph weight output count does not match its keys");
            t.targets = t.values.size() / (t.times.size() * per);
            t_start = std::min(t_start, t.times.front());
            t_end = std::max(t_end, t.times.back());
            track_of[size_t(ch.target_node)] = int(tracks.size());
            tracks.push_back(std::move(t));
        }
    }
    // Primitives of every mesh node (not skinned ones: those are read as skinned input).
    std::vector<MorphPrim> prims;
    VertexAnimation a;
    a.source = path;
    a.fps = fps;
    bool any_normals = true;
    for (size_t ni = 0; ni < m.nodes.size(); ++ni) {
        const auto& node = m.nodes[ni];
        if (node.mesh < 0) continue;
        if (size_t(node.mesh) >= m.meshes.size()) g.fail("node " + std::to_string(ni) + " has a bad mesh index");
        const auto& mesh = m.meshes[size_t(node.mesh)];
        for (size_t pi = 0; pi < mesh.primitives.size(); ++pi) {
            const auto& pr = mesh.primitives[pi];
            const std::string who = "mesh " + std::to_string(node.mesh) + " primitive " + std::to_string(pi);
            auto it = pr.attributes.find("POSITION");
            if (it == pr.attributes.end()) continue;
            MorphPrim mp;
            mp.world = world[ni];
            mp.base = read_acc(g, it->second, 3, who + " POSITION");
            mp.count = mp.base.size() / 3;
            mp.first = a.vertex_count;
            auto nit = pr.attributes.find("NORMAL");
            if (nit != pr.attributes.end()) mp.normals = read_acc(g, nit->second, 3, who + " NORMAL");
            if (mp.normals.size() != mp.base.size()) {
                mp.normals.clear();
                any_normals = false;
            }
            for (size_t ti = 0; ti < pr.targets.size(); ++ti) {
                auto tit = pr.targets[ti].find("POSITION");
                std::vector<double> d(mp.base.size(), 0.0);
                if (tit != pr.targets[ti].end()) d = read_acc(g, tit->second, 3, who + " morph target " + std::to_string(ti));
                if (d.size() != mp.base.size()) g.fail(who + ": morph target " + std::to_string(ti) + " count differs from POSITION");
                mp.targets.push_back(std::move(d));
            }
            mp.default_weights.assign(pr.targets.size(), 0.0);
            const std::vector<double>& dw = !node.weights.empty() ? node.weights : mesh.weights;
            for (size_t i = 0; i < std::min(dw.size(), mp.default_weights.size()); ++i) mp.default_weights[i] = dw[i];
            if (track_of[ni] >= 0) mp.track = &tracks[size_t(track_of[ni])];
            if (mp.track && mp.track->targets != mp.targets.size())
                g.fail(who + ": weights animation has " + std::to_string(mp.track->targets) + " values per key for " +
                       std::to_string(mp.targets.size()) + " morph targets");
            // Triangles (mode TRIANGLES only).
            if (pr.mode == -1 || pr.mode == TINYGLTF_MODE_TRIANGLES) {
                std::vector<double> idx;
                if (pr.indices >= 0) {
                    idx = read_acc(g, pr.indices, 1, who + " indices");
                } else {
                    idx.resize(mp.count);
                    for (size_t i = 0; i < mp.count; ++i) idx[i] = double(i);
                }
                for (size_t i = 0; i + 2 < idx.size(); i += 3)
                    for (int k = 0; k < 3; ++k) {
                        if (idx[i + k] >= double(mp.count)) g.fail(who + ": index out of range");
                        a.triangles.push_back(uint32_t(mp.first + size_t(idx[i + k])));
                    }
            }
            a.vertex_count += mp.count;
            prims.push_back(std::move(mp));
        }
    }
    if (a.vertex_count == 0) g.fail("no mesh vertices");
    if (!std::isfinite(t_start)) t_start = t_end = 0.0;
    const double duration = std::max(0.0, t_end - t_start);
    a.frame_count = size_t(std::floor(duration * fps + 1e-6)) + 1;
    a.positions.resize(a.vertex_count * a.frame_count);
    std::vector<double> w;
    for (size_t f = 0; f < a.frame_count; ++f) {
        const double t = t_start + double(f) / fps;
        for (const MorphPrim& mp : prims) {
            if (mp.track) mp.track->sample(t, w);
            else w = mp.default_weights;
            for (size_t v = 0; v < mp.count; ++v) {
                glm::dvec3 p(mp.base[3 * v], mp.base[3 * v + 1], mp.base[3 * v + 2]);
                for (size_t ti = 0; ti < mp.targets.size(); ++ti)
                    if (w[ti] != 0.0)
                        p += w[ti] * glm::dvec3(mp.targets[ti][3 * v], mp.targets[ti][3 * v + 1], mp.targets[ti][3 * v + 2]);
                a.positions[f * a.vertex_count + mp.first + v] = glm::vec3(mp.world * glm::dvec4(p, 1.0));
            }
        }
    }
    if (any_normals) {
        a.normals.resize(a.vertex_count);
        for (const MorphPrim& mp : prims) {
            const glm::dmat3 nm = glm::inverseTranspose(glm::dmat3(mp.world));
            for (size_t v = 0; v < mp.count; ++v) {
                glm::dvec3 n = nm * glm::dvec3(mp.normals[3 * v], mp.normals[3 * v + 1], mp.normals[3 * v + 2]);
                const double l = glm::length(n);
                a.normals[mp.first + v] = glm::vec3(l > 0 ? n / l : glm::dvec3(0, 0, 1));
            }
        }
    }
    a.diagonal = frame_diagonal(a, 0);
    a.validate();
    return a;
}

// ---------------------------------------------------------------------------
// Skinned glTF as vertices

VertexAnimation load_gltf_skinned_as_vertices(const std::string& path, const VertexAnimationOptions& o) {
    const Character c = import_character(path, o.character);
    std::vector<ClipSelection> sels;
    if (o.clip.empty() || o.clip == "auto") sels = default_training_set(c);
    else sels = {select_clips(c, o.clip)};
    const FrameSet frames = sample_frames(c, sels, o.fps);
    VertexAnimation a;
    a.source = path;
    a.fps = o.fps;
    a.vertex_count = c.vertex_count();
    a.frame_count = frames.frame_count();
    if (a.vertex_count == 0) throw Error(path + ": no vertices");
    a.positions.resize(a.vertex_count * a.frame_count);
    for (size_t f = 0; f < a.frame_count; ++f)
        reference_positions(c, frames, f, std::span<glm::vec3>(a.positions.data() + f * a.vertex_count, a.vertex_count));
    a.triangles = c.triangles;
    // Normals: the rest pose is not one of the frames; leave them to the exporter.
    a.diagonal = rest_diagonal(c);
    a.validate();
    return a;
}

std::vector<SourcePrimitive> gltf_source_primitives(const std::string& path, int character) {
    if (!(ends_with_ci(path, ".gltf") || ends_with_ci(path, ".glb"))) return {};
    Gltf g;
    g.path = path;
    load(g);
    std::vector<SourcePrimitive> out;
    bool skinned = false;
    for (const auto& n : g.m.nodes)
        if (n.skin >= 0 && n.mesh >= 0) skinned = true;
    if (skinned) {
        for (const PrimitiveRange& r : import_character(path, character).primitives)
            out.push_back({r.node, r.mesh, r.primitive, r.first, r.count});
        return out;
    }
    uint32_t first = 0;
    for (size_t ni = 0; ni < g.m.nodes.size(); ++ni) {  // as load_gltf_morph_animation
        const auto& node = g.m.nodes[ni];
        if (node.mesh < 0 || size_t(node.mesh) >= g.m.meshes.size()) continue;
        const auto& mesh = g.m.meshes[size_t(node.mesh)];
        for (size_t pi = 0; pi < mesh.primitives.size(); ++pi) {
            auto it = mesh.primitives[pi].attributes.find("POSITION");
            if (it == mesh.primitives[pi].attributes.end()) continue;
            if (it->second < 0 || size_t(it->second) >= g.m.accessors.size()) g.fail("bad POSITION accessor");
            const uint32_t count = uint32_t(g.m.accessors[size_t(it->second)].count);
            out.push_back({int(ni), node.mesh, int(pi), first, count});
            first += count;
        }
    }
    return out;
}

VertexAnimation load_vertex_animation(const std::string& path, const VertexAnimationOptions& o) {
    if (ends_with_ci(path, ".pc2")) return load_pc2(path);
    // A glTF with a skin is evaluated as skinned vertices, else as morph targets.
    Gltf g;
    g.path = path;
    load(g);
    bool skinned = false;
    for (const auto& n : g.m.nodes)
        if (n.skin >= 0 && n.mesh >= 0) skinned = true;
    if (skinned) return load_gltf_skinned_as_vertices(path, o);
    return load_gltf_morph_animation(path, o.fps);
}

}  // namespace progskin
