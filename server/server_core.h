// server_core.h — the server without sockets: the catalogue, the instances
// (FrameEncoder), every session's ClientStream by id, the counters and the
// connect-token state. server.cpp (the shell: io_context, acceptor, TLS
// streams, UDP socket, timers) drives it: open a session per accepted
// connection, hand it control bytes, route datagrams (on_datagram), tick.
// Everything here runs on the shell's thread except add_instance,
// remove_instance, encoder() pushes and stats(), which are thread-safe.
#pragma once
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "client_stream.h"
#include "control_messages.h"
#include "crypto.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "server.h"

namespace progskin::net {

class ServerCore {
public:
    // Checks the configuration (tick rate, assets, TLS files named in pairs,
    // sealing only with TLS, one kind of token); throws Error. The TLS files
    // themselves are the shell's.
    ServerCore(ServerConfig config, ServerAssets assets, std::vector<InstanceSpec> instances);

    const ServerConfig& config() const { return cfg_; }
    const ServerAssets& assets() const { return assets_; }
    double total_asset_bytes() const { return total_asset_bytes_; }
    FrameEncoder& encoder() { return encoder_; }
    bool tls() const { return !cfg_.tls_cert_file.empty(); }
    uint16_t udp_port() const { return udp_port_; }
    void set_udp_port(uint16_t p) { udp_port_ = p; }  // announced in every Welcome

    // ------------------------------------------------------------ sessions --
    // A session for a connection from `remote` (its port ignored), with a
    // fresh random id and UDP token. Over max_per_address connections from
    // that address it is refused at once: closed without a word over TLS
    // (no handshake spent on it), else a Refuse, Closing.
    std::shared_ptr<ClientStream> open(const PeerAddress& remote, double now);
    void erase(uint64_t id);  // the shell, once the connection is closed
    int welcomed_sessions() const;  // Welcomed or Streaming (max_clients)
    // Hello.token against the configured access token or connect-token key:
    // an empty string, or why it is refused; `who` gets "client N " for a
    // connect token.
    std::string check_token(const flatbuffers::String* token, std::string& who);

    // ----------------------------------------------------------------- I/O --
    // One datagram from `from`: opened (sealed: with the key of the session
    // its header names), verified, routed by session id and token, counted.
    // An answer (Challenge, BindAck) goes to `out`, to `from`, only when it is
    // smaller than what came (never amplifies toward an unproven address).
    void on_datagram(std::span<const uint8_t> bytes, const PeerAddress& from, double now, DatagramSink& out);
    // One tick at `now`: instances announced, the frame encoded once (when
    // anyone streams), each Streaming session's tick to `out`, timeouts.
    void tick(double now, DatagramSink& out);

    // --------------------------------------------------------------- world --
    int add_instance(const InstanceSpec& spec);  // thread-safe; every session is told at the next tick
    void remove_instance(int id);                // thread-safe
    uint64_t instances_version() const { return instances_version_.load(); }
    template <class F>
    void count(F f) {
        std::lock_guard lock(stats_mutex_);
        f(stats_);
    }
    ServerStats stats() const;  // thread-safe snapshot
    void log(const std::string& s) const;
    // Scratch shared by the sessions' ticks (one thread).
    std::vector<uint32_t>& generations() { return generations_; }
    DatagramPacker& packer() { return packer_; }
    std::vector<std::vector<uint8_t>>& datagrams() { return datagrams_; }
    std::vector<uint8_t>& sealed() { return sealed_; }

private:
    ClientStream* route(const wire::Datagram& d, ClientStream* sealed_by);

    ServerConfig cfg_;
    ServerAssets assets_;
    FrameEncoder encoder_;
    double total_asset_bytes_ = 0;
    uint16_t udp_port_ = 0;
    struct Entry {
        std::shared_ptr<ClientStream> stream;
        PeerAddress remote;  // the TCP peer (max_per_address)
    };
    std::map<uint64_t, Entry> sessions_;
    std::atomic<uint64_t> instances_version_{1};  // bumped by every add / remove
    uint32_t tick_ = 0;
    double last_tick_time_ = 0;
    mutable std::mutex stats_mutex_;
    ServerStats stats_;
    bool connect_tokens_ = false;
    crypto::PublicKey token_key_{};
    crypto::TokenReplayCache token_replays_;
    std::vector<uint32_t> generations_;
    DatagramPacker packer_;
    std::vector<std::vector<uint8_t>> datagrams_;
    std::vector<uint8_t> sealed_, opened_;
};

}  // namespace progskin::net
