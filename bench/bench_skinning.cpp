// CPU skinning throughput (skin_stream, skinning.h) beside the plain
// loop (skin_plain_loop.cpp, -O2, no -march) and a STREAM triad over arrays of
// the same byte footprint as the kernel's inputs + outputs, all in one run on
// one core; and a client frame of 100 Fox + 100 CesiumMan instances (palettes
// + skinning). docs/performance.md "CPU skinning" has the table and command:
//
//   build/bench/bench_skinning --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
//       --benchmark_out_format=json --benchmark_out=skin.json   (one line)
//   python3 bench/skin_table.py skin.json
#include <benchmark/benchmark.h>
#include <hwy/targets.h>

#include <map>
#include <random>
#include <tuple>

#include "animation.h"
#include "gltf_import.h"
#include "palette.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "skin_plain_loop.h"
#include "skinning.h"

using namespace progskin;

namespace {

constexpr int kBones = 64;

// Random rigid palette of kBones joints (the setup).
std::vector<Mat34> random_palette(std::mt19937& rng) {
    std::normal_distribution<double> g;
    std::uniform_real_distribution<double> u(-1, 1);
    std::vector<Mat34> pal;
    for (int b = 0; b < kBones; ++b) {
        const glm::dquat q = glm::normalize(glm::dquat(g(rng), g(rng), g(rng), g(rng)));
        glm::dmat4 m = glm::mat4_cast(q);
        m[3] = glm::dvec4(u(rng), u(rng), u(rng), 1);
        pal.push_back(Mat34::from_glm(m));
    }
    return pal;
}

struct Data {
    int n = 0, influences = 0;
    std::vector<glm::vec3> pos, nrm, out_p, out_n;
    std::vector<uint16_t> joints;
    std::vector<float> weights;  // normalised
    std::vector<Mat34> palette;
    std::map<SkinWeightFormat, SkinStream> streams;
    Data(int influences_, int n_) : n(n_), influences(influences_) {
        std::mt19937 rng(1234 + influences * 7 + n);
        std::uniform_real_distribution<float> u(-1, 1), u01(0.05f, 1);
        std::uniform_int_distribution<int> jb(0, kBones - 1);
        for (int v = 0; v < n; ++v) {
            pos.push_back({u(rng), u(rng), u(rng)});
            nrm.push_back(glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + glm::vec3(0, 0, 2)));
            float w[8], sum = 0;
            for (int i = 0; i < influences; ++i) sum += w[i] = u01(rng);
            for (int i = 0; i < influences; ++i) {
                joints.push_back(uint16_t(jb(rng)));
                weights.push_back(w[i] / sum);
            }
        }
        palette = random_palette(rng);
        out_p.resize(size_t(n));
        out_n.resize(size_t(n));
        for (SkinWeightFormat f : {SkinWeightFormat::F32, SkinWeightFormat::U16, SkinWeightFormat::U8}) {
            SkinningJob src{pos, nrm, joints, weights, influences, influences, palette, out_p, out_n};
            if (!build_skin_stream(streams[f], src, f)) std::abort();
        }
    }
};

Data& data(int influences, int n) {
    static std::map<std::pair<int, int>, Data> cache;
    auto it = cache.find({influences, n});
    if (it == cache.end()) it = cache.try_emplace({influences, n}, influences, n).first;
    return it->second;
}

// Bytes the kernel reads and writes per vertex (its footprint for the triad).
double footprint_per_vertex(int influences, bool normals, SkinWeightFormat f) {
    const double wbytes = f == SkinWeightFormat::F32 ? 4 : f == SkinWeightFormat::U16 ? 2 : 1;
    return 12.0 * (normals ? 4 : 2) + influences * 1.0 + (influences - 1) * wbytes;  // u8 joints (64 bones)
}

void set_counters(benchmark::State& st, double n, double bytes_per_vertex) {
    st.counters["Mvert/s"] = benchmark::Counter(n * st.iterations() * 1e-6, benchmark::Counter::kIsRate);
    st.counters["GB/s"] =
        benchmark::Counter(n * bytes_per_vertex * st.iterations() * 1e-9, benchmark::Counter::kIsRate);
}

// Args: influences, normals (0/1), vertices.
void BM_PlainLoop(benchmark::State& st) {
    const int I = int(st.range(0));
    const bool N = st.range(1) != 0;
    Data& d = data(I, int(st.range(2)));
    for (auto _ : st) {
        bench::skin_plain_loop(&d.pos[0].x, N ? &d.nrm[0].x : nullptr, d.joints.data(), d.weights.data(), I,
                               d.palette.data(), &d.out_p[0].x, N ? &d.out_n[0].x : nullptr, size_t(d.n));
        benchmark::DoNotOptimize(d.out_p.data());
        benchmark::ClobberMemory();
    }
    // Plain layout: vec3 in, u16 joints + f32 weights, vec3 out.
    set_counters(st, d.n, 12.0 * (N ? 4 : 2) + I * 6.0);
}

