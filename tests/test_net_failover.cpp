// test_net_failover.cpp — a Client given several servers (Client::connect's
// list, docs/protocol.md "Failover") loses its server and goes on with the
// next: real servers and sockets on loopback.
#include <gtest/gtest.h>

#include <thread>

#include "errors.h"
#include "net_test_support.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

namespace {

ClientConfig config(const std::string& name) {
    ClientConfig cfg;
    cfg.name = name;
    cfg.cache_dir = RunningServer::cache_dir();
    return cfg;
}

ServerAddress address(const RunningServer& s) { return {"127.0.0.1", s.server->tcp_port()}; }

// A player publishing the bind pose of a character of asset 0 (spawned
// once its catalogue is ready), and what it saw.
struct Publisher {
    Client client;
    int handle = -1;
    bool failed_over = false, ever_failed = false;
    std::vector<Mat34> skin;
    explicit Publisher(std::span<const ServerAddress> servers) : client(config("publisher")) { client.connect(servers); }
    void update() {
        const double now = now_seconds();
        client.update(now);
        for (const ClientEvent& e : client.events()) failed_over = failed_over || e.type == ClientEvent::Type::FailedOver;
        ever_failed = ever_failed || client.state() == ClientState::Failed;
        if (handle < 0 && client.state() == ClientState::Streaming && !client.assets().empty() && client.assets()[0]) {
            skin.assign(client.assets()[0]->character.joint_count(), Mat34::identity());
            SpawnSpec spec;
            spec.asset = 0;
            handle = client.spawn(spec);
        }
        if (handle >= 0) client.publish(handle, RootPose{}, skin);
    }
};

// Whether `observer` shows a character published by someone (the publisher).
bool shows_published(const Client& observer) {
    for (const RemoteCharacter& c : observer.characters())
        if (c.shown && c.publisher.published) return true;
    return false;
}

// Updates every client every 10 ms until done() or `seconds` pass; the time it took.
template <class Done>
double run_until(double seconds, Done done, Publisher& p, Client* observer) {
    const double start = now_seconds();
    while (now_seconds() - start < seconds) {
        p.update();
        if (observer) observer->update(now_seconds());
        if (done()) return now_seconds() - start;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return -1;
}

}  // namespace

// The publisher's server stops (its Goodbye): the publisher connects to the
// second server, spawns its character again, and an observer there sees it,
// within 3 s; the handle stays, the state never reads Failed.
TEST(NetFailover, PublisherMovesToTheNextServerWhenItsServerStops) {
    auto first = std::make_unique<RunningServer>();
    RunningServer second;
    const ServerAddress list[] = {address(*first), address(second)};
    Publisher p(list);
    Client observer(config("observer"));
    observer.connect("127.0.0.1", second.server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return p.handle >= 0 && p.client.instance_of(p.handle) >= 0; }, p, &observer), 0)
        << p.client.error();
    EXPECT_EQ(first->server->stats().sessions_active, 1u);

    first.reset();  // Goodbye "shutdown: ...", then the sockets close
    const double t = run_until(
        3.0, [&] { return p.failed_over && p.client.instance_of(p.handle) >= 0 && shows_published(observer); }, p, &observer);
    EXPECT_GE(t, 0) << "not streaming again within 3 s: " << p.client.error();
    EXPECT_TRUE(p.failed_over);
    EXPECT_FALSE(p.ever_failed) << p.client.error();
    EXPECT_EQ(p.client.state(), ClientState::Streaming);
    const ClientStats st = p.client.stats();
    EXPECT_EQ(st.failovers, 1);
    EXPECT_GT(st.failover_seconds, 0.0);
    EXPECT_LT(st.failover_seconds, 3.0);
    std::printf("failover: streaming again %.3f s after the server stopped; the observer saw the character after %.3f s\n",
                st.failover_seconds, t);
}

// A server of another catalogue is not the same world: the failover fails
// with that reason, not with a desynchronised scene.
TEST(NetFailover, AnotherCatalogueIsRefused) {
    auto first = std::make_unique<RunningServer>();
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    cfg.port = 0;
    const std::vector<std::shared_ptr<ServerAsset>> one{default_assets()[0]};
    Server other(cfg, one, default_instances(one));
    std::thread t([&] { other.run(); });
    const ServerAddress list[] = {address(*first), {"127.0.0.1", other.tcp_port()}};
    Publisher p(list);
    ASSERT_GE(run_until(10, [&] { return p.client.state() == ClientState::Streaming; }, p, nullptr), 0) << p.client.error();
    first.reset();
    run_until(5, [&] { return p.client.state() == ClientState::Failed; }, p, nullptr);
    EXPECT_EQ(p.client.state(), ClientState::Failed);
    EXPECT_EQ(p.client.fail_reason(), FailReason::BadServerData);
    EXPECT_NE(p.client.error().find("serves another catalogue"), std::string::npos) << p.client.error();
    other.stop();
    t.join();
}

// Each server is tried once per loss: with the only other one unreachable
// the client ends Failed, saying why, instead of cycling.
TEST(NetFailover, EveryServerTriedOnceThenFailed) {
    auto first = std::make_unique<RunningServer>();
    const ServerAddress list[] = {address(*first), {"127.0.0.1", 1}};
    Publisher p(list);
    ASSERT_GE(run_until(10, [&] { return p.client.state() == ClientState::Streaming; }, p, nullptr), 0) << p.client.error();
    first.reset();
    run_until(5, [&] { return p.client.state() == ClientState::Failed; }, p, nullptr);
    EXPECT_EQ(p.client.state(), ClientState::Failed);
    EXPECT_EQ(p.client.fail_reason(), FailReason::Unreachable) << p.client.error();
    EXPECT_NE(p.client.error().find("127.0.0.1:1"), std::string::npos) << p.client.error();
    EXPECT_EQ(p.client.stats().failovers, 1);
}

TEST(NetFailover, ServerListsAreParsedOrRefusedByName) {
    const auto l = parse_server_list("10.0.0.1:7777,[::1]:8000,host.example:1");
    ASSERT_EQ(l.size(), 3u);
    EXPECT_EQ(l[0].host, "10.0.0.1");
    EXPECT_EQ(l[0].port, 7777);
    EXPECT_EQ(l[1].host, "::1");
    EXPECT_EQ(l[1].port, 8000);
    EXPECT_EQ(l[2].host, "host.example");
    for (const char* bad : {"", "a", "a:", ":7", "a:0", "a:65536", "a:7,", "a:7,,b:8", "a:x7"}) {
        try {
            parse_server_list(bad);
            ADD_FAILURE() << "accepted '" << bad << "'";
        } catch (const Error& e) {
            EXPECT_NE(std::string(e.what()).find("is not HOST:PORT"), std::string::npos) << e.what();
        }
    }
}
