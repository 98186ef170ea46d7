// gltf_import.h — glTF 2.0 (.gltf with embedded or external buffers, .glb) to Characters.
//
// All primitives of all mesh nodes that use a skin are merged into one
// Character per skeleton (skins that share joints, or whose joints share a root
// joint, are one skeleton); meshes without a skin whose node descends from a
// joint become vertices with weight 1 on that joint. JOINTS_0/1, WEIGHTS_0/1
// (up to 8 influences), every component type the spec allows, byte strides and
// sparse accessors are read. Node matrices and TRS, inverse bind matrices
// (identity when absent), morph targets (POSITION and NORMAL deltas, default
// weights from node.weights or mesh.weights, names from extras.targetNames) and
// animation channels (translation, rotation, scale and morph weights) are read.
//
// Any defect throws progskin::Error("<file>: <what is wrong>"): not glTF, no
// skin, accessor or buffer view out of range, joint index out of range,
// NaN/Inf, cyclic nodes, missing buffer, bad key times.
#pragma once
#include <string>
#include <vector>

#include "character.h"

namespace progskin {

struct ImportOptions {
    bool require_skin = true;  // throw "<file>: no skin" if the file has no skinned mesh
};

// Every character (one per skeleton) in the file, in order of their first skin.
std::vector<Character> import_gltf(const std::string& path, const ImportOptions& options = {});

// Convenience: the character with the given index, with a clear error if out of range.
Character import_character(const std::string& path, int character_index = 0);

}  // namespace progskin
