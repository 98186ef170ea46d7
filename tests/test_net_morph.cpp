// Morph target weights streamed end to end (docs/protocol.md "Morph block"):
// tests/data/skinned_morph.gltf (3 bones, 4 morph targets, its "talk" clip
// animating the weights) served by an in-process Server over real loopback
// sockets to run_client --verify, which measures the displayed (morphed,
// skinned) mesh against the reference (morph targets at the clip's weights,
// then the skin; docs/metrics.md §2).
#include <gtest/gtest.h>

#include <bit>
#include <thread>

#include "animation.h"
#include "client_stream.h"
#include "error_metric.h"
#include "frame_encoder.h"
#include "frame_reader.h"
#include "net_test_support.h"
#include "server.h"
#include "server_core.h"
#include "wire.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using namespace progskin::thresholds;

namespace {

std::string fixture() { return std::string(PROGSKIN_TEST_DATA) + "/skinned_morph.gltf"; }

const std::shared_ptr<ServerAsset>& morph_asset() {
    static const std::shared_ptr<ServerAsset> a = load_server_asset(fixture());
    return a;
}

// The selection playing the clip "talk".
int talk_selection(const ServerAsset& a) {
    for (size_t s = 0; s < a.selections.size(); ++s)
        for (int c : a.selections[s].clips)
            if (a.character.clips[size_t(c)].name == "talk" && a.selections[s].clips.size() == 1) return int(s);
    return -1;
}

// RMS % of the diagonal of showing the clip with exact bones and the morph
// targets ignored (the bind shape skinned): what a client without weights shows.
double ignored_morph_rms_pct(const ServerAsset& a, int sel) {
    const Character& c = a.character;
    const FrameSet frames = sample_frames(c, {a.selections[size_t(sel)]}, 30.0);
    ErrorAccumulator acc(rest_diagonal(c));
    std::vector<glm::vec3> ref(c.vertex_count()), bind(c.vertex_count());
    for (size_t f = 0; f < frames.frame_count(); ++f) {
        reference_positions(c, frames, f, ref);
        skinned_bind_positions(c, frames, f, bind);
        acc.add(ref, bind);
    }
    return acc.stats().rms_pct;
}

struct Streamed {
    ClientReport report;
};

ClientReport stream(double max_kbps, double seconds) {
    const ServerAsset& a = *morph_asset();
    const int sel = talk_selection(a);
    EXPECT_GE(sel, 0);
    InstanceSpec spec;
    spec.asset = 0;
    spec.selection = sel;
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    cfg.port = 0;
    Server server(cfg, {morph_asset()}, {spec});
    std::thread t([&] { server.run(); });
    ClientOptions o;
    o.host = "127.0.0.1";
    o.port = server.tcp_port();
    o.duration = seconds;
    o.cache_dir = RunningServer::cache_dir();
    o.verify = true;
    o.max_kbps = max_kbps;
    ClientReport r;
    try {
        r = run_client(o);
    } catch (...) {
        server.stop();
        t.join();
        throw;
    }
    server.stop();
    t.join();
    return r;
}

}  // namespace

TEST(NetMorph, FixtureAnimatesWeights) {
    const ServerAsset& a = *morph_asset();
    ASSERT_EQ(a.character.morphs.size(), 4u);
    ASSERT_EQ(a.morph_importance.size(), 4u);
    for (double v : a.morph_importance) EXPECT_GT(v, 0.0);
    ASSERT_GE(talk_selection(a), 0);
    EXPECT_GT(ignored_morph_rms_pct(a, talk_selection(a)), kMorphIgnoredMinRmsPct);  // ignoring the weights is visible
}

// Unlimited rate: every weight that changes goes every tick; the displayed
// mesh matches the reference within the codec's and interpolation's error,
// at most kMorphStreamedFraction of the error of ignoring the weights.
TEST(NetMorph, StreamedWeightsMatchTheReference) {
    const ServerAsset& a = *morph_asset();
    const double ignored = ignored_morph_rms_pct(a, talk_selection(a));
    const ClientReport r = stream(0, 3.0);
    ASSERT_EQ(r.instances.size(), 1u);
    const InstanceReport& ir = r.instances[0];
    std::printf("skinned_morph talk, unlimited: %.1f kbit/s, RMS %.4f %% max %.4f %% of the diagonal "
                "(ignoring the weights: RMS %.3f %%)\n",
                r.rate_kbps, ir.rms_pct, ir.max_pct, ignored);
    ASSERT_GT(ir.frames, 30u);
    EXPECT_EQ(r.malformed, 0u);
    EXPECT_LE(ir.rms_pct, kMorphStreamedFraction * ignored);
    EXPECT_LT(ir.rms_pct, kStreamRmsPctUnlimited);
}

