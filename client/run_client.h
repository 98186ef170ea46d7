// run_client.h — progskin-client's session (the program, not the library a
// game embeds; not installed): runs a Client (client.h) for
// options.duration seconds, publishes the --publish characters, and reports
// what it received and displayed; in verification mode measures the
// displayed vertices against the reference (docs/metrics.md §2).
// render/ draws its DisplaySnapshot (render/snapshot.h, --snapshot-every).
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "client.h"
#include "errors.h"

namespace progskin::net {

// What the client displays at one moment, handed to ClientOptions::on_snapshot
// (a renderer draws it: render/snapshot.h). Spans are valid during the call.
struct DisplayedCharacter {
    int instance = 0;
    const Character* character = nullptr;
    const ProgressiveSkin* skin = nullptr;
    const SkinStream* stream = nullptr;  // skin's vertex stream for skin_stream
    std::span<const Mat34> palette;  // B matrices in progressive order (copy-down and blending applied)
    glm::vec3 position{0.0f};        // world placement
    int bones = 0;                   // bones displayed (the LOD target)
    std::span<const float> morph_weights;  // displayed morph weights (apply before skinning), empty without targets
};
struct DisplaySnapshot {
    double seconds = 0;    // since streaming began
    double rate_kbps = 0;  // over the last full second
    std::vector<DisplayedCharacter> characters;
};

struct PublishOptions {
    std::string asset;             // the catalogue's file name, or its index
    std::string clip;              // a clip name/index/list/"all" (select_clips); empty: every clip together
    double walk = 0;               // radius in bounding-box diagonals (0: standing)
};

struct ClientOptions {
    std::string host = "127.0.0.1";
    uint16_t port = 7777;
    std::vector<ServerAddress> failover;  // the servers after host:port, tried in turn when one is lost
    std::string udp_via_host;
    uint16_t udp_via_port = 0;
    std::string name = "progskin-client";
    std::string token;
    double max_kbps = 0;
    ViewSpec view;
    bool send_view = false;
    double duration = 10;          // seconds of streaming
    double delay_ms = 100;
    double max_delay_ms = 600;
    double display_rate = 30;      // displayed frames per second
    bool verify = false;           // measure displayed vertices against the reference
    double warmup = 1.0;           // seconds of display not counted in bones/error statistics
    int verify_every = 1;
    bool snap_to_ticks = false;
    int blend_frames = 8;
    std::string cache_dir;
    uint16_t protocol_version = 0;
    double connect_timeout = 10;
    bool tls = false;              // ClientConfig::tls, ca_file, pin_sha256, insecure
    std::string ca_file;
    std::string pin_sha256;
    bool insecure = false;
    bool verbose = false;
    std::vector<std::pair<double, double>> cap_schedule;  // (seconds since streaming began, kbit/s): tests
    double snapshot_every = 0;
    std::function<void(const DisplaySnapshot&)> on_snapshot;
    std::function<void(const std::string&, uint64_t, uint64_t)> on_download;
    std::vector<PublishOptions> publish;  // characters to spawn and publish (--publish)
    double publish_rate = 30;      // poses per second per published character
};

struct InstanceReport {
    int instance = 0;
    std::string asset;
    double bones_mean = 0;
    int bones_min = 0, bones_max = 0;
    double rms_pct = -1, max_pct = -1;  // -1 (JSON null): not verified
    double max_jump_pct = -1;  // largest change of a vertex's error between displayed frames; -1: not verified
    uint64_t frames = 0;      // displayed frames with a pose
    bool published = false;   // a player's character
};

struct ClientReport {
    double seconds = 0;
    double rate_kbps = 0;
    double rate_max_kbps = 0;
    std::vector<double> per_second_kbps;
    double max_gap_ms = 0;     // longest time between two frames received (ClientStats::max_gap_ms)
    uint64_t datagrams = 0, malformed = 0, duplicates = 0;
    uint64_t predicted_records = 0, missing_baselines = 0;  // ClientStats
    double loss = 0;
    int characters = 0;        // instances with at least one frame received
    double bones_mean = 0, bones_min = 0, bones_max = 0;
    double rms_pct = -1, max_pct = -1;  // -1: not verified
    double max_jump_pct = 0;
    double rtt_ms = 0, estimate_kbps = 0;
    double delay_ms = 0;
    uint64_t asset_bytes_downloaded = 0;
    int assets_cached = 0;
    double download_seconds = 0;  // from connecting until every asset was ready (cache or download)
    std::vector<InstanceReport> instances;
    // Remote published characters (--verify): error against what their
    // publisher displays at the same world time, and latency from the
    // publisher's send to this display (same clock: loopback).
    int remote_characters = 0;
    double remote_rms_pct = -1, remote_max_pct = -1;
    double latency_ms_p50 = -1, latency_ms_p99 = -1;
    int published = 0;         // characters this client published
    uint64_t poses_sent = 0;
    uint64_t poses_predicted = 0;  // of them, predicted from a pose the server acknowledged
    double pose_kbps = 0;          // Pose datagrams sent (sealed + 28 bytes each) over the session
    // Assets of the catalogue this client could not load (ClientEvent::AssetFailed):
    // (name, why). Their characters are not shown; the others are.
    std::vector<std::pair<std::string, std::string>> assets_failed;
    // Why the session ended early ("" when it ran its duration): the
    // Client's error (the server closed the connection, a timeout, bad data).
    std::string error;
    // The server ended the session with a Goodbye (FailReason::SessionEnded):
    // its reason is in `error` (kShutdownReason when it stopped cleanly).
    bool server_goodbye = false;
    int failovers = 0;                  // servers lost and replaced by the next (ClientStats::failovers)
    double failover_seconds_to_stream = 0;  // the longest time from losing a server to the next frame
};

// run_client's failure after it connected: what was received until then,
// with ClientReport::error (and server_goodbye) set.
struct ClientRunError : Error {
    ClientRunError(const std::string& what, ClientReport r) : Error(what), report(std::move(r)) {}
    ClientReport report;
};

// Runs a session for options.duration seconds. Throws Error (refusal,
// timeout, bad server data, lost stream, the server's Goodbye) with a
// message for the user: a ClientRunError carrying the report so far once
// connect() returned (an unresolvable host throws a plain Error).
ClientReport run_client(const ClientOptions& options);
std::string report_json(const ClientReport& r);
std::string report_text(const ClientReport& r);

}  // namespace progskin::net