// Args: influences, normals, vertices, weight format (0 F32, 1 U16, 2 U8), renormalise.
void BM_Kernel(benchmark::State& st) {
    const int I = int(st.range(0));
    const bool N = st.range(1) != 0;
    const auto f = SkinWeightFormat(st.range(3));
    Data& d = data(I, int(st.range(2)));
    const SkinStream& s = d.streams.at(f);
    SkinRunOptions o;
    o.renormalize = st.range(4) != 0;
    std::span<glm::vec3> on = N ? std::span<glm::vec3>(d.out_n) : std::span<glm::vec3>();
    for (auto _ : st) {
        if (!skin_stream(s, d.palette, d.out_p, on, o)) st.SkipWithError("skin_stream refused");
        benchmark::DoNotOptimize(d.out_p.data());
        benchmark::ClobberMemory();
    }
    set_counters(st, d.n, footprint_per_vertex(I, N, f));
    st.SetLabel(skin_simd_target());
}

// STREAM triad a[i] = b[i] + s * c[i] over three float arrays whose total size
// is the U16 kernel's footprint for the same args (influences, normals, vertices).
__attribute__((target("avx2,fma"))) void triad(float* __restrict a, const float* __restrict b,
                                               const float* __restrict c, size_t n, float s) {
    for (size_t i = 0; i < n; ++i) a[i] = b[i] + s * c[i];
}
void BM_Triad(benchmark::State& st) {
    const double bytes = footprint_per_vertex(int(st.range(0)), st.range(1) != 0, SkinWeightFormat::U16) * st.range(2);
    const size_t n = size_t(bytes / 12.0);
    std::vector<float> a(n), b(n, 1.0f), c(n, 2.0f);
    const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    for (auto _ : st) {
        if (avx2) triad(a.data(), b.data(), c.data(), n, 3.0f);
        else
            for (size_t i = 0; i < n; ++i) a[i] = b[i] + 3.0f * c[i];
        benchmark::DoNotOptimize(a.data());
        benchmark::ClobberMemory();
    }
    st.counters["GB/s"] = benchmark::Counter(double(n) * 12 * st.iterations() * 1e-9, benchmark::Counter::kIsRate);
}

void rows(benchmark::internal::Benchmark* b, bool kernel) {
    for (int n : {10000, 100000})
        for (int I : {1, 2, 4, 8})
            for (int N : {0, 1}) {
                if (kernel) b->Args({I, N, n, 1, 0});
                else b->Args({I, N, n});
            }
}
BENCHMARK(BM_PlainLoop)->Apply([](auto* b) { rows(b, false); })->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Kernel)->Apply([](auto* b) { rows(b, true); })->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Triad)->Apply([](auto* b) { rows(b, false); })->Unit(benchmark::kMicrosecond);
// Other weight formats and renormalised normals, 100k vertices.
BENCHMARK(BM_Kernel)->Apply([](auto* b) {
    for (int I : {1, 2, 4, 8}) {
        b->Args({I, 1, 100000, 1, 1});  // U16, renormalised normals
        if (I > 1) b->Args({I, 1, 100000, 0, 0}), b->Args({I, 1, 100000, 2, 0});  // F32, U8
    }
})->Unit(benchmark::kMicrosecond);

// The kernel forced onto each SIMD target this CPU supports (arg: index in
// hwy::SupportedAndGeneratedTargets()), 100k vertices, 4 influences, U16.
void BM_KernelPerTarget(benchmark::State& st) {
    const std::vector<int64_t> targets = hwy::SupportedAndGeneratedTargets();
    const size_t t = size_t(st.range(0));
    if (t >= targets.size()) {
        st.SkipWithError("no such target here");
        for (auto _ : st) {
        }
        return;
    }
    const bool N = st.range(1) != 0;
    Data& d = data(4, 100000);
    hwy::SetSupportedTargetsForTest(targets[t]);
    hwy::GetChosenTarget().Update(hwy::SupportedTargets());
    std::span<glm::vec3> on = N ? std::span<glm::vec3>(d.out_n) : std::span<glm::vec3>();
    for (auto _ : st) {
        if (!skin_stream(d.streams.at(SkinWeightFormat::U16), d.palette, d.out_p, on)) st.SkipWithError("refused");
        benchmark::ClobberMemory();
    }
    st.SetLabel(skin_simd_target());
    hwy::SetSupportedTargetsForTest(0);
    hwy::GetChosenTarget().Update(hwy::SupportedTargets());
    set_counters(st, d.n, footprint_per_vertex(4, N, SkinWeightFormat::U16));
}
BENCHMARK(BM_KernelPerTarget)->ArgsProduct({{0, 1, 2, 3, 4}, {0, 1}})->Unit(benchmark::kMicrosecond);

