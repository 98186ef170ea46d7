// test_net_bandwidth.cpp — bandwidth-limited playback on loopback: the
// measured rate (docs/metrics.md §3) never above the cap by more than 5% in any one
// second, error non-increasing as the cap grows, closer characters get at
// least as many bones, the adaptive estimate backs off on a slow link, and
// loss + reordering + duplication (link_emulator.h) cause no harm.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <filesystem>

#include "link_emulator.h"
#include "net_test_support.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using namespace progskin::thresholds;

TEST(NetBandwidth, CapsFrom16kTo2MRespectedAndErrorFallsWithRate) {
    // 24 instances: the full rate is about 1.1 Mbit/s with standalone
    // records and less predicted, so the top cap need not limit.
    const auto layout = crowd_layout(default_assets(), 24);
    double full_bones = 0;  // mean bones of the layout's characters
    for (const auto& spec : layout) full_bones += double(default_assets()[size_t(spec.asset)]->bone_count()) / double(layout.size());
    RunningServer s(layout);
    const std::vector<double> caps = {16, 64, 256, 1000, 2000};
    std::vector<ClientReport> r(caps.size());
    std::vector<std::thread> ts;
    for (size_t i = 0; i < caps.size(); ++i)
        ts.emplace_back([&, i] {
            ClientOptions o = s.client(5.0);
            o.max_kbps = caps[i];
            o.verify = true;
            o.verify_every = 3;
            r[i] = run_client(o);
        });
    for (auto& t : ts) t.join();
    for (size_t i = 0; i < caps.size(); ++i) {
        std::printf("cap %6.0f: rate %7.1f (max 1 s %7.1f) kbit/s, bones %.1f, RMS %.4f%% max %.4f%%\n", caps[i],
                    r[i].rate_kbps, r[i].rate_max_kbps, r[i].bones_mean, r[i].rms_pct, r[i].max_pct);
        ASSERT_GE(r[i].per_second_kbps.size(), 3u);
        for (double k : r[i].per_second_kbps) EXPECT_LE(k, caps[i] * 1.05) << "cap " << caps[i];
        // The cap is used, or it does not limit: every bone shown at a lower rate.
        if (r[i].rate_kbps <= caps[i] * 0.6) {
            EXPECT_GE(r[i].bones_mean, full_bones - 0.3) << "cap " << caps[i] << " poorly used";
        }
        EXPECT_EQ(r[i].characters, 24);
        // Non-increasing within 5 % while the cap limits the error; once the
        // previous cap already reached the floor where every bone goes
        // (kStreamFloorRmsPct: interpolation between ticks at the display
        // times of five verifying clients and a server sharing two cores, which
        // moves with the load: 1000 and 2000 kbit/s alone gave 0.045 and
        // 0.042 %), the next stays on it.
        if (i > 0) {
            if (r[i - 1].rms_pct > kStreamFloorRmsPct)
                EXPECT_LE(r[i].rms_pct, r[i - 1].rms_pct * 1.05 + 0.002) << "cap " << caps[i];
            else
                EXPECT_LE(r[i].rms_pct, kStreamFloorRmsPct) << "cap " << caps[i];
        }
    }
}

TEST(NetBandwidth, CloserCharactersGetAtLeastAsManyBones) {
    auto inst = crowd_layout(default_assets(), 8);
    const float spacing = float(default_assets()[0]->diagonal);
    for (size_t i = 0; i < inst.size(); ++i) {
        inst[i].asset = 0;  // all Fox, walking, along a line
        inst[i].selection = 1;
        inst[i].position = glm::vec3(0, 0, float(i + 1) * spacing * 2.0f);
    }
    RunningServer s(inst);
    // 8 s: the far characters' averages sit near one hull step (12 bones)
    // and a 4 s run on a loaded machine moved them by up to 2 bones.
    ClientOptions o = s.client(8.0);
    o.max_kbps = 96;
    o.view.has_camera = true;
    o.view.camera = glm::vec3(0, 0, 0);
    o.send_view = true;
    ClientReport r = run_client(o);
    ASSERT_EQ(r.instances.size(), inst.size());
    for (size_t i = 0; i < inst.size(); ++i) {
        std::printf("instance %zu at %.0f: %.2f bones\n", i, double(inst[i].position.z), r.instances[i].bones_mean);
        // Time averages move in hull steps (e.g. 12 -> 20 bones for the Fox): one bone of slack.
        if (i > 0) {
            EXPECT_GE(r.instances[i - 1].bones_mean + 1.0, r.instances[i].bones_mean) << "instance " << i;
        }
        // (Within each tick the order is exact: NetPipeline.MoreImportantInstances...;
        // time averages over a loaded machine's ticks get one bone of slack.)
        if (i > 1) {
            EXPECT_GE(r.instances[i - 2].bones_mean + 1.0, r.instances[i].bones_mean) << "instance " << i;
        }
    }
    EXPECT_GT(r.instances[0].bones_mean, r.instances.back().bones_mean + 3.0);
}

