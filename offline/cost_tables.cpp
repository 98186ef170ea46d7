// cost_tables.cpp — see cost_tables.h.
#include "cost_tables.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <span>

#include "error_metric.h"
#include "errors.h"
#include "pose.h"
#include "range_of_motion.h"

namespace progskin {

std::vector<HullStep> error_hull(const std::vector<double>& err) {
    // Points (k, e(k)) for k = 1..B; lower convex hull from k = 1 (monotone chain).
    std::vector<HullStep> steps;
    const int B = int(err.size());
    if (B <= 1) return steps;
    std::vector<int> h;  // hull vertex ks
    auto e = [&](int k) { return err[size_t(k - 1)]; };
    for (int k = 1; k <= B; ++k) {
        while (h.size() >= 2) {
            int a = h[h.size() - 2], b = h.back();
            // b is above segment a-k (or on it): drop it
            double cross = (b - a) * (e(k) - e(a)) - (k - a) * (e(b) - e(a));
            if (cross <= 0) h.pop_back();
            else break;
        }
        h.push_back(k);
    }
    for (size_t i = 1; i < h.size(); ++i)
        steps.push_back({h[i - 1], h[i], std::max(0.0, e(h[i - 1]) - e(h[i]))});
    return steps;
}

namespace {

// Segment layout and collapse values: segment 0 is bone 0, then one segment
// per step of the hull of the squared error table over all frames; collapse
// per model from that model's own table (models: selections, then all).
// rom: the range-of-motion frames that stand in for clips that do not move
// the skeleton (range_of_motion.h), else null.
void layout_segments(AssetTables& t, const Character& c, const ProgressiveSkin& s,
                     const std::vector<ClipSelection>& selections, const FrameSet* rom) {
    const size_t M = selections.size() + 1;
    std::vector<double> mse;
    for (const auto& e : s.error) mse.push_back(e.rms * e.rms);
    std::vector<std::vector<double>> sel_mse(M);
    for (size_t m = 0; m + 1 < M; ++m)
        for (const auto& e : evaluate_error_table(c, s, rom ? *rom : sample_frames(c, {selections[m]}, 30.0)))
            sel_mse[m].push_back(e.rms * e.rms);
    sel_mse[M - 1] = mse;
    t.segments.clear();
    CostSegment root;
    root.from = 0;
    root.to = 1;
    for (size_t m = 0; m < M; ++m) {
        const double e1 = sel_mse[m].empty() ? 0.0 : std::sqrt(sel_mse[m][0]);
        root.collapse.push_back((t.diagonal + e1) * (t.diagonal + e1));
    }
    t.segments.push_back(root);
    for (const HullStep& h : error_hull(mse)) {
        CostSegment seg;
        seg.from = h.from;
        seg.to = h.to;
        for (size_t m = 0; m < M; ++m)
            seg.collapse.push_back(sel_mse[m].size() >= size_t(h.to)
                                       ? std::max(0.0, sel_mse[m][size_t(h.from - 1)] - sel_mse[m][size_t(h.to - 1)])
                                       : h.gain);
        t.segments.push_back(seg);
    }
}

// Sums, per model and gap, of the squared vertex error when only one
// segment's bones are interpolated over an interval (gap tables), as the
// client interpolates: each bone relative to its progressive parent, about
// its pivot, composed down the prefix (docs/algorithms.md "Interpolation
// between ticks"), so that a segment's error carries on to the bones below
// it, which are exact relative to it.
struct GapSampler {
    const Character& c;
    const ProgressiveSkin& s;
    const FrameSet& frames;
    size_t M, S, J, B;
    std::vector<int> seg_of_bone;               // per progressive bone
    std::vector<glm::dvec3> pivot;              // per bone: its joint's bind position (model space)
    std::vector<BonePose> p0, pa, pb, p3;       // the frames around an interval, per bone, relative about the pivot
    std::vector<glm::dmat4> rel_exact, rel_interp, model, exact;  // per bone
    std::vector<Mat34> diff;                    // S x J (segment q, joint): displayed - exact, model space
    std::vector<char> touched;                  // S x J: segment q's interpolation moves joint j
    std::vector<Mat34> diff_all;                // J: every segment interpolated together
    std::vector<double> sum, samples, all;      // per model (x segment)

