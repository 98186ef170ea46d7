// scratch_blend_probe.cpp — seventh round on CesiumMan k=4 / k=8 (issue 4):
// blended stand-ins, i.e. copy-down that blends several active bones.
//
// Rounds one to six changed the skin (order, hierarchy, weights, coarse
// bones) and kept the runtime rule: an inactive bone stands in as ONE active
// ancestor's streamed matrix times a constant correction, and an active bone
// streams the same matrix at every level. Each round found that the first k
// bones cannot serve level k and the fine levels at once. This probe keeps the
// shipped skin (vertex stream, weights, bind positions, full-detail matrices)
// and measures what a level-aware runtime rule would reach at level k:
//
//   today     the shipped table (copy-down with chained corrections);
//   blend     standin_k(j) = sum_a c_ja(k) * S_a * D_ja over PSK_NC (3)
//             candidates a: today's stand-in (nearest active ancestor, chained
//             correction) and the active bones with the least stand-in cost for
//             j (D_ja their affine least-squares correction); c(k) per level by
//             linear least squares over all vertices and frames, each bone's
//             summing to 1 (PSK_SUM1=0: free), with a ridge toward today's
//             stand-in of PSK_RIDGE x the normal matrix's mean diagonal;
//   free-wts  Dem Bones' model on the shipped first k motions: every vertex its
//             own unconstrained least-squares weights over all k streamed
//             matrices at its bind position (no limit, sign or sum; no
//             corrections, so it can lose to today's at fine levels);
//   group     today's stand-ins, but each active bone streams, instead of its
//             own matrix, a rigid matrix fitted per frame to everything it moves
//             at level k (Gauss-Seidel weighted Procrustes, PSK_GSWEEPS 4);
//   both      blend and group alternated PSK_ROUNDS (3) times (e after each;
//             "coefficients" is the range of the last round's c).
//
// Full detail is the shipped skin in every column. The figures are training
// error on the input frames, like every table of the build and Dem Bones';
// PSK_HOLDOUT=1 fits the coefficients, corrections and free weights on the
// even frames and measures on the odd ones (the skin itself and the per-frame
// group matrices still use every frame).
// PSK_PAIR=1 replaces every inactive bone's chained correction by one fitted
// for its (bone, nearest active ancestor) pair at each level (GUIDE.md's
// C_b,a; affine least squares over the bone's users, weighted by their weight
// in it), which "today" then measures: a copy-down runtime with a correction
// table per pair instead of per bone.
//
// Build (from the repository root, after the README's test build in build/):
//   g++ -std=c++20 -O2 -Icommon -I/usr/include/eigen3 docs/experiments/scratch_blend_probe.cpp
//       build/common/libprogskin_core.a -ltinygltf -o /tmp/blend_probe
//   /tmp/blend_probe [../shared/assets/CesiumMan.glb]   (about a minute)
#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numeric>
#include <string>
#include <vector>

#include "palette.h"
#include "probe_util.h"
#include "scratch_build.h"
#include "vertex_animation.h"

using namespace progskin;
using namespace probe;

