// test_net_world.cpp — one world across servers on a real nats-server
// (server/world_bus.h, docs/deployment.md): a player on one node is seen by
// a player on another; a node that stops takes its characters with it; a
// nats-server restart is survived; a node of another catalogue is refused.
#include <gtest/gtest.h>
#include <nats/nats.h>

#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <set>
#include <thread>

#include "errors.h"
#include "nats_test_support.h"
#include "net_test_support.h"
#include "server_core.h"
#include "tls_identity.h"
#include "world_bus.h"
#include "world_message.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

namespace {

ServerConfig node(const NatsServer& nats, const std::string& name) {
    ServerConfig cfg;
    cfg.nats_url = nats.url();
    cfg.world_node = name;
    cfg.world_name = "test" + std::to_string(::getpid());
    return cfg;
}

ClientConfig client_config(const std::string& name) {
    ClientConfig cfg;
    cfg.name = name;
    cfg.cache_dir = RunningServer::cache_dir();
    return cfg;
}

// A player publishing the bind pose of a character of asset 0 (identity
// skinning matrices) once its catalogue is ready.
struct Publisher {
    Client client;
    int handle = -1;
    double spawned_at = 0;  // Spawned (its instance known)
    std::vector<Mat34> skin;
    glm::dvec3 at{1.0, 0.0, 2.0};  // where it stands
    explicit Publisher(uint16_t port) : client(client_config("publisher")) { client.connect("127.0.0.1", port); }
    void update() {
        client.update(now_seconds());
        if (handle < 0 && client.state() == ClientState::Streaming && !client.assets().empty() && client.assets()[0]) {
            skin.assign(client.assets()[0]->character.joint_count(), Mat34::identity());
            SpawnSpec spec;
            spec.asset = 0;
            spec.position = glm::vec3(at);
            handle = client.spawn(spec);
        }
        if (handle >= 0 && spawned_at == 0 && client.instance_of(handle) >= 0) spawned_at = now_seconds();
        if (handle >= 0) client.publish(handle, RootPose{at}, skin);
    }
};

// The published character `observer` shows, or nullptr.
const RemoteCharacter* published(const Client& observer) {
    for (const RemoteCharacter& c : observer.characters())
        if (c.shown && c.publisher.published) return &c;
    return nullptr;
}

template <class Done>
double run_until(double seconds, Done done, Publisher* p, Client& observer) {
    const double start = now_seconds();
    while (now_seconds() - start < seconds) {
        if (p) p->update();
        observer.update(now_seconds());
        if (done()) return now_seconds() - start;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return -1;
}

// Largest difference of a shown palette from the identity (the bind pose published).
double off_identity(const RemoteCharacter& c) {
    double worst = 0;
    for (const Mat34& m : c.palette)
        for (int i = 0; i < 12; ++i) worst = std::max(worst, double(std::abs(m.m[i] - Mat34::identity().m[i])));
    return worst;
}

// Another node of the world as the test's own libnats peer: publishes n
// messages of one player's character (node id `node`, asset 0) to cell 0.0
// at once, message t (1..n) with the bind pose raised t x rise, standing at
// `at`. False when the connection or a publish fails.
bool flood_cell(const NatsServer& nats, const std::string& world, uint16_t node, int n, float rise, glm::dvec3 at) {
    natsConnection* nc = nullptr;
    if (natsConnection_ConnectTo(&nc, nats.url().c_str()) != NATS_OK) return false;
    const ServerAssets& assets = default_assets();  // the nodes' catalogue
    const ServerAsset& asset = *assets[0];
    // The bind pose raised: every bone's skinning matrix a translation (the
    // records the encoder codes for it, as the other node's would be).
    InstanceSpec live;
    live.asset = 0;
    live.selection = -1;
    FrameEncoder enc(assets, {live}, 30.0f);
    WorldCharacter c;
    bool ok = true;
    std::vector<uint8_t> bytes;
    const std::string subject = "progskin." + world + ".cell.0.0";
    for (int t = 1; t <= n && ok; ++t) {
        Mat34 m = Mat34::identity();
        m.m[7] = rise * float(t);
        ok = enc.push_pose(0, std::vector<Mat34>(asset.character.joint_count(), m)) &&
             world_character(enc.encode(uint32_t(t)), 0, RootPose{at}, c);
        c.id = 9;
        c.world_id = (uint64_t(node) << 40) | 9u;
        c.published = true;
        if (ok) {
            std::array<uint8_t, ROOT_BYTES> root{};
            ok = encode_root(RootPose{at}, root.data());
            c.root = root;
        }
        write_world_message(WorldHeader{node, catalogue_hash(assets), uint32_t(t)}, std::span(&c, 1), assets, bytes);
        ok = ok && natsConnection_Publish(nc, subject.c_str(), bytes.data(), int(bytes.size())) == NATS_OK;
    }
    ok = ok && natsConnection_Flush(nc) == NATS_OK;
    natsConnection_Destroy(nc);
    return ok;
}

}  // namespace

// A player on node B is seen by a player on node A within 1 s of its spawn,
// as published, at full detail; B stops: gone on A within 2 s.
TEST(NetWorld, PlayersOnTwoNodesSeeEachOther) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    RunningServer a({}, node(nats, "alpha"));
    auto b = std::make_unique<RunningServer>(std::vector<InstanceSpec>{}, node(nats, "beta"));
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    Publisher p(b->server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return p.spawned_at > 0; }, &p, observer), 0) << p.client.error();
    const double seen = run_until(3, [&] { return published(observer) != nullptr; }, &p, observer);
    ASSERT_GE(seen, 0) << "not seen across nodes: " << observer.error();
    const double after_spawn = now_seconds() - p.spawned_at;
    EXPECT_LT(after_spawn, 1.0);
    // Full detail at unlimited rate: the bind pose within the quantisation step.
    run_until(1.0, [] { return false; }, &p, observer);
    const RemoteCharacter* rc = published(observer);
    ASSERT_NE(rc, nullptr);
    EXPECT_EQ(rc->bones, rc->asset->skin.bone_count());
    // Quantised twice: the published record (half a translation step) and
    // the frame stream's relative record (its dead zone, 1.5 steps); the bus
    // adds nothing (its records are the stream's).
    const glm::vec3 extent = rc->asset->format.t_max - rc->asset->format.t_min;
    const double t_step = double(std::max({extent.x, extent.y, extent.z})) / 65535.0;
    EXPECT_LT(off_identity(*rc), 2e-3 + 2.0 * t_step);
    EXPECT_NEAR(rc->root.position.x, 1.0, 1e-3);
    EXPECT_NEAR(rc->root.position.z, 2.0, 1e-3);
    // B's four clip characters are on A too, as the server's own (not published).
    EXPECT_EQ(observer.characters().size(), 4u + 4u + 1u);
    // One id across the world: the publisher's character has on A the world
    // id B gave it (the publisher sees it as its own instance on B).
    EXPECT_NE(rc->world_id, 0u);
    std::set<uint64_t> ids;
    for (const RemoteCharacter& c : observer.characters()) ids.insert(c.world_id);
    EXPECT_EQ(ids.size(), observer.characters().size()) << "world ids are distinct";
    EXPECT_EQ(ids.count(0), 0u);
    Client b_observer(client_config("b-observer"));
    b_observer.connect("127.0.0.1", b->server->tcp_port());
    run_until(3, [&] { return published(b_observer) != nullptr; }, &p, b_observer);
    const RemoteCharacter* on_b = published(b_observer);
    ASSERT_NE(on_b, nullptr);
    EXPECT_EQ(on_b->world_id, published(observer)->world_id) << "one character, one world id on both nodes";
    // Seen across the bus as on its own node: the same records, so the same
    // palette (the pose is still), up to the float rounding of the two
    // clients' interpolations at their own display times (5.7e-6 seen):
    // far under a translation step of the records, where the bus's absolute
    // records of version 2 put a foreign character up to 6 steps off.
    const RemoteCharacter* on_a = published(observer);
    ASSERT_EQ(on_a->palette.size(), on_b->palette.size());
    double apart = 0;
    for (size_t j = 0; j < on_a->palette.size(); ++j)
        for (int k = 0; k < 12; ++k) apart = std::max(apart, double(std::abs(on_a->palette[j].m[k] - on_b->palette[j].m[k])));
    const double step = double(on_a->asset->format.t_step > 0 ? on_a->asset->format.t_step : float(t_step));
    EXPECT_LT(apart, 0.02 * step) << "node A shows the character " << apart << " away from its own node (step " << step << ")";
    const ServerStats st = a.server->stats();
    EXPECT_GT(st.world_messages_in, 0u);
    EXPECT_EQ(st.world_malformed, 0u);
    EXPECT_EQ(st.world_foreign, 5);
    std::printf("seen on the other node %.3f s after its spawn; %llu bus messages, %llu bytes in on A\n", after_spawn,
                (unsigned long long)st.world_messages_in, (unsigned long long)st.world_bytes_in);

    b.reset();  // node B stops: its characters leave A's scene
    const double gone = run_until(4, [&] { return observer.characters().size() == 4u; }, nullptr, observer);
    EXPECT_GE(gone, 0) << observer.characters().size() << " characters left";
    EXPECT_LT(gone, 2.0);
    std::printf("node B stopped: its characters gone from A after %.3f s\n", gone);
}

