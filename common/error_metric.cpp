#include "error_metric.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace progskin {

void ErrorAccumulator::add(std::span<const glm::vec3> reference, std::span<const glm::vec3> reconstructed) {
    const size_t n = std::min(reference.size(), reconstructed.size());
    double s = 0, m = 0;
    for (size_t i = 0; i < n; ++i) {
        const glm::dvec3 d = glm::dvec3(reference[i]) - glm::dvec3(reconstructed[i]);
        const double e2 = glm::dot(d, d);
        s += e2;
        m = std::max(m, e2);
    }
    add_squared(s, std::sqrt(m), double(n));
}

void ErrorAccumulator::add_squared(double sum_sq, double max, double samples) {
    sum_sq_ += sum_sq;
    max_ = std::max(max_, max);
    samples_ += samples;
}

ErrorStats ErrorAccumulator::stats() const {
    ErrorStats s;
    s.samples = samples_;
    s.rms = samples_ > 0 ? std::sqrt(sum_sq_ / samples_) : 0.0;
    s.max = max_;
    const double d = diagonal_ > 0 ? diagonal_ : 1.0;
    s.rms_pct = 100.0 * s.rms / d;
    s.max_pct = 100.0 * s.max / d;
    return s;
}

// Linear blend skinning of `bind` (vertex_count positions) with the character's own weights.
static void skin_reference(const Character& c, std::span<const glm::vec3> bind, const Mat34* palette,
                           std::span<glm::vec3> out) {
    const int I = c.influences;
    for (size_t v = 0; v < c.positions.size(); ++v) {
        const glm::vec3 p = bind[v];
        glm::vec3 acc(0.0f);
        for (int i = 0; i < I; ++i) {
            const float w = c.weights[v * I + i];
            if (w != 0.0f) acc += w * palette[c.joints[v * I + i]].transform_point(p);
        }
        out[v] = acc;
    }
}

void morph_positions(const Character& c, std::span<const float> weights, std::span<glm::vec3> out) {
    std::copy(c.positions.begin(), c.positions.end(), out.begin());
    for (size_t m = 0; m < c.morphs.size(); ++m) {
        const MorphTarget& t = c.morphs[m];
        const float w = weights.empty() ? t.default_weight : weights[m];
        if (w == 0.0f) continue;
        for (size_t i = 0; i < t.vertices.size(); ++i) out[t.vertices[i]] += w * t.position_deltas[i];
    }
}

std::vector<double> morph_importance(const Character& c) {
    std::vector<double> out;
    const double n = double(std::max<size_t>(c.vertex_count(), 1));
    for (const MorphTarget& t : c.morphs) {
        double sum = 0;
        for (const glm::vec3& d : t.position_deltas) sum += glm::dot(glm::dvec3(d), glm::dvec3(d));
        out.push_back(std::sqrt(sum / n));
    }
    return out;
}

std::vector<glm::vec3> rest_pose_positions(const Character& c) {
    std::vector<glm::dmat4> m(c.joint_count());
    sample_skinning_matrices(c, ClipSelection{}, 0.0, m);
    std::vector<Mat34> pal(m.size());
    for (size_t j = 0; j < m.size(); ++j) pal[j] = Mat34::from_glm(m[j]);
    std::vector<glm::vec3> bind(c.vertex_count()), out(c.vertex_count());
    morph_positions(c, {}, bind);
    skin_reference(c, bind, pal.data(), out);
    return out;
}

double rest_diagonal(const Character& c) {
    const auto p = rest_pose_positions(c);
    if (p.empty()) return 0.0;
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (const auto& v : p) {
        lo = glm::min(lo, glm::dvec3(v));
        hi = glm::max(hi, glm::dvec3(v));
    }
    return glm::length(hi - lo);
}

void reference_positions(const Character& c, const FrameSet& frames, size_t f, std::span<glm::vec3> out) {
    if (c.morphs.empty()) return skin_reference(c, c.positions, frames.frame(f), out);
    thread_local std::vector<glm::vec3> bind;
    bind.resize(c.vertex_count());
    morph_positions(c, frames.weights(f), bind);
    skin_reference(c, bind, frames.frame(f), out);
}

void skinned_bind_positions(const Character& c, const FrameSet& frames, size_t f, std::span<glm::vec3> out) {
    skin_reference(c, c.positions, frames.frame(f), out);
}

}  // namespace progskin
