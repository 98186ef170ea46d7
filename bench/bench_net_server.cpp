// bench_net_server.cpp — server tick cost per client and per character.
//
// BM_ClientTick: the per-client part of a tick (ClientStream::tick: the
// importance of each character from the client's view, scheduler selection
// under the client's byte budget, packing datagrams by copying pre-encoded
// records; a detached stream: fixed rate, unsealed, nothing sent), for 100
// characters, at several caps. BM_ServerTick200x100: one whole tick of 200
// clients x 100 characters without sockets (encode once + 200 x
// ClientStream::tick; second argument 1: every client acknowledges its
// datagrams before the next tick, so records go predicted and the clients
// share the coding of each (character, baseline)). BM_Loopback200Clients: a real Server on loopback with 200
// lightweight clients (Hello, UDP Bind, Acks; no display) for 5 s: mean tick
// time, the server thread's CPU time per client, and the datagrams, bytes
// and rate each client received; its 4th argument 1 runs every session over
// TLS (a self-signed pair from server/tls_identity.h) with sealed datagrams,
// its 5th is the server's tick threads (ServerConfig::threads).
// BM_PublishingPlayers: players publishing their own characters, at 1 or
// more tick threads (CPU per player per tick, scaling).
#include <benchmark/benchmark.h>
#include <poll.h>
#include <sys/socket.h>
#include <pthread.h>
#include <time.h>

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <filesystem>
#include <thread>

#include "crypto.h"
#include "tls_identity.h"

#include "client_stream.h"
#include "frame_encoder.h"
#include "scene.h"
#include "server.h"
#include "server_core.h"
#include "tick_pool.h"
#include "wire.h"
#include "datagram_generated.h"  // the digest reads the frames

using namespace progskin;
using namespace progskin::net;

