// client_stream.h — one client's session on the server, without sockets (the
// netcode.io / yojimbo shape): server.cpp owns the TCP connection and the UDP
// socket and drives one ClientStream per connection through ServerCore
// (server_core.h); tests and benchmarks drive it with no socket at all.
//
// Session state machine (docs/protocol.md "Session state machine"):
//   AwaitHello --Hello ok--> Welcomed --Bind, Challenge, ChallengeResponse
//       from the same address--> Streaming
//   Streaming --Bind from a new address, Challenge, ChallengeResponse--> Streaming (moved)
//   any --Goodbye / TCP close / error / output backlog--> Closed
//   AwaitHello --no Hello in hello_timeout--> Closed
//   Welcomed --not bound client_timeout after Welcome (TCP traffic or not)--> Goodbye, Closing
//   Streaming --no Ack from the bound address in client_timeout--> Goodbye, Closing
//   AwaitHello --bad version or token, server full, Welcome too large--> Refuse, Closing
//   Closing --queued output written, or 1 s--> Closed
// With TLS (ServerConfig::tls_cert_file) the handshake is the shell's and runs
// under hello_timeout like the rest of AwaitHello; with seal_datagrams, every
// datagram both ways is sealed with keys sent in the Welcome.
//
// In: control message bodies (on_control), the datagrams ServerCore routes to
// this session (on_datagram: Bind, ChallengeResponse, Ack, Pose), the tick
// (tick: importance, Scheduler::select, DatagramPacker::pack, seal, rate
// accounting) and the time (expired, expire).
// Out: control messages, framed, queued for the shell to write (output(),
// on_written(); at most ServerConfig::max_queued_bytes waiting, more closes
// the session), datagrams through a DatagramSink, and the state: Closed
// means the shell closes the connection (close_reason() says why).
// Whole-server things (catalogue, instances, counters, the other sessions)
// go through ServerCore. Not thread-safe: one thread at a time, holding
// ServerCore::mutex() (the shell's control or tick thread), or a tick worker
// that ServerCore::tick gave this session to (tick_pool.h).
#pragma once
#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "crypto.h"
#include "datagram_packer.h"
#include "frame_encoder.h"
#include "rate_controller.h"
#include "scheduler.h"
#include "wire.h"

namespace progskin::net {

class ServerCore;

// A UDP or TCP peer as the core sees it: comparable, printable, no socket type.
struct PeerAddress {
    std::array<uint8_t, 16> ip{};  // IPv4: the first 4 bytes
    uint32_t scope = 0;            // IPv6 scope id (link-local addresses)
    uint16_t port = 0;
    bool v6 = false;
    bool operator==(const PeerAddress&) const = default;
    bool same_ip(const PeerAddress& o) const { return ip == o.ip && scope == o.scope && v6 == o.v6; }
    std::string ip_string() const;  // as asio writes the address ("127.0.0.1", "::1", "fe80::1%eth0")
    std::string to_string() const { return ip_string() + ":" + std::to_string(port); }
    static PeerAddress v4(uint32_t host_order_ip, uint16_t port);
};

// Where a core's datagrams go (the shell: its UDP socket).
class DatagramSink {
public:
    virtual void send(std::span<const uint8_t> datagram, const PeerAddress& to) = 0;

protected:
    ~DatagramSink() = default;
};

// A sink that keeps what it is given (tests, tools).
class DatagramCollector final : public DatagramSink {
public:
    struct Sent {
        std::vector<uint8_t> bytes;
        PeerAddress to;
    };
    std::vector<Sent> sent;
    void send(std::span<const uint8_t> datagram, const PeerAddress& to) override { sent.push_back({{datagram.begin(), datagram.end()}, to}); }
};

enum class SessionState { AwaitHello, Welcomed, Streaming, Closing, Closed };

// What became of a datagram routed to a session (ServerCore counts it).
enum class DatagramVerdict { accepted, rejected, malformed };

// Scratch of one thread's client ticks (packing and sealing buffers), reused
// from tick to tick: ServerCore keeps one per tick thread (tick_pool.h), so
// that sessions ticked at once on several threads share nothing writable.
struct TickScratch {
    DatagramPacker packer;
    Scheduler::Scratch schedule;  // the scheduler's per-tick working memory (Scheduler::Scratch)
    // The ticking client's record plan (each character's baseline and
    // bits), made before its scheduler runs and read until its datagrams
    // are packed: one per thread, in cache from one client to the next.
    RecordPlan plan;
    std::vector<std::vector<uint8_t>> datagrams;
    std::vector<uint8_t> sealed;
};

struct TickResult {
    size_t datagrams = 0;
    size_t wire_bytes = 0;  // payload + UDP_IP_OVERHEAD per datagram, seal included
};

class ClientStream {
public:
    // A session in AwaitHello, opened at `now` from `remote` (its port
    // ignored: the TCP peer; ServerCore::open).
    ClientStream(ServerCore& core, uint64_t id, uint64_t token, double now, PeerAddress remote = {});
    ~ClientStream();
    ClientStream(const ClientStream&) = delete;
    ClientStream& operator=(const ClientStream&) = delete;

