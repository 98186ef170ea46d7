// server_core.h — the server without sockets: the catalogue, the instances
// (FrameEncoder), every session's ClientStream by id, the counters and the
// connect-token state. server.cpp (the shell: io_context, acceptor, TLS
// streams, UDP socket, timers) drives it: open a session per accepted
// connection, hand it control bytes, route datagrams (on_datagram), tick.
//
// Threads (ownership rule; docs/protocol.md "Threads"): add_instance,
// remove_instance, encoder() pushes and stats() are thread-safe. Everything
// else — the session table, the address budgets, the token replay cache,
// drained_, and every ClientStream — is touched only by a thread holding
// mutex() (the shell's control thread for connections and control messages,
// its tick thread for datagrams and the tick), with one exception: during
// tick(), with a pool attached (set_pool), the pool's workers tick the
// Streaming sessions the tick thread handed them (each session on one
// thread, with that thread's TickScratch), while the tick thread holds
// mutex() for them all. The encoded frame, the catalogue, the configuration
// and owner_groups() are then read-only.
#pragma once
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "client_stream.h"
#include "control_messages.h"
#include "crypto.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "server.h"
#include "tick_pool.h"

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
    // The shell, once the connection is closed. Its id is remembered for
    // kClosedRememberSeconds (at most kClosedRemembered ids) so that its
    // datagrams still in flight count as late_datagrams, not rejected ones.
    void erase(uint64_t id, double now);
    static constexpr size_t kClosedRemembered = 1024;
    static constexpr double kClosedRememberSeconds = 2.0;
    int welcomed_sessions() const;  // Welcomed or Streaming (max_clients)
    // Hello.token against the configured access token or connect-token key:
    // an empty string, or why it is refused; `who` gets "client N " for a
    // connect token.
    std::string check_token(const flatbuffers::String* token, std::string& who);

    // ------------------------------------------------------------- budgets --
    // Counts one refusal of a budget or admission limit (ServerStats::refusals).
    void refused(const std::string& reason);
    // Why session `s` may not spawn another character: its address's players
    // hold max_characters_per_address already (empty: it may).
    std::string spawn_budget(const ClientStream& s) const;
    // Takes n asset bytes from the bucket of `remote`'s address (shared by its
    // sessions, kept across reconnects); false when it holds fewer.
    bool charge_assets(const PeerAddress& remote, size_t n, double now);
    // The server is full and `newcomer` said Hello: closes one session to make
    // room (ServerConfig::evict_after), counted; false when none may go.
    bool make_room(const ClientStream& newcomer, double now);
    // Fair share: per instance slot, 0 for the server's own characters, else
    // a number naming its owning session, the same in every session's tick.
    std::span<const uint32_t> owner_groups() const { return owner_groups_; }
    // Liveness independent of the tick's load: the shell says when it last
    // found the UDP receive queue empty (every Ack sent before then has been
    // accounted). A Streaming session times out client_timeout after its
    // newest Ack as of that moment (heard_until), not as of now, unless the
    // queue has not been empty for 2 x client_timeout. Without a shell: now.
    void input_drained(double t) { drained_ = t; }
    double heard_until(double now) const;

    // ----------------------------------------------------------------- I/O --
    // One datagram from `from`: opened (sealed: with the key of the session
    // its header names), verified, routed by session id and token, counted.
    // An answer (Challenge, BindAck) goes to `out`, to `from`, only when it is
    // smaller than what came (never amplifies toward an unproven address).
    void on_datagram(std::span<const uint8_t> bytes, const PeerAddress& from, double now, DatagramSink& out);
    // One tick at `now`: instances announced, the frame encoded once (when
    // anyone streams), each Streaming session's tick to `out` (on the pool's
    // threads when one is attached: `out` must then take sends from several
    // threads at once), timeouts. The caller holds mutex(). encoded, when
    // given, is called with the tick's frame right after its encode, before
    // any session's work (a world node publishes it on the bus then, so that
    // the other nodes do not wait for this node's clients).
    void tick(double now, DatagramSink& out, const std::function<void(const EncodedFrame&)>& encoded = {});
    // The Streaming sessions' part of a tick: each of `streams` ticked once
    // (ClientStream::tick) with `frame`, spread over the pool's threads when
    // one is attached (each stream on one thread), else on this one. Returns
    // the datagrams and wire bytes sent in all. (tick(); benchmarks.)
    TickResult tick_streams(std::span<ClientStream* const> streams, const EncodedFrame& frame, double now, double dt,
                            DatagramSink& out);
    // The pool of threads tick_streams uses from now on (null: this thread
    // alone); it must outlive its use. One TickScratch per pool thread.
    void set_pool(TickPool* pool);

    // The lock that owns the sessions (see the ownership rule above).
    std::mutex& mutex() { return mutex_; }

    // --------------------------------------------------------------- world --
    int add_instance(const InstanceSpec& spec);  // thread-safe; every session is told at the next tick
    // Where this node's clients look from (ClientStream::view_centres) in the
    // last encoded frame, for interest management (world_bus.h): appended to
    // `out`. Returns the number of Welcomed or Streaming clients, or -1 when
    // one of them has no centre (it sees everything). Takes mutex().
    int view_centres(std::vector<glm::dvec3>& out);
    void remove_instance(int id);                // thread-safe
    uint64_t instances_version() const { return instances_version_.load(); }
    template <class F>
    void count(F f) {
        std::lock_guard lock(stats_mutex_);
        f(stats_);
    }
    ServerStats stats() const;  // thread-safe snapshot
    void log(const std::string& s) const;
    // Scratch of whoever holds mutex() (sync_instances, datagram answers,
    // ticks without a pool).
    std::vector<uint32_t>& generations() { return generations_; }
    TickScratch& scratch() { return scratch_; }

