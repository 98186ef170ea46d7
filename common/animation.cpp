// animation.cpp — clip selection and pose sampling (see animation.h).
//
// Sampling follows the glTF 2.0 spec, Appendix C (interpolation): STEP holds
// the previous key, LINEAR lerps vectors and slerps quaternions along the
// shortest path, CUBICSPLINE is the Hermite spline with tangents scaled by the
// key interval. Times outside a channel's keys clamp to its first/last key.
// Everything is evaluated in double precision.
#include "animation.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <glm/gtc/matrix_transform.hpp>

#include "errors.h"

namespace progskin {
namespace {

// A node's local transform while a pose is being evaluated.
struct LocalPose {
    glm::dvec3 translation;
    glm::dquat rotation;
    glm::dvec3 scale;
    bool animated;  // some channel wrote it: use TRS even if the node has a matrix
};

// Scratch reused across the frames of one sampling call.
struct PoseScratch {
    std::vector<LocalPose> locals;
    std::vector<glm::dmat4> local_matrices;
    std::vector<glm::dmat4> globals;
};

// Key value k (components n) of a channel; for CUBICSPLINE the value, not a tangent.
const float* key_value(const Channel& ch, size_t k, int n) {
    const size_t per_key = ch.interpolation == Interpolation::CubicSpline ? 3 : 1;
    const size_t offset = ch.interpolation == Interpolation::CubicSpline ? size_t(n) : 0;
    return ch.values.data() + k * per_key * size_t(n) + offset;
}

glm::dquat to_quat(const double* v) { return glm::dquat(v[3], v[0], v[1], v[2]); }  // glTF x y z w

// Spherical interpolation along the shortest arc (nlerp when nearly parallel).
glm::dquat slerp_shortest(glm::dquat a, glm::dquat b, double u) {
    double d = glm::dot(a, b);
    if (d < 0.0) {
        b = -b;
        d = -d;
    }
    if (d > 1.0 - 1e-12) return glm::normalize(a * (1.0 - u) + b * u);
    const double theta = std::acos(std::min(d, 1.0));
    const double s = std::sin(theta);
    return a * (std::sin((1.0 - u) * theta) / s) + b * (std::sin(u * theta) / s);
}

// Value of a channel at time t (clamped to its keys) into out[0..n), n = 3 or 4 (x y z w).
void sample_channel(const Channel& ch, double t, int n, double* out) {
    const size_t keys = ch.times.size();
    auto copy_key = [&](size_t k) {
        const float* v = key_value(ch, k, n);
        for (int i = 0; i < n; ++i) out[i] = double(v[i]);
    };
    if (keys == 0) return;
    if (keys == 1 || t <= double(ch.times.front())) return copy_key(0);
    if (t >= double(ch.times.back())) return copy_key(keys - 1);
    // Interval [k, k+1] with times[k] <= t < times[k+1].
    const size_t k = size_t(std::upper_bound(ch.times.begin(), ch.times.end(), t,
                                                  [](double x, float key) { return x < double(key); }) - ch.times.begin()) - 1;
    const size_t k1 = std::min(k + 1, keys - 1);
    const double t0 = double(ch.times[k]), t1 = double(ch.times[k1]);
    if (ch.interpolation == Interpolation::Step || t1 <= t0) return copy_key(k);
    const double u = std::clamp((t - t0) / (t1 - t0), 0.0, 1.0);
    const float* a = key_value(ch, k, n);
    const float* b = key_value(ch, k1, n);
    if (ch.interpolation == Interpolation::Linear) {
        if (n == 4 && ch.path == ChannelPath::Rotation) {
            const double qa[4] = {a[0], a[1], a[2], a[3]}, qb[4] = {b[0], b[1], b[2], b[3]};
            const glm::dquat q = slerp_shortest(glm::normalize(to_quat(qa)), glm::normalize(to_quat(qb)), u);
            out[0] = q.x, out[1] = q.y, out[2] = q.z, out[3] = q.w;
        } else {
            for (int i = 0; i < n; ++i) out[i] = double(a[i]) + (double(b[i]) - double(a[i])) * u;
        }
        return;
    }
    // CUBICSPLINE: p = h00 v_k + h10 d b_k + h01 v_k1 + h11 d a_k1 (b = out-tangent, a = in-tangent).
    const double d = t1 - t0;
    const double u2 = u * u, u3 = u2 * u;
    const double h00 = 2 * u3 - 3 * u2 + 1, h10 = u3 - 2 * u2 + u, h01 = -2 * u3 + 3 * u2, h11 = u3 - u2;
    const float* out_tangent = a + n;  // key k: [in, value, out]
    const float* in_tangent = b - n;   // key k1: [in, value, out]
    for (int i = 0; i < n; ++i)
        out[i] = h00 * a[i] + h10 * d * out_tangent[i] + h01 * b[i] + h11 * d * in_tangent[i];
    if (n == 4 && ch.path == ChannelPath::Rotation) {
        const double len = std::sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3]);
        if (len > 0.0)
            for (int i = 0; i < 4; ++i) out[i] /= len;
    }
}

