// test_net_pipeline.cpp — the data flow without sockets: frame_encoder ->
// scheduler -> datagram_packer -> (verify, decode) pose_buffer -> client
// palette -> skinning, against the reference at the same clip time.
#include <gtest/gtest.h>

#include <filesystem>
#include <unistd.h>

#include <map>

#include "client_palette.h"
#include "datagram_packer.h"
#include "error_metric.h"
#include "frame_encoder.h"
#include "scene.h"
#include "scheduler.h"
#include "wire.h"
#include "net_test_support.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using progskin::net::testing::apply_frame;
using progskin::net::FrameApplied;
using progskin::net::testing::client_asset;
using progskin::net::testing::frame_of;
using namespace progskin::thresholds;

namespace {

std::vector<std::shared_ptr<ServerAsset>>& shared_assets() {
    static std::vector<std::shared_ptr<ServerAsset>> a = {
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    return a;
}


struct Pipeline {
    std::vector<std::shared_ptr<ServerAsset>> assets = shared_assets();
    std::vector<InstanceSpec> specs;
    FrameEncoder enc;
    Scheduler sched;
    DatagramPacker packer;
    std::vector<std::unique_ptr<InstanceView>> views;
    uint32_t seq = 0;
    explicit Pipeline(int blend = 8, std::vector<InstanceSpec> layout = crowd_layout(shared_assets(), 4),
                      std::vector<std::shared_ptr<ServerAsset>> use = shared_assets())
        : assets(std::move(use)), specs(std::move(layout)), enc(assets, specs, 30.0f) {
        for (const auto& s : specs) {
            ClipInfo ci;
            ci.selection = assets[s.asset]->selections[s.selection];
            ci.time_offset = s.time_offset;
            ci.speed = s.speed;
            views.push_back(std::make_unique<InstanceView>(client_asset(*assets[s.asset]), ci, blend));
        }
    }
    // One tick at a byte budget (or with the given picks); returns wire bytes.
    size_t tick(uint32_t t, size_t budget, std::span<const float> imp, const std::vector<Pick>* forced = nullptr) {
        const EncodedFrame& f = enc.encode(t);
        std::vector<Pick> picks;
        if (forced) picks = *forced;
        else sched.select(f, assets, imp, budget, 30.0f, picks);
        std::vector<std::vector<uint8_t>> dgs;
        size_t wire = packer.pack(f, picks, seq, dgs);
        sched.sent(picks, t);
        for (auto& d : dgs) {
            const std::optional<FrameDatagram> fr = frame_of(d);
            EXPECT_TRUE(fr);
            if (!fr) continue;
            EXPECT_LE(d.size(), MAX_DATAGRAM);
            const FrameApplied a = apply_frame(*fr, views);
            EXPECT_TRUE(a.read);
            EXPECT_EQ(a.refused, 0);
        }
        return wire;
    }
    // Error (% of diagonal) of instance i displayed at tick d.
    std::pair<double, double> error(int i, double d) {
        InstanceView& v = *views[i];
        std::vector<glm::vec3> shown, ref;
        EXPECT_TRUE(v.display(d));
        v.skin(shown);
        v.reference(v.clip().clip_time(d, 30.0), ref);
        ErrorAccumulator acc(v.asset().diagonal);
        acc.add(ref, shown);
        return {acc.stats().rms_pct, acc.stats().max_pct};
    }
};

}  // namespace

TEST(NetPipeline, FullBudgetShowsOnlyQuantisationError) {
    Pipeline p(1);
    std::vector<float> imp(p.specs.size(), 1.0f);
    for (uint32_t t = 1; t <= 40; ++t) {
        p.tick(t, 1 << 20, imp);
        for (int i = 0; i < int(p.specs.size()); ++i) {
            auto [rms, max] = p.error(i, t);
            EXPECT_LT(max, kQuantisationMaxPct) << "instance " << i << " tick " << t;
            EXPECT_EQ(p.views[i]->target_bones(), p.assets[p.specs[i].asset]->bone_count());
        }
    }
}

// Key samples (ServerConfig::key_samples) at full rate, the bundled
// characters built --strategy rate (every bone under its artist parent):
// their 24 Hz linearly keyed clips sampled at their keys, interpolated
// linearly between adjacent ticks, are shown between the ticks within the
// quantisation's error (issue 27's 0.01 % RMS and 0.25 % max at unlimited
// rate); sampled at the ticks and interpolated by the cubic, the kinks
// between the ticks cost several times more.
TEST(NetPipeline, KeySamplesFollowLinearClipsBetweenTicks) {
    AssetOptions options;
    options.build_by_rate = true;
    options.cache_dir = (std::filesystem::temp_directory_path() / ("progskin-keys-" + std::to_string(::getpid()))).string();
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({std::string(PROGSKIN_ASSETS) + "/Fox.glb", std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb"},
                                    options, pending)
                    .empty());
    std::vector<std::shared_ptr<ServerAsset>> rate;
    for (const auto& p : pending) rate.push_back(build_server_asset(p, options));
    std::filesystem::remove_all(options.cache_dir);
    double rms[2] = {0, 0}, max[2] = {0, 0};
    for (int keyed = 0; keyed < 2; ++keyed) {
        Pipeline p(1, crowd_layout(rate, 4), rate);
        p.enc.set_key_samples(keyed == 1);
        std::vector<float> imp(p.specs.size(), 1.0f);
        double sum = 0;
        int n = 0;
        for (uint32_t t = 1; t <= 75; ++t) {
            p.tick(t, 1 << 20, imp);
            if (t < 10) continue;
            for (double frac : {0.1, 0.3, 0.5, 0.7, 0.9}) {
                for (int i = 0; i < int(p.specs.size()); ++i) {
                    auto [r, m] = p.error(i, double(t) - 3.0 + frac);  // 100 ms behind the newest
                    sum += r * r;
                    ++n;
                    max[keyed] = std::max(max[keyed], m);
                }
            }
        }
        rms[keyed] = std::sqrt(sum / n);
    }
    std::printf("between ticks at full rate: tick samples RMS %.4f %% max %.4f %%, key samples RMS %.4f %% max %.4f %%\n", rms[0],
                max[0], rms[1], max[1]);
    EXPECT_LT(rms[1], 0.01);
    EXPECT_LT(max[1], 0.25);
    EXPECT_GT(rms[0], 5 * rms[1]);
}

TEST(NetPipeline, FrameOverheadMatchesWireCost) {
    Pipeline p;
    std::vector<float> imp(p.specs.size(), 1.0f);
    for (size_t budget : {150u, 300u, 700u, 1300u, 4000u, 100000u}) {
        const EncodedFrame& f = p.enc.encode(5);
        std::vector<Pick> picks;
        size_t est = p.sched.select(f, p.assets, imp, budget, 30.0f, picks);
        std::vector<std::vector<uint8_t>> dgs;
        size_t wire = p.packer.pack(f, picks, p.seq, dgs);
        EXPECT_LE(wire, est) << "budget " << budget;
        EXPECT_LE(wire, budget) << "budget " << budget;
    }
}

TEST(NetPipeline, DelayedDisplayInterpolatesBetweenTicks) {
    Pipeline p(1);
    std::vector<float> imp(p.specs.size(), 1.0f);
    double worst_on_tick = 0;
    for (uint32_t t = 1; t <= 40; ++t) {
        p.tick(t, 1 << 20, imp);
        if (t < 5) continue;
        for (int i = 0; i < int(p.specs.size()); ++i) worst_on_tick = std::max(worst_on_tick, p.error(i, t - 3).second);
    }
    EXPECT_LT(worst_on_tick, kQuantisationMaxPct);
}

// Switching k back and forth: with blending, no vertex's error changes by
// much more between displayed frames than the error difference spread over
// the blend; without blending (n = 1) the switch is a pop.
static double largest_jump(int blend) {
    Pipeline p(blend);
    std::vector<float> imp(p.specs.size(), 1.0f);
    std::vector<std::vector<glm::vec3>> prev(p.specs.size());
    double jump = 0;
    for (uint32_t t = 1; t <= 90; ++t) {
        std::vector<Pick> picks;  // 3 bones, then all, every half second; every instance every tick
        for (int i = 0; i < int(p.specs.size()); ++i)
            picks.push_back({i, (t / 15) % 2 ? 3 : p.assets[p.specs[i].asset]->bone_count()});
        p.tick(t, 0, imp, &picks);
        for (int i = 0; i < int(p.specs.size()); ++i) {
            InstanceView& v = *p.views[i];
            if (!v.display(t)) continue;
            std::vector<glm::vec3> shown, ref;
            v.skin(shown);
            v.reference(v.clip().clip_time(t, 30.0), ref);
            if (!prev[i].empty())
                for (size_t j = 0; j < shown.size(); ++j)
                    jump = std::max(jump, 100.0 * glm::length((shown[j] - ref[j]) - prev[i][j]) / v.asset().diagonal);
            prev[i].resize(shown.size());
            for (size_t j = 0; j < shown.size(); ++j) prev[i][j] = shown[j] - ref[j];
        }
    }
    return jump;
}

TEST(NetPipeline, SwitchingBonesBlendsWithoutPops) {
    double hard = largest_jump(1), soft = largest_jump(8);
    std::printf("largest change of a vertex's error between frames: %.3f%% (no blend), %.3f%% (8-frame blend)\n", hard, soft);
    EXPECT_LT(soft, hard * 0.5);
}

// docs/metrics.md §4: within every tick, of two instances of the same asset playing
// the same clip, the more important one is never shown fewer bones.
// Deterministic (no sockets, no timing).
TEST(NetPipeline, MoreImportantInstancesGetAtLeastAsManyBonesEveryTick) {
    std::vector<InstanceSpec> layout = crowd_layout(shared_assets(), 6);
    for (size_t i = 0; i < layout.size(); ++i) layout[i].selection = 0;  // Fox: Survey; CesiumMan: its clips
    Pipeline p(8, layout);
    std::vector<float> imp(p.specs.size());
    for (size_t i = 0; i < imp.size(); ++i) imp[i] = 1.0f / float(i + 1);  // farther along the line
    int compared = 0;
    for (size_t budget : {300u, 600u, 1200u, 2500u}) {
        for (uint32_t t = 1; t <= 60; ++t) {
            const EncodedFrame& f = p.enc.encode(t);
            std::vector<Pick> picks;
            p.sched.select(f, p.assets, imp, budget, 30.0f, picks);
            p.sched.sent(picks, t);
            for (const Pick& a : picks)
                for (const Pick& b : picks) {
                    if (p.specs[a.instance].asset != p.specs[b.instance].asset ||
                        p.specs[a.instance].selection != p.specs[b.instance].selection || imp[a.instance] <= imp[b.instance])
                        continue;
                    EXPECT_GE(a.show, b.show) << "tick " << t << " budget " << budget << ": instance " << a.instance
                                        << " is more important than " << b.instance;
                    ++compared;
                }
        }
    }
    EXPECT_GT(compared, 50);
}

// Per-bone refresh (scheduler.h): at half the full rate the server sends a
// shorter prefix on most ticks and refreshes deep bones less often, and the
// client keeps showing them (Chunk.show), interpolated between their own frames.
TEST(NetPipeline, DeepBonesRefreshedLessOftenStayShown) {
    Pipeline p;
    const size_t n = p.specs.size();
    std::vector<float> imp(n, 1.0f);
    size_t full = 0;
    for (const auto& s : p.specs) full += WireCost::header(p.assets[s.asset]->bone_count()) + size_t(p.assets[s.asset]->bone_count()) * p.assets[s.asset]->format.size();
    const size_t budget = WireCost::wire(full) / 2;
    std::vector<double> sent(n, 0), picked(n, 0), displayed(n, 0), frames(n, 0);
    const int delay = 8;
    for (uint32_t t = 1; t <= 150; ++t) {
        const EncodedFrame& f = p.enc.encode(t);
        std::vector<Pick> picks;
        p.sched.select(f, p.assets, imp, budget, 30.0f, picks);
        std::vector<Pick> forced = picks;
        p.tick(t, 0, imp, &forced);  // the same picks through packer and client
        std::vector<int> sent_now(n, -1);
        for (const Pick& k : picks) {
            EXPECT_GE(k.show, k.k);
            EXPECT_LE(k.show, p.assets[p.specs[k.instance].asset]->bone_count());
            sent_now[size_t(k.instance)] = std::max(0, sent_now[size_t(k.instance)]) + k.k - k.first;
        }
        if (t > 40)
            for (size_t i = 0; i < n; ++i)
                if (sent_now[i] >= 0) {
                    sent[i] += sent_now[i];
                    picked[i] += 1;
                }
        if (t > 40)
            for (size_t i = 0; i < n; ++i)
                if (p.views[i]->display(double(t - delay))) {
                    displayed[i] += p.views[i]->target_bones();
                    frames[i] += 1;
                }
    }
    double more = 0;
    for (size_t i = 0; i < n; ++i) {
        ASSERT_GT(picked[i], 0) << "instance " << i;
        ASSERT_GT(frames[i], 0) << "instance " << i;
        std::printf("instance %zu: %.1f bones per update sent, %.1f displayed\n", i, sent[i] / picked[i], displayed[i] / frames[i]);
        EXPECT_GE(displayed[i] / frames[i] + 0.5, sent[i] / picked[i]) << "instance " << i;
        more += displayed[i] / frames[i] - sent[i] / picked[i];
    }
    EXPECT_GT(more / double(n), 0.5);  // deep bones stay shown between their refreshes (old scheduler: <= 0)
}