static std::vector<std::shared_ptr<ServerAsset>>& assets() {
    static std::vector<std::shared_ptr<ServerAsset>> a = {load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
                                                          load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    return a;
}

// PROGSKIN_BENCH_DIGEST=1: ClientTick and PublishingPlayers print, on
// stderr, an FNV-1a digest of the frames they sent in their first ticks
// (tick, chunks, payload: not the clock's send time), so that a change
// meant to make the tick cheaper can be shown to send the same frames:
// compare two builds' digests once both ran past the ticks it covers
// (60 for ClientTick, 20 for PublishingPlayers: more iterations than that).
static const bool g_digest_on = std::getenv("PROGSKIN_BENCH_DIGEST") != nullptr;
static uint64_t g_digest = 0;
static bool g_hash_on = false;  // the current tick is one the digest covers
static void digest_begin() { g_digest = 1469598103934665603ull; }
static void digest_end(const benchmark::State& st) {
    if (g_digest_on) std::fprintf(stderr, "digest %016llx iterations %lld\n", (unsigned long long)g_digest, (long long)st.iterations());
}
static void digest_add(const void* p, size_t n) {
    for (size_t i = 0; i < n; ++i) g_digest = (g_digest ^ static_cast<const uint8_t*>(p)[i]) * 1099511628211ull;
}

// A sink that drops what it is given: the ticks' cost without sockets.
struct NoSockets final : DatagramSink {
    void send(std::span<const uint8_t> d, const PeerAddress&) override {
        if (!g_digest_on || !g_hash_on) return;
        FrameDatagram f;
        if (!read_frame_datagram(d, f)) return;
        const uint32_t tick = f.tick;
        digest_add(&tick, sizeof tick);
        if (!f.payload.empty()) digest_add(f.payload.data(), f.payload.size());
    }
};

static void BM_ClientTick(benchmark::State& st) {
    digest_begin();
    const int n = 100;
    const double kbps = double(st.range(0));
    const bool acked = st.range(1) != 0;  // the client acknowledges every datagram before the next tick
    ServerCore core(ServerConfig{}, assets(), crowd_layout(assets(), n));
    auto client = ClientStream::detached(core, 1, kbps);
    ViewSpec view;
    view.has_camera = true;
    client->set_view(view);
    NoSockets sink;
    uint32_t tick = 0;
    size_t bytes = 0, dgrams = 0;
    for (auto _ : st) {
        st.PauseTiming();
        const EncodedFrame& f = core.encoder().encode(++tick);
        st.ResumeTiming();
        g_hash_on = tick <= 60;
        const TickResult r = client->tick(f, tick / 30.0, 1.0 / 30.0, sink);
        if (acked && r.datagrams > 0) client->acknowledge(client->next_seq() - 1, ~0u);
        bytes += r.wire_bytes;
        dgrams += r.datagrams;
    }
    digest_end(st);
    st.counters["kbps_sent"] = benchmark::Counter(double(bytes) * 8 / 1000 / (double(st.iterations()) / 30.0));
    st.counters["datagrams_per_tick"] = double(dgrams) / double(st.iterations());
    st.SetLabel(acked ? "100 characters, per client per tick, acknowledged (records predicted; this client codes each baseline first)"
                      : "100 characters, per client per tick, never acknowledged (standalone records)");
}
BENCHMARK(BM_ClientTick)->ArgsProduct({{64, 256, 1000, 4000, 20000}, {0, 1}})->Unit(benchmark::kMicrosecond);

static void BM_ServerTick200x100(benchmark::State& st) {
    const int n = 100, clients = 200;
    const double kbps = double(st.range(0));
    const bool acked = st.range(1) != 0;  // each client acknowledges its datagrams before the next tick
    auto specs = crowd_layout(assets(), n);
    ServerCore core(ServerConfig{}, assets(), specs);
    std::vector<std::unique_ptr<ClientStream>> client;
    for (int c = 0; c < clients; ++c) {
        client.push_back(ClientStream::detached(core, uint64_t(c + 1), kbps));
        ViewSpec v;
        v.has_camera = true;
        v.camera = specs[size_t(c) % specs.size()].position + glm::vec3(0, 0, 300);
        client.back()->set_view(v);
    }
    NoSockets sink;
    uint32_t tick = 0;
    double busy = 0;
    for (auto _ : st) {
        const double t0 = now_seconds();
        const EncodedFrame& f = core.encoder().encode(++tick);
        for (auto& c : client) {
            const TickResult r = c->tick(f, tick / 30.0, 1.0 / 30.0, sink);
            if (acked && r.datagrams > 0) c->acknowledge(c->next_seq() - 1, ~0u);
        }
        busy += now_seconds() - t0;
    }
    st.counters["core_load_at_30Hz"] = busy / double(st.iterations()) * 30.0;
    st.SetLabel(acked ? "encode 100 + 200 clients select/pack (no sockets), acknowledged: records predicted, each (character, baseline) coded once for the clients that share it; core_load = tick time x 30 Hz"
                      : "encode 100 + 200 clients select/pack (no sockets), never acknowledged; core_load = tick time x 30 Hz");
}
BENCHMARK(BM_ServerTick200x100)->ArgsProduct({{256, 1000}, {0, 1}})->Unit(benchmark::kMillisecond);

// CPU seconds of this thread / of every thread of this process (a shared
// machine's other load does not count).
static double thread_seconds() {
    timespec ts;
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
static double process_seconds() {
    timespec ts;
    ::clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// Players' characters (live poses published by their owners): one tick of
// a server with P players, each owning one character and watching the
// others. Per tick: every player's newest pose arrives (the server's checks
// on a Pose datagram: every record decodes to a valid rotation, then
// push_records), the frame is encoded once, then per player its importance
// (its view, its own character excluded), selection and packing.
// mode 0: everyone sees everyone alike (no view) at 1 Mbit/s each; mode 1:
// players spread over a 2 km world, each viewing from its own character
// (far characters cheap), 256 kbit/s each; mode 2: as mode 1, each player
// weighing only the nearest 100 characters (ServerConfig::max_candidates 100);
// mode 3: as mode 2, each player acknowledging its datagrams before the next
// tick, as real players do (records go predicted from its own baselines);
// mode 4: as mode 3 on a server that sends standalone records
// (progskin-server --standalone-records: more bytes per bone, no plan).
// Third argument: tick threads (ServerConfig::threads; the per-player part
// spread over a TickPool by ServerCore::tick_streams, as in the server; the
// poses and the encoding stay on this thread). core_load_at_30Hz: the
// process's CPU time (every thread) per tick x 30; players_per_core = P /
// load (at this P); cpu_us_per_player_tick: CPU per player per tick;
// wall_ms_per_tick: elapsed time per tick (what threads shorten). Timed
// from tick kWarmTicks + 1 on (the digest covers ticks 1-20 all the same).
// Players' characters: n live instances (no clip), alternately of the two
// assets, player p + 1 owning instance p.
static std::vector<InstanceSpec> players_characters(int n) {
    std::vector<InstanceSpec> specs;
    for (int p = 0; p < n; ++p) {
        InstanceSpec s;
        s.asset = p % 2;
        s.selection = -1;
        s.owner = uint64_t(p + 1);
        specs.push_back(s);
    }
    return specs;
}

// A player's pose source: per asset, 30 frames of its first clip as the
// records a publisher sends.
static std::vector<std::vector<std::vector<uint8_t>>> published_poses() {
    std::vector<std::vector<std::vector<uint8_t>>> poses(2);
    for (int a = 0; a < 2; ++a) {
        const ServerAsset& as = *assets()[size_t(a)];
        std::vector<glm::dmat4> m(as.character.joint_count());
        for (int f = 0; f < 30; ++f) {
            sample_skinning_matrices(as.character, as.selections[0], as.selections[0].start + f / 30.0 * as.selections[0].duration(), m);
            std::vector<uint8_t> rec(size_t(as.bone_count()) * size_t(as.format.size()));
            for (int b = 0; b < as.bone_count(); ++b)
                encode_bone(decompose(Mat34::from_glm(m[size_t(as.skin.order[size_t(b)])])), as.format,
                            rec.data() + size_t(b) * size_t(as.format.size()));
            poses[size_t(a)].push_back(std::move(rec));
        }
    }
    return poses;
}

static constexpr int kWarmTicks = 45;
static void BM_PublishingPlayers(benchmark::State& st) {
    digest_begin();
    const int players = int(st.range(0));
    const int mode = int(st.range(1));
    const bool views = mode != 0;
    const bool acked = mode >= 3;
    const int threads = std::max(1, int(st.range(2)));
    const double kbps = views ? 256 : 1000;
    const std::vector<InstanceSpec> specs = players_characters(players);
    ServerConfig cfg;
    if (mode >= 2) cfg.max_candidates = 100;
    if (mode == 4) cfg.predict_records = false;  // progskin-server --standalone-records
    ServerCore core(cfg, assets(), specs);
    TickPool pool(threads);
    core.set_pool(&pool);
    FrameEncoder& enc = core.encoder();
    // Each player's pose source: its asset's clip, sampled as a publisher does.
    const auto poses = published_poses();  // per asset, 30 frames of records
    std::vector<glm::dvec3> where(static_cast<size_t>(players));
    std::vector<std::unique_ptr<ClientStream>> client;  // player p's session (id p + 1: never sent its own)
    for (int p = 0; p < players; ++p) {
        const double ang = 2.399963 * p, r = views ? 1000.0 * std::sqrt((p + 0.5) / players) : 0.0;
        where[size_t(p)] = glm::dvec3(r * std::cos(ang), 0.0, r * std::sin(ang));
        client.push_back(ClientStream::detached(core, uint64_t(p + 1), kbps));
        ViewSpec v;
        if (views) {
            v.has_camera = true;
            v.camera = glm::vec3(where[size_t(p)]);
        }
        client.back()->set_view(v);
    }
    std::vector<ClientStream*> streams;
    for (auto& c : client) streams.push_back(c.get());
    std::vector<uint32_t> seq_before(client.size());
    NoSockets sink;
    std::array<uint8_t, ROOT_BYTES> root{};
    uint32_t tick = 0;
    double busy = 0, sent = 0, wall = 0, weighed = 0, encoding = 0, bones = 0;
    auto one_tick = [&](bool timed) {
        const double t0 = process_seconds(), w0 = now_seconds();
        ++tick;
        for (int p = 0; p < players; ++p) {
            const auto& rec = poses[size_t(p % 2)][(tick + uint32_t(p)) % 30];
            const RecordFormat& fmt = assets()[size_t(p % 2)]->format;
            bool ok = true;
            for (size_t r = 0; r < rec.size(); r += size_t(fmt.size())) ok = ok && record_valid(rec.data() + r, fmt);
            RootPose rp;
            rp.position = where[size_t(p)];
            encode_root(rp, root.data());
            if (ok) enc.push_records(p, tick, 0, 0, rec, root);
        }
        const EncodedFrame& f = enc.encode(tick);
        const double t_encoded = process_seconds();
        g_hash_on = tick <= 20;
        if (acked)
            for (size_t p = 0; p < client.size(); ++p) seq_before[p] = client[p]->next_seq();
        const double bytes = double(core.tick_streams(streams, f, tick / 30.0, 1.0 / 30.0, sink).wire_bytes);
        // Mode 3: each player acknowledges what it was sent before the next tick (records go predicted).
        if (acked)
            for (size_t p = 0; p < client.size(); ++p)
                if (client[p]->next_seq() != seq_before[p]) client[p]->acknowledge(client[p]->next_seq() - 1, ~0u);
        if (!timed) return;
        sent += bytes;
        busy += process_seconds() - t0;
        encoding += t_encoded - t0;
        wall += now_seconds() - w0;
        for (const ClientStream* c : streams) {
            weighed += double(c->weighed());
            for (const Pick& pk : c->picks()) bones += double(std::max(0, pk.k - pk.first));
        }
    };
    // The steady state: the first ticks send every character whole, and an
    // acknowledging player's records go predicted only once its first
    // acknowledgements are past BaselineBook::kGraceTicks and its bones'
    // baselines span the ages a refresh period takes: kWarmTicks untimed first.
    for (int k = 0; k < kWarmTicks; ++k) one_tick(false);
    for (auto _ : st) one_tick(true);
    const double ticks = double(st.iterations());
    const double load = busy / ticks * 30.0;
    st.counters["core_load_at_30Hz"] = load;
    digest_end(st);
    st.counters["players_per_core"] = double(players) / load;
    st.counters["cpu_us_per_player_tick"] = 1e6 * busy / ticks / players;
    // of which the poses' arrival and FrameEncoder::encode (the tick thread's, once per tick)
    st.counters["encode_us_per_player_tick"] = 1e6 * encoding / ticks / players;
    st.counters["wall_ms_per_tick"] = 1e3 * wall / ticks;
    st.counters["kbps_per_player"] = sent * 8 / 1000 / (ticks / 30.0) / players;
    st.counters["weighed_per_player"] = weighed / ticks / players;  // instances whose importance a player's tick computed
    // bone records a player receives per tick (at its rate: fewer bits per bone, more bones)
    st.counters["bones_per_player_tick"] = bones / ticks / players;
    st.SetLabel(mode == 0   ? "everyone sees everyone, 1 Mbit/s"
                : mode == 1 ? "players over 2 km, each viewing from its character, 256 kbit/s"
                : mode == 2 ? "players over 2 km, each weighing its nearest 100, 256 kbit/s"
                : mode == 3 ? "players over 2 km, each weighing its nearest 100, 256 kbit/s, acknowledging"
                            : "players over 2 km, each weighing its nearest 100, 256 kbit/s, acknowledging, standalone records");
}
BENCHMARK(BM_PublishingPlayers)
    ->ArgNames({"players", "mode", "threads"})
    ->Args({16, 0, 1})
    ->Args({200, 0, 1})
    ->Args({200, 1, 1})
    ->Args({200, 2, 1})
    ->Args({200, 2, 2})
    ->Args({1000, 2, 1})
    ->Args({1000, 2, 2})
    ->Args({200, 3, 1})
    ->Args({1000, 3, 1})
    ->Args({1000, 3, 2})
    ->Args({1000, 4, 1})
    ->Args({1000, 4, 2})
    ->Unit(benchmark::kMillisecond);

// A node whose scene holds a whole world of `characters` players'
// characters (docs/scaling.md "every node holds the whole world"), spread at
// one density (1,000 over a disc of 1 km radius, the world's
// radius growing with the square root of its players), 200 of them this
// node's clients, each viewing from its character and weighing its nearest
// 100 at 256 kbit/s. Per tick: every character's pose arrives and the frame
// is encoded (world_ms_per_tick: the node's cost per tick for its scene, on
// the tick thread; encode_ms_per_tick: of which FrameEncoder::encode),
// then the 200 clients tick (client_us_per_tick: CPU per client tick). How
// a player's tick grows with the world it is in.
static void BM_CrowdedWorld(benchmark::State& st) {
    const int characters = int(st.range(0)), clients = 200;
    const bool acked = st.range(1) != 0;  // every client acknowledges each datagram before the next tick (records predicted)
    const std::vector<InstanceSpec> specs = players_characters(characters);
    ServerConfig cfg;
    cfg.max_candidates = 100;
    ServerCore core(cfg, assets(), specs);
    FrameEncoder& enc = core.encoder();
    const auto poses = published_poses();  // per asset, 30 frames of records
    const double radius = 1000.0 * std::sqrt(characters / 1000.0);
    std::vector<glm::dvec3> where(static_cast<size_t>(characters));
    for (int p = 0; p < characters; ++p) {
        const double ang = 2.399963 * p, r = radius * std::sqrt((p + 0.5) / characters);
        where[size_t(p)] = glm::dvec3(r * std::cos(ang), 0.0, r * std::sin(ang));
    }
    std::vector<std::unique_ptr<ClientStream>> client;  // every (characters / clients)-th player is this node's
    for (int c = 0; c < clients; ++c) {
        const int p = int(int64_t(c) * characters / clients);
        client.push_back(ClientStream::detached(core, uint64_t(p + 1), 256));
        ViewSpec v;
        v.has_camera = true;
        v.camera = glm::vec3(where[size_t(p)]);
        client.back()->set_view(v);
    }
    NoSockets sink;
    std::array<uint8_t, ROOT_BYTES> root{};
    uint32_t tick = 0;
    double world = 0, encoding = 0, ticking = 0, weighed = 0;
    auto one_tick = [&](bool timed) {
        const double t0 = thread_seconds();
        ++tick;
        for (int p = 0; p < characters; ++p) {
            RootPose rp;
            rp.position = where[size_t(p)];
            encode_root(rp, root.data());
            enc.push_records(p, tick, 0, 0, poses[size_t(p % 2)][(tick + uint32_t(p)) % 30], root);
        }
        const double tp = thread_seconds();
        const EncodedFrame& f = enc.encode(tick);
        const double t1 = thread_seconds();
        for (auto& c : client) {
            const TickResult r = c->tick(f, tick / 30.0, 1.0 / 30.0, sink);
            if (acked && r.datagrams > 0) c->acknowledge(c->next_seq() - 1, ~0u);
        }
        const double t2 = thread_seconds();
        if (!timed) return;
        world += t1 - t0;
        encoding += t1 - tp;
        ticking += t2 - t1;
        for (auto& c : client) weighed += double(c->weighed());
    };
    // The first ticks send every character whole (nothing was sent yet):
    // a second of them first, untimed.
    for (int k = 0; k < 30; ++k) one_tick(false);
    for (auto _ : st) one_tick(true);
    const double ticks = double(st.iterations());
    st.counters["world_ms_per_tick"] = 1e3 * world / ticks;  // poses in (push_records) and the encode
    st.counters["encode_ms_per_tick"] = 1e3 * encoding / ticks;  // of which FrameEncoder::encode
    st.counters["client_us_per_tick"] = 1e6 * ticking / ticks / clients;
    st.counters["weighed_per_client"] = weighed / ticks / clients;
    st.SetLabel(acked ? "200 clients of a world held whole, each weighing its nearest 100 at 256 kbit/s, acknowledged"
                      : "200 clients of a world held whole, each weighing its nearest 100 at 256 kbit/s, never acknowledged");
}
BENCHMARK(BM_CrowdedWorld)->ArgNames({"characters", "acked"})->ArgsProduct({{1000, 3000, 10000}, {0, 1}})->Unit(benchmark::kMillisecond);

// The encode of a tick (FrameEncoder::encode, on the server's tick pool,
// FrameEncoder::set_pool) of `characters` players' characters, each posed
// every tick: wall and CPU per tick at 1 or more threads.
static void BM_EncodeWorld(benchmark::State& st) {
    const int characters = int(st.range(0)), threads = int(st.range(1));
    const std::vector<InstanceSpec> specs = players_characters(characters);
    FrameEncoder enc(assets(), specs, 30.0f);
    TickPool pool(threads);
    enc.set_pool(&pool);
    const auto poses = published_poses();
    std::array<uint8_t, ROOT_BYTES> root{};
    uint32_t tick = 0;
    double cpu = 0, wall = 0;
    for (auto _ : st) {
        ++tick;
        st.PauseTiming();
        for (int p = 0; p < characters; ++p) {
            RootPose rp;
            rp.position = glm::dvec3(double(p % 100), 0.0, double(p / 100));
            encode_root(rp, root.data());
            enc.push_records(p, tick, 0, 0, poses[size_t(p % 2)][(tick + uint32_t(p)) % 30], root);
        }
        st.ResumeTiming();
        const double c0 = process_seconds(), w0 = now_seconds();
        benchmark::DoNotOptimize(enc.encode(tick).tick);
        cpu += process_seconds() - c0;
        wall += now_seconds() - w0;
    }
    st.counters["encode_wall_ms"] = 1e3 * wall / double(st.iterations());
    st.counters["encode_cpu_ms"] = 1e3 * cpu / double(st.iterations());
    st.SetLabel("every character posed every tick (push_records untimed)");
}
BENCHMARK(BM_EncodeWorld)->ArgNames({"characters", "threads"})->ArgsProduct({{1000, 10000}, {1, 2}})->Unit(benchmark::kMillisecond);

// How the tick's workers send (server.cpp UdpSink): sendto(2) from T threads
// at once on one UDP socket, 1,100-byte datagrams to a loopback socket that
// nobody reads (the kernel drops them once its queue is full, after the
// whole send path). wall_ns_per_datagram falls with T when concurrent sends
// on one socket scale; the alternative, collecting every worker's datagrams
// and sending them from the tick thread after the workers join, would
// stay at the 1-thread figure for all of them.
static void BM_UdpSendShared(benchmark::State& st) {
    const int threads = int(st.range(0));
    asio::io_context io;
    asio::ip::udp::socket rx(io, asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
    asio::ip::udp::socket tx(io, asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
    tx.non_blocking(true);
    tx.set_option(asio::socket_base::send_buffer_size(4 << 20));
    const asio::ip::udp::endpoint to = rx.local_endpoint();
    const int fd = tx.native_handle();
    constexpr int kPerThread = 2000;
    std::vector<uint8_t> payload(1100, 0x5a);
    double wall = 0, cpu = 0;
    for (auto _ : st) {
        const double w0 = now_seconds(), c0 = process_seconds();
        std::vector<std::thread> ts;
        auto send = [&] {
            for (int i = 0; i < kPerThread; ++i)
                (void)::sendto(fd, payload.data(), payload.size(), MSG_DONTWAIT, to.data(), socklen_t(to.size()));
        };
        for (int t = 1; t < threads; ++t) ts.emplace_back(send);
        send();
        for (auto& t : ts) t.join();
        wall += now_seconds() - w0;
        cpu += process_seconds() - c0;
    }
    const double n = double(st.iterations()) * kPerThread * threads;
    st.counters["wall_ns_per_datagram"] = 1e9 * wall / n;
    st.counters["cpu_ns_per_datagram"] = 1e9 * cpu / n;
}
BENCHMARK(BM_UdpSendShared)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

// ---------------------------------------------------------------- loopback --

namespace {
struct LightClient {
    asio::ip::tcp::socket tcp;
    std::unique_ptr<asio::ssl::stream<asio::ip::tcp::socket&>> tls;  // sealed run
    std::unique_ptr<crypto::Sealer> sealer;
    std::unique_ptr<crypto::Opener> opener;
    asio::ip::udp::socket udp;
    uint64_t session = 0, token = 0;
    uint32_t ack = 0, bits = 0, echo = 0;
    bool any = false;
    uint64_t datagrams = 0, bytes = 0, since_ack = 0;
    explicit LightClient(asio::io_context& io) : tcp(io), udp(io) {}
};

template <class Stream>
void send_control(Stream& s, flatbuffers::FlatBufferBuilder& fbb) {
    std::vector<uint8_t> m;
    frame_control(fbb, m);
    asio::write(s, asio::buffer(m));
}

template <class Stream>
bool read_control(Stream& s, std::vector<uint8_t>& body) {
    uint8_t len[4];
    asio::error_code ec;
    asio::read(s, asio::buffer(len), ec);
    if (ec) return false;
    uint32_t n = 0;
    read_length({len, 4}, n);
    body.resize(n);
    asio::read(s, asio::buffer(body), ec);
    return !ec;
}

// Sends a datagram to the server, sealed when the session seals.
asio::ip::udp::endpoint g_server_udp;
void send_dgram(LightClient& c, const flatbuffers::FlatBufferBuilder& b) {
    static thread_local std::vector<uint8_t> sealed;
    asio::error_code ec;
    if (c.sealer) {
        crypto::seal_datagram(*c.sealer, c.session, PROTOCOL_VERSION, {b.GetBufferPointer(), b.GetSize()}, sealed);
        c.udp.send_to(asio::buffer(sealed), g_server_udp, 0, ec);
    } else {
        c.udp.send_to(asio::buffer(b.GetBufferPointer(), b.GetSize()), g_server_udp, 0, ec);
    }
}
}  // namespace

static void BM_Loopback200Clients(benchmark::State& st) {
    const int clients = int(st.range(0)), n = int(st.range(1));
    const double kbps = double(st.range(2));
    const bool sealed = st.range(3) != 0;
    for (auto _ : st) {
        ServerConfig cfg;
        cfg.bind_address = "127.0.0.1";
        cfg.max_clients = clients + 8;
        cfg.max_per_address = 0;  // every client comes from 127.0.0.1
        const std::string tls_dir = (std::filesystem::temp_directory_path() / ("progskin-bench-tls-" + std::to_string(::getpid()))).string();
        if (sealed) {
            const TlsIdentity id = ensure_self_signed(tls_dir);
            cfg.tls_cert_file = id.cert_path;
            cfg.tls_key_file = id.key_path;
            cfg.seal_datagrams = true;
        }
        asio::ssl::context ctx(asio::ssl::context::tls_client);
        ctx.set_verify_mode(asio::ssl::verify_none);  // the bench's own pair; clients elsewhere verify
        cfg.threads = int(st.range(4));
        Server server(cfg, assets(), crowd_layout(assets(), n));
        std::thread th([&] { server.run(); });
        // Every server thread (control, tick, workers): the process's CPU
        // less this thread's, which runs the clients.
        auto server_cpu = [&] { return process_seconds() - thread_seconds(); };
        asio::io_context io;
        std::vector<std::unique_ptr<LightClient>> cs;
        asio::ip::udp::endpoint srv(asio::ip::make_address("127.0.0.1"), server.udp_port());
        g_server_udp = srv;
        std::vector<uint8_t> body;
        for (int i = 0; i < clients; ++i) {
            auto c = std::make_unique<LightClient>(io);
            c->tcp.connect(asio::ip::tcp::endpoint(asio::ip::make_address("127.0.0.1"), server.tcp_port()));
            flatbuffers::FlatBufferBuilder fbb;
            auto name = fbb.CreateString("bench");
            auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, name, 0, uint32_t(kbps));
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
            bool welcomed = false;
            if (sealed) {
                c->tls = std::make_unique<asio::ssl::stream<asio::ip::tcp::socket&>>(c->tcp, ctx);
                c->tls->handshake(asio::ssl::stream_base::client);
                send_control(*c->tls, fbb);
                welcomed = read_control(*c->tls, body) && verify_control(body);
            } else {
                send_control(c->tcp, fbb);
                welcomed = read_control(c->tcp, body) && verify_control(body);
            }
            if (!welcomed) {
                st.SkipWithError("no welcome");
                break;
            }
            const wire::Welcome* w = wire::GetControl(body.data())->body_as_Welcome();
            c->session = w->session_id();
            c->token = w->udp_token();
            if (sealed) {
                if (!w->datagram_keys() || w->datagram_keys()->size() != 2 * crypto::KEY_BYTES) {
                    st.SkipWithError("no datagram keys");
                    break;
                }
                crypto::Key down{}, up{};
                std::copy(w->datagram_keys()->begin(), w->datagram_keys()->begin() + crypto::KEY_BYTES, down.begin());
                std::copy(w->datagram_keys()->begin() + crypto::KEY_BYTES, w->datagram_keys()->end(), up.begin());
                c->opener = std::make_unique<crypto::Opener>(down);
                c->sealer = std::make_unique<crypto::Sealer>(up);
            }
            c->udp.open(asio::ip::udp::v4());
            c->udp.bind(asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
            c->udp.non_blocking(true);
            c->udp.set_option(asio::socket_base::receive_buffer_size(1 << 20));
            flatbuffers::FlatBufferBuilder b;
            std::vector<uint8_t> pad(64, 0);
            auto p = b.CreateVector(pad);
            auto bo = wire::CreateBind(b, c->session, c->token, p);
            b.Finish(wire::CreateDatagram(b, 0, 0, wire::DatagramBody::Bind, bo.Union()), wire::DatagramIdentifier());
            send_dgram(*c, b);
            cs.push_back(std::move(c));
        }
        const double seconds = 5.0;
        const double t0 = now_seconds();
        double last_ack = t0;
        std::vector<pollfd> fds(cs.size());
        alignas(16) uint8_t buf[2048];
        std::vector<uint8_t> opened;
        ServerStats before = server.stats();
        const double cpu0 = server_cpu();
        while (now_seconds() - t0 < seconds) {
            for (size_t i = 0; i < cs.size(); ++i) fds[i] = {cs[i]->udp.native_handle(), POLLIN, 0};
            ::poll(fds.data(), fds.size(), 5);
            for (size_t i = 0; i < cs.size(); ++i) {
                if (!fds[i].revents) continue;
                auto& c = *cs[i];
                for (;;) {
                    asio::error_code ec;
                    asio::ip::udp::endpoint from;
                    size_t got = c.udp.receive_from(asio::buffer(buf), from, 0, ec);
                    if (ec) break;
                    const wire::Datagram* d = nullptr;
                    FrameDatagram fd;
                    bool frame = false;
                    uint64_t seq = 0;
                    std::span<const uint8_t> plain;
                    if (!c.opener) plain = {buf, got};
                    else if (crypto::open_datagram(*c.opener, c.session, PROTOCOL_VERSION, {buf, got}, opened, seq) == crypto::OpenResult::ok)
                        plain = opened;
                    if (is_frame_datagram(plain)) frame = read_frame_datagram(plain, fd);
                    else if (!plain.empty()) d = verify_datagram(plain);
                    if (d && d->body_type() == wire::DatagramBody::Challenge && d->body_as_Challenge()->nonce()) {
                        const auto* nonce = d->body_as_Challenge()->nonce();  // return routability
                        flatbuffers::FlatBufferBuilder r;
                        build_challenge_response(r, c.session, c.token, {nonce->data(), nonce->size()});
                        send_dgram(c, r);
                        continue;
                    }
                    if (!frame) continue;
                    ++c.datagrams;
                    c.bytes += got + UDP_IP_OVERHEAD;
                    ++c.since_ack;
                    if (!c.any || int32_t(fd.seq - c.ack) > 0) {
                        c.ack = fd.seq;
                        c.echo = fd.send_time_us;
                        c.any = true;
                    }
                }
            }
            if (now_seconds() - last_ack > 0.05) {  // ack everything received, 20 Hz
                last_ack = now_seconds();
                for (auto& cp : cs) {
                    auto& c = *cp;
                    if (!c.since_ack) continue;
                    flatbuffers::FlatBufferBuilder fbb;
                    auto a = wire::CreateAck(fbb, c.session, c.token, c.ack, 0xffffffffu, c.echo, 0);
                    fbb.Finish(wire::CreateDatagram(fbb, 0, 0, wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
                    send_dgram(c, fbb);
                    c.since_ack = 0;
                }
            }
        }
        ServerStats after = server.stats();
        const double cpu = server_cpu() - cpu0;
        server.stop();
        th.join();
        if (sealed) std::filesystem::remove_all(tls_dir);
        uint64_t datagrams = 0, bytes = 0;
        for (auto& c : cs) datagrams += c->datagrams, bytes += c->bytes;
        st.counters["server_cpu_ms_per_client_s"] = 1000.0 * cpu / seconds / double(cs.size());
        st.counters["wire_bytes_per_datagram"] = datagrams ? double(bytes) / double(datagrams) : 0;
        st.counters["datagrams_per_client_s"] = double(datagrams) / seconds / double(cs.size());
        double min_kbps = 1e18, sum_kbps = 0;
        for (auto& c : cs) {
            double k = double(c->bytes) * 8 / 1000 / seconds;
            min_kbps = std::min(min_kbps, k);
            sum_kbps += k;
        }
        const double ticks = double(after.ticks - before.ticks);
        st.counters["mean_tick_ms"] = 1000.0 * (after.tick_seconds - before.tick_seconds) / std::max(1.0, ticks);
        st.counters["ticks_per_s"] = ticks / seconds;
        st.counters["core_load"] = (after.tick_seconds - before.tick_seconds) / seconds;
        st.counters["client_kbps_mean"] = sum_kbps / double(cs.size());
        st.counters["client_kbps_min"] = min_kbps;
        st.counters["sessions"] = double(after.sessions_active);
    }
}
BENCHMARK(BM_Loopback200Clients)
    ->ArgNames({"clients", "characters", "kbps", "sealed", "threads"})
    ->Args({200, 100, 256, 0, 1})
    ->Args({200, 100, 256, 1, 1})
    ->Args({200, 4, 256, 0, 1})
    ->Args({200, 4, 256, 1, 1})
    ->Args({200, 100, 256, 1, 2})
    ->Iterations(1)
    ->Unit(benchmark::kSecond);

BENCHMARK_MAIN();