// TLS everywhere (docs/deployment.md): a nats-server that requires TLS and
// verifies its clients' certificates. Nodes with its CA and their own
// certificate form one world (a player on B seen on A); a node without a
// certificate, or trusting another CA, is refused at start with the reason.
TEST(NetWorld, TlsToTheBus) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    const std::string dir = RunningServer::cache_dir() + "/nats-tls-" + std::to_string(::getpid());
    const TlsIdentity bus_id = ensure_self_signed(dir + "/bus");
    // The nodes' client certificate (extended key usage clientAuth, which the
    // development identity's serverAuth certificate is not).
    TlsIdentity node_id;
    node_id.cert_path = dir + "/node-cert.pem";
    node_id.key_path = dir + "/node-key.pem";
    const std::string make = "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 2 -subj /CN=node"
                             " -addext extendedKeyUsage=clientAuth -keyout " + node_id.key_path + " -out " +
                             node_id.cert_path + " >/dev/null 2>&1";
    ASSERT_EQ(std::system(make.c_str()), 0) << make;
    NatsServer nats(free_port(), {"--tlsverify", "--tlscert", bus_id.cert_path, "--tlskey", bus_id.key_path, "--tlscacert",
                                  node_id.cert_path});
    const std::string url = "tls://127.0.0.1:" + std::to_string(nats.port());
    auto tls_node = [&](const std::string& name) {
        ServerConfig cfg = node(nats, name);
        cfg.nats_url = url;
        cfg.nats_ca_file = bus_id.cert_path;
        cfg.nats_cert_file = node_id.cert_path;
        cfg.nats_key_file = node_id.key_path;
        return cfg;
    };
    const std::vector<std::shared_ptr<ServerAsset>> assets = default_assets();
    auto refused = [&](ServerConfig cfg) -> std::string {
        cfg.bind_address = "127.0.0.1";
        try {
            Server s(cfg, assets, {});
        } catch (const Error& e) {
            return e.what();
        }
        return "";
    };
    ServerConfig no_cert = tls_node("no-cert");
    no_cert.nats_cert_file.clear();
    no_cert.nats_key_file.clear();
    const std::string no_cert_why = refused(no_cert);
    EXPECT_NE(no_cert_why.find("cannot join " + url), std::string::npos) << no_cert_why;
    ServerConfig other_ca = tls_node("other-ca");
    other_ca.nats_ca_file = node_id.cert_path;
    const std::string why = refused(other_ca);
    EXPECT_NE(why.find("SSL"), std::string::npos) << why;
    EXPECT_NE(why.find("--nats-ca"), std::string::npos) << why;
    ServerConfig plain = node(nats, "plain");  // nats:// to a server that requires TLS: refused, not retried
    const std::string plain_why = refused(plain);
    EXPECT_NE(plain_why.find("cannot join"), std::string::npos) << plain_why;

    RunningServer a({}, tls_node("alpha"));
    RunningServer b(std::vector<InstanceSpec>{}, tls_node("beta"));
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    Publisher p(b.server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return p.spawned_at > 0; }, &p, observer), 0) << p.client.error();
    const double seen = run_until(3, [&] { return published(observer) != nullptr; }, &p, observer);
    EXPECT_GE(seen, 0) << "not seen across nodes over TLS: " << observer.error();
    EXPECT_GT(a.server->stats().world_messages_in, 0u);
    std::filesystem::remove_all(dir);
}

