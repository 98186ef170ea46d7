// client.h — the embeddable streaming client (docs/protocol.md), the header a
// game includes (installed; it names no wire, FlatBuffers or socket type).
//
// A game creates one progskin::net::Client, calls connect() once and then
// update(now) once per frame from its own loop. The client starts no threads
// and needs none: update() does the socket I/O (non-blocking), the asset
// downloads (disk cache by content hash), the acks and the display clock,
// then rebuilds the palette of every remote character for the display time.
// No allocation per update once the scene is steady (characters and assets
// allocate when they arrive).
//
//   Client c(cfg);
//   c.connect("127.0.0.1", 7777);
//   int me = c.spawn({.asset = 0});              // a character of the catalogue
//   for (;;) {
//       c.update(now_seconds());
//       for (const ClientEvent& e : c.events()) ...   // added, removed, spawned, lost
//       c.publish(me, root, skinning_matrices);  // my pose, joint order, relative to root
//       for (const RemoteCharacter& rc : c.characters())   // morph_weights: before skinning
//           draw(rc.asset->character, rc.root, rc.palette, rc.morph_weights);
//   }
//   c.close();
//
// Inside, a Client is a shell around the protocol core ClientSession
// (client/session.h: the state machine, control messages, assets,
// instances, acks, display clock; no socket): the Client owns the
// io_context, the TCP socket with its TLS stream and certificate check, and
// the UDP socket, and moves bytes between them and the session.
//
// Ownership: every pointer and span a Client returns is owned by it.
// characters() and each RemoteCharacter::palette / morph_weights are valid until the next
// update() or close(); RemoteCharacter::asset (a ClientAsset: character,
// progressive skin) stays valid as long as the Client lives. events() is
// valid until the next update().
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "bone_codec.h"
#include "character.h"
#include "client_asset.h"
#include "progressive_skin.h"
#include "view.h"

