// control_messages.h — the server's control messages (control.fbs) as
// FlatBuffers: the Welcome with the catalogue, InstanceAdded / Removed,
// Spawned, AssetChunk, Stats; and what it reads from a client's Spawn and
// View. Pure functions of their arguments (no session state: client_stream.h
// decides when to send them).
#pragma once
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "crypto.h"
#include "scene.h"
#include "view.h"
#include "wire.h"

namespace progskin::net {

using ServerAssets = std::vector<std::shared_ptr<ServerAsset>>;

// Reads a player's Spawn (control.fbs) against the catalogue into an
// instance owned by `owner` (live poses, the announced clips and walk).
// Returns an empty string, or why it is refused (an unknown asset or clip, a
// value not finite, a position outside the world). O(clips).
std::string read_spawn(const wire::Spawn& m, const ServerAssets& assets, uint64_t owner, InstanceSpec& out);

// Reads a client's View into `out`: camera, field of view, viewport and the
// explicit weights (the finite ones) sorted by instance, one per instance
// (the last given wins), so that the tick indexes them instead of scanning.
// Returns an empty string, or why it is refused (more than MAX_VIEW_WEIGHTS
// weights; `out` unchanged).
std::string read_view(const wire::View& v, ViewSpec& out);

// The Welcome: the session's ids, the UDP port, the tick rate, the cap and
// every asset's header; keys (server -> client, then client -> server) when
// datagrams are sealed, else null.
void build_welcome(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets, uint64_t session_id, uint64_t udp_token,
                   uint16_t udp_port, float tick_rate, double cap_kbps, const crypto::Key* tx_key, const crypto::Key* rx_key);

// The most bytes instance `sp`'s table adds to an InstanceAdded (at most
// MAX_INSTANCE_TABLE_BYTES: FrameEncoder refuses instances of more clips).
size_t instance_table_bound(const ServerAssets& assets, const InstanceSpec& sp);
// How many of `added`, from the front, go into one InstanceAdded: batches are
// cut by bytes (instance_table_bound) so that every message is within
// MAX_CONTROL_MESSAGE, and at most MAX_BATCH_INSTANCES tables (the verifier's
// table limit); at least 1 when `added` is not empty.
size_t instances_per_message(const ServerAssets& assets, std::span<const std::pair<int, InstanceSpec>> added);

// InstanceAdded for `added` (id, spec; at most instances_per_message of them);
// InstanceRemoved for `ids` (at most MAX_BATCH_REMOVED).
void build_instances_added(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets,
                           std::span<const std::pair<int, InstanceSpec>> added);
void build_instances_removed(flatbuffers::FlatBufferBuilder& fbb, std::span<const uint16_t> ids);

void build_spawned(flatbuffers::FlatBufferBuilder& fbb, uint32_t request, bool ok, int instance, const std::string& reason);
// Bytes offset .. offset + n of the asset.
void build_asset_chunk(flatbuffers::FlatBufferBuilder& fbb, const ServerAsset& a, uint64_t offset, size_t n);
void build_stats(flatbuffers::FlatBufferBuilder& fbb, double estimate_kbps, double loss, double rtt_ms, uint32_t sent_datagrams);

}  // namespace progskin::net