// A node behind the bus: another node's 200 messages of one cell arrive
// between two of its ticks; it takes only the newest of them (each holds
// the sender's whole cell), counts the rest as superseded, and shows the
// character at the newest message's pose. Every message is accounted for.
TEST(NetWorld, ABehindNodeTakesTheNewestMessageOfEachCell) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    const ServerConfig cfg = node(nats, "alpha");
    RunningServer a({}, cfg);
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return observer.characters().size() == 4u; }, nullptr, observer), 0) << observer.error();
    // A subscribes to the cells (interest, every 0.1 s); the subscription
    // reaches nats-server asynchronously.
    run_until(1.0, [] { return false; }, nullptr, observer);

    // The bind pose raised 0.05 t by message t: the newest is the last (0.05
    // is far over the records' translation step, so that the newest tells
    // itself from the one before).
    const int n = 200;
    const float rise = 0.05f;
    ASSERT_TRUE(flood_cell(nats, cfg.world_name, 4242, n, rise, glm::dvec3(1.0, 0.0, 1.0)));
    const double seen = run_until(3, [&] { return published(observer) != nullptr; }, nullptr, observer);
    ASSERT_GE(seen, 0) << "the flooding node's character not shown";
    run_until(0.5, [] { return false; }, nullptr, observer);
    const ServerStats st = a.server->stats();
    EXPECT_EQ(st.world_messages_in + st.world_superseded + st.world_dropped, uint64_t(n)) << "every message accounted for";
    EXPECT_GT(st.world_superseded, uint64_t(n) / 2) << "most were behind a newer one: " << st.world_messages_in << " taken";
    EXPECT_EQ(st.world_malformed, 0u);
    // Shown at the newest pose (200 rises up), not an older one.
    const RemoteCharacter* rc = published(observer);
    ASSERT_NE(rc, nullptr);
    EXPECT_NEAR(rc->palette[0].m[7], double(n) * rise, 0.4 * rise);
    std::printf("%llu of %d messages taken, %llu superseded, %llu dropped\n", (unsigned long long)st.world_messages_in, n,
                (unsigned long long)st.world_superseded, (unsigned long long)st.world_dropped);
}

