// server.h — the streaming server (docs/protocol.md): TCP control sessions,
// a UDP frame stream, and a tick that samples + encodes every instance once,
// then per client selects (scheduler.h) and packs (datagram_packer.h) within
// the client's rate (rate_controller.h). ServerConfig::threads: with 1, one
// asio io_context on one thread does everything; with N > 1, connections
// (TLS handshakes, control messages, asset downloads) have a thread of their
// own, the UDP socket and the tick another, and the tick's per-client work
// runs on N threads (tick_pool.h; docs/protocol.md "Threads"). push_pose,
// set_root, add_instance, remove_instance, stop and stats may be called from
// other threads.
//
// Library use (game servers pushing their own characters' poses, NPCs):
//   Server s(cfg, assets, instances);   // InstanceSpec::selection = -1: live only
//   std::thread t([&] { s.run(); });
//   int npc = s.add_instance(spec);      // at any time; every client is told
//   s.set_root(npc, {world_position, rotation}, false);
//   s.push_pose(npc, skinning_matrices);  // each game tick, joint order, relative to the root
//   s.remove_instance(npc);
//   s.stop(); t.join();
// Players' characters arrive from their clients (control Spawn, datagram
// Pose) and go away with their session. The sessions themselves are
// socket-free cores (server_core.h, client_stream.h) this class drives.
#pragma once
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "scene.h"

