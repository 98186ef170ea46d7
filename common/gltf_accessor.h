// gltf_accessor.h — the glTF file and accessor reading that the importer uses,
// for the other readers of glTF data (morph-target animation, the progressive
// glTF writer), so every file from outside is checked the same way.
#pragma once
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace tinygltf {
class Model;
class Value;
}

namespace progskin::gltf {

// Parses path (.glb or .gltf with embedded or external buffers) into model,
// images left undecoded. Checks the GLB container, glTF 2.0 and unsupported
// required extensions. Throws Error("<path>: <what is wrong>").
void load_model(const std::string& path, tinygltf::Model& model);

// Accessor `index` of model decoded to doubles, count * components values:
// byte strides, normalized integers and sparse substitution applied, every
// offset and index range-checked, NaN/Inf refused. `components` must be the
// accessor type's component count. Throws Error("<path>: <what> ...").
std::vector<double> read_accessor(const std::string& path, const tinygltf::Model& model, int index, int components,
                                  const std::string& what);

// An extension or extras value as JSON (objects, arrays, strings, booleans,
// numbers; anything else null).
nlohmann::json value_json(const tinygltf::Value& v);

}  // namespace progskin::gltf