// WorldBus::before_tick, which the tick thread calls right before
// ServerCore::tick: what it takes from the bus goes out with that very tick
// (the foreign character's pose is in the tick's encode), so a pose from
// another node waits for one tick of this node, not two. Driven by hand as
// server.cpp drives it, against a real nats-server.
TEST(NetWorld, WhatBeforeTickTakesGoesWithThatTick) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    const ServerConfig cfg = node(nats, "alpha");
    ServerCore core(cfg, default_assets(), {});
    // One welcomed client without a view: the node follows every cell.
    auto s = core.open(PeerAddress::v4(0x7f000001, 0), now_seconds());
    ASSERT_TRUE(s->on_control(hello(), now_seconds()));
    WorldBus bus(WorldConfig{cfg.nats_url, "", "", "", cfg.world_node, cfg.world_name, cfg.world_cell, cfg.world_queue}, core);
    DatagramCollector sink;
    // As server.cpp's tick: the bus, then the core's tick under its lock.
    // True when before_tick took a message.
    auto tick = [&] {
        const uint64_t before = bus.stats().messages_in;
        bus.before_tick(now_seconds());
        const bool took = bus.stats().messages_in > before;
        std::lock_guard lock(core.mutex());
        core.tick(now_seconds(), sink);
        return took;
    };
    const double t0 = now_seconds();
    while (!(bus.stats().connected && bus.stats().cells == -1) && now_seconds() - t0 < 10) {
        tick();
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ASSERT_EQ(bus.stats().cells, -1) << "the node follows every cell";
    for (int k = 0; k < 30; ++k) {  // the subscription reaches nats-server asynchronously
        tick();
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    const glm::dvec3 at(1.0, 0.0, 2.0);
    ASSERT_TRUE(flood_cell(nats, cfg.world_name, 4242, 1, 0.05f, at));
    bool taken = false;
    for (const double t1 = now_seconds(); !taken && now_seconds() - t1 < 5;) {
        taken = tick();
        if (!taken) {
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
            continue;
        }
        // The tick right after: the character is in its encode, posed by it.
        const EncodedFrame& f = core.encoder().frame();
        int shown = 0;
        for (const EncodedInstance& e : f.instances) {
            if (!e.valid) continue;
            ++shown;
            EXPECT_EQ(e.changed_tick, f.tick) << "the pose taken before the tick is this tick's content";
            EXPECT_NEAR(e.world.x, at.x, 1e-3);
            EXPECT_NEAR(e.world.z, at.z, 1e-3);
        }
        EXPECT_EQ(shown, 1) << "the foreign character encoded by the tick after before_tick took it";
    }
    ASSERT_TRUE(taken) << "the message never reached the node";
    EXPECT_EQ(bus.stats().foreign, 1);
}

// A NATS server with a user and password (nats://USER:PASSWORD@HOST:PORT,
// as libnats reads it): a node with them joins; one with a wrong password is
// refused at start; no log or error shows the password.
TEST(NetWorld, CredentialsInTheUrlAndNeverInTheLogs) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    EXPECT_EQ(redact_nats_url("nats://node:s3cret@10.0.0.1:4222,tls://tok@10.0.0.2:4222,nats://10.0.0.3:4222"),
              "nats://***@10.0.0.1:4222,tls://***@10.0.0.2:4222,nats://10.0.0.3:4222");
    NatsServer nats(free_port(), {"--user", "node", "--pass", "s3cret-pw"});
    ServerConfig good = node(nats, "alpha");
    good.nats_url = "nats://node:s3cret-pw@127.0.0.1:" + std::to_string(nats.port());
    ServerConfig bad = good;
    bad.nats_url = "nats://node:wrong-pw@127.0.0.1:" + std::to_string(nats.port());
    bad.bind_address = "127.0.0.1";
    std::string why;
    try {
        Server s(bad, default_assets(), {});
    } catch (const Error& e) {
        why = e.what();
    }
    EXPECT_NE(why.find("cannot join nats://***@127.0.0.1"), std::string::npos) << why;
    EXPECT_EQ(why.find("wrong-pw"), std::string::npos) << why;
    RunningServer a({}, good);
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return observer.characters().size() == 4u; }, nullptr, observer), 0) << observer.error();
    run_until(1.5, [] { return false; }, nullptr, observer);
    EXPECT_GT(a.server->stats().world_messages_out, 0u) << "the node publishes on the bus it joined";
}