namespace progskin::net {

struct ClientConfig {
    std::string name = "progskin-client";
    std::string token;             // access token (Hello)
    double max_kbps = 0;           // 0: the server's maximum
    std::string udp_via_host;      // non-empty: send UDP here (progskin-netem) instead of the server
    uint16_t udp_via_port = 0;
    double delay_ms = 100;         // display delay behind the newest frame (minimum)
    double max_delay_ms = 600;     // the delay adapts up to this to cover gaps between frames
    int blend_frames = 8;          // LodBlender frames for bones switching on/off
    bool snap_to_ticks = false;    // display exactly on server ticks (no interpolation error)
    std::string cache_dir;         // asset cache (default $XDG_CACHE_HOME/progskin or ~/.cache/progskin)
    uint16_t protocol_version = 0; // 0: PROTOCOL_VERSION (tests send others)
    double connect_timeout = 10;   // seconds from connect() until the first frame (or every asset ready)
    double stream_timeout = 5;     // seconds without any datagram while characters exist: the stream is lost
    // TLS on the control channel (docs/protocol.md "Security"). The server's
    // certificate must be trusted one way at least: signed by a CA of
    // ca_file (PEM; the certificate must then name the host connected to),
    // and/or its SHA-256 fingerprint (hex of the DER, colons allowed) equal
    // to pin_sha256; insecure accepts any certificate (development only; the
    // caller warns). With none of them, connect() fails: never silent trust.
    // When the Welcome carries datagram keys (server --seal-datagrams), every
    // datagram both ways is sealed (proto/crypto.h); keys over plain TCP fail.
    bool tls = false;
    std::string ca_file;
    std::string pin_sha256;
    bool insecure = false;
    // Called after every asset chunk received (asset name, bytes so far, size); may be empty.
    std::function<void(const std::string&, uint64_t, uint64_t)> on_download;
};

// Monotonic seconds: the clock of update(now) (also declared in proto/wire.h).
double now_seconds();

enum class ClientState {
    Idle,        // before connect()
    Connecting,  // TCP, Hello, Welcome, asset downloads, UDP bind
    Streaming,   // bound: frames arrive, characters are displayed
    Closed,      // close() (the server's Goodbye is Failed, FailReason::SessionEnded)
    Failed,      // refused, unreachable, timed out, bad data, stream lost: see fail_reason(), error()
};

// Why a client is Failed (Client::fail_reason; the text is Client::error()).
enum class FailReason {
    None,           // not failed
    Config,         // TLS with nothing to trust the certificate by, a malformed pin, an unreadable CA file
    Unreachable,    // the server's address cannot be resolved or connected to
    TlsHandshake,   // the TLS handshake failed
    TlsUntrusted,   // the server's certificate is not trusted (CA chain, host name, pin)
    Timeout,        // connecting, the Welcome, a download or the UDP bind took longer than connect_timeout
    Refused,        // the server's Refuse (version, token, full)
    BadServerData,  // a malformed, unexpected or inconsistent message, asset or key from the server
    ChannelLost,    // the control connection closed or failed
    SessionEnded,   // the server's Goodbye
    StreamLost,     // no datagram for stream_timeout while characters exist
    LocalIo,        // the asset cache cannot be written
};

// What a publisher announced about a character (control.fbs Instance): the
// clips it plays from publisher_start_us (its clock), its walk.
struct PublisherInfo {
    bool published = false;
    uint64_t start_us = 0;
    glm::dvec3 walk_center{0.0};
    double walk_radius = 0, walk_speed = 0;
};

struct RemoteCharacter {
    int instance = 0;                    // the server's instance id (per server: frames use it)
    uint64_t world_id = 0;               // the character's id across a world of servers, the same on every node
                                         // (0 from a server that does not send one)
    const ClientAsset* asset = nullptr;  // character + progressive skin (lives as long as the Client)
    ClipInfo clip;                       // the clip it plays (server-driven), or announced by its publisher
    bool once = false;                   // the clip plays once and holds
    PublisherInfo publisher;
    RootPose root;                       // world placement at the display time (source_us: the pose's producer time)
    bool shown = false;                  // a pose exists at the display time (palette valid)
    std::span<const Mat34> palette;      // B matrices in progressive order (copy-down and blending applied)
    std::span<const float> morph_weights;  // one per morph target of asset->character (apply before skinning:
                                           // morph_positions in common/error_metric.h); empty without targets
    int bones = 0;                       // bones shown (the LOD target)
    // Of those, the bones whose records of the ticks around the display time
    // are here (PoseBuffer::bones_recorded): bones - fresh_bones are
    // interpolated across a longer gap (a lost datagram, a bone the
    // scheduler refreshed less often) or held.
    int fresh_bones = 0;
    double display_tick = 0;             // the server tick displayed
    // The time on the server's tick clock the displayed pose is of:
    // display_tick, but with snap_to_ticks the frame's own sample time
    // (a little before its tick when the server samples clips at their keys:
    // docs/protocol.md "Key samples").
    double pose_tick = 0;
};

struct ClientEvent {
    enum class Type {
        Connected,         // Welcome received
        AssetReady,        // an asset is downloaded (or found in the cache) and loaded: asset = index
        CharacterAdded,    // instance
        CharacterRemoved,  // instance
        Spawned,           // handle (spawn()) now owns instance
        SpawnRefused,      // handle; text: the server's reason
        Closed,            // text: close()'s reason (the server's Goodbye raises Failed)
        Failed,            // text: why (also in error())
        AssetFailed,       // an asset of the catalogue cannot be loaded: asset = index, text: why. The session
                           // goes on; characters of that asset are never shown (the others are)
        FailedOver,        // the server was lost (text: why, and the next server): the client connects to the
                           // next of connect()'s list; remote characters are removed (CharacterRemoved), the
                           // player's are spawned again there (Spawned, with their new instance)
    };
    Type type;
    int instance = -1;
    int asset = -1;
    int handle = -1;
    std::string text;
};

struct SpawnSpec {
    int asset = 0;                  // index into the server's catalogue (assets())
    std::vector<int> clips;         // announced to observers (their --verify reference); may be empty
    bool once = false;
    float speed = 1;
    uint64_t start_us = 0;          // publisher clock at clip start (source_us of publish)
    glm::dvec3 walk_center{0.0};
    double walk_radius = 0, walk_speed = 0;
    glm::vec3 position{0.0f};
};

struct ClientStats {
    double seconds = 0;            // since the first frame
    uint64_t datagrams = 0, malformed = 0, duplicates = 0, unknown_chunks = 0;
    // Records decoded from an acknowledged baseline, and runs refused because
    // a predicted record's baseline was not held (expected 0: the server
    // predicts only from acknowledged frames; such a datagram is not acked).
    uint64_t predicted_records = 0, missing_baselines = 0;
    uint64_t wire_bytes = 0;       // docs/metrics.md §3 rate bytes received (payload + 28 per datagram)
    double loss = 0;
    double rtt_ms = 0, estimate_kbps = 0;
    double delay_ms = 0;           // largest display delay used
    uint64_t asset_bytes_downloaded = 0;
    int assets_cached = 0;
    double download_seconds = -1;  // from connect() until every catalogue asset was ready (-1: not yet)
    uint64_t poses_sent = 0, poses_refused = 0;  // publish(): sent, and refused (out of the codec's range)
    uint64_t poses_predicted = 0;  // publish()es whose records were predicted from a pose the server acknowledged
    uint64_t pose_wire_bytes = 0;  // Pose datagrams sent (sealed size + 28 IP/UDP bytes each)
    std::vector<double> per_second_bytes;  // wire bytes per second since the first frame
    double max_gap_ms = 0;         // longest time between two frames received (the stream's worst stall)
    int failovers = 0;             // times the client lost its server and moved to the next of connect()'s list
    double failover_seconds = 0;   // the longest of them: from losing a server to the next frame (0: none)
};

// One server of a world (connect()'s list).
struct ServerAddress {
    std::string host;
    uint16_t port = 0;
};
// "HOST:PORT[,HOST:PORT...]" (IPv6 hosts in brackets: [::1]:7777). Throws
// Error naming the entry that is not HOST:PORT with a port in 1..65535.
std::vector<ServerAddress> parse_server_list(const std::string& list);

class Client {
public:
    explicit Client(ClientConfig config = {});
    ~Client();
    Client(const Client&) = delete;
    Client& operator=(const Client&) = delete;

