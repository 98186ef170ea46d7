// pose.cpp — see pose.h.
#include "pose.h"

#include <algorithm>
#include <cmath>

namespace progskin {

BonePose decompose(const Mat34& m) {
    glm::vec3 c0{m.m[0], m.m[4], m.m[8]}, c1{m.m[1], m.m[5], m.m[9]}, c2{m.m[2], m.m[6], m.m[10]};
    float det = glm::dot(c0, glm::cross(c1, c2));
    float s = std::cbrt(std::fabs(det));
    if (!(s > 1e-12f)) s = 1.0f;
    glm::mat3 r(c0 / s, c1 / s, c2 / s);
    BonePose p;
    p.r = glm::normalize(glm::quat_cast(r));
    p.t = {m.m[3], m.m[7], m.m[11]};
    p.s = s;
    return p;
}

Mat34 compose(const BonePose& p) {
    glm::mat3 r = glm::mat3_cast(p.r) * p.s;
    Mat34 m;
    for (int row = 0; row < 3; ++row) {
        for (int c = 0; c < 3; ++c) m.m[row * 4 + c] = r[c][row];
        m.m[row * 4 + 3] = p.t[row];
    }
    return m;
}

BonePose inverse(const BonePose& p) {
    BonePose q;
    q.r = glm::conjugate(p.r);
    q.s = p.s != 0.0f ? 1.0f / p.s : 1.0f;
    q.t = -(q.r * p.t) * q.s;
    return q;
}

BonePose interpolate(const BonePose& a, const BonePose& b, float t) {
    BonePose p;
    glm::quat qb = b.r;
    if (glm::dot(a.r, qb) < 0.0f) qb = -qb;
    p.r = glm::normalize(glm::slerp(a.r, qb, t));
    p.t = a.t + (b.t - a.t) * t;
    p.s = a.s + (b.s - a.s) * t;
    return p;
}

BonePose interpolate_cubic(const BonePose& p0, const BonePose& a, const BonePose& b, const BonePose& p3, double t0,
                           double ta, double tb, double t3, double t) {
    const double h = tb - ta;
    if (!(h > 0) || !(ta > t0) || !(t3 > tb)) return interpolate(a, b, float(h > 0 ? (t - ta) / h : 0.0));
    const double u = (t - ta) / h, u2 = u * u, u3 = u2 * u;
    const float h00 = float(2 * u3 - 3 * u2 + 1), h10 = float((u3 - 2 * u2 + u) * h), h01 = float(-2 * u3 + 3 * u2),
                h11 = float((u3 - u2) * h);
    const float ia = float(1.0 / (tb - t0)), ib = float(1.0 / (t3 - ta));
    // Quaternion components, on a's hemisphere.
    auto comp = [&](const glm::quat& q) {
        const glm::vec4 v(q.x, q.y, q.z, q.w);
        return glm::dot(a.r, q) < 0.0f ? -v : v;
    };
    const glm::vec4 q0 = comp(p0.r), qa = comp(a.r), qb = comp(b.r), q3 = comp(p3.r);
    const glm::vec4 q = h00 * qa + h10 * (qb - q0) * ia + h01 * qb + h11 * (q3 - qa) * ib;
    BonePose p;
    p.r = glm::normalize(glm::quat(q.w, q.x, q.y, q.z));
    p.t = h00 * a.t + h10 * (b.t - p0.t) * ia + h01 * b.t + h11 * (p3.t - a.t) * ib;
    p.s = h00 * a.s + h10 * (b.s - p0.s) * ia + h01 * b.s + h11 * (p3.s - a.s) * ib;
    return p;
}

BonePose interpolate_between(const BonePose* p0, const BonePose& a, const BonePose& b, const BonePose* p3, double t0,
                             double ta, double tb, double t3, double t) {
    if (p0 && p3) return interpolate_cubic(*p0, a, b, *p3, t0, ta, tb, t3, t);
    return interpolate(a, b, float((t - ta) / (tb - ta)));
}

bool translation_step_fits(const glm::vec3& t_min, const glm::vec3& t_max, float t_step) {
    if (t_step == 0.0f) return true;
    if (!(t_step > 0.0f) || !std::isfinite(t_step)) return false;
    const glm::vec3 ext = t_max - t_min;
    const float most = std::max({ext.x, ext.y, ext.z});
    return std::isfinite(most) && double(most) / double(t_step) <= double(1 << 22);
}

ReferenceScale reference_scale(std::span<float> scales) {
    ReferenceScale r;
    if (scales.empty()) return r;
    const auto mid = scales.begin() + std::ptrdiff_t(scales.size() / 2);
    std::nth_element(scales.begin(), mid, scales.end());  // reorders, keeps the set
    const float m = *mid;
    if (std::isfinite(m) && m >= kMinReferenceScale && m <= kMaxReferenceScale && std::abs(m - 1.0f) > 1e-4f) r.scale = m;
    for (float s : scales) r.scaled = r.scaled || std::fabs(s / r.scale - 1.0f) > 1e-4f;
    return r;
}

}  // namespace progskin
