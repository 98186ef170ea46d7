// The C API's promise (capi/progskin.h, docs/bindings.md): once the scene is
// steady, psk_client_update and the per-frame queries (events, characters,
// publish) allocate nothing — the same test as test_net_client_alloc.cpp
// for the C++ Client, through libprogskin_c.so. Every operator new of the
// test's thread is counted (the library's calls resolve to this one) while a
// C client streams the default scene from an in-process server and
// publishes a character of its own.
#include <gtest/gtest.h>

#include <thread>
#include <vector>

#include "alloc_counter.h"
#include "net_test_support.h"
#include "progskin.h"

using alloc_counter::allocations;
using alloc_counter::counting;
using alloc_counter::measuring;

using progskin::net::testing::RunningServer;

TEST(NetCApiAlloc, UpdateAllocatesNothingOnceSteady) {
    RunningServer server;
    psk_client_config cfg;
    ASSERT_EQ(psk_client_config_init(&cfg), PSK_OK);
    cfg.tls = 0;  // the in-process server speaks plain TCP
    const std::string cache = RunningServer::cache_dir();
    cfg.cache_dir = cache.c_str();
    psk_client* c = psk_client_create(&cfg);
    ASSERT_NE(c, nullptr) << psk_last_error();
    ASSERT_EQ(psk_client_connect(c, "127.0.0.1", server.server->tcp_port()), PSK_OK) << psk_last_error();
    int handle = -1, instance = -1, joints = 0;
    std::vector<float> skin;
    long shown = 0;
    // Counts the library's calls only (sampling the clip is the game's work).
    auto frame = [&](double now) {
        counting = measuring;
        const psk_status s = psk_client_update(c, now);
        psk_event e;
        while (psk_client_poll_event(c, &e) == PSK_OK) {
        }
        counting = false;
        ASSERT_EQ(s, PSK_OK) << psk_last_error();
        if (instance < 0 && handle >= 0) psk_client_instance_of(c, handle, &instance);
        if (instance < 0) return;
        psk_client_sample_clip(c, 0, -1, now, skin.data(), int(skin.size()));
        psk_root root{};
        root.rotation[3] = 1;
        root.source_us = uint64_t(now * 1e6);
        counting = measuring;
        const psk_status p = psk_client_publish(c, handle, &root, skin.data(), joints, nullptr, 0, 0);
        int n = 0;
        psk_client_character_count(c, &n);
        shown = 0;
        for (int i = 0; i < n; ++i) {
            psk_character ch;
            if (psk_client_character(c, i, &ch) == PSK_OK) shown += ch.shown;
        }
        counting = false;
        // Not bound yet while settling (PSK_NOT_READY); sent every frame once steady.
        ASSERT_TRUE(p == PSK_OK || (!measuring && p == PSK_NOT_READY)) << psk_status_name(p) << ": " << psk_last_error();
    };
    const double t0 = psk_now();
    while (psk_now() - t0 < 3.0) {  // connect, download, spawn, settle
        frame(psk_now());
        if (HasFatalFailure()) return;
        psk_asset a;
        if (handle < 0 && psk_client_asset(c, 0, &a) == PSK_OK) {
            joints = a.joint_count;
            skin.resize(size_t(joints) * 12);
            psk_spawn_spec s;
            psk_spawn_spec_init(&s);
            ASSERT_EQ(psk_client_spawn(c, &s, &handle), PSK_OK) << psk_last_error();
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(16));
    }
    ASSERT_GE(instance, 0);
    int count = 0;
    ASSERT_EQ(psk_client_character_count(c, &count), PSK_OK);
    ASSERT_EQ(count, 4);
    long updates = 0;
    const double t1 = psk_now();
    measuring = true;
    while (psk_now() - t1 < 2.5) {
        frame(psk_now());
        if (HasFatalFailure()) break;
        ++updates;
        std::this_thread::sleep_for(std::chrono::milliseconds(16));
    }
    measuring = false;
    EXPECT_EQ(shown, 4);
    EXPECT_EQ(allocations, 0) << "over " << updates << " updates";
    std::printf("%ld updates, %ld allocations\n", updates, allocations);
    // The count sees the library's allocations: set_view copies the weights.
    const int32_t ids[2] = {1, 2};
    const float weights[2] = {1, 2};
    psk_view v{};
    v.weight_instances = ids;
    v.weights = weights;
    v.weight_count = 2;
    allocations = 0;
    counting = true;
    EXPECT_EQ(psk_client_set_view(c, &v), PSK_OK) << psk_last_error();
    counting = false;
    EXPECT_GT(allocations, 0) << "operator new of the test does not see libprogskin_c.so's allocations";
    EXPECT_EQ(psk_client_close(c, "done"), PSK_OK);
    EXPECT_EQ(psk_client_destroy(c), PSK_OK);
}
