// client.h — the streaming client (docs/protocol.md): connects, fetches the
// assets it lacks (disk cache by content hash), binds its UDP address,
// receives frames, acknowledges them, displays every instance at a fixed
// delay behind the newest frame (client_palette.h) and, in verification
// mode, measures the displayed vertices against the reference.
#pragma once
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "character.h"
#include "progressive_skin.h"
#include "scheduler.h"  // ViewSpec

namespace progskin::net {

// What the client displays at one moment, handed to ClientOptions::on_snapshot
// (a renderer draws it: render/snapshot.h). Spans are valid during the call.
struct DisplayedCharacter {
    int instance = 0;
    const Character* character = nullptr;
    const ProgressiveSkin* skin = nullptr;
    const SkinStream* stream = nullptr;  // skin's vertex stream for skin_stream
    std::span<const Mat34> palette;  // B matrices in progressive order (copy-down and blending applied)
    glm::vec3 position{0.0f};        // world placement announced by the server
    int bones = 0;                   // bones displayed (the LOD target)
};
struct DisplaySnapshot {
    double seconds = 0;    // since streaming began
    double rate_kbps = 0;  // over the last full second
    std::vector<DisplayedCharacter> characters;
};

struct ClientOptions {
    std::string host = "127.0.0.1";
    uint16_t port = 7777;
    std::string udp_via_host;      // non-empty: send UDP here (progskin-netem) instead of the server
    uint16_t udp_via_port = 0;
    std::string name = "progskin-client";
    std::string token;
    double max_kbps = 0;           // 0: the server's maximum
    ViewSpec view;
    bool send_view = false;
    double duration = 10;          // seconds of streaming
    double delay_ms = 100;         // display delay behind the newest frame (minimum)
    double max_delay_ms = 600;     // the delay adapts up to this to cover gaps between frames
    double display_rate = 30;      // displayed frames per second
    bool verify = false;           // measure displayed vertices against the reference
    double warmup = 1.0;           // seconds of display not counted in bones/error statistics
    int verify_every = 1;          // verify every n-th displayed frame
    bool snap_to_ticks = false;    // display exactly on server ticks (no interpolation error)
    int blend_frames = 8;          // LodBlender frames for bones switching on/off
    std::string cache_dir;         // asset cache (default $XDG_CACHE_HOME/progskin or ~/.cache/progskin)
    uint16_t protocol_version = 0; // 0: PROTOCOL_VERSION (tests send others)
    double connect_timeout = 10;
    bool verbose = false;          // per-second lines on stderr
    // Mid-run cap changes (seconds since streaming began, kbit/s): tests.
    std::vector<std::pair<double, double>> cap_schedule;
    // Called about every snapshot_every seconds of display (after the warm-up)
    // with what is shown; 0 or no callback: never.
    double snapshot_every = 0;
    std::function<void(const DisplaySnapshot&)> on_snapshot;
    // Called after every asset chunk received (asset name, bytes so far, size); may be empty.
    std::function<void(const std::string&, uint64_t, uint64_t)> on_download;
};

struct InstanceReport {
    int instance = 0;
    std::string asset;
    double bones_mean = 0;
    int bones_min = 0, bones_max = 0;
    double rms_pct = 0, max_pct = 0;
    double max_jump_pct = 0;  // largest change of a vertex's error between displayed frames
    uint64_t frames = 0;      // displayed frames with a pose
};

struct ClientReport {
    double seconds = 0;        // streaming time measured
    double rate_kbps = 0;      // GUIDE.md rate, mean over the run
    double rate_max_kbps = 0;  // highest full one-second window
    std::vector<double> per_second_kbps;
    uint64_t datagrams = 0, malformed = 0, duplicates = 0;
    double loss = 0;
    int characters = 0;        // instances with at least one frame received
    double bones_mean = 0, bones_min = 0, bones_max = 0;  // over instances' mean k
    double rms_pct = -1, max_pct = -1;  // -1: not verified
    double max_jump_pct = 0;
    double rtt_ms = 0, estimate_kbps = 0;
    double delay_ms = 0;       // largest display delay used
    uint64_t asset_bytes_downloaded = 0;
    int assets_cached = 0;
    std::vector<InstanceReport> instances;
};

// Runs a session for options.duration seconds. Throws Error (refusal,
// timeout, bad server data) with a message for the user.
ClientReport run_client(const ClientOptions& options);
std::string report_json(const ClientReport& r);
std::string report_text(const ClientReport& r);

}  // namespace progskin::net
