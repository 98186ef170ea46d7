// palette.h — the runtime palette builder of a progressive skin.
//
// Given the skinning matrices of bones 0..n-1 (what was animated or streamed),
// fills all B palette matrices in progressive order:
//   b <  n: out[b] = lerp(standin(b), own[b], presence[b])   (presence 1 if absent)
//   b >= n: out[b] = standin(b)
// with standin(b) = out[parent[b]] * correction[b] (copy-down; the correction
// is identity for a plain copy). Bone 0 is always its own matrix. O(B), no
// allocation; validate() checks sizes and parent[b] < b.
#pragma once
#include <cstdint>
#include <span>
#include <vector>

#include "mat34.h"

namespace progskin {

struct PaletteJob {
    std::span<const int16_t> parents;     // B progressive parents, parents[0] = -1
    std::span<const Mat34> corrections;   // B corrections (or empty: plain copy-down)
    std::span<const Mat34> own;           // n <= B own matrices of bones 0..n-1, n >= 1
    std::span<const float> presence;      // n blend weights in [0,1], or empty (all 1)
    std::span<Mat34> out;                 // B

    bool validate() const;
    void run() const;
};

// Smooth switching of bones on and off (no popping). Each bone has a presence
// in [0,1] that moves toward 1 (b < target) or 0 (b >= target) by 1/frames per
// step. The palette is built with own = bones 0..needed()-1 and presence().
class LodBlender {
public:
    LodBlender() = default;
    LodBlender(int bone_count, int blend_frames, int initial_k);
    void set_target(int k);       // clamped to 1..B
    void step();                  // advance one displayed frame
    int target() const { return target_; }
    int needed() const { return needed_; }  // bones whose own matrix is required
    std::span<const float> presence() const { return {presence_.data(), size_t(needed_)}; }
    bool settled() const;

private:
    void update_needed();
    std::vector<float> presence_;
    int target_ = 1, needed_ = 1, frames_ = 8;
};

}  // namespace progskin
