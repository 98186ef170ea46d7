// Core benchmarks: skinning throughput against a plain scalar loop and a
// STREAM-style triad (memory bandwidth) on the same machine and run, palette
// build time, and progressive-skin build time per asset.
//
//   build/bench/bench_core --benchmark_filter=Skin|Triad|Palette   (CPU skinning in full: bench_skinning)
//   build/bench/bench_core --benchmark_filter=Build
#include <benchmark/benchmark.h>

#include <random>

#include "animation.h"
#include "gltf_import.h"
#include "palette.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "skinning.h"
#include "../tests/synthetic.h"

using namespace progskin;

namespace {

constexpr int kVerts = 100000, kBones = 64;

struct SkinData {
    std::vector<glm::vec3> pos, nrm, out_p, out_n;
    std::vector<uint16_t> joints;
    std::vector<float> weights;
    std::vector<Mat34> palette;
    SkinData() {
        std::mt19937 rng(7);
        std::uniform_real_distribution<float> u(-1, 1);
        std::uniform_int_distribution<int> jb(0, kBones - 1);
        for (int v = 0; v < kVerts; ++v) {
            pos.push_back({u(rng), u(rng), u(rng)});
            nrm.push_back(glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + glm::vec3(0, 0, 2)));
            // Neighbouring vertices share bones, as in a real mesh.
            const int base = (v / 512) % kBones;
            float w[4] = {0.5f + 0.5f * std::abs(u(rng)), 0, 0, 0}, rest = 1 - w[0];
            w[1] = rest * 0.6f, w[2] = rest * 0.3f, w[3] = rest * 0.1f;
            for (int i = 0; i < 4; ++i) {
                joints.push_back(uint16_t((base + i) % kBones));
                weights.push_back(w[i]);
            }
        }
        for (int b = 0; b < kBones; ++b) {
            const glm::dquat q = glm::angleAxis(0.1 * b, glm::normalize(glm::dvec3(1, 2, 3)));
            glm::dmat4 m = glm::mat4_cast(q);
            m[3] = glm::dvec4(0.01 * b, 0.02, -0.01 * b, 1);
            palette.push_back(Mat34::from_glm(m));
        }
        out_p.resize(kVerts);
        out_n.resize(kVerts);
    }
};
SkinData& data() {
    static SkinData d;
    return d;
}

void BM_SkinScalar(benchmark::State& st) {
    auto& d = data();
    const int m = int(st.range(0));
    SkinningJob job{d.pos, d.nrm, d.joints, d.weights, 4, m, d.palette, d.out_p, d.out_n};
    for (auto _ : st) {
        job.run();
        benchmark::DoNotOptimize(d.out_p.data());
    }
    st.counters["verts/s"] = benchmark::Counter(double(kVerts) * st.iterations(), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_SkinScalar)->Arg(1)->Arg(2)->Arg(4)->Unit(benchmark::kMicrosecond);

// skin_stream (the SIMD kernel; bench_skinning has the full comparison), U16 weights.
void BM_SkinStream(benchmark::State& st) {
    auto& d = data();
    const int m = int(st.range(0));
    SkinStream s;
    build_skin_stream(s, SkinningJob{d.pos, d.nrm, d.joints, d.weights, 4, m, d.palette, d.out_p, d.out_n});
    for (auto _ : st) {
        skin_stream(s, d.palette, d.out_p, d.out_n);
        benchmark::DoNotOptimize(d.out_p.data());
    }
    st.counters["verts/s"] = benchmark::Counter(double(kVerts) * st.iterations(), benchmark::Counter::kIsRate);
    // Bytes touched: stream input + output positions and normals.
    const double bytes = double(s.bytes()) + double(kVerts) * 24;
    st.counters["bytes/s"] = benchmark::Counter(bytes * st.iterations(), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_SkinStream)->Arg(1)->Arg(2)->Arg(4)->Unit(benchmark::kMicrosecond);

// STREAM triad a = b + s * c over arrays far larger than the caches.
void BM_StreamTriad(benchmark::State& st) {
    const size_t n = 8u << 20;
    std::vector<float> a(n), b(n, 1.0f), c(n, 2.0f);
    for (auto _ : st) {
        const float s = 3.0f;
        for (size_t i = 0; i < n; ++i) a[i] = b[i] + s * c[i];
        benchmark::DoNotOptimize(a.data());
        benchmark::ClobberMemory();
    }
    st.counters["bytes/s"] = benchmark::Counter(double(n) * 12 * st.iterations(), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_StreamTriad)->Unit(benchmark::kMillisecond);

void BM_PaletteBuild(benchmark::State& st) {
    const int B = int(st.range(0)), k = int(st.range(1));
    const size_t nb = size_t(B), nk = size_t(k);
    std::vector<int16_t> parents(nb);
    std::vector<Mat34> corr(nb, Mat34::identity()), own(nk, Mat34::identity()), out(nb);
    parents[0] = -1;
    for (int b = 1; b < B; ++b) parents[b] = int16_t((b - 1) / 2);
    std::vector<float> presence(nk, 1.0f);
    presence[k - 1] = 0.5f;
    PaletteJob job{parents, corr, own, presence, out};
    if (!job.validate()) st.SkipWithError("invalid job");
    for (auto _ : st) {
        job.run();
        benchmark::DoNotOptimize(out.data());
    }
}
BENCHMARK(BM_PaletteBuild)->Args({64, 64})->Args({64, 16})->Args({64, 1})->Unit(benchmark::kNanosecond);

void run_build(benchmark::State& st, const Character& c, const FrameSet& f, Strategy s) {
    BuildOptions o;
    o.strategy = s;
    for (auto _ : st) benchmark::DoNotOptimize(build_progressive_skin(c, f, o).error.data());
    st.counters["bones"] = double(c.joint_count());
    st.counters["verts"] = double(c.vertex_count());
    st.counters["frames"] = double(f.frame_count());
}

void BM_BuildAsset(benchmark::State& st, const char* file, Strategy s) {
    const Character c = import_character(std::string(PROGSKIN_ASSETS) + "/" + file);
    const FrameSet f = sample_frames(c, default_training_set(c), 30.0);
    run_build(st, c, f, s);
}
BENCHMARK_CAPTURE(BM_BuildAsset, Fox_reorder, "Fox.glb", Strategy::Reorder)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_BuildAsset, Fox_flatten, "Fox.glb", Strategy::Flatten)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_BuildAsset, CesiumMan_reorder, "CesiumMan.glb", Strategy::Reorder)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_BuildAsset, CesiumMan_flatten, "CesiumMan.glb", Strategy::Flatten)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_BuildAsset, RiggedSimple_reorder, "RiggedSimple.gltf", Strategy::Reorder)->Unit(benchmark::kMillisecond);

// The size target: 70 bones, ~30k vertices, 1,000 frames.
void BM_BuildLarge(benchmark::State& st) {
    // 23 limbs of 3 bones + root = 70 bones; 70 bones * rings * 8 ~ 30k vertices.
    const Character c = synth::make_tree(23, 3, 54, 1000, 0.5f);
    const FrameSet f = sample_frames(c, {select_clips(c, "all")}, 30.0);
    run_build(st, c, f, Strategy(st.range(0)));
}
BENCHMARK(BM_BuildLarge)->Arg(int(Strategy::Reorder))->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