    // A session with no connection (benchmarks, tests, tools): Streaming at
    // once at a fixed kbps (set rate() to change), every instance of the core
    // announced (the InstanceAdded messages dropped), datagrams unsealed, to
    // PeerAddress{}. Not in the core's session table: the caller ticks it.
    static std::unique_ptr<ClientStream> detached(ServerCore& core, uint64_t id, double kbps);

    uint64_t id() const { return id_; }
    uint64_t token() const { return token_; }
    const std::string& name() const { return name_; }
    SessionState state() const { return state_; }
    bool is_open() const { return state_ != SessionState::Closed && state_ != SessionState::Closing; }
    bool welcomed() const { return state_ == SessionState::Welcomed || state_ == SessionState::Streaming; }
    const std::string& close_reason() const { return close_reason_; }
    bool bound() const { return bound_; }
    const PeerAddress& peer() const { return peer_; }
    const PeerAddress& remote() const { return remote_; }
    uint32_t seq() const { return seq_; }
    // What admission and eviction weigh (ServerCore): when it connected, was
    // welcomed, last heard an Ack from its bound address, last asked for
    // asset bytes; the characters it owns.
    double opened_at() const { return opened_; }
    double welcomed_at() const { return welcomed_; }
    double last_heard() const { return last_heard_; }
    double last_asset_request() const { return asked_assets_; }
    size_t owned_count() const { return owned_.size(); }

    // ------------------------------------------------------ control in --
    // A control message's length prefix: false (counted malformed, closed) when out of range.
    bool accept_length(uint32_t n);
    // One control message body. Returns whether to read the next one.
    bool on_control(std::span<const uint8_t> body, double now);
    // Refuse (counted) then Closing; the shell's own refusals too.
    void refuse(const std::string& reason, double now);
    // Closed at once (its characters despawned, logged); no-op when Closed.
    void close(const std::string& why);
    // Goodbye "evicted: <why>" then Closing (ServerCore::make_room).
    void evict(const std::string& why, double now);
    // Goodbye `reason` then Closing: the server ends the session (Server::stop:
    // "shutdown: the server is stopping"). No-op once Closing or Closed.
    void goodbye(const std::string& reason, double now);

    // ----------------------------------------------------- control out --
    // Framed messages waiting to be written, oldest first.
    const std::deque<std::vector<uint8_t>>& output() const { return out_; }
    // The oldest was written; Closing with nothing left: Closed.
    void on_written();
    // Tells the client about instances added and removed since it last heard
    // (never its own), in messages that fit the control limit: removals at
    // once, additions paced (announce_pending).
    void sync_instances();
    // Queues InstanceAdded batches of the instances not yet announced while
    // the queued output stays within half of max_queued_bytes (a 16,000-instance
    // scene is joined a batch at a time as the client reads; the rest waits
    // for on_written or the next tick). Until announced an instance gets no
    // importance and is not streamed.
    void announce_pending();
    bool announcing() const { return pending_at_ < pending_.size(); }

    // ------------------------------------------------------- datagrams --
    // The token matches (constant time) and the session is Welcomed or Streaming.
    bool accepts(uint64_t token) const;
    // Opens a sealed datagram with this session's key; false when it does not
    // seal, or the datagram is forged, replayed or unsealed.
    crypto::OpenResult open_sealed(std::span<const uint8_t> wire, std::vector<uint8_t>& plain);
    bool sealed() const { return opener_ != nullptr; }  // keys were sent in the Welcome
    // A WebSocket session (web_endpoint.h): its datagrams travel inside the
    // connection (TLS with wss://) and are never sealed, even with
    // ServerConfig::seal_datagrams (its Welcome carries no keys). Before Hello.
    void never_seal() { never_seal_ = true; }
    // A verified datagram for this session (ServerCore::on_datagram checked
    // the id and token): Bind -> Challenge (or BindAck from the bound address),
    // ChallengeResponse -> bound, Ack -> rate, Pose -> the owned character.
    // `size`: its bytes (opened); an answer goes to `from` only when smaller.
    DatagramVerdict on_datagram(const wire::Datagram& d, size_t size, const PeerAddress& from, double now, DatagramSink& out);