// ---- a client frame: 100 Fox + 100 CesiumMan instances ----------------------

struct Asset {
    Character c;
    FrameSet frames;
    ProgressiveSkin skin;
    SkinStream stream;
};
struct Crowd {
    std::vector<Asset> assets;
    struct Instance {
        int asset, frame, k, max_influences;
        std::vector<Mat34> own, palette;
        std::vector<glm::vec3> out_p, out_n;
    };
    std::vector<Instance> inst;
    std::vector<SkinTask> tasks;
    std::vector<SkinningJob> jobs;  // the scalar reference, for comparison
    Crowd() {
        for (const char* file : {"Fox.glb", "CesiumMan.glb"}) {
            Asset a;
            a.c = import_character(std::string(PROGSKIN_ASSETS) + "/" + file);
            a.frames = sample_frames(a.c, default_training_set(a.c), 30.0);
            BuildOptions o;
            o.strategy = Strategy::LeafPrune;
            a.skin = build_progressive_skin(a.c, a.frames, o);
            std::vector<glm::vec3> tmp(a.c.vertex_count());
            SkinningJob src = skinning_job(a.c, a.skin, {}, tmp);
            src.normals = a.c.normals;
            if (!build_skin_stream(a.stream, src, SkinWeightFormat::U16)) std::abort();
            assets.push_back(std::move(a));
        }
        for (int i = 0; i < 200; ++i) {
            Instance x;
            x.asset = i % 2;
            const Asset& a = assets[size_t(x.asset)];
            const int B = a.skin.bone_count();
            x.frame = int((i * 7) % a.frames.frame_count());
            x.k = i % 4 == 3 ? std::max(1, B / 2) : B;        // a quarter at half the bones
            x.max_influences = 4 - (i / 2) % 3;             // influence limits 4, 3, 2
            x.own.resize(size_t(x.k));
            x.palette.resize(size_t(B));
            x.out_p.resize(a.c.vertex_count());
            x.out_n.resize(a.c.normals.empty() ? 0 : a.c.vertex_count());
            inst.push_back(std::move(x));
        }
        for (Instance& x : inst) {
            const Asset& a = assets[size_t(x.asset)];
            SkinRunOptions o;
            o.max_influences = x.max_influences;
            tasks.push_back({&a.stream, x.palette, x.out_p, x.out_n, o});
            SkinningJob j = skinning_job(a.c, a.skin, x.palette, x.out_p);
            j.normals = a.c.normals;
            j.out_normals = x.out_n;
            j.max_influences = x.max_influences;
            jobs.push_back(j);
        }
    }
    size_t vertices() const {
        size_t n = 0;
        for (const Instance& x : inst) n += x.out_p.size();
        return n;
    }
    void palettes() {
        for (Instance& x : inst) {
            const Asset& a = assets[size_t(x.asset)];
            const Mat34* f = a.frames.frame(size_t(x.frame));
            for (int b = 0; b < x.k; ++b) x.own[size_t(b)] = f[a.skin.order[size_t(b)]];
            PaletteJob{a.skin.parents, a.skin.corrections, x.own, {}, x.palette}.run();
            x.frame = int((size_t(x.frame) + 1) % a.frames.frame_count());
        }
    }
};

// Arg: 0 = skin_many, 1 = SkinningJob::run per instance (scalar reference), 2 = palettes only.
void BM_ClientFrame(benchmark::State& st) {
    static Crowd crowd;
    for (auto _ : st) {
        crowd.palettes();
        if (st.range(0) == 0) {
            if (!skin_many(crowd.tasks)) st.SkipWithError("skin_many refused");
        } else if (st.range(0) == 1) {
            for (const SkinningJob& j : crowd.jobs) j.run();
        }
        benchmark::ClobberMemory();
    }
    st.counters["Mvert/s"] =
        benchmark::Counter(double(crowd.vertices()) * st.iterations() * 1e-6, benchmark::Counter::kIsRate);
    st.counters["verts"] = double(crowd.vertices());
    st.SetLabel(st.range(0) == 0 ? "skin_many" : st.range(0) == 1 ? "SkinningJob::run" : "palettes only");
}
BENCHMARK(BM_ClientFrame)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
