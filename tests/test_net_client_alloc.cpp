// The embedded client's promise (client/client.h): once the scene is steady,
// update() allocates nothing, whatever it does (socket I/O, acks, stats,
// display, palettes). Every operator new of the test's thread is counted
// while a Client streams the default scene from an in-process server (its
// own thread, not counted) and publishes a character of its own.
#include <gtest/gtest.h>

#include <atomic>

#include "alloc_counter.h"
#include "animation.h"
#include "net_test_support.h"
#include "wire.h"

using alloc_counter::allocations;
using alloc_counter::counting;
using alloc_counter::measuring;

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::RunningServer;

TEST(NetClientAlloc, UpdateAllocatesNothingOnceSteady) {
    RunningServer server;
    ClientConfig cfg;
    cfg.cache_dir = RunningServer::cache_dir();
    Client client(cfg);
    client.connect("127.0.0.1", server.server->tcp_port());
    int me = -1;
    ClipSelection clip;
    std::vector<glm::dmat4> joints;
    std::vector<Mat34> skinning;
    // Counts the Client's calls only (sampling the clip is the game's work).
    auto frame = [&](double now) {
        counting = measuring;
        client.update(now);
        counting = false;
        ASSERT_NE(client.state(), ClientState::Failed) << client.error();
        if (client.instance_of(me) >= 0) {
            const ClientAsset& a = *client.assets()[0];
            sample_skinning_matrices(a.character, clip, clip.looped(now), joints);
            for (size_t j = 0; j < joints.size(); ++j) skinning[j] = Mat34::from_glm(joints[j]);
            RootPose root;
            root.source_us = uint64_t(now * 1e6);
            counting = measuring;
            client.publish(me, root, skinning);
            for (const RemoteCharacter& c : client.characters()) (void)c.palette;
            counting = false;
        }
    };
    const double t0 = now_seconds();
    while (now_seconds() - t0 < 3.0) {  // connect, download, spawn, settle
        frame(now_seconds());
        if (HasFatalFailure()) return;
        if (me < 0 && !client.assets().empty() && client.assets()[0]) {
            const Character& c = client.assets()[0]->character;
            clip = select_clips(c, "all");
            joints.resize(c.joint_count());
            skinning.resize(c.joint_count());
            SpawnSpec s;
            s.clips = clip.clips;
            me = client.spawn(s);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(16));
    }
    ASSERT_GE(client.instance_of(me), 0);
    ASSERT_EQ(client.characters().size(), 4u);
    // 2.5 s of frames (Stats go out and come back, acks, poses, palettes).
    long updates = 0;
    const double t1 = now_seconds();
    measuring = true;
    while (now_seconds() - t1 < 2.5) {
        frame(now_seconds());
        ++updates;
        std::this_thread::sleep_for(std::chrono::milliseconds(16));
    }
    measuring = false;
    size_t shown = 0;
    for (const RemoteCharacter& c : client.characters()) shown += c.shown;
    EXPECT_EQ(shown, 4u);
    EXPECT_EQ(allocations, 0) << "over " << updates << " updates";
    std::printf("%ld updates, %ld allocations\n", updates, allocations);
    client.close();
}
