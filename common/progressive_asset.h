// progressive_asset.h — loading a progressive glTF (one written by
// `progskin build`, offline/gltf_export.h): the character and, from its
// PROGSKIN_progressive_skin extension, the progressive skin. Runtime code:
// no fitting, no Eigen; the file is checked as every file from outside is
// (gltf_import.h), and the extension's values are range-checked.
#pragma once
#include <string>

#include "character.h"
#include "progressive_skin.h"

namespace progskin {

struct ProgressiveAsset {
    Character character;
    ProgressiveSkin skin;
    bool progressive = false;  // false: a plain glTF (skin not yet built)
};

// Reads a file; when it carries PROGSKIN_progressive_skin, the skin is read
// from it (joints already in progressive order), else progressive = false.
// Throws Error naming the file and what is wrong.
ProgressiveAsset load_progressive(const std::string& path, int character_index = 0);

// Decodes the extension of an already imported character (character joints in
// file order must be the progressive order). Used by load_progressive.
// raw_json (optional) receives the whole extension object as stored (JSON text).
bool read_progressive_extension(const std::string& path, const Character& c, ProgressiveSkin& out,
                                std::string* raw_json = nullptr);

}  // namespace progskin