// A node so far behind that its bus queue overflows follows fewer cells
// (the nearest to its clients' view first) until it keeps up, then grows
// back: 3,000 messages flood a cell near the observer at once into a queue
// of 64 (ServerConfig::world_queue; with the default 1,024 a node that
// drains every tick may keep up with nats-server's delivery on a loaded
// machine, and nothing overflows); the node sheds the farthest half of the
// 196 cells its observer wants, keeps the flooded (nearest) one, and
// follows all of them again within seconds.
TEST(NetWorld, ABehindNodeFollowsFewerCellsThenAllAgain) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    ServerConfig cfg = node(nats, "alpha");
    cfg.view_radius = 100.0;  // 14 x 14 cells of 16 around the camera
    cfg.world_queue = 64;
    RunningServer a({}, cfg);
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    ViewSpec v;
    v.has_camera = true;
    v.camera = glm::vec3(1.0f, 1.5f, 1.0f);
    observer.set_view(v);
    ASSERT_GE(run_until(10, [&] { return a.server->stats().world_cells == 196; }, nullptr, observer), 0)
        << a.server->stats().world_cells << " cells";
    // The node's subscriptions reach nats-server asynchronously: give them
    // time to be in place before the flood (else it goes to nobody).
    run_until(1.0, [] { return false; }, nullptr, observer);

    ASSERT_TRUE(flood_cell(nats, cfg.world_name, 4343, 3000, 0.0f, glm::dvec3(2.0, 0.0, 2.0)));
    int fewest = 196, most_shed = 0;
    run_until(1.0, [&] {
        const ServerStats st = a.server->stats();
        fewest = std::min(fewest, st.world_cells);
        most_shed = std::max(most_shed, st.world_cells_shed);
        return false;
    }, nullptr, observer);
    const ServerStats st = a.server->stats();
    EXPECT_EQ(st.world_messages_in + st.world_superseded + st.world_dropped, 3000u) << "every message accounted for";
    EXPECT_GT(st.world_dropped, 0u) << "the flood overflowed the bus queue";
    EXPECT_GT(most_shed, 0) << "a node behind sheds cells";
    EXPECT_LE(fewest, 98) << "the farthest half shed";
    EXPECT_NE(published(observer), nullptr) << "the flooded cell, the nearest, is still followed";
    const double back = run_until(8, [&] { return a.server->stats().world_cells == 196; }, nullptr, observer);
    EXPECT_GE(back, 0) << "all 196 cells followed again; now " << a.server->stats().world_cells;
    std::printf("flood: %llu dropped, %llu superseded, cells down to %d (%d shed), all 196 again %.1f s later\n",
                (unsigned long long)st.world_dropped, (unsigned long long)st.world_superseded, fewest, most_shed, back);
}

