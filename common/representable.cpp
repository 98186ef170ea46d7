// representable.cpp — see representable.h.
#include "representable.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "animation.h"
#include "pose.h"

namespace progskin {
namespace {

enum class Kind { Mirrored, Zero, NonUniform };

// A STEP channel whose value changes from one key to the next.
bool steps(const Channel& ch) {
    if (ch.interpolation != Interpolation::Step || ch.times.size() < 2) return false;
    const size_t n = ch.values.size() / ch.times.size();
    for (size_t k = 1; k < ch.times.size(); ++k)
        if (!std::equal(ch.values.begin() + long((k - 1) * n), ch.values.begin() + long(k * n), ch.values.begin() + long(k * n)))
            return true;
    return false;
}

struct Worst {
    double pct = 0;
    int clip = -1;  // -1: the rest pose
    double t = 0;
    Kind kind = Kind::NonUniform;
};

// Bind-space distance of the farthest vertex each joint moves (0: none).
std::vector<double> joint_radii(const Character& c) {
    std::vector<double> r(c.joint_count(), 0.0);
    const size_t k = size_t(std::max(1, c.influences));
    for (size_t v = 0; v < c.vertex_count(); ++v)
        for (size_t i = 0; i < k && v * k + i < c.weights.size(); ++i)
            if (c.weights[v * k + i] > 0.0f && c.joints[v * k + i] < r.size())
                r[c.joints[v * k + i]] = std::max(r[c.joints[v * k + i]], double(glm::length(c.positions[v])));
    return r;
}

double bind_diagonal(const Character& c) {
    if (c.positions.empty()) return 0;
    glm::vec3 lo = c.positions[0], hi = lo;
    for (const glm::vec3& p : c.positions) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    return double(glm::length(hi - lo));
}

// Upper bound of how far compose(decompose(m)) moves a vertex within radius
// of the origin (Frobenius norm of the 3x3 difference times the radius, plus
// the translation's difference), and the kind of matrix m is.
double round_trip_distance(const Mat34& m, double radius, Kind& kind) {
    const Mat34 back = compose(decompose(m));
    double lin = 0, tr = 0;
    for (int row = 0; row < 3; ++row) {
        for (int col = 0; col < 3; ++col) {
            const double d = double(m.m[row * 4 + col]) - double(back.m[row * 4 + col]);
            lin += d * d;
        }
        const double d = double(m.m[row * 4 + 3]) - double(back.m[row * 4 + 3]);
        tr += d * d;
    }
    const glm::dvec3 c0{m.m[0], m.m[4], m.m[8]}, c1{m.m[1], m.m[5], m.m[9]}, c2{m.m[2], m.m[6], m.m[10]};
    const double det = glm::dot(c0, glm::cross(c1, c2));
    kind = det < 0 ? Kind::Mirrored : std::cbrt(std::fabs(det)) < 1e-6 ? Kind::Zero : Kind::NonUniform;
    return std::sqrt(lin) * radius + std::sqrt(tr);
}

const char* kind_text(Kind k) {
    switch (k) {
        case Kind::Mirrored: return "is mirrored (negative scale)";
        case Kind::Zero: return "is scaled to zero";
        case Kind::NonUniform: return "has non-uniform scale or shear";
    }
    return "";
}

const char* advice(Kind k) {
    switch (k) {
        case Kind::Mirrored: return "apply the mirror in the exporter, or keep the rig's scales positive";
        case Kind::Zero: return "hide the part another way (its own mesh, a morph target) or scale it to a small positive size";
        case Kind::NonUniform: return "apply the scale in the exporter, or keep each joint's scale uniform";
    }
    return "";
}

}  // namespace

std::vector<std::string> representability_notes(const Character& c, double fps, double threshold_pct, size_t max_notes) {
    std::vector<std::string> notes;
    const double diagonal = bind_diagonal(c);
    if (c.joint_count() == 0 || diagonal <= 0 || !(fps > 0)) return notes;
    const std::vector<double> radius = joint_radii(c);
    std::vector<Worst> worst(c.joint_count());
    std::vector<glm::dmat4> mats(c.joint_count());
    const auto check = [&](const ClipSelection& sel, int clip, double t) {
        sample_skinning_matrices(c, sel, t, mats);
        for (size_t j = 0; j < mats.size(); ++j) {
            if (radius[j] <= 0) continue;
            Kind kind;
            const double pct = 100.0 * round_trip_distance(Mat34::from_glm(mats[j]), radius[j], kind) / diagonal;
            if (pct > worst[j].pct) worst[j] = {pct, clip, t, kind};
        }
    };
    check(ClipSelection{}, -1, 0.0);
    // At most kMaxFrames frames in all: longer clips (a file's key times are
    // its own) are sampled more sparsely, never for longer.
    constexpr double kMaxFrames = 20000;
    double total = 0;
    for (size_t k = 0; k < c.clips.size(); ++k) total += std::max(0.0, double(c.clips[k].end) - double(c.clips[k].start));
    const double rate = total * fps > kMaxFrames ? kMaxFrames / total : fps;
    for (size_t k = 0; k < c.clips.size(); ++k) {
        const ClipSelection sel = make_selection(c, {int(k)});
        const double frames = std::floor(std::max(0.0, double(sel.duration())) * rate) + 1;
        for (double f = 0; f < frames && std::isfinite(frames); ++f) check(sel, int(k), double(sel.start) + f / rate);
        check(sel, int(k), double(sel.end));
    }
    std::vector<size_t> bad;
    for (size_t j = 0; j < worst.size(); ++j)
        if (worst[j].pct > threshold_pct) bad.push_back(j);
    std::sort(bad.begin(), bad.end(), [&](size_t a, size_t b) { return worst[a].pct > worst[b].pct; });
    for (size_t i = 0; i < bad.size() && i < max_notes; ++i) {
        const Worst& w = worst[bad[i]];
        const int node = c.joint_node[bad[i]];
        const std::string name = node >= 0 && size_t(node) < c.nodes.size() ? c.nodes[size_t(node)].name : std::string();
        char where[64];
        std::snprintf(where, sizeof where, " at %.3f s", w.t);
        char dist[64];
        std::snprintf(dist, sizeof dist, "%.3g", w.pct);
        notes.push_back("joint " + std::to_string(bad[i]) + " \"" + name + "\" " + kind_text(w.kind) +
                        (w.clip < 0 ? std::string(" in the rest pose") : " in clip \"" + c.clips[size_t(w.clip)].name + "\"" + where) +
                        ": a bone record carries rotation, one positive scale and translation, so streamed it shows up to " +
                        dist + " % of the diagonal off (" + advice(w.kind) + ")");
    }
    if (bad.size() > max_notes)
        notes.push_back("and " + std::to_string(bad.size() - max_notes) + " more joint(s) the bone records cannot carry exactly");
    for (const Clip& clip : c.clips)
        if (std::any_of(clip.channels.begin(), clip.channels.end(), steps))
            notes.push_back("clip \"" + clip.name + "\" has STEP channels: clients interpolate between the server's ticks, so "
                            "each step shows blended over one tick (--snap-to-ticks shows the ticks as sent)");
    return notes;
}

}  // namespace progskin
