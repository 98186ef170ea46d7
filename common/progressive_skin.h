// progressive_skin.h — a progressive skin (docs/algorithms.md): the data a
// runtime needs (order, progressive parents, corrections, the vertex stream in
// progressive bone indices), its error table, and the LOD reconstruction.
// Building one is offline: offline/collapse.h (from a skin) and
// offline/scratch_build.h (from vertex animation).
//
// Bones are renumbered 0..B-1 so that any prefix 0..k-1 is closed under the
// progressive parent (parent[b] < b). An inactive bone b stands in as
// M_parent(b) * correction[b] (palette.h). The build is a greedy collapse: at
// each step the active bone whose collapse adds the least squared vertex error
// (over all vertices and training frames, against the full-detail reference) is
// collapsed into its target and becomes the last active bone; its correction is
// the least-squares fit that best stands in for it, or identity for plain
// copy-down.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "animation.h"
#include "character.h"
#include "mat34.h"
#include "skinning.h"

namespace progskin {

enum class Strategy : uint8_t {
    Reorder,    // progressive parent = nearest active ancestor in the artist's hierarchy
    Flatten,    // world-space bones, new minimal-error hierarchy
    LeafPrune,  // naive baseline: deepest bones dropped first, plain copy-down
    Scratch,    // built from vertex animation (issue 4)
    Hierarchy,  // as reorder, but only bones without active children collapse: every
                // bone follows its artist parent in progressive order and that parent is
                // its progressive parent (cheaper parent-relative records)
};
const char* strategy_name(Strategy s);
Strategy parse_strategy(const std::string& s);  // throws Error

struct LodError {
    int bones = 0;  // k
    double rms = 0, max = 0, rms_pct = 0, max_pct = 0;
    double influences = 0;  // mean distinct non-zero influences per vertex at k
    // Vertex-animation inputs only (docs/metrics.md §2): 100 ||A - A'||_F / ||A - Abar||_F; < 0 when not measured.
    double distortion_pct = -1;
};

struct ProgressiveSkin {
    Strategy strategy = Strategy::Reorder;
    std::vector<int> order;          // progressive bone b -> Character joint
    std::vector<int16_t> parents;    // progressive parent, parents[0] = -1, parents[b] < b
    std::vector<Mat34> corrections;  // stand-in correction per bone (identity for bone 0)
    std::vector<LodError> error;     // e(k) for k = 1..B at index k-1
    double diagonal = 0;
    // The vertex stream in progressive bone indices, influences of each vertex
    // ordered so that dropping the last ones costs least.
    int influences = 4;
    std::vector<uint16_t> joints;
    std::vector<float> weights;

    int bone_count() const { return int(order.size()); }
};

// The error table evaluated independently of the build: for every k, the
// palette (palette.h) and skinning (skinning.h) against the reference. With
// morph targets both sides use the frame's morph weights (lod_positions), so
// the table is the skinning error on the morphed mesh. build_progressive_skin
// returns this table for characters with morph targets (its collapse itself
// runs on the unmorphed mesh).
std::vector<LodError> evaluate_error_table(const Character& c, const ProgressiveSkin& s,
                                           const FrameSet& frames);

// A skinning job over c's bind positions with the progressive skin's vertex
// stream (all its influence slots); add normals / out_normals to skin normals.
SkinningJob skinning_job(const Character& c, const ProgressiveSkin& s, std::span<const Mat34> palette,
                         std::span<glm::vec3> out_positions);
// The same with the character's own vertex stream (file joint order): the
// full-detail reference when given the character's skinning matrices.
SkinningJob skinning_job(const Character& c, std::span<const Mat34> palette, std::span<glm::vec3> out_positions);

// Reconstructed vertices at frame f with k bones (copy-down with corrections),
// morph targets applied at the frame's exact weights before skinning.
void lod_positions(const Character& c, const ProgressiveSkin& s, const FrameSet& frames, size_t f,
                   int k, std::span<glm::vec3> out);

}  // namespace progskin
