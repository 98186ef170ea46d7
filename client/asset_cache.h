// asset_cache.h — the client's asset files: download over the control
// channel (AssetRequest / AssetChunk, docs/protocol.md) into a disk cache
// named by content hash, and turn a cached file plus the server's Asset
// description into a ClientAsset. Independent of the session loop: the
// transport is two callbacks, so any client object can drive it.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "client.h"
#include "client_palette.h"
#include "wire.h"

namespace progskin::net {

// How fetch_asset talks to the server: send one control message; wait up to
// `timeout` seconds for the next message body (false: none came).
struct AssetTransport {
    std::function<void(const flatbuffers::FlatBufferBuilder&)> send;
    std::function<bool(std::vector<uint8_t>&, double timeout)> next;
};

// Largest asset file the client accepts; a larger announced size is refused
// before anything is allocated.
inline constexpr uint64_t MAX_ASSET_BYTES = uint64_t(256) << 20;

// $XDG_CACHE_HOME/progskin, else ~/.cache/progskin, else /tmp/progskin-cache.
std::string default_cache_dir();

// Downloads (or finds in the cache) one asset file; returns its path. Memory
// grows with the bytes received (chunks must arrive in order), never with the
// size the server announces; sizes over MAX_ASSET_BYTES are refused.
std::string fetch_asset(const AssetTransport& ctl, const wire::Asset* a, const std::string& cache_dir, ClientReport& rep,
                        double timeout, const std::function<void(const std::string&, uint64_t, uint64_t)>& progress);

// Throws Error unless every external buffer / image URI of the glTF or GLB at
// `path` is embedded (data:) or names an existing file inside the folder of
// `path` (a plain relative name: no "..", no absolute path, no scheme, no
// percent escapes; symbolic links resolved). Then the loader, which searches
// the file's folder first and the working directory second, only ever opens
// files in that folder.
void check_external_uris(const std::string& path);

// Imports the cached file (after check_external_uris) and checks the server's
// skin description against it.
std::shared_ptr<ClientAsset> load_client_asset(const wire::Asset* a, const std::string& path);

}  // namespace progskin::net
