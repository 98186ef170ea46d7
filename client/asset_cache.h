// asset_cache.h — the client's asset files: the disk cache named by content
// hash (the Client downloads into it: AssetRequest / AssetChunk,
// docs/protocol.md), the checks a downloaded file passes before it is
// imported, and a cached file plus the server's Asset description turned
// into a ClientAsset.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "client_asset.h"
#include "wire.h"

namespace progskin::net {

// Largest asset file the client accepts; a larger announced size is refused
// before anything is allocated.
inline constexpr uint64_t MAX_ASSET_BYTES = uint64_t(256) << 20;

// $XDG_CACHE_HOME/progskin, else ~/.cache/progskin, else /tmp/progskin-cache.
std::string default_cache_dir();

// The cache file of an asset: DIR/<hex64(id)>.glb when its bytes are a
// binary glTF (they start with "glTF"; what progskin-server serves, whatever
// the catalogue name's extension), DIR/<hex64(id)>.gltf otherwise, so that a
// loader that picks its parser by extension reads it.
std::string cached_asset_path(const std::string& dir, uint64_t id, bool glb);
bool is_glb(std::span<const uint8_t> bytes);

// Writes `bytes` to `path` whole: into a temporary name unique to this
// process and `writer` (several clients may fill the same cache at once),
// then renamed, so that the file appears complete. Returns an empty string,
// or what failed.
std::string write_cached_asset(const std::string& path, std::span<const uint8_t> bytes, const void* writer);

// The whole file at `path` (empty when it cannot be read).
std::vector<uint8_t> read_file(const std::string& path);

// Throws Error unless every external buffer / image URI of the glTF or GLB at
// `path` is embedded (data:) or names an existing file inside the folder of
// `path` (a plain relative name: no "..", no absolute path, no scheme, no
// percent escapes; symbolic links resolved). Then the loader, which searches
// the file's folder first and the working directory second, only ever opens
// files in that folder.
void check_external_uris(const std::string& path);

// The record format an Asset table describes (translation box, scaled,
// reference scale, translation step) into out. Returns "" or what is wrong
// (a reference scale outside [2^-16, 2^16] or not finite, a translation step
// that does not suit the box: translation_step_fits). Reads nothing else; the
// client refuses the asset on a non-empty answer. O(1).
std::string read_asset_format(const wire::Asset& a, RecordFormat& out);

// Imports the cached file (after check_external_uris) and checks the server's
// skin description against it.
std::shared_ptr<ClientAsset> load_client_asset(const wire::Asset* a, const std::string& path);

}  // namespace progskin::net
