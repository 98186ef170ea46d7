// test_import.cpp — glTF import on the shipped assets, on hand-made fixtures
// (tests/data/make_gltf_fixtures.py) and on broken files (tests/data/broken/).
#include <gtest/gtest.h>

#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <string>

#include "animation.h"
#include "errors.h"
#include "gltf_import.h"
#include "representable.h"

using namespace progskin;

namespace {

std::string asset(const std::string& name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }
std::string data(const std::string& name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }

// Every vertex's weights are non-negative and sum to 1; joints index the character's joints.
void expect_valid_influences(const Character& c) {
    const size_t k = size_t(c.influences);
    ASSERT_EQ(c.weights.size(), c.vertex_count() * k);
    ASSERT_EQ(c.joints.size(), c.vertex_count() * k);
    for (size_t v = 0; v < c.vertex_count(); ++v) {
        double sum = 0.0;
        for (size_t i = 0; i < k; ++i) {
            EXPECT_GE(c.weights[v * k + i], 0.0f);
            EXPECT_LT(c.joints[v * k + i], c.joint_count());
            sum += c.weights[v * k + i];
        }
        ASSERT_NEAR(sum, 1.0, 1e-6) << "vertex " << v;
    }
}

// Structural invariants every imported character satisfies.
void expect_consistent(const Character& c) {
    ASSERT_EQ(c.joint_parent.size(), c.joint_count());
    ASSERT_EQ(c.inverse_bind.size(), c.joint_count());
    for (size_t i = 0; i < c.nodes.size(); ++i) EXPECT_LT(c.nodes[i].parent, int(i)) << "parents come first";
    for (int n : c.joint_node) EXPECT_TRUE(n >= 0 && size_t(n) < c.nodes.size());
    EXPECT_TRUE(c.normals.empty() || c.normals.size() == c.positions.size());
    for (uint32_t t : c.triangles) EXPECT_LT(t, c.vertex_count());
    uint32_t next = 0;
    for (const PrimitiveRange& r : c.primitives) {
        EXPECT_EQ(r.first, next);
        next += r.count;
    }
    EXPECT_EQ(next, c.vertex_count());
    expect_valid_influences(c);
}

// Skinned positions v = sum w M v of the whole character at time t of `sel`.
std::vector<glm::dvec3> skinned(const Character& c, const ClipSelection& sel, double t) {
    std::vector<glm::dmat4> m(c.joint_count());
    sample_skinning_matrices(c, sel, t, m);
    std::vector<glm::dvec3> out(c.vertex_count(), glm::dvec3(0.0));
    const size_t k = size_t(c.influences);
    for (size_t v = 0; v < c.vertex_count(); ++v)
        for (size_t i = 0; i < k; ++i)
            out[v] += double(c.weights[v * k + i]) *
                      glm::dvec3(m[c.joints[v * k + i]] * glm::dvec4(glm::dvec3(c.positions[v]), 1.0));
    return out;
}

double diagonal(const std::vector<glm::dvec3>& p) {
    glm::dvec3 lo(1e300), hi(-1e300);
    for (const auto& x : p) lo = glm::min(lo, x), hi = glm::max(hi, x);
    return glm::length(hi - lo);
}

double max_distance(const std::vector<glm::dvec3>& a, const std::vector<glm::dvec3>& b) {
    double d = 0.0;
    for (size_t i = 0; i < a.size(); ++i) d = std::max(d, glm::length(a[i] - b[i]));
    return d;
}

void expect_near(const glm::dvec3& a, const glm::dvec3& b, double tol = 1e-6) {
    EXPECT_NEAR(a.x, b.x, tol);
    EXPECT_NEAR(a.y, b.y, tol);
    EXPECT_NEAR(a.z, b.z, tol);
}

// The error message of importing `file`, or "" when it imports.
std::string import_error(const std::string& file) {
    try {
        import_gltf(file);
    } catch (const Error& e) {
        return e.what();
    }
    return "";
}

}  // namespace

