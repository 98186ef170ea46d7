// scratch_alias_probe.cpp — sixth round on CesiumMan k=4 / k=8 (issue 4):
// aliases, i.e. twins that cost no streamed bone.
//
// Round four found that a frozen coarse skin meets k=4 and k=8 but that every
// fine motion then needs a copy in every coarse group it crosses, and the
// copies used up the bone budget. Here a copy is an *alias*: a palette joint
// with a source bone; while the source is streamed the alias takes its matrix,
// otherwise it stands in through its own progressive parent. It costs a
// palette slot and an influence, never a streamed matrix, so k counts sources.
//
// Probe: coarse skin = hybrid build with K0 bones (PSK_K0, default 8; levels
// 1..K0 are its palette), fine motions = the collapse build's PSK_NF (32)
// bones, transforms re-fitted to the coarse bind positions (the same: both
// builds keep the mean pose, PSK_BIND=0). A joint is (coarse bone g, motion
// m): the coarse bone itself (m = -1) or an alias of fine motion m that falls
// back to g until m is streamed. Per vertex at most 4 joints with weights by
// NNLS: PSK_ML=0 keeps the coarse skin's weight per group (round four's
// constraint, with free copies); PSK_ML=1 (default) solves the weights over
// all groups for a weighted sum of levels (PSK_MLL, then PSK_MLL2 once an
// order exists: "L:target,..." with lambda = 1/target^2, L = 0 full detail).
// Fine motions are streamed in greedy order (each step the motion that lowers
// the error most), then weights and order alternate PSK_ROUNDS (3) times.
// Prints e(k) for every k and one RESULT line per stage.
//
// Build (from the repository root, after the README's test build in build/):
//   g++ -std=c++20 -O2 -Icommon -I/usr/include/eigen3 docs/experiments/scratch_alias_probe.cpp
//       build/common/libprogskin_core.a -ltinygltf -o /tmp/alias_probe
//   /tmp/alias_probe [../shared/assets/CesiumMan.glb]   (about a minute)
#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "palette.h"
#include "probe_util.h"
#include "scratch_build.h"
#include "vertex_animation.h"

using namespace progskin;
using namespace probe;

// Lawson-Hanson NNLS on the normal equations G w = h (G symmetric PSD), over `allowed`.
// Kept apart from the library's file-local nnls (common/scratch_build.cpp):
// swapping it in moves this probe's figures in the third digit (its step
// tolerance and ridge differ), and scratch-aliases.log records these.
static Eigen::VectorXd nnls(const Eigen::MatrixXd& G, const Eigen::VectorXd& h, const std::vector<char>& allowed) {
    const int n = int(h.size());
    Eigen::VectorXd w = Eigen::VectorXd::Zero(n);
    std::vector<char> P(size_t(n), 0);
    for (int outer = 0; outer < 3 * n + 3; ++outer) {
        const Eigen::VectorXd grad = h - G * w;
        int best = -1;
        double bg = 1e-12 * (1 + h.cwiseAbs().maxCoeff());
        for (int i = 0; i < n; ++i)
            if (allowed[size_t(i)] && !P[size_t(i)] && grad(i) > bg) bg = grad(i), best = i;
        if (best < 0) break;
        P[size_t(best)] = 1;
        for (int inner = 0; inner < 3 * n + 3; ++inner) {
            std::vector<int> idx;
            for (int i = 0; i < n; ++i)
                if (P[size_t(i)]) idx.push_back(i);
            Eigen::MatrixXd Gs(idx.size(), idx.size());
            Eigen::VectorXd hs(idx.size());
            for (size_t a = 0; a < idx.size(); ++a) {
                hs(Eigen::Index(a)) = h(idx[a]);
                for (size_t b = 0; b < idx.size(); ++b) Gs(Eigen::Index(a), Eigen::Index(b)) = G(idx[a], idx[b]);
            }
            Gs.diagonal().array() += 1e-12 * (1 + Gs.diagonal().cwiseAbs().maxCoeff());
            const Eigen::VectorXd z = Gs.ldlt().solve(hs);
            if (z.minCoeff() > 0) {
                w.setZero();
                for (size_t a = 0; a < idx.size(); ++a) w(idx[a]) = z(Eigen::Index(a));
                break;
            }
            double alpha = 1;
            for (size_t a = 0; a < idx.size(); ++a)
                if (z(Eigen::Index(a)) <= 0) {
                    const double wa = w(idx[a]);
                    alpha = std::min(alpha, wa / std::max(wa - z(Eigen::Index(a)), 1e-300));
                }
            for (size_t a = 0; a < idx.size(); ++a) w(idx[a]) += alpha * (z(Eigen::Index(a)) - w(idx[a]));
            for (size_t a = 0; a < idx.size(); ++a)
                if (w(idx[a]) <= 1e-14) w(idx[a]) = 0, P[size_t(idx[a])] = 0;
        }
    }
    return w;
}

