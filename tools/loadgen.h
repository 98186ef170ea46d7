// loadgen.h — progskin-loadgen's simulation (issue 26 item 4): N simulated
// players in one process against one progskin-server or a world of nodes
// (players spread round-robin over them, or in bands: LoadOptions::bands).
// Each player is a ClientSession
// (client/session.h, the real client's protocol core) behind a light shell:
// its own TCP connection (TLS as progskin-client: --pin / --ca / --insecure, or
// plain) and its own UDP socket (the server binds a session to the address
// its Bind came from; one socket per player), on LoadOptions::threads
// threads (default one), each with its own asio io_context and its share of
// the players (player i on thread i mod threads), no thread per player. Each player spawns one character
// of the catalogue, walks it around its own spot of a square grid, publishes
// its pose every tick (the clip's loop sampled once per asset at the tick
// rate, at most 3,600 frames, and shared by every player: each publishes the
// frame of its time), receives frames, acknowledges them (the session)
// and decodes every record received (decode_bone), but keeps no pose history
// and skins nothing (the session's FrameSink: no InstanceView per remote
// character). The decoded assets are shared between the players. Nothing is
// allocated per player turn once steady (tests/test_net_loadgen.cpp counts).
//
// What it measures, in the measurement window (after every player joined,
// plus `settle` seconds):
//   rate        per player, wire bytes received (payload + 28) / window, kbit/s
//   bones       the `show` of the chunks received (the server's LOD target)
//   latency     receipt: a publisher sets root.source_us = its send time
//               (now_seconds, the one clock of this process); the server
//               copies the root block into every frame chunk of that
//               character (the world bus too); an observer's sample is the
//               datagram's kernel arrival time (SO_TIMESTAMPNS) less the
//               source_us of a root it had not received before (each pose
//               counts once per observer, at its first receipt).
//               display: at each update (10 per second per player), for each
//               character of its nearest set, the session's display clock
//               tick d (display_tick) is placed among the ticks of the last 8
//               roots received and their source_us interpolated (held past
//               the newest, as the client holds); the sample is now less it,
//               as progskin-client measures it (client/run_client.cpp).
//               Same-node and cross-node (publisher on another node) apart.
//   starved     a pair (observer, character of its nearest `see` others,
//               both players streaming the whole window) starved when no chunk of
//               that character reached the observer for more than `starve_s`
//               in the window (the window's ends count: never received = the
//               whole window). A player starved when one of its pairs did.
// Exit status of the program: 0 when every player joined and streamed to the
// end, 1 otherwise (the report says why); starvation is reported, not fatal.
#pragma once
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "client.h"

namespace progskin::net {

struct LoadOptions {
    std::vector<ServerAddress> servers;  // one node, or a world (players round-robin)
    int players = 20;                    // 1..kMaxPlayers
    double duration = 10;                // measurement window, seconds
    double settle = 2;                   // seconds after the last join before the window
    double delay_ms = 100;               // display delay (ClientConfig::delay_ms); max_delay_ms the same
    double max_kbps = 256;               // each player's cap (0: the server's maximum)
    double tick_rate = 30;               // updates and poses per second per player
    std::string asset = "0";             // catalogue name or index of every player's character
    std::string clip = "all";
    double walk = 0.5;                   // walk radius, bounding-box diagonals (0: standing)
    double spacing = 2;                  // grid step between players' spots, diagonals
    int see = 100;                       // the nearest others each player must see (starved)
    // How players are spread over the nodes: round-robin (player i on node
    // i mod nodes: most neighbours are on other nodes) or bands (the grid's
    // rows cut in one band per node: neighbours on the same node but at the
    // bands' edges, as a world placing players by region would).
    bool bands = false;
    double starve_s = 1.0;
    double connect_rate = 100;           // players started per second
    int addresses = -1;                  // source addresses 127.0.0.2..; -1: auto (loopback: one per 16 players)
    bool tls = true, insecure = false;
    std::string ca_file, pin_sha256, token, cache_dir;
    double connect_timeout = 20;
    // A player whose session fails before it streams (refused while the
    // server is busy, a TLS handshake cut, no answer) starts again this
    // many times, as a game client would, after 0.5, 1, 2, ... s (jittered).
    int retries = 2;                     // 0..10
    // Threads, each with its own players (player i on thread i mod threads)
    // and io_context; 1: everything on the calling thread.
    int threads = 1;                     // 1..kMaxThreads
    double progress_s = 5;               // progress line period on stderr (0: none)
    bool verbose = false;
    // Called on each thread when its measurement window starts (true) and
    // ends (false); tests count allocations in between.
    void (*on_window)(bool start) = nullptr;

    static constexpr int kMaxPlayers = 4000;
    static constexpr int kMaxThreads = 64;
};

struct Percentiles {
    uint64_t samples = 0;
    double p50 = 0, p99 = 0, max = 0;
};

struct LoadReport {
    bool ok = false;
    std::string error;                 // why not ok (first failure), empty when ok
    int players = 0, nodes = 0, addresses = 0, threads = 1;
    double grid_step = 0;              // world units between two players' spots
    int joined = 0;                    // players that reached Streaming with their character spawned
    int failed = 0;                    // players whose session failed (refused, lost, timed out...), after their retries
    int retried = 0;                   // restarts of players that failed before streaming (LoadOptions::retries)
    std::vector<std::string> errors;   // the first failures, "player N (node): why"
    double join_seconds = 0;           // from the first start to the last join
    double window_seconds = 0;
    double rate_kbps_mean = 0, rate_kbps_min = 0, rate_kbps_max = 0;
    double bones_mean = 0;             // mean show of the chunks received in the window
    double bones_nearest_mean = 0;     // mean newest show over every player's nearest set at the end
    int see = 0;                       // the nearest set's size
    int seen_min = 0;                  // fewest characters of its nearest set a player received
    double seen_mean = 0;
    bool all_seen = false;             // every player received every character of its nearest set
    Percentiles receipt_ms, display_ms, cross_receipt_ms, cross_display_ms;
    int starved_players = 0;
    uint64_t starved_pairs = 0, pairs = 0;
    double max_gap_ms = 0;             // longest gap of a nearest-set pair in the window
    uint64_t frames = 0, malformed = 0, duplicates = 0, records = 0;
    uint64_t bad_records = 0;          // records or root blocks that did not decode (never expected)
    double loss_mean = 0;
    uint64_t poses_sent = 0, poses_refused = 0, spawn_refused = 0;
    double cpu_seconds = 0;            // this process (user + system) over the window
    double late_turns = 0;             // share of player updates more than one tick late
    uint64_t turns = 0;                // player updates in the window
};

// Runs the whole load (connect, spawn, stream, measure) and returns the
// report; never throws for what happens on the network (the report says it).
// Throws Error for options out of range. stop (optional): ends it early.
LoadReport run_loadgen(const LoadOptions& opt, const std::atomic<bool>* stop = nullptr);

std::string report_json(const LoadReport& r, const LoadOptions& opt);
std::string report_table(const LoadReport& r, const LoadOptions& opt);

}  // namespace progskin::net
