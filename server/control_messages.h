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

// A client's View: camera, field of view, viewport, explicit weights (the
// finite ones).
ViewSpec read_view(const wire::View& v);

// The Welcome: the session's ids, the UDP port, the tick rate, the cap and
// every asset's header; keys (server -> client, then client -> server) when
// datagrams are sealed, else null.
void build_welcome(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets, uint64_t session_id, uint64_t udp_token,
                   uint16_t udp_port, float tick_rate, double cap_kbps, const crypto::Key* tx_key, const crypto::Key* rx_key);

// InstanceAdded for `added` (id, spec); InstanceRemoved for `ids`.
void build_instances_added(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets,
                           std::span<const std::pair<int, InstanceSpec>> added);
void build_instances_removed(flatbuffers::FlatBufferBuilder& fbb, std::span<const uint16_t> ids);

void build_spawned(flatbuffers::FlatBufferBuilder& fbb, uint32_t request, bool ok, int instance, const std::string& reason);
// Bytes offset .. offset + n of the asset.
void build_asset_chunk(flatbuffers::FlatBufferBuilder& fbb, const ServerAsset& a, uint64_t offset, size_t n);
void build_stats(flatbuffers::FlatBufferBuilder& fbb, double estimate_kbps, double loss, double rtt_ms, uint32_t sent_datagrams);

}  // namespace progskin::net
