// gltf_export.h — progressive glTF: a standard glTF 2.0 file whose skin lists
// its joints in progressive order, with each vertex's weights reordered for
// dropping, animations untouched, and the progressive data in the skin
// extension PROGSKIN_progressive_skin (docs/algorithms.md, "File format"):
//   { "version": 1, "strategy": "reorder", "parents": [-1, 0, ...],
//     "corrections": [12 floats per bone, row-major 3x4], "diagonal": d,
//     "error": [{"bones": k, "rms": .., "max": .., "rms_pct": .., "max_pct": ..,
//                "influences": ..}, ...], "fps": 30, "clips": "auto" }
// Any glTF viewer ignores the extension and plays the file as the input.
#pragma once
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "character.h"
#include "progressive_asset.h"
#include "progressive_skin.h"

namespace tinygltf {
class Model;
}

namespace progskin {


// Writes `skin` of `c` (imported from c.source) to out_path (.glb binary, or
// .gltf with embedded buffers). Self-contained: images the input keeps in
// files beside it are embedded (offline/self_contained.h embed_external_images;
// a URI it refuses or a missing image throws). The file is written to a temporary name and
// renamed, so a failure leaves no partial output. Throws Error.
// `extra`: further members of the extension object (e.g. "server", the
// server's precomputed tables, server/scene.h); must be an object or null.
void save_progressive(const Character& c, const ProgressiveSkin& skin, const std::string& out_path,
                      const std::string& note = "", const nlohmann::json& extra = nullptr);

// The extension object of a skin (the JSON above).
nlohmann::json progressive_extension_json(const ProgressiveSkin& skin);

// Writes a tinygltf model to path (.gltf: JSON with embedded buffers, else
// .glb), adding skin_ext[i] as the PROGSKIN_progressive_skin extension of skin
// i (tinygltf 2.7 does not write skin extensions). Buffers must already be one
// buffer without uri for .glb. Written to a temporary name, then renamed; no
// partial output on failure. Throws Error.
void write_gltf(tinygltf::Model& model, const std::map<int, nlohmann::json>& skin_ext, const std::string& path);

// Removes accessors that no mesh, skin or animation refers to and buffer
// views that no accessor or image refers to, and compacts buffer 0 (views
// keep their offset modulo 16, so every accessor keeps its alignment).
// Expects one buffer (after merging); does nothing for a model using an
// extension that refers to accessors by index (GPU instancing, Draco, meshopt,
// animation pointer). Returns the number of accessors removed.
size_t prune_unused(tinygltf::Model& m);

// Sets accessor.min/max where glTF requires them and the input left them out
// (POSITION attributes and morph targets, animation inputs), computed from
// the data. `path` names the file in error messages. Throws Error on bad data.
void add_missing_bounds(tinygltf::Model& m, const std::string& path);

// Appends `bytes` of data to buffer 0 of m (4-byte aligned) behind a new
// buffer view and accessor; returns the accessor index.
int append_accessor(tinygltf::Model& m, const void* data, size_t bytes, int component, int type, size_t count,
                    int target, bool normalized = false);

// Writes a copy of the glTF at `path` (as .glb, buffers merged, external
// images embedded as with save_progressive) in which the skins `first` come first, in that order, followed by
// the others in file order, with every node.skin and skin extension moved
// along: import_gltf of the copy lists the character of those skins as
// character 0 (what a client that imports character 0 needs). Throws Error.
void write_with_skins_first(const std::string& path, const std::vector<int>& first, const std::string& out_path);

}  // namespace progskin