namespace {

// A 4 s verifying client of s through a relay emulating a 10 % lossy link
// (10 ms delay, 5 ms jitter; reordering and duplication as given), its
// counts in *ls.
ClientReport run_lossy(const RunningServer& s, double reorder_and_duplicate, uint64_t seed, LinkStats& ls) {
    LinkConfig lc;
    lc.loss = 0.10;
    lc.reorder = reorder_and_duplicate;
    lc.duplicate = reorder_and_duplicate;
    lc.delay_ms = 10;
    lc.jitter_ms = 5;
    lc.seed = seed;
    LinkEmulator link(lc, "127.0.0.1", s.server->udp_port());
    link.start();
    ClientOptions o = s.client(4.0);
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = link.port();
    o.verify = true;
    ClientReport r = run_client(o);
    link.stop();
    ls = link.stats();
    return r;
}

}  // namespace

TEST(NetBandwidth, LossReorderingAndDuplicationDoNoHarm) {
    RunningServer s;
    LinkStats ls;
    ClientReport r = run_lossy(s, 0.10, 42, ls);
    std::printf("loss %.3f, duplicates %llu, RMS %.4f%% max %.4f%%, link: %llu dropped %llu reordered %llu duplicated\n",
                r.loss, (unsigned long long)r.duplicates, r.rms_pct, r.max_pct, (unsigned long long)ls.dropped,
                (unsigned long long)ls.reordered, (unsigned long long)ls.duplicated);
    EXPECT_GT(ls.dropped, 0u);
    EXPECT_EQ(r.characters, 4);
    // What the relay dropped, less what went again in time: repairs
    // (RepairsFillTheLostTicks) usually leave nothing missing.
    EXPECT_LT(r.loss, 0.25);
    EXPECT_GT(r.duplicates, 0u);
    EXPECT_EQ(r.malformed, 0u);
    // Records are predicted from acknowledged frames only: lost, reordered
    // and duplicated datagrams never leave a record without its baseline.
    std::printf("predicted records %llu, missing baselines %llu\n", (unsigned long long)r.predicted_records,
                (unsigned long long)r.missing_baselines);
    EXPECT_GT(r.predicted_records, 0u);
    EXPECT_EQ(r.missing_baselines, 0u);
    for (double k : r.per_second_kbps) EXPECT_GT(k, 50.0);  // the stream keeps flowing every second
    EXPECT_LT(r.rms_pct, kLossyLinkRmsPct);
}