// Interest management (ServerConfig::view_radius): node A subscribes only to
// the cells near its observer's camera. A player on B standing 1.4 km away
// is not on A; the observer moves its camera there: shown within 1 s; back:
// gone again (its cell unsubscribed after the linger, the character after
// the foreign timeout).
TEST(NetWorld, InterestFollowsTheObserversView) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    ServerConfig ca = node(nats, "alpha"), cb = node(nats, "beta");
    ca.view_radius = cb.view_radius = 30.0;
    RunningServer a({}, ca);
    RunningServer b({}, cb);
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    ViewSpec home;
    home.has_camera = true;
    home.camera = glm::vec3(0.0f, 1.5f, -5.0f);
    observer.set_view(home);
    Publisher p(b.server->tcp_port());
    p.at = glm::dvec3(1000.0, 0.0, 1000.0);
    ASSERT_GE(run_until(10, [&] { return p.spawned_at > 0; }, &p, observer), 0) << p.client.error();
    EXPECT_LT(run_until(1.5, [&] { return published(observer) != nullptr; }, &p, observer), 0)
        << "a player 1.4 km from the observer's camera reached node A";
    ServerStats st = a.server->stats();
    EXPECT_GT(st.world_cells, 0) << "A subscribes to the cells around its observer";
    EXPECT_LE(st.world_cells, 25) << "(30 m around one camera: at most 5 x 5 cells of 16 m)";
    ViewSpec there = home;
    there.camera = glm::vec3(1000.0f, 1.5f, 990.0f);
    observer.set_view(there);
    const double seen = run_until(3, [&] { return published(observer) != nullptr; }, &p, observer);
    EXPECT_GE(seen, 0) << "the camera moved to the player: not shown";
    EXPECT_LT(seen, 1.0);
    observer.set_view(home);
    const double gone = run_until(8, [&] { return published(observer) == nullptr; }, &p, observer);
    EXPECT_GE(gone, 0) << "the camera went home: the far player still shown";
    st = a.server->stats();
    EXPECT_GT(st.world_cells, 0);
    std::printf("interest: far player shown %.3f s after the camera moved to it, gone %.3f s after it left; %d cells now\n",
                seen, gone, st.world_cells);
}

// nats-server dies and comes back on the same port: the nodes reconnect and
// the cross-node character is shown again within 3 s; A's own never stop.
TEST(NetWorld, NatsServerRestartSurvived) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    RunningServer a({}, node(nats, "alpha"));
    RunningServer b({}, node(nats, "beta"));
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    Publisher p(b.server->tcp_port());
    ASSERT_GE(run_until(10, [&] { return published(observer) != nullptr; }, &p, observer), 0);
    nats.stop();
    // Without the bus the foreign characters leave; A's own stream on.
    EXPECT_GE(run_until(4, [&] { return published(observer) == nullptr; }, &p, observer), 0);
    EXPECT_EQ(observer.state(), ClientState::Streaming);
    EXPECT_GE(observer.characters().size(), 4u);
    nats.start();
    const double back = run_until(6, [&] { return published(observer) != nullptr; }, &p, observer);
    EXPECT_GE(back, 0) << "cross-node streaming did not resume";
    EXPECT_LT(back, 3.0);
    EXPECT_TRUE(a.server->stats().world_connected);
    std::printf("nats-server restarted: cross-node character shown again after %.3f s\n", back);
}

// A node serving another catalogue: its messages are refused and counted,
// none of its characters enter the world.
TEST(NetWorld, AnotherCatalogueIsRefused) {
    if (!have_nats_server()) GTEST_SKIP() << "nats-server not installed (apt-get install nats-server)";
    NatsServer nats(free_port());
    RunningServer a({}, node(nats, "alpha"));
    ServerConfig cfg = node(nats, "other");
    cfg.bind_address = "127.0.0.1";
    const std::vector<std::shared_ptr<ServerAsset>> one{default_assets()[0]};
    Server other(cfg, one, default_instances(one));
    std::thread t([&] { other.run(); });
    Client observer(client_config("observer"));
    observer.connect("127.0.0.1", a.server->tcp_port());
    run_until(2, [] { return false; }, nullptr, observer);
    const ServerStats st = a.server->stats();
    EXPECT_GT(st.world_refused, 0u);
    EXPECT_EQ(st.world_foreign, 0);
    EXPECT_EQ(observer.characters().size(), 4u);  // A's own only
    other.stop();
    t.join();
}

