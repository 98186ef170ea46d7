// scratch_export.cpp — a built-from-scratch skin as a progressive glTF (see
// save_scratch in scratch_build.h). Node 0 is the root (not a joint), nodes
// 1..B the joints in progressive order, node B+1 the skinned mesh.
#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "animation.h"
#include "errors.h"
#include "gltf_import.h"
#include "gltf_export.h"
#include "scratch_build.h"
#include "gltf_accessor.h"
#include "vertex_animation.h"

#include <filesystem>

namespace progskin {

namespace {

template <int N>
void set_min_max(tinygltf::Accessor& a, const float* v, size_t count) {
    std::vector<double> lo(N, std::numeric_limits<double>::max()), hi(N, -std::numeric_limits<double>::max());
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < N; ++k) {
            lo[k] = std::min(lo[k], double(v[i * N + k]));
            hi[k] = std::max(hi[k], double(v[i * N + k]));
        }
    a.minValues = lo;
    a.maxValues = hi;
}

// Appends raw bytes as a new buffer view (16-byte aligned) of buffer 0.
int append_bytes(tinygltf::Model& m, const unsigned char* data, size_t bytes) {
    auto& buf = m.buffers[0].data;
    while (buf.size() % 16) buf.push_back(0);
    tinygltf::BufferView bv;
    bv.buffer = 0;
    bv.byteOffset = buf.size();
    bv.byteLength = bytes;
    buf.insert(buf.end(), data, data + bytes);
    m.bufferViews.push_back(bv);
    return int(m.bufferViews.size() - 1);
}

// Copies the source's materials, textures, samplers and images (embedded
// images' bytes too) into m, indices unchanged.
void copy_materials(tinygltf::Model& m, const tinygltf::Model& src) {
    m.materials = src.materials;
    m.textures = src.textures;
    m.samplers = src.samplers;
    m.images = src.images;
    for (auto& img : m.images) {
        if (img.bufferView < 0 || size_t(img.bufferView) >= src.bufferViews.size()) continue;
        const tinygltf::BufferView& bv = src.bufferViews[size_t(img.bufferView)];
        if (bv.buffer < 0 || size_t(bv.buffer) >= src.buffers.size() ||
            bv.byteOffset + bv.byteLength > src.buffers[size_t(bv.buffer)].data.size()) {
            img.bufferView = -1;
            continue;
        }
        img.bufferView = append_bytes(m, src.buffers[size_t(bv.buffer)].data.data() + bv.byteOffset, bv.byteLength);
    }
}

// With a glTF source: the mesh split back into the source's mesh nodes and
// primitives (names, materials, TEXCOORD_n and COLOR_n kept) instead of one
// merged mesh. jj/ww: the progressive JOINTS_0/WEIGHTS_0 of every vertex.
// Returns false (m untouched) when the source cannot be mapped to the vertices.
bool keep_source_meshes(tinygltf::Model& m, const ScratchResult& r, const std::vector<uint16_t>& jj,
                        const std::vector<float>& ww, int mesh_node_index, nlohmann::json& ext) {
    const Character& c = r.character;
    const size_t V = c.vertex_count();
    std::vector<SourcePrimitive> sp;
    tinygltf::Model src;
    try {
        sp = gltf_source_primitives(c.source);
        if (sp.empty()) return false;
        gltf::load_model(c.source, src);
    } catch (const Error&) {
        return false;
    }
    size_t total = 0;
    for (const SourcePrimitive& p : sp) total += p.count;
    if (total != V) return false;
    copy_materials(m, src);
    // Triangles of each primitive (the loaders append them per primitive, in order).
    std::vector<std::vector<uint32_t>> tris(sp.size());
    size_t at = 0;
    for (size_t t = 0; t + 2 < c.triangles.size(); t += 3) {
        while (at < sp.size() && c.triangles[t] >= sp[at].first + sp[at].count) ++at;
        if (at == sp.size()) break;
        for (int k = 0; k < 3; ++k) tris[at].push_back(c.triangles[t + size_t(k)] - sp[at].first);
    }
    std::vector<tinygltf::Mesh> meshes;
    std::vector<tinygltf::Node> nodes;
    std::vector<std::string> dropped;
    for (size_t i = 0; i < sp.size(); ++i) {
        const SourcePrimitive& p = sp[i];
        if (nodes.empty() || nodes.back().name != src.nodes[size_t(p.node)].name ||
            meshes.back().name != src.meshes[size_t(p.mesh)].name || i == 0 || sp[i - 1].node != p.node) {
            tinygltf::Node n;
            n.name = src.nodes[size_t(p.node)].name;
            n.mesh = int(meshes.size());
            n.skin = 0;
            nodes.push_back(n);
            tinygltf::Mesh mesh;
            mesh.name = src.meshes[size_t(p.mesh)].name;
            meshes.push_back(mesh);
        }
        const tinygltf::Primitive& in = src.meshes[size_t(p.mesh)].primitives[size_t(p.primitive)];
        tinygltf::Primitive prim;
        prim.mode = tris[i].empty() ? TINYGLTF_MODE_POINTS : TINYGLTF_MODE_TRIANGLES;
        prim.material = in.material;
        const int pos = append_accessor(m, &c.positions[p.first], size_t(p.count) * 12, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                        TINYGLTF_TYPE_VEC3, p.count, TINYGLTF_TARGET_ARRAY_BUFFER);
        set_min_max<3>(m.accessors[size_t(pos)], &c.positions[p.first].x, p.count);
        prim.attributes["POSITION"] = pos;
        if (c.normals.size() == V)
            prim.attributes["NORMAL"] = append_accessor(m, &c.normals[p.first], size_t(p.count) * 12,
                                                        TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, p.count,
                                                        TINYGLTF_TARGET_ARRAY_BUFFER);
        prim.attributes["JOINTS_0"] = append_accessor(m, &jj[size_t(p.first) * 4], size_t(p.count) * 8,
                                                      TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT, TINYGLTF_TYPE_VEC4, p.count,
                                                      TINYGLTF_TARGET_ARRAY_BUFFER);
        prim.attributes["WEIGHTS_0"] = append_accessor(m, &ww[size_t(p.first) * 4], size_t(p.count) * 16,
                                                       TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC4, p.count,
                                                       TINYGLTF_TARGET_ARRAY_BUFFER);
        for (const auto& [name, index] : in.attributes) {
            const bool keep = name.rfind("TEXCOORD_", 0) == 0 || name.rfind("COLOR_", 0) == 0;
            if (!keep) {
                if (name != "POSITION" && name != "NORMAL" && name.rfind("JOINTS_", 0) != 0 &&
                    name.rfind("WEIGHTS_", 0) != 0)
                    dropped.push_back(name);  // TANGENT: belongs to the source's rest shape, not the new bind pose
                continue;
            }
            const tinygltf::Accessor& acc = src.accessors[size_t(index)];
            const int n = acc.type == TINYGLTF_TYPE_VEC2 ? 2 : acc.type == TINYGLTF_TYPE_VEC3 ? 3 : 4;
            const std::vector<double> v = gltf::read_accessor(c.source, src, index, n, name);
            if (v.size() != size_t(p.count) * size_t(n)) continue;
            const std::vector<float> f(v.begin(), v.end());
            prim.attributes[name] = append_accessor(m, f.data(), f.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                    n == 2 ? TINYGLTF_TYPE_VEC2 : n == 3 ? TINYGLTF_TYPE_VEC3
                                                                                       : TINYGLTF_TYPE_VEC4,
                                                    p.count, TINYGLTF_TARGET_ARRAY_BUFFER);
        }
        if (!tris[i].empty())
            prim.indices = append_accessor(m, tris[i].data(), tris[i].size() * 4, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT,
                                           TINYGLTF_TYPE_SCALAR, tris[i].size(), TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
        meshes.back().primitives.push_back(prim);
    }
    m.meshes = std::move(meshes);
    m.nodes.resize(size_t(mesh_node_index));
    m.scenes[0].nodes = {0};
    for (tinygltf::Node& n : nodes) {
        m.scenes[0].nodes.push_back(int(m.nodes.size()));
        m.nodes.push_back(std::move(n));
    }
    std::sort(dropped.begin(), dropped.end());
    dropped.erase(std::unique(dropped.begin(), dropped.end()), dropped.end());
    if (!dropped.empty()) ext["attributes_not_kept"] = dropped;
    return true;
}

// A run of keys of the fitted clip that came from one clip (group) of the source.
struct ClipPart {
    std::string name;
    size_t keys = 0;
};

// How the `keys` frames of a vertex animation loaded from `source` divide into
// its clips: a skinned glTF's default training set (each independently played
// group, names joined by "+", floor(duration * fps) + 1 frames each at the
// fitted clip's rate) when the counts add up; a morph-animation glTF's single
// named animation; else one part named `fallback`.
std::vector<ClipPart> source_clip_parts(const std::string& source, size_t keys, double fps,
                                        const std::string& fallback) {
    std::vector<ClipPart> parts;
    try {
        if (!gltf_source_primitives(source).empty()) {
            tinygltf::Model src;
            gltf::load_model(source, src);
            bool skinned = false;
            for (const auto& n : src.nodes) skinned = skinned || (n.skin >= 0 && n.mesh >= 0);
            if (skinned) {
                const Character c = import_character(source, 0);
                const auto sels = default_training_set(c);
                // The fitted clip's keys are sample_frames' frames of the default training set at fps.
                size_t total = 0;
                for (const ClipSelection& sel : sels) {
                    ClipPart p;
                    for (int i : sel.clips) p.name += (p.name.empty() ? "" : "+") + c.clips[size_t(i)].name;
                    p.keys = size_t(std::floor(std::max(0.0, double(sel.end) - double(sel.start)) * fps + 1e-6)) + 1;
                    total += p.keys;
                    parts.push_back(p);
                }
                if (total == keys && !parts.empty() && !parts[0].name.empty()) return parts;
                parts.clear();
            } else if (src.animations.size() == 1 && !src.animations[0].name.empty()) {
                return {{src.animations[0].name, keys}};
            }
        }
    } catch (const Error&) {
        parts.clear();
    }
    return {{fallback, keys}};
}

}  // namespace

void save_scratch(const ScratchResult& r, const std::string& path) {
    const Character& c = r.character;
    const ProgressiveSkin& s = r.skin;
    const int B = int(c.joint_count());
    const size_t V = c.vertex_count();
    if (B < 1 || V == 0 || s.bone_count() != B || c.clips.size() != 1)
        throw Error(path + ": nothing to write (empty scratch skin)");
    tinygltf::Model m;
    m.asset.version = "2.0";
    m.asset.generator = "progskin (build from scratch)";
    m.buffers.emplace_back();

    // Nodes.
    tinygltf::Node root;
    root.name = c.nodes[0].name;
    for (int j = 0; j < B; ++j) root.children.push_back(j + 1);
    m.nodes.push_back(root);
    for (int j = 0; j < B; ++j) {
        const Node& n = c.nodes[size_t(c.joint_node[size_t(j)])];
        tinygltf::Node gn;
        gn.name = n.name;
        gn.translation = {n.translation.x, n.translation.y, n.translation.z};
        m.nodes.push_back(gn);
    }
    tinygltf::Node mesh_node;
    mesh_node.name = "scratch_mesh";
    mesh_node.mesh = 0;
    mesh_node.skin = 0;
    m.nodes.push_back(mesh_node);
    tinygltf::Scene scene;
    scene.nodes = {0, B + 1};
    m.scenes.push_back(scene);
    m.defaultScene = 0;

    // Mesh.
    tinygltf::Primitive prim;
    prim.mode = TINYGLTF_MODE_TRIANGLES;
    {
        const int a = append_accessor(m, c.positions.data(), V * 12, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, V,
                                   TINYGLTF_TARGET_ARRAY_BUFFER);
        set_min_max<3>(m.accessors[size_t(a)], &c.positions[0].x, V);
        prim.attributes["POSITION"] = a;
    }
    if (c.normals.size() == V)
        prim.attributes["NORMAL"] = append_accessor(m, c.normals.data(), V * 12, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                 TINYGLTF_TYPE_VEC3, V, TINYGLTF_TARGET_ARRAY_BUFFER);
    std::vector<uint16_t> jj(V * 4, 0);
    std::vector<float> ww(V * 4, 0.0f);
    for (size_t v = 0; v < V; ++v)
        for (int i = 0; i < std::min(4, s.influences); ++i) {
            jj[v * 4 + i] = s.joints[v * s.influences + i];
            ww[v * 4 + i] = s.weights[v * s.influences + i];
        }
    prim.attributes["JOINTS_0"] = append_accessor(m, jj.data(), jj.size() * 2, TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                               TINYGLTF_TYPE_VEC4, V, TINYGLTF_TARGET_ARRAY_BUFFER);
    prim.attributes["WEIGHTS_0"] = append_accessor(m, ww.data(), ww.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                                TINYGLTF_TYPE_VEC4, V, TINYGLTF_TARGET_ARRAY_BUFFER);
    if (!c.triangles.empty())
        prim.indices = append_accessor(m, c.triangles.data(), c.triangles.size() * 4, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT,
                                    TINYGLTF_TYPE_SCALAR, c.triangles.size(), TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    else
        prim.mode = TINYGLTF_MODE_POINTS;
    tinygltf::Mesh mesh;
    mesh.name = "scratch";
    mesh.primitives.push_back(prim);
    m.meshes.push_back(mesh);
    nlohmann::json kept;
    const bool split = keep_source_meshes(m, r, jj, ww, B + 1, kept);
    if (split) prune_unused(m);  // the merged mesh's accessors

    // Skin.
    std::vector<float> ibm(size_t(B) * 16);
    for (int j = 0; j < B; ++j)
        for (int col = 0; col < 4; ++col)
            for (int row = 0; row < 4; ++row) ibm[size_t(j) * 16 + col * 4 + row] = float(c.inverse_bind[size_t(j)][col][row]);
    tinygltf::Skin skin;
    skin.name = "scratch";
    skin.skeleton = 0;
    for (int j = 0; j < B; ++j) skin.joints.push_back(j + 1);
    skin.inverseBindMatrices =
        append_accessor(m, ibm.data(), ibm.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_MAT4, size_t(B), 0);
    m.skins.push_back(skin);

    // Animations: the fitted clip cut back into the source's clips (one per
    // independently played group), else one; one sampler per channel, a
    // shared time accessor per animation, times from 0.
    const Clip& clip = c.clips[0];
    const size_t keys = clip.channels.empty() ? 0 : clip.channels[0].times.size();
    const double fps = r.frames.frame_count() > 1 ? 1.0 / (r.frames.times[1] - r.frames.times[0]) : 30.0;
    const std::vector<ClipPart> parts = source_clip_parts(c.source, keys, fps, clip.name);
    size_t first_key = 0;
    for (const ClipPart& part : parts) {
        tinygltf::Animation anim;
        anim.name = part.name;
        int time_acc = -1;
        for (const Channel& ch : clip.channels) {
            if (ch.times.size() < first_key + part.keys) continue;
            if (time_acc < 0) {
                std::vector<float> t(ch.times.begin() + std::ptrdiff_t(first_key),
                                     ch.times.begin() + std::ptrdiff_t(first_key + part.keys));
                const float t0 = t.front();
                for (float& x : t) x -= t0;
                time_acc = append_accessor(m, t.data(), t.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                           TINYGLTF_TYPE_SCALAR, t.size(), 0);
                set_min_max<1>(m.accessors[size_t(time_acc)], t.data(), t.size());
            }
            const bool rot = ch.path == ChannelPath::Rotation;
            const size_t n = rot ? 4 : 3;
            tinygltf::AnimationSampler smp;
            smp.input = time_acc;
            smp.interpolation = "LINEAR";
            smp.output = append_accessor(m, ch.values.data() + first_key * n, part.keys * n * 4,
                                         TINYGLTF_COMPONENT_TYPE_FLOAT, rot ? TINYGLTF_TYPE_VEC4 : TINYGLTF_TYPE_VEC3,
                                         part.keys, 0);
            anim.samplers.push_back(smp);
            tinygltf::AnimationChannel ac;
            ac.sampler = int(anim.samplers.size() - 1);
            ac.target_node = c.nodes[size_t(ch.node)].gltf_index;
            ac.target_path = ch.path == ChannelPath::Translation ? "translation" : rot ? "rotation" : "scale";
            anim.channels.push_back(ac);
        }
        m.animations.push_back(anim);
        first_key += part.keys;
    }

    m.extensionsUsed.push_back("PROGSKIN_progressive_skin");
    nlohmann::json ext = progressive_extension_json(s);
    ext["fps"] = fps;
    ext["clips"] = "all";
    // The input's file name only: a path would publish the build machine's directories.
    ext["source"] = std::filesystem::path(c.source).filename().string();
    ext["source_meshes_kept"] = split;  // meshes, names, materials, UVs and colours of a glTF source
    for (const auto& [key, value] : kept.items()) ext[key] = value;
    ext["clips_kept"] = nlohmann::json::array();
    for (const ClipPart& part : parts) ext["clips_kept"].push_back(part.name);
    write_gltf(m, {{0, ext}}, path);
}

}  // namespace progskin