private:
    ClientStream* route(const wire::Datagram& d, ClientStream* sealed_by);
    static uint64_t datagram_session(const wire::Datagram& d);  // 0 for server -> client bodies
    bool closed_recently(uint64_t id, double now);  // and forgets those older than kClosedRememberSeconds
    bool ending(const ClientStream* sealed_by, uint64_t id, double now);  // closing, or closed_recently
    // Per IP address (its port ignored): new connections and asset bytes,
    // token buckets that outlive the address's sessions (pruned once full).
    struct AddressBudget {
        double connects = 0, connects_at = 0;
        double assets = 0, assets_at = 0;
    };
    struct IpLess {
        bool operator()(const PeerAddress& a, const PeerAddress& b) const {
            return std::tie(a.ip, a.scope, a.v6) < std::tie(b.ip, b.scope, b.v6);
        }
    };
    AddressBudget* budget_of(const PeerAddress& remote, double now);
    bool admit_connection(const PeerAddress& remote, double now);  // the per-address connection rate
    void limit_handshakes();  // max_handshakes: the oldest closed
    void prune_addresses(double now);
    void update_owner_groups(const EncodedFrame* frame);
    const EncodedFrame* prepare_tick(double now, std::vector<std::shared_ptr<ClientStream>>& drop);
    double asset_bucket_bytes() const;
    ClientStream* eviction_candidate(const ClientStream& newcomer, double now, std::string& reason);

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
    std::deque<std::pair<uint64_t, double>> closed_recently_;  // erase(): id, when
    std::map<PeerAddress, AddressBudget, IpLess> addresses_;
    double pruned_at_ = 0;
    double drained_ = -1;  // input_drained (-1: no shell says)
    std::vector<uint32_t> owner_groups_;
    std::atomic<uint64_t> instances_version_{1};  // bumped by every add / remove
    uint32_t tick_ = 0;
    double last_tick_time_ = 0;
    mutable std::mutex stats_mutex_;
    ServerStats stats_;
    bool connect_tokens_ = false;
    crypto::PublicKey token_key_{};
    crypto::TokenReplayCache token_replays_;
    std::vector<uint32_t> generations_;
    TickScratch scratch_;
    std::vector<uint8_t> opened_;
    std::mutex mutex_;  // mutex(): the sessions' owner
    TickPool* pool_ = nullptr;
    std::vector<std::unique_ptr<TickScratch>> pool_scratch_;  // per pool thread
    std::vector<ClientStream*> streaming_;  // tick's: the sessions to tick (capacity kept)
    struct alignas(64) ThreadTotals {  // tick_streams: per pool thread (own cache line)
        size_t datagrams = 0, wire_bytes = 0;
    };
    std::vector<ThreadTotals> totals_;
};

}  // namespace progskin::net