// Checks a selection's clip indices against the character.
void check_selection(const Character& c, const ClipSelection& sel) {
    for (int clip : sel.clips)
        if (clip < 0 || size_t(clip) >= c.clips.size())
            throw Error(c.source + ": clip index " + std::to_string(clip) + " out of range (" +
                        std::to_string(c.clips.size()) + " clips)");
}

// Node globals at time t into s.globals (rest pose plus the selection's channels).
void evaluate_globals(const Character& c, const ClipSelection& sel, double t, PoseScratch& s) {
    const size_t count = c.nodes.size();
    s.locals.resize(count);
    s.globals.resize(count);
    for (size_t i = 0; i < count; ++i) {
        const Node& n = c.nodes[i];
        s.locals[i] = {n.translation, n.rotation, n.scale, false};
    }
    double v[4];
    for (int clip : sel.clips) {
        for (const Channel& ch : c.clips[size_t(clip)].channels) {
            if (ch.node < 0 || size_t(ch.node) >= count || ch.path == ChannelPath::Weights) continue;
            LocalPose& p = s.locals[size_t(ch.node)];
            switch (ch.path) {
                case ChannelPath::Translation:
                    sample_channel(ch, t, 3, v);
                    p.translation = {v[0], v[1], v[2]};
                    break;
                case ChannelPath::Rotation:
                    sample_channel(ch, t, 4, v);
                    p.rotation = glm::normalize(to_quat(v));
                    break;
                case ChannelPath::Scale:
                    sample_channel(ch, t, 3, v);
                    p.scale = {v[0], v[1], v[2]};
                    break;
                case ChannelPath::Weights: break;  // skipped above (sample_morph_weights)
            }
            p.animated = !ch.times.empty() || p.animated;
        }
    }
    s.local_matrices.resize(count);
    for (size_t i = 0; i < count; ++i) {
        const Node& n = c.nodes[i];
        const LocalPose& p = s.locals[i];
        s.local_matrices[i] = n.has_matrix && !p.animated ? n.matrix
                                                          : glm::translate(glm::dmat4(1.0), p.translation) *
                                                                glm::mat4_cast(p.rotation) *
                                                                glm::scale(glm::dmat4(1.0), p.scale);
    }
    compose_node_globals(c, s.local_matrices, s.globals);
}