// ---------------------------------------------------------------------------
// Shipped assets

TEST(ImportAssets, RiggedSimple) {
    const auto all = import_gltf(asset("RiggedSimple.gltf"));
    ASSERT_EQ(all.size(), 1u);
    const Character& c = all[0];
    expect_consistent(c);
    EXPECT_EQ(c.joint_count(), 2u);
    EXPECT_EQ(c.vertex_count(), 160u);
    EXPECT_EQ(c.normals.size(), 160u);
    EXPECT_EQ(c.influences, 4);
    EXPECT_EQ(c.joint_parent, (std::vector<int>{-1, 0}));
    ASSERT_EQ(c.primitives.size(), 1u);
    EXPECT_EQ(c.primitives[0].node, 2);
    EXPECT_EQ(c.primitives[0].skin, 0);
    EXPECT_FALSE(c.primitives[0].rigid);
    // Z_UP and Armature are non-joint ancestors of the skeleton and the mesh.
    ASSERT_EQ(c.nodes.size(), 5u);
    EXPECT_EQ(c.nodes[0].name, "Z_UP");
    EXPECT_TRUE(c.nodes[0].has_matrix);
    EXPECT_EQ(c.nodes[c.joint_node[0]].name, "Bone");
    ASSERT_EQ(c.clips.size(), 1u);
    EXPECT_EQ(c.clips[0].name, "clip 0");
    EXPECT_EQ(c.clips[0].channels.size(), 3u);
    EXPECT_EQ(c.source, asset("RiggedSimple.gltf"));
}

TEST(ImportAssets, CesiumManClipsPlayTogether) {
    const Character c = import_character(asset("CesiumMan.glb"));
    expect_consistent(c);
    EXPECT_EQ(c.joint_count(), 19u);
    EXPECT_EQ(c.vertex_count(), 3273u);
    EXPECT_EQ(c.clips.size(), 19u);
    EXPECT_GT(c.renormalised_vertices, 0u);  // the file's weights do not all sum to 1
    bool noted = false;
    for (const auto& n : c.notes) noted = noted || n.find("renormalised") != std::string::npos;
    EXPECT_TRUE(noted);
    const auto training = default_training_set(c);
    ASSERT_EQ(training.size(), 1u);
    EXPECT_EQ(training[0].clips.size(), 19u);
    EXPECT_FLOAT_EQ(training[0].start, 0.0f);
    EXPECT_FLOAT_EQ(training[0].end, 2.0f);
    const FrameSet fs = sample_frames(c, training, 30.0);
    EXPECT_EQ(fs.frame_count(), 61u);
    EXPECT_DOUBLE_EQ(fs.times.front(), 0.0);
    EXPECT_NEAR(fs.times.back(), 2.0, 1e-9);
    EXPECT_EQ(fs.skinning.size(), 61u * 19u);
}

TEST(ImportAssets, FoxClipsAndNoNormals) {
    const Character c = import_character(asset("Fox.glb"));
    expect_consistent(c);
    EXPECT_EQ(c.joint_count(), 24u);
    EXPECT_EQ(c.vertex_count(), 1728u);
    EXPECT_TRUE(c.normals.empty());
    ASSERT_EQ(c.clips.size(), 3u);
    EXPECT_EQ(c.clips[0].name, "Survey");
    EXPECT_EQ(c.clips[1].name, "Walk");
    EXPECT_EQ(c.clips[2].name, "Run");
    EXPECT_EQ(default_training_set(c).size(), 3u);  // the clips animate the same joints
    EXPECT_EQ(select_clips(c, "Walk").clips, std::vector<int>{1});
    EXPECT_EQ(select_clips(c, "2").clips, std::vector<int>{2});
    EXPECT_EQ(select_clips(c, "Survey, Run").clips, (std::vector<int>{0, 2}));
    EXPECT_EQ(select_clips(c, "all").clips, (std::vector<int>{0, 1, 2}));
    const ClipSelection run = select_clips(c, "Run");
    EXPECT_FLOAT_EQ(run.start, c.clips[2].start);
    EXPECT_FLOAT_EQ(run.end, c.clips[2].end);
    try {
        select_clips(c, "Jump");
        FAIL() << "unknown clip accepted";
    } catch (const Error& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("Jump"), std::string::npos);
        EXPECT_NE(what.find("Survey"), std::string::npos);
        EXPECT_NE(what.find("Fox.glb"), std::string::npos);
    }
    EXPECT_THROW(select_clips(c, "7"), Error);
}

