// test_net_loopback.cpp — real sockets on 127.0.0.1: handshake, asset
// download and cache, streaming at unlimited bandwidth (all bones, error
// within the quantisation bound), version mismatch and bad token refused.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "errors.h"
#include "error_metric.h"
#include "gltf_export.h"
#include "net_test_support.h"
#include "wire.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using namespace progskin::thresholds;

TEST(NetLoopback, HandshakeDownloadsAssetsThenUsesCache) {
    RunningServer s;
    ClientOptions o = s.client(1.0);
    o.cache_dir = RunningServer::cache_dir() + "/fresh";
    std::filesystem::remove_all(o.cache_dir);
    ClientReport r = run_client(o);
    size_t total = 0;
    for (const auto& a : default_assets()) total += a->bytes.size();
    EXPECT_EQ(r.asset_bytes_downloaded, total);
    EXPECT_EQ(r.assets_cached, 0);
    EXPECT_EQ(r.characters, 4);
    EXPECT_GT(r.datagrams, 10u);
    ClientReport again = run_client(o);
    EXPECT_EQ(again.asset_bytes_downloaded, 0u);
    EXPECT_EQ(again.assets_cached, 2);
    EXPECT_EQ(again.characters, 4);
}

TEST(NetLoopback, UnlimitedBandwidthDeliversAllBonesWithinQuantisationBound) {
    RunningServer s;
    ClientOptions o = s.client(3.0);
    o.verify = true;
    o.snap_to_ticks = true;  // displayed exactly at server ticks: only quantisation error remains
    ClientReport r = run_client(o);
    ASSERT_EQ(r.instances.size(), 4u);
    double bound_pct = 0;
    for (const auto& a : default_assets())
        bound_pct = std::max(bound_pct, 100.0 * quantisation_bound(a->format, a->bind_radius, a->max_scale) / rest_diagonal(a->character));
    for (const auto& i : r.instances) {
        const auto& a = *default_assets()[i.asset == "Fox.glb" ? 0 : 1];
        EXPECT_EQ(i.bones_min, a.bone_count()) << i.asset;
        EXPECT_GE(i.frames, 50u);  // 3 s at 30 Hz after the 1 s warm-up: 60
    }
    EXPECT_EQ(r.loss, 0.0);
    EXPECT_EQ(r.malformed, 0u);
    EXPECT_GE(r.max_pct, 0.0);
    EXPECT_LE(r.max_pct, bound_pct);
    std::printf("unlimited: %.1f kbit/s, RMS %.5f%%, max %.5f%% (quantisation bound %.5f%%)\n", r.rate_kbps, r.rms_pct,
                r.max_pct, bound_pct);
}

TEST(NetLoopback, InterpolatedDisplayStaysClose) {
    RunningServer s;
    ClientOptions o = s.client(2.0);
    o.verify = true;
    o.display_rate = 60;
    ClientReport r = run_client(o);
    EXPECT_LT(r.rms_pct, kInterpolatedRmsPct);  // interpolation between 30 Hz ticks
}

TEST(NetLoopback, ProtocolVersionMismatchIsRefusedClearly) {
    RunningServer s;
    ClientOptions o = s.client(1.0);
    o.protocol_version = PROTOCOL_VERSION + 1;
    try {
        run_client(o);
        FAIL() << "connection was not refused";
    } catch (const Error& e) {
        std::string m = e.what();
        EXPECT_NE(m.find("refused"), std::string::npos) << m;
        EXPECT_NE(m.find("protocol version"), std::string::npos) << m;
    }
    EXPECT_EQ(s.server->stats().refused, 1u);
}

TEST(NetLoopback, WrongTokenIsRefused) {
    ServerConfig cfg;
    cfg.token = "secret";
    RunningServer s({}, cfg);
    ClientOptions o = s.client(1.0);
    o.token = "guess";
    EXPECT_THROW(run_client(o), Error);
    o.token = "secret";
    EXPECT_EQ(run_client(o).characters, 4);
}

TEST(NetLoopback, ManyClientsAtOnce) {
    std::vector<InstanceSpec> few = default_instances(default_assets());
    RunningServer s(few);
    const int n = 24;
    std::vector<ClientReport> reports(n);
    std::vector<std::thread> ts;
    for (int i = 0; i < n; ++i)
        ts.emplace_back([&, i] {
            ClientOptions o = s.client(2.0);
            o.max_kbps = 64;
            reports[i] = run_client(o);
        });
    for (auto& t : ts) t.join();
    for (const auto& r : reports) {
        EXPECT_EQ(r.characters, 4);
        EXPECT_LE(r.rate_max_kbps, 64 * 1.05);
    }
    EXPECT_EQ(s.server->stats().sessions_total, uint64_t(n));
}

TEST(NetLoopback, LivePosesPushedThroughTheLibraryApi) {
    std::vector<InstanceSpec> inst(1);
    inst[0].asset = 0;
    inst[0].selection = -1;  // live only
    RunningServer s(inst);
    const auto& a = *default_assets()[0];
    FrameSet fs = sample_frames(a.character, {a.selections[1]}, 30.0);
    std::atomic<bool> run{true};
    std::thread pusher([&] {
        size_t f = 0;
        while (run) {
            s.server->push_pose(0, std::span<const Mat34>(fs.frame(f % fs.frame_count()), a.character.joint_count()));
            ++f;
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
    });
    ClientOptions o = s.client(1.5);
    o.warmup = 0.5;
    ClientReport r = run_client(o);
    run = false;
    pusher.join();
    EXPECT_EQ(r.characters, 1);
    EXPECT_EQ(r.bones_min, a.bone_count());
}

TEST(NetLoopback, ServesAProgressiveGltfWithoutRebuilding) {
    const auto& fox = *default_assets()[0];
    std::string path = RunningServer::cache_dir() + "/Fox.progressive.glb";
    save_progressive(fox.character, fox.skin, path);
    auto a = load_server_asset(path);
    EXPECT_TRUE(a->progressive_file);
    ASSERT_EQ(a->bone_count(), fox.bone_count());
    for (int b = 0; b < a->bone_count(); ++b) EXPECT_EQ(a->skin.order[b], b);
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    InstanceSpec i;
    i.selection = 1;
    Server server(cfg, {a}, {i});
    std::thread th([&] { server.run(); });
    ClientOptions o;
    o.port = server.tcp_port();
    o.duration = 2.0;
    o.cache_dir = RunningServer::cache_dir() + "/progressive";
    o.verify = true;
    o.snap_to_ticks = true;
    ClientReport r = run_client(o);
    server.stop();
    th.join();
    EXPECT_EQ(r.characters, 1);
    EXPECT_EQ(r.bones_min, a->bone_count());
    EXPECT_LT(r.max_pct, kSnappedFoxMaxPct);
}