// Morph weights at time t into out (size c.morphs.size()): defaults, then every
// Weights channel of the selection (later clips win where two animate one node).
void evaluate_morph_weights(const Character& c, const ClipSelection& sel, double t, std::vector<double>& buf,
                            std::span<float> out) {
    for (size_t m = 0; m < c.morphs.size(); ++m) out[m] = c.morphs[m].default_weight;
    for (int clip : sel.clips)
        for (const Channel& ch : c.clips[size_t(clip)].channels) {
            if (ch.path != ChannelPath::Weights || ch.morph_count <= 0 || ch.morph_first < 0 ||
                size_t(ch.morph_first) + size_t(ch.morph_count) > c.morphs.size())
                continue;
            buf.resize(size_t(ch.morph_count));
            sample_channel(ch, t, ch.morph_count, buf.data());
            for (int i = 0; i < ch.morph_count; ++i) out[size_t(ch.morph_first + i)] = float(buf[size_t(i)]);
        }
}

// M_j = G_j * IBM_j of every joint from already evaluated globals.
void skinning_from_globals(const Character& c, const PoseScratch& s, std::span<glm::dmat4> out) {
    for (size_t j = 0; j < c.joint_node.size(); ++j) out[j] = s.globals[size_t(c.joint_node[j])] * c.inverse_bind[j];
}

std::string trim(const std::string& s) {
    const size_t b = s.find_first_not_of(" \t");
    if (b == std::string::npos) return {};
    return s.substr(b, s.find_last_not_of(" \t") - b + 1);
}

// Index of the clip named or numbered `item`, or -1.
int find_clip(const Character& c, const std::string& item) {
    for (size_t i = 0; i < c.clips.size(); ++i)
        if (c.clips[i].name == item) return int(i);
    if (!item.empty() && item.find_first_not_of("0123456789") == std::string::npos && item.size() < 10) {
        const int index = std::stoi(item);
        if (size_t(index) < c.clips.size()) return index;
    }
    return -1;
}


}  // namespace

ClipSelection make_selection(const Character& c, std::vector<int> clips) {
    ClipSelection sel;
    sel.clips = std::move(clips);
    bool first = true;
    for (int i : sel.clips) {
        const Clip& clip = c.clips[size_t(i)];
        if (clip.channels.empty()) continue;
        sel.start = first ? clip.start : std::min(sel.start, clip.start);
        sel.end = first ? clip.end : std::max(sel.end, clip.end);
        first = false;
    }
    return sel;
}

std::vector<double> linear_key_times(const Character& c, const ClipSelection& sel) {
    std::vector<double> keys;
    for (int i : sel.clips) {
        for (const Channel& ch : c.clips[size_t(i)].channels) {
            if (ch.interpolation != Interpolation::Linear) return {};
            keys.insert(keys.end(), ch.times.begin(), ch.times.end());
        }
    }
    std::sort(keys.begin(), keys.end());
    std::vector<double> out;
    for (double k : keys)
        if (out.empty() || k - out.back() > 1e-6) out.push_back(k);
    return out;
}

double latest_key_in(const std::vector<double>& keys, double lo, double hi) {
    auto it = std::upper_bound(keys.begin(), keys.end(), hi);
    if (it == keys.begin() || !(*(it - 1) > lo)) return std::nan("");
    return *(it - 1);
}

double ClipSelection::looped(double t) const {
    const double dur = duration();
    if (!(dur > 0)) return start;
    t = std::fmod(t, dur);
    if (t < 0) t += dur;
    return start + t;
}

double ClipSelection::played(double t, bool once, int64_t* loops) const {
    const double dur = duration();
    if (loops) *loops = !once && dur > 0 ? int64_t(std::floor(t / dur)) : 0;
    if (once) return start + std::clamp(t, 0.0, std::max(0.0, dur));
    return looped(t);
}