TEST(ImportAssets, MorphSphereHasNoSkin) {
    const std::string what = import_error(asset("AnimatedMorphSphere.gltf"));
    EXPECT_NE(what.find("AnimatedMorphSphere.gltf"), std::string::npos);
    EXPECT_NE(what.find("no skin"), std::string::npos);
    ImportOptions lenient;
    lenient.require_skin = false;
    EXPECT_TRUE(import_gltf(asset("AnimatedMorphSphere.gltf"), lenient).empty());
}

TEST(ImportAssets, ImportCharacterIndexOutOfRange) {
    try {
        import_character(asset("Fox.glb"), 3);
        FAIL();
    } catch (const Error& e) {
        EXPECT_NE(std::string(e.what()).find("no character 3"), std::string::npos);
    }
}

// At rest every skinning matrix is the same rigid transform (the transform above the skeleton).
TEST(ImportAssets, RestPoseIsRigid) {
    for (const char* name : {"RiggedSimple.gltf", "CesiumMan.glb", "Fox.glb"}) {
        const Character c = import_character(asset(name));
        std::vector<glm::dmat4> m(c.joint_count());
        sample_skinning_matrices(c, ClipSelection{}, 0.0, m);
        const glm::dmat3 r(m[0]);
        const glm::dmat3 rtr = glm::transpose(r) * r;
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) EXPECT_NEAR(rtr[a][b], a == b ? 1.0 : 0.0, 1e-4) << name;
        for (const auto& x : m)
            for (int a = 0; a < 4; ++a)
                for (int b = 0; b < 4; ++b) EXPECT_NEAR(x[a][b], m[0][a][b], 1e-4) << name;
        const auto rest = skinned(c, ClipSelection{}, 0.0);
        for (const auto& p : rest) ASSERT_TRUE(finite(p));
    }
}

// Small time steps move vertices little: no jumps within or between keys.
TEST(ImportAssets, SamplingIsContinuous) {
    struct Case {
        const char* file;
        const char* clip;
    };
    for (const Case& k : {Case{"RiggedSimple.gltf", "all"}, Case{"CesiumMan.glb", "all"}, Case{"Fox.glb", "Survey"},
                          Case{"Fox.glb", "Run"}}) {
        const Character c = import_character(asset(k.file));
        const ClipSelection sel = select_clips(c, k.clip);
        const double diag = diagonal(skinned(c, ClipSelection{}, 0.0));
        const double dt = 1.0 / 480.0;
        std::vector<glm::dvec3> prev = skinned(c, sel, sel.start);
        double worst = 0.0, total = 0.0;
        for (double t = sel.start + dt; t <= sel.end; t += dt) {
            const auto cur = skinned(c, sel, t);
            const double step = max_distance(prev, cur);
            worst = std::max(worst, step);
            total += step;
            prev = cur;
        }
        EXPECT_GT(total, 0.01 * diag) << k.file << " " << k.clip << " does not move";
        EXPECT_LT(worst, 0.02 * diag) << k.file << " " << k.clip << " jumps";
        // Clamping: before the first key equals the first key, after the last equals the last.
        EXPECT_LT(max_distance(skinned(c, sel, sel.start - 1.0), skinned(c, sel, sel.start)), 1e-9 * diag);
        EXPECT_LT(max_distance(skinned(c, sel, sel.end + 1.0), skinned(c, sel, sel.end)), 1e-9 * diag);
    }
}

