// Live multiplayer sync on loopback (issue: "Live multiplayer character
// sync"): eight players on a catalogue-only server, seven embedded
// progskin::net::Client objects driven from this thread's game loop and one
// separate progskin-client process, each publishing a character driven by
// a clip and walking a circle of 100 diagonals. Every player sees the other
// seven within 1 s of their spawn and never itself; one leaves and one joins
// mid-run and everybody notices; the separate process measures what it
// displays of the others against what their publishers display (--verify).
#include <gtest/gtest.h>

#include <cstdio>
#include <future>
#include <map>
#include <set>

#include "animation.h"
#include "net_test_support.h"
#include "wire.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::default_assets;
using progskin::net::testing::RunningServer;
using namespace progskin::thresholds;

namespace {

struct Player {
    std::unique_ptr<Client> client;
    int handle = -1, instance = -1, asset = 0;
    double spawned_at = -1;  // when the server confirmed the spawn
    ClipSelection selection;
    glm::dvec3 center{0.0};
    double radius = 0, speed = 0;
    uint64_t start_us = 0;
    std::vector<glm::dmat4> mats;
    std::vector<Mat34> skin;
    std::map<int, double> first_seen;  // instance -> time first displayed
    std::set<int> removed;             // instances it was told are gone
    bool saw_itself = false, left = false;
};

uint64_t now_us() { return uint64_t(now_seconds() * 1e6); }

void start(Player& p, uint16_t port, int index) {
    ClientConfig cfg;
    cfg.cache_dir = RunningServer::cache_dir();
    cfg.name = "player" + std::to_string(index);
    p.client = std::make_unique<Client>(cfg);
    p.client->connect("127.0.0.1", port);
    p.asset = index % 2;
}

void step(Player& p, double now, int index) {
    Client& c = *p.client;
    c.update(now);
    ASSERT_NE(c.state(), ClientState::Failed) << "player " << index << ": " << c.error();
    for (const ClientEvent& e : c.events()) {
        if (e.type == ClientEvent::Type::Spawned) {
            p.instance = e.instance;
            p.spawned_at = now;
        }
        ASSERT_NE(e.type, ClientEvent::Type::SpawnRefused) << e.text;
        if (e.type == ClientEvent::Type::CharacterRemoved) p.removed.insert(e.instance);
    }
    if (p.handle < 0 && !c.assets().empty() && c.assets()[size_t(p.asset)]) {
        const ClientAsset& a = *c.assets()[size_t(p.asset)];
        p.selection = select_clips(a.character, "all");
        p.radius = 100.0 * a.diagonal;
        p.speed = 0.75 * a.diagonal;
        p.center = glm::dvec3(double(index) * 500.0 * a.diagonal, 0.0, 0.0);
        p.start_us = now_us();
        p.mats.resize(a.character.joint_count());
        p.skin.resize(a.character.joint_count());
        SpawnSpec s;
        s.asset = p.asset;
        s.clips = p.selection.clips;
        s.start_us = p.start_us;
        s.walk_center = p.center;
        s.walk_radius = p.radius;
        s.walk_speed = p.speed;
        p.handle = c.spawn(s);
    }
    if (p.instance >= 0) {
        const ClientAsset& a = *c.assets()[size_t(p.asset)];
        const uint64_t t_us = now_us();
        const double t = double(t_us - p.start_us) * 1e-6;
        sample_skinning_matrices(a.character, p.selection, p.selection.looped(t), p.mats);
        for (size_t j = 0; j < p.mats.size(); ++j) p.skin[j] = Mat34::from_glm(p.mats[j]);
        RootPose root = walk_root(p.center, p.radius, p.speed, t);
        root.source_us = t_us;
        c.publish(p.handle, root, p.skin);
    }
    for (const RemoteCharacter& rc : c.characters()) {
        if (rc.instance == p.instance) p.saw_itself = true;
        if (rc.shown && !p.first_seen.count(rc.instance)) p.first_seen[rc.instance] = now;
    }
}

}  // namespace