ClipSelection select_clips(const Character& c, const std::string& spec) {
    const std::string whole = trim(spec);
    if (whole == "all") {
        std::vector<int> all(c.clips.size());
        for (size_t i = 0; i < all.size(); ++i) all[i] = int(i);
        return make_selection(c, std::move(all));
    }
    std::vector<int> clips;
    auto add = [&](int i) {
        if (std::find(clips.begin(), clips.end(), i) == clips.end()) clips.push_back(i);
    };
    const int exact = find_clip(c, whole);  // a name may itself contain commas
    if (exact >= 0) {
        add(exact);
    } else {
        size_t pos = 0;
        while (pos <= whole.size()) {
            const size_t comma = std::min(whole.find(',', pos), whole.size());
            const std::string item = trim(whole.substr(pos, comma - pos));
            const int index = find_clip(c, item);
            if (index < 0) {
                std::string available;
                for (size_t i = 0; i < c.clips.size(); ++i)
                    available += (i ? ", " : "") + std::string("\"") + c.clips[i].name + "\"";
                if (available.empty()) available = "none";
                throw Error(c.source + ": no clip \"" + item + "\" (clips: " + available +
                            "; or give an index, \"all\" or a comma-separated list)");
            }
            add(index);
            pos = comma + 1;
        }
    }
    return make_selection(c, std::move(clips));
}

std::vector<ClipSelection> default_training_set(const Character& c) {
    std::vector<int> animated;  // clips with at least one channel
    for (size_t i = 0; i < c.clips.size(); ++i)
        if (!c.clips[i].channels.empty()) animated.push_back(int(i));
    if (animated.empty()) return {ClipSelection{}};
    std::set<int> seen;
    bool disjoint = true;
    for (int i : animated) {
        std::set<int> nodes;
        for (const Channel& ch : c.clips[size_t(i)].channels) nodes.insert(ch.node);
        for (int n : nodes) disjoint = seen.insert(n).second && disjoint;
    }
    if (disjoint) return {make_selection(c, animated)};
    std::vector<ClipSelection> out;
    for (int i : animated) out.push_back(make_selection(c, {i}));
    return out;
}

void sample_node_globals(const Character& c, const ClipSelection& sel, double t, std::span<glm::dmat4> out) {
    if (out.size() != c.nodes.size())
        throw Error("sample_node_globals: output has " + std::to_string(out.size()) + " matrices for " +
                    std::to_string(c.nodes.size()) + " nodes");
    check_selection(c, sel);
    PoseScratch s;
    evaluate_globals(c, sel, t, s);
    std::copy(s.globals.begin(), s.globals.end(), out.begin());
}

void compose_node_globals(const Character& c, std::span<const glm::dmat4> locals, std::span<glm::dmat4> globals) {
    const size_t count = c.nodes.size();
    if (locals.size() != count || globals.size() != count)
        throw Error("compose_node_globals: " + std::to_string(locals.size()) + " local and " +
                    std::to_string(globals.size()) + " global matrices for " + std::to_string(count) + " nodes");
    // Parents normally precede children (the importer orders them so); otherwise resolve chains.
    bool ordered = true;
    for (size_t i = 0; i < count && ordered; ++i) ordered = c.nodes[i].parent < int(i);
    if (ordered) {
        for (size_t i = 0; i < count; ++i) {
            const int parent = c.nodes[i].parent;
            globals[i] = parent < 0 ? locals[i] : globals[size_t(parent)] * locals[i];
        }
        return;
    }
    std::vector<char> done(count, 0);
    std::vector<size_t> chain;
    for (size_t i = 0; i < count; ++i) {
        chain.clear();  // unresolved nodes from i up to the first resolved ancestor or root
        for (size_t n = i; !done[n];) {
            chain.push_back(n);
            if (chain.size() > count) throw Error(c.source + ": cyclic node hierarchy in character " + c.name);
            if (c.nodes[n].parent < 0) break;
            n = size_t(c.nodes[n].parent);
        }
        for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
            const int parent = c.nodes[*it].parent;
            globals[*it] = parent < 0 ? locals[*it] : globals[size_t(parent)] * locals[*it];
            done[*it] = 1;
        }
    }
}

void sample_skinning_matrices(const Character& c, const ClipSelection& sel, double t, std::span<glm::dmat4> out) {
    if (out.size() != c.joint_count())
        throw Error("sample_skinning_matrices: output has " + std::to_string(out.size()) + " matrices for " +
                    std::to_string(c.joint_count()) + " joints");
    check_selection(c, sel);
    PoseScratch s;
    evaluate_globals(c, sel, t, s);
    skinning_from_globals(c, s, out);
}

