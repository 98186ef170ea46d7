#include "mesh_data.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cstring>

#include "palette.h"

namespace progskin::render {
namespace {

// Reads accessor `index` as `comps` floats per element (float, or normalized
// unsigned byte/short as the spec allows for TEXCOORD). Empty on any problem.
std::vector<float> read_floats(const tinygltf::Model& m, int index, int comps) {
    if (index < 0 || size_t(index) >= m.accessors.size()) return {};
    const tinygltf::Accessor& a = m.accessors[size_t(index)];
    if (a.bufferView < 0 || size_t(a.bufferView) >= m.bufferViews.size() || a.sparse.isSparse) return {};
    const tinygltf::BufferView& v = m.bufferViews[size_t(a.bufferView)];
    if (v.buffer < 0 || size_t(v.buffer) >= m.buffers.size()) return {};
    const auto& data = m.buffers[size_t(v.buffer)].data;
    int csize = a.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT            ? 4
                : a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT ? 2
                : a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE  ? 1
                                                                            : 0;
    if (csize == 0) return {};
    const size_t stride = v.byteStride ? v.byteStride : size_t(csize * comps);
    const size_t base = v.byteOffset + a.byteOffset;
    if (a.count > 0 && base + stride * (a.count - 1) + size_t(csize * comps) > data.size()) return {};
    std::vector<float> out(a.count * size_t(comps));
    for (size_t i = 0; i < a.count; ++i)
        for (int c = 0; c < comps; ++c) {
            const unsigned char* p = data.data() + base + stride * i + size_t(c * csize);
            float f = 0;
            if (csize == 4) {
                std::memcpy(&f, p, 4);
            } else if (csize == 2) {
                uint16_t u;
                std::memcpy(&u, p, 2);
                f = u / 65535.0f;
            } else {
                f = *p / 255.0f;
            }
            out[i * size_t(comps) + size_t(c)] = f;
        }
    return out;
}

bool load_model(const std::string& path, tinygltf::Model& model) {
    tinygltf::TinyGLTF loader;
    std::string err, warn;
    const bool glb = path.size() > 4 && (path.substr(path.size() - 4) == ".glb" || path.substr(path.size() - 4) == ".GLB");
    return glb ? loader.LoadBinaryFromFile(&model, &err, &warn, path) : loader.LoadASCIIFromFile(&model, &err, &warn, path);
}

void compute_normals(MeshData& m) {
    m.normals.assign(m.positions.size(), glm::vec3(0.0f));
    for (size_t t = 0; t + 2 < m.triangles.size(); t += 3) {
        const uint32_t a = m.triangles[t], b = m.triangles[t + 1], c = m.triangles[t + 2];
        const glm::vec3 n = glm::cross(m.positions[b] - m.positions[a], m.positions[c] - m.positions[a]);
        m.normals[a] += n;
        m.normals[b] += n;
        m.normals[c] += n;
    }
    for (auto& n : m.normals) {
        const float l = glm::length(n);
        n = l > 0 ? n / l : glm::vec3(0, 1, 0);
    }
}

}  // namespace

MeshData mesh_from_skin(const Character& c, const ProgressiveSkin& s, bool load_materials) {
    MeshData m;
    m.positions = c.positions;
    m.normals = c.normals;
    m.influences = s.influences;
    m.joints = s.joints;
    m.weights = s.weights;

    // Group triangles by the primitive their first vertex belongs to.
    const size_t P = c.primitives.size();
    std::vector<std::vector<uint32_t>> per_part(std::max<size_t>(P, 1));
    for (size_t t = 0; t + 2 < c.triangles.size(); t += 3) {
        const uint32_t v = c.triangles[t];
        size_t p = 0;
        for (size_t i = 0; i < P; ++i)
            if (v >= c.primitives[i].first && v < c.primitives[i].first + c.primitives[i].count) {
                p = i;
                break;
            }
        per_part[p].insert(per_part[p].end(), c.triangles.begin() + long(t), c.triangles.begin() + long(t) + 3);
    }
    for (size_t p = 0; p < per_part.size(); ++p) {
        MeshPart part;
        part.first_index = uint32_t(m.triangles.size());
        part.index_count = uint32_t(per_part[p].size());
        m.triangles.insert(m.triangles.end(), per_part[p].begin(), per_part[p].end());
        m.parts.push_back(part);
    }
    if (m.normals.size() != m.positions.size()) {
        m.flat_shaded = true;  // glTF: "client implementations MUST calculate flat normals"
        compute_normals(m);
    }
    if (!load_materials || c.source.empty() || P == 0) return m;

    tinygltf::Model model;
    if (!load_model(c.source, model)) return m;
    std::vector<int> texture_of_image(model.images.size(), -1);
    bool any_uv = false;
    std::vector<glm::vec2> uvs(c.positions.size(), glm::vec2(0.0f));
    for (size_t i = 0; i < P; ++i) {
        const PrimitiveRange& r = c.primitives[i];
        if (r.mesh < 0 || size_t(r.mesh) >= model.meshes.size()) continue;
        const auto& prims = model.meshes[size_t(r.mesh)].primitives;
        if (r.primitive < 0 || size_t(r.primitive) >= prims.size()) continue;
        const tinygltf::Primitive& prim = prims[size_t(r.primitive)];
        MeshPart& part = m.parts[i];
        int tex_coord = 0;
        if (prim.material >= 0 && size_t(prim.material) < model.materials.size()) {
            const auto& pbr = model.materials[size_t(prim.material)].pbrMetallicRoughness;
            if (pbr.baseColorFactor.size() == 4)
                part.base_color = glm::vec4(float(pbr.baseColorFactor[0]), float(pbr.baseColorFactor[1]),
                                            float(pbr.baseColorFactor[2]), float(pbr.baseColorFactor[3]));
            const int ti = pbr.baseColorTexture.index;
            tex_coord = pbr.baseColorTexture.texCoord;
            if (ti >= 0 && size_t(ti) < model.textures.size()) {
                const int src = model.textures[size_t(ti)].source;
                if (src >= 0 && size_t(src) < model.images.size()) {
                    const tinygltf::Image& img = model.images[size_t(src)];
                    if (texture_of_image[size_t(src)] < 0 && img.width > 0 && img.height > 0 &&
                        img.bits == 8 && (img.component == 3 || img.component == 4) &&
                        img.image.size() >= size_t(img.width) * size_t(img.height) * size_t(img.component)) {
                        Texture t;
                        t.width = img.width;
                        t.height = img.height;
                        t.rgba.resize(size_t(img.width) * size_t(img.height) * 4);
                        for (size_t px = 0; px < size_t(img.width) * size_t(img.height); ++px)
                            for (int k = 0; k < 4; ++k)
                                t.rgba[px * 4 + size_t(k)] =
                                    k < img.component ? img.image[px * size_t(img.component) + size_t(k)] : 255;
                        texture_of_image[size_t(src)] = int(m.textures.size());
                        m.textures.push_back(std::move(t));
                    }
                    part.texture = texture_of_image[size_t(src)];
                }
            }
        }
        const auto it = prim.attributes.find("TEXCOORD_" + std::to_string(tex_coord));
        if (it == prim.attributes.end()) {
            part.texture = -1;
            continue;
        }
        const std::vector<float> uv = read_floats(model, it->second, 2);
        if (uv.size() != size_t(r.count) * 2) {
            part.texture = -1;
            continue;
        }
        for (uint32_t v = 0; v < r.count; ++v) uvs[r.first + v] = {uv[v * 2], uv[v * 2 + 1]};
        any_uv = true;
    }
    if (any_uv) m.uvs = std::move(uvs);
    return m;
}

std::vector<Mat34> lod_palette(const ProgressiveSkin& s, std::span<const Mat34> joint_matrices, int k) {
    const int B = s.bone_count();
    k = std::clamp(k, 1, B);
    std::vector<Mat34> own(static_cast<size_t>(k)), out(static_cast<size_t>(B));
    for (int b = 0; b < k; ++b) own[size_t(b)] = joint_matrices[size_t(s.order[size_t(b)])];
    PaletteJob job;
    job.parents = s.parents;
    job.corrections = s.corrections;
    job.own = own;
    job.out = out;
    if (!job.validate()) return {};
    job.run();
    return out;
}

}  // namespace progskin::render
