// scratch_export.cpp — a built-from-scratch skin as a progressive glTF (see
// save_scratch in scratch_build.h). Node 0 is the root (not a joint), nodes
// 1..B the joints in progressive order, node B+1 the skinned mesh.
#include <tiny_gltf.h>

#include <algorithm>
#include <cstring>
#include <limits>

#include "error.h"
#include "gltf_export.h"
#include "scratch_build.h"

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

    // Animation: one sampler per channel, a shared time accessor.
    const Clip& clip = c.clips[0];
    tinygltf::Animation anim;
    anim.name = clip.name;
    int time_acc = -1;
    for (const Channel& ch : clip.channels) {
        if (time_acc < 0) {
            time_acc = append_accessor(m, ch.times.data(), ch.times.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                    TINYGLTF_TYPE_SCALAR, ch.times.size(), 0);
            set_min_max<1>(m.accessors[size_t(time_acc)], ch.times.data(), ch.times.size());
        }
        const bool rot = ch.path == ChannelPath::Rotation;
        const int n = rot ? 4 : 3;
        tinygltf::AnimationSampler smp;
        smp.input = time_acc;
        smp.interpolation = "LINEAR";
        smp.output = append_accessor(m, ch.values.data(), ch.values.size() * 4, TINYGLTF_COMPONENT_TYPE_FLOAT,
                                  rot ? TINYGLTF_TYPE_VEC4 : TINYGLTF_TYPE_VEC3, ch.values.size() / size_t(n), 0);
        anim.samplers.push_back(smp);
        tinygltf::AnimationChannel ac;
        ac.sampler = int(anim.samplers.size() - 1);
        ac.target_node = c.nodes[size_t(ch.node)].gltf_index;
        ac.target_path = ch.path == ChannelPath::Translation ? "translation" : rot ? "rotation" : "scale";
        anim.channels.push_back(ac);
    }
    m.animations.push_back(anim);

    m.extensionsUsed.push_back("PROGSKIN_progressive_skin");
    nlohmann::json ext = progressive_extension_json(s);
    ext["fps"] = r.frames.frame_count() > 1 ? 1.0 / (r.frames.times[1] - r.frames.times[0]) : 30.0;
    ext["clips"] = "all";
    // The input's file name only: a path would publish the build machine's directories.
    ext["source"] = std::filesystem::path(c.source).filename().string();
    write_gltf(m, {{0, ext}}, path);
}

}  // namespace progskin
