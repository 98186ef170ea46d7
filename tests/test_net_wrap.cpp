// Clip playback across its discontinuities (issue: "Correct clip
// playback"): a looping clip's wrap and a once-played clip's end show no
// error spike. The server flags every wrap with a new epoch (datagram.fbs
// Chunk.epoch), so the client never interpolates from the last frame to the
// first; a once-played clip holds its last frame. Measured with the error
// metric (docs/metrics.md §2) on every displayed frame of an embedded Client, at
// unlimited rate: the largest error over the frames within 3 ticks of the
// wrap against the largest elsewhere.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

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

struct WrapErrors {
    double near = 0, elsewhere = 0;
    int near_frames = 0, frames = 0;
};

// Streams one instance of `asset` (its first clip group, or the first
// `cut` of it: a loop whose last pose is not its first) for `seconds` and
// measures every displayed frame.
WrapErrors measure(int asset, bool once, double seconds, double cut = 1.0) {
    InstanceSpec spec;
    for (const auto& s : default_instances(default_assets()))
        if (s.asset == asset && s.selection == 0) spec = s;
    spec.once = once;
    spec.time_offset = 0;
    auto assets = default_assets();
    if (cut < 1.0) {
        auto copy = std::make_shared<ServerAsset>(*assets[size_t(asset)]);
        ClipSelection& sel = copy->selections[size_t(spec.selection)];
        sel.end = float(sel.start + cut * sel.duration());
        assets[size_t(asset)] = copy;
    }
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    Server srv(cfg, assets, {spec});
    std::thread thread([&] { srv.run(); });
    struct Stop {
        Server& s;
        std::thread& t;
        ~Stop() { s.stop(); t.join(); }
    } stop{srv, thread};
    struct {
        Server* server;
    } server{&srv};
    ClientConfig cc;
    cc.cache_dir = RunningServer::cache_dir();
    Client client(cc);
    client.connect("127.0.0.1", server.server->tcp_port());  // the first Fox clip ends mid-motion when cut
    WrapErrors out;
    std::vector<glm::vec3> shown, ref;
    std::vector<glm::dmat4> mats;
    std::vector<Mat34> pal;
    const double t0 = now_seconds();
    double first_shown = 0;
    while (now_seconds() - t0 < seconds + 10) {
        const double now = now_seconds();
        client.update(now);
        EXPECT_NE(client.state(), ClientState::Failed) << client.error();
        if (client.state() == ClientState::Failed) break;
        for (const RemoteCharacter& c : client.characters()) {
            if (!c.shown) continue;
            if (first_shown == 0) first_shown = now;
            if (now - first_shown < 0.5) continue;  // the display delay settles
            const Character& ch = c.asset->character;
            shown.resize(ch.vertex_count());
            skinning_job(ch, c.asset->skin, c.palette, shown).run();
            const double u = c.clip.time_offset + c.display_tick / client.tick_rate() * c.clip.speed;
            mats.resize(ch.joint_count());
            pal.resize(ch.joint_count());
            sample_skinning_matrices(ch, c.clip.selection, c.clip.at(u), mats);
            for (size_t j = 0; j < mats.size(); ++j) pal[j] = Mat34::from_glm(mats[j]);
            ref.resize(ch.vertex_count());
            skinning_job(ch, pal, ref).run();
            double mx = 0;
            for (size_t v = 0; v < shown.size(); ++v) mx = std::max(mx, double(glm::length(shown[v] - ref[v])));
            mx *= 100.0 / c.asset->diagonal;
            const double dur = c.clip.selection.duration();
            const double phase = once ? u - dur : u - std::round(u / dur) * dur;  // time from the nearest wrap / the end
            const bool near = std::fabs(phase) <= 3.0 / client.tick_rate();
            (near ? out.near : out.elsewhere) = std::max(near ? out.near : out.elsewhere, mx);
            out.near_frames += near;
            ++out.frames;
        }
        if (first_shown > 0 && now - first_shown > seconds) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(8));
    }
    client.close();
    return out;
}

}  // namespace

TEST(NetWrap, LoopingClipShowsNoSpikeAtItsWrap) {
    for (int asset : {0, 1}) {
        const auto& a = *default_assets()[size_t(asset)];
        const double dur = a.selections[0].duration();
        const WrapErrors e = measure(asset, false, std::min(8.0, 2.2 * dur + 0.5));
        std::printf("%s loop (%.2f s): max %% diagonal within 3 ticks of a wrap %.4f (%d frames), elsewhere %.4f (%d frames)\n",
                    a.name.c_str(), dur, e.near, e.near_frames, e.elsewhere, e.frames - e.near_frames);
        ASSERT_GT(e.near_frames, 3) << a.name;
        ASSERT_GT(e.frames - e.near_frames, 30) << a.name;
        EXPECT_LE(e.near, kWrapSpikeFactor * e.elsewhere + kWrapSpikeSlackPct) << a.name;
    }
}

// A loop whose last pose is not its first: the server bumps the epoch at
// the wrap, the client extrapolates each side up to the wrap instead of
// smearing from the last frame to the first: up to the wrap it carries the
// nearest frame along the clip's own motion (the client holds the clip).
TEST(NetWrap, CutLoopShowsNoSpikeAtItsWrap) {
    const auto& a = *default_assets()[0];
    const double dur = 0.6 * a.selections[0].duration();
    const WrapErrors e = measure(0, false, std::min(8.0, 2.2 * dur + 0.5), 0.6);
    std::printf("%s cut to %.2f s: max %% diagonal within 3 ticks of a wrap %.4f (%d frames), elsewhere %.4f (%d frames)\n",
                a.name.c_str(), dur, e.near, e.near_frames, e.elsewhere, e.frames - e.near_frames);
    ASSERT_GT(e.near_frames, 3);
    EXPECT_LE(e.near, kWrapSpikeFactor * e.elsewhere + kWrapSpikeSlackPct);
}

TEST(NetWrap, OnceClipHoldsItsLastFrame) {
    const int asset = 1;  // CesiumMan: a 2 s clip
    const auto& a = *default_assets()[size_t(asset)];
    const WrapErrors e = measure(asset, true, a.selections[0].duration() + 1.5);
    std::printf("%s once: max %% diagonal within 3 ticks of the end %.4f (%d frames), elsewhere %.4f (%d frames)\n", a.name.c_str(),
                e.near, e.near_frames, e.elsewhere, e.frames - e.near_frames);
    ASSERT_GT(e.near_frames, 3);
    EXPECT_LE(e.near, kWrapSpikeFactor * e.elsewhere + kWrapSpikeSlackPct);
}
