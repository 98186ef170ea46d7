// bench_net_capi.cpp — the C API's overhead per call (capi/progskin.h,
// libprogskin_c.so) against the C++ Client it wraps (client/client.h), the
// same work on both sides:
//   UpdateIdle: update() of a client that is not connected (the boundary
//     alone: argument checks, exception guard, event reset);
//   UpdateStreaming: update() of a client streaming the default scene (4
//     characters) from an in-process server on loopback (socket I/O, acks,
//     palettes: the boundary is a small part of it);
//   Characters: reading every character (instance, root, palette pointer,
//     bones) once, per frame: C++ iterates characters(), C calls
//     psk_client_character_count and psk_client_character(i);
//   Publish: publishing one spawned character's pose (encode + one datagram).
//   bench_net_capi --benchmark_filter=. --benchmark_repetitions=5
#include <benchmark/benchmark.h>

#include <chrono>
#include <memory>
#include <thread>
#include <vector>

#include "animation.h"
#include "client.h"
#include "progskin.h"
#include "scene.h"
#include "server.h"

using namespace progskin;
using namespace progskin::net;

namespace {

// An in-process server (plain TCP, default scene) and one client of each
// API, each with a spawned character, streaming: built on first use.
struct World {
    std::unique_ptr<Server> server;
    std::thread thread;
    std::unique_ptr<Client> cpp;
    psk_client* c = nullptr;
    int cpp_handle = -1, c_handle = -1;
    std::vector<Mat34> skin;  // the asset's bind pose, joint order