// The bus message (world_message.h): what is written reads back; every cut,
// an extra byte, a wrong bone count or clip, another catalogue: refused whole.
TEST(WorldMessage, RoundTripAndEveryMalformedMessageRefused) {
    const ServerAssets& assets = default_assets();
    InstanceSpec running;
    running.asset = 0;
    running.selection = 0;
    FrameEncoder enc(assets, {running}, 30.0f);
    const EncodedFrame& frame = enc.encode(7);
    WorldCharacter c;
    ASSERT_TRUE(world_character(frame, 0, RootPose{}, c));
    c.id = 7;
    c.world_id = 0x123456000010007ull;
    c.epoch = 3;
    c.published = true;
    const std::vector<uint8_t> records(c.records.begin(), c.records.end());
    c.clips = {0};
    c.publisher_start_us = 123456789;
    c.walk_radius = 2.5;
    std::vector<uint8_t> bytes;
    const WorldHeader h0{42, catalogue_hash(assets), 1000};
    write_world_message(h0, std::span(&c, 1), assets, bytes);
    WorldHeader h;
    std::vector<WorldCharacter> got;
    ASSERT_EQ(read_world_message(bytes, assets, h, got), "");
    ASSERT_EQ(got.size(), 1u);
    EXPECT_EQ(h.node, 42);
    EXPECT_EQ(h.tick, 1000u);
    EXPECT_EQ(got[0].id, 7);
    EXPECT_EQ(got[0].world_id, 0x123456000010007ull);
    EXPECT_EQ(got[0].epoch, 3);
    EXPECT_TRUE(got[0].published);
    EXPECT_TRUE(std::equal(records.begin(), records.end(), got[0].records.begin(), got[0].records.end()));
    ASSERT_EQ(got[0].ints.size(), size_t(assets[0]->bone_count()));
    const RecordInts* sent = frame.ints.data();  // slot 0's integers
    for (int b = 0; b < assets[0]->bone_count(); ++b) {
        EXPECT_TRUE(std::equal(sent[b].rot, sent[b].rot + 3, got[0].ints[size_t(b)].rot)) << "bone " << b;
        EXPECT_TRUE(std::equal(sent[b].trans, sent[b].trans + 3, got[0].ints[size_t(b)].trans)) << "bone " << b;
        EXPECT_EQ(sent[b].has_trans, got[0].ints[size_t(b)].has_trans) << "bone " << b;
    }
    EXPECT_EQ(got[0].clips, std::vector<int>{0});
    EXPECT_EQ(got[0].publisher_start_us, 123456789u);
    EXPECT_EQ(got[0].walk_radius, 2.5);
    for (size_t n = 0; n < bytes.size(); ++n)
        EXPECT_NE(read_world_message(std::span(bytes).first(n), assets, h, got), "") << "cut at " << n;
    std::vector<uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_NE(read_world_message(longer, assets, h, got).find("after the last character"), std::string::npos);
    std::vector<uint8_t> bad = bytes;
    bad[4 + 2 + 2 + 8 + 4 + 2 + 2 + 8 + 2 + 1 + 1 + 1] ^= 1;  // the bone count (after id, world id, asset, epoch, flags, sample)
    EXPECT_NE(read_world_message(bad, assets, h, got).find("bones"), std::string::npos);
    bad = bytes;
    std::fill_n(bad.begin() + 4 + 2 + 2 + 8 + 4 + 2 + 2, 8, uint8_t(0));  // the world id
    EXPECT_NE(read_world_message(bad, assets, h, got).find("world id"), std::string::npos);
    // The records: a byte more than they fill (a zero byte left over), or
    // more bytes than any records of that many bones take.
    constexpr size_t kRecordBytesAt = 4 + 2 + 2 + 8 + 4 + 2 + 2 + 8 + 2 + 1 + 1 + 1 + 1;
    const size_t record_bytes = size_t(bytes[kRecordBytesAt]) | size_t(bytes[kRecordBytesAt + 1]) << 8;
    ASSERT_EQ(record_bytes, records.size());
    bad = bytes;
    bad[kRecordBytesAt] = uint8_t(record_bytes + 1);
    bad[kRecordBytesAt + 1] = uint8_t((record_bytes + 1) >> 8);
    bad.insert(bad.begin() + long(kRecordBytesAt + 2 + ROOT_BYTES + record_bytes), uint8_t(0));
    EXPECT_NE(read_world_message(bad, assets, h, got).find("records out of bounds"), std::string::npos);
    bad = bytes;
    bad[kRecordBytesAt] = bad[kRecordBytesAt + 1] = 0xff;
    EXPECT_NE(read_world_message(bad, assets, h, got).find("bytes of records"), std::string::npos);
    write_world_message({42, catalogue_hash(assets) ^ 1, 1000}, std::span(&c, 1), assets, bytes);
    EXPECT_EQ(read_world_message(bytes, assets, h, got), "another catalogue");
    c.clips = {999};
    write_world_message(h0, std::span(&c, 1), assets, bytes);
    EXPECT_NE(read_world_message(bytes, assets, h, got).find("clip 999"), std::string::npos);
}