    GapSampler(const Character& ch, const ProgressiveSkin& sk, const FrameSet& f, const AssetTables& t, size_t models)
        : c(ch), s(sk), frames(f), M(models), S(t.segments.size()), J(ch.joint_count()), B(size_t(sk.bone_count())),
          seg_of_bone(B, 0), pivot(B), p0(B), pa(B), pb(B), p3(B), rel_exact(B), rel_interp(B), model(B), exact(B),
          diff(S * J), touched(S * J, 0), diff_all(J), sum(S * M), samples(M), all(M) {
        for (size_t g = 0; g < S; ++g)
            for (int b = t.segments[g].from; b < t.segments[g].to; ++b) seg_of_bone[size_t(b)] = int(g);
        for (size_t b = 0; b < B; ++b) pivot[b] = glm::dvec3(glm::inverse(c.inverse_bind[size_t(s.order[b])])[3]);
    }

    glm::dmat4 model_of(size_t f, size_t b) const { return glm::dmat4(frames.frame(f)[size_t(s.order[b])].to_glm()); }
    glm::dmat4 parent_of(size_t f, size_t b) const {
        const int p = s.parents[b];
        return p < 0 ? glm::dmat4(1.0) : model_of(f, size_t(p));
    }
    // Bone b's pose relative to its parent in frame f, about its pivot (the
    // translation is the pivot's image), as the client keeps it.
    BonePose relative(size_t f, size_t b) const {
        BonePose r = decompose(Mat34::from_glm(glm::inverse(parent_of(f, b)) * model_of(f, b)));
        r.t += r.s * (r.r * glm::vec3(pivot[b]));
        return r;
    }

    // Adds the interval [f, f + g] of selection sel at a quarter, half and
    // three quarters of the gap.
    void add_interval(size_t f, int g, int sel) {
        // What the client does (pose.h interpolate_between): cubic over the
        // neighbours f - g and f + 2g when they exist (same clip), else slerp/lerp.
        const size_t G = size_t(g);
        const bool cubic = f >= G && f + 2 * G < frames.frame_count() && frames.selection_of_frame[f - G] == sel &&
                           frames.selection_of_frame[f + 2 * G] == sel;
        for (size_t b = 0; b < B; ++b) {
            pa[b] = relative(f, b);
            pb[b] = relative(f + G, b);
            if (cubic) {
                p0[b] = relative(f - G, b);
                p3[b] = relative(f + 2 * G, b);
            }
        }
        int prev_h = 0;
        for (int q = 1; q <= 3; ++q) {
            const int h = std::clamp(int(std::lround(g * q / 4.0)), 1, g - 1);
            if (h == prev_h) continue;
            prev_h = h;
            const size_t fh = f + size_t(h);
            for (size_t b = 0; b < B; ++b) {
                exact[b] = model_of(fh, b);
                rel_exact[b] = glm::inverse(parent_of(fh, b)) * exact[b];
                BonePose ip = interpolate_between(cubic ? &p0[b] : nullptr, pa[b], pb[b], cubic ? &p3[b] : nullptr, -double(g),
                                                  0.0, double(g), 2.0 * g, double(h));
                ip.t -= ip.s * (ip.r * glm::vec3(pivot[b]));
                rel_interp[b] = glm::dmat4(compose(ip).to_glm());
            }
            std::fill(touched.begin(), touched.end(), 0);
            for (size_t seg = 0; seg < S; ++seg) compose_with(int(seg), diff.data() + seg * J, touched.data() + seg * J);
            compose_with(-1, diff_all.data(), nullptr);
            add_vertices(size_t(sel));
        }
    }

