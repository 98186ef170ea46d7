// mesh_data.h — what the renderer draws, built from progskin's core data.
//
// MeshData is the vertex stream of one character ready for upload: bind-space
// positions and normals, optional UVs, triangles grouped by material, and the
// skinning attributes (joint indices into the palette the shader reads, and
// weights). mesh_from_skin takes the progressive skin's stream (progressive bone
// indices, influences ordered for dropping), so the GPU skins from exactly the
// palette PaletteJob builds on the CPU.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "character.h"
#include "mat34.h"
#include "progressive_skin.h"

namespace progskin::render {

struct Texture {
    int width = 0, height = 0;
    std::vector<uint8_t> rgba;  // width * height * 4, first row = top of the image (glTF uv (0,0))
};

struct MeshPart {             // one glTF primitive's triangles and material
    uint32_t first_index = 0;  // into MeshData::triangles (a multiple of 3)
    uint32_t index_count = 0;
    glm::vec4 base_color{0.8f, 0.8f, 0.8f, 1.0f};  // pbrMetallicRoughness.baseColorFactor
    int texture = -1;                               // index into MeshData::textures, -1 none
};

struct MeshData {
    std::vector<glm::vec3> positions;  // bind space
    std::vector<glm::vec3> normals;    // same count (smooth normals computed when the file has none)
    bool flat_shaded = false;          // the file has no normals: shade flat (glTF spec), normals unused
    std::vector<glm::vec2> uvs;        // same count, or empty
    std::vector<uint32_t> triangles;
    int influences = 4;                // slots per vertex (1..8)
    std::vector<uint16_t> joints;      // palette indices, positions.size() * influences
    std::vector<float> weights;
    std::vector<MeshPart> parts;
    std::vector<Texture> textures;
};

// The skin's vertex stream in progressive bone indices. With load_materials, UVs,
// base colour factors and base colour textures are read again from c.source
// (tinygltf, images decoded); a file that cannot be read gives flat grey parts.
MeshData mesh_from_skin(const Character& c, const ProgressiveSkin& s, bool load_materials = true);

// Palette of all B bones (progressive order) with the first k bones animated:
// own[b] = joint_matrices[s.order[b]] for b < k, the rest copied down with the
// skin's corrections (palette.h PaletteJob). joint_matrices: per Character joint.
std::vector<Mat34> lod_palette(const ProgressiveSkin& s, std::span<const Mat34> joint_matrices, int k);

// Axis-aligned bounds of points (lo > hi when empty).
struct Bounds {
    glm::vec3 lo{1e30f}, hi{-1e30f};
    void add(const glm::vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void add(std::span<const glm::vec3> ps) {
        for (const auto& p : ps) add(p);
    }
    bool valid() const { return lo.x <= hi.x; }
};

}  // namespace progskin::render