// ---------------------------------------------------------------------------
// Hand-made fixtures

TEST(ImportFixtures, SparseQuantizedStrided) {
    const Character c = import_character(data("sparse_quantized.gltf"));
    expect_consistent(c);
    ASSERT_EQ(c.vertex_count(), 7u);
    // Primitive 0: strided view with offsets, vertex 2 replaced by the sparse value.
    expect_near(c.positions[0], {0, 0, 0});
    expect_near(c.positions[1], {1, 0, 0});
    expect_near(c.positions[2], {0, 2.5, 0});
    expect_near(c.positions[3], {1, 2, 0});
    // Primitive 1: no buffer view (zeros) with two sparse values.
    expect_near(c.positions[4], {0, 0, 0});
    expect_near(c.positions[5], {1, 0, 0});
    expect_near(c.positions[6], {0, 1, 0});
    // NORMAL only on primitive 0: primitive 1 is filled with +z.
    ASSERT_EQ(c.normals.size(), 7u);
    expect_near(c.normals[6], {0, 0, 1});
    // Normalized u8 weights (strided), u8 joints at an offset with a stride.
    EXPECT_EQ(c.joints[0 * 4 + 0], 0);
    EXPECT_EQ(c.joints[0 * 4 + 1], 1);
    EXPECT_FLOAT_EQ(c.weights[0 * 4 + 0], 1.0f);
    EXPECT_NEAR(c.weights[1 * 4 + 0], 128.0 / 255.0, 1e-6);
    EXPECT_NEAR(c.weights[1 * 4 + 1], 127.0 / 255.0, 1e-6);
    EXPECT_NEAR(c.weights[2 * 4 + 0], 0.5, 1e-6);  // 100/255 + 100/255, renormalised
    EXPECT_NEAR(c.weights[3 * 4 + 1], 1.0, 1e-6);  // 254/255, renormalised
    EXPECT_EQ(c.renormalised_vertices, 2u);
    // Normalized u16 weights and u16 joints.
    EXPECT_EQ(c.joints[4 * 4 + 0], 1);
    EXPECT_FLOAT_EQ(c.weights[4 * 4 + 0], 1.0f);
    EXPECT_NEAR(c.weights[5 * 4 + 0], 32768.0 / 65535.0, 1e-6);
    EXPECT_NEAR(c.weights[5 * 4 + 1], 32767.0 / 65535.0, 1e-6);
    // Triangles: primitive 0 non-indexed (4 vertices -> 1 triangle), primitive 1 likewise.
    EXPECT_EQ(c.triangles, (std::vector<uint32_t>{0, 1, 2, 4, 5, 6}));
    // Inverse bind matrices read through a (tight) stride.
    expect_near(glm::dvec3(c.inverse_bind[1][3]), {0, -1, 0});

    ASSERT_EQ(c.clips.size(), 3u);
    std::vector<glm::dmat4> g(c.nodes.size());
    const int bone = c.joint_node[1], root = c.joint_node[0];
    // The root (translation 2 along x) had a matrix although animated: decomposed into TRS.
    EXPECT_FALSE(c.nodes[size_t(root)].has_matrix);
    expect_near(c.nodes[size_t(root)].translation, {2, 0, 0});
    bool noted = false;
    for (const auto& n : c.notes) noted = noted || n.find("decomposed") != std::string::npos;
    EXPECT_TRUE(noted);
    // CUBICSPLINE translation at mid-interval: Hermite with tangents scaled by the key delta (2 s).
    sample_node_globals(c, select_clips(c, "cubic"), 1.0, g);
    expect_near(glm::dvec3(g[size_t(bone)][3]), {2.25, 1.5, -0.75}, 1e-6);
    sample_node_globals(c, select_clips(c, "cubic"), 2.0, g);
    expect_near(glm::dvec3(g[size_t(bone)][3]), {2, 2, 0}, 1e-6);
    // STEP rotation from normalized int16 quaternions: holds 90 degrees over [1, 2).
    sample_node_globals(c, select_clips(c, "steps"), 1.7, g);
    expect_near(glm::dvec3(g[size_t(bone)] * glm::dvec4(1, 0, 0, 0)), {0, 1, 0}, 1e-4);
    // LINEAR scale.
    sample_node_globals(c, select_clips(c, "grow"), 0.5, g);
    EXPECT_NEAR(g[size_t(root)][0][0], 1.5, 1e-6);
    expect_near(glm::dvec3(g[size_t(root)][3]), {2, 0, 0});
}