// ServerConfig::repair_lost: on the lossy link above (the same seeded
// relay), a datagram an Ack shows lost goes once more while its tick can
// still be displayed, so the client misses far fewer datagrams than with
// repairs off (measured: 0.024 against 0.112 of the sequence numbers).
TEST(NetBandwidth, RepairsFillTheLostTicks) {
    auto run = [](bool repair, uint64_t& repaired, double& dropped) {
        ServerConfig cfg;
        cfg.repair_lost = repair;
        RunningServer s({}, cfg);
        LinkStats ls;
        const ClientReport r = run_lossy(s, 0.0, 7, ls);
        repaired = s.server->stats().datagrams_repaired;
        dropped = double(ls.dropped) / double(std::max<uint64_t>(1, ls.dropped + ls.forwarded));
        std::printf("repair %s: the relay dropped %.3f, the client saw %.3f missing, %llu repaired, RMS %.4f%% max %.4f%%\n",
                    repair ? "on" : "off", dropped, r.loss, (unsigned long long)repaired, r.rms_pct, r.max_pct);
        EXPECT_EQ(r.missing_baselines, 0u);
        return r;
    };
    uint64_t repaired_on = 0, repaired_off = 0;
    double dropped_on = 0, dropped_off = 0;
    const ClientReport on = run(true, repaired_on, dropped_on);
    const ClientReport off = run(false, repaired_off, dropped_off);
    EXPECT_GT(repaired_on, 0u);
    EXPECT_EQ(repaired_off, 0u);
    ASSERT_GT(dropped_on, 0.03);
    ASSERT_GT(dropped_off, 0.03);
    EXPECT_LT(on.loss, 0.5 * off.loss) << "repairs filled fewer than half of the missing datagrams";
}

TEST(NetBandwidth, EstimateBacksOffOnASlowLink) {
    RunningServer s;
    LinkConfig lc;
    lc.rate_kbps = 100;  // the link, not the client's cap, limits
    lc.queue_ms = 150;
    LinkEmulator link(lc, "127.0.0.1", s.server->udp_port());
    link.start();
    ClientOptions o = s.client(6.0);
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = link.port();
    o.max_kbps = 2000;
    ClientReport r = run_client(o);
    link.stop();
    std::printf("slow link: rate %.1f kbit/s, loss %.3f, estimate %.1f kbit/s, rtt %.1f ms\n", r.rate_kbps, r.loss,
                r.estimate_kbps, r.rtt_ms);
    EXPECT_EQ(r.characters, 4);
    EXPECT_LT(r.estimate_kbps, 400.0);
    EXPECT_GT(r.rate_kbps, 40.0);
}

// progskin-netem --tcp: the control channel (handshake, asset download) goes
// through the relay too and shares its rate cap, so downloading the assets
// over a capped link takes at least their bits / rate.
TEST(NetBandwidth, ControlChannelThroughTheRelay) {
    RunningServer s;
    LinkConfig lc;
    lc.rate_kbps = 4000;
    lc.delay_ms = 20;
    LinkEmulator link(lc, "127.0.0.1", s.server->udp_port());
    link.relay_tcp(s.server->tcp_port());
    link.start();
    ClientOptions o = s.client(2.0);
    o.port = link.port();  // TCP to the relay, not the server
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = link.port();
    const auto cache = std::filesystem::temp_directory_path() / ("progskin-relay-cache-" + std::to_string(::getpid()));
    std::filesystem::remove_all(cache);
    o.cache_dir = cache.string();  // empty: every asset is downloaded through the relay
    const auto t0 = std::chrono::steady_clock::now();
    ClientReport r = run_client(o);
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    link.stop();
    std::filesystem::remove_all(cache);
    const LinkStats ls = link.stats();
    const double download_s = double(r.asset_bytes_downloaded) * 8.0 / (lc.rate_kbps * 1000.0);
    std::printf("relay: %llu TCP connection(s), %llu bytes to the client (%llu of assets), wall %.2f s, download %.2f s "
                "(at the cap >= %.2f s), rtt %.1f ms\n",
                (unsigned long long)ls.tcp_connections, (unsigned long long)ls.tcp_bytes_down,
                (unsigned long long)r.asset_bytes_downloaded, wall, r.download_seconds, download_s, r.rtt_ms);
    EXPECT_EQ(r.characters, 4);
    EXPECT_EQ(r.malformed, 0u);
    EXPECT_GT(r.asset_bytes_downloaded, 100000u);
    EXPECT_GE(ls.tcp_connections, 1u);
    EXPECT_GE(ls.tcp_bytes_down, r.asset_bytes_downloaded);  // the assets came through the relay
    EXPECT_GT(ls.tcp_bytes_up, 0u);
    EXPECT_GE(r.download_seconds, 0.95 * download_s);  // and at no more than the cap (streaming meanwhile)
    EXPECT_GE(wall, o.duration);
    EXPECT_GT(ls.forwarded, 0u);                       // the frame stream went through it as before
}
