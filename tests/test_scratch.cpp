// test_scratch.cpp — build from scratch (scratch_build.h) and the vertex
// animation loaders (vertex_animation.h).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <cstring>
#include <unistd.h>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>

#include "errors.h"
#include "gltf_export.h"
#include "progressive_skin.h"
#include "scratch_build.h"
#include "vertex_animation.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::thresholds;

namespace {

std::string tmp_path(const std::string& name) {
    return (std::filesystem::temp_directory_path() / ("progskin_test_scratch_" + std::to_string(::getpid()) + "_" + name))
        .string();
}

// Vertex animation made by a known rigid skin: `bones` blobs of vertices, each
// following its own rigid motion; blob 1's vertices nearest blob 0 blend the
// two (known weights). Frame 0 is the bind pose (every transform identity).
VertexAnimation synthetic(int bones, int per_blob = 60, int frames = 24) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-0.3, 0.3);
    VertexAnimation a;
    a.source = "synthetic";
    a.fps = 30;
    std::vector<glm::dvec3> bind;
    std::vector<std::pair<int, double>> w;  // second bone 0 with weight 1 - w (blend) when w < 1
    for (int b = 0; b < bones; ++b)
        for (int i = 0; i < per_blob; ++i) {
            const glm::dvec3 p(2.0 * b + u(rng), u(rng), u(rng));
            bind.push_back(p);
            const double wt = (b == 1 && p.x < 1.9) ? 0.35 + (p.x - 1.7) : 1.0;
            w.push_back({b, wt});
        }
    a.vertex_count = bind.size();
    a.frame_count = size_t(frames);
    for (int f = 0; f < frames; ++f) {
        std::vector<glm::dmat4> M(static_cast<size_t>(bones), glm::dmat4(1.0));
        for (int b = 0; b < bones; ++b) {
            const double t = f / 30.0;
            const glm::dvec3 axis = glm::normalize(glm::dvec3(0.3 + b, 1.0, 0.5 * b - 0.2));
            M[size_t(b)] = glm::translate(glm::dmat4(1.0), glm::dvec3(0.1 * b * std::sin(3 * t), 0.2 * t, 0.05 * b * t)) *
                           glm::rotate(glm::dmat4(1.0), (0.4 + 0.3 * b) * std::sin(2 * t + 0.3 * b * t), axis);
        }
        for (size_t v = 0; v < bind.size(); ++v) {
            const auto [b, wt] = w[v];
            glm::dvec3 p = wt * glm::dvec3(M[size_t(b)] * glm::dvec4(bind[v], 1.0));
            if (wt < 1.0) p += (1.0 - wt) * glm::dvec3(M[0] * glm::dvec4(bind[v], 1.0));
            a.positions.push_back(glm::vec3(p));
        }
    }
    a.diagonal = frame_diagonal(a, 0);
    return a;
}

void expect_non_increasing(const std::vector<LodError>& t) {
    ASSERT_FALSE(t.empty());
    for (size_t k = 1; k < t.size(); ++k) EXPECT_LE(t[k].rms, t[k - 1].rms) << "k = " << k + 1;
    for (size_t k = 0; k < t.size(); ++k) EXPECT_EQ(t[k].bones, int(k + 1));
}

