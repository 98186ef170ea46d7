// bone_codec.h — the quantised bone record of the frame stream.
//
// A bone's skinning matrix M = G * InverseBind (model space, GUIDE.md §1) is
// sent as a record of 12 bytes (14 when the asset is `scaled`):
//   bytes 0..5   rotation, "smallest three": 2-bit index of the largest
//                quaternion component (made positive), then the other three
//                in that order as 15-bit fixed point over [-1/sqrt2, 1/sqrt2],
//                packed little-endian into 48 bits (1 bit unused).
//   bytes 6..11  translation, 3 x uint16 little-endian, fixed point over the
//                asset's translation box [t_min, t_max] (Asset.t_min/t_max).
//   bytes 12..13 (scaled assets only) uniform scale as int16 log2(s) * 2048.
// Precision: per quaternion component <= 2.2e-5, rotation angle <= 1.5e-4 rad;
// translation <= box extent / 131070 per axis; scale <= 1.7e-4 relative.
// quantisation_bound() turns that into a vertex error bound (model units);
// tests/test_net_codec.cpp measures the actual error with the error metric.
// Non-uniform scale and shear in M are not representable (dropped).
#pragma once
#include <cstdint>
#include <span>

#include "math.h"

namespace progskin::net {

struct RecordFormat {
    glm::vec3 t_min{-1.0f}, t_max{1.0f};
    bool scaled = false;
    static constexpr int kPlainSize = 12, kScaledSize = 14;  // record bytes
    int size() const { return scaled ? kScaledSize : kPlainSize; }
};

// Decoded bone: rotation (unit quaternion), translation, uniform scale.
struct BonePose {
    glm::quat r{1, 0, 0, 0};
    glm::vec3 t{0.0f};
    float s = 1.0f;
};

BonePose decompose(const Mat34& m);
Mat34 compose(const BonePose& p);
// The inverse transform (rotation, translation, uniform scale).
BonePose inverse(const BonePose& p);
// Cubic (Hermite) interpolation between a (time ta) and b (tb) at time t,
// tangents by finite differences over the neighbours p0 (t0 < ta) and p3
// (t3 > tb): for translation, scale and the quaternion's components (aligned
// to a's hemisphere, then normalised). Exact for poses moving along a cubic.
BonePose interpolate_cubic(const BonePose& p0, const BonePose& a, const BonePose& b, const BonePose& p3, double t0,
                           double ta, double tb, double t3, double t);
// Interpolation between two poses of a bone: slerp (shortest path) for the
// rotation, lerp for translation and scale.
BonePose interpolate(const BonePose& a, const BonePose& b, float t);

// Writes fmt.size() bytes. O(1), no allocation.
void encode_bone(const BonePose& p, const RecordFormat& fmt, uint8_t* out);
BonePose decode_bone(const uint8_t* in, const RecordFormat& fmt);

// Worst-case vertex error (model units) of one record for vertices whose
// bind-space distance from the origin is at most bind_radius and scale at most max_scale.
double quantisation_bound(const RecordFormat& fmt, double bind_radius, double max_scale = 1.0);

}  // namespace progskin::net