TEST(NetMultiplayer, EightPlayersSeeEachOtherJoinAndLeave) {
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    cfg.threads = progskin::net::testing::test_threads();
    Server server(cfg, default_assets(), {});  // catalogue only (--no-scene)
    std::thread st([&] { server.run(); });
    const uint16_t port = server.tcp_port();

    // The separate process: publishes a CesiumMan walking 100 diagonals out
    // and verifies what it displays of everybody else.
    const std::string cmd = std::string(PROGSKIN_BIN_DIR) + "/client/progskin-client --no-tls --server 127.0.0.1:" + std::to_string(port) +
                            " --publish CesiumMan.glb --walk 100 --duration 7 --warmup 1.5 --verify --verify-every 3 --report json --cache " +
                            RunningServer::cache_dir() + " 2>&1";
    auto external = std::async(std::launch::async, [cmd] {
        std::string out;
        FILE* f = ::popen(cmd.c_str(), "r");
        if (!f) return std::make_pair(-1, out);
        char buf[4096];
        size_t n;
        while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
        const int rc = ::pclose(f);
        return std::make_pair(WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, out);
    });

    std::vector<Player> players(8);  // players[7] joins when players[6] leaves
    for (int i = 0; i < 7; ++i) start(players[size_t(i)], port, i);
    const double t0 = now_seconds();
    double left_at = -1;
    while (now_seconds() - t0 < 9.0) {
        const double now = now_seconds();
        for (int i = 0; i < 8; ++i) {
            Player& p = players[size_t(i)];
            if (!p.client || p.left) continue;
            step(p, now, i);
            if (HasFatalFailure()) break;
        }
        if (HasFatalFailure()) break;
        if (left_at < 0 && now - t0 > 4.5) {  // player 6 leaves, player 7 joins
            players[6].client->close();
            players[6].left = true;
            left_at = now;
            start(players[7], port, 7);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(16));
    }
    const auto [rc, out] = external.get();
    const ServerStats ss = server.stats();
    server.stop();
    st.join();
    ASSERT_FALSE(HasFatalFailure());

    // Published poses travel predicted from poses the server acknowledged
    // (docs/protocol.md "Pose"); none was predicted from one it lacked.
    for (int i = 0; i < 6; ++i) {
        const ClientStats cs = players[size_t(i)].client->stats();
        EXPECT_GT(cs.poses_sent, 60u) << "player " << i;
        EXPECT_GE(double(cs.poses_predicted), 0.8 * double(cs.poses_sent)) << "player " << i;
    }
    EXPECT_EQ(ss.poses_missing_baseline, 0u);
    EXPECT_EQ(ss.malformed_datagrams, 0u);
    EXPECT_GT(ss.poses_received, 600u);

    // Everybody saw everybody else within 1 s of their spawn, never itself.
    std::set<int> external_instances;
    for (int i = 0; i < 8; ++i) {
        const Player& p = players[size_t(i)];
        ASSERT_GE(p.instance, 0) << "player " << i << " never spawned";
        EXPECT_FALSE(p.saw_itself) << "player " << i;
        for (const auto& [inst, t] : p.first_seen) {
            bool in_process = false;
            for (const Player& q : players) in_process = in_process || q.instance == inst;
            if (!in_process) external_instances.insert(inst);
        }
    }
    ASSERT_EQ(external_instances.size(), 1u) << "the separate process's character";
    for (int i = 0; i < 8; ++i) {
        const Player& p = players[size_t(i)];
        for (int j = 0; j < 8; ++j) {
            const Player& q = players[size_t(j)];
            if (i == j || (i == 6 && j == 7) || (i == 7 && j == 6)) continue;  // 6 left before 7 came
            auto it = p.first_seen.find(q.instance);
            ASSERT_NE(it, p.first_seen.end()) << "player " << i << " never saw player " << j;
            const double since = std::max(q.spawned_at, p.spawned_at);  // the later of the two arrivals
            EXPECT_LE(it->second - since, 1.0) << "player " << i << " saw player " << j << " late";
        }
        EXPECT_EQ(p.first_seen.count(*external_instances.begin()), 1u) << "player " << i << " never saw the process";
    }
    // The one who left was removed everywhere.
    for (int i = 0; i < 6; ++i) {
        EXPECT_EQ(players[size_t(i)].removed.count(players[6].instance), 1u) << "player " << i;
    }

    // The separate process: exit 0, saw the others, displayed them within
    // kStreamRmsPctUnlimited (RMS) of what their publishers displayed.
    ASSERT_EQ(rc, 0) << out;
    const size_t at = out.find("\"remote\": {");
    ASSERT_NE(at, std::string::npos) << out;
    auto field = [&](const std::string& key) {
        const size_t k = out.find("\"" + key + "\": ", at);
        return k == std::string::npos ? -1.0 : std::atof(out.c_str() + k + key.size() + 4);
    };
    EXPECT_GE(field("characters"), 7) << out;
    const double rms = field("rms_pct");
    EXPECT_GE(rms, 0.0) << out;
    EXPECT_LE(rms, kStreamRmsPctUnlimited) << out;
    EXPECT_GT(field("latency_ms_p50"), 0.0) << out;
    std::printf("separate process: %s\n", out.c_str());
}

// examples/game_loop.cpp, the embedding example, joins a scene, is given its
// character and prints the server's characters it displays.
TEST(NetMultiplayer, GameLoopExampleJoinsAndSeesTheScene) {
    RunningServer server;
    const std::string cmd = std::string(PROGSKIN_BIN_DIR) + "/examples/game_loop 127.0.0.1 " +
                            std::to_string(server.server->tcp_port()) + " 3 2>&1";
    FILE* f = ::popen(cmd.c_str(), "r");
    ASSERT_NE(f, nullptr);
    std::string out;
    char buf[4096];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
    const int rc = ::pclose(f);
    ASSERT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << out;
    EXPECT_NE(out.find("I am character"), std::string::npos) << out;
    EXPECT_NE(out.find("(Fox.glb): 24 bones"), std::string::npos) << out;
    EXPECT_NE(out.find("(CesiumMan.glb): 19 bones"), std::string::npos) << out;
}