// Full-detail playback of a loaded file equals the fit's own.
void expect_round_trip(const ScratchResult& r, const VertexAnimation& an, const std::string& name) {
    const std::string path = tmp_path(name);
    save_scratch(r, path);
    const ProgressiveAsset a = load_progressive(path);
    std::filesystem::remove(path);
    ASSERT_TRUE(a.progressive);
    EXPECT_EQ(a.skin.strategy, Strategy::Scratch);
    ASSERT_EQ(a.skin.bone_count(), r.skin.bone_count());
    ASSERT_EQ(a.character.vertex_count(), an.vertex_count);
    ASSERT_EQ(a.skin.error.size(), r.skin.error.size());
    EXPECT_NEAR(a.skin.error.back().distortion_pct, r.skin.error.back().distortion_pct, 1e-6);
    const FrameSet fr = sample_frames(a.character, {select_clips(a.character, "all")}, an.fps);
    ASSERT_EQ(fr.frame_count(), an.frame_count);
    const int B = r.skin.bone_count();
    std::vector<glm::vec3> x(an.vertex_count), y(an.vertex_count);
    const double tol = 1e-5 * r.skin.diagonal;
    for (size_t f = 0; f < an.frame_count; f += std::max<size_t>(1, an.frame_count / 7)) {
        for (int k : {1, B}) {
            lod_positions(r.character, r.skin, r.frames, f, k, x);
            lod_positions(a.character, a.skin, fr, f, k, y);
            for (size_t v = 0; v < an.vertex_count; ++v) ASSERT_LT(glm::length(x[v] - y[v]), tol) << f << " " << v;
        }
    }
    // The stored table is what the loaded file plays.
    const auto t = scratch_error_table(a.character, a.skin, fr, an, a.skin.diagonal);
    for (size_t k = 0; k < t.size(); ++k) EXPECT_NEAR(t[k].rms, r.skin.error[k].rms, 1e-5 * r.skin.diagonal);
}

}  // namespace

TEST(Scratch, RecoversKnownRigidSkin) {
    for (int bones : {2, 3, 4}) {
        const VertexAnimation an = synthetic(bones);
        ScratchOptions o;
        o.max_bones = bones;
        // Frame 0 is the generating bind pose (the per-vertex mean is not a
        // rigid image of it).
        o.rest_frame = 0;
        o.method = ScratchMethod::Collapse;
        o.iterations = 200;  // the alternation converges linearly
        o.update_bind = false;  // the bind pose is known
        const ScratchResult r = build_from_vertices(an, o);
        ASSERT_EQ(r.skin.bone_count(), bones);
        expect_non_increasing(r.skin.error);
        EXPECT_LT(r.skin.error.back().rms / r.skin.diagonal, 1e-4) << bones << " bones";
        // Auto keeps the better of both methods.
        o.method = ScratchMethod::Auto;
        const ScratchResult a = build_from_vertices(an, o);
        EXPECT_LT(a.skin.error.back().rms / a.skin.diagonal, 1e-4) << bones << " bones (auto)";
    }
}

TEST(Scratch, HybridIsProgressive) {
    // Top-down with the decomposition's bones as proposals, then the
    // multi-level refit (weights included): the table stays non-increasing
    // and full detail beats one bone by far.
    const VertexAnimation an = synthetic(4);
    ScratchOptions o;
    o.max_bones = 6;
    o.method = ScratchMethod::Hybrid;
    const ScratchResult r = build_from_vertices(an, o);
    expect_non_increasing(r.skin.error);
    EXPECT_GE(r.skin.bone_count(), 4);
    EXPECT_LT(r.skin.error.back().rms, 0.1 * r.skin.error.front().rms);
}

TEST(Scratch, SkinMatchesSampledCharacter) {
    const VertexAnimation an = synthetic(3);
    ScratchOptions o;
    o.max_bones = 3;
    const ScratchResult r = build_from_vertices(an, o);
    // The stored clip reproduces per-frame matrices: sample_frames of the
    // character gives the frames the table was computed with.
    const FrameSet fr = sample_frames(r.character, {select_clips(r.character, "all")}, an.fps);
    ASSERT_EQ(fr.skinning.size(), r.frames.skinning.size());
    for (size_t i = 0; i < fr.skinning.size(); ++i)
        for (int j = 0; j < 12; ++j) EXPECT_FLOAT_EQ(fr.skinning[i].m[j], r.frames.skinning[i].m[j]);
    for (size_t k = 0; k < r.skin.parents.size(); ++k) EXPECT_LT(r.skin.parents[k], int(k));
    for (size_t v = 0; v < an.vertex_count; ++v) {
        float s = 0;
        for (int i = 0; i < 4; ++i) {
            EXPECT_GE(r.skin.weights[v * 4 + i], 0.0f);
            s += r.skin.weights[v * 4 + i];
        }
        EXPECT_NEAR(s, 1.0f, 1e-5f);
    }
    expect_round_trip(r, an, "synthetic.glb");
}