struct Joint {
    int group;   // coarse bone
    int motion;  // -1: the coarse bone itself, else fine motion
};

int main(int argc, char** argv) {
    const std::string path = argc > 1 ? argv[1] : "../shared/assets/CesiumMan.glb";
    const int K0 = envi("PSK_K0", 8), NF = envi("PSK_NF", 32);
    const bool bind = envi("PSK_BIND", 0) != 0;
    double diag = 0;
    const VertexAnimation an = load_all_clips(path, &diag);
    const size_t V = an.vertex_count, F = an.frame_count;
    auto t0 = std::chrono::steady_clock::now();

    ScratchOptions co;
    co.max_bones = K0;
    co.method = ScratchMethod(envi("PSK_CMETHOD", int(ScratchMethod::Hybrid)));
    co.update_bind = bind;
    const ScratchResult C = build_from_vertices(an, co);
    std::printf("coarse (%d bones):", K0);
    for (auto& e : C.skin.error) std::printf(" %.3g", e.rms_pct);
    std::printf("\n");
    ScratchOptions fo;
    fo.max_bones = NF;
    fo.method = ScratchMethod::Collapse;
    fo.update_bind = bind;
    const ScratchResult Fi = build_from_vertices(an, fo);
    std::printf("fine (%d bones): e(%d) %.3g  e(16) %.3g\n", NF, NF, Fi.skin.error.back().rms_pct,
                Fi.skin.error[std::min<size_t>(15, Fi.skin.error.size() - 1)].rms_pct);
    const int Bf = Fi.skin.bone_count();

    std::vector<V3> p(V), pf(V);
    double dp = 0;
    for (size_t v = 0; v < V; ++v) {
        p[v] = V3(C.character.positions[v].x, C.character.positions[v].y, C.character.positions[v].z);
        pf[v] = V3(Fi.character.positions[v].x, Fi.character.positions[v].y, Fi.character.positions[v].z);
        dp += (p[v] - pf[v]).squaredNorm();
    }
    std::printf("bind difference rms %.3g %%\n", 100 * std::sqrt(dp / double(V)) / diag);
    std::vector<V3> X(V * F);
    for (size_t f = 0; f < F; ++f)
        for (size_t v = 0; v < V; ++v) {
            const glm::vec3 x = an.frame(f)[v];
            X[f * V + v] = V3(x.x, x.y, x.z);
        }

    // Coarse palettes per level k <= K0 and frame.
    const int Kc = C.skin.bone_count();
    std::vector<M34> Pc(size_t(Kc) * F * size_t(Kc));  // [k-1][f][g]
    for (int k = 1; k <= Kc; ++k)
        for (size_t f = 0; f < F; ++f) {
            std::vector<Mat34> own{size_t(k), Mat34{}}, out{size_t(Kc), Mat34{}};
            for (int b = 0; b < k; ++b) own[size_t(b)] = C.frames.frame(f)[C.skin.order[size_t(b)]];
            PaletteJob pj{C.skin.parents, C.skin.corrections, own, {}, out};
            pj.run();
            for (int g = 0; g < Kc; ++g) Pc[(size_t(k - 1) * F + f) * size_t(Kc) + size_t(g)] = to_e(out[size_t(g)]);
        }
    auto coarse = [&](int k, size_t f, int g) -> const M34& { return Pc[(size_t(k - 1) * F + f) * size_t(Kc) + size_t(g)]; };
    const int inf = C.skin.influences;

    // Fine motions: transforms re-fitted to the coarse bind positions (SSDR transform sweeps).
    std::vector<M34> T(size_t(Bf) * F);
    for (size_t f = 0; f < F; ++f)
        for (int m = 0; m < Bf; ++m) T[f * size_t(Bf) + size_t(m)] = to_e(Fi.frames.frame(f)[Fi.skin.order[size_t(m)]]);
    std::vector<std::vector<std::pair<int, double>>> fw(V);
    const int finf = Fi.skin.influences;
    for (size_t v = 0; v < V; ++v)
        for (int i = 0; i < finf; ++i) {
            const float w = Fi.skin.weights[v * size_t(finf) + size_t(i)];
            if (w > 0) fw[v].push_back({Fi.skin.joints[v * size_t(finf) + size_t(i)], w});
        }
    for (int sweep = 0; sweep < envi("PSK_TSWEEPS", 3); ++sweep)
        for (int m = 0; m < Bf; ++m)
            for (size_t f = 0; f < F; ++f) {
                std::vector<V3> xs, ys;
                std::vector<double> ws;
                for (size_t v = 0; v < V; ++v) {
                    double wm = 0;
                    V3 rest = X[f * V + v];
                    for (auto [b, w] : fw[v]) {
                        if (b == m) wm = w;
                        else rest -= w * xf(T[f * size_t(Bf) + size_t(b)], p[v]);
                    }
                    if (wm < 1e-3) continue;
                    xs.push_back(p[v]);
                    ys.push_back(rest / wm);
                    ws.push_back(wm * wm);
                }
                if (xs.size() >= 3) T[f * size_t(Bf) + size_t(m)] = procrustes(xs, ys, ws);
            }
    {
        double e = 0;
        for (size_t f = 0; f < F; ++f)
            for (size_t v = 0; v < V; ++v) {
                V3 r = V3::Zero();
                for (auto [b, w] : fw[v]) r += w * xf(T[f * size_t(Bf) + size_t(b)], p[v]);
                e += (r - X[f * V + v]).squaredNorm();
            }
        std::printf("fine skin on coarse binds: %.3g %%\n", 100 * std::sqrt(e / double(V * F)) / diag);
    }

    // Joints: (coarse group, motion); the first Kc are the coarse bones.
    std::vector<Joint> joints;
    auto joint_id = [&](int g, int m) {
        for (size_t j = 0; j < joints.size(); ++j)
            if (joints[j].group == g && joints[j].motion == m) return int(j);
        joints.push_back({g, m});
        return int(joints.size() - 1);
    };
    for (int g = 0; g < Kc; ++g) joint_id(g, -1);
    std::vector<std::vector<std::pair<int, double>>> vw(V);
    const double penalty = envd("PSK_PEN", 1e4);
    const bool ml = envi("PSK_ML", 1) != 0;
    auto parse_levels = [](const char* name, const char* def) {
        std::vector<std::pair<int, double>> out;  // (level, lambda); level 0 = full detail
        const std::string spec = std::getenv(name) ? std::getenv(name) : def;
        size_t i = 0;
        while (i < spec.size()) {
            size_t c = spec.find(',', i);
            if (c == std::string::npos) c = spec.size();
            const std::string item = spec.substr(i, c - i);
            const size_t colon = item.find(':');
            const double t = std::atof(item.substr(colon + 1).c_str());
            out.push_back({std::atoi(item.substr(0, colon).c_str()), 1.0 / (t * t)});
            i = c + 1;
        }
        return out;
    };
    // rank[m]: position of fine motion m in the streamed order after the coarse bones (Bf = not yet).
    std::vector<int> rank(size_t(Bf), Bf);
    // Matrix of joint (g, m) at level L (0 = full detail), frame f; aliases fall back to their coarse bone.
    auto joint_matrix = [&](int g, int m, int L, size_t f) -> const M34& {
        if (L == 0) return m < 0 ? coarse(Kc, f, g) : T[f * size_t(Bf) + size_t(m)];
        if (L <= Kc || m < 0 || rank[size_t(m)] >= L - Kc) return coarse(std::min(L, Kc), f, g);
        return T[f * size_t(Bf) + size_t(m)];
    };
    auto solve_weights = [&](const std::vector<std::pair<int, double>>& levels) {
        double err_full = 0;
        for (size_t v = 0; v < V; ++v) {
            std::vector<std::pair<int, double>> groups;
            for (int i = 0; i < inf; ++i) {
                const float w = C.skin.weights[v * size_t(inf) + size_t(i)];
                if (w > 0) groups.push_back({C.skin.joints[v * size_t(inf) + size_t(i)], w});
            }
            std::vector<int> mot;
            for (auto [b, w] : fw[v]) mot.push_back(b);
            struct Var {
                int g, m;
            };
            std::vector<Var> vars;
            if (ml) {
                groups.clear();
                for (int g = 0; g < Kc; ++g) groups.push_back({g, 0.0});
            }
            for (auto [g, w] : groups) {
                vars.push_back({g, -1});
                for (int m : mot) vars.push_back({g, m});
            }
            const int n = int(vars.size());
            Eigen::VectorXd x(3 * F);
            for (size_t f = 0; f < F; ++f) x.segment(Eigen::Index(3 * f), 3) = X[f * V + v];
            auto columns = [&](int L) {
                Eigen::MatrixXd A(3 * F, n);
                for (int j = 0; j < n; ++j)
                    for (size_t f = 0; f < F; ++f)
                        A.block(Eigen::Index(3 * f), j, 3, 1) = xf(joint_matrix(vars[size_t(j)].g, vars[size_t(j)].m, L, f), p[v]);
                return A;
            };
            const Eigen::MatrixXd A = columns(0);
            Eigen::MatrixXd G = Eigen::MatrixXd::Zero(n, n);
            Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
            if (ml) {
                for (auto [L, lam] : levels) {
                    const Eigen::MatrixXd AL = L == 0 ? A : columns(L);
                    G += lam * AL.transpose() * AL;
                    h += lam * AL.transpose() * x;
                }
                const double s = penalty * (1 + G.diagonal().maxCoeff());
                G.array() += s;
                h.array() += s;
            } else {
                G = A.transpose() * A;
                h = A.transpose() * x;
                const double s = penalty * (1 + G.diagonal().maxCoeff());
                for (auto [g, wg] : groups)
                    for (int a = 0; a < n; ++a) {
                        if (vars[size_t(a)].g != g) continue;
                        h(a) += s * wg;
                        for (int b = 0; b < n; ++b)
                            if (vars[size_t(b)].g == g) G(a, b) += s;
                    }
            }
            std::vector<char> allowed(size_t(n), 1);
            Eigen::VectorXd w = nnls(G, h, allowed);
            for (;;) {
                int nnz = 0;
                for (int j = 0; j < n; ++j) nnz += w(j) > 0;
                if (nnz <= 4) break;
                int drop = -1;
                for (int j = 0; j < n; ++j) {
                    if (w(j) <= 0) continue;
                    int in_group = 0;
                    for (int i = 0; i < n; ++i) in_group += w(i) > 0 && vars[size_t(i)].g == vars[size_t(j)].g;
                    if (!ml && in_group < 2) continue;
                    if (drop < 0 || w(j) < w(drop)) drop = j;
                }
                if (drop < 0) break;
                allowed[size_t(drop)] = 0;
                w = nnls(G, h, allowed);
            }
            if (ml) {
                w /= std::max(w.sum(), 1e-300);
            } else {
                for (auto [g, wg] : groups) {
                    double sg = 0;
                    for (int j = 0; j < n; ++j)
                        if (vars[size_t(j)].g == g) sg += w(j);
                    for (int j = 0; j < n; ++j)
                        if (vars[size_t(j)].g == g && sg > 0) w(j) *= wg / sg;
                    if (sg <= 0)
                        for (int j = 0; j < n; ++j)
                            if (vars[size_t(j)].g == g && vars[size_t(j)].m < 0) w(j) = wg;
                }
            }
            vw[v].clear();
            for (int j = 0; j < n; ++j)
                if (w(j) > 0) vw[v].push_back({joint_id(vars[size_t(j)].g, vars[size_t(j)].m), w(j)});
            err_full += (A * w - x).squaredNorm();
        }
        return 100 * std::sqrt(err_full / double(V * F)) / diag;
    };
    // Squared error of vertex v at level L with the current rank.
    auto vertex_err = [&](size_t v, int L) {
        double e = 0;
        for (size_t f = 0; f < F; ++f) {
            V3 r = V3::Zero();
            for (auto [j, w] : vw[v]) r += w * xf(joint_matrix(joints[size_t(j)].group, joints[size_t(j)].motion, L, f), p[v]);
            e += (r - X[f * V + v]).squaredNorm();
        }
        return e;
    };
    auto table = [&]() {
        std::vector<double> t;
        int n_on = 0;
        for (int m = 0; m < Bf; ++m) n_on += rank[size_t(m)] < Bf;
        for (int k = 1; k <= Kc + n_on; ++k) {
            double e = 0;
            for (size_t v = 0; v < V; ++v) e += vertex_err(v, k);
            t.push_back(100 * std::sqrt(e / double(V * F)) / diag);
        }
        return t;
    };
    // Greedy order of the fine motions: each step streams the motion that lowers the error most.
    auto greedy_order = [&]() {
        std::vector<std::vector<size_t>> users;
        users.resize(size_t(Bf));
        for (size_t v = 0; v < V; ++v)
            for (auto [j, w] : vw[v])
                if (joints[size_t(j)].motion >= 0) {
                    auto& u = users[size_t(joints[size_t(j)].motion)];
                    if (u.empty() || u.back() != v) u.push_back(v);
                }
        std::fill(rank.begin(), rank.end(), Bf);
        std::vector<double> ev(V);
        for (size_t v = 0; v < V; ++v) ev[v] = vertex_err(v, Kc);
        for (int step = 0; step < Bf; ++step) {
            int best = -1;
            double bd = 0;
            for (int m = 0; m < Bf; ++m) {
                if (rank[size_t(m)] < Bf || users[size_t(m)].empty()) continue;
                rank[size_t(m)] = step;
                double d = 0;
                for (size_t v : users[size_t(m)]) d += vertex_err(v, Kc + step + 1) - ev[v];
                rank[size_t(m)] = Bf;
                if (best < 0 || d < bd) bd = d, best = m;
            }
            if (best < 0) break;
            rank[size_t(best)] = step;
            // Only the motion's users change: every other vertex is the same at all levels >= Kc.
            for (size_t v : users[size_t(best)]) ev[v] = vertex_err(v, Kc + step + 1);
        }
    };
    auto report = [&](const char* what) {
        const std::vector<double> t = table();
        const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        auto g = [&](int k) { return t[size_t(std::min<int>(k, int(t.size())) - 1)]; };
        bool mono = true;
        for (size_t i = 1; i < t.size(); ++i) mono = mono && t[i] <= t[i - 1] * (1 + 1e-9);
        size_t switched = 0;  // vertices whose every joint follows a streamed fine motion at k=16
        for (size_t v = 0; v < V; ++v) {
            bool all = true;
            for (auto [j, w] : vw[v]) {
                const int m = joints[size_t(j)].motion;
                all = all && m >= 0 && rank[size_t(m)] < 16 - Kc;
            }
            switched += all;
        }
        std::printf("vertices fully on fine motions at k=16: %.1f %%\n", 100.0 * double(switched) / double(V));
        std::printf("table:");
        for (double e : t) std::printf(" %.3g", e);
        std::printf("\nRESULT %s K0=%d NF=%d: %.3g %.3g %.3g %.3g %.3g e19=%.3g ratios %.2f %.2f %.2f %s joints=%zu (%.0fs)\n",
                    what, K0, NF, g(2), g(4), g(8), g(16), g(32), g(19), g(4) / 1.64, g(8) / 0.338, g(16) / 0.153,
                    mono ? "mono" : "RISE", joints.size(), secs);
        std::fflush(stdout);
    };
    std::printf("full detail of the first solve: %.3g %%\n",
                solve_weights(parse_levels("PSK_MLL", "4:1.64,8:0.338,0:0.05")));
    greedy_order();
    report("round0");
    const auto levels2 = parse_levels("PSK_MLL2", "4:1.64,8:0.338,12:0.25,16:0.12,20:0.08,24:0.06,32:0.05,0:0.05");
    for (int round = 1; round <= envi("PSK_ROUNDS", 3); ++round) {
        std::printf("full detail: %.3g %%\n", solve_weights(levels2));
        report("weights");
        greedy_order();
        const std::string tag = "round" + std::to_string(round);
        report(tag.c_str());
    }
}
