// session.h — ClientSession, the client's protocol core (docs/protocol.md
// "Session state machine", "Client display"): everything the client does
// between the bytes its sockets carry, and no socket. Bytes and time in,
// bytes to send and events out:
//
//   shell (client.cpp Client)              ClientSession
//   connect() ------------------------->  start(now, peer)                 Idle -> OpeningChannel
//   TCP connected (TLS) ---------------->  on_transport_connected()         -> Handshaking
//   channel ready (certificate checked) ->  on_channel_ready()              Hello -> AwaitWelcome
//   bytes read from the channel -------->  on_control_bytes(bytes, now)    Welcome -> Binding; ...
//   update(now) ------------------------>  update(now, source)             timeouts, View, Bind, then
//   datagrams received, as sent ------->    on_datagram(bytes, from_server, arrival) for each
//                                           (source->next; the session unseals), Acks, Stats, display
//   writes Outbox::control, sends Outbox's datagrams  <--  (appended by every call above)
//
// One phase enum (SessionPhase) replaces the client's loose flags; the
// public ClientState is derived from it (state()). A failure is a
// FailReason and its message (fail()). The asset downloads run from the
// Welcome on, beside Binding and Streaming (the server drops a session not
// bound 10 s after its Welcome, a download may take longer): they are the
// catalogue's progress, not a phase. The session writes a downloaded asset
// into the cache folder itself (asset_cache.h) and imports it; it seals and
// opens datagrams itself (proto/crypto.h, keys from the Welcome).
//
// No Asio, no OpenSSL: tests drive it directly (tests/test_client_session.cpp).
// Allocates nothing per update once steady (Outbox and its own buffers keep
// their capacity).
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "client.h"
#include "client_palette.h"
#include "pose_buffer.h"
#include "wire.h"

namespace progskin::net {

namespace crypto {
class Sealer;
class Opener;
}  // namespace crypto

// Reads an announced instance (control.fbs Instance) of a catalogue of
// `catalogue_size` assets into `out` (instance, clip, placement, publisher;
// asset and palette unset). Returns an empty string, or what is wrong (an
// unknown asset, a negative clip index, a value not finite, a rotation that
// is not a unit quaternion). Clip indices are checked against the asset
// once it is loaded. O(clips), allocates the clip list.
std::string read_instance(const wire::Instance& in, size_t catalogue_size, RemoteCharacter& out);

// ------------------------------------------------------ frame application --
// The one place a received Frame is applied (the client, tests, the fuzz
// target): the pose buffer of each instance, by instance id.
struct PoseTarget {
    PoseBuffer* buffer = nullptr;  // nullptr: unknown instance (its chunks are skipped)
    int record_size = 0;           // the asset's RecordFormat::size() (12 or 14: scaled or not); 0: unknown
};
struct FrameApplied {
    bool read = false;        // the frame passed read_frame (else nothing was applied)
    int applied = 0;          // runs of bones and morph blocks the pose buffers took
    int refused = 0;          // runs and morph blocks a pose buffer refused (inconsistent)
    size_t record_bits = 0;   // bits of the records of every run
    int unknown_chunks = 0;   // chunks of instances without a target
    int missing_baselines = 0;  // runs refused because a predicted record's baseline is not held (never acked)
    int predicted = 0;          // records decoded from a baseline
    // The oldest tick the display must reach back to for these runs: over
    // every accepted run of an instance that had frames, the older of its
    // newest frame before and this frame, and this frame less the bones'
    // last gap (PoseBuffer::last_gap); +infinity when none.
    double reach_from = std::numeric_limits<double>::infinity();
};
// Checks the whole frame (proto/frame_reader.h read_frame), then hands every
// run of bones to its instance's buffer (PoseBuffer::add_chunk with the
// chunk's epoch and root block) and every morph block (add_morphs).
// O(payload bytes), no allocation.
FrameApplied apply_frame(const FrameDatagram& frame, std::span<const PoseTarget> instances);

// -------------------------------------------------------------- output ---
// What the session has to send, in order, appended by its calls; the shell
// writes `control` to the channel (and removes what it takes) and sends the
// datagrams (then clear_datagrams). Capacities are kept: no allocation once
// steady.
struct Outbox {
    std::vector<uint8_t> control;          // framed control messages (4-byte length + body each)
    std::vector<uint8_t> datagram_bytes;   // datagrams to the server's UDP port, back to back (sealed when keyed)
    std::vector<uint32_t> datagram_ends;   // end offset of each in datagram_bytes
    size_t datagrams() const { return datagram_ends.size(); }
    std::span<const uint8_t> datagram(size_t i) const {
        const uint32_t begin = i ? datagram_ends[i - 1] : 0;
        return {datagram_bytes.data() + begin, datagram_ends[i] - begin};
    }
    void clear_datagrams() {
        datagram_bytes.clear();
        datagram_ends.clear();
    }
};

// Where update() reads the datagrams received since the last one (the
// shell's UDP socket; netcode.io's receive override).
class DatagramSource {
public:
    // The next datagram, false when none is pending. bytes: valid until the
    // next call; from_server: sent from the server's UDP address (others are
    // counted as malformed); arrival: its arrival time, now_seconds() clock.
    virtual bool next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) = 0;

protected:
    ~DatagramSource() = default;
};

