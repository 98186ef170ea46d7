// bone_codec.h — the quantised bone record of the frame stream.
//
// A bone's skinning matrix M = G * InverseBind (model space, docs/metrics.md §1) is
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

#include "mat34.h"
#include "pose.h"  // BonePose, compose/decompose, interpolation

namespace progskin::net {

struct RecordFormat {
    glm::vec3 t_min{-1.0f}, t_max{1.0f};
    bool scaled = false;  // records carry a scale: some skinning matrix's differs from `scale`
    // The skin's reference scale: the scale most of its skinning matrices
    // share (reference_scale, pose.h), 1 for most files; 0.01 for one whose
    // armature node turns centimetres into metres. A plain (not scaled)
    // record's bone has this scale. The parent-relative records code bone 0's
    // scale against it and the other bones' translations in their parent's
    // units (bone_record.h), so such a skin codes as it would unscaled.
    float scale = 1.0f;
    // The parent-relative records' translation step (protocol 10, Asset.t_step;
    // bone_record.h RelativeFormat::t_step); 0: the box's largest extent /
    // 65,535. The box covers every rigid pose of the skeleton (live poses go
    // beyond the clips); the step is that of the clips' own box, so that the
    // clips stream as finely as a box of theirs alone would give.
    float t_step = 0.0f;
    static constexpr int kPlainSize = 12, kScaledSize = 14;  // record bytes
    int size() const { return scaled ? kScaledSize : kPlainSize; }
};

// Writes fmt.size() bytes. O(1), no allocation.
void encode_bone(const BonePose& p, const RecordFormat& fmt, uint8_t* out);
BonePose decode_bone(const uint8_t* in, const RecordFormat& fmt);

// True when encode_bone represents p within its stated precision: every
// value finite, the translation inside [t_min, t_max] (to half a step), the
// scale inside the int16 log2 range (scaled formats) or fmt.scale to 1e-3
// relative (plain formats, which carry no scale). Out-of-range poses are refused by their
// producers, never clamped into a wrong pose (docs/protocol.md).
bool bone_in_range(const BonePose& p, const RecordFormat& fmt);

// True when a received record is one encode_bone can write: its three
// rotation components (and the one they imply) form a unit quaternion whose
// dropped component is the largest, and the unused bit is clear. Every
// translation and scale code decodes to a finite value. O(1).
bool record_valid(const uint8_t* record, const RecordFormat& fmt);

// The root block of a chunk or Pose (ROOT_BYTES = 26): an instance's world
// placement, apart from its bone records (which are relative to it).
//   bytes 0..11  position, 3 x int32 little-endian millimetres (+-2147 km)
//   bytes 12..17 rotation, the bone record's 48-bit "smallest three"
//   bytes 18..25 source time, uint64 little-endian microseconds of the
//                pose's producer clock (publisher, or the server for clips)
struct RootPose {
    glm::dvec3 position{0.0};
    glm::quat rotation{1, 0, 0, 0};
    uint64_t source_us = 0;
};
// Returns false (writing nothing) when a value is not finite or the
// position is outside +-2^31 mm.
bool encode_root(const RootPose& r, uint8_t* out);
RootPose decode_root(const uint8_t* in);
// Interpolates two roots (lerp position, slerp rotation, lerp source time).
RootPose interpolate(const RootPose& a, const RootPose& b, double t);

// Worst-case vertex error (model units) of one record for vertices whose
// bind-space distance from the origin is at most bind_radius and scale at most max_scale.
double quantisation_bound(const RecordFormat& fmt, double bind_radius, double max_scale = 1.0);

}  // namespace progskin::net