TEST(Scratch, StopsAtMaxError) {
    const VertexAnimation an = synthetic(4);
    ScratchOptions o;
    o.max_bones = 64;
    o.max_error_pct = 1.0;
    const ScratchResult r = build_from_vertices(an, o);
    EXPECT_LT(r.skin.bone_count(), 64);
    expect_non_increasing(r.skin.error);
}

TEST(Scratch, DegenerateInputs) {
    VertexAnimation base = synthetic(2, 20, 6);
    // One frame.
    {
        VertexAnimation a = base;
        a.frame_count = 1;
        a.positions.resize(a.vertex_count);
        const ScratchResult r = build_from_vertices(a, {});
        ASSERT_GE(r.skin.bone_count(), 1);
        EXPECT_LT(r.skin.error.back().rms_pct, kLosslessPct);
    }
    // Static mesh.
    {
        VertexAnimation a = base;
        for (size_t f = 1; f < a.frame_count; ++f)
            for (size_t v = 0; v < a.vertex_count; ++v) a.positions[f * a.vertex_count + v] = a.positions[v];
        const ScratchResult r = build_from_vertices(a, {});
        EXPECT_EQ(r.skin.bone_count(), 1);
        EXPECT_LT(r.skin.error.back().rms_pct, kLosslessPct);
        EXPECT_LT(r.skin.error.back().distortion_pct, 0);  // undefined: nothing moves
    }
    // Collinear and coincident vertices.
    for (int kind = 0; kind < 2; ++kind) {
        VertexAnimation a = base;
        for (size_t f = 0; f < a.frame_count; ++f)
            for (size_t v = 0; v < a.vertex_count; ++v)
                a.positions[f * a.vertex_count + v] =
                    kind == 0 ? glm::vec3(float(v) * 0.1f, 0.3f * float(f), 0.0f) : glm::vec3(1.0f, float(f), 2.0f);
        ScratchOptions o;
        o.max_bones = 4;
        const ScratchResult r = build_from_vertices(a, o);
        ASSERT_GE(r.skin.bone_count(), 1);
        expect_non_increasing(r.skin.error);
        EXPECT_LT(r.skin.error.back().rms_pct, kLosslessPct);
    }
    // Single vertex.
    {
        VertexAnimation a = base;
        a.vertex_count = 1;
        a.positions.clear();
        for (size_t f = 0; f < base.frame_count; ++f) a.positions.push_back(base.positions[f * base.vertex_count]);
        const ScratchResult r = build_from_vertices(a, {});
        EXPECT_GE(r.skin.bone_count(), 1);
    }
    // NaN, zero vertices, bad sizes, bad options: clear errors.
    {
        VertexAnimation a = base;
        a.positions[5].y = std::nanf("");
        EXPECT_THROW(build_from_vertices(a, {}), Error);
        a = base;
        a.vertex_count = 0;
        a.positions.clear();
        EXPECT_THROW(build_from_vertices(a, {}), Error);
        a = base;
        a.positions.pop_back();
        EXPECT_THROW(build_from_vertices(a, {}), Error);
        ScratchOptions o;
        o.rest_frame = 100;
        EXPECT_THROW(build_from_vertices(base, o), Error);
        o = {};
        o.max_bones = 0;
        EXPECT_THROW(build_from_vertices(base, o), Error);
    }
}

