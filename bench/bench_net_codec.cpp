// bench_net_codec.cpp — encode and decode cost per bone record (bone_codec.h),
// and the frame encoder's cost per character per tick (sample + encode).
#include <benchmark/benchmark.h>

#include <random>

#include "bone_codec.h"
#include "frame_encoder.h"
#include "scene.h"

using namespace progskin;
using namespace progskin::net;

static std::vector<Mat34> random_bones(size_t n) {
    std::mt19937 rng(1);
    std::normal_distribution<float> g;
    std::vector<Mat34> out;
    for (size_t i = 0; i < n; ++i) {
        BonePose p;
        p.r = glm::normalize(glm::quat(g(rng), g(rng), g(rng), g(rng)));
        p.t = glm::vec3(g(rng), g(rng), g(rng));
        out.push_back(compose(p));
    }
    return out;
}

static void BM_EncodeBone(benchmark::State& st) {
    auto bones = random_bones(1024);
    RecordFormat fmt;
    fmt.t_min = glm::vec3(-5);
    fmt.t_max = glm::vec3(5);
    std::vector<uint8_t> out(bones.size() * 12);
    for (auto _ : st) {
        for (size_t i = 0; i < bones.size(); ++i) encode_bone(decompose(bones[i]), fmt, out.data() + i * 12);
        benchmark::DoNotOptimize(out.data());
    }
    st.SetItemsProcessed(int64_t(st.iterations() * bones.size()));
    st.SetLabel("decompose + quantise, per bone = time / 1024");
}
BENCHMARK(BM_EncodeBone);

static void BM_DecodeBone(benchmark::State& st) {
    auto bones = random_bones(1024);
    RecordFormat fmt;
    fmt.t_min = glm::vec3(-5);
    fmt.t_max = glm::vec3(5);
    std::vector<uint8_t> rec(bones.size() * 12);
    for (size_t i = 0; i < bones.size(); ++i) encode_bone(decompose(bones[i]), fmt, rec.data() + i * 12);
    std::vector<Mat34> out(bones.size());
    for (auto _ : st) {
        for (size_t i = 0; i < bones.size(); ++i) out[i] = compose(decode_bone(rec.data() + i * 12, fmt));
        benchmark::DoNotOptimize(out.data());
    }
    st.SetItemsProcessed(int64_t(st.iterations() * bones.size()));
    st.SetLabel("dequantise + compose, per bone = time / 1024");
}
BENCHMARK(BM_DecodeBone);

static std::vector<std::shared_ptr<ServerAsset>>& assets() {
    static std::vector<std::shared_ptr<ServerAsset>> a = {load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
                                                          load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    return a;
}

// Sample + encode every instance once (the server's per-tick work that does not depend on clients).
static void BM_EncodeTick(benchmark::State& st) {
    const int n = int(st.range(0));
    FrameEncoder enc(assets(), crowd_layout(assets(), n), 30.0f);
    uint32_t tick = 0;
    for (auto _ : st) benchmark::DoNotOptimize(enc.encode(++tick).bytes.data());
    st.SetItemsProcessed(int64_t(st.iterations() * n));
    st.SetLabel("sample + encode, per character = time / n");
}
BENCHMARK(BM_EncodeTick)->Arg(4)->Arg(100)->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