// The example announces what it plays (clips, start time, walk): a peer
// verifying what it displays of the example's character against that
// announcement measures a small error (it measured 501 % RMS when the spawn
// announced no walk and no start time).
TEST(NetMultiplayer, GameLoopExampleAnnouncesWhatItPlays) {
    RunningServer server;
    const std::string cmd = std::string(PROGSKIN_BIN_DIR) + "/examples/game_loop 127.0.0.1 " +
                            std::to_string(server.server->tcp_port()) + " 7 2>&1";
    auto example = std::async(std::launch::async, [&cmd] {
        FILE* f = ::popen(cmd.c_str(), "r");
        std::string out;
        if (!f) return out;
        char buf[4096];
        size_t n;
        while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
        ::pclose(f);
        return out;
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // the example spawns
    ClientOptions o = server.client(3.0);
    o.verify = true;
    const ClientReport r = run_client(o);
    const std::string out = example.get();
    EXPECT_NE(out.find("I am character"), std::string::npos) << out;
    ASSERT_EQ(r.remote_characters, 1) << out;
    std::printf("game_loop seen by a verifying peer: RMS %.4f %%, max %.4f %% of the diagonal\n", r.remote_rms_pct,
                r.remote_max_pct);
    EXPECT_GE(r.remote_rms_pct, 0.0);
    // The example publishes at its own frame times, interpolated here (measured 0.070 %; 501 % before).
    EXPECT_LE(r.remote_rms_pct, kInterpolatedRmsPct);
}

// More players than their caps comfortably hold (issue 24: four players at
// 64 kbit/s with 43- and 49-bone characters waited 14.5 s and saw some
// characters at 1 bone; eight at 8 kbit/s displayed 3 of their 7 remote
// characters): six players, every one capped at 6 kbit/s, each publishing a
// walking character. The scheduler's floor (ROOT_REFRESH_TICKS) refreshes
// every character's root in turn: every player displays all five others,
// and the newest pose it shows of any is never seconds old.
TEST(NetMultiplayer, StarvedRoomStillShowsEveryCharacter) {
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    cfg.port = 0;
    Server server(cfg, default_assets(), {});  // a catalogue only: the players bring the characters
    std::thread t([&] { server.run(); });
    constexpr int kPlayers = 6;
    std::vector<std::future<ClientReport>> players;
    for (int i = 0; i < kPlayers; ++i) {
        ClientOptions o;
        o.host = "127.0.0.1";
        o.port = server.tcp_port();
        o.cache_dir = RunningServer::cache_dir();
        o.name = "starved" + std::to_string(i);
        o.max_kbps = 6;
        o.duration = 8;
        o.warmup = 2;
        o.publish.push_back({std::to_string(i % 2), "", 100.0});
        players.push_back(std::async(std::launch::async, [o] { return run_client(o); }));
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    std::vector<ClientReport> reports;
    for (auto& p : players) reports.push_back(p.get());
    server.stop();
    t.join();
    for (int i = 0; i < kPlayers; ++i) {
        const ClientReport& r = reports[size_t(i)];
        std::printf("player %d: %.1f kbit/s, %d remote characters, latency p50 %.0f ms p99 %.0f ms\n", i, r.rate_kbps,
                    r.remote_characters, r.latency_ms_p50, r.latency_ms_p99);
        EXPECT_EQ(r.remote_characters, kPlayers - 1) << "player " << i;
        EXPECT_LE(r.rate_kbps, 6.0 * 1.1) << "player " << i;  // the first datagram is a full bucket
        EXPECT_GT(r.latency_ms_p99, 0.0) << "player " << i;
        EXPECT_LT(r.latency_ms_p99, 3000.0) << "player " << i;
        for (const InstanceReport& ir : r.instances) {
            if (ir.published) {
                EXPECT_GE(ir.bones_min, 1) << "player " << i << " instance " << ir.instance;
            }
        }
    }
}

// A crowd of 5,000 instances reaches a client whole (InstanceAdded batches;
// Welcome no longer lists instances) and streams.
TEST(NetMultiplayer, CrowdOf5000InstancesArrives) {
    RunningServer server(crowd_layout(default_assets(), 5000));
    ClientConfig cfg;
    cfg.cache_dir = RunningServer::cache_dir();
    cfg.max_kbps = 2000;
    Client client(cfg);
    client.connect("127.0.0.1", server.server->tcp_port());
    size_t most = 0;
    int shown = 0;
    const double t0 = now_seconds();
    while (now_seconds() - t0 < 20 && (most < 5000 || shown == 0)) {
        client.update(now_seconds());
        ASSERT_NE(client.state(), ClientState::Failed) << client.error();
        most = std::max(most, client.characters().size());
        shown = 0;
        for (const RemoteCharacter& c : client.characters()) shown += c.shown;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    EXPECT_EQ(most, 5000u);
    EXPECT_GT(shown, 0);
    client.close();
}