// A low cap: bones and weights compete by value per byte; the weights still
// go (they remove most of the visible error), so the displayed error stays far
// below ignoring them.
TEST(NetMorph, WeightsStillGoAtALowCap) {
    const ServerAsset& a = *morph_asset();
    const double ignored = ignored_morph_rms_pct(a, talk_selection(a));
    const ClientReport r = stream(12, 4.0);
    ASSERT_EQ(r.instances.size(), 1u);
    const InstanceReport& ir = r.instances[0];
    std::printf("skinned_morph talk, 12 kbit/s cap: %.1f kbit/s, RMS %.4f %% max %.4f %% (ignoring the weights: %.3f %%)\n",
                r.rate_kbps, ir.rms_pct, ir.max_pct, ignored);
    ASSERT_GT(ir.frames, 30u);
    EXPECT_LE(r.rate_kbps, 12 * 1.05);
    EXPECT_LE(ir.rms_pct, kMorphLowCapFraction * ignored);
}

// Offline (the server's session core without sockets: encoder, scheduler,
// packer; the client's reader): the weights that travel are
// the encoder's, sparse (a weight that did not change is not re-sent before
// its refresh), and a tight budget picks them by value per byte.
TEST(NetMorph, SchedulerSendsChangedWeightsOnly) {
    const std::vector<std::shared_ptr<ServerAsset>> assets = {morph_asset()};
    InstanceSpec spec;
    spec.selection = talk_selection(*assets[0]);
    ServerCore core(ServerConfig{}, assets, {spec});  // the server's session core, without sockets
    auto client = ClientStream::detached(core, 1, 1000);
    FrameEncoder& enc = core.encoder();
    size_t weights_sent = 0, ticks = 0;
    const size_t n = assets[0]->character.morphs.size();
    std::vector<float> shown(n, 0.0f);
    for (uint32_t t = 1; t <= 90; ++t) {
        const EncodedFrame& f = enc.encode(t);
        DatagramCollector out;
        client->send_frame(f, 1 << 20, out);
        for (const auto& d : out.sent) {
            const std::optional<FrameDatagram> fr = frame_of(d.bytes);
            ASSERT_TRUE(fr);
            ASSERT_TRUE(read_frame(
                *fr, [](uint16_t) { return 12; }, [](uint16_t, int, int, int, const RecordRun&) {},
                [&](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t* m) {
                    if (!m) return;
                    for (int i = 0; i < m[0]; ++i) {
                        const uint8_t* e = m + 1 + i * 3;
                        ASSERT_LT(e[0], n);
                        shown[e[0]] = decode_morph_weight(int16_t(uint16_t(e[1] | e[2] << 8)));
                        ++weights_sent;
                    }
                }));
        }
        ++ticks;
        // What the client holds equals the encoder's weights (all that changed went).
        const auto q = f.morphs(0);
        ASSERT_EQ(q.size(), n);
        for (size_t m = 0; m < n; ++m) EXPECT_EQ(shown[m], decode_morph_weight(int16_t(q[m]))) << "tick " << t << " weight " << m;
    }
    // Sparse: fewer than every weight every tick (the fixture animates some of them).
    std::printf("weights sent: %zu over %zu ticks (%zu targets)\n", weights_sent, ticks, n);
    EXPECT_LT(weights_sent, n * ticks);
    EXPECT_GE(weights_sent, n);
}

