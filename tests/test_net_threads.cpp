// test_net_threads.cpp — the server on several threads (ServerConfig::threads,
// progskin-server --threads; docs/protocol.md "Threads"): the tick pool
// itself, then real servers at 2 and 4 tick threads with several real
// clients on loopback (TLS with sealed datagrams, and plain at unlimited
// rate), every client streaming exactly as it does from one thread. Run
// under ThreadSanitizer by scripts/tsan.sh.
#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>
#include <thread>

#include "error_metric.h"
#include "errors.h"
#include "net_test_support.h"
#include "server_core.h"
#include "thresholds.h"
#include "tick_pool.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using namespace progskin::thresholds;

TEST(NetThreads, PoolRunsEveryThreadOncePerRun) {
    TickPool pool(4);
    ASSERT_EQ(pool.threads(), 4);
    std::vector<int> calls(4, 0);  // each slot written by one thread only
    for (int run = 0; run < 200; ++run) {
        auto job = [&](int w) { ++calls[size_t(w)]; };
        pool.run(job);
    }
    for (int w = 0; w < 4; ++w) EXPECT_EQ(calls[size_t(w)], 200) << w;
    auto failing = [](int w) {
        if (w == 2) throw std::runtime_error("worker 2");
    };
    EXPECT_THROW(pool.run(failing), std::runtime_error);
    std::atomic<int> after{0};
    auto again = [&](int) { ++after; };
    pool.run(again);  // still serving after an exception
    EXPECT_EQ(after.load(), 4);
    EXPECT_THROW(TickPool(0), Error);
    EXPECT_THROW(TickPool(TickPool::kMaxThreads + 1), Error);
}

TEST(NetThreads, BadThreadCountsAreRefused) {
    ServerConfig cfg;
    cfg.threads = -1;
    EXPECT_THROW(ServerCore(cfg, default_assets(), {}), Error);
    cfg.threads = TickPool::kMaxThreads + 1;
    EXPECT_THROW(ServerCore(cfg, default_assets(), {}), Error);
    cfg.threads = 0;
    EXPECT_GE(tick_threads(cfg), 1);
    cfg.threads = 3;
    EXPECT_EQ(tick_threads(cfg), 3);
}

// The tick's sessions spread over the pool give every session the same
// datagrams as ticking them one after another on one thread.
TEST(NetThreads, PoolTicksMatchOneThread) {
    const auto specs = crowd_layout(default_assets(), 40);
    ServerCore one(ServerConfig{}, default_assets(), specs), many(ServerConfig{}, default_assets(), specs);
    TickPool pool(3);
    many.set_pool(&pool);
    std::vector<std::unique_ptr<ClientStream>> a, b;
    std::vector<ClientStream*> pa, pb;
    for (int c = 0; c < 13; ++c) {
        for (auto* core : {&one, &many}) {
            auto& list = core == &one ? a : b;
            list.push_back(ClientStream::detached(*core, uint64_t(c + 1), 64.0 + 40.0 * c));
            ViewSpec v;
            v.has_camera = true;
            v.camera = specs[size_t(c) % specs.size()].position + glm::vec3(0, 0, 300);
            list.back()->set_view(v);
        }
        pa.push_back(a.back().get());
        pb.push_back(b.back().get());
    }
    struct Counting final : DatagramSink {
        std::atomic<uint64_t> n{0}, bytes{0};
        void send(std::span<const uint8_t> d, const PeerAddress&) override {
            ++n;
            bytes += d.size();
        }
    } sa, sb;
    for (uint32_t t = 1; t <= 30; ++t) {
        const TickResult ra = one.tick_streams(pa, one.encoder().encode(t), t / 30.0, 1.0 / 30.0, sa);
        const TickResult rb = many.tick_streams(pb, many.encoder().encode(t), t / 30.0, 1.0 / 30.0, sb);
        EXPECT_EQ(ra.datagrams, rb.datagrams) << "tick " << t;
        EXPECT_EQ(ra.wire_bytes, rb.wire_bytes) << "tick " << t;
        for (size_t c = 0; c < pa.size(); ++c) {
            EXPECT_EQ(pa[c]->seq(), pb[c]->seq()) << "client " << c;
            ASSERT_EQ(pa[c]->picks().size(), pb[c]->picks().size()) << "client " << c << " tick " << t;
        }
    }
    EXPECT_EQ(sa.n.load(), sb.n.load());
    EXPECT_EQ(sa.bytes.load(), sb.bytes.load());
    EXPECT_GT(sa.n.load(), 0u);
}

