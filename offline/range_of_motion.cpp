// range_of_motion.cpp — see range_of_motion.h.
#include "range_of_motion.h"

#include <cmath>
#include <numbers>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>

#include "errors.h"
#include "error_metric.h"

namespace progskin {

namespace {

// splitmix64: a small, well-mixed deterministic generator.
struct Random {
    uint64_t s;
    uint64_t next() {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    double uniform(double lo, double hi) { return lo + (hi - lo) * double(next() >> 11) * 0x1.0p-53; }
    glm::dvec3 axis() {  // uniform on the sphere
        const double z = uniform(-1.0, 1.0), a = uniform(0.0, 2.0 * std::numbers::pi);
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        return {r * std::cos(a), r * std::sin(a), z};
    }
};

// One joint's motion: two turns, each about its own axis.
struct Wave {
    glm::dvec3 axis[2];
    double amplitude[2], frequency[2], phase[2];
};

}  // namespace

FrameSet range_of_motion_frames(const Character& c, double fps, uint64_t seed) {
    if (!(fps > 0.0) || !std::isfinite(fps)) throw Error("range_of_motion_frames: fps must be positive");
    const size_t N = c.nodes.size(), J = c.joint_count();
    std::vector<int> joint_of_node(N, -1);
    for (size_t j = 0; j < J; ++j) joint_of_node[size_t(c.joint_node[j])] = int(j);
    Random rng{seed};
    std::vector<Wave> waves(J);
    const double max_angle = kRangeOfMotionDegrees * std::numbers::pi / 180.0;
    for (Wave& w : waves)
        for (int k = 0; k < 2; ++k) {
            w.axis[k] = rng.axis();
            w.amplitude[k] = rng.uniform(0.5, 1.0) * max_angle;
            w.frequency[k] = rng.uniform(0.4, 1.2);
            w.phase[k] = rng.uniform(0.0, 2.0 * std::numbers::pi);
        }
    // Rest local matrices, rotation apart for TRS nodes (the turn goes between
    // the rest rotation and the scale: about the joint, in its parent's frame
    // turned by its rest rotation).
    std::vector<glm::dmat4> locals(N), globals(N);
    const size_t frames = size_t(std::floor(kRangeOfMotionSeconds * fps + 1e-6)) + 1;
    FrameSet fs;
    fs.joint_count = int(J);
    fs.morph_count = int(c.morphs.size());
    fs.times.reserve(frames);
    fs.selection_of_frame.assign(frames, 0);
    fs.skinning.reserve(frames * J);
    for (size_t f = 0; f < frames; ++f) {
        const double t = double(f) / fps;
        for (size_t i = 0; i < N; ++i) {
            const Node& n = c.nodes[i];
            glm::dquat turn(1.0, 0.0, 0.0, 0.0);
            if (const int j = joint_of_node[i]; j >= 0) {
                const Wave& w = waves[size_t(j)];
                for (int k = 0; k < 2; ++k)
                    turn = turn * glm::angleAxis(w.amplitude[k] * std::sin(2.0 * std::numbers::pi * w.frequency[k] * t + w.phase[k]),
                                                 w.axis[k]);
            }
            locals[i] = n.has_matrix ? n.matrix * glm::mat4_cast(turn)
                                     : glm::translate(glm::dmat4(1.0), n.translation) * glm::mat4_cast(n.rotation * turn) *
                                           glm::scale(glm::dmat4(1.0), n.scale);
        }
        compose_node_globals(c, locals, globals);
        fs.times.push_back(t);
        for (size_t j = 0; j < J; ++j)
            fs.skinning.push_back(Mat34::from_glm(globals[size_t(c.joint_node[j])] * c.inverse_bind[j]));
        for (const MorphTarget& m : c.morphs) fs.morph_weights.push_back(m.default_weight);
    }
    return fs;
}

bool skeleton_moves(const FrameSet& frames, double tolerance) {
    const size_t J = size_t(std::max(0, frames.joint_count));
    for (size_t f = 1; f < frames.frame_count(); ++f)
        for (size_t j = 0; j < J; ++j)
            for (int x = 0; x < 12; ++x)
                if (std::abs(double(frames.frame(f)[j].m[x]) - double(frames.frame(0)[j].m[x])) > tolerance) return true;
    return false;
}

FrameSet training_frames(const Character& c, const std::vector<ClipSelection>& selections, double fps,
                         bool* range_of_motion) {
    FrameSet frames = sample_frames(c, selections, fps);
    // The tolerance in model units: a millionth of the character's size.
    const double size = std::max(rest_diagonal(c), 1e-12);
    const bool rom = !skeleton_moves(frames, 1e-6 * std::max(1.0, size));
    if (range_of_motion) *range_of_motion = rom;
    return rom ? range_of_motion_frames(c, fps) : frames;
}

}  // namespace progskin