namespace progskin::net {

struct ServerConfig {
    std::string bind_address = "0.0.0.0";
    uint16_t port = 0;            // TCP port; 0 = ephemeral
    uint16_t udp_port = 0;        // 0 = the TCP port's number if free, else ephemeral
    float tick_rate = 30.0f;
    int max_clients = 256;
    double max_kbps = 50000;      // per-client ceiling (a client's cap is min(its own, this))
    double initial_kbps = 1000;   // start of the adaptive estimate
    double hello_timeout = 5.0;   // seconds to receive Hello after connecting
    double client_timeout = 10.0; // seconds without UDP acks from the bound address (or unbound after Welcome) before dropping
    std::string token;            // non-empty: Hello.token must match
    // Non-empty (64 hex digits, an Ed25519 public key; off by default): Hello.token
    // must be a connect token signed by the matching secret key (proto/crypto.h,
    // `progskin token`), unexpired, for public_address if that is set, never used before.
    std::string token_public_key;
    std::string public_address;   // "host:port" as written in connect tokens; empty: any
    // Both non-empty (PEM files; off by default): the control channel is TLS
    // 1.2+ (OpenSSL through asio::ssl) from the first byte; clients that speak
    // plain TCP fail the handshake and are closed.
    std::string tls_cert_file, tls_key_file;
    // With TLS (off by default): every datagram both ways is sealed
    // (proto/crypto.h seal_datagram) with per-session keys sent in the Welcome;
    // unsealed or forged datagrams are dropped and counted.
    bool seal_datagrams = false;
    // A frame datagram an Ack shows lost (docs/protocol.md "Ack") goes again,
    // byte for byte, when its tick is at most ClientStream::kRepairTicks old
    // and the client's stream has room (its last tick sent everything due
    // within the budget, and the budget holds it), and again when the repair
    // is lost too (at most ClientStream::kMaxRepairs times): the client then
    // displays that tick as sent instead of interpolating across the gap.
    // Off: never.
    bool repair_lost = true;
    // >= 0 (off by default, -1): a WebSocket endpoint for browsers at
    // ws://bind_address:web_port/ws, or wss:// with TLS (tls_cert_file: the
    // same certificate as the control channel); 0: an ephemeral port
    // (web_endpoint.h, docs/protocol.md "WebSocket transport").
    int web_port = -1;
    // The folder whose files the web port also serves to HTTP GET (the
    // browser client's page, web_files.h); empty: none (404 saying so).
    // progskin-server fills it from --web-root or WebFiles::find_root.
    std::string web_root;
    double asset_bytes_factor = 4.0;  // per-session download limit, x total asset bytes
    size_t max_queued_bytes = 1 << 20;  // per-session control output waiting to be written; more closes the session
    int max_per_address = 64;     // open TCP connections from one IP address (0: no limit)
    // Budgets: what one player (session, or IP address) may make the server
    // spend on it or on everybody else (docs/protocol.md "Security").
    // Characters per session: MAX_SPAWNED.
    int max_characters_per_address = 32;  // players' characters spawned from one IP address (0: no limit)
    // Fair share: the characters of one session take at most this of each
    // observer's stream, and at most an equal part of its budget among the
    // owners with something to send (their items beyond it wait, and the
    // observer's rate does not grow for them; 0: no limit).
    double owner_share_kbps = 256;
    // Per-character floor (Scheduler::set_floor): each character's own most
    // valuable bones go first until it has this fraction of its part of the
    // observer's budget (parts in proportion to size on screen); 0: the
    // greedy alone, which may starve an almost still character in favour of
    // moving ones (docs/performance.md "Per character").
    double fair_floor = 0.5;
    // Records predicted from what each client acknowledged (baseline_book.h);
    // false: every record standalone (the A/B of bench_net_rd and the docs).
    bool predict_records = true;
    // Clips whose every channel is linear are sampled at their keys (the
    // latest key since the tick before, else half a tick before the tick:
    // FrameEncoder set_key_samples, Frame.sampled), so that a client
    // interpolating linearly between adjacent ticks follows their kinks.
    // Off in the library: it pays where every bone's progressive parent is
    // its artist parent, at full rate, and can cost below it
    // (docs/performance.md "Protocol 8"); progskin-server turns it on with
    // its default build, --build-strategy rate.
    bool key_samples = false;
    // Asset bytes sent to one IP address, across its sessions and reconnects:
    // a bucket this deep refilled at this per minute (0: 64 x the catalogue's
    // bytes: 64 players behind one NAT joining at once for the first time).
    // Over it the session is closed.
    double asset_bytes_per_minute = 0;
    // The tick: a client's scheduler weighs at most this many characters
    // (the most important), and never more than its budget could carry.
    int max_candidates = 2048;
    // Admission: connections before Hello (TLS handshakes included) at once;
    // a new one beyond closes the oldest (0: no limit).
    int max_handshakes = 128;
    // New connections per IP address per second (a bucket of 8 s of them);
    // beyond: closed at once, no handshake spent (0: no limit).
    double connects_per_second = 32;
    // When full, a Hello evicts (Goodbye "evicted: ...") a session unbound
    // this long after its Welcome and not downloading, else one silent (no
    // Ack) this long, else the newest of the address holding the most
    // sessions when that is more than the newcomer's address holds + 1.
    double evict_after = 2.0;
    // Threads of the tick's per-client work (importance, selection, packing,
    // sealing, sending), the tick thread included. 0: the machine's cores
    // (std::thread::hardware_concurrency). 1: one thread for everything, the
    // tick, the UDP socket and the connections. More than 1: the connections
    // also get a thread of their own, so that TLS handshakes, control
    // messages and asset downloads never delay a tick. At most 256.
    int threads = 0;
    bool verbose = false;
    // One world across servers (docs/deployment.md): non-empty, the NATS
    // server this node joins (nats://HOST:PORT; needs a build with libnats).
    std::string nats_url;
    // TLS to the NATS server (WorldConfig): CA file, this node's certificate and key.
    std::string nats_ca_file, nats_cert_file, nats_key_file;
    std::string world_node = "node";   // this node's name in the world's logs
    std::string world_name = "default";
    double world_cell = 16.0;          // side of a bus cell, world units
    size_t world_queue = 1024;         // bus messages held between ticks (WorldConfig::queue_messages)
    // A client sees the characters within this horizontal distance (world
    // units, x and z) of its view centre: its View's camera, else its own
    // published characters (the nearest of them); a client with neither sees
    // every character. 0: no limit. In a world, a node subscribes only to
    // the bus cells within this distance of its clients' centres (interest
    // management, docs/deployment.md); with 0 it takes every cell.
    double view_radius = 0;
};

// The tick threads a configuration asks for: ServerConfig::threads, or the
// machine's cores when it is 0 (at least 1, at most 256).
int tick_threads(const ServerConfig& cfg);

struct ServerStats {
    uint64_t sessions_total = 0, sessions_active = 0, refused = 0, timeouts = 0;
    uint64_t ticks = 0, datagrams_sent = 0, wire_bytes_sent = 0;
    uint64_t datagrams_received = 0, malformed_datagrams = 0, rejected_datagrams = 0;
    uint64_t late_datagrams = 0;  // of a session saying goodbye or closed less than 2 s before (ServerCore::ending)
    // Sealed datagrams naming a live session whose sequence was already opened
    // or is older than the replay window: the network's duplicates, or replays
    // (dropped before the tag, so not authenticated); not counted rejected.
    uint64_t stale_datagrams = 0;
    // Frame datagrams sent again, as they were, when an Ack showed them lost
    // while the client could still display them (ServerConfig::repair_lost),
    // each copy counted (ClientStream::kRepairCopies).
    uint64_t datagrams_repaired = 0;
    // The world bus (nats_url): messages and bytes each way, messages dropped
    // (a full queue, no instance id left), malformed, of another catalogue,
    // the other nodes' characters in this scene now.
    uint64_t world_messages_out = 0, world_bytes_out = 0, world_messages_in = 0, world_bytes_in = 0;
    uint64_t world_dropped = 0, world_malformed = 0, world_refused = 0, world_publish_failed = 0;
    uint64_t world_superseded = 0;  // cell messages skipped for a newer one of the same cell (node behind)
    int world_foreign = 0;
    int world_cells = 0;  // bus cells subscribed now (-1: every cell)
    int world_cells_shed = 0;  // cells wanted but not followed now (the node fell behind: the farthest shed)
    bool world_connected = false;
    uint64_t unverified_bytes_in = 0, unverified_bytes_out = 0;  // from addresses not bound / to them (Challenges only)
    uint64_t malformed_control = 0, asset_bytes_sent = 0;
    uint64_t poses_received = 0, poses_stale = 0, poses_rate_limited = 0;  // players' Pose datagrams
    uint64_t poses_missing_baseline = 0;  // Poses predicted from a pose this server does not hold whole (dropped)
    uint64_t poses_out_of_range = 0;  // live poses refused by the codec's range (FrameEncoder)
    uint64_t morphs_out_of_range = 0; // clip morph weights outside the wire range, refused (FrameEncoder)
    uint64_t challenges_sent = 0;  // return-routability challenges (answers to Binds from new addresses)
    uint64_t accept_errors = 0, backlog_closes = 0, handler_errors = 0;
    uint64_t tls_failures = 0;     // TLS handshakes that failed
    uint64_t tokens_refused = 0;   // connect tokens invalid, expired, for another server or replayed
    // WebSocket transport (web_endpoint.h): sessions opened (upgrades
    // accepted), connections closed for a malformed or oversized message or
    // request, datagrams dropped because the connection's queue was full,
    // static files served (200s, web_files.h).
    uint64_t web_sessions = 0, web_malformed = 0, web_datagrams_dropped = 0, web_files_served = 0;
    double tick_seconds = 0;      // total time spent in ticks
    // Every refusal of a budget or admission limit, by reason (docs/protocol.md
    // "Limits"): characters_per_session, characters_per_address, spawn_invalid,
    // view_too_large, asset_budget_session, asset_budget_address, connect_rate,
    // connections_per_address, handshake_evicted, server_full, evicted_unbound,
    // evicted_idle, evicted_address_share.
    std::map<std::string, uint64_t> refusals;
    uint64_t refusals_total() const {
        uint64_t n = 0;
        for (const auto& [k, v] : refusals) n += v;
        return n;
    }
};

// A server's TCP listener and UDP socket, bound (and listening) but not yet
// served: progskin-server binds them before it builds its assets, so that a
// port in use is reported at once. Owns the descriptors until a Server takes them.
struct BoundPorts {
    int tcp_fd = -1, udp_fd = -1;
    BoundPorts() = default;
    BoundPorts(BoundPorts&& o) noexcept : tcp_fd(std::exchange(o.tcp_fd, -1)), udp_fd(std::exchange(o.udp_fd, -1)) {}
    BoundPorts& operator=(BoundPorts&& o) noexcept;
    ~BoundPorts();
    uint16_t tcp_port() const;  // 0 when not bound
};
// Binds cfg's TCP port (bind_address:port, 0 = ephemeral), then UDP on the
// same number when free (or cfg.udp_port). Throws Error naming the address
// and port ("cannot listen on 0.0.0.0:7777: Address already in use").
BoundPorts bind_ports(const ServerConfig& cfg);

class Server {
public:
    // Serves on `ports` when given (bind_ports), else binds cfg's ports here (throws Error).
    Server(ServerConfig config, std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
           BoundPorts ports = {});
    ~Server();
    Server(const Server&) = delete;
    Server& operator=(const Server&) = delete;

    uint16_t tcp_port() const;
    uint16_t udp_port() const;
    uint16_t web_port() const;  // 0 without a WebSocket endpoint
    void run();   // serves until stop()
    void stop();  // thread-safe
    // Thread-safe. Returns false (the previous pose stays) when a matrix is
    // outside the codec's range (counted in stats().poses_out_of_range);
    // throws Error for an unknown instance or a wrong matrix count.
    bool push_pose(int instance, std::span<const Mat34> skinning_matrices);
    // Thread-safe. World placement of an instance (its root block travels in
    // every frame from then on); teleport marks a discontinuity. False when
    // the instance is unknown or the root is out of range (+-2147 km, finite).
    bool set_root(int instance, const RootPose& root, bool teleport = false);
    // Thread-safe. Adds an instance (an NPC; selection -1: live poses) and
    // returns its id; every client is told at the next tick. Throws Error.
    int add_instance(const InstanceSpec& spec);
    void remove_instance(int instance);  // thread-safe; no-op for an unknown id
    ServerStats stats() const;  // thread-safe snapshot

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace progskin::net