namespace {

// n clients at once against `s`, each with `base` (its duration, checks).
std::vector<ClientReport> run_clients(const RunningServer& s, int n, ClientOptions base) {
    std::vector<ClientReport> reports(static_cast<size_t>(n));
    std::vector<std::string> errors(static_cast<size_t>(n));
    std::vector<std::thread> ts;
    for (int i = 0; i < n; ++i)
        ts.emplace_back([&, i] {
            ClientOptions o = base;
            o.port = s.server->tcp_port();
            try {
                reports[size_t(i)] = run_client(o);
            } catch (const std::exception& e) {
                errors[size_t(i)] = e.what();
            }
        });
    for (auto& t : ts) t.join();
    for (int i = 0; i < n; ++i) EXPECT_TRUE(errors[size_t(i)].empty()) << "client " << i << ": " << errors[size_t(i)];
    return reports;
}

}  // namespace

// Two tick threads, TLS control channels and sealed datagrams: six clients
// at once all stream every character, interpolated within the usual bound.
TEST(NetThreads, TwoThreadsStreamToSeveralTlsClients) {
    ServerConfig cfg;
    cfg.threads = 2;
    cfg.tls_cert_file = std::string(PROGSKIN_TEST_DATA) + "/tls/test_cert.pem";
    cfg.tls_key_file = std::string(PROGSKIN_TEST_DATA) + "/tls/test_key.pem";
    cfg.seal_datagrams = true;
    RunningServer s({}, cfg);
    ClientOptions o = s.client(2.5);
    o.tls = true;
    o.ca_file = cfg.tls_cert_file;
    o.verify = true;
    o.display_rate = 60;
    const std::vector<ClientReport> reports = run_clients(s, 6, o);
    for (const ClientReport& r : reports) {
        EXPECT_EQ(r.characters, 4);
        EXPECT_EQ(r.malformed, 0u);
        EXPECT_GT(r.datagrams, 30u);
        for (const auto& i : r.instances) EXPECT_GE(i.frames, 20u) << i.asset;  // 1.5 s after the warm-up: 45 at 30 Hz
        EXPECT_LT(r.rms_pct, kInterpolatedRmsPct);
    }
    const ServerStats st = s.server->stats();
    EXPECT_EQ(st.sessions_total, 6u);
    EXPECT_EQ(st.handler_errors, 0u);
    EXPECT_EQ(st.tls_failures, 0u);
    EXPECT_EQ(st.malformed_datagrams, 0u);  // (a late Bind retry's ChallengeResponse may be rejected: not a fault)
}

// Four tick threads (more than this machine may have cores), plain, at
// unlimited rate and snapped to ticks: every bone of every character, only
// quantisation error, at each of eight clients.
TEST(NetThreads, FourThreadsDeliverAllBonesToEightClients) {
    ServerConfig cfg;
    cfg.threads = 4;
    RunningServer s({}, cfg);
    ClientOptions o = s.client(2.0);
    o.verify = true;
    o.snap_to_ticks = true;
    const std::vector<ClientReport> reports = run_clients(s, 8, o);
    double bound_pct = 0;
    for (const auto& a : default_assets())
        bound_pct = std::max(bound_pct, 100.0 * quantisation_bound(a->format, a->bind_radius, a->max_scale) / rest_diagonal(a->character));
    for (const ClientReport& r : reports) {
        ASSERT_EQ(r.instances.size(), 4u);
        for (const auto& i : r.instances) {
            const auto& a = *default_assets()[i.asset == "Fox.glb" ? 0 : 1];
            EXPECT_EQ(i.bones_min, a.bone_count()) << i.asset;
        }
        EXPECT_EQ(r.malformed, 0u);
        EXPECT_LE(r.max_pct, bound_pct);
    }
    EXPECT_EQ(s.server->stats().handler_errors, 0u);
}
