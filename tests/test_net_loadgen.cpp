// test_net_loadgen.cpp — progskin-loadgen's simulation (tools/loadgen.h)
// against real servers on loopback: 20 players on one node all see each
// other's characters, receive at a non-zero rate, measure latency and
// nobody starves; the JSON report has its fields; with a nats-server, 12
// players on a world of 2 nodes see each other across nodes (cross-node
// latency measured).
#include <gtest/gtest.h>

#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <nlohmann/json.hpp>
#include <thread>

#include "alloc_counter.h"  // the one source file of this executable that includes it
#include "loadgen.h"
#include "nats_test_support.h"
#include "net_test_support.h"
#include "run_command.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

namespace {

// A catalogue-only server (players bring the characters) on 127.0.0.1.
struct Node {
    std::unique_ptr<Server> server;
    std::thread thread;
    explicit Node(ServerConfig cfg = {}) {
        cfg.bind_address = "127.0.0.1";
        cfg.port = 0;
        if (cfg.threads == 0) cfg.threads = test_threads();
        server = std::make_unique<Server>(cfg, default_assets(), std::vector<InstanceSpec>{});
        thread = std::thread([this] { server->run(); });
    }
    ~Node() {
        server->stop();
        thread.join();
    }
    ServerAddress address() const { return {"127.0.0.1", server->tcp_port()}; }
};

LoadOptions options(std::vector<ServerAddress> servers, int players) {
    LoadOptions o;
    o.servers = std::move(servers);
    o.players = players;
    o.duration = 3;
    o.settle = 1;
    o.tls = false;
    o.cache_dir = RunningServer::cache_dir();
    o.progress_s = 0;
    o.asset = "1";  // CesiumMan (the bundled catalogue: Fox, CesiumMan)
    return o;
}

void expect_report_fields(const LoadReport& r, const LoadOptions& o) {
    const auto j = nlohmann::json::parse(report_json(r, o));
    for (const char* k : {"ok", "error", "players", "nodes", "joined", "failed", "rate_kbps", "bones", "nearest", "latency_ms",
                          "starved", "malformed", "poses", "loadgen"})
        EXPECT_TRUE(j.contains(k)) << k;
    for (const char* k : {"receipt", "display", "cross_node_receipt", "cross_node_display"}) {
        ASSERT_TRUE(j["latency_ms"].contains(k)) << k;
        EXPECT_TRUE(j["latency_ms"][k].contains("p50") && j["latency_ms"][k].contains("p99")) << k;
    }
    EXPECT_TRUE(j["starved"].contains("players"));
    EXPECT_EQ(j["players"], o.players);
    EXPECT_EQ(j["threads"], o.threads);
}

// The loadgen threads' allocations in the measurement window
// (alloc_counter.h counts per thread; each thread adds its count at the end).
std::atomic<long> window_allocations{0};
void count_window(bool start) {
    if (start) alloc_counter::allocations = 0;
    alloc_counter::counting = start;
    if (!start) window_allocations += alloc_counter::allocations;
}

// Twenty players all seeing each other, on `threads` threads.
void twenty_players(int threads) {
    Node node;
    LoadOptions o = options({node.address()}, 20);
    o.threads = threads;
    o.on_window = count_window;
    window_allocations = 0;
    const LoadReport r = run_loadgen(o);
    // Steady state: no allocation per player turn (reads, acks, poses, the sink).
    std::printf("loadgen, %d thread(s): %ld allocations in %llu player turns of the window\n", threads,
                window_allocations.load(), (unsigned long long)r.turns);
    EXPECT_EQ(r.threads, threads);
    EXPECT_GT(r.turns, 20u * 30u * 2u);
    EXPECT_EQ(window_allocations.load(), 0);
    SCOPED_TRACE(report_table(r, o));
    EXPECT_TRUE(r.ok) << r.error;
    EXPECT_EQ(r.joined, 20);
    EXPECT_EQ(r.failed, 0);
    EXPECT_EQ(r.see, 19);
    EXPECT_TRUE(r.all_seen);
    EXPECT_EQ(r.seen_min, 19);
    EXPECT_GT(r.rate_kbps_min, 0.0);
    EXPECT_LE(r.rate_kbps_max, 256.0 * 1.25);  // the players' cap
    EXPECT_GT(r.receipt_ms.samples, 100u);
    EXPECT_GT(r.receipt_ms.p50, 0.0);
    EXPECT_LT(r.receipt_ms.p99, 500.0);
    EXPECT_GT(r.display_ms.samples, 100u);
    EXPECT_GE(r.display_ms.p50, r.receipt_ms.p50);  // displayed after received
    EXPECT_EQ(r.cross_receipt_ms.samples, 0u);      // one node: nothing crosses
    EXPECT_EQ(r.starved_players, 0);
    EXPECT_EQ(r.pairs, 20u * 19u);
    EXPECT_GT(r.bones_mean, 0.0);
    EXPECT_GT(r.records, 0u);
    EXPECT_EQ(r.bad_records, 0u);
    EXPECT_EQ(r.malformed, 0u);
    EXPECT_GT(r.poses_sent, 20u * 30u);
    expect_report_fields(r, o);
}

TEST(NetLoadgen, TwentyPlayersOnOneNodeSeeEachOther) { twenty_players(1); }

// The same players split over three threads (players 0, 3, 6, ... on the
// first): every check of one thread holds, the counts of every thread are
// in the report, and no thread allocates per turn.
TEST(NetLoadgen, ThreeThreadsShareThePlayers) { twenty_players(3); }

TEST(NetLoadgen, ServerRefusalIsReportedNotHidden) {
    ServerConfig cfg;
    cfg.max_clients = 3;
    cfg.evict_after = 1e9;  // nobody is evicted to make room
    Node node(cfg);
    LoadOptions o = options({node.address()}, 6);
    o.connect_timeout = 3;
    const LoadReport r = run_loadgen(o);
    EXPECT_FALSE(r.ok);
    EXPECT_GE(r.failed, 1);
    EXPECT_GE(r.retried, r.failed);  // each refused player tried again before it counted as failed
    EXPECT_FALSE(r.errors.empty());
    EXPECT_FALSE(r.error.empty());
    expect_report_fields(r, o);
}

// Players refused at first (the server's new-connection rate per address:
// a bucket of 8, refilled at 1 per second; 12 players from one address)
// start again after a backoff, as game clients would: all join, none
// failed, the restarts counted. On two threads: each restarts its own.
TEST(NetLoadgen, RefusedPlayersStartAgainAndJoin) {
    ServerConfig cfg;
    cfg.connects_per_second = 1;
    Node node(cfg);
    LoadOptions o = options({node.address()}, 12);
    o.threads = 2;
    o.addresses = 1;
    o.retries = 5;  // 0.5 + 1 + 2 + 4 + 8 s of backoff at most: the bucket refills 4 in time
    o.connect_timeout = 5;
    const LoadReport r = run_loadgen(o);
    SCOPED_TRACE(report_table(r, o));
    EXPECT_TRUE(r.ok) << r.error;
    EXPECT_EQ(r.joined, 12);
    EXPECT_EQ(r.failed, 0);
    EXPECT_GE(r.retried, 4);  // at least the 4 beyond the bucket
    std::printf("12 players, 8 connections in the bucket: %d restarts, all joined in %.1f s\n", r.retried, r.join_seconds);
}

// The program: --help, exit 2 on bad arguments, a JSON report and exit 1
// when the server cannot be reached.
TEST(NetLoadgen, ProgramArgumentsAndReportOnFailure) {
    const std::string exe = std::string(PROGSKIN_BIN_DIR) + "/tools/progskin-loadgen";
    const CmdResult help = run(exe + " --help");
    EXPECT_EQ(help.code, 0);
    EXPECT_NE(help.out.find("--players"), std::string::npos);
    for (const char* bad : {"--players 0", "--players 4001", "--threads 0", "--threads 65", "--duration -1", "--bogus", "--report xml --no-tls",
                            "--server nohost --no-tls", "--players 2" /* TLS with nothing to trust */, "--no-tls --pin ab",
                            "--addresses 300 --no-tls", "--retries 11 --no-tls"}) {
        const CmdResult r = run(exe + " " + bad);
        EXPECT_EQ(r.code, 2) << bad << "\n" << r.out;
    }
    // Nothing listens on port 1: every player fails; the report says so.
    const CmdResult r = run("(" + exe + " --no-tls --server 127.0.0.1:1 --players 3 --duration 1 --connect-timeout 2 "
                                        "--progress 0 --report json 2>/dev/null)");
    EXPECT_EQ(r.code, 1);
    const auto j = nlohmann::json::parse(r.out);
    EXPECT_FALSE(j["ok"].get<bool>());
    EXPECT_FALSE(j["error"].get<std::string>().empty());
    EXPECT_EQ(j["failed"], 3);
}

TEST(NetLoadgen, WorldOfTwoNodesCrossNodeLatency) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server is not installed";
    NatsServer nats(free_port());
    const uint16_t port = nats.port();
    LoadReport r;
    LoadOptions o;
    {
        auto node_cfg = [&](const char* name) {
            ServerConfig cfg;
            cfg.nats_url = "nats://127.0.0.1:" + std::to_string(port);
            cfg.world_node = name;
            cfg.world_name = "loadgen" + std::to_string(::getpid());
            return cfg;
        };
        Node a(node_cfg("a")), b(node_cfg("b"));
        o = options({a.address(), b.address()}, 12);
        r = run_loadgen(o);
    }
    nats.stop();
    SCOPED_TRACE(report_table(r, o));
    EXPECT_TRUE(r.ok) << r.error;
    EXPECT_EQ(r.joined, 12);
    EXPECT_TRUE(r.all_seen);  // every player sees the 11 others, whatever their node
    EXPECT_GT(r.cross_receipt_ms.samples, 100u);
    EXPECT_GT(r.receipt_ms.samples, 100u);
    EXPECT_GT(r.cross_display_ms.samples, 100u);
    EXPECT_LT(r.cross_receipt_ms.p99, 1000.0);
    EXPECT_EQ(r.starved_players, 0);
    EXPECT_GT(r.rate_kbps_min, 0.0);
    expect_report_fields(r, o);
}

}  // namespace
