// bench_interpolation.cpp — how much of the error displayed at unlimited
// rate is the interpolation between server ticks, and what other ways of
// interpolating the same samples would leave (issue 27 item 5). No network,
// no quantisation: every joint's exact skinning matrix is sampled at the
// tick times k / rate of each clip; at nine display times inside each tick
// interval (away from the clip's ends) the skinned vertices of each method
// are compared with the clip evaluated at that time (docs/metrics.md §2,
// RMS / max in % of the rest diagonal). Methods, all over the same samples:
//   lerp           model space: slerp rotation, lerp translation and scale
//   cubic          model space, cubic Hermite (pose.h interpolate_between:
//                  what the client does)
//   joint cubic    the same about each joint's bind position (each matrix's
//                  image of the joint interpolated instead of its translation)
//   rel joint lerp parent-relative (M_parent^-1 M) about the joint, slerp /
//                  lerp, composed down the hierarchy: exactly what a glTF
//                  clip of linear keys does between two of its keys
//   rel joint cubic the same, cubic
// Then a second table: key samples against tick samples (report_keys).
//
// usage: bench_interpolation [--rates "24 30 60"] [FILE...]
//   FILE: glTF/glb characters (default: the bundled Fox and CesiumMan); rates:
//   tick rates in Hz (default "24 30 48 60 120").
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <string>
#include <vector>

#include "animation.h"
#include "error_metric.h"
#include "errors.h"
#include "gltf_import.h"
#include "pose.h"
#include "skinning.h"

using namespace progskin;