// ------------------------------------------------------------ hooks ---
// For a shell that runs many sessions in one process (tools/loadgen.h:
// progskin-loadgen's simulated players). A session with a FrameSink keeps no
// pose history and builds no palette for its remote characters (no
// InstanceView: 48 frames of every bone of every character it knows, some
// 150 KB each, which 1,000 players seeing 1,000 characters could not hold):
// characters() stays empty, CharacterAdded / CharacterRemoved are still
// raised, and every received frame, read and checked as always
// (proto/frame_reader.h read_frame: lengths, masks, record sizes), goes to
// the sink chunk by chunk; a chunk whose show exceeds its asset's bones is
// not passed on, its runs counted in ClientStats::malformed, as a game
// client's pose buffer refuses and counts them. Acks, Stats, loss, rate, the display clock
// (display_tick) run as without it.
class FrameSink {
public:
    // A remote character announced with its asset ready (rc: its instance,
    // asset, clip, publisher), or removed (rc == nullptr).
    virtual void on_character(int instance, const RemoteCharacter* rc) = 0;
    // One chunk of a received frame of a known character, before its runs:
    // the frame's tick, the bones to show, the root block as received
    // (root_block.h, absolute or predicted; empty when none), the datagram's
    // arrival (the clock of update's now).
    virtual void on_chunk(int instance, uint32_t tick, int show, std::span<const uint8_t> root, double arrival) = 0;
    // A run of `count` parent-relative records (bone_record.h) of bones
    // first.. of that chunk, as received (not yet decoded).
    virtual void on_run(int instance, int first, int count, const RecordRun& records) = 0;
    // Called for every chunk of a frame of a known character while the frame
    // is checked, before any on_chunk of it: a sink may prefetch what its
    // on_chunk will touch (its misses then overlap). Default: nothing.
    virtual void prefetch(int /*instance*/, uint32_t /*tick*/) {}

protected:
    ~FrameSink() = default;
};
struct SessionHooks {
    FrameSink* frame_sink = nullptr;  // see FrameSink; nullptr: pose buffers and palettes (a game client)
    // Loads a catalogue asset from its cache file (default: load_client_asset);
    // a shell of many sessions shares one decoded asset between them by id.
    std::function<std::shared_ptr<ClientAsset>(const wire::Asset*, const std::string& path)> load_asset;
};

enum class SessionPhase : uint8_t {
    Idle,            // before start()
    OpeningChannel,  // TCP connect under way (the shell)
    Handshaking,     // TLS handshake and certificate check (the shell)
    AwaitWelcome,    // Hello sent; Refuse -> Failed
    Binding,         // Welcome received: Bind (answering each Challenge) until BindAck or a Frame
    Streaming,       // bound: frames, Acks, Stats, poses of the player's characters
    Closed,          // close(); Goodbye sent when the channel was up
    Failed,          // fail_reason(), error()
};

class ClientSession {
public:
    // out: where every call appends what is to be sent (owned by the caller,
    // outlives the session). clock: read after work that takes time
    // (importing an asset), on the clock of every `now` (tests pass theirs).
    ClientSession(ClientConfig cfg, Outbox& out, double (*clock)() = now_seconds);
    ~ClientSession();
    // Before start(): see SessionHooks.
    void set_hooks(SessionHooks hooks) { hooks_ = std::move(hooks); }
    ClientSession(const ClientSession&) = delete;
    ClientSession& operator=(const ClientSession&) = delete;

