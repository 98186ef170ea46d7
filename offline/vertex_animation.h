// vertex_animation.h — meshes that have only vertex animation: per-frame
// vertex positions, the input of the "build from scratch" method
// (scratch_build.h, docs/algorithms.md "Build from scratch").
//
// Three sources:
//   - glTF morph-target animation: every mesh primitive's POSITION plus its
//     morph targets, weighted by the node's `weights` animation channel
//     (LINEAR / STEP / CUBICSPLINE) or the mesh's default weights, evaluated at
//     fps from the first to the last key, in world space (the node's rest
//     world transform applied).
//   - any skinned glTF evaluated as vertices (import_character, the clips of
//     `clip` as in the rest of progskin, sample_frames, reference_positions);
//     the skeleton is then forgotten.
//   - PC2 point caches: "POINTCACHE2\0", int32 version (1), int32 numPoints,
//     float startFrame, float sampleRate, int32 numSamples, then numSamples *
//     numPoints * 3 float32 (little-endian).
//
// Every defect throws progskin::Error naming the file: truncated or oversized
// data, NaN/Inf, zero vertices or frames, bad header fields.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

namespace progskin {

struct VertexAnimation {
    std::string source;                // file it came from (or "synthetic")
    size_t vertex_count = 0;
    size_t frame_count = 0;
    double fps = 30.0;
    std::vector<glm::vec3> positions;  // frame-major: positions[f * vertex_count + v]
    std::vector<glm::vec3> normals;    // vertex_count rest normals, or empty
    std::vector<uint32_t> triangles;   // 3 indices per triangle (may be empty)
    // Bounding-box diagonal the error is reported against (docs/metrics.md §2): a
    // skinned input's rest pose; otherwise frame 0 (the skinning-decomposition
    // convention); 0 = compute from frame 0.
    double diagonal = 0;

    const glm::vec3* frame(size_t f) const { return positions.data() + f * vertex_count; }
    // Throws Error("<source>: ...") when sizes disagree, counts are zero or a
    // value is not finite.
    void validate() const;
};

struct VertexAnimationOptions {
    double fps = 30.0;            // sampling rate of glTF inputs (PC2 keeps its samples)
    std::string clip = "auto";    // skinned glTF: clip SPEC as in `progskin build`
    int character = 0;            // skinned glTF: character index
};

// By extension: .pc2 -> load_pc2; .gltf / .glb -> skinned if the file has a
// skin, else morph-target animation.
VertexAnimation load_vertex_animation(const std::string& path, const VertexAnimationOptions& options = {});

VertexAnimation load_pc2(const std::string& path);
void save_pc2(const VertexAnimation& anim, const std::string& path, float start_frame = 0.0f);

VertexAnimation load_gltf_morph_animation(const std::string& path, double fps = 30.0);
VertexAnimation load_gltf_skinned_as_vertices(const std::string& path, const VertexAnimationOptions& options = {});

// Where each run of a glTF input's vertices came from, in the order the
// loaders above merge them: mesh nodes by node index, then primitives (only
// those with POSITION; for a skinned input, those of character `character`,
// import_character's order). Lets an exporter keep per-primitive data the
// vertex animation does not carry (materials, UVs, colours, names). Empty
// for PC2 and for files that are not glTF. Throws Error as the loaders do.
struct SourcePrimitive {
    int node = -1, mesh = -1, primitive = -1;  // glTF indices in the source file
    uint32_t first = 0, count = 0;             // vertex range in the animation
};
std::vector<SourcePrimitive> gltf_source_primitives(const std::string& path, int character = 0);

// Bounding-box diagonal of frame f.
double frame_diagonal(const VertexAnimation& anim, size_t f = 0);

// Joins vertices whose positions are identical (bit for bit, -0 = +0) in every
// frame: the copies a mesh splits along UV or normal seams, which skinning-
// decomposition tools join before fitting (Dem Bones joins vertices at
// identical rest positions). Keeps the first vertex of each set, in input
// order, with its normal; remaps the triangles and drops those that collapse;
// keeps source, fps and diagonal. `representative`, if given, receives for
// every input vertex its index in the result. O(V*F) time, O(V) memory
// besides the result. Throws Error (naming the source) for no frames,
// positions that do not match vertices x frames or a triangle index out of
// range.
VertexAnimation join_coincident(const VertexAnimation& anim, std::vector<uint32_t>* representative = nullptr);

}  // namespace progskin