void sample_morph_weights(const Character& c, const ClipSelection& sel, double t, std::span<float> out) {
    if (out.size() != c.morphs.size())
        throw Error("sample_morph_weights: output has " + std::to_string(out.size()) + " weights for " +
                    std::to_string(c.morphs.size()) + " morph targets");
    check_selection(c, sel);
    std::vector<double> buf;
    evaluate_morph_weights(c, sel, t, buf, out);
}

FrameSet sample_pose(const Character& c, const ClipSelection& sel, double t) {
    check_selection(c, sel);
    FrameSet fs;
    fs.joint_count = int(c.joint_count());
    fs.morph_count = int(c.morphs.size());
    fs.times = {t};
    fs.selection_of_frame = {0};
    PoseScratch s;
    std::vector<glm::dmat4> m(c.joint_count());
    evaluate_globals(c, sel, t, s);
    skinning_from_globals(c, s, m);
    for (const glm::dmat4& x : m) fs.skinning.push_back(Mat34::from_glm(x));
    fs.morph_weights.resize(c.morphs.size());
    std::vector<double> buf;
    evaluate_morph_weights(c, sel, t, buf, fs.morph_weights);
    return fs;
}

FrameSet sample_frames(const Character& c, const std::vector<ClipSelection>& sels, double fps) {
    if (!(fps > 0.0) || !std::isfinite(fps)) throw Error("sample_frames: fps must be positive (got " + std::to_string(fps) + ")");
    FrameSet fs;
    fs.joint_count = int(c.joint_count());
    fs.morph_count = int(c.morphs.size());
    // floor(duration * fps) + 1 frames per selection (the epsilon absorbs float rounding of the end time).
    auto frame_count = [fps](const ClipSelection& sel) {
        const double duration = std::max(0.0, double(sel.end) - double(sel.start));
        return std::floor(duration * fps + 1e-6) + 1.0;
    };
    double total_d = 0;
    for (const ClipSelection& sel : sels) {
        check_selection(c, sel);
        total_d += frame_count(sel);
    }
    // Key times come from the file: a clip spanning days must not take the
    // machine's memory (100,000 frames is 55 minutes at 30 fps).
    if (total_d > double(kMaxSampledFrames))
        throw Error(c.source + ": the selected clips span " + std::to_string(total_d / fps) + " s, " +
                    std::to_string(size_t(total_d)) + " frames at " + std::to_string(fps) +
                    " fps, more than the limit of " + std::to_string(kMaxSampledFrames) +
                    " (choose a clip with --clip or a lower --fps)");
    const size_t total = size_t(total_d);
    fs.times.reserve(total);
    fs.selection_of_frame.reserve(total);
    fs.skinning.reserve(total * c.joint_count());
    fs.morph_weights.reserve(total * c.morphs.size());
    PoseScratch s;
    std::vector<glm::dmat4> m(c.joint_count());
    std::vector<double> buf;
    std::vector<float> w(c.morphs.size());
    for (size_t k = 0; k < sels.size(); ++k) {
        const ClipSelection& sel = sels[k];
        const size_t frames = size_t(frame_count(sel));
        for (size_t f = 0; f < frames; ++f) {
            const double t = double(sel.start) + double(f) / fps;
            evaluate_globals(c, sel, t, s);
            skinning_from_globals(c, s, m);
            fs.times.push_back(t);
            fs.selection_of_frame.push_back(int(k));
            for (const glm::dmat4& x : m) fs.skinning.push_back(Mat34::from_glm(x));
            evaluate_morph_weights(c, sel, t, buf, w);
            fs.morph_weights.insert(fs.morph_weights.end(), w.begin(), w.end());
        }
    }
    return fs;
}

}  // namespace progskin