    // ------------------------------------------------------------ tick --
    // One tick of a Streaming session: the rate (refill by dt, re-evaluated
    // at now when adaptive), then send_frame within its budget.
    // `scratch`: the calling thread's (default: the core's own, one thread).
    // Reads the frame, the catalogue, the configuration and the core's owner
    // groups; writes only this session and `scratch`.
    TickResult tick(const EncodedFrame& frame, double now, double dt, DatagramSink& out, TickScratch& scratch);
    TickResult tick(const EncodedFrame& frame, double now, double dt, DatagramSink& out);
    // Importance (the view; 0 for instances not announced or own), the
    // selection within `budget` wire bytes, packing, sealing, to peer();
    // spends the rate and tells the scheduler.
    TickResult send_frame(const EncodedFrame& frame, size_t budget, DatagramSink& out, TickScratch& scratch);
    TickResult send_frame(const EncodedFrame& frame, size_t budget, DatagramSink& out);
    // A timeout is due at `now` (hello, bind, acks) or Closing ran out of time.
    bool expired(double now) const;
    // Acts on expired(): Goodbye and Closing, or Closed. True when it counts as a timeout.
    bool expire(double now);

    // -------------------------------------------- tuning (benchmarks) --
    RateController& rate() { return rate_; }
    // A detached stream's client acknowledging datagrams (benchmarks: what
    // its Ack would say): their bones become baselines (baseline_book.h).
    void acknowledge(uint32_t ack, uint32_t bits) { book_.on_ack(ack, bits); }
    uint32_t next_seq() const { return seq_; }  // the sequence number of the next datagram
    // This tick's record plan (each character's baseline and bits), made
    // before the scheduler or a selector runs. It lives in the thread's
    // TickScratch: valid until another client ticks on that thread.
    const RecordPlan& plan() const { return *plan_; }
    void set_view(ViewSpec v) { view_ = std::move(v); }
    // Where this client looks from (ServerConfig::view_radius): its camera,
    // else the world positions of its own characters in `frame`. Appends to
    // `out`; false when it has neither (it sees every character).
    bool view_centres(const EncodedFrame& frame, std::vector<glm::dvec3>& out) const;
    // Picks within a budget instead of the scheduler (bench_net_rd's
    // baselines); the scheduler is then neither asked nor told.
    using Selector = std::function<void(const EncodedFrame& frame, size_t budget, std::vector<Pick>& out)>;
    void set_selector(Selector s) { selector_ = std::move(s); }
    const std::vector<Pick>& picks() const { return picks_; }  // the last tick's
    const std::vector<float>& importance() const { return importance_; }
    // Instances whose importance the last tick computed: the slots near the
    // camera (the frame's grid), else every slot.
    size_t weighed() const { return weighed_; }