TEST(ImportFixtures, EightInfluences) {
    const Character c = import_character(data("eight_influences.gltf"));
    expect_consistent(c);
    ASSERT_EQ(c.influences, 8);
    ASSERT_EQ(c.vertex_count(), 6u);
    for (int i = 0; i < 8; ++i) {
        EXPECT_EQ(c.joints[size_t(i)], i);
        EXPECT_FLOAT_EQ(c.weights[size_t(i)], 0.125f);
    }
    EXPECT_FLOAT_EQ(c.weights[1 * 8 + 0], 0.5f);
    EXPECT_FLOAT_EQ(c.weights[1 * 8 + 7], 0.5f);
    // Primitive without a second set: slots 4..7 empty.
    EXPECT_EQ(c.joints[3 * 8 + 0], 7);
    EXPECT_FLOAT_EQ(c.weights[3 * 8 + 0], 1.0f);
    for (int i = 1; i < 8; ++i) EXPECT_FLOAT_EQ(c.weights[3 * 8 + size_t(i)], 0.0f);
    EXPECT_EQ(c.joint_parent, (std::vector<int>{-1, 0, 1, 2, 3, 4, 5, 6}));
}

TEST(ImportFixtures, SkinsOfOneSkeletonMergeAndRigidMeshes) {
    const auto all = import_gltf(data("multi_skin.gltf"));
    ASSERT_EQ(all.size(), 2u);
    const Character& c = all[0];
    expect_consistent(c);
    // Joints: skin 0 (hip, left), skin 1 (right: shares hip as top-most joint), skin 2 (same joints,
    // same matrices: nothing new), skin 4 (hip again but another inverse bind matrix: a new joint).
    std::vector<int> gltf_nodes;
    for (int n : c.joint_node) gltf_nodes.push_back(c.nodes[size_t(n)].gltf_index);
    EXPECT_EQ(gltf_nodes, (std::vector<int>{1, 2, 3, 1}));
    EXPECT_EQ(c.joint_parent, (std::vector<int>{-1, 0, 0, -1}));
    ASSERT_EQ(c.nodes.size(), 9u);
    EXPECT_EQ(c.nodes[0].name, "armature");
    EXPECT_EQ(c.nodes[0].parent, -1);
    // Mesh nodes by node index: prop (rigid), body, arm, tail, cape.
    std::vector<int> prim_nodes;
    for (const auto& r : c.primitives) prim_nodes.push_back(r.node);
    EXPECT_EQ(prim_nodes, (std::vector<int>{4, 5, 6, 9, 10}));
    EXPECT_TRUE(c.primitives[0].rigid);
    EXPECT_EQ(c.primitives[0].skin, -1);
    EXPECT_EQ(c.primitives[2].skin, 1);
    EXPECT_EQ(c.vertex_count(), 15u);
    EXPECT_EQ(c.joints[0], 2);  // rigid prop: weight 1 on "right"
    EXPECT_FLOAT_EQ(c.weights[0], 1.0f);
    EXPECT_EQ(c.joints[6 * 4], 2);   // arm: skin 1 joint 0 = "right"
    EXPECT_EQ(c.joints[12 * 4], 3);  // cape: skin 4 joint 0 = hip with its own matrix
    EXPECT_EQ(c.joints[9 * 4], 1);   // tail: skin 2 joint 0 = "left"

    // The rigid prop sits where its node puts it, at rest and while "right" rotates.
    const glm::dmat4 right_rest = glm::translate(glm::dmat4(1.0), glm::dvec3(0.5, 1, 0));
    const glm::dmat4 prop_local = glm::translate(glm::dmat4(1.0), glm::dvec3(0, 0, 1)) *
                                  glm::rotate(glm::dmat4(1.0), glm::radians(90.0), glm::dvec3(0, 0, 1));
    const ClipSelection wave = select_clips(c, "wave");
    const glm::dmat4 right_at_1 = right_rest * glm::rotate(glm::dmat4(1.0), glm::radians(90.0), glm::dvec3(0, 0, 1));
    const auto rest = skinned(c, ClipSelection{}, 0.0);
    const auto moved = skinned(c, wave, 1.0);
    const glm::dvec3 prop[3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    for (int v = 0; v < 3; ++v) {
        expect_near(rest[size_t(v)], glm::dvec3(right_rest * prop_local * glm::dvec4(prop[v], 1)));
        expect_near(moved[size_t(v)], glm::dvec3(right_at_1 * prop_local * glm::dvec4(prop[v], 1)));
    }
    // Rigid normals follow the node's rotation: +x turned 90 degrees about z.
    expect_near(c.normals[0], {0, 1, 0});
    // Cape: hip global (1,1,0) times its own inverse bind T(-1,-2,0) moves it down by 1.
    expect_near(rest[12], {0, -1, 0});
    ASSERT_EQ(c.clips.size(), 1u);
    EXPECT_EQ(c.clips[0].channels.size(), 1u);  // the channel of the other skeleton is dropped

    const Character& other = all[1];
    expect_consistent(other);
    EXPECT_EQ(other.joint_count(), 1u);
    EXPECT_EQ(other.vertex_count(), 3u);
    EXPECT_EQ(other.nodes[size_t(other.joint_node[0])].name, "other_root");
    ASSERT_EQ(other.clips.size(), 1u);
    EXPECT_EQ(other.clips[0].channels.size(), 1u);
}

TEST(ImportFixtures, GlbAndExternalBufferMatch) {
    const Character a = import_character(data("basic.glb"));
    const Character b = import_character(data("external_buffer.gltf"));
    expect_consistent(a);
    ASSERT_EQ(a.vertex_count(), 4u);
    ASSERT_EQ(b.vertex_count(), 4u);
    for (size_t v = 0; v < 4; ++v) EXPECT_EQ(a.positions[v], b.positions[v]);
    EXPECT_EQ(a.triangles, (std::vector<uint32_t>{0, 1, 2, 2, 1, 3}));
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(a.weights, b.weights);
    ASSERT_EQ(a.clips.size(), 1u);
    EXPECT_EQ(a.clips[0].name, "bend");
}

// ---------------------------------------------------------------------------
// Broken files: a clear message naming the file and the defect.

struct BrokenCase {
    const char* file;
    const char* phrase;
};

void PrintTo(const BrokenCase& k, std::ostream* os) { *os << k.file; }

class ImportBroken : public ::testing::TestWithParam<BrokenCase> {};

TEST_P(ImportBroken, NamesFileAndDefect) {
    const BrokenCase k = GetParam();
    const std::string what = import_error(data(std::string("broken/") + k.file));
    ASSERT_FALSE(what.empty()) << k.file << " was accepted";
    EXPECT_NE(what.find(k.file), std::string::npos) << what;
    EXPECT_NE(what.find(k.phrase), std::string::npos) << what;
}

INSTANTIATE_TEST_SUITE_P(
    Files, ImportBroken,
    ::testing::Values(BrokenCase{"not_gltf.gltf", "not a glTF file"}, BrokenCase{"no_skin.gltf", "no skin"},
                      BrokenCase{"accessor_out_of_range.gltf", "accessor 0 out of range of buffer view 0"},
                      BrokenCase{"view_out_of_range.gltf", "buffer view 0 out of range of buffer 0"},
                      BrokenCase{"joint_out_of_range.gltf", "joint index 5 out of range"},
                      BrokenCase{"nan_position.gltf", "POSITION has a NaN or infinite value"},
                      BrokenCase{"nan_keyframe.gltf", "output has a NaN or infinite value"},
                      BrokenCase{"cyclic_nodes.gltf", "cyclic node hierarchy"},
                      BrokenCase{"shared_child.gltf", "node 2 is a child of both node 0 and node 1"},
                      BrokenCase{"missing_buffer.gltf", "missing buffer"},
                      BrokenCase{"truncated.glb", "truncated GLB"},
                      BrokenCase{"zero_weights.gltf", "vertex 1: weights sum to 0"},
                      BrokenCase{"negative_weight.gltf", "negative weight"},
                      BrokenCase{"bad_key_times.gltf", "not strictly increasing"},
                      BrokenCase{"ibm_count.gltf", "1 matrices for 2 joints"}),
    [](const ::testing::TestParamInfo<BrokenCase>& info) {
        std::string name = info.param.file;
        for (char& ch : name)
            if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
        return name;
    });

TEST(ImportBrokenFiles, MissingFile) {
    const std::string what = import_error(data("broken/does_not_exist.glb"));
    EXPECT_NE(what.find("does_not_exist.glb"), std::string::npos);
    EXPECT_NE(what.find("cannot open"), std::string::npos);
}

// What a bone record cannot carry is said, per joint, with the clip and the
// distance (common/representable.h); the shipped characters have none of it.
namespace {
size_t count_containing(const std::vector<std::string>& notes, const std::string& what) {
    size_t n = 0;
    for (const std::string& s : notes) n += s.find(what) != std::string::npos;
    return n;
}
}  // namespace

TEST(Representable, ShippedCharactersAreCarried) {
    for (const char* name : {"RiggedSimple.gltf", "CesiumMan.glb", "Fox.glb"}) {
        const Character c = import_character(asset(name));
        EXPECT_TRUE(representability_notes(c).empty()) << name << ": " << representability_notes(c).front();
    }
}

TEST(Representable, MirroredZeroAndNonUniformJointsAreNamed) {
    const Character base = import_character(asset("RiggedSimple.gltf"));
    const int child = base.joint_node[1];
    struct Case {
        glm::dvec3 scale;
        const char* kind;
    };
    for (const Case& k : {Case{{-1, 1, 1}, "is mirrored"}, Case{{0, 0, 0}, "is scaled to zero"},
                          Case{{1, 1.5, 1}, "non-uniform scale"}}) {
        Character c = base;
        c.nodes[size_t(child)].scale = k.scale;
        // The clip animates rotation only, so the scale holds in the rest pose and every frame.
        const std::vector<std::string> notes = representability_notes(c);
        ASSERT_FALSE(notes.empty()) << k.kind;
        EXPECT_NE(notes.front().find(k.kind), std::string::npos) << notes.front();
        EXPECT_NE(notes.front().find("\"" + base.nodes[size_t(child)].name + "\""), std::string::npos) << notes.front();
        EXPECT_NE(notes.front().find("% of the diagonal off"), std::string::npos) << notes.front();
    }
    // A uniform positive scale is carried exactly.
    Character c = base;
    c.nodes[size_t(child)].scale = {2, 2, 2};
    EXPECT_TRUE(representability_notes(c).empty());
}

TEST(Representable, StepClipsAreNoted) {
    const Character c = import_character(data("sparse_quantized.gltf"));
    EXPECT_EQ(count_containing(representability_notes(c), "clip \"steps\" has STEP channels"), 1u);
}

TEST(Representable, ALongClipIsSampledWithinItsBound) {
    // Key times are the file's: a clip of 10^7 s is checked at 20,000 frames
    // (a bound on the import's work), not 3 * 10^8.
    Character c = import_character(asset("RiggedSimple.gltf"));
    ASSERT_FALSE(c.clips.empty());
    c.clips[0].end = 1e7f;
    EXPECT_TRUE(representability_notes(c).empty());
}