int main(int argc, char** argv) {
    const std::string path = argc > 1 ? argv[1] : "../shared/assets/CesiumMan.glb";
    const int NC = std::max(1, envi("PSK_NC", 3));
    const bool sum1 = envi("PSK_SUM1", 1) != 0;
    const bool pair_corr = envi("PSK_PAIR", 0) != 0;
    // PSK_HOLDOUT=1: coefficients, corrections and free weights fitted on the
    // even frames, every column measured on the odd ones.
    const bool holdout = envi("PSK_HOLDOUT", 0) != 0;
    auto fit_frame = [&](size_t f) { return !holdout || f % 2 == 0; };
    auto eval_frame = [&](size_t f) { return !holdout || f % 2 == 1; };
    double diag = 0;
    const VertexAnimation an = load_all_clips(path, &diag);
    const size_t V = an.vertex_count, F = an.frame_count;
    const auto t0 = std::chrono::steady_clock::now();

    ScratchOptions so;
    so.max_bones = envi("PSK_BONES", 32);
    so.method = ScratchMethod(envi("PSK_METHOD", int(ScratchMethod::Auto)));
    const ScratchResult R = build_from_vertices(an, so);
    const ProgressiveSkin& sk = R.skin;
    const int B = sk.bone_count();
    std::printf("shipped skin (%d bones, %.0f s):", B,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    for (int k : {2, 4, 8, 16, 32})
        if (k <= B) std::printf(" e(%d) %.3g", k, sk.error[size_t(k - 1)].rms_pct);
    std::printf("\n");

    std::vector<V3> p(V), X(V * F);
    for (size_t v = 0; v < V; ++v) p[v] = V3(R.character.positions[v].x, R.character.positions[v].y, R.character.positions[v].z);
    for (size_t f = 0; f < F; ++f)
        for (size_t v = 0; v < V; ++v) {
            const glm::vec3 x = an.frame(f)[v];
            X[f * V + v] = V3(x.x, x.y, x.z);
        }
    std::vector<M34> S(F * size_t(B));  // [f][b] own skinning matrices
    for (size_t f = 0; f < F; ++f)
        for (int b = 0; b < B; ++b) S[f * size_t(B) + size_t(b)] = to_e(R.frames.frame(f)[sk.order[size_t(b)]]);
    std::vector<std::vector<std::pair<int, double>>> wv(V);
    std::vector<std::vector<int>> users(static_cast<size_t>(B));
    for (size_t v = 0; v < V; ++v)
        for (int i = 0; i < sk.influences; ++i) {
            const float w = sk.weights[v * size_t(sk.influences) + size_t(i)];
            const int j = sk.joints[v * size_t(sk.influences) + size_t(i)];
            if (w > 0) wv[v].push_back({j, w}), users[size_t(j)].push_back(int(v));
        }
    auto wof = [&](size_t v, int j) {
        for (auto [b, w] : wv[v])
            if (b == j) return w;
        return 0.0;
    };

    struct Term {
        int a;      // active bone whose streamed (or group) matrix it uses
        M34 D;      // constant correction
        int coef;   // index into c, -1: fixed 1 (active bones' own term)
    };
    const int rounds = envi("PSK_ROUNDS", 3);
    std::printf("k   today    blend    free-wts group    both(%d rounds)   (blend: candidates %d, %s)\n", rounds, NC,
                sum1 ? "sum 1" : "free");
    for (int k : {2, 3, 4, 6, 8, 12, 16}) {
        if (k >= B) break;
        // Today's stand-ins at level k give each inactive bone its nearest
        // active ancestor and chained correction: standin = S_anc * Cs.
        std::vector<Mat34> own(static_cast<size_t>(k)), out(static_cast<size_t>(B));
        for (int b = 0; b < k; ++b) own[size_t(b)] = R.frames.frame(0)[sk.order[size_t(b)]];
        PaletteJob pj{sk.parents, sk.corrections, own, {}, out};
        pj.run();
        std::vector<std::vector<Term>> terms(static_cast<size_t>(B));
        int n = 0;
        for (int j = 0; j < B; ++j) {
            if (j < k) {
                terms[size_t(j)].push_back({j, M34::Identity(), -1});
                continue;
            }
            int a = j;
            while (a >= k) a = sk.parents[size_t(a)];
            const M34& Sa = S[size_t(a)];  // frame 0
            M34 inv;
            inv.leftCols<3>() = Sa.leftCols<3>().inverse();
            inv.col(3) = -inv.leftCols<3>() * Sa.col(3);
            terms[size_t(j)].push_back({a, mul(inv, to_e(out[size_t(j)])), n++});
            // Other candidates: the active bones with the least stand-in cost,
            // each with its affine least-squares correction over j's users.
            std::vector<std::pair<double, int>> costs;
            std::vector<M34> fits(static_cast<size_t>(k));
            // Affine least-squares correction of j's stand-in through bone b,
            // over j's users weighted by their weight in j.
            auto fit_corr = [&](int b) {
                Eigen::Matrix4d A = Eigen::Matrix4d::Zero();
                Eigen::Matrix<double, 4, 3> Bm = Eigen::Matrix<double, 4, 3>::Zero();
                for (int v : users[size_t(j)]) {
                    const double w = wof(size_t(v), j);
                    const Eigen::Vector4d xh(p[size_t(v)].x(), p[size_t(v)].y(), p[size_t(v)].z(), 1);
                    for (size_t f = 0; f < F; ++f) {
                        if (!fit_frame(f)) continue;
                        const M34& Sb = S[f * size_t(B) + size_t(b)];
                        const V3 z = Sb.leftCols<3>().transpose() * (xf(S[f * size_t(B) + size_t(j)], p[size_t(v)]) - Sb.col(3));
                        A += w * xh * xh.transpose();
                        Bm += w * xh * z.transpose();
                    }
                }
                A.diagonal().array() += 1e-9 * (1 + A.trace());
                return M34(Eigen::Matrix<double, 4, 3>(A.ldlt().solve(Bm)).transpose());
            };
            // PSK_PAIR=1: the nearest active ancestor's correction fitted for
            // this (bone, ancestor) pair (GUIDE's C_b,a) instead of chained.
            if (pair_corr) terms[size_t(j)][0].D = fit_corr(a);
            for (int b = 0; b < k && NC > 1; ++b) {
                fits[size_t(b)] = fit_corr(b);
                double c = 0;
                for (int v : users[size_t(j)]) {
                    const double w = wof(size_t(v), j);
                    for (size_t f = 0; f < F; ++f)
                        if (fit_frame(f))
                            c += w * (xf(mul(S[f * size_t(B) + size_t(b)], fits[size_t(b)]), p[size_t(v)]) -
                                  xf(S[f * size_t(B) + size_t(j)], p[size_t(v)]))
                                     .squaredNorm();
                }
                costs.push_back({c, b});
            }
            std::sort(costs.begin(), costs.end());
            for (int i = 0; i < int(costs.size()) && int(terms[size_t(j)].size()) < NC; ++i)
                terms[size_t(j)].push_back({costs[size_t(i)].second, fits[size_t(costs[size_t(i)].second)], n++});
        }
        Eigen::VectorXd c0 = Eigen::VectorXd::Zero(n);
        for (int j = k; j < B; ++j) c0(terms[size_t(j)][0].coef) = 1;
        auto coef = [&](const Eigen::VectorXd& c, const Term& t) { return t.coef < 0 ? 1.0 : c(t.coef); };
        std::vector<M34> M0(F * size_t(k));  // [f][a]: streamed matrices of the active bones
        for (size_t f = 0; f < F; ++f)
            for (int a = 0; a < k; ++a) M0[f * size_t(k) + size_t(a)] = S[f * size_t(B) + size_t(a)];
        auto error = [&](const std::vector<M34>& M, const Eigen::VectorXd& c) {
            double e = 0;
            size_t n_eval = 0;
            for (size_t f = 0; f < F; ++f)
                for (size_t v = 0; v < V && eval_frame(f); ++v, ++n_eval) {
                    V3 y = V3::Zero();
                    for (auto [j, w] : wv[v])
                        for (const Term& t : terms[size_t(j)])
                            y += w * coef(c, t) * xf(mul(M[f * size_t(k) + size_t(t.a)], t.D), p[v]);
                    e += (y - X[f * V + v]).squaredNorm();
                }
            return 100 * std::sqrt(e / double(n_eval)) / diag;
        };
        // Coefficients given the streamed matrices: linear least squares,
        // each inactive bone's summing to 1 (KKT) with PSK_SUM1.
        auto solve_blend = [&](const std::vector<M34>& M) {
            Eigen::MatrixXd G = Eigen::MatrixXd::Zero(n, n);
            Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
            std::vector<int> idx;
            std::vector<V3> u;
            for (size_t f = 0; f < F; ++f)
                for (size_t v = 0; v < V && fit_frame(f); ++v) {
                    V3 r = X[f * V + v];
                    idx.clear(), u.clear();
                    for (auto [j, w] : wv[v])
                        for (const Term& t : terms[size_t(j)]) {
                            const V3 q = w * xf(mul(M[f * size_t(k) + size_t(t.a)], t.D), p[v]);
                            if (t.coef < 0) r -= q;
                            else idx.push_back(t.coef), u.push_back(q);
                        }
                    for (size_t a = 0; a < idx.size(); ++a) {
                        h(idx[a]) += u[a].dot(r);
                        for (size_t b = 0; b < idx.size(); ++b) G(idx[a], idx[b]) += u[a].dot(u[b]);
                    }
                }
            // Ridge toward today's stand-ins (PSK_RIDGE x the mean diagonal).
            const double lam = envd("PSK_RIDGE", 0) * G.diagonal().mean();
            G.diagonal().array() += lam + 1e-9 * (1 + G.diagonal().maxCoeff());
            h += lam * c0;
            if (!sum1) return Eigen::VectorXd(G.ldlt().solve(h));
            const int m = B - k;
            Eigen::MatrixXd K = Eigen::MatrixXd::Zero(n + m, n + m);
            Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n + m);
            K.topLeftCorner(n, n) = G;
            rhs.head(n) = h;
            for (int j = k; j < B; ++j) {
                for (const Term& t : terms[size_t(j)]) K(n + j - k, t.coef) = K(t.coef, n + j - k) = 1;
                rhs(n + j - k) = 1;
            }
            return Eigen::VectorXd(K.fullPivLu().solve(rhs).head(n));
        };
        // Group matrices given the coefficients: per frame, each active bone's
        // matrix is the rigid fit to everything it moves at level k
        // (Gauss-Seidel weighted Procrustes, PSK_GSWEEPS sweeps).
        auto fit_groups = [&](std::vector<M34>& M, const Eigen::VectorXd& c) {
            std::vector<std::vector<std::pair<int, double>>> gw(V);  // (a, W_va)
            std::vector<std::vector<V3>> gz(V);                       // z_va
            for (size_t v = 0; v < V; ++v) {
                for (auto [j, w] : wv[v])
                    for (const Term& t : terms[size_t(j)]) {
                        size_t i = 0;
                        while (i < gw[v].size() && gw[v][i].first != t.a) ++i;
                        if (i == gw[v].size()) gw[v].push_back({t.a, 0}), gz[v].push_back(V3::Zero());
                        gw[v][i].second += w * coef(c, t);
                        gz[v][i] += w * coef(c, t) * xf(t.D, p[v]);
                    }
                for (size_t i = 0; i < gw[v].size(); ++i)
                    if (std::abs(gw[v][i].second) > 1e-9) gz[v][i] /= gw[v][i].second;
            }
            for (size_t f = 0; f < F; ++f)
                for (int sweep = 0; sweep < envi("PSK_GSWEEPS", 4); ++sweep)
                    for (int a = 0; a < k; ++a) {
                        std::vector<V3> xs, ys;
                        std::vector<double> ws;
                        for (size_t v = 0; v < V; ++v) {
                            double Wa = 0;
                            V3 r = X[f * V + v], za = V3::Zero();
                            for (size_t i = 0; i < gw[v].size(); ++i) {
                                if (gw[v][i].first == a) Wa = gw[v][i].second, za = gz[v][i];
                                else r -= gw[v][i].second * xf(M[f * size_t(k) + size_t(gw[v][i].first)], gz[v][i]);
                            }
                            if (std::abs(Wa) < 1e-6) continue;
                            xs.push_back(za), ys.push_back(r / Wa), ws.push_back(Wa * Wa);
                        }
                        if (xs.size() >= 3) M[f * size_t(k) + size_t(a)] = procrustes(xs, ys, ws);
                    }
        };
        const double e_today = error(M0, c0);
        const Eigen::VectorXd cb = solve_blend(M0);
        const double e_blend = error(M0, cb);
        std::vector<M34> Mg = M0;
        fit_groups(Mg, c0);
        const double e_group = error(Mg, c0);
        std::vector<M34> Mb = M0;
        Eigen::VectorXd c = c0;
        std::string both;
        for (int r = 0; r < rounds; ++r) {
            c = solve_blend(Mb);
            fit_groups(Mb, c);
            char buf[32];
            std::snprintf(buf, sizeof buf, "%s%.3g", r ? "/" : "", error(Mb, c));
            both += buf;
        }
        // Dem Bones' model on the shipped motions: each vertex its own
        // least-squares weights over all k streamed matrices at its bind
        // position (no influence limit, no sign or sum constraint, no corrections).
        double e_free = 0;
        size_t n_fit = 0, n_eval = 0;
        for (size_t f = 0; f < F; ++f) n_fit += fit_frame(f), n_eval += eval_frame(f);
        for (size_t v = 0; v < V; ++v) {
            Eigen::MatrixXd A(3 * n_fit, k), Ae(3 * n_eval, k);
            Eigen::VectorXd y(3 * n_fit), ye(3 * n_eval);
            for (size_t f = 0, i = 0, ie = 0; f < F; ++f) {
                for (int a = 0; a < k; ++a) {
                    const V3 q = xf(S[f * size_t(B) + size_t(a)], p[v]);
                    if (fit_frame(f)) A.block<3, 1>(Eigen::Index(3 * i), a) = q;
                    if (eval_frame(f)) Ae.block<3, 1>(Eigen::Index(3 * ie), a) = q;
                }
                if (fit_frame(f)) y.segment<3>(Eigen::Index(3 * i++)) = X[f * V + v];
                if (eval_frame(f)) ye.segment<3>(Eigen::Index(3 * ie++)) = X[f * V + v];
            }
            e_free += (Ae * A.colPivHouseholderQr().solve(y) - ye).squaredNorm();
        }
        e_free = 100 * std::sqrt(e_free / double(V * n_eval)) / diag;
        std::printf("%-3d %-8.3g %-8.3g %-8.3g %-8.3g %-17s (table %.3g; coefficients %.2f..%.2f)\n", k, e_today,
                    e_blend, e_free, e_group, both.c_str(), sk.error[size_t(k - 1)].rms_pct, c.minCoeff(), c.maxCoeff());
        std::fflush(stdout);
    }
    std::printf("(%.0f s)\n", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
}
