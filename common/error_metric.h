// error_metric.h — the one error metric of progskin (docs/metrics.md §2).
//
// e = Euclidean distance between a reconstructed and a reference vertex, both
// world space. Reported as RMS over all vertices and frames and max, in model
// units and in % of the rest-pose bounding-box diagonal (the diagonal of the
// box around the vertices skinned with every node at its rest transform).
// Tests, benchmarks, inspect, the streaming client and docs all use this.
#pragma once
#include <span>
#include <vector>

#include "animation.h"
#include "character.h"

namespace progskin {

struct ErrorStats {
    double rms = 0, max = 0;          // model units
    double rms_pct = 0, max_pct = 0;  // % of diagonal
    double samples = 0;               // vertex-frames measured
};

class ErrorAccumulator {
public:
    explicit ErrorAccumulator(double diagonal) : diagonal_(diagonal) {}
    void add(std::span<const glm::vec3> reference, std::span<const glm::vec3> reconstructed);
    void add_squared(double sum_sq, double max, double samples);
    ErrorStats stats() const;

private:
    double diagonal_;
    double sum_sq_ = 0, max_ = 0, samples_ = 0;
};

// Rest-pose skinned positions (every node at its rest TRS/matrix, every morph
// target at its default weight).
std::vector<glm::vec3> rest_pose_positions(const Character& c);
double rest_diagonal(const Character& c);

// Bind positions with the morph targets applied (glTF: morphs before skinning):
// out = positions + sum_m weights[m] * delta_m. weights.size() == morphs.size(),
// or empty for the default weights. out.size() == vertex_count. Cost: the
// copy plus one multiply-add per listed vertex of each target with w != 0.
void morph_positions(const Character& c, std::span<const float> weights, std::span<glm::vec3> out);

// Per morph target, the RMS over all of the character's vertices of its
// position delta: the RMS vertex error (model units) that a unit of its weight
// removes, i.e. how much sending its weight is worth (docs/metrics.md §4).
std::vector<double> morph_importance(const Character& c);

// Reference vertices of frame f (full detail, original weights, morph targets
// at the frame's weights): out.size() == vertex_count.
void reference_positions(const Character& c, const FrameSet& frames, size_t f, std::span<glm::vec3> out);

// The same without morph targets (the unmorphed bind mesh skinned): what a
// collapse over constant bind positions can reproduce.
void skinned_bind_positions(const Character& c, const FrameSet& frames, size_t f, std::span<glm::vec3> out);

}  // namespace progskin
