// pose.h — a bone's pose (rotation, translation, uniform scale), its matrix
// form and interpolation in time: the one place pose math lives. The wire
// codec (proto/bone_codec.h) quantises these poses; the client's pose buffer
// and the server's cost tables interpolate them with the same policy
// (interpolate_between), so what the cost model predicts is what a client shows.
//
// Every function is O(1), allocation-free and pure (reference_scale: O(n)).
#pragma once
#include <span>
#include "mat34.h"

namespace progskin {

// A bone stays shown this many ticks after its newest received frame; the
// wire's HOLD_TICKS (proto/wire.h) and the cost tables' hold (cost_model.h).
inline constexpr int kHoldTicks = 16;

// A bone's skinning matrix M (docs/metrics.md §1) as rotation (unit
// quaternion), translation and uniform scale.
struct BonePose {
    glm::quat r{1, 0, 0, 0};
    glm::vec3 t{0.0f};
    float s = 1.0f;
};

// M's rotation, translation and uniform scale (the cube root of |det|);
// non-uniform scale and shear are not representable (dropped).
BonePose decompose(const Mat34& m);
Mat34 compose(const BonePose& p);
// The inverse transform (rotation, translation, uniform scale).
BonePose inverse(const BonePose& p);

// Interpolation between two poses of a bone: slerp (shortest path) for the
// rotation, lerp for translation and scale.
BonePose interpolate(const BonePose& a, const BonePose& b, float t);
// Cubic (Hermite) interpolation between a (time ta) and b (tb) at time t,
// tangents by finite differences over the neighbours p0 (t0 < ta) and p3
// (t3 > tb): for translation, scale and the quaternion's components (aligned
// to a's hemisphere, then normalised). Exact for poses moving along a cubic.
// Falls back to interpolate() when the times are not increasing.
BonePose interpolate_cubic(const BonePose& p0, const BonePose& a, const BonePose& b, const BonePose& p3, double t0,
                           double ta, double tb, double t3, double t);

// The interpolation policy of the stream (docs/algorithms.md): between two
// received samples a (time ta) and b (tb), cubic when both outer neighbours
// (p0 before a, p3 after b, of the same clip or epoch) are known, else
// slerp/lerp. p0 and p3 may be null.
BonePose interpolate_between(const BonePose* p0, const BonePose& a, const BonePose& b, const BonePose* p3, double t0,
                             double ta, double tb, double t3, double t);

// Bounds of a skin's reference scale (RecordFormat::scale, proto/bone_codec.h):
// a received one outside them, or not finite, is refused.
inline constexpr float kMinReferenceScale = 1.0f / 65536.0f, kMaxReferenceScale = 65536.0f;
// Whether a translation step (RecordFormat::t_step, proto/bone_codec.h) suits
// the translation box [t_min, t_max]: 0 (the box's own step, its largest
// extent / 65,535), or finite and positive with the box's largest extent at
// most 2^22 steps (every translation of the box, and any difference of two,
// within the relative records' integers, bone_record.h kMaxTransInt). A
// received step that does not is refused. O(1).
bool translation_step_fits(const glm::vec3& t_min, const glm::vec3& t_max, float t_step);

// The reference scale of a skin whose skinning matrices have these scales
// (decompose's s): their median, or 1 when that is within 1e-4 of 1, not
// finite or outside the bounds above; `scaled` when some scale differs from
// it by more than 1e-4 relative (records then carry a scale). `scales` is
// reordered. O(n).
struct ReferenceScale {
    float scale = 1.0f;
    bool scaled = false;
};
ReferenceScale reference_scale(std::span<float> scales);

}  // namespace progskin
