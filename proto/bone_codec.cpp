// bone_codec.cpp — see bone_codec.h.
#include "bone_codec.h"

#include <algorithm>
#include <cmath>

namespace progskin::net {
namespace {

constexpr float kInvSqrt2 = 0.70710678118654752f;
constexpr float kRotSteps = 32767.0f;   // 15 bits
constexpr float kTransSteps = 65535.0f; // 16 bits
constexpr float kScaleUnit = 2048.0f;   // log2 scale fixed point

uint32_t quant(float v, float lo, float hi, float steps) {
    float x = (v - lo) / (hi - lo);
    if (!(x > 0.0f)) x = 0.0f;  // also NaN
    if (x > 1.0f) x = 1.0f;
    return static_cast<uint32_t>(std::lround(x * steps));
}
float dequant(uint32_t q, float lo, float hi, float steps) { return lo + (hi - lo) * (float(q) / steps); }

}  // namespace

namespace {
void encode_rotation(const glm::quat& r, uint8_t* out) {
    float q[4] = {r.x, r.y, r.z, r.w};
    int big = 0;
    for (int i = 1; i < 4; ++i)
        if (std::fabs(q[i]) > std::fabs(q[big])) big = i;
    float sign = q[big] < 0.0f ? -1.0f : 1.0f;
    uint64_t bits = uint64_t(big);
    int shift = 2;
    for (int i = 0; i < 4; ++i) {
        if (i == big) continue;
        bits |= uint64_t(quant(q[i] * sign, -kInvSqrt2, kInvSqrt2, kRotSteps)) << shift;
        shift += 15;
    }
    for (int i = 0; i < 6; ++i) out[i] = uint8_t(bits >> (8 * i));
}
}  // namespace

bool bone_in_range(const BonePose& p, const RecordFormat& fmt) {
    if (!std::isfinite(p.r.x) || !std::isfinite(p.r.y) || !std::isfinite(p.r.z) || !std::isfinite(p.r.w) ||
        !std::isfinite(p.s))
        return false;
    for (int a = 0; a < 3; ++a) {
        const float half = (fmt.t_max[a] - fmt.t_min[a]) / kTransSteps * 0.5f;
        if (!(p.t[a] >= fmt.t_min[a] - half && p.t[a] <= fmt.t_max[a] + half)) return false;
    }
    if (fmt.scaled) {
        const float l = std::log2(p.s) * kScaleUnit;
        return p.s > 0.0f && l >= -32768.0f && l <= 32767.0f;
    }
    return std::fabs(p.s / fmt.scale - 1.0f) <= 1e-3f;
}

bool encode_root(const RootPose& r, uint8_t* out) {
    int32_t mm[3];
    for (int a = 0; a < 3; ++a) {
        const double v = std::round(r.position[a] * 1000.0);
        if (!(v >= -2147483648.0 && v <= 2147483647.0)) return false;  // also NaN
        mm[a] = int32_t(v);
    }
    const glm::quat q = r.rotation;
    if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z) || !std::isfinite(q.w)) return false;
    const float len = std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    if (!(len > 1e-6f)) return false;
    for (int a = 0; a < 3; ++a)
        for (int i = 0; i < 4; ++i) out[4 * a + i] = uint8_t(uint32_t(mm[a]) >> (8 * i));
    encode_rotation(q / len, out + 12);
    for (int i = 0; i < 8; ++i) out[18 + i] = uint8_t(r.source_us >> (8 * i));
    return true;
}

RootPose decode_root(const uint8_t* in) {
    RootPose r;
    for (int a = 0; a < 3; ++a) {
        uint32_t u = 0;
        for (int i = 0; i < 4; ++i) u |= uint32_t(in[4 * a + i]) << (8 * i);
        r.position[a] = double(int32_t(u)) / 1000.0;
    }
    uint8_t rec[RecordFormat::kPlainSize] = {};
    for (int i = 0; i < 6; ++i) rec[i] = in[12 + i];
    r.rotation = decode_bone(rec, RecordFormat{}).r;
    for (int i = 0; i < 8; ++i) r.source_us |= uint64_t(in[18 + i]) << (8 * i);
    return r;
}