    // Model poses with the bones of segment seg (every bone: -1) interpolated
    // and the others exact relative to their parents; out[joint] = displayed -
    // exact, touch[joint] set where it differs.
    void compose_with(int seg, Mat34* out, char* touch) {
        for (size_t b = 0; b < B; ++b) {
            const int p = s.parents[b];
            const bool moved = seg < 0 || seg_of_bone[b] == seg || (p >= 0 && touch && touch[size_t(s.order[size_t(p)])]);
            const bool interp = seg < 0 || seg_of_bone[b] == seg;
            if (!moved) {
                model[b] = exact[b];
                out[size_t(s.order[b])] = Mat34{};
                continue;
            }
            model[b] = (p < 0 ? glm::dmat4(1.0) : model[size_t(p)]) * (interp ? rel_interp[b] : rel_exact[b]);
            const glm::dmat4 d = model[b] - exact[b];
            Mat34& o = out[size_t(s.order[b])];
            for (int row = 0; row < 3; ++row)
                for (int col = 0; col < 4; ++col) o.m[row * 4 + col] = float(d[col][row]);
            if (touch) touch[size_t(s.order[b])] = 1;
        }
    }

    // Per vertex: the error of each segment's bones apart, and of all together.
    void add_vertices(size_t sel) {
        double* out = sum.data() + sel * S;
        const int I = c.influences;
        auto apply = [](const Mat34& d, const glm::vec3& p) {
            return glm::vec3{d.m[0] * p.x + d.m[1] * p.y + d.m[2] * p.z + d.m[3], d.m[4] * p.x + d.m[5] * p.y + d.m[6] * p.z + d.m[7],
                             d.m[8] * p.x + d.m[9] * p.y + d.m[10] * p.z + d.m[11]};
        };
        for (size_t v = 0; v < c.vertex_count(); ++v) {
            const glm::vec3 p = c.positions[v];
            const float* w = c.weights.data() + v * size_t(I);
            const uint16_t* jv = c.joints.data() + v * size_t(I);
            glm::vec3 total(0.0f);
            for (int k = 0; k < I; ++k)
                if (w[k] != 0.0f) total += w[k] * apply(diff_all[jv[k]], p);
            all[sel] += double(glm::dot(total, total));
            for (size_t seg = 0; seg < S; ++seg) {
                const char* touch = touched.data() + seg * J;
                const Mat34* d = diff.data() + seg * J;
                glm::vec3 e(0.0f);
                bool any = false;
                for (int k = 0; k < I; ++k)
                    if (w[k] != 0.0f && touch[jv[k]]) {
                        e += w[k] * apply(d[jv[k]], p);
                        any = true;
                    }
                if (any) out[seg] += double(glm::dot(e, e));
            }
        }
        samples[sel] += double(c.vertex_count());
    }

