// scratch_build.h — a progressive skin built from scratch for a mesh that has
// only vertex animation (docs/algorithms.md, "Build from scratch").
//
// Three methods (ScratchMethod; Auto builds Collapse and Hybrid and keeps the
// lower mean log RMS over k). Collapse: a full-detail decomposition (motion clustering by
// rigid trajectory fits, no mesh connectivity; then alternating per-vertex
// NNLS weights, Gauss-Seidel weighted Procrustes per bone and per-vertex bind
// positions), ordered by the greedy collapse of progressive_skin.h (strategy
// Flatten, least-squares corrections). TopDown: bone 0 is the whole mesh's
// per-frame Procrustes fit, bones are added one at a time each taking weight
// from its progressive parent, then SSDR refinement sweeps. Hybrid: top-down,
// each new bone the best of the region-grown one and bones started from the
// Collapse decomposition's motions. All end with the multi-level refit
// (transforms, corrections, weights and bind positions for a weighted sum of
// several levels' errors). Either way the table is evaluated honestly and is
// non-increasing (see the .cpp and docs/algorithms.md "Build from scratch").
//
// Output: a Character with one root node (identity, not a joint) whose
// children are the B joints (flat), each with rigid per-frame TRS animation
// (one clip "scratch", LINEAR keys at every frame), inverse bind matrices =
// inverse of the joint's rest transform (a translation to the weighted
// centroid of its vertices), joints in progressive order (order = identity),
// so sample_frames(character, {select_clips(character, "all")}, fps)
// reproduces the skinning matrices of the fit; and the ProgressiveSkin with
// strategy Scratch, its corrections (identity for top-down), and the error table evaluated
// honestly with lod_positions against the input animation.
//
// Memory O(V*F + B*F); time O(B * V * F) per bone added plus refinement.
#pragma once
#include <cstdint>
#include <functional>
#include <string>

#include "animation.h"
#include "character.h"
#include "progressive_skin.h"
#include "vertex_animation.h"

namespace progskin {

// How the skin is built (docs/algorithms.md "Build from scratch").
enum class ScratchMethod : uint8_t {
    Auto,      // Collapse and Hybrid, keep the one with the lower mean log RMS over k = 1..B
    Collapse,  // full-detail decomposition, then made progressive by greedy collapse
    TopDown,   // bones added one at a time, each splitting weight from its parent
    Hybrid,    // top-down, each new bone the best of the region-grown one and the
               // full-detail decomposition's bones (as starting motions)
};

struct ScratchOptions {
    int max_bones = 16;          // stop at this many bones (--bones)
    double max_error_pct = 0;    // stop once RMS <= this % of the diagonal (--max-error); 0 = off
    int rest_frame = -1;         // bind pose: -1 = per-vertex mean over frames, else this frame
    bool similarity = false;     // bones may scale uniformly
    ScratchMethod method = ScratchMethod::Auto;  // --method
    // Collapse: alternation iterations of the decomposition (stops earlier
    // when the error stalls) and whether bind positions are re-fitted.
    int iterations = 30;
    bool update_bind = true;
    // Top-down: global refinement sweeps after the greedy build (0 = none).
    int refine_sweeps = 4;
    // All methods: Gauss-Seidel sweeps of the multi-level refit after the
    // progressive order is known (0 = off).
    int multilevel_sweeps = 8;
    // Whether the multi-level refit also re-fits the weights and (with
    // update_bind) the bind positions for the sum of the levels' errors, not
    // only full detail (when that table rises somewhere, the refit without
    // them is the fallback).
    bool multilevel_weights = true;
    // Progress (step, total).
    std::function<void(int, int)> progress;
};
struct ScratchResult {
    Character character;
    ProgressiveSkin skin;
    FrameSet frames;  // sample_frames of the character's clip (what playback computes)
};

// Throws Error for an invalid animation (validate()) or options.
ScratchResult build_from_vertices(const VertexAnimation& anim, const ScratchOptions& options = {});

// The error table e(k), k = 1..B, of a progressive skin against a vertex
// animation: lod_positions (copy-down palette + skinning) of every frame
// against the input, RMS / max in units and % of `diagonal`, mean distinct
// influences, and the distortion percentage 100 ||A - A'||_F / ||A - Abar||_F
// (-1 when the animation does not move).
std::vector<LodError> scratch_error_table(const Character& c, const ProgressiveSkin& s, const FrameSet& frames,
                                          const VertexAnimation& anim, double diagonal);

// Writes the result as a progressive glTF (.glb, or .gltf with embedded
// buffers): mesh with POSITION, NORMAL (input normals or computed from the
// triangles), JOINTS_0/WEIGHTS_0, indices; the skin with its joints and
// inverse bind matrices; one animation with per-frame T/R (and S when the
// bones scale) channels; PROGSKIN_progressive_skin with the error table.
// load_progressive reads it back. Throws Error.
void save_scratch(const ScratchResult& r, const std::string& path);

}  // namespace progskin