    // Repairs (ServerConfig::repair_lost): a frame datagram of a tick older
    // than kRepairTicks is not sent again; one datagram goes again at most
    // kMaxRepairs times (each a lost repair: repair_again), each time as
    // repair_copies(first loss) copies back to back, fewer (at least one)
    // when the budget does not hold them. A repair lost too comes back an
    // RTT later or more, after its tick was displayed, and such ticks were
    // most of the displayed error under loss at the full rate
    // (docs/performance.md "Repairs in two copies", "Repair copies for the
    // link's loss"): the copies are as many as make all of them lost less
    // likely than kRepairMiss at the link's loss before repairs
    // (BaselineBook::first_loss), from kRepairCopies up to kMaxRepairCopies.
    static constexpr int kRepairTicks = 6;
    static constexpr int kMaxRepairs = 5;
    static constexpr int kRepairCopies = 2, kMaxRepairCopies = 4;
    static constexpr double kRepairMiss = 1e-3;
    // The smallest n in kRepairCopies..kMaxRepairCopies with loss^n <= kRepairMiss
    // (kMaxRepairCopies when none). O(1).
    static int repair_copies(double loss);
    double first_loss() const { return book_.first_loss(); }  // BaselineBook::first_loss

private:
    // Published poses kept per character: twice the publisher's window
    // (POSE_BASELINES). A publisher predicts pose P from an acknowledged
    // pose A less than POSE_BASELINES older; with a ring of only
    // POSE_BASELINES, pose A + POSE_BASELINES overtaking P on the network
    // (one pose of reordering when P = A + 7) took A's place, and P was
    // dropped (poses_missing_baseline) though the publisher was honest.
    static constexpr uint32_t kPoseRing = 2 * POSE_BASELINES;
    struct Owned {
        int instance = 0;
        double tokens = 0, refilled = 0;  // pose rate limit (token bucket)
        // The newest kPoseRing published poses (ring by pose_seq): each
        // one's record integers and which bones arrived (the baselines of
        // predicted Pose records); allocated at the first Pose.
        std::array<uint32_t, kPoseRing> seq{};
        std::array<uint16_t, kPoseRing> received{};  // bones of each
        std::vector<RecordInts> ints;                // kPoseRing x bones
        std::vector<uint8_t> have;                   // kPoseRing x bones
        std::array<std::array<uint8_t, ROOT_BYTES>, kPoseRing> roots{};  // each one's root (absolute)
        uint32_t acked = 0, acked_sent = 0;  // newest pose held whole; the newest told (Frame.pose_acks)
    };
    std::vector<RecordInts> pose_ints_;        // on_pose: one Pose's records
    std::vector<wire::PoseAck> pose_acks_;     // send_frame: the acks that changed
    uint32_t pose_acks_tick_ = 0;              // the tick acks last went out alone
    static constexpr uint32_t kAloneAckTicks = 4;
    void send(const flatbuffers::FlatBufferBuilder& fbb);
    void finish(const flatbuffers::FlatBufferBuilder& last, const std::string& why, double now);
    void despawn_all();
    void log(const std::string& s) const;
    // Control messages (on_control); each returns whether to read on.
    bool on_hello(const wire::Hello& h, double now);
    std::string check_hello(const wire::Hello& h, double now);
    bool send_welcome(double cap, double now);
    bool on_asset_request(const wire::AssetRequest& r, double now);
    bool on_view(const wire::View& v);
    bool on_stats();
    void on_spawn(const wire::Spawn& m, double now);
    void spawned(uint32_t request, bool ok, int instance, const std::string& reason);
    bool on_despawn(const wire::Despawn& m);
    bool malformed(const std::string& why);
    // Datagrams (on_datagram).
    DatagramVerdict on_bind(size_t size, const PeerAddress& from, double now, DatagramSink& out);
    DatagramVerdict on_challenge_response(const wire::ChallengeResponse& r, size_t size, const PeerAddress& from, double now,
                                          DatagramSink& out);
    DatagramVerdict on_ack(const wire::Ack& a, const PeerAddress& from, double now, DatagramSink& out);
    DatagramVerdict on_pose(const wire::Pose& p, const PeerAddress& from, double now);
    void bind_ack(size_t size, const PeerAddress& from, DatagramSink& out);
    void answer(const flatbuffers::FlatBufferBuilder& fbb, size_t size, const PeerAddress& from, bool unverified, DatagramSink& out);
    // Sends one datagram to `to`, sealed (into `sealed`) when the session
    // seals; returns the bytes sent.
    size_t send_datagram(std::span<const uint8_t> plain, const PeerAddress& to, DatagramSink& out, std::vector<uint8_t>& sealed);
    // Each instance's importance this tick; `most`: candidate_limit (with a
    // camera only the nearest are weighed: near_importance).
    void update_importance(const EncodedFrame& frame, size_t most);
    bool near_importance(const EncodedFrame& frame, size_t most);
    static constexpr size_t kGridFrom = 4;  // near_importance from this many slots per candidate
    // The characters that can matter: at most max_candidates, and no more
    // than `budget` could carry a chunk of.
    size_t candidate_limit(size_t budget) const;
    // Leaves importance only to the `most` most important.
    void bound_candidates(size_t most, uint32_t tick);
    // Calls f(slot) for every slot this tick's importance may be non-zero
    // for: those near_importance weighed, else every slot.
    template <class F>
    void each_weighed(F f) const {
        if (near_valid_) {
            for (const uint32_t i : near_) f(size_t(i));
        } else {
            for (size_t i = 0; i < importance_.size(); ++i) f(i);
        }
    }
    static constexpr size_t kMinCandidates = 128;  // whatever the budget (a client sees at least its nearest 128)
    bool refuse_message(const std::string& reason, const std::string& why);