TEST(Scratch, Pc2RoundTripAndErrors) {
    const VertexAnimation an = synthetic(2, 10, 5);
    const std::string path = tmp_path("a.pc2");
    save_pc2(an, path);
    const VertexAnimation b = load_pc2(path);
    EXPECT_EQ(b.vertex_count, an.vertex_count);
    EXPECT_EQ(b.frame_count, an.frame_count);
    EXPECT_DOUBLE_EQ(b.fps, 30.0);
    ASSERT_EQ(b.positions.size(), an.positions.size());
    for (size_t i = 0; i < an.positions.size(); ++i) EXPECT_EQ(b.positions[i], an.positions[i]);
    const VertexAnimation c = load_vertex_animation(path);
    EXPECT_EQ(c.positions.size(), an.positions.size());

    std::string bytes;
    {
        std::ifstream in(path, std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    auto write = [&](const std::string& s) {
        std::ofstream o(path, std::ios::binary);
        o.write(s.data(), std::streamsize(s.size()));
    };
    auto expect_error = [&](const std::string& s, const std::string& what) {
        write(s);
        try {
            load_pc2(path);
            ADD_FAILURE() << "no error for " << what;
        } catch (const Error& e) {
            EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
        }
    };
    expect_error(bytes.substr(0, bytes.size() - 4), "truncated");
    expect_error(bytes + "xxxx", "trailing bytes");
    expect_error(bytes.substr(0, 20), "short header");
    std::string bad = bytes;
    bad[0] = 'X';
    expect_error(bad, "magic");
    bad = bytes;
    bad[12] = 2;
    expect_error(bad, "version");
    bad = bytes;
    const int32_t zero = 0;
    std::memcpy(&bad[16], &zero, 4);
    expect_error(bad, "zero points");
    bad = bytes;
    const int32_t huge = 0x7fffffff;
    std::memcpy(&bad[28], &huge, 4);
    expect_error(bad, "huge sample count");
    bad = bytes;
    const float nan = std::nanf("");
    std::memcpy(&bad[32], &nan, 4);
    expect_error(bad, "NaN");
    std::filesystem::remove(path);
    EXPECT_THROW(load_pc2(tmp_path("missing.pc2")), Error);
}

TEST(Scratch, AnimatedMorphSphere) {
    const VertexAnimation an = load_vertex_animation(std::string(PROGSKIN_ASSETS) + "/AnimatedMorphSphere.gltf", {10.0});
    EXPECT_EQ(an.vertex_count, 1876u);
    EXPECT_GT(an.frame_count, 50u);
    EXPECT_FALSE(an.normals.empty());
    EXPECT_EQ(an.triangles.size(), 2880u);
    // The animation moves the vertices.
    double moved = 0;
    for (size_t v = 0; v < an.vertex_count; ++v)
        moved = std::max(moved, double(glm::length(an.frame(an.frame_count / 2)[v] - an.frame(0)[v])));
    EXPECT_GT(moved, 0.01 * an.diagonal);
    ScratchOptions o;
    o.max_bones = 8;
    const ScratchResult r = build_from_vertices(an, o);
    expect_non_increasing(r.skin.error);
    EXPECT_LT(r.skin.error.back().rms_pct, 0.5 * r.skin.error.front().rms_pct);
    EXPECT_GT(r.skin.error.back().distortion_pct, 0);
    expect_round_trip(r, an, "sphere.gltf");
}

TEST(Scratch, SkinnedAssetsAsVertices) {
    struct Case {
        const char* file;
        const char* clip;
        int bones;
        int original;  // the artist skin's bone count, where issue 4 asks for < 0.1 % (0: not checked here)
    };
    for (const Case& c : {Case{"RiggedSimple.gltf", "auto", 4, 2}, Case{"CesiumMan.glb", "all", 10, 0},
                          Case{"Fox.glb", "Survey", 10, 0}}) {
        VertexAnimationOptions vo;
        vo.fps = 10;
        vo.clip = c.clip;
        const VertexAnimation an = load_vertex_animation(std::string(PROGSKIN_ASSETS) + "/" + c.file, vo);
        ScratchOptions o;
        o.max_bones = c.bones;
        const ScratchResult r = build_from_vertices(an, o);
        SCOPED_TRACE(c.file);
        expect_non_increasing(r.skin.error);
        EXPECT_LT(r.skin.error.back().rms_pct, r.skin.error.front().rms_pct);
        if (c.original > 0) {
            ASSERT_GE(r.skin.bone_count(), c.original);
            EXPECT_LT(r.skin.error[size_t(c.original - 1)].rms_pct, kScratchAtOriginalBonesRmsPct);
        }
        expect_round_trip(r, an, std::string(c.file) + ".glb");
    }
}

// join_coincident joins only vertices equal in every frame, remaps the
// triangles and drops the ones that collapse.
TEST(Scratch, JoinCoincident) {
    VertexAnimation a;
    a.source = "join";
    a.vertex_count = 6;
    a.frame_count = 2;
    a.diagonal = 5;
    // v3 copies v1 in both frames; v4 meets v2 in frame 0 only; v5 is v0 with -0.
    const glm::vec3 f0[6] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 0, 0}, {0, 1, 0}, {-0.0f, 0, -0.0f}};
    const glm::vec3 f1[6] = {{0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 0, 1}, {0, 2, 1}, {0, 0, 1}};
    a.positions.assign(f0, f0 + 6);
    a.positions.insert(a.positions.end(), f1, f1 + 6);
    for (int v = 0; v < 6; ++v) a.normals.push_back({0, 0, float(v)});
    a.triangles = {0, 1, 2, 1, 3, 2, 3, 4, 5};
    std::vector<uint32_t> rep;
    const VertexAnimation j = join_coincident(a, &rep);
    EXPECT_NO_THROW(j.validate());
    EXPECT_EQ(j.vertex_count, 4u);
    EXPECT_EQ(rep, (std::vector<uint32_t>{0, 1, 2, 1, 3, 0}));
    for (size_t f = 0; f < 2; ++f)
        for (size_t v = 0; v < 6; ++v) EXPECT_EQ(j.frame(f)[rep[v]], a.frame(f)[v]) << "frame " << f << " vertex " << v;
    EXPECT_EQ(j.normals[3], a.normals[4]);
    EXPECT_EQ(j.triangles, (std::vector<uint32_t>{0, 1, 2, 1, 3, 0}));  // (1,1,2) dropped
    EXPECT_EQ(j.diagonal, 5);
    VertexAnimation bad = a;
    bad.triangles.push_back(6), bad.triangles.push_back(0), bad.triangles.push_back(1);
    EXPECT_THROW(join_coincident(bad), Error);
    bad = a;
    bad.positions.pop_back();
    EXPECT_THROW(join_coincident(bad), Error);
    bad.frame_count = 0, bad.positions.clear();
    EXPECT_THROW(join_coincident(bad), Error);

    // A real mesh: the Fox's flat-shaded seams, every vertex at its
    // representative's position in every frame.
    VertexAnimationOptions vo;
    vo.fps = 10;
    vo.clip = "Survey";
    const VertexAnimation fox = load_vertex_animation(std::string(PROGSKIN_ASSETS) + "/Fox.glb", vo);
    const VertexAnimation fj = join_coincident(fox, &rep);
    EXPECT_LT(fj.vertex_count, fox.vertex_count / 2);
    ASSERT_EQ(rep.size(), fox.vertex_count);
    for (size_t f = 0; f < fox.frame_count; ++f)
        for (size_t v = 0; v < fox.vertex_count; ++v) ASSERT_EQ(fj.frame(f)[rep[v]], fox.frame(f)[v]);
    EXPECT_NEAR(frame_diagonal(fj, 0), frame_diagonal(fox, 0), 1e-9);
}

TEST(Scratch, MalformedGltf) {
    const std::string path = tmp_path("bad.gltf");
    {
        std::ofstream o(path);
        o << "{\"asset\":{\"version\":\"2.0\"},\"meshes\":[],\"nodes\":[]}";
    }
    EXPECT_THROW(load_vertex_animation(path), Error);
    {
        std::ofstream o(path);
        o << "not json";
    }
    EXPECT_THROW(load_vertex_animation(path), Error);
    std::filesystem::remove(path);
}