// A character from another node streams as it would from this one: its
// records go on the bus as the sending encoder coded them, and the node
// that takes them (push_relative, as WorldBus does) codes the same integers
// at every bone and tick. Every character of the default scene, clips that
// move every bone (the Fox running, CesiumMan walking), 90 ticks, sampled
// at their keys as progskin-server does (the sample byte goes along).
TEST(WorldMessage, AForeignCharacterCodesToTheSenderIntegers) {
    const ServerAssets& assets = default_assets();
    const std::vector<InstanceSpec> scene = default_instances(assets);
    std::vector<InstanceSpec> live = scene;
    for (InstanceSpec& s : live) s.selection = -1;
    FrameEncoder sender(assets, scene, 30.0f), taker(assets, live, 30.0f);
    sender.set_key_samples(true);  // as progskin-server: linearly keyed clips sampled at their keys
    std::vector<uint8_t> bytes;
    std::vector<WorldCharacter> got;
    size_t compared = 0, differing = 0, message_bytes = 0, absolute_bytes = 0, record_bytes = 0, keyed = 0;
    for (uint32_t t = 1; t <= 90; ++t) {
        const EncodedFrame& f = sender.encode(t);
        std::vector<WorldCharacter> chars(scene.size());
        for (size_t i = 0; i < scene.size(); ++i) {
            ASSERT_TRUE(world_character(f, int(i), RootPose{glm::dvec3(scene[i].position)}, chars[i]));
            chars[i].world_id = 1 + i;
        }
        write_world_message({1, catalogue_hash(assets), t}, chars, assets, bytes);
        message_bytes += bytes.size();
        absolute_bytes += bytes.size();  // the same message with version 2's absolute records
        for (const WorldCharacter& c : chars) {
            absolute_bytes += size_t(f.instances[c.id].bone_count * f.instances[c.id].record_size) - c.records.size() - 2;
            record_bytes += c.records.size();
        }
        WorldHeader h;
        ASSERT_EQ(read_world_message(bytes, assets, h, got), "");
        for (const WorldCharacter& c : got)
            ASSERT_TRUE(taker.push_relative(c.id, t, c.epoch, 0, c.ints, c.root, c.morphs, c.sample)) << "tick " << t;
        const EncodedFrame& g = taker.encode(t);
        for (size_t i = 0; i < scene.size(); ++i) {
            const int B = f.instances[i].bone_count;
            ASSERT_EQ(g.instances[i].bone_count, B);
            const RecordInts* a = f.ints.data() + i * f.ring_bones;  // slot i's integers
            const RecordInts* b = g.ints.data() + i * g.ring_bones;
            for (int k = 0; k < B; ++k, ++compared) {
                const bool same = std::equal(a[k].rot, a[k].rot + 3, b[k].rot) && std::equal(a[k].trans, a[k].trans + 3, b[k].trans) &&
                                  a[k].scale == b[k].scale && a[k].has_trans == b[k].has_trans && a[k].has_scale == b[k].has_scale;
                differing += !same;
            }
            EXPECT_EQ(f.record_bits(int(i), 0, B), g.record_bits(int(i), 0, B)) << "tick " << t << " instance " << i;
            EXPECT_EQ(f.instances[i].sample, g.instances[i].sample) << "tick " << t << " instance " << i;  // the key's time
            keyed += f.instances[i].sample != 0;
            if (f.instances[i].flags & CHUNK_ROOT) {
                EXPECT_EQ(f.instances[i].root, g.instances[i].root) << "tick " << t;
            } else {  // a node's clip instance stands at its spec's place; the bus carries it in the root block
                EXPECT_LT(glm::length(decode_root(g.instances[i].root.data()).position - glm::dvec3(scene[i].position)), 1e-3);
            }
        }
    }
    EXPECT_EQ(differing, 0u) << "of " << compared << " bone records";
    EXPECT_GT(keyed, 0u) << "some poses were sampled at a key before their tick";
    std::printf("%zu bone records over 90 ticks, %zu differ; %.0f bytes a message (%.0f with absolute records), %.1f of them records\n",
                compared, differing, double(message_bytes) / 90, double(absolute_bytes) / 90, double(record_bytes) / 90);
}