// A weight outside the wire range ([-2, 2)) is refused by the encoder and
// counted, never clamped: it does not travel, and the client keeps its last
// value; the weights in range still go.
TEST(NetMorph, OutOfRangeWeightsAreRefusedAndCounted) {
    auto scaled = std::make_shared<ServerAsset>(*morph_asset());
    const int sel = talk_selection(*scaled);
    // Weight channels of "talk" times 10: the larger weights leave the range.
    for (int c : scaled->selections[size_t(sel)].clips)
        for (Channel& ch : scaled->character.clips[size_t(c)].channels)
            if (ch.path == ChannelPath::Weights)
                for (float& v : ch.values) v *= 10.0f;
    const std::vector<std::shared_ptr<ServerAsset>> assets = {scaled};
    InstanceSpec spec;
    spec.selection = sel;
    ServerCore core(ServerConfig{}, assets, {spec});
    auto client = ClientStream::detached(core, 1, 1000);
    FrameEncoder& enc = core.encoder();
    size_t refused_ticks = 0, sent = 0;
    std::vector<float> exact(scaled->character.morphs.size());
    for (uint32_t t = 1; t <= 60; ++t) {
        const EncodedFrame& f = enc.encode(t);
        const auto q = f.morphs(0);
        DatagramCollector out;
        client->send_frame(f, 1 << 20, out);
        sample_morph_weights(scaled->character, scaled->selections[size_t(sel)], enc.clip_time(0, t), exact);
        for (size_t m = 0; m < q.size(); ++m) {
            const bool in_range = exact[m] >= -2.0f && exact[m] < 2.0f;
            EXPECT_EQ(q[m] == kNoWeight, !in_range) << "tick " << t << " weight " << m << " = " << exact[m];
            if (!in_range) ++refused_ticks;
        }
        for (const auto& d : out.sent)
            ASSERT_TRUE(read_frame(
                *frame_of(d.bytes), [](uint16_t) { return 12; },
                [](uint16_t, int, int, int, const RecordRun&) {},
                [&](const wire::Chunk&, uint8_t, std::span<const uint8_t>, const uint8_t* m) {
                    if (!m) return;
                    for (int i = 0; i < m[0]; ++i) {
                        const uint8_t* e = m + 1 + i * 3;
                        ASSERT_NE(q[e[0]], kNoWeight) << "a refused weight travelled";
                        EXPECT_EQ(int16_t(uint16_t(e[1] | e[2] << 8)), q[e[0]]);
                        ++sent;
                    }
                }));
    }
    EXPECT_GT(refused_ticks, 0u);
    EXPECT_GT(sent, 0u);
    EXPECT_EQ(enc.stats().morphs_out_of_range, refused_ticks);
}

// A player's character with morph targets: the publisher sends every weight
// with its pose (Pose.morphs), the server streams them like a clip's, and an
// observer (run_client --verify) displays the published face at a small
// fraction of the error of ignoring the weights. (Measured 0.22 % RMS against
// 0.013 % for the same clip played by the server: the publisher samples at
// its own 30 Hz, not on the ticks, so some ticks repeat a pose and others skip
// one, and the client's interpolation between such frames is coarser.)
TEST(NetMorph, PublishedWeightsReachObservers) {
    const ServerAsset& a = *morph_asset();
    const double ignored = ignored_morph_rms_pct(a, talk_selection(a));
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    Server server(cfg, {morph_asset()}, {});  // catalogue only
    std::thread t([&] { server.run(); });
    auto options = [&](const std::string& name, double seconds) {
        ClientOptions o;
        o.host = "127.0.0.1";
        o.port = server.tcp_port();
        o.name = name;
        o.duration = seconds;
        o.cache_dir = RunningServer::cache_dir();
        PublishOptions p;
        p.asset = "0";
        p.clip = "talk";
        o.publish.push_back(p);
        return o;
    };
    ClientReport pub, obs;
    std::thread publisher([&] { pub = run_client(options("publisher", 5.0)); });
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    ClientOptions o = options("observer", 3.0);
    o.verify = true;
    obs = run_client(o);
    publisher.join();
    server.stop();
    t.join();
    std::printf("published skinned_morph talk: remote RMS %.4f %% max %.4f %% (ignoring the weights: RMS %.3f %%), %llu poses\n",
                obs.remote_rms_pct, obs.remote_max_pct, ignored, (unsigned long long)pub.poses_sent);
    ASSERT_EQ(obs.remote_characters, 1);
    ASSERT_GE(obs.remote_rms_pct, 0.0);
    EXPECT_LE(obs.remote_rms_pct, kMorphStreamedFraction * ignored);
}
