// skinning.h — linear blend skinning on the CPU (docs/metrics.md §1, glTF "Skins").
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

#include "mat34.h"

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

// ---- fast skinning (skinning_simd.cpp) -------------------------------------
//
// The same contract as SkinningJob over a layout built once per mesh, with
// two differences: normals are NOT renormalised unless asked (GPU and ozz
// skinning use them unnormalised; the blended normal of a rigid palette is
// already unit length), and weights may be quantised. Blocks of 16 vertices
// keep their joints and weights slot-major (16 joints of slot 0, 16 of slot 1,
// ...); positions and normals stay xyz. The kernel blends each vertex's 3x4
// matrices in one 16-lane vector (AVX-512; two with AVX2, three with SSE4,
// chosen at run time by Google Highway), transforms 4 vertices at a time and
// transposes the sums back to xyz. Joints are u8 when every index is < 256,
// else u16. The last kept slot's weight is not stored: it is 1 minus the
// others, so quantised weights still sum to 1 (rigid palettes stay rigid).
// docs/performance.md "CPU skinning" has the speed against ozz-animation and
// the plain loop, and the errors of the quantised formats.

enum class SkinWeightFormat : uint8_t {
    F32,  // exact (float, pre-normalised)
    U16,  // w rounded to k/65535: |dw| <= 7.7e-6 per stored slot, the last slot the sum of those
    U8,   // w rounded to k/255:   |dw| <= 2.0e-3 per stored slot (visible on large meshes)
};        // a run-time max_influences below the stream's divides these by the kept weight sum

// Built only by build_skin_stream (its members are private, so a stream is
// always consistent: joints < max_joint + 1, arrays sized for count).
class SkinStream {
public:
    int count() const { return count_; }                // vertices
    int influences() const { return influences_; }      // slots kept per vertex (1..8)
    bool has_normals() const { return !normals_.empty(); }
    bool u8_joints() const { return !joints8_.empty() || count_ == 0; }  // else u16
    SkinWeightFormat weight_format() const { return weight_format_; }
    uint16_t max_joint() const { return max_joint_; }   // the palette must be larger
    size_t bytes() const {                              // memory held by the arrays
        return (positions_.size() + normals_.size()) * sizeof(float) + joints8_.size() +
               joints16_.size() * sizeof(uint16_t) + weights_.size();
    }

private:
    friend bool build_skin_stream(SkinStream&, const SkinningJob&, SkinWeightFormat);
    friend struct SkinStreamAccess;  // the kernels (skinning_simd.cpp)
    int count_ = 0;
    int influences_ = 0;
    SkinWeightFormat weight_format_ = SkinWeightFormat::F32;
    uint16_t max_joint_ = 0;
    std::vector<float> positions_;       // xyz per vertex (+ padding)
    std::vector<float> normals_;         // the same, or empty
    std::vector<uint8_t> joints8_;       // per block of 16 vertices: influences * 16 (slot-major)
    std::vector<uint16_t> joints16_;     // the same when some joint is >= 256
    std::vector<uint8_t> weights_;       // per block: (influences - 1) * 16 of F32/U16/U8
};
constexpr int kSkinBlock = 16;

// Builds the stream of a SkinningJob's vertex data (positions, normals when
// given, joints, weights, influences; max_influences slots are kept, weights
// renormalised over them; palette and outputs are not read). Returns false
// and leaves out empty when the spans disagree in size, influences is not in
// 1..8 or max_influences < 1. Cost: one pass over the vertices, allocates.
bool build_skin_stream(SkinStream& out, const SkinningJob& src, SkinWeightFormat weights = SkinWeightFormat::U16);

struct SkinRunOptions {
    int max_influences = 0;     // use the first k slots of the stream (0 or >= influences: all);
                                // weights are renormalised over them as SkinningJob does
    bool renormalize = false;   // unit normals: rsqrt estimate + one Newton step (| |n| - 1 | < 2e-7)
};

// Skins a stream with a palette into out_positions (count) and, when not
// empty, out_normals (count; the stream must have normals). Returns false and
// writes nothing when a size is wrong, the stream was never built or the
// palette has <= max_joint entries. No allocation (a u8-joint stream copies the
// palette to 64-byte rows on the stack, 16 KiB at most). Cost per vertex
// (AVX-512): one 64-byte matrix load and one FMA per slot, then per attribute
// one multiply and ~2 shuffles; 1.5 Gvert/s at 1 influence, 0.3 at 8 (Zen 4).
bool skin_stream(const SkinStream& s, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
                 std::span<glm::vec3> out_normals = {}, const SkinRunOptions& options = {});

// One character of a frame for skin_many.
struct SkinTask {
    const SkinStream* stream = nullptr;
    std::span<const Mat34> palette;
    std::span<glm::vec3> out_positions;
    std::span<glm::vec3> out_normals;  // or empty
    SkinRunOptions options;
};
// Skins every task (a character: its stream, its palette, its influence limit)
// in order on the calling thread. All tasks are validated first: returns false
// and writes nothing when any is invalid (null stream or a skin_stream
// refusal). No allocation. Tasks are independent: split the list to use threads.
bool skin_many(std::span<const SkinTask> tasks);

// The SIMD target skin_stream dispatches to now ("AVX3", "AVX2", "SSE4", ...).
const char* skin_simd_target();

}  // namespace progskin