    // Starts connecting (resolves host synchronously: pass a numeric address
    // to never block); update() carries on (TCP, then the TLS handshake and
    // certificate check when cfg.tls). Throws Error for an unresolvable
    // host or when called twice. With cfg.tls and nothing to trust the
    // certificate by (no ca_file, pin_sha256 or insecure), a malformed pin or
    // an unreadable CA file, the state is Failed on return (see error()).
    void connect(const std::string& host, uint16_t port);
    // Failover: connects to servers[0]; when the server is lost (the
    // connection closes or fails, its Goodbye, a timeout, no datagram for
    // stream_timeout, a refusal) the client connects to the next one of the
    // list, within the same update(), spawns the player's characters again
    // and sends its view and cap again (a FailedOver event, then Connected,
    // Spawned...). Each server is tried at most once per loss: when every
    // other one failed too, the state is Failed. Every server of the list must
    // serve the same catalogue (another one fails: BadServerData).
    void connect(std::span<const ServerAddress> servers);
    // Once per game frame; never blocks. `now`: seconds on now_seconds()'s clock.
    void update(double now);
    void close(const std::string& reason = "done");

    ClientState state() const;
    const std::string& error() const;  // why the state is Failed
    FailReason fail_reason() const;    // None unless Failed
    std::span<const ClientEvent> events() const;  // raised by the last update()
    std::span<const RemoteCharacter> characters() const;  // every remote character, by instance id
    const RemoteCharacter* character(int instance) const;  // nullptr when unknown
    // The server's catalogue; entries are null until their asset is ready
    // (and stay null for an asset that failed to load: AssetFailed).
    const std::vector<std::shared_ptr<ClientAsset>>& assets() const;
    const std::vector<std::string>& asset_names() const;  // catalogue names (Welcome), ready or not
    double tick_rate() const;
    ClientStats stats() const;

    // At any time (sent when connected); throws Error for more than
    // MAX_VIEW_WEIGHTS weights (the server would end the session).
    void set_view(const ViewSpec& view);
    void set_max_kbps(double kbps);        // 0: the server's maximum

    // Asks the server for a character of its catalogue; returns a handle.
    // The answer comes as a Spawned or SpawnRefused event.
    int spawn(const SpawnSpec& spec);
    // Publishes the newest pose of a spawned character: skinning matrices in
    // the Character's joint order, relative to the root, and the root in the
    // world (root.source_us: the publisher's clock). teleport marks a
    // discontinuity. Returns false when the handle is not spawned yet, the
    // stream is not bound, or a value is outside the codec's range (counted
    // in stats().poses_refused; nothing is clamped).
    // morph_weights (optional): every morph target's weight of the character
    // (glTF order, at most 255), sent with the pose; empty: none (the last
    // sent stay). A weight outside [-2, 2) refuses the pose like a matrix.
    bool publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport = false,
                 std::span<const float> morph_weights = {});
    void despawn(int handle);
    int instance_of(int handle) const;  // -1 until Spawned

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

// The world placement of a character walking a circle of `radius` around
// `center` at `speed` units/s, t seconds after it started (facing along the
// circle). radius 0: standing at center. Both publishers and observers
// (--verify reference) use it.
RootPose walk_root(const glm::dvec3& center, double radius, double speed, double t);

}  // namespace progskin::net