    World() {
        std::vector<std::shared_ptr<ServerAsset>> assets = {
            load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
            load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
        ServerConfig scfg;
        scfg.bind_address = "127.0.0.1";
        scfg.port = 0;
        server = std::make_unique<Server>(scfg, assets, default_instances(assets));
        thread = std::thread([this] { server->run(); });
        const std::string cache = "/tmp/progskin-bench-capi-cache";
        ClientConfig cc;
        cc.cache_dir = cache;
        cc.stream_timeout = 600;
        cpp = std::make_unique<Client>(cc);
        cpp->connect("127.0.0.1", server->tcp_port());
        psk_client_config cfg;
        psk_client_config_init(&cfg);
        cfg.tls = 0;
        cfg.cache_dir = cache.c_str();
        cfg.stream_timeout = 600;
        c = psk_client_create(&cfg);
        psk_client_connect(c, "127.0.0.1", server->tcp_port());
        settle();
    }
    void update() {
        const double now = now_seconds();
        cpp->update(now);
        psk_client_update(c, now);
    }
    // Until both clients show the 4 characters and own a spawned one.
    void settle() {
        const double t0 = now_seconds();
        int c_instance = -1;
        while (now_seconds() - t0 < 10) {
            update();
            if (cpp_handle < 0 && !cpp->assets().empty() && cpp->assets()[0]) {
                cpp_handle = cpp->spawn({});
                skin.assign(cpp->assets()[0]->character.joint_count(), Mat34::identity());
            }
            psk_asset a;
            psk_spawn_spec s;
            psk_spawn_spec_init(&s);
            if (c_handle < 0 && psk_client_asset(c, 0, &a) == PSK_OK) psk_client_spawn(c, &s, &c_handle);
            psk_client_instance_of(c, c_handle, &c_instance);
            int n = 0;
            psk_client_character_count(c, &n);
            if (cpp->instance_of(cpp_handle) >= 0 && c_instance >= 0 && cpp->characters().size() >= 5 && n >= 5) return;
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        std::fprintf(stderr, "bench_net_capi: the clients did not settle\n");
        std::exit(1);
    }
    ~World() {
        psk_client_destroy(c);
        cpp.reset();
        server->stop();
        thread.join();
    }
};

World& world() {
    static World w;
    return w;
}

void BM_Cpp_UpdateIdle(benchmark::State& st) {
    Client client;
    double t = 1;
    for (auto _ : st) client.update(t += 1e-3);
}

void BM_C_UpdateIdle(benchmark::State& st) {
    psk_client_config cfg;
    psk_client_config_init(&cfg);
    psk_client* c = psk_client_create(&cfg);
    double t = 1;
    for (auto _ : st) benchmark::DoNotOptimize(psk_client_update(c, t += 1e-3));
    psk_client_destroy(c);
}

// Both clients are updated every iteration (a client left alone would be
// timed out by the server); only the one measured is timed (manual time).
template <class F>
void timed(benchmark::State& st, F&& measured, bool cpp_measured) {
    World& w = world();
    for (auto _ : st) {
        const double now = now_seconds();
        if (cpp_measured) psk_client_update(w.c, now);
        else w.cpp->update(now);
        const auto t0 = std::chrono::steady_clock::now();
        measured(now);
        st.SetIterationTime(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    psk_state s;
    psk_client_state(w.c, &s);
    if (w.cpp->state() != ClientState::Streaming || s != PSK_STATE_STREAMING) st.SkipWithError("a client is not streaming");
}

void BM_Cpp_UpdateStreaming(benchmark::State& st) {
    World& w = world();
    timed(st, [&](double now) { w.cpp->update(now); }, true);
}

void BM_C_UpdateStreaming(benchmark::State& st) {
    World& w = world();
    timed(st, [&](double now) { benchmark::DoNotOptimize(psk_client_update(w.c, now)); }, false);
}

void BM_Cpp_Characters(benchmark::State& st) {
    World& w = world();
    w.update();
    int64_t n = 0;
    for (auto _ : st) {
        for (const RemoteCharacter& rc : w.cpp->characters()) {
            benchmark::DoNotOptimize(rc.palette.data());
            benchmark::DoNotOptimize(rc.root.position.x + rc.bones + rc.instance);
            ++n;
        }
    }
    st.SetItemsProcessed(n);  // items: characters read
}

void BM_C_Characters(benchmark::State& st) {
    World& w = world();
    w.update();
    int64_t n = 0;
    for (auto _ : st) {
        int count = 0;
        psk_client_character_count(w.c, &count);
        for (int i = 0; i < count; ++i) {
            psk_character ch;
            psk_client_character(w.c, i, &ch);
            benchmark::DoNotOptimize(ch.palette);
            benchmark::DoNotOptimize(ch.position[0] + ch.bones + ch.instance);
            ++n;
        }
    }
    st.SetItemsProcessed(n);  // items: characters read
}

void BM_Cpp_Publish(benchmark::State& st) {
    World& w = world();
    RootPose root;
    uint64_t us = uint64_t(now_seconds() * 1e6);
    for (auto _ : st) {
        root.source_us = ++us;
        if (!w.cpp->publish(w.cpp_handle, root, w.skin)) st.SkipWithError("not sent");
    }
    w.update();
}

void BM_C_Publish(benchmark::State& st) {
    World& w = world();
    psk_root root{};
    root.rotation[3] = 1;
    root.source_us = uint64_t(psk_now() * 1e6);
    const float* m = w.skin.data()->m;
    const int joints = int(w.skin.size());
    for (auto _ : st) {
        ++root.source_us;
        if (psk_client_publish(w.c, w.c_handle, &root, m, joints, nullptr, 0, 0) != PSK_OK) st.SkipWithError(psk_last_error());
    }
    w.update();
}

}  // namespace

BENCHMARK(BM_Cpp_UpdateIdle);
BENCHMARK(BM_C_UpdateIdle);
BENCHMARK(BM_Cpp_Characters);
BENCHMARK(BM_C_Characters);
BENCHMARK(BM_Cpp_Publish);
BENCHMARK(BM_C_Publish);
BENCHMARK(BM_Cpp_UpdateStreaming)->UseManualTime();
BENCHMARK(BM_C_UpdateStreaming)->UseManualTime();
BENCHMARK_MAIN();