RootPose interpolate(const RootPose& a, const RootPose& b, double t) {
    RootPose r;
    r.position = a.position + (b.position - a.position) * t;
    glm::quat qb = b.rotation;
    if (glm::dot(a.rotation, qb) < 0.0f) qb = -qb;
    r.rotation = glm::normalize(glm::slerp(a.rotation, qb, float(t)));
    r.source_us = a.source_us + uint64_t(std::llround(double(int64_t(b.source_us - a.source_us)) * t));
    return r;
}

void encode_bone(const BonePose& p, const RecordFormat& fmt, uint8_t* out) {
    encode_rotation(p.r, out);
    for (int a = 0; a < 3; ++a) {
        uint32_t v = quant(p.t[a], fmt.t_min[a], fmt.t_max[a], kTransSteps);
        out[6 + 2 * a] = uint8_t(v);
        out[7 + 2 * a] = uint8_t(v >> 8);
    }
    if (fmt.scaled) {
        float l = std::log2(std::max(p.s, 1e-9f)) * kScaleUnit;
        int v = int(std::lround(std::clamp(l, -32768.0f, 32767.0f)));
        uint16_t u = uint16_t(int16_t(v));
        out[12] = uint8_t(u);
        out[13] = uint8_t(u >> 8);
    }
}

BonePose decode_bone(const uint8_t* in, const RecordFormat& fmt) {
    uint64_t bits = 0;
    for (int i = 0; i < 6; ++i) bits |= uint64_t(in[i]) << (8 * i);
    int big = int(bits & 3);
    float q[4];
    float sum = 0.0f;
    int shift = 2;
    for (int i = 0; i < 4; ++i) {
        if (i == big) continue;
        q[i] = dequant(uint32_t(bits >> shift) & 0x7fff, -kInvSqrt2, kInvSqrt2, kRotSteps);
        sum += q[i] * q[i];
        shift += 15;
    }
    q[big] = std::sqrt(std::max(0.0f, 1.0f - sum));
    BonePose p;
    p.r = glm::normalize(glm::quat(q[3], q[0], q[1], q[2]));
    for (int a = 0; a < 3; ++a) {
        uint32_t v = uint32_t(in[6 + 2 * a]) | uint32_t(in[7 + 2 * a]) << 8;
        p.t[a] = dequant(v, fmt.t_min[a], fmt.t_max[a], kTransSteps);
    }
    if (fmt.scaled) {
        int16_t v = int16_t(uint16_t(in[12]) | uint16_t(in[13]) << 8);
        p.s = std::exp2(float(v) / kScaleUnit);
    } else {
        p.s = fmt.scale;  // a plain record's bone has the reference scale
    }
    return p;
}

bool record_valid(const uint8_t* in, const RecordFormat&) {
    uint64_t bits = 0;
    for (int i = 0; i < 6; ++i) bits |= uint64_t(in[i]) << (8 * i);
    float sum = 0.0f, largest_other = 0.0f;
    for (int i = 0, shift = 2; i < 3; ++i, shift += 15) {
        const float c = dequant(uint32_t(bits >> shift) & 0x7fff, -kInvSqrt2, kInvSqrt2, kRotSteps);
        sum += c * c;
        largest_other = std::max(largest_other, std::fabs(c));
    }
    if (bits >> 47) return false;  // the unused top bit
    const float step = 2.0f * kInvSqrt2 / kRotSteps;
    if (sum > 1.0f + 4.0f * step) return false;
    return std::sqrt(std::max(0.0f, 1.0f - sum)) + 2.0f * step >= largest_other;  // the dropped one is the largest
}

double quantisation_bound(const RecordFormat& fmt, double bind_radius, double max_scale) {
    const double h = (2.0 / std::sqrt(2.0)) / kRotSteps / 2.0;  // half step per component
    const double dq = std::sqrt(12.0) * h;                       // quaternion error norm
    const double angle = 2.0 * dq;                               // rotation angle error
    glm::dvec3 ext = glm::dvec3(fmt.t_max - fmt.t_min) / (2.0 * kTransSteps);
    double trans = glm::length(ext);
    double scale = fmt.scaled ? std::log(2.0) / (2.0 * kScaleUnit) : 0.0;
    // float32 arithmetic of compose/skinning adds a few ulps of the magnitudes.
    double fp = 1e-6 * (max_scale * bind_radius + glm::length(glm::dvec3(glm::max(glm::abs(fmt.t_min), glm::abs(fmt.t_max)))));
    return max_scale * bind_radius * (angle + scale) + trans + fp;
}

}  // namespace progskin::net