namespace {

BonePose about(const BonePose& p, const glm::vec3& pivot) {  // translation -> image of the pivot
    BonePose q = p;
    q.t = p.s * (p.r * pivot) + p.t;
    return q;
}
BonePose back(const BonePose& p, const glm::vec3& pivot) {
    BonePose q = p;
    q.t = p.t - p.s * (p.r * pivot);
    return q;
}
BonePose mul(const BonePose& a, const BonePose& b) {
    BonePose c;
    c.r = glm::normalize(a.r * b.r);
    c.s = a.s * b.s;
    c.t = a.s * (a.r * b.t) + a.t;
    return c;
}

// The character's vertices skinned with these poses (skinning.h SkinningJob).
void skin(const Character& c, const std::vector<BonePose>& poses, std::vector<glm::vec3>& out) {
    std::vector<Mat34> m(poses.size());
    for (size_t j = 0; j < poses.size(); ++j) m[j] = compose(poses[j]);
    out.resize(c.vertex_count());
    SkinningJob job;
    job.positions = c.positions;
    job.joints = c.joints;
    job.weights = c.weights;
    job.influences = job.max_influences = c.influences;
    job.palette = m;
    job.out_positions = out;
    job.run();
}

constexpr int kMethods = 5;
const char* kNames[kMethods] = {"lerp", "cubic (client)", "joint cubic", "rel joint lerp", "rel joint cubic"};

void report(const Character& c, int clip, double rate) {
    const size_t J = c.joint_count();
    const ClipSelection sel = make_selection(c, {clip});
    const int N = int(sel.duration() * rate);
    if (N < 6) return;
    std::vector<glm::vec3> pivot(J);
    for (size_t j = 0; j < J; ++j) pivot[j] = glm::vec3(glm::inverse(c.inverse_bind[j])[3]);
    auto sample = [&](double t) {
        std::vector<glm::dmat4> m(J);
        sample_skinning_matrices(c, sel, sel.start + t, m);
        std::vector<BonePose> p(J);
        for (size_t j = 0; j < J; ++j) p[j] = decompose(Mat34::from_glm(m[j]));
        return p;
    };
    // Per tick: model-space poses about the origin and about the joint, and
    // parent-relative about the joint.
    std::vector<std::vector<BonePose>> model(size_t(N) + 1), joint(size_t(N) + 1), rel(size_t(N) + 1);
    for (int k = 0; k <= N; ++k) {
        model[size_t(k)] = sample(k / rate);
        joint[size_t(k)].resize(J);
        rel[size_t(k)].resize(J);
        for (size_t j = 0; j < J; ++j) {
            const int q = c.joint_parent[j];
            joint[size_t(k)][j] = about(model[size_t(k)][j], pivot[j]);
            rel[size_t(k)][j] = about(q < 0 ? model[size_t(k)][j] : mul(inverse(model[size_t(k)][size_t(q)]), model[size_t(k)][j]), pivot[j]);
        }
    }
    const double diag = rest_diagonal(c);
    std::vector<ErrorAccumulator> err(kMethods, ErrorAccumulator(diag));
    std::vector<std::vector<BonePose>> out(kMethods, std::vector<BonePose>(J));
    std::vector<glm::vec3> ref, got;
    for (int k = 1; k + 2 < N; ++k) {
        for (int s = 1; s < 10; ++s) {
            const double u = k + s / 10.0;
            skin(c, sample(u / rate), ref);
            auto cubic = [&](const std::vector<std::vector<BonePose>>& f, size_t j) {
                return interpolate_between(&f[size_t(k - 1)][j], f[size_t(k)][j], f[size_t(k + 1)][j], &f[size_t(k + 2)][j],
                                           k - 1, k, k + 1, k + 2, u);
            };
            for (size_t j = 0; j < J; ++j) {
                const int q = c.joint_parent[j];
                out[0][j] = interpolate(model[size_t(k)][j], model[size_t(k + 1)][j], float(s / 10.0));
                out[1][j] = cubic(model, j);
                out[2][j] = back(cubic(joint, j), pivot[j]);
                const BonePose rl = back(interpolate(rel[size_t(k)][j], rel[size_t(k + 1)][j], float(s / 10.0)), pivot[j]);
                const BonePose rc = back(cubic(rel, j), pivot[j]);
                out[3][j] = q < 0 ? rl : mul(out[3][size_t(q)], rl);  // joint_parent[j] < j
                out[4][j] = q < 0 ? rc : mul(out[4][size_t(q)], rc);
            }
            for (int m = 0; m < kMethods; ++m) {
                skin(c, out[size_t(m)], got);
                err[size_t(m)].add(ref, got);
            }
        }
    }
    std::printf("| %s | %s | %g |", c.name.c_str(), c.clips[size_t(clip)].name.c_str(), rate);
    for (auto& e : err) std::printf(" %.4f / %.3f |", e.stats().rms_pct, e.stats().max_pct);
    std::printf("\n");
}

// Key samples (progskin-server --key-samples, docs/algorithms.md): the
// parent-relative poses about the joint (the hierarchy build's records)
// sampled at the ticks or at the server's key samples (the latest key since
// the tick before, else half a tick before the tick), a bone refreshed every
// g ticks: between its frames the client's interpolation at the samples'
// times (linear between key samples of adjacent ticks, else the cubic), at
// nine display times per interval. Clips whose channels are not all linear
// are left out.
void report_keys(const Character& c, int clip, double rate) {
    const size_t J = c.joint_count();
    const ClipSelection sel = make_selection(c, {clip});
    const std::vector<double> keys = linear_key_times(c, sel);
    const int N = int(sel.duration() * rate);
    if (keys.empty() || N < 16) return;
    std::vector<glm::vec3> pivot(J);
    for (size_t j = 0; j < J; ++j) pivot[j] = glm::vec3(glm::inverse(c.inverse_bind[j])[3]);
    auto sample = [&](double t) {  // t: seconds after the clip's start
        std::vector<glm::dmat4> m(J);
        sample_skinning_matrices(c, sel, sel.start + t, m);
        std::vector<BonePose> p(J);
        for (size_t j = 0; j < J; ++j) p[j] = decompose(Mat34::from_glm(m[j]));
        return p;
    };
    auto relative = [&](const std::vector<BonePose>& model) {
        std::vector<BonePose> r(J);
        for (size_t j = 0; j < J; ++j) {
            const int q = c.joint_parent[j];
            r[j] = about(q < 0 ? model[j] : mul(inverse(model[size_t(q)]), model[j]), pivot[j]);
        }
        return r;
    };
    const double diag = rest_diagonal(c);
    std::printf("| %s | %s | %g |", c.name.c_str(), c.clips[size_t(clip)].name.c_str(), rate);
    for (int g = 1; g <= 4; ++g) {
        for (int keyed = 0; keyed < 2; ++keyed) {
            // Sample times in ticks of every g-th tick.
            std::vector<double> at;
            for (int k = 0; k <= N; k += g) {
                double t = k;
                if (keyed && k > 0) {
                    const double key = latest_key_in(keys, sel.start + (k - 1) / rate, sel.start + k / rate);
                    t = std::isnan(key) ? k - 0.5 : (key - sel.start) * rate;
                }
                at.push_back(t);
            }
            std::vector<std::vector<BonePose>> rel;
            for (double t : at) rel.push_back(relative(sample(t / rate)));
            ErrorAccumulator err(diag);
            std::vector<BonePose> out(J);
            std::vector<glm::vec3> ref, got;
            for (size_t m = 1; m + 2 < at.size(); ++m) {
                for (int s = 0; s < 9; ++s) {
                    const double u = at[m] + (at[m + 1] - at[m]) * (s + 0.5) / 9.0;
                    skin(c, sample(u / rate), ref);
                    for (size_t j = 0; j < J; ++j) {
                        const int q = c.joint_parent[j];
                        const BonePose r =
                            keyed && g == 1
                                ? interpolate(rel[m][j], rel[m + 1][j], float((u - at[m]) / (at[m + 1] - at[m])))
                                : interpolate_between(&rel[m - 1][j], rel[m][j], rel[m + 1][j], &rel[m + 2][j], at[m - 1], at[m],
                                                      at[m + 1], at[m + 2], u);
                        out[j] = q < 0 ? back(r, pivot[j]) : mul(out[size_t(q)], back(r, pivot[j]));
                    }
                    skin(c, out, got);
                    err.add(ref, got);
                }
            }
            std::printf(" %.4f / %.3f |", err.stats().rms_pct, err.stats().max_pct);
        }
    }
    std::printf("\n");
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string> files;
    std::vector<double> rates = {24, 30, 48, 60, 120};
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--help" || a == "-h") {
            std::printf("usage: bench_interpolation [--rates \"24 30 60\"] [FILE...]\n"
                        "The error of interpolating exact 30 Hz (or --rates) samples of each clip, per method\n"
                        "(model-space lerp and cubic, about the joint, parent-relative): RMS / max in %% of the\n"
                        "rest diagonal. FILE: glTF/glb characters (default: the bundled Fox and CesiumMan).\n");
            return 0;
        }
        if (a == "--rates") {
            if (i + 1 >= argc) { std::fprintf(stderr, "bench_interpolation: --rates needs a list of Hz\n"); return 2; }
            rates.clear();
            std::istringstream in(argv[++i]);
            double r;
            while (in >> r) {
                if (!(r > 0 && r <= 1000)) { std::fprintf(stderr, "bench_interpolation: --rates: %g is not in (0, 1000]\n", r); return 2; }
                rates.push_back(r);
            }
            if (rates.empty() || !in.eof()) { std::fprintf(stderr, "bench_interpolation: --rates: not a list of numbers: %s\n", argv[i]); return 2; }
            continue;
        }
        if (!a.empty() && a[0] == '-') { std::fprintf(stderr, "bench_interpolation: unknown option %s (--help)\n", a.c_str()); return 2; }
        files.push_back(a);
    }
    if (files.empty()) files = {std::string(PROGSKIN_ASSETS) + "/Fox.glb", std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb"};
    std::printf("| character | clip | tick Hz |");
    for (const char* n : kNames) std::printf(" %s |", n);
    std::printf("\n|---|---|---|");
    for (int m = 0; m < kMethods; ++m) std::printf("---|");
    std::printf("\n");
    try {
        for (const auto& f : files) {
            const Character c = import_character(f);
            for (double r : rates)
                for (int k = 0; k < int(c.clips.size()); ++k) report(c, k, r);
        }
        std::printf("\nKey samples against tick samples, parent-relative about the joint, a bone refreshed every g ticks\n"
                    "(RMS / max, %% of the rest diagonal):\n\n| character | clip | tick Hz |");
        for (int g = 1; g <= 4; ++g) std::printf(" g %d, ticks | g %d, keys |", g, g);
        std::printf("\n|---|---|---|");
        for (int g = 1; g <= 4; ++g) std::printf("---|---|");
        std::printf("\n");
        for (const auto& f : files) {
            const Character c = import_character(f);
            for (double r : rates)
                for (int k = 0; k < int(c.clips.size()); ++k) report_keys(c, k, r);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "bench_interpolation: %s\n", e.what());
        return 1;
    }
    return 0;
}
