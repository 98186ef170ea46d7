// self_contained.h — a glTF whose buffers and images live in files beside it
// (`avatar.gltf` + `buffer.bin` + `skin.png`) turned into one GLB that
// holds them all, so that a client that downloads only that file can load it
// (progskin-server serves it; progskin build writes it).
//
// Every external URI is checked before anything is read: a plain relative
// file name (percent escapes decoded), no scheme or drive (`http:`, `C:`), no
// absolute path, no "..", no backslash, resolving (symbolic links followed)
// to a regular file inside the glTF's folder, each file at most
// kMaxEmbeddedFileBytes and all of them together at most
// kMaxSelfContainedBytes. `data:` URIs are embedded already and left as they
// are.
#pragma once
#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace tinygltf {
class Model;
}

namespace progskin {

// The largest file progskin embeds, and the largest self-contained GLB (the
// client's MAX_ASSET_BYTES, client/asset_cache.h: a larger asset is refused
// by every client).
inline constexpr uint64_t kMaxEmbeddedFileBytes = uint64_t(256) << 20;
inline constexpr uint64_t kMaxSelfContainedBytes = uint64_t(256) << 20;

// One external file of a glTF.
struct ExternalFile {
    std::string kind;            // "buffers" or "images"
    size_t index = 0;            // in that array
    std::string uri;             // as written in the file
    std::filesystem::path path;  // resolved, inside the glTF's folder
    uint64_t size = 0;
};

// Resolves one URI of the glTF at `gltf_path` under the rules above. Throws
// Error "<gltf_path>: <kind>[<index>] uri "<uri>": <why>" (a missing file
// names the path looked for).
ExternalFile resolve_external_uri(const std::string& gltf_path, const std::string& kind, size_t index,
                                  const std::string& uri);

// Every external (not data:) buffer and image URI of the glTF or GLB at
// `path`, each resolved and checked, their total bounded. Throws Error (the
// first problem; a file that does not parse as glTF JSON is left to the
// importer: empty list).
std::vector<ExternalFile> external_files(const std::string& path);

// The glTF or GLB at `path` as one self-contained GLB: external buffers
// appended to the binary chunk (their buffer views moved along), external
// images stored in it behind new buffer views (mimeType from the file's
// extension or its first bytes), every other member of the JSON kept as it
// is. Returns the file's bytes unchanged when nothing is external. Throws
// Error (a URI refused, a file shorter than its buffer's byteLength, the
// result over kMaxSelfContainedBytes).
std::vector<uint8_t> self_contained_glb(const std::string& path);

// The JSON object of a glTF or GLB file (a GLB's JSON chunk); a discarded
// value when the file is neither. Throws Error when it cannot be read.
nlohmann::json read_gltf_json(const std::string& path);

// For writers that go through tinygltf (offline/gltf_export.cpp): stores
// every image of `m` that has an external URI (relative to `source_path`,
// checked as above) in buffer 0 behind a new buffer view, clearing its URI.
// Expects buffers merged into buffer 0. Returns how many were embedded.
// Throws Error.
size_t embed_external_images(tinygltf::Model& m, const std::string& source_path);

}  // namespace progskin