    // ------------------------------------------------ the shell's calls --
    // connect(): the connect timeout counts from now; peer ("host:port")
    // names the server in messages. Idle -> OpeningChannel.
    void start(double now, std::string peer);
    void on_transport_connected();  // TCP connected, the TLS handshake begins: -> Handshaking
    void on_channel_ready();        // the channel carries messages (certificate checked): Hello -> AwaitWelcome
    // Bytes read from the channel, any split: whole messages are handled.
    void on_control_bytes(std::span<const uint8_t> bytes, double now);
    void on_channel_closed();  // the server closed the channel (end of stream): Failed, ChannelLost
    // One datagram as received (sealed or not); arrival on the clock of now.
    void on_datagram(std::span<const uint8_t> bytes, bool from_server, double arrival);
    // Once per game frame (after the shell's socket reads): timeouts, View,
    // Bind when due, the datagrams of `source`, Acks, Stats, the display
    // clock and every character's palette.
    void update(double now, DatagramSource* source = nullptr);
    void clear_events();  // before the shell reads its sockets, once per update
    void fail(FailReason why, const std::string& text);
    // Failover (docs/protocol.md "Failover"): after a failure another server
    // of the same world may carry on (can_fail_over: the connection was lost,
    // timed out, refused or ended by the server; not a trust, configuration
    // or data failure). restart() starts over with that server as start()
    // does: the remote characters are removed (CharacterRemoved), the
    // player's characters keep their handles and are spawned again once the
    // new server's Welcome comes (Spawned again, with their new instance),
    // the view and cap are sent again, the assets are kept when the new
    // catalogue is the same (another catalogue fails: BadServerData). The
    // shell opens a new channel first. O(characters).
    bool can_fail_over() const;
    void restart(double now, std::string peer);
    // Closed; the Goodbye goes into Outbox::control when the channel is up.
    void close(const std::string& reason);

    // ------------------------------------------------------------ state --
    SessionPhase phase() const { return phase_; }
    ClientState state() const;
    bool running() const { return phase_ > SessionPhase::Idle && phase_ < SessionPhase::Closed; }
    bool channel_open() const { return phase_ >= SessionPhase::AwaitWelcome && phase_ <= SessionPhase::Streaming; }
    bool welcomed() const { return phase_ == SessionPhase::Binding || phase_ == SessionPhase::Streaming; }
    FailReason fail_reason() const { return fail_reason_; }
    const std::string& error() const { return error_; }
    uint16_t udp_port() const { return udp_port_; }  // the server's, from the Welcome

    // ----------------------------------------------- the game's calls --
    // As Client (client.h).
    std::span<const ClientEvent> events() const { return events_; }
    std::span<const RemoteCharacter> characters() const { return shown_; }
    const RemoteCharacter* character(int instance) const;
    const std::vector<std::shared_ptr<ClientAsset>>& assets() const { return assets_; }
    const std::vector<std::string>& asset_names() const { return asset_names_; }
    double tick_rate() const { return tick_rate_; }
    // The server tick displayed at `now` (the display clock: newest frame's
    // tick less the adaptive delay, as of the last update); NaN before the
    // first frame.
    double display_tick(double now) const;
    ClientStats stats(double now) const;
    void set_view(const ViewSpec& view);
    void set_max_kbps(double kbps);
    int spawn(const SpawnSpec& spec);
    bool publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport,
                 std::span<const float> morph_weights);
    void despawn(int handle);
    int instance_of(int handle) const;

