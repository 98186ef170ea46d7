// skinning.h — linear blend skinning on the CPU (GUIDE.md §1, glTF "Skins").
//
// v' = sum_i w_i * palette[j_i] * v for the first max_influences slots of each
// vertex, weights renormalised over the slots kept (a vertex whose kept weights
// sum to 0 keeps its first slot at weight 1). Normals use the 3x3 part and are
// renormalised. Influence slots are ordered for dropping (progressive_skin.h),
// so limiting max_influences drops the least important ones.
#pragma once
#include <cstdint>
#include <span>
#include <vector>

#include "math.h"

namespace progskin {

struct SkinningJob {
    std::span<const glm::vec3> positions;  // N bind-space positions
    std::span<const glm::vec3> normals;    // N normals, or empty
    std::span<const uint16_t> joints;      // N * influences palette indices
    std::span<const float> weights;        // N * influences
    int influences = 4;                    // slots per vertex in joints/weights (1..8)
    int max_influences = 8;                // slots used at run time (1..influences)
    std::span<const Mat34> palette;
    std::span<glm::vec3> out_positions;    // N
    std::span<glm::vec3> out_normals;      // N, or empty (then normals are not skinned)

    // True when every span has the right size and every joint index is in the palette.
    bool validate() const;
    void run() const;  // reference scalar loop; no allocation
};

// The same contract over a packed vertex layout built once per mesh and
// influence count: per vertex (x,y,z,1) and (nx,ny,nz,0) as 16-byte rows, u16
// joints and weights pre-normalised over the kept slots. skin_packed blends the
// 3x4 matrices of a vertex with 4-wide SIMD (SSE, FMA when the CPU has AVX2)
// and transforms once; several times faster than SkinningJob::run.
struct PackedSkin {
    int count = 0;
    int influences = 0;       // slots packed per vertex (the max_influences it was packed for)
    std::vector<float> pos;   // 4 floats per vertex
    std::vector<float> nrm;   // 4 floats per vertex
    std::vector<float> wgt;   // influences per vertex
    std::vector<uint16_t> jnt;
    uint16_t max_joint = 0;   // largest joint index packed (checked against the palette)
};
PackedSkin pack_skin(std::span<const glm::vec3> positions, std::span<const glm::vec3> normals,
                     std::span<const uint16_t> joints, std::span<const float> weights,
                     int influences, int max_influences);
// Skins a PackedSkin; out_normals may be empty. Returns false (and does
// nothing) when the palette is smaller than max_joint + 1 or an output span has
// the wrong size; otherwise the cost is only the arithmetic.
bool skin_packed(const PackedSkin& p, std::span<const Mat34> palette,
                 std::span<glm::vec3> out_positions, std::span<glm::vec3> out_normals);

}  // namespace progskin
