// gltf_export.cpp — writing and reading the progressive glTF (see gltf_export.h).
#include "gltf_export.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include "errors.h"
#include "gltf_accessor.h"
#include "gltf_import.h"
#include "self_contained.h"

namespace progskin {

namespace {

constexpr const char* kExtension = "PROGSKIN_progressive_skin";

bool no_image_write(const std::string*, const std::string*, const tinygltf::Image*, bool, std::string*, void*) {
    return false;  // keep the original uri / bufferView
}

bool ends_with(const std::string& s, const std::string& suffix) {
    return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

tinygltf::Model load_model(const std::string& path) {
    tinygltf::Model model;
    gltf::load_model(path, model);
    return model;
}

// All buffers merged into buffer 0 so that a .glb has its single BIN chunk.
void merge_buffers(tinygltf::Model& m) {
    if (m.buffers.empty()) m.buffers.emplace_back();
    std::vector<size_t> base(m.buffers.size(), 0);
    auto& dst = m.buffers[0].data;
    for (size_t i = 1; i < m.buffers.size(); ++i) {
        while (dst.size() % 16) dst.push_back(0);
        base[i] = dst.size();
        dst.insert(dst.end(), m.buffers[i].data.begin(), m.buffers[i].data.end());
    }
    for (auto& bv : m.bufferViews) {
        bv.byteOffset += base[size_t(bv.buffer)];
        bv.buffer = 0;
    }
    m.buffers.resize(1);
    m.buffers[0].uri.clear();
}

// Extensions whose JSON refers to accessors or buffer views by index: a model
// using one is not pruned (its references are not visible to prune_unused).
bool refers_by_index(const tinygltf::Model& m) {
    for (const std::string& e : m.extensionsUsed)
        if (e == "EXT_mesh_gpu_instancing" || e == "KHR_draco_mesh_compression" || e == "EXT_meshopt_compression" ||
            e == "KHR_meshopt_compression" || e == "KHR_animation_pointer")
            return true;
    return false;
}

}  // namespace

void add_missing_bounds(tinygltf::Model& m, const std::string& path) {
    auto bound = [&](int index, int components, const std::string& what) {
        if (index < 0 || size_t(index) >= m.accessors.size()) return;
        tinygltf::Accessor& a = m.accessors[size_t(index)];
        if (a.minValues.size() == size_t(components) && a.maxValues.size() == size_t(components)) return;
        const std::vector<double> v = gltf::read_accessor(path, m, index, components, what);
        if (v.empty()) return;
        a.minValues.assign(v.begin(), v.begin() + components);
        a.maxValues = a.minValues;
        for (size_t i = 0; i < v.size(); ++i) {
            const size_t c = i % size_t(components);
            a.minValues[c] = std::min(a.minValues[c], v[i]);
            a.maxValues[c] = std::max(a.maxValues[c], v[i]);
        }
    };
    for (size_t mi = 0; mi < m.meshes.size(); ++mi)
        for (const auto& prim : m.meshes[mi].primitives) {
            auto it = prim.attributes.find("POSITION");
            if (it != prim.attributes.end()) bound(it->second, 3, "mesh " + std::to_string(mi) + " POSITION");
            for (const auto& target : prim.targets) {
                auto t = target.find("POSITION");
                if (t != target.end()) bound(t->second, 3, "mesh " + std::to_string(mi) + " morph target POSITION");
            }
        }
    for (size_t ai = 0; ai < m.animations.size(); ++ai)
        for (const auto& smp : m.animations[ai].samplers) bound(smp.input, 1, "animation " + std::to_string(ai) + " input");
}

size_t prune_unused(tinygltf::Model& m) {
    if (refers_by_index(m) || m.buffers.size() != 1) return 0;
    // Accessors referenced by meshes, skins and animations.
    std::vector<char> used_acc(m.accessors.size(), 0);
    auto use = [&](int a) {
        if (a >= 0 && size_t(a) < used_acc.size()) used_acc[size_t(a)] = 1;
    };
    for (const auto& mesh : m.meshes)
        for (const auto& prim : mesh.primitives) {
            for (const auto& [name, a] : prim.attributes) use(a);
            use(prim.indices);
            for (const auto& target : prim.targets)
                for (const auto& [name, a] : target) use(a);
        }
    for (const auto& skin : m.skins) use(skin.inverseBindMatrices);
    for (const auto& anim : m.animations)
        for (const auto& smp : anim.samplers) {
            use(smp.input);
            use(smp.output);
        }
    std::vector<int> acc_index(m.accessors.size(), -1);
    std::vector<tinygltf::Accessor> accessors;
    for (size_t a = 0; a < m.accessors.size(); ++a)
        if (used_acc[a]) {
            acc_index[a] = int(accessors.size());
            accessors.push_back(m.accessors[a]);
        }
    const size_t removed = m.accessors.size() - accessors.size();
    auto remap_acc = [&](int& a) {
        if (a >= 0 && size_t(a) < acc_index.size()) a = acc_index[size_t(a)];
    };
    for (auto& mesh : m.meshes)
        for (auto& prim : mesh.primitives) {
            for (auto& [name, a] : prim.attributes) remap_acc(a);
            remap_acc(prim.indices);
            for (auto& target : prim.targets)
                for (auto& [name, a] : target) remap_acc(a);
        }
    for (auto& skin : m.skins) remap_acc(skin.inverseBindMatrices);
    for (auto& anim : m.animations)
        for (auto& smp : anim.samplers) {
            remap_acc(smp.input);
            remap_acc(smp.output);
        }
    m.accessors = std::move(accessors);

    // Buffer views referenced by the remaining accessors and by images; the buffer compacted.
    std::vector<char> used_view(m.bufferViews.size(), 0);
    auto use_view = [&](int v) {
        if (v >= 0 && size_t(v) < used_view.size()) used_view[size_t(v)] = 1;
    };
    for (const auto& a : m.accessors) {
        use_view(a.bufferView);
        if (a.sparse.isSparse) {
            use_view(a.sparse.indices.bufferView);
            use_view(a.sparse.values.bufferView);
        }
    }
    for (const auto& img : m.images) use_view(img.bufferView);
    std::vector<int> view_index(m.bufferViews.size(), -1);
    std::vector<tinygltf::BufferView> views;
    std::vector<unsigned char> data;
    const std::vector<unsigned char>& old = m.buffers[0].data;
    for (size_t v = 0; v < m.bufferViews.size(); ++v) {
        if (!used_view[v]) continue;
        tinygltf::BufferView bv = m.bufferViews[v];
        // Same offset modulo 16 as before: every accessor keeps its alignment.
        size_t at = (data.size() + 15) & ~size_t(15);
        at += bv.byteOffset % 16;
        data.resize(at, 0);
        if (bv.byteOffset + bv.byteLength > old.size()) return removed;  // malformed: leave the data as it is
        data.insert(data.end(), old.begin() + std::ptrdiff_t(bv.byteOffset),
                    old.begin() + std::ptrdiff_t(bv.byteOffset + bv.byteLength));
        bv.byteOffset = at;
        view_index[v] = int(views.size());
        views.push_back(bv);
    }
    while (data.size() % 4) data.push_back(0);
    auto remap_view = [&](int& v) {
        if (v >= 0 && size_t(v) < view_index.size()) v = view_index[size_t(v)];
    };
    for (auto& a : m.accessors) {
        remap_view(a.bufferView);
        if (a.sparse.isSparse) {
            remap_view(a.sparse.indices.bufferView);
            remap_view(a.sparse.values.bufferView);
        }
    }
    for (auto& img : m.images) remap_view(img.bufferView);
    m.bufferViews = std::move(views);
    m.buffers[0].data = std::move(data);
    return removed;
}

// Appends bytes to buffer 0 (4-byte aligned) and returns a new buffer view.
static int append_view(tinygltf::Model& m, const void* data, size_t bytes, int target) {
    auto& buf = m.buffers[0].data;
    while (buf.size() % 4) buf.push_back(0);
    tinygltf::BufferView bv;
    bv.buffer = 0;
    bv.byteOffset = buf.size();
    bv.byteLength = bytes;
    bv.target = target;
    const auto* p = static_cast<const unsigned char*>(data);
    buf.insert(buf.end(), p, p + bytes);
    m.bufferViews.push_back(bv);
    return int(m.bufferViews.size() - 1);
}

int append_accessor(tinygltf::Model& m, const void* data, size_t bytes, int component, int type, size_t count,
                    int target, bool normalized) {
    tinygltf::Accessor a;
    a.bufferView = append_view(m, data, bytes, target);
    a.byteOffset = 0;
    a.componentType = component;
    a.type = type;
    a.count = count;
    a.normalized = normalized;
    m.accessors.push_back(a);
    return int(m.accessors.size() - 1);
}

nlohmann::json progressive_extension_json(const ProgressiveSkin& s) {
    nlohmann::json j;
    j["version"] = 1;
    j["strategy"] = strategy_name(s.strategy);
    j["parents"] = nlohmann::json::array();
    for (int16_t p : s.parents) j["parents"].push_back(int(p));
    j["corrections"] = nlohmann::json::array();
    for (const Mat34& m : s.corrections)
        for (float x : m.m) j["corrections"].push_back(double(x));
    j["diagonal"] = s.diagonal;
    j["error"] = nlohmann::json::array();
    for (const LodError& e : s.error)
        j["error"].push_back({{"bones", e.bones},
                              {"rms", e.rms},
                              {"max", e.max},
                              {"rms_pct", e.rms_pct},
                              {"max_pct", e.max_pct},
                              {"influences", e.influences}});
    for (size_t i = 0; i < s.error.size(); ++i)
        if (s.error[i].distortion_pct >= 0) j["error"][i]["distortion_pct"] = s.error[i].distortion_pct;
    return j;
}

namespace {

// tinygltf 2.7 does not serialise skin extensions, so the extension objects
// are patched into the JSON chunk after writing (skin index -> extension).
std::string patch_json(const std::string& text, const std::map<int, nlohmann::json>& skin_ext, bool pretty) {
    nlohmann::json j = nlohmann::json::parse(text);
    for (const auto& [i, e] : skin_ext) j["skins"][size_t(i)]["extensions"][kExtension] = e;
    return j.dump(pretty ? 2 : -1);
}

uint32_t read_u32(const std::string& s, size_t at) {
    uint32_t v;
    std::memcpy(&v, s.data() + at, 4);
    return v;
}
void put_u32(std::string& s, uint32_t v) { s.append(reinterpret_cast<const char*>(&v), 4); }

std::string patch_glb(const std::string& glb, const std::map<int, nlohmann::json>& skin_ext) {
    if (glb.size() < 20 || read_u32(glb, 0) != 0x46546C67u) throw Error("internal: tinygltf wrote no GLB");
    const uint32_t json_len = read_u32(glb, 12);
    std::string json = patch_json(glb.substr(20, json_len), skin_ext, false);
    while (json.size() % 4) json.push_back(' ');
    const std::string rest = glb.substr(20 + json_len);  // BIN chunk with its header, if any
    std::string out;
    put_u32(out, 0x46546C67u);
    put_u32(out, 2);
    put_u32(out, uint32_t(12 + 8 + json.size() + rest.size()));
    put_u32(out, uint32_t(json.size()));
    put_u32(out, 0x4E4F534Au);
    out += json;
    out += rest;
    return out;
}

}  // namespace

void write_gltf(tinygltf::Model& m, const std::map<int, nlohmann::json>& skin_ext, const std::string& out_path) {
    namespace fs = std::filesystem;
    const bool binary = !ends_with(out_path, ".gltf");
    tinygltf::TinyGLTF writer;
    writer.SetImageWriter(no_image_write, nullptr);
    std::ostringstream os;
    if (!writer.WriteGltfSceneToStream(&m, os, !binary, binary)) throw Error(out_path + ": cannot serialise the glTF");
    const std::string bytes = binary ? patch_glb(os.str(), skin_ext) : patch_json(os.str(), skin_ext, true);
    const fs::path out(out_path);
    const fs::path tmp = out.parent_path() / (out.filename().string() + ".tmp" + std::to_string(getpid()));
    std::error_code ec;
    {
        std::ofstream f(tmp, std::ios::binary);
        f.write(bytes.data(), std::streamsize(bytes.size()));
        f.close();
        if (!f) {
            fs::remove(tmp, ec);
            throw Error(out_path + ": cannot write the file");
        }
    }
    fs::rename(tmp, out, ec);
    if (ec) {
        fs::remove(tmp, ec);
        throw Error(out_path + ": cannot write the file: " + ec.message());
    }
}


void save_progressive(const Character& c, const ProgressiveSkin& s, const std::string& out_path,
                      const std::string& note, const nlohmann::json& extra) {
    const int B = s.bone_count();
    if (B != int(c.joint_count()) || s.parents.size() != size_t(B) || s.corrections.size() != size_t(B))
        throw Error(out_path + ": progressive skin does not match the character");
    tinygltf::Model m = load_model(c.source);
    merge_buffers(m);
    embed_external_images(m, c.source);  // the output is self-contained wherever it is written

    // The unified joint list in progressive order, with its inverse bind matrices.
    std::vector<int> joints(size_t(B), 0);
    std::vector<float> ibm(size_t(B) * 16);
    for (int b = 0; b < B; ++b) {
        const int j = s.order[b];
        joints[b] = c.nodes[c.joint_node[j]].gltf_index;
        const glm::dmat4& M = c.inverse_bind[j];
        for (int col = 0; col < 4; ++col)
            for (int row = 0; row < 4; ++row) ibm[b * 16 + col * 4 + row] = float(M[col][row]);
    }
    // Two joints of the character on one glTF node (skins of one skeleton
    // merged, gltf_import.cpp, whose inverse binds differ) cannot both be
    // listed: glTF forbids a node twice in skin.joints. The second gets a
    // child node of its own with the identity transform (the same global
    // matrix), listed instead.
    {
        std::vector<char> listed(m.nodes.size(), 0);
        for (int b = 0; b < B; ++b) {
            const int node = joints[size_t(b)];
            if (!listed[size_t(node)]) {
                listed[size_t(node)] = 1;
                continue;
            }
            tinygltf::Node helper;
            helper.name = m.nodes[size_t(node)].name + "_joint" + std::to_string(b);
            m.nodes.push_back(helper);
            joints[size_t(b)] = int(m.nodes.size()) - 1;
            m.nodes[size_t(node)].children.push_back(joints[size_t(b)]);
        }
    }
    const int ibm_acc = append_accessor(m, ibm.data(), ibm.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                        TINYGLTF_TYPE_MAT4, size_t(B), 0);

    nlohmann::json ext = progressive_extension_json(s);
    if (!note.empty()) ext["note"] = note;
    if (extra.is_object())
        for (const auto& [key, value] : extra.items()) ext[key] = value;
    // A mesh that this character skins and that another node uses too
    // (another character's, or this one's under another skin) gets a copy
    // for each of its users but the last: its joints are rewritten for this
    // character's joint list.
    {
        std::vector<int> users(m.meshes.size(), 0);
        for (const tinygltf::Node& n : m.nodes)
            if (n.mesh >= 0 && size_t(n.mesh) < m.meshes.size()) ++users[size_t(n.mesh)];
        std::vector<char> copied(m.nodes.size(), 0);
        for (const PrimitiveRange& r : c.primitives) {
            if (r.rigid || r.node < 0 || size_t(r.node) >= m.nodes.size() || copied[size_t(r.node)]) continue;
            copied[size_t(r.node)] = 1;
            const int mesh = m.nodes[size_t(r.node)].mesh;
            // The last of its users keeps the original (no mesh left unused).
            if (mesh < 0 || size_t(mesh) >= m.meshes.size() || users[size_t(mesh)] < 2) continue;
            --users[size_t(mesh)];
            tinygltf::Mesh copy = m.meshes[size_t(mesh)];
            m.meshes.push_back(std::move(copy));
            m.nodes[size_t(r.node)].mesh = int(m.meshes.size()) - 1;
        }
    }
    std::vector<char> skin_done(m.skins.size(), 0);
    std::map<int, nlohmann::json> skin_ext;
    const int I = s.influences;
    for (const PrimitiveRange& r : c.primitives) {
        if (r.rigid) continue;
        if (r.skin < 0 || size_t(r.skin) >= m.skins.size()) throw Error(c.source + ": primitive without its skin");
        if (!skin_done[r.skin]) {
            tinygltf::Skin& sk = m.skins[size_t(r.skin)];
            sk.joints = joints;
            sk.inverseBindMatrices = ibm_acc;
            skin_ext[r.skin] = ext;
            skin_done[r.skin] = 1;
        }
        auto& prim = m.meshes[size_t(m.nodes[size_t(r.node)].mesh)].primitives[size_t(r.primitive)];
        for (int set = 0; set * 4 < I; ++set) {
            std::vector<uint16_t> jj(size_t(r.count) * 4, 0);
            std::vector<float> ww(size_t(r.count) * 4, 0.0f);
            for (uint32_t v = 0; v < r.count; ++v)
                for (int i = 0; i < 4; ++i) {
                    jj[v * 4 + i] = s.joints[(r.first + v) * I + set * 4 + i];
                    ww[v * 4 + i] = s.weights[(r.first + v) * I + set * 4 + i];
                }
            const std::string n = std::to_string(set);
            prim.attributes["JOINTS_" + n] =
                append_accessor(m, jj.data(), jj.size() * 2, TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT,
                                TINYGLTF_TYPE_VEC4, r.count, TINYGLTF_TARGET_ARRAY_BUFFER);
            prim.attributes["WEIGHTS_" + n] =
                append_accessor(m, ww.data(), ww.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC4,
                                r.count, TINYGLTF_TARGET_ARRAY_BUFFER);
        }
    }
    if (std::find(m.extensionsUsed.begin(), m.extensionsUsed.end(), kExtension) == m.extensionsUsed.end())
        m.extensionsUsed.push_back(kExtension);
    prune_unused(m);  // the input's JOINTS/WEIGHTS and inverse bind matrices, now replaced
    add_missing_bounds(m, c.source);
    write_gltf(m, skin_ext, out_path);
}

void write_with_skins_first(const std::string& path, const std::vector<int>& first, const std::string& out_path) {
    tinygltf::Model m = load_model(path);
    std::vector<int> order;  // new skin index -> old
    for (int s : first) {
        if (s < 0 || size_t(s) >= m.skins.size()) throw Error(path + ": no skin " + std::to_string(s));
        if (std::find(order.begin(), order.end(), s) == order.end()) order.push_back(s);
    }
    for (int s = 0; s < int(m.skins.size()); ++s)
        if (std::find(order.begin(), order.end(), s) == order.end()) order.push_back(s);
    std::vector<int> new_index(m.skins.size());
    for (size_t i = 0; i < order.size(); ++i) new_index[size_t(order[i])] = int(i);
    std::vector<tinygltf::Skin> skins;
    std::map<int, nlohmann::json> skin_ext;
    for (size_t i = 0; i < order.size(); ++i) {
        skins.push_back(m.skins[size_t(order[i])]);
        if (skins.back().extensions.count(kExtension))
            skin_ext[int(i)] = gltf::value_json(skins.back().extensions.at(kExtension));
    }
    m.skins = std::move(skins);
    for (auto& n : m.nodes)
        if (n.skin >= 0 && size_t(n.skin) < new_index.size()) n.skin = new_index[size_t(n.skin)];
    merge_buffers(m);
    embed_external_images(m, path);
    add_missing_bounds(m, path);
    write_gltf(m, skin_ext, out_path);
}

}  // namespace progskin
