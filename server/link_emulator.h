// link_emulator.h — a UDP relay that emulates a slow or bad link between
// clients and a server: rate cap (serialisation + drop-tail queue of at most
// queue_ms), fixed delay, uniform jitter, loss, reordering and duplication,
// deterministic for a given seed. Each client address gets its own upstream
// socket, so the server sees one address per client. Used by progskin-netem
// and by the tests (clients send their UDP to the relay: --udp-via).
//
// With relay_tcp() the control channel goes through it too: a TCP listener on
// the same port number, one upstream connection per accepted one. TCP bytes
// share the link's rate cap with the datagrams (each read chunk costs its
// bytes + 40 of headers) and get the delay and jitter, in order (a chunk never
// overtakes the one before it); loss, reordering and duplication do not apply
// to a reliable stream. When the rate-cap queue is longer than queue_ms the
// relay stops reading TCP (back-pressure) instead of dropping. The upstream
// connect is blocking (the relay pauses while it connects: meant for loopback
// and LAN servers); at most 1024 connections and 1 MiB in flight each way per
// connection.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>

namespace progskin::net {

struct LinkConfig {
    double rate_kbps = 0;     // 0 = unlimited (docs/metrics.md §3 wire bytes: payload + 28)
    double delay_ms = 0;
    double jitter_ms = 0;
    double loss = 0;          // probability per datagram
    double reorder = 0;       // probability that a datagram is held back by extra delay
    double duplicate = 0;     // probability that a datagram is sent twice
    double queue_ms = 200;    // rate-cap queue limit
    uint64_t seed = 1;
    bool both_ways = false;   // false: impairments only server -> client (acks get the delay only)
};

struct LinkStats {
    uint64_t forwarded = 0, dropped = 0, duplicated = 0, reordered = 0, queue_drops = 0;
    uint64_t tcp_connections = 0, tcp_bytes_down = 0, tcp_bytes_up = 0;  // relay_tcp() only
};

class LinkEmulator {
public:
    // Listens on listen_address:listen_port (0 = ephemeral) and relays to target.
    LinkEmulator(const LinkConfig& cfg, const std::string& target_host, uint16_t target_port,
                 const std::string& listen_address = "127.0.0.1", uint16_t listen_port = 0);
    ~LinkEmulator();
    uint16_t port() const;
    // Before start(): also relay TCP from listen_address:port() to the target
    // host's tcp_port. Throws Error when that TCP port cannot be bound.
    void relay_tcp(uint16_t tcp_port);
    void start();  // relays on a thread of its own
    void stop();
    LinkStats stats() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace progskin::net