private:
    struct CatalogueEntry {
        std::string name;
        uint64_t id = 0, size = 0;
        std::vector<uint8_t> bytes;  // downloaded so far (grows with what arrives)
        uint64_t requested = 0;
        int in_flight = 0;
        bool ready = false;
        bool failed = false;  // cannot be loaded (AssetFailed raised): skipped, its characters never shown
    };
    struct Remote {  // a remote character, by instance id
        RemoteCharacter rc;
        std::unique_ptr<InstanceView> view;
        int asset = -1;
        bool active = false, announced = false;  // announced: CharacterAdded raised (asset ready)
    };
    struct Own {  // a character of this player
        int handle = 0;
        int instance = -1;
        int asset = 0;
        uint32_t request = 0, pose_seq = 0;
        uint8_t epoch = 0;
        bool refused = false, gone = false;
        SpawnSpec spec;  // spawned again on the next server after a failover
        // Published poses as parent-relative records (publish()): the format,
        // the newest pose the server acknowledged holding whole (0: none,
        // reset at every Spawned), and the integers of the last
        // POSE_BASELINES poses sent (ring by pose_seq), the baselines of
        // predicted records.
        RelativeFormat fmt;
        uint32_t acked = 0;
        std::array<uint32_t, POSE_BASELINES> ring_seq{};
        std::vector<RecordInts> ring;  // POSE_BASELINES x bones
        std::array<std::array<uint8_t, ROOT_BYTES>, POSE_BASELINES> ring_root{};  // each one's root (absolute)
    };
    // The receive window of the frame stream: the newest sequence and the
    // 32 before it (Ack), the range seen (loss).
    struct AckWindow {
        bool started = false;  // a Frame arrived
        uint32_t ack = 0, bits = 0, min_seq = 0, max_seq = 0;
        uint64_t unique = 0;   // frames received once
        bool duplicate(uint32_t seq) const;
        void add(uint32_t seq);
    };

    void raise(ClientEvent::Type t, int instance = -1, int asset = -1, int handle = -1, std::string text = {});
    void send(const flatbuffers::FlatBufferBuilder& b);
    void send_datagram(const flatbuffers::FlatBufferBuilder& b);
    void handle_control(std::vector<uint8_t>& body, double now);
    void on_welcome(const wire::Welcome* w, double now);
    bool same_catalogue(const wire::Welcome& w) const;
    void send_spawn(const Own& o);
    void respawn_own();
    bool was_welcomed() const { return welcome_ != nullptr; }  // stays true once Failed or Closed
    void start_downloads();
    void request_chunks();
    void on_asset_chunk(const wire::AssetChunk& ch, double now);
    void asset_loaded(size_t i, const std::string& path);
    bool all_assets_ready() const;
    bool on_instance_added(const wire::Instance& in);
    void make_view(size_t id);
    void remove_remote(int id);
    void on_spawned(const wire::Spawned& m);
    void handle_frame(const FrameDatagram& f, size_t wire_bytes, double t);
    FrameApplied sink_frame(const FrameDatagram& f, double arrival);
    bool stream_checks(double now);
    void send_ack(double now);
    void send_stats(double now);
    void send_view();
    void display(double now);
    bool has_characters() const;
    Own* find_own(int handle);

    ClientConfig cfg_;
    SessionHooks hooks_;
    Outbox& out_;
    double (*clock_)();
    SessionPhase phase_ = SessionPhase::Idle;
    FailReason fail_reason_ = FailReason::None;
    std::string error_, peer_;
    std::vector<ClientEvent> events_;
    double started_ = 0;  // start() time

    // control channel
    std::vector<uint8_t> rx_, rx_body_;           // bytes received; one message body
    flatbuffers::FlatBufferBuilder ctl_fbb_{256};  // Stats, the one periodic control message

    // session (Welcome)
    uint64_t session_ = 0, udp_token_ = 0;
    double tick_rate_ = 30;
    uint16_t udp_port_ = 0;
    std::unique_ptr<crypto::Sealer> sealer_;  // sealed datagrams (Welcome.datagram_keys)
    std::unique_ptr<crypto::Opener> opener_;
    std::vector<uint8_t> sealed_buf_, opened_buf_;

    // assets
    std::string cache_;
    std::vector<uint8_t> welcome_body_;  // kept: the catalogue's Asset tables point into it
    const wire::Welcome* welcome_ = nullptr;
    std::vector<CatalogueEntry> catalogue_;
    std::vector<std::shared_ptr<ClientAsset>> assets_;
    std::vector<std::string> asset_names_;
    size_t downloading_ = 0;   // index of the asset being downloaded
    double last_progress_ = 0; // last asset chunk (or the start of the download)

    // remote characters
    std::vector<Remote> remotes_;       // indexed by instance id
    std::vector<PoseTarget> targets_;   // remotes_' pose buffers, for apply_frame
    // characters(): one entry per character with a view, in instance order;
    // rebuilt when characters come or go, updated in place every update.
    std::vector<RemoteCharacter> shown_;
    std::vector<int> shown_ids_;
    bool shown_dirty_ = true;

    // frame stream (bound: phase Streaming, after a BindAck or a Frame)
    AckWindow window_;
    uint32_t ack_echo_ = 0;
    double ack_arrival_ = 0, last_ack_sent_ = 0, next_bind_ = 0, next_stats_ = 0, last_datagram_ = 0;
    uint64_t since_ack_ = 0;
    bool ack_now_ = false;  // a gap in the sequence: acknowledge at the next update
    double t_first_ = 0;
    double last_frame_at_ = 0;  // newest frame datagram (ClientStats::max_gap_ms)
    ClientStats st_;
    // failover: when the last server was lost (0: streaming), the loss
    // figures of the servers before
    double lost_at_ = 0;
    uint64_t loss_unique_before_ = 0, loss_span_before_ = 0;

    // display clock (display())
    double base_delay_ = 0, max_delay_ = 0, delay_ticks_ = 0, needed_delay_ = 0, last_display_time_ = 0;
    // The needed delay decays by this factor per second: the display keeps
    // covering the latest gaps and late frames (a lossy link's repairs come
    // every second or so) for about ten seconds.
    static constexpr double kDelayMemory = 0.9;
    double tick_offset_ = -1e300;

    // view and cap
    ViewSpec view_;
    bool view_set_ = false, view_dirty_ = false;
    double cap_ = 0;

    // own characters
    std::vector<Own> own_;
    uint32_t next_request_ = 1;
    std::vector<int16_t> pose_morphs_;
    // publish() scratch: model-space poses, their decoded poses, the records'
    // bits (all bones) with each bone's bit offset, one datagram's bits.
    std::vector<BonePose> pose_model_, pose_decoded_;
    std::vector<uint8_t> pose_bits_, pose_chunk_, pose_root_;
    std::vector<uint32_t> pose_offsets_;
    void apply_pose_acks(const FrameDatagram& f);
    flatbuffers::FlatBufferBuilder fbb_{1400};
};

}  // namespace progskin::net