    ServerCore& core_;
    uint64_t id_ = 0, token_ = 0;
    SessionState state_ = SessionState::AwaitHello;
    std::string name_;
    std::string close_reason_;
    double opened_ = 0, welcomed_ = 0, last_heard_ = 0;  // last_heard: newest Ack from the bound address
    double asked_assets_ = -1e300;  // newest AssetRequest
    PeerAddress remote_;            // the TCP peer (port 0)
    double close_deadline_ = 0;
    std::deque<std::vector<uint8_t>> out_;
    size_t queued_ = 0;
    double asset_bytes_ = 0;
    // UDP: the proven address, and (return routability) the address a Bind
    // came from with the nonce sent there.
    PeerAddress peer_;
    bool bound_ = false;
    PeerAddress challenge_peer_;
    std::array<uint8_t, CHALLENGE_NONCE> challenge_nonce_{};
    double challenge_sent_ = -1e300;
    // seal_datagrams: server -> client and client -> server keys (sent in the Welcome).
    crypto::Key tx_key_{}, rx_key_{};
    std::unique_ptr<crypto::Sealer> sealer_;
    bool never_seal_ = false;
    std::unique_ptr<crypto::Opener> opener_;
    uint32_t seq_ = 0;
    RateController rate_;
    // Off (detached streams): no feedback is expected (no acks), so the tick
    // neither re-evaluates the estimate nor records sends for loss.
    bool adaptive_ = true;
    Scheduler scheduler_;
    BaselineBook book_;   // what this client acknowledged: the baselines of predicted records
    std::vector<BaselineBook::LostRun> lost_;  // on_ack's scratch: the bones of datagrams it shows lost
    // The last frame datagrams as sent (sealed when sealing), for repairs
    // (ServerConfig::repair_lost): a ring as long as an Ack's window, buffers
    // reused. A lost datagram goes again up to kMaxRepairs times while its
    // tick is at most kRepairTicks old: once when an Ack shows it lost, and
    // again when an Ack of a datagram sent after the repair leaves it out
    // while the repair left 9/8 of the RTT before (the repair was lost too).
    static constexpr size_t kKeptSent = 32;
    struct Kept {
        uint32_t seq = 0, tick = 0;
        uint32_t sent_us = 0;   // its last send (the first, or the last repair)
        uint8_t repairs = 0;    // sent again this many times
        bool valid = false;
        std::vector<uint8_t> bytes;
    };
    std::array<Kept, kKeptSent> kept_;
    uint32_t newest_tick_sent_ = 0;
    bool last_limited_ = true;  // the last tick left something due unsent (no room for repairs)
    // Sends kept datagram `seq` again when ServerConfig::repair_lost allows it.
    void repair(uint32_t seq, DatagramSink& out);
    // On an Ack (after book_.on_ack; ack and loss_delay as on_ack's): sends
    // again the kept datagrams whose repair it shows lost (acknowledgement
    // and first send times: book_). O(kKeptSent).
    void repair_again(uint32_t ack, uint32_t loss_delay_us, DatagramSink& out);
    const RecordPlan* plan_ = &no_plan_;  // plan(): the last tick's, in its scratch
    RecordPlan no_plan_;                  // before the first tick
    Selector selector_;
    ViewSpec view_;
    std::vector<glm::dvec3> centres_;  // update_importance's (view_radius)
    std::vector<float> importance_;
    std::vector<Pick> picks_;
    std::vector<uint32_t> known_;    // per instance slot: generation announced to this client (0: none)
    std::vector<std::pair<int, uint32_t>> pending_;  // (slot, generation) to announce, in order
    size_t pending_at_ = 0;          // next in pending_
    std::vector<size_t> candidates_, below_;  // bound_candidates' scratch
    std::vector<uint32_t> near_;      // near_importance: the instances weighed this tick (importance > 0)
    std::vector<uint32_t> below_near_;  // near_importance: those not yet above a ring's bound
    std::vector<uint32_t> weighed_list_;  // send_frame: the instances of non-zero importance after bound_candidates, ascending
    bool near_valid_ = false;         // this tick's importance came from near_importance (zero beyond near_)
    size_t weighed_ = 0;              // weighed()
    float cut_ = 0.0f;                // bound_candidates: the importance cut tried first (0: none)
    uint64_t instances_seen_ = ~0ull;  // ServerCore::instances_version last synced
    std::vector<Owned> owned_;       // characters this session spawned
};

}  // namespace progskin::net