    // The gap-g column of every segment's table, from the sums of gap g.
    void finish_gap(int g, AssetTables& t) {
        for (size_t m = 0; m + 1 < M; ++m) {
            samples[M - 1] += samples[m];
            all[M - 1] += all[m];
            for (size_t q = 0; q < S; ++q) sum[(M - 1) * S + q] += sum[m * S + q];
        }
        for (size_t m = 0; m < M; ++m) {
            // Errors of bones that move together add up: scale the segments'
            // errors so that they sum to the error of all bones interpolated.
            double parts = 0;
            for (size_t q = 0; q < S; ++q) parts += sum[m * S + q];
            const double k = parts > 0 ? all[m] / parts : 1.0;
            for (size_t q = 0; q < S; ++q) sum[m * S + q] *= k;
        }
        for (size_t m = 0; m < M; ++m)
            for (size_t q = 0; q < S; ++q) {
                // Clips shorter than the gap: grow from the previous gap as g^2.
                auto& row = t.segments[q].gap[m];
                row[size_t(g)] = samples[m] > 0 ? sum[m * S + q] / samples[m] * double(g - 1) / double(g)
                                                : row[size_t(g - 1)] * double(g * g) / double((g - 1) * (g - 1));
            }
    }
};

// Interpolation error over gaps of 2..16 frames, sampled at a quarter, half
// and three quarters of the gap from up to 24 start frames per selection.
void gap_tables(AssetTables& t, const Character& c, const ProgressiveSkin& s, const FrameSet& frames, size_t M) {
    for (auto& seg : t.segments) seg.gap.assign(M, {});
    GapSampler gs(c, s, frames, t, M);
    std::vector<size_t> sel_frames(M - 1, 0);
    for (int x : frames.selection_of_frame)
        if (x >= 0 && size_t(x) + 1 < M) ++sel_frames[size_t(x)];
    for (int g = 2; g < AssetTables::kGapTable; ++g) {
        std::fill(gs.sum.begin(), gs.sum.end(), 0.0);
        std::fill(gs.samples.begin(), gs.samples.end(), 0.0);
        std::fill(gs.all.begin(), gs.all.end(), 0.0);
        for (size_t f = 0; f + size_t(g) < frames.frame_count(); ++f) {
            const int sel = frames.selection_of_frame[f];
            if (sel < 0 || size_t(sel) + 1 >= M || sel != frames.selection_of_frame[f + size_t(g)]) continue;
            if (f % std::max<size_t>(1, sel_frames[size_t(sel)] / 24) != 0) continue;
            gs.add_interval(f, g, sel);
        }
        gs.finish_gap(g, t);
    }
}

// Refresh and show values from the gap tables (cost_model.h).
void value_tables(AssetTables& t, size_t M) {
    for (auto& seg : t.segments) {
        seg.refresh.assign(M, {});
        seg.show_value.assign(M, 0.0);
        for (size_t m = 0; m < M; ++m) {
            for (int x = 1; x < AssetTables::kGapTable; ++x)
                seg.refresh[m][size_t(x)] = x * (x + 1.0) * (seg.gap_at(int(m), x + 1.0) - seg.gap_at(int(m), x));
            for (int p = 1; p < kHoldTicks; ++p)
                seg.show_value[m] = std::max(seg.show_value[m], p * (seg.collapse[m] - seg.gap[m][size_t(p)]));
        }
    }
}

// The translations of the skinning matrices that any rigid pose of the
// skeleton gives, about the roots' positions in `frames`: a live pose (a game
// driving the character) may turn every joint beyond what the clips do.
// Joint j at q_j, bind-space position b_j = IBM_j^-1 (0): its skinning matrix
// M_j = G_j IBM_j moves the bind-space origin to t_j = q_j - s_j R_j b_j, and
// q_j lies within the chain length L_j (joint to joint, to its root joint r)
// of q_r. So t_j is within L_j + s_j |b_j| of q_r. O(frames * joints).
// scale: each joint's largest skinning scale over the frames.
void reach_box(const Character& c, const FrameSet& frames, std::span<const double> scale, glm::dvec3& lo, glm::dvec3& hi) {
    const size_t J = c.joint_count();
    if (J == 0 || frames.frame_count() == 0 || scale.size() != J) return;
    std::vector<glm::dvec3> bind(J);
    for (size_t j = 0; j < J; ++j) bind[j] = glm::dvec3(glm::inverse(c.inverse_bind[j])[3]);
    std::vector<double> link(J, 0.0);  // max over frames: |q_j - q_parent|
    std::vector<glm::dvec3> q(J), root_lo(J, glm::dvec3(1e300)), root_hi(J, glm::dvec3(-1e300));
    for (size_t f = 0; f < frames.frame_count(); ++f) {
        const Mat34* m = frames.frame(f);
        for (size_t j = 0; j < J; ++j) {
            const float* x = m[j].m;
            const glm::dvec3 b = bind[j];
            q[j] = {x[0] * b.x + x[1] * b.y + x[2] * b.z + x[3], x[4] * b.x + x[5] * b.y + x[6] * b.z + x[7],
                    x[8] * b.x + x[9] * b.y + x[10] * b.z + x[11]};
        }
        for (size_t j = 0; j < J; ++j) {
            const int p = c.joint_parent[j];
            if (p >= 0) {
                link[j] = std::max(link[j], glm::length(q[j] - q[size_t(p)]));
            } else {
                root_lo[j] = glm::min(root_lo[j], q[j]);
                root_hi[j] = glm::max(root_hi[j], q[j]);
            }
        }
    }
    for (size_t j = 0; j < J; ++j) {
        double reach = scale[j] * glm::length(bind[j]);
        size_t r = j;
        for (size_t hops = 0; c.joint_parent[r] >= 0 && hops <= J; ++hops) {
            reach += link[r];
            r = size_t(c.joint_parent[r]);
        }
        if (c.joint_parent[r] >= 0) continue;  // a cycle: the importer refuses those
        lo = glm::min(lo, root_lo[r] - glm::dvec3(reach));
        hi = glm::max(hi, root_hi[r] + glm::dvec3(reach));
    }
}

// Translation box and scale range of the skinning matrices: the frames' box
// with a margin, grown to the reach box (every rigid pose, reach_box) and
// kLiveRootReach of the diagonal around it.
constexpr double kLiveRootReach = 0.25;
void record_range(AssetTables& t, const Character& c, const FrameSet& frames) {
    glm::vec3 lo(1e30f), hi(-1e30f);
    t.max_scale = 1;
    std::vector<float> scales;
    scales.reserve(frames.frame_count() * size_t(std::max(0, frames.joint_count)));
    std::vector<double> joint_scale(size_t(std::max(0, frames.joint_count)), 0.0);  // per joint, for reach_box
    for (size_t f = 0; f < frames.frame_count(); ++f) {
        const Mat34* m = frames.frame(f);
        for (int j = 0; j < frames.joint_count; ++j) {
            glm::vec3 x{m[j].m[3], m[j].m[7], m[j].m[11]};
            lo = glm::min(lo, x);
            hi = glm::max(hi, x);
            BonePose p = decompose(m[j]);
            t.max_scale = std::max(t.max_scale, double(p.s));
            joint_scale[size_t(j)] = std::max(joint_scale[size_t(j)], double(p.s));
            scales.push_back(p.s);
        }
    }
    const ReferenceScale rs = reference_scale(scales);
    t.ref_scale = rs.scale;
    t.scaled = rs.scaled;
    glm::vec3 ext = hi - lo;
    glm::vec3 margin = ext * 0.25f + glm::vec3(float(0.05 * t.diagonal));
    t.t_min = lo - margin;
    t.t_max = hi + margin;
    const glm::vec3 box = t.t_max - t.t_min;
    t.t_step = std::max({box.x, box.y, box.z, 1e-9f}) / 65535.0f;  // the frames' own step, before the reach
    glm::dvec3 reach_lo(1e300), reach_hi(-1e300);
    reach_box(c, frames, joint_scale, reach_lo, reach_hi);
    if (reach_lo.x <= reach_hi.x) {
        // The root joint itself may move (a crouch, a jump) by a quarter of
        // the diagonal beyond where the frames put it.
        const glm::dvec3 pad(kLiveRootReach * t.diagonal);
        t.t_min = glm::min(t.t_min, glm::vec3(reach_lo - pad));
        t.t_max = glm::max(t.t_max, glm::vec3(reach_hi + pad));
    }
    // At most 2^22 steps across the grown box (translation_step_fits): a
    // skeleton far from the model's origin has a box far larger than its
    // clips', and steps as that box needs.
    const glm::vec3 grown = t.t_max - t.t_min;
    t.t_step = std::max(t.t_step, std::max({grown.x, grown.y, grown.z}) / float(1 << 22) * 1.001f);
}

// RMS vertex motion per second between consecutive frames of one selection.
double rms_motion(const Character& c, const FrameSet& frames) {
    std::vector<glm::vec3> p0(c.vertex_count()), p1(c.vertex_count());
    double sum = 0, n = 0;
    for (size_t f = 0; f + 1 < frames.frame_count(); ++f) {
        if (frames.selection_of_frame[f] != frames.selection_of_frame[f + 1]) continue;
        reference_positions(c, frames, f, p0);
        reference_positions(c, frames, f + 1, p1);
        double dt = frames.times[f + 1] - frames.times[f];
        if (!(dt > 0)) continue;
        for (size_t v = 0; v < p0.size(); ++v) {
            double d = glm::length(p1[v] - p0[v]) / dt;
            sum += d * d;
        }
        n += double(p0.size());
        if (n > 2e6) break;  // enough for an estimate
    }
    return n > 0 ? std::sqrt(sum / n) : 0.0;
}

}  // namespace

AssetTables compute_asset_tables(const Character& c, const ProgressiveSkin& s,
                                 const std::vector<ClipSelection>& selections) {
    if (selections.empty()) throw Error("compute_asset_tables: no clip selection");
    if (s.bone_count() < 1 || s.order.size() != c.joint_count())
        throw Error("compute_asset_tables: the skin does not fit the character");
    AssetTables t;
    t.diagonal = s.diagonal > 0 ? s.diagonal : rest_diagonal(c);
    if (!(t.diagonal > 0)) t.diagonal = 1;
    t.bind_radius = 0;
    for (const auto& p : c.positions) t.bind_radius = std::max(t.bind_radius, double(glm::length(p)));
    // Clips that do not move the skeleton: the range-of-motion poses stand in
    // for every model (what the build trained on, range_of_motion.h).
    bool rom = false;
    const FrameSet frames = training_frames(c, selections, 30.0, &rom);
    record_range(t, c, frames);
    t.motion = rms_motion(c, frames);
    const size_t M = selections.size() + 1;  // models: selections, then all
    layout_segments(t, c, s, selections, rom ? &frames : nullptr);
    gap_tables(t, c, s, frames, M);
    value_tables(t, M);
    return t;
}

namespace {

// x to 7 significant digits: the tables are a cost model, and the shortest
// decimal of the rounded value takes half the bytes of a full double.
double round7(double x) {
    if (x == 0 || !std::isfinite(x)) return x;
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.7g", x);
    return std::strtod(buf, nullptr);
}

nlohmann::json vec3_json(const glm::vec3& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

nlohmann::json numbers_json(const double* x, size_t n) {
    nlohmann::json a = nlohmann::json::array();
    for (size_t i = 0; i < n; ++i) a.push_back(round7(x[i]));
    return a;
}

template <size_t N>
nlohmann::json rows_json(const std::vector<std::array<double, N>>& rows) {
    nlohmann::json a = nlohmann::json::array();
    for (const auto& r : rows) a.push_back(numbers_json(r.data(), N));
    return a;
}

// Reads a JSON array of numbers of exactly n entries into out; false otherwise.
bool read_numbers(const nlohmann::json& j, size_t n, double* out) {
    if (!j.is_array() || j.size() != n) return false;
    for (size_t i = 0; i < n; ++i) {
        if (!j[i].is_number()) return false;
        out[i] = j[i].get<double>();
        if (!std::isfinite(out[i])) return false;
    }
    return true;
}

// One stored segment into s (M models); "" or what is wrong.
std::string read_segment(const nlohmann::json& sj, size_t M, CostSegment& s) {
    s.collapse.resize(M);
    s.show_value.resize(M);
    s.gap.resize(M);
    s.refresh.resize(M);
    if (!read_numbers(sj.value("collapse", nlohmann::json()), M, s.collapse.data()) ||
        !read_numbers(sj.value("show_value", nlohmann::json()), M, s.show_value.data()))
        return "bad stored segment values";
    const nlohmann::json gap = sj.value("gap", nlohmann::json()), refresh = sj.value("refresh", nlohmann::json());
    if (!gap.is_array() || gap.size() != M || !refresh.is_array() || refresh.size() != M)
        return "bad stored segment tables";
    for (size_t m = 0; m < M; ++m)
        if (!read_numbers(gap[m], AssetTables::kGapTable, s.gap[m].data()) ||
            !read_numbers(refresh[m], AssetTables::kGapTable, s.refresh[m].data()))
            return "bad stored segment tables";
    return {};
}

}  // namespace

nlohmann::json asset_tables_json(const AssetTables& t, int bones, size_t selections) {
    nlohmann::json j;
    j["version"] = kServerTablesVersion;
    j["fps"] = 30;
    j["hold_ticks"] = kHoldTicks;  // constants the tables were computed with
    j["gap_table"] = AssetTables::kGapTable;
    j["selections"] = selections;
    j["bones"] = bones;
    j["diagonal"] = t.diagonal;
    j["motion"] = t.motion;
    j["bind_radius"] = t.bind_radius;
    j["max_scale"] = t.max_scale;
    j["format"] = {{"t_min", vec3_json(t.t_min)}, {"t_max", vec3_json(t.t_max)}, {"scaled", t.scaled}, {"scale", t.ref_scale}, {"t_step", t.t_step}};
    j["segments"] = nlohmann::json::array();
    for (const CostSegment& s : t.segments)
        j["segments"].push_back({{"from", s.from},
                                 {"to", s.to},
                                 {"collapse", numbers_json(s.collapse.data(), s.collapse.size())},
                                 {"gap", rows_json(s.gap)},
                                 {"refresh", rows_json(s.refresh)},
                                 {"show_value", numbers_json(s.show_value.data(), s.show_value.size())}});
    return j;
}

bool read_asset_tables(const nlohmann::json& j, int bones, size_t selections, AssetTables& out, std::string* why) {
    auto no = [&](const std::string& w) {
        if (why) *why = w;
        return false;
    };
    if (!j.is_object()) return no("no stored server tables");
    if (j.value("version", 0) != kServerTablesVersion)
        return no("stored server tables are version " + std::to_string(j.value("version", 0)) + ", this server uses " +
                  std::to_string(kServerTablesVersion));
    const size_t M = selections + 1;
    if (j.value("bones", -1) != bones || j.value("selections", size_t(0)) != selections || j.value("fps", 0) != 30)
        return no("stored server tables do not match the character (bones, clip groups or fps)");
    if (j.value("hold_ticks", -1) != kHoldTicks || j.value("gap_table", -1) != AssetTables::kGapTable)
        return no("stored server tables were computed with another HOLD_TICKS or gap table size");
    AssetTables t;  // parsed into a scratch copy: `out` changes only when everything reads
    double v[3];
    t.diagonal = j.value("diagonal", 0.0);
    t.motion = j.value("motion", -1.0);
    t.bind_radius = j.value("bind_radius", -1.0);
    t.max_scale = j.value("max_scale", 0.0);
    if (!(t.diagonal > 0) || !(t.motion >= 0) || !(t.bind_radius >= 0) || !(t.max_scale > 0))
        return no("stored server tables have a bad diagonal, motion, bind radius or scale");
    const nlohmann::json& f = j.contains("format") ? j["format"] : nlohmann::json();
    if (!f.is_object() || !read_numbers(f.value("t_min", nlohmann::json()), 3, v)) return no("bad stored format");
    t.t_min = glm::vec3(float(v[0]), float(v[1]), float(v[2]));
    if (!read_numbers(f.value("t_max", nlohmann::json()), 3, v)) return no("bad stored format");
    t.t_max = glm::vec3(float(v[0]), float(v[1]), float(v[2]));
    t.scaled = f.value("scaled", false);
    t.ref_scale = f.value("scale", 1.0f);
    if (!(t.ref_scale >= kMinReferenceScale && t.ref_scale <= kMaxReferenceScale)) return no("bad stored reference scale");
    if (!f.contains("t_step") || !f["t_step"].is_number()) return no("no stored translation step");
    t.t_step = f["t_step"].get<float>();
    if (!translation_step_fits(t.t_min, t.t_max, t.t_step)) return no("bad stored translation step");
    const nlohmann::json& segs = j.contains("segments") ? j["segments"] : nlohmann::json();
    if (!segs.is_array() || segs.empty()) return no("no stored segments");
    int expect_from = 0;
    for (const nlohmann::json& sj : segs) {
        CostSegment s;
        s.from = sj.value("from", -1);
        s.to = sj.value("to", -1);
        if (s.from != expect_from || s.to <= s.from || s.to > bones) return no("stored segments do not tile the bones");
        expect_from = s.to;
        if (const std::string w = read_segment(sj, M, s); !w.empty()) return no(w);
        t.segments.push_back(std::move(s));
    }
    if (expect_from != bones) return no("stored segments do not cover every bone");
    out = std::move(t);
    return true;
}

}  // namespace progskin
