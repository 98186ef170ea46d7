// world_bus.h — one node of a world on NATS (docs/deployment.md,
// docs/protocol.md "World bus"). Each tick, right after its encode, the node publishes its own
// characters (clip instances and players' published ones), as the encoder
// encoded them, one message per spatial cell (world_message.h) on
// `progskin.<world>.cell.<cx>.<cz>`; it receives the other nodes' cells and
// keeps their characters in its own scene as foreign live instances
// (ServerCore::add_instance, FrameEncoder::push_relative: the sender's
// record integers, coded again to the same ones), so that its clients see
// them exactly as local ones. A foreign character is removed
// when none of its messages came for 1.5 s (its node died or it left).
// Every second a hello on `progskin.<world>.hello` names the node and its
// catalogue; messages of another catalogue are refused and counted.
// Interest management: with a view radius (ServerConfig::view_radius) the
// node subscribes only to the cells within it of its clients' view centres,
// re-evaluated every 0.1 s; without one, to every cell while it has clients;
// with no client, to none.
//
// Threads: libnats delivers on its own threads; a message is copied into a
// bounded queue (WorldConfig::queue_messages, kQueueBytes: beyond, dropped
// and counted)
// that before_tick drains on the tick thread. Publishing never blocks (libnats
// buffers; while it reconnects, up to its reconnect buffer, then the
// message is dropped and counted). A nats-server that restarts is reconnected
// to (every 250 ms, forever).
#pragma once
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "world_message.h"

namespace progskin::net {

class ServerCore;
struct EncodedFrame;

struct WorldConfig {
    std::string url;            // nats://HOST:PORT, or tls://HOST:PORT (TLS)
    // TLS to the NATS server (on with a tls:// URL or any of these): the PEM
    // certificates that sign its certificate (else the system's trust
    // store, as libnats loads it), and this node's own certificate and key
    // when the NATS server verifies its clients (nats-server --tlsverify).
    std::string ca_file, cert_file, key_file;
    std::string node = "node";  // this node's name (logs, hello)
    std::string world = "default";
    double cell_size = 16.0;    // metres (world units) per cell side
    // Bus messages held between two ticks (the receive queue's bound, and
    // libnats's pending limit per subscription): beyond, dropped and counted,
    // and the node sheds its farthest cells until it keeps up.
    size_t queue_messages = kDefaultQueueMessages;
    static constexpr size_t kDefaultQueueMessages = 1024, kMaxQueueMessages = 1 << 20;
};

// The NATS URL(s) (comma-separated) with each one's credentials
// (USER:PASSWORD@ or TOKEN@) replaced by "***", for logs and errors.
std::string redact_nats_url(const std::string& urls);

struct WorldStats {
    uint64_t messages_out = 0, bytes_out = 0, publish_failed = 0;
    uint64_t messages_in = 0, bytes_in = 0, dropped = 0, malformed = 0, refused = 0;
    uint64_t superseded = 0;  // cell messages skipped for a newer one of the same sender and cell (behind)
    uint64_t foreign_added = 0, foreign_removed = 0;
    uint64_t subscribe_failed = 0;
    int foreign = 0, nodes_seen = 0;
    int cells = 0;  // cell subscriptions now (-1: every cell)
    int cells_shed = 0;  // cells its clients want that it does not follow now (behind: the farthest shed)
    bool connected = false;
};

class WorldBus {
public:
    // Connects (retrying in the background if nats-server is not up yet).
    // Throws Error for a bad URL or name.
    WorldBus(WorldConfig cfg, ServerCore& core);
    ~WorldBus();
    WorldBus(const WorldBus&) = delete;
    WorldBus& operator=(const WorldBus&) = delete;

    // Tick thread, right before ServerCore::tick: the foreign characters
    // received since the last call into the scene (so that this tick encodes
    // and sends them: a pose from another node waits for one tick of this
    // node, not two), those unheard for kForeignTimeout removed, the cell
    // subscriptions renewed; a hello every second.
    void before_tick(double now);
    // Tick thread, within ServerCore::tick right after the encode (its
    // `encoded` callback), before the sessions' work: this node's
    // characters, as the tick encoded them, published by cell. The other
    // nodes then need not wait for this node's clients to be served.
    void publish(const EncodedFrame& frame);
    WorldStats stats() const;

    static constexpr size_t kQueueBytes = 16 << 20;
    static constexpr size_t kQueuedHeader = 9;  // per queued message: kind, the subject's hash
    static constexpr double kForeignTimeout = 1.5;
    // Interest management (ServerConfig::view_radius): recomputed this often,
    // a cell kept this long after last wanted, beyond this many cells every cell.
    static constexpr double kInterestPeriod = 0.1, kInterestLinger = 2.0;
    static constexpr size_t kMaxCellSubscriptions = 256;

    struct Impl;  // libnats callbacks reach it

private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace progskin::net
