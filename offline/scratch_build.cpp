// scratch_build.cpp — build a progressive skin from vertex animation (see
// scratch_build.h and docs/algorithms.md "Build from scratch").
//
// State: per vertex up to 4 (bone, weight) slots, weights >= 0 summing to 1;
// per bone a parent (< its index) and per frame a rigid 3x4 transform M_b(f)
// acting on bind positions; the current reconstruction R[f*V + v] and per
// vertex outstanding squared error E[v] = sum_f |a_vf - R_vf|^2.
#include "scratch_build.h"

#include "collapse.h"

#include <Eigen/Dense>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>

#include <glm/gtc/matrix_transform.hpp>

#include "errors.h"
#include "error_metric.h"

namespace progskin {

namespace {

using V3 = Eigen::Vector3d;
using M3 = Eigen::Matrix3d;
using M34 = Eigen::Matrix<double, 3, 4>;

inline V3 xf(const M34& m, const V3& p) { return m.leftCols<3>() * p + m.col(3); }

M34 identity34() {
    M34 m = M34::Zero();
    m.leftCols<3>().setIdentity();
    return m;
}

// Weighted Procrustes: minimise sum w |s R x + t - y|^2 over rotations R
// (det +1), translation t and (optionally) uniform scale s > 0.
struct Procrustes {
    double W = 0, sxx = 0;
    V3 sx = V3::Zero(), sy = V3::Zero();
    M3 sxy = M3::Zero();
    void add(const V3& x, const V3& y, double w) {
        W += w;
        sx += w * x;
        sy += w * y;
        sxy += w * x * y.transpose();
        sxx += w * x.squaredNorm();
    }
    M34 solve(bool scale) const {
        M34 out = identity34();
        if (!(W > 0)) return out;
        const V3 mx = sx / W, my = sy / W;
        const M3 H = sxy - W * mx * my.transpose();  // sum w (x - mx)(y - my)^T
        const double varx = sxx - W * mx.squaredNorm();
        M3 R = M3::Identity();
        double s = 1.0;
        if (varx > 1e-300 && H.allFinite() && H.norm() > 1e-300) {
            Eigen::JacobiSVD<M3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
            M3 D = M3::Identity();
            if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0) D(2, 2) = -1;
            R = svd.matrixV() * D * svd.matrixU().transpose();
            if (scale) {
                const double tr = (svd.singularValues().asDiagonal() * D).trace();
                s = tr > 0 ? tr / varx : 1.0;
            }
        }
        out.leftCols<3>() = s * R;
        out.col(3) = my - s * R * mx;
        if (!out.allFinite()) return identity34();
        return out;
    }
};

constexpr int kSlots = 4;

struct Bone {
    int parent = -1;
    std::vector<M34> M;  // per frame
    V3 center = V3::Zero();
};

class Builder {
public:
    // A new bone's share alpha of a vertex's parent weight and the error
    // decrease it gives.
    struct Share {
        double alpha = 0, gain = 0;
    };
    // A candidate bone: motion Mk, parent p, shares alpha of the vertices S.
    struct Proposal {
        int p = 0;
        std::vector<M34> Mk;
        std::vector<size_t> S;
        std::vector<Share> sh;
        double gain = 0;
    };
    Builder(const VertexAnimation& an, const ScratchOptions& opt) : opt_(opt) {
        V_ = an.vertex_count;
        F_ = an.frame_count;
        A_.resize(V_ * F_);
        for (size_t i = 0; i < V_ * F_; ++i) A_[i] = V3(an.positions[i].x, an.positions[i].y, an.positions[i].z);
        P_.assign(V_, V3::Zero());
        if (opt.rest_frame >= 0) {
            if (size_t(opt.rest_frame) >= F_)
                throw Error(an.source + ": --rest-frame " + std::to_string(opt.rest_frame) + " out of range (" +
                            std::to_string(F_) + " frames)");
            for (size_t v = 0; v < V_; ++v) P_[v] = A_[size_t(opt.rest_frame) * V_ + v];
        } else {
            for (size_t f = 0; f < F_; ++f)
                for (size_t v = 0; v < V_; ++v) P_[v] += A_[f * V_ + v];
            for (V3& p : P_) p /= double(F_);
        }
        slot_bone_.assign(V_, {});
        slot_w_.assign(V_, {});
        nslot_.assign(V_, 0);
        R_.assign(V_ * F_, V3::Zero());
        E_.assign(V_, 0.0);
    }

    const std::vector<Bone>& bones() const { return bones_; }
    const std::vector<V3>& bind() const { return P_; }

    double total_error() const { return std::accumulate(E_.begin(), E_.end(), 0.0); }

    void fit_root() {
        Bone b;
        b.M.resize(F_);
        for (size_t f = 0; f < F_; ++f) {
            Procrustes pr;
            for (size_t v = 0; v < V_; ++v) pr.add(P_[v], A_[f * V_ + v], 1.0);
            b.M[f] = pr.solve(opt_.similarity);
        }
        for (const V3& p : P_) b.center += p;
        b.center /= double(V_);
        bones_.push_back(std::move(b));
        for (size_t v = 0; v < V_; ++v) {
            nslot_[v] = 1;
            slot_bone_[v] = {0, 0, 0, 0};
            slot_w_[v] = {1.0, 0, 0, 0};
        }
        recompute_all();
    }

    // One bone added top-down; false when no seed gives a useful bone.
    bool add_bone() {
        const double total = total_error();
        if (!(total > 0)) return false;
        size_t seed = 0;
        std::optional<Proposal> c = grown_proposal(total, seed);
        if (!c) return false;
        commit(std::move(*c), seed);
        return true;
    }

    // The region-grown bone from the first of the 6 worst-fitted vertices
    // that gives a useful bone (its seed in `seed`).
    std::optional<Proposal> grown_proposal(double total, size_t& seed) const {
        std::vector<size_t> seeds(V_);
        std::iota(seeds.begin(), seeds.end(), 0);
        const size_t tries = std::min<size_t>(V_, 6);
        std::partial_sort(seeds.begin(), seeds.begin() + tries, seeds.end(),
                          [&](size_t a, size_t b) { return E_[a] > E_[b]; });
        for (size_t t = 0; t < tries; ++t) {
            if (!(E_[seeds[t]] > 1e-12 * total)) break;
            Proposal c = seed_proposal(seeds[t]);
            if (c.gain > 1e-7 * total) {
                seed = seeds[t];
                return c;
            }
        }
        return std::nullopt;
    }

    // One bone added top-down, the best (largest error decrease) of the
    // region-grown bone from the worst vertex and bones starting from the
    // given motions (a full-detail decomposition's bones; the 3 most promising
    // are tried); false when none gives a useful bone.
    bool add_bone_from(const std::vector<std::vector<M34>>& motions) {
        const double total = total_error();
        if (!(total > 0)) return false;
        std::optional<Proposal> best;
        size_t best_seed = 0;
        // Screening: each motion's region (the vertices it predicts better
        // than the skin does by half) and rough gain sum (E_v - e_v) there;
        // the share alternation runs for the 3 best.
        struct Screen {
            double rough = 0;
            size_t m = 0;
        };
        std::vector<Screen> screen;
        for (size_t m = 0; m < motions.size(); ++m) {
            Screen sc{0, m};
            size_t count = 0;
            for (size_t v = 0; v < V_; ++v) {
                const double e = fit_error(v, motions[m]);
                if (e < 0.5 * E_[v]) {
                    sc.rough += E_[v] - e;
                    ++count;
                }
            }
            if (count >= 3) screen.push_back(sc);
        }
        const size_t keep = std::min<size_t>(screen.size(), 3);
        std::partial_sort(screen.begin(), screen.begin() + long(keep), screen.end(),
                          [](const Screen& a, const Screen& b) { return a.rough > b.rough; });
        std::vector<double> eT(V_);
        for (size_t i = 0; i < keep; ++i) {
            const std::vector<M34>& T = motions[screen[i].m];
            std::vector<size_t> region;
            size_t seed = 0;
            double seed_gain = -1;
            for (size_t v = 0; v < V_; ++v) {
                eT[v] = fit_error(v, T);
                if (eT[v] < 0.5 * E_[v]) {
                    region.push_back(v);
                    if (E_[v] - eT[v] > seed_gain) {
                        seed_gain = E_[v] - eT[v];
                        seed = v;
                    }
                }
            }
            Proposal c = propose(T, region, eT);
            if (!best || c.gain > best->gain) {
                best = std::move(c);
                best_seed = seed;
            }
        }
        size_t seed = 0;
        std::optional<Proposal> grown = grown_proposal(total, seed);
        if (grown && (!best || grown->gain > best->gain)) {
            best = std::move(grown);
            best_seed = seed;
        }
        if (!best || !(best->gain > 1e-7 * total)) return false;
        commit(std::move(*best), best_seed);
        return true;
    }

    int bone_count() const { return int(bones_.size()); }

    // Per vertex slots, for the export.
    int nslot(size_t v) const { return nslot_[v]; }
    int slot_bone(size_t v, int i) const { return slot_bone_[v][i]; }
    double slot_w(size_t v, int i) const { return slot_w_[v][i]; }

    // Drops bones >= k: their weight goes to their nearest ancestor < k.
    void truncate(int k) {
        if (k >= bone_count()) return;
        std::vector<int> up(bones_.size());
        for (size_t b = 0; b < bones_.size(); ++b) up[b] = int(b) < k ? int(b) : up[size_t(bones_[b].parent)];
        for (size_t v = 0; v < V_; ++v) {
            std::array<int, kSlots> nb{};
            std::array<double, kSlots> nw{};
            int n = 0;
            for (int i = 0; i < nslot_[v]; ++i) {
                const int b = up[size_t(slot_bone_[v][i])];
                int j = 0;
                while (j < n && nb[j] != b) ++j;
                if (j == n) {
                    nb[n] = b;
                    nw[n++] = 0;
                }
                nw[j] += slot_w_[v][i];
            }
            slot_bone_[v] = nb;
            slot_w_[v] = nw;
            nslot_[v] = n;
        }
        bones_.resize(size_t(k));
        recompute_all();
    }

    // Full-detail decomposition (see decompose() below).
    void decompose(int bones, double target_sq, int iterations, const std::function<void()>& tick);
    void refine_weights_candidates(int candidates);
    // Vertex v's influences := bones cand[i] with weights w[i], i in keep (w[i] > 0).
    void set_slots(size_t v, const std::vector<int>& keep, const Eigen::VectorXd& w, const std::vector<int>& cand) {
        nslot_[v] = 0;
        for (int i : keep) {
            if (!(w[i] > 0)) continue;
            slot_bone_[v][nslot_[v]] = cand[size_t(i)];
            slot_w_[v][nslot_[v]] = w[i];
            ++nslot_[v];
        }
    }
    void refine_bind();
    void update_centers();
    // Renumbers bones: new bone i is old bone order[i]; parents are reset.
    void permute(const std::vector<int>& order);
    void set_parent(int b, int p) { bones_[size_t(b)].parent = p; }
    double fit_error(size_t v, const std::vector<M34>& M) const {
        double e = 0;
        for (size_t f = 0; f < F_; ++f) e += (xf(M[f], P_[v]) - A_[f * V_ + v]).squaredNorm();
        return e;
    }

    // Global refinement (see refine() below).
    void refine(int sweeps, const std::function<void()>& tick);
    void refine_transforms(int first_bone);
    void refine_weights_full();
    // Multi-level weight and bind update (see below).
    void multilevel_weights(const std::vector<int>& levels, const std::vector<double>& lam,
                            const std::vector<std::vector<int>>& up, const std::vector<std::vector<Eigen::Matrix4d>>& K);
    // Multi-level refit of transforms, corrections, weights (see below).
    void multilevel_refit(std::vector<M34>& corrections, int sweeps, bool fit_corrections, bool fit_weights,
                          const std::vector<int>& extra_levels = {});

private:
    // Current reconstruction and errors from scratch.
    void recompute_all() {
        for (size_t v = 0; v < V_; ++v) recompute_vertex(v);
    }
    void recompute_vertex(size_t v) {
        double e = 0;
        for (size_t f = 0; f < F_; ++f) {
            V3 r = V3::Zero();
            for (int i = 0; i < nslot_[v]; ++i) r += slot_w_[v][i] * xf(bones_[size_t(slot_bone_[v][i])].M[f], P_[v]);
            R_[f * V_ + v] = r;
            e += (A_[f * V_ + v] - r).squaredNorm();
        }
        E_[v] = e;
    }
    double weight_on(size_t v, int b) const {
        for (int i = 0; i < nslot_[v]; ++i)
            if (slot_bone_[v][i] == b) return slot_w_[v][i];
        return 0.0;
    }

    // Rigid per-frame fit of a vertex set to the input.
    std::vector<M34> fit_set(const std::vector<size_t>& set) const {
        std::vector<M34> T(F_);
        for (size_t f = 0; f < F_; ++f) {
            Procrustes pr;
            for (size_t v : set) pr.add(P_[v], A_[f * V_ + v], 1.0);
            T[f] = pr.solve(opt_.similarity);
        }
        return T;
    }

    // Least-squares share alpha of vertex v's parent weight w_p moved to a bone
    // moving with Mk, and the error decrease it gives.
    Share solve_share(size_t v, int p, double wp, const std::vector<M34>& Mk) const {
        const std::vector<M34>& Mp = bones_[size_t(p)].M;
        double num = 0, den = 0;
        for (size_t f = 0; f < F_; ++f) {
            const V3 d = wp * (xf(Mk[f], P_[v]) - xf(Mp[f], P_[v]));
            const V3 e = A_[f * V_ + v] - R_[f * V_ + v];
            num += e.dot(d);
            den += d.squaredNorm();
        }
        Share s;
        if (!(den > 0)) return s;
        double a = std::clamp(num / den, 0.0, 1.0);
        if (nslot_[v] >= kSlots && a < 1.0) a = (den - 2 * num < 0) ? 1.0 : 0.0;  // no free slot: all or nothing
        s.alpha = a;
        s.gain = 2 * a * num - a * a * den;
        return s;
    }

    // A bone grown from a seed vertex (see grown_proposal).
    Proposal seed_proposal(size_t seed) const {
        // Initial region: the seed's nearest vertices in the bind pose.
        const size_t n0 = std::min(V_, std::clamp<size_t>(V_ / size_t(4 * std::max(1, opt_.max_bones)), 8, 200));
        std::vector<size_t> idx(V_);
        std::iota(idx.begin(), idx.end(), 0);
        std::nth_element(idx.begin(), idx.begin() + (n0 - 1), idx.end(), [&](size_t a, size_t b) {
            return (P_[a] - P_[seed]).squaredNorm() < (P_[b] - P_[seed]).squaredNorm();
        });
        std::vector<size_t> region(idx.begin(), idx.begin() + n0);
        std::vector<M34> T;
        std::vector<double> eT(V_);
        // Grow by motion similarity: the vertices the region's rigid motion
        // predicts better than the current skin does.
        for (int it = 0; it < 4; ++it) {
            T = fit_set(region);
            std::vector<size_t> next;
            for (size_t v = 0; v < V_; ++v) {
                double e = 0;
                for (size_t f = 0; f < F_; ++f) e += (xf(T[f], P_[v]) - A_[f * V_ + v]).squaredNorm();
                eT[v] = e;
                if (e < 0.5 * E_[v]) next.push_back(v);
            }
            if (std::find(next.begin(), next.end(), seed) == next.end()) next.push_back(seed);
            if (next.size() < 3 || next == region) break;
            region = std::move(next);
        }
        return propose(std::move(T), region, eT);
    }

    // The share/transform alternation for a new bone starting from motion T,
    // with the region (vertices T predicts well, eT their errors under T)
    // choosing the parent.
    Proposal propose(std::vector<M34> T, const std::vector<size_t>& region, const std::vector<double>& eT) const {
        // Parent: the bone the region's improvement draws its weight from.
        std::vector<double> score(bones_.size(), 0.0);
        for (size_t v : region)
            for (int i = 0; i < nslot_[v]; ++i)
                score[size_t(slot_bone_[v][i])] += slot_w_[v][i] * std::max(0.0, E_[v] - eT[v]);
        const int p = int(std::max_element(score.begin(), score.end()) - score.begin());
        // Candidates: every vertex holding weight on the parent (restricting
        // them to the region gives better full-detail skins with many bones
        // but worse small k; see docs/algorithms.md).
        std::vector<size_t> S;
        for (size_t v = 0; v < V_; ++v)
            if (weight_on(v, p) > 0) S.push_back(v);
        // Alternate shares and the bone's transform.
        std::vector<M34> Mk = T;
        std::vector<Share> sh(S.size());
        const std::vector<M34>& Mp = bones_[size_t(p)].M;
        for (int it = 0; it < 6; ++it) {
            for (size_t i = 0; i < S.size(); ++i) sh[i] = solve_share(S[i], p, weight_on(S[i], p), Mk);
            for (size_t f = 0; f < F_; ++f) {
                Procrustes pr;
                for (size_t i = 0; i < S.size(); ++i) {
                    const size_t v = S[i];
                    const double c = sh[i].alpha * weight_on(v, p);
                    if (c < 1e-6) continue;
                    const V3 q = A_[f * V_ + v] - R_[f * V_ + v] + c * xf(Mp[f], P_[v]);
                    pr.add(P_[v], q / c, c * c);
                }
                if (pr.W > 0) Mk[f] = pr.solve(opt_.similarity);
            }
        }
        double gain = 0;
        for (size_t i = 0; i < S.size(); ++i) {
            sh[i] = solve_share(S[i], p, weight_on(S[i], p), Mk);
            gain += sh[i].gain;
        }
        Proposal out;
        out.p = p;
        out.Mk = std::move(Mk);
        out.S = std::move(S);
        out.sh = std::move(sh);
        out.gain = gain;
        return out;
    }

    void commit(Proposal&& c, size_t seed) {
        const int p = c.p;
        std::vector<M34>& Mk = c.Mk;
        const std::vector<size_t>& S = c.S;
        const std::vector<Share>& sh = c.sh;
        const int k = int(bones_.size());
        Bone b;
        b.parent = p;
        b.M = std::move(Mk);
        double csum = 0;
        for (size_t i = 0; i < S.size(); ++i) {
            const size_t v = S[i];
            const double a = sh[i].alpha;
            if (a <= 0) continue;
            int ip = 0;
            while (slot_bone_[v][ip] != p) ++ip;
            const double c = a * slot_w_[v][ip];
            b.center += c * P_[v];
            csum += c;
            if (a >= 1.0) {
                slot_bone_[v][ip] = k;
            } else {
                slot_w_[v][ip] -= c;
                slot_bone_[v][nslot_[v]] = k;
                slot_w_[v][nslot_[v]] = c;
                ++nslot_[v];
            }
        }
        b.center = csum > 0 ? V3(b.center / csum) : P_[seed];
        bones_.push_back(std::move(b));
        for (size_t i = 0; i < S.size(); ++i)
            if (sh[i].alpha > 0) recompute_vertex(S[i]);
    }

    ScratchOptions opt_;
    size_t V_ = 0, F_ = 0;
    std::vector<V3> A_, P_, R_;
    std::vector<double> E_;
    std::vector<Bone> bones_;
    std::vector<std::array<int, kSlots>> slot_bone_;
    std::vector<std::array<double, kSlots>> slot_w_;
    std::vector<int> nslot_;
};

// SSDR-style transform update of every bone with the weights fixed
// (Gauss-Seidel: each bone's weighted Procrustes against the residual of the
// others), lowering the full-detail error.
void Builder::refine_transforms(int first_bone) {
    std::vector<size_t> vs;
    std::vector<double> ws;
    for (int b = first_bone; b < bone_count(); ++b) {
        vs.clear();
        ws.clear();
        for (size_t v = 0; v < V_; ++v) {
            const double w = weight_on(v, b);
            if (w > 1e-6) {
                vs.push_back(v);
                ws.push_back(w);
            }
        }
        if (vs.empty()) continue;
        std::vector<M34>& M = bones_[size_t(b)].M;
        for (size_t f = 0; f < F_; ++f) {
            Procrustes pr;
            for (size_t i = 0; i < vs.size(); ++i) {
                const size_t v = vs[i];
                const double w = ws[i];
                const V3 q = A_[f * V_ + v] - R_[f * V_ + v] + w * xf(M[f], P_[v]);
                pr.add(P_[v], q / w, w * w);
            }
            const M34 Mn = pr.solve(opt_.similarity);
            for (size_t i = 0; i < vs.size(); ++i) {
                const size_t v = vs[i];
                R_[f * V_ + v] += ws[i] * (xf(Mn, P_[v]) - xf(M[f], P_[v]));
            }
            M[f] = Mn;
        }
        for (size_t v : vs) {
            double e = 0;
            for (size_t f = 0; f < F_; ++f) e += (A_[f * V_ + v] - R_[f * V_ + v]).squaredNorm();
            E_[v] = e;
        }
    }
}

// Non-negative least squares on the normal equations (Lawson-Hanson):
// minimise w'Gw - 2h'w, w >= 0, over the index set `allowed`.
Eigen::VectorXd nnls(const Eigen::MatrixXd& G, const Eigen::VectorXd& h, const std::vector<int>& allowed) {
    const int n = int(G.rows());
    Eigen::VectorXd w = Eigen::VectorXd::Zero(n);
    std::vector<char> inP(size_t(n), 0), ok(size_t(n), 0);
    for (int i : allowed) ok[size_t(i)] = 1;
    const double tol = 1e-12 * std::max(1.0, G.diagonal().maxCoeff());
    for (int outer = 0; outer < 3 * n; ++outer) {
        const Eigen::VectorXd grad = h - G * w;
        int j = -1;
        for (int i = 0; i < n; ++i)
            if (ok[size_t(i)] && !inP[size_t(i)] && grad[i] > tol && (j < 0 || grad[i] > grad[j])) j = i;
        if (j < 0) break;
        inP[size_t(j)] = 1;
        for (int inner = 0; inner < 3 * n; ++inner) {
            std::vector<int> P;
            for (int i = 0; i < n; ++i)
                if (inP[size_t(i)]) P.push_back(i);
            Eigen::MatrixXd Gp(P.size(), P.size());
            Eigen::VectorXd hp(P.size());
            for (size_t a = 0; a < P.size(); ++a) {
                hp[Eigen::Index(a)] = h[P[a]];
                for (size_t b = 0; b < P.size(); ++b) Gp(Eigen::Index(a), Eigen::Index(b)) = G(P[a], P[b]);
            }
            const Eigen::VectorXd z = Gp.ldlt().solve(hp);
            bool pos = z.allFinite();
            for (Eigen::Index a = 0; a < z.size() && pos; ++a) pos = z[a] > 0;
            if (pos) {
                for (size_t a = 0; a < P.size(); ++a) w[P[a]] = z[Eigen::Index(a)];
                break;
            }
            double alpha = 1.0;
            for (size_t a = 0; a < P.size(); ++a) {
                const double za = z.allFinite() ? z[Eigen::Index(a)] : 0.0;
                if (za <= 0) alpha = std::min(alpha, w[P[a]] / std::max(1e-300, w[P[a]] - za));
            }
            for (size_t a = 0; a < P.size(); ++a) {
                const double za = z.allFinite() ? z[Eigen::Index(a)] : 0.0;
                w[P[a]] += alpha * (za - w[P[a]]);
                if (w[P[a]] <= 1e-14) {
                    w[P[a]] = 0;
                    inP[size_t(P[a])] = 0;
                }
            }
        }
    }
    return w;
}

// One vertex's weights: minimise w'Gw - 2h'w over w >= 0 with sum(w) = 1
// enforced by a stiff penalty row (lambda = 1e4 x the mean diagonal, added
// to every entry of G and h), at most kSlots of them non-zero (the largest
// kept and re-solved). Returns false when no positive, finite solution is
// left; else w normalised to sum 1 and keep, its non-zero indices by
// decreasing weight.
bool sparse_weights(const Eigen::MatrixXd& G, const Eigen::VectorXd& h, Eigen::VectorXd& w, std::vector<int>& keep) {
    const int n = int(G.rows());
    const double lambda = 1e4 * std::max(1e-300, G.trace() / n);
    const Eigen::MatrixXd Gp = G.array() + lambda;
    const Eigen::VectorXd hp = h.array() + lambda;
    std::vector<int> all(static_cast<size_t>(n));
    std::iota(all.begin(), all.end(), 0);
    w = nnls(Gp, hp, all);
    std::vector<int> ord(all);
    std::sort(ord.begin(), ord.end(), [&](int a, int b) { return w[a] > w[b]; });
    keep.clear();
    for (int i = 0; i < n && int(keep.size()) < kSlots; ++i)
        if (w[ord[size_t(i)]] > 1e-9) keep.push_back(ord[size_t(i)]);
    if (keep.empty()) return false;
    if (std::count_if(w.data(), w.data() + n, [](double x) { return x > 1e-9; }) > kSlots) w = nnls(Gp, hp, keep);
    const double sum = w.sum();
    if (!(sum > 0) || !w.allFinite()) return false;
    w /= sum;
    return true;
}

void Builder::refine_weights_full() { refine_weights_candidates(bone_count()); }

// SSDR weight update: per vertex, non-negative weights summing to 1 (a stiff
// penalty row) over the `candidates` bones that alone predict its trajectory
// best plus its current ones, at most 4 kept (the largest, then re-solved);
// accepted only where the vertex's error decreases.
void Builder::refine_weights_candidates(int candidates) {
    const int B = bone_count();
    if (B < 2) return;
    std::vector<double> eb(static_cast<size_t>(B));
    std::vector<int> cand, idx(static_cast<size_t>(B));
    std::vector<V3> y;
    for (size_t v = 0; v < V_; ++v) {
        if (candidates < B) {
            for (int b = 0; b < B; ++b) eb[size_t(b)] = fit_error(v, bones_[size_t(b)].M);
            std::iota(idx.begin(), idx.end(), 0);
            std::partial_sort(idx.begin(), idx.begin() + candidates, idx.end(),
                              [&](int a, int b) { return eb[size_t(a)] < eb[size_t(b)]; });
            cand.assign(idx.begin(), idx.begin() + candidates);
            for (int i = 0; i < nslot_[v]; ++i)
                if (std::find(cand.begin(), cand.end(), slot_bone_[v][i]) == cand.end()) cand.push_back(slot_bone_[v][i]);
        } else {
            cand.resize(size_t(B));
            std::iota(cand.begin(), cand.end(), 0);
        }
        const int n = int(cand.size());
        Eigen::MatrixXd G = Eigen::MatrixXd::Zero(n, n);
        Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
        y.resize(size_t(n));
        for (size_t f = 0; f < F_; ++f) {
            for (int i = 0; i < n; ++i) y[size_t(i)] = xf(bones_[size_t(cand[size_t(i)])].M[f], P_[v]);
            const V3& a = A_[f * V_ + v];
            for (int i = 0; i < n; ++i) {
                h[i] += y[size_t(i)].dot(a);
                for (int j = i; j < n; ++j) G(i, j) += y[size_t(i)].dot(y[size_t(j)]);
            }
        }
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < i; ++j) G(i, j) = G(j, i);
        Eigen::VectorXd w;
        std::vector<int> keep;
        if (!sparse_weights(G, h, w, keep)) continue;
        double e = 0;
        for (size_t f = 0; f < F_; ++f) {
            V3 r = V3::Zero();
            for (int i : keep) r += w[i] * xf(bones_[size_t(cand[size_t(i)])].M[f], P_[v]);
            e += (A_[f * V_ + v] - r).squaredNorm();
        }
        if (!(e < E_[v])) continue;
        set_slots(v, keep, w, cand);
        recompute_vertex(v);
    }
}

// Full-detail decomposition with N bones (SSDR-style, no mesh connectivity):
// (1) hard clustering of the vertices by rigid motion: starting from one
// cluster (the root fit), repeatedly split the cluster whose split lowers the
// error most (2-means between the cluster's rigid motion and a new one seeded
// at the bind-pose neighbours of its worst-fitted vertex), then reassign every
// vertex to the bone whose per-frame rigid transform predicts its trajectory
// best and refit (k-means in trajectory space); (2) alternate Gauss-Seidel
// weighted Procrustes per bone, per-vertex NNLS weights (<= 4 influences, sum
// 1) and per-vertex least-squares bind positions until the error stalls.
// Splitting stops early once the squared error sum <= target_sq.
void Builder::decompose(int N, double target_sq, int iters, const std::function<void()>& tick) {
    std::vector<int> lab(V_, 0);
    std::vector<double> err(V_);
    for (size_t v = 0; v < V_; ++v) err[v] = fit_error(v, bones_[0].M);
    auto total = [&]() { return std::accumulate(err.begin(), err.end(), 0.0); };
    std::vector<std::vector<size_t>> mem;
    auto members = [&]() {
        mem.assign(bones_.size(), {});
        for (size_t v = 0; v < V_; ++v) mem[size_t(lab[v])].push_back(v);
    };
    // k-means rounds: assign, refit, drop empty bones.
    auto relabel = [&](int rounds) {
        for (int r = 0; r < rounds; ++r) {
            bool changed = false;
            for (size_t v = 0; v < V_; ++v) {
                int best = lab[v];
                double be = fit_error(v, bones_[size_t(best)].M);
                for (int b = 0; b < int(bones_.size()); ++b) {
                    if (b == lab[v]) continue;
                    const double e = fit_error(v, bones_[size_t(b)].M);
                    if (e < be) {
                        be = e;
                        best = b;
                    }
                }
                changed |= best != lab[v];
                lab[v] = best;
                err[v] = be;
            }
            members();
            std::vector<int> keep_map(bones_.size(), -1);
            std::vector<Bone> kept;
            for (size_t b = 0; b < bones_.size(); ++b) {
                if (mem[b].empty()) continue;
                keep_map[b] = int(kept.size());
                kept.push_back(std::move(bones_[b]));
                if (mem[b].size() >= 3) kept.back().M = fit_set(mem[b]);
            }
            bones_ = std::move(kept);
            for (size_t v = 0; v < V_; ++v) {
                lab[v] = keep_map[size_t(lab[v])];
                err[v] = fit_error(v, bones_[size_t(lab[v])].M);
            }
            if (!changed) break;
        }
    };
    for (int splits = 0; int(bones_.size()) < N && splits < 2 * N + 8; ++splits) {  // relabel may drop bones
        const double tot = total();
        if (!(tot > 0) || (target_sq > 0 && tot <= target_sq)) break;
        members();
        std::vector<int> cl(bones_.size());
        std::iota(cl.begin(), cl.end(), 0);
        std::vector<double> cerr(bones_.size(), 0.0);
        for (size_t v = 0; v < V_; ++v) cerr[size_t(lab[v])] += err[v];
        std::sort(cl.begin(), cl.end(), [&](int a, int b) { return cerr[size_t(a)] > cerr[size_t(b)]; });
        double best_gain = 0;
        int best_c = -1;
        std::vector<M34> best_new, best_old;
        std::vector<size_t> best_moved;
        for (size_t ci = 0; ci < std::min<size_t>(cl.size(), 3); ++ci) {
            const int c = cl[ci];
            std::vector<size_t> m = mem[size_t(c)];
            if (m.size() < 2) continue;
            const size_t seed = *std::max_element(m.begin(), m.end(), [&](size_t a, size_t b) { return err[a] < err[b]; });
            if (!(err[seed] > 0)) continue;
            const size_t n0 = std::min(m.size(), std::clamp<size_t>(m.size() / 8, 4, 40));
            std::nth_element(m.begin(), m.begin() + long(n0 - 1), m.end(), [&](size_t a, size_t b) {
                return (P_[a] - P_[seed]).squaredNorm() < (P_[b] - P_[seed]).squaredNorm();
            });
            std::vector<M34> Tn = fit_set(std::vector<size_t>(m.begin(), m.begin() + long(n0)));
            std::vector<M34> To = bones_[size_t(c)].M;
            std::vector<size_t> sn, so;
            double gain = 0;
            for (int it = 0; it < 8; ++it) {
                sn.clear();
                so.clear();
                double after = 0, before = 0;
                for (size_t v : m) {
                    const double en = fit_error(v, Tn), eo = fit_error(v, To);
                    (en < eo ? sn : so).push_back(v);
                    after += std::min(en, eo);
                    before += err[v];
                }
                gain = before - after;
                if (sn.empty() || so.empty() || it == 7) break;
                if (sn.size() >= 3) Tn = fit_set(sn);
                if (so.size() >= 3) To = fit_set(so);
            }
            if (!sn.empty() && gain > best_gain) {
                best_gain = gain;
                best_c = c;
                best_new = Tn;
                best_old = To;
                best_moved = sn;
            }
        }
        if (best_c < 0 || !(best_gain > 1e-12 * tot)) break;
        const int k = int(bones_.size());
        Bone nb;
        nb.M = std::move(best_new);
        bones_.push_back(std::move(nb));
        bones_[size_t(best_c)].M = std::move(best_old);
        for (size_t v : best_moved) lab[v] = k;
        for (size_t v : mem[size_t(best_c)]) err[v] = fit_error(v, bones_[size_t(lab[v])].M);
        if (bones_.size() <= 64 || (bones_.size() & (bones_.size() - 1)) == 0) relabel(2);
        tick();
    }
    relabel(4);
    // Trimmed refit: each bone's motion from the better-fitted half of its
    // members (vertices blended between parts spoil the plain fit), so that
    // the alternation starts next to the rigid parts' own motions.
    members();
    for (size_t b = 0; b < bones_.size(); ++b) {
        std::vector<size_t> m = mem[b];
        if (m.size() < 8) continue;
        std::nth_element(m.begin(), m.begin() + long(m.size() / 2), m.end(),
                         [&](size_t x, size_t y) { return err[x] < err[y]; });
        m.resize(m.size() / 2 + 1);
        bones_[b].M = fit_set(m);
    }
    // Hard weights, then alternation.
    for (size_t v = 0; v < V_; ++v) {
        nslot_[v] = 1;
        slot_bone_[v] = {lab[v], 0, 0, 0};
        slot_w_[v] = {1.0, 0, 0, 0};
    }
    for (Bone& b : bones_) b.parent = -1;
    recompute_all();
    for (int it = 0; it < iters; ++it) {
        const double before = total_error();
        refine_weights_candidates(8);
        refine_transforms(0);
        if (opt_.update_bind) refine_bind();
        tick();
        if (!(total_error() < before * (1 - 1e-6))) break;
    }
    update_centers();
}

// Per vertex: the bind position minimising its error with weights and
// transforms fixed (3x3 least squares), kept when it lowers the error.
void Builder::refine_bind() {
    for (size_t v = 0; v < V_; ++v) {
        M3 H = M3::Zero();
        V3 g = V3::Zero();
        for (size_t f = 0; f < F_; ++f) {
            M3 Af = M3::Zero();
            V3 cf = V3::Zero();
            for (int i = 0; i < nslot_[v]; ++i) {
                const M34& M = bones_[size_t(slot_bone_[v][i])].M[f];
                Af += slot_w_[v][i] * M.leftCols<3>();
                cf += slot_w_[v][i] * M.col(3);
            }
            H += Af.transpose() * Af;
            g += Af.transpose() * (A_[f * V_ + v] - cf);
        }
        const V3 p = H.ldlt().solve(g);
        if (!p.allFinite()) continue;
        const V3 old = P_[v];
        const double eold = E_[v];
        P_[v] = p;
        recompute_vertex(v);
        if (!(E_[v] < eold)) {
            P_[v] = old;
            recompute_vertex(v);
        }
    }
}

void Builder::update_centers() {
    std::vector<double> ws(bones_.size(), 0.0);
    std::vector<V3> cs(bones_.size(), V3::Zero());
    for (size_t v = 0; v < V_; ++v)
        for (int i = 0; i < nslot_[v]; ++i) {
            ws[size_t(slot_bone_[v][i])] += slot_w_[v][i];
            cs[size_t(slot_bone_[v][i])] += slot_w_[v][i] * P_[v];
        }
    for (size_t b = 0; b < bones_.size(); ++b)
        if (ws[b] > 0) bones_[b].center = cs[b] / ws[b];
}

void Builder::permute(const std::vector<int>& order) {
    std::vector<int> inv(bones_.size(), -1);
    std::vector<Bone> nb(order.size());
    for (size_t i = 0; i < order.size(); ++i) {
        nb[i] = bones_[size_t(order[i])];
        nb[i].parent = -1;
        inv[size_t(order[i])] = int(i);
    }
    bones_ = std::move(nb);
    for (size_t v = 0; v < V_; ++v)
        for (int i = 0; i < nslot_[v]; ++i) slot_bone_[v][i] = inv[size_t(slot_bone_[v][i])];
}

// Multi-level refit of the per-frame transforms of a progressive skin (parents
// set, corrections C fixed, weights fixed). Bone j's transform is used at every
// level L > j (as itself and, through copy-down with corrections, by the
// inactive bones that hang from it), never below. At level L vertex v is
// reconstructed as sum over its owners o of M_o(f) u_{v,o,L}, u the homogeneous
// sum of w_b K_b [p_v; 1] over the bones b that o stands in for (K_b the
// composed corrections). The objective is sum over a set of levels of
// lambda_L * E_L (E_L the squared error sum at level L, lambda_L = 1 / E_L at
// the start: relative errors), minimised by Gauss-Seidel over bones: each
// bone's per-frame weighted Procrustes against the other owners' residual at
// all the levels where it is active (exact minimiser of its sub-problem, so
// the objective never rises). The levels: 2, 3, 4, 6, 8, 12, 16, 24, 32, ...
// below B, B, and extra_levels (those where an earlier refit's table rose).
// With fit_weights each sweep ends with multilevel_weights (weights and bind
// positions for the same objective). Memory: one reconstruction per level,
// O(V*F).
void Builder::multilevel_refit(std::vector<M34>& C, int sweeps, bool fit_corrections, bool fit_weights,
                               const std::vector<int>& extra_levels) {
    const int B = bone_count();
    if (B < 2 || sweeps <= 0) return;
    std::vector<int> levels;
    for (int L : {2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128})
        if (L < B) levels.push_back(L);
    for (int L : extra_levels)
        if (L >= 2 && L < B && std::find(levels.begin(), levels.end(), L) == levels.end()) levels.push_back(L);
    std::sort(levels.begin(), levels.end());
    levels.push_back(B);
    const size_t NL = levels.size();
    using V4 = Eigen::Vector4d;
    using M4 = Eigen::Matrix4d;
    auto hom = [](const M34& c) {
        M4 m = M4::Identity();
        m.topRows<3>() = c;
        return m;
    };
    struct Item {
        uint32_t v;
        V4 u;
    };
    std::vector<std::vector<Item>> items(NL * size_t(B));  // [level][owner]
    std::vector<std::vector<int>> up(NL, std::vector<int>(static_cast<size_t>(B)));
    std::vector<std::vector<M4>> K(NL, std::vector<M4>(static_cast<size_t>(B), M4::Identity()));
    auto build_items = [&]() {
        for (auto& it : items) it.clear();
        for (size_t li = 0; li < NL; ++li) {
            const int L = levels[li];
            for (int b = 0; b < B; ++b) {
                K[li][size_t(b)].setIdentity();
                if (b < L) {
                    up[li][size_t(b)] = b;
                    continue;
                }
                const int p = bones_[size_t(b)].parent;
                up[li][size_t(b)] = up[li][size_t(p)];
                K[li][size_t(b)] = K[li][size_t(p)] * hom(C[size_t(b)]);
            }
            for (size_t v = 0; v < V_; ++v) {
                std::array<int, kSlots> ob{};
                std::array<V4, kSlots> ou{};
                int n = 0;
                const V4 ph(P_[v].x(), P_[v].y(), P_[v].z(), 1.0);
                for (int i = 0; i < nslot_[v]; ++i) {
                    const int b = slot_bone_[v][i];
                    const int o = up[li][size_t(b)];
                    int j = 0;
                    while (j < n && ob[j] != o) ++j;
                    if (j == n) {
                        ob[n] = o;
                        ou[n++] = V4::Zero();
                    }
                    ou[j] += slot_w_[v][i] * (K[li][size_t(b)] * ph);
                }
                for (int j = 0; j < n; ++j)
                    if (std::abs(ou[j][3]) > 1e-8) items[li * size_t(B) + size_t(ob[j])].push_back({uint32_t(v), ou[j]});
            }
        }
    };
    auto apply = [](const M34& M, const V4& u) -> V3 { return M.leftCols<3>() * u.head<3>() + M.col(3) * u[3]; };
    std::vector<V3> R(NL * V_ * F_, V3::Zero());
    std::vector<double> lam(NL, 1.0);
    auto build_recon = [&](bool set_lambda) {
        std::fill(R.begin(), R.end(), V3::Zero());
        for (size_t li = 0; li < NL; ++li) {
            V3* Rl = &R[li * V_ * F_];
            for (int o = 0; o < B; ++o)
                for (const Item& it : items[li * size_t(B) + size_t(o)])
                    for (size_t f = 0; f < F_; ++f) Rl[f * V_ + it.v] += apply(bones_[size_t(o)].M[f], it.u);
            if (!set_lambda) continue;
            double e = 0;
            for (size_t i = 0; i < V_ * F_; ++i) e += (A_[i] - Rl[i]).squaredNorm();
            lam[li] = 1.0 / std::max(e, 1e-300);
        }
    };
    // Children lists for the subtree test of the correction update.
    std::vector<std::vector<int>> kids(static_cast<size_t>(B));
    for (int b = 1; b < B; ++b) kids[size_t(bones_[size_t(b)].parent)].push_back(b);
    for (int s = 0; s < sweeps; ++s) {
        build_items();
        build_recon(s == 0);
        // Transforms: per bone, per frame, weighted Procrustes over the levels where it is active.
        for (int j = 0; j < B; ++j) {
            std::vector<M34>& M = bones_[size_t(j)].M;
            for (size_t f = 0; f < F_; ++f) {
                Procrustes pr;
                for (size_t li = 0; li < NL; ++li) {
                    if (levels[li] <= j) continue;
                    const V3* Rl = &R[li * V_ * F_ + f * V_];
                    for (const Item& it : items[li * size_t(B) + size_t(j)]) {
                        const double w = it.u[3];
                        if (w < 1e-8) continue;
                        const V3 q = A_[f * V_ + it.v] - Rl[it.v] + apply(M[f], it.u);
                        pr.add(V3(it.u.head<3>() / w), q / w, lam[li] * w * w);
                    }
                }
                if (!(pr.W > 0)) continue;
                const M34 Mn = pr.solve(opt_.similarity);
                for (size_t li = 0; li < NL; ++li) {
                    if (levels[li] <= j) continue;
                    V3* Rl = &R[li * V_ * F_ + f * V_];
                    for (const Item& it : items[li * size_t(B) + size_t(j)])
                        Rl[it.v] += apply(Mn, it.u) - apply(M[f], it.u);
                }
                M[f] = Mn;
            }
        }
        if (fit_corrections) {
            // Corrections: bone b's C_b (affine, 12 unknowns) acts at every level
            // L <= b as G_L(f) C_b y_v, G_L(f) = M_o(f) K_L[parent(b)] (o the owner
            // at level L), y_v = sum over v's slot bones b' in b's subtree of
            // w K_{b'<-b} [p_v; 1] (corrections below b). Linear least squares.
            std::vector<M4> Kb(static_cast<size_t>(B));  // corrections below the current b
            std::vector<char> in_sub(static_cast<size_t>(B));
            for (int b = 1; b < B; ++b) {
                std::fill(in_sub.begin(), in_sub.end(), 0);
                std::vector<int> stack{b};
                Kb[size_t(b)].setIdentity();
                while (!stack.empty()) {
                    const int x = stack.back();
                    stack.pop_back();
                    in_sub[size_t(x)] = 1;
                    for (int c : kids[size_t(x)]) {
                        Kb[size_t(c)] = Kb[size_t(x)] * hom(C[size_t(c)]);
                        stack.push_back(c);
                    }
                }
                std::vector<uint32_t> vs;
                std::vector<V4> ys;
                for (size_t v = 0; v < V_; ++v) {
                    V4 y = V4::Zero();
                    bool any = false;
                    const V4 ph(P_[v].x(), P_[v].y(), P_[v].z(), 1.0);
                    for (int i = 0; i < nslot_[v]; ++i) {
                        const int bb = slot_bone_[v][i];
                        if (!in_sub[size_t(bb)]) continue;
                        y += slot_w_[v][i] * (Kb[size_t(bb)] * ph);
                        any = true;
                    }
                    if (any) {
                        vs.push_back(uint32_t(v));
                        ys.push_back(y);
                    }
                }
                if (vs.empty()) continue;
                Eigen::Matrix4d Y = Eigen::Matrix4d::Zero();
                for (const V4& y : ys) Y += y * y.transpose();
                Eigen::Matrix<double, 12, 12> N = Eigen::Matrix<double, 12, 12>::Zero();
                Eigen::Matrix<double, 3, 4> Rm = Eigen::Matrix<double, 3, 4>::Zero();
                const int p = bones_[size_t(b)].parent;
                std::vector<size_t> lis;
                for (size_t li = 0; li < NL; ++li) {
                    if (levels[li] > b) continue;
                    lis.push_back(li);
                    const int o = up[li][size_t(p)];
                    const M4& Kp = K[li][size_t(p)];
                    M3 Q = M3::Zero();
                    const V3* Rl = &R[li * V_ * F_];
                    for (size_t f = 0; f < F_; ++f) {
                        const M34 G = bones_[size_t(o)].M[f] * Kp;
                        const M3 Af = G.leftCols<3>();
                        const V3 tf = G.col(3);
                        Q += Af.transpose() * Af;
                        Eigen::Matrix<double, 3, 4> Pf = Eigen::Matrix<double, 3, 4>::Zero();
                        for (size_t i = 0; i < vs.size(); ++i) {
                            const size_t v = vs[i];
                            const V4& y = ys[i];
                            const V3 cur = Af * (C[size_t(b)] * y) + tf * y[3];
                            const V3 T = A_[f * V_ + v] - Rl[f * V_ + v] + cur - tf * y[3];
                            Pf += T * y.transpose();
                        }
                        Rm += lam[li] * Af.transpose() * Pf;
                    }
                    for (int i = 0; i < 4; ++i)
                        for (int j = 0; j < 4; ++j) N.block<3, 3>(3 * i, 3 * j) += lam[li] * Y(i, j) * Q;
                }
                if (lis.empty()) continue;
                const double ridge = 1e-9 * std::max(N.trace() / 12.0, 1e-300);
                Eigen::Matrix<double, 12, 1> rhs;
                for (int col = 0; col < 4; ++col)
                    for (int row = 0; row < 3; ++row) rhs[3 * col + row] = Rm(row, col) + ridge * C[size_t(b)](row, col);
                N.diagonal().array() += ridge;
                const Eigen::Matrix<double, 12, 1> x = N.ldlt().solve(rhs);
                if (!x.allFinite()) continue;
                M34 Cn;
                for (int col = 0; col < 4; ++col)
                    for (int row = 0; row < 3; ++row) Cn(row, col) = x[3 * col + row];
                // Update the reconstructions of the levels where b stands in, and
                // the composed corrections of b's subtree at those levels.
                const M34 dC = Cn - C[size_t(b)];
                for (size_t li : lis) {
                    const int o = up[li][size_t(p)];
                    const M4& Kp = K[li][size_t(p)];
                    V3* Rl = &R[li * V_ * F_];
                    for (size_t f = 0; f < F_; ++f) {
                        const M3 Af = (bones_[size_t(o)].M[f] * Kp).leftCols<3>();
                        for (size_t i = 0; i < vs.size(); ++i) Rl[f * V_ + vs[i]] += Af * (dC * ys[i]);
                    }
                }
                C[size_t(b)] = Cn;
                for (size_t li : lis)
                    for (int x = b; x < B; ++x)
                        if (in_sub[size_t(x)]) K[li][size_t(x)] = K[li][size_t(bones_[size_t(x)].parent)] * hom(C[size_t(x)]);
            }
        }
        if (fit_weights) multilevel_weights(levels, lam, up, K);
    }
    recompute_all();
}

// Multi-level weight and bind update (transforms and corrections fixed).
// Vertex v's reconstruction at level L is sum_b w_b M_o(f) K_{L,b} [p_v; 1] (o
// the owner of b at level L), linear in the weights and affine in p_v, so the
// weighted sum over the levels sum_L lambda_L sum_f |a_vf - ...|^2 is one
// quadratic per vertex in each. With Q_ab = sum_f M_a(f)^T M_b(f) (4x4 per bone
// pair) and q_vb = sum_f M_b(f)^T a_vf it costs O(levels * n^2) per vertex
// instead of O(levels * frames * n^2). Weights: NNLS (sum 1 by a stiff penalty
// row) over the vertex's current bones plus the 6 bones whose own motion
// predicts its trajectory best, at most 4 kept; then the bind position by 3x3
// least squares; each accepted only when the vertex's multi-level objective
// decreases. Vertices are independent.
void Builder::multilevel_weights(const std::vector<int>& levels, const std::vector<double>& lam,
                                 const std::vector<std::vector<int>>& up,
                                 const std::vector<std::vector<Eigen::Matrix4d>>& K) {
    using M4 = Eigen::Matrix4d;
    using V4 = Eigen::Vector4d;
    const int B = bone_count();
    const size_t NL = levels.size();
    const int extra = std::min(B, 6);
    std::vector<M4> Q(size_t(B) * size_t(B), M4::Zero());
    for (size_t f = 0; f < F_; ++f)
        for (int a = 0; a < B; ++a)
            for (int b = a; b < B; ++b) {
                const M34& Ma = bones_[size_t(a)].M[f];
                const M34& Mb = bones_[size_t(b)].M[f];
                Q[size_t(a) * size_t(B) + size_t(b)].noalias() += Ma.transpose() * Mb;
            }
    for (int a = 0; a < B; ++a)
        for (int b = 0; b < a; ++b) Q[size_t(a) * size_t(B) + size_t(b)] = Q[size_t(b) * size_t(B) + size_t(a)].transpose();
    auto Qof = [&](int a, int b) -> const M4& { return Q[size_t(a) * size_t(B) + size_t(b)]; };
    std::vector<V4> q(static_cast<size_t>(B));
    std::vector<double> eb(static_cast<size_t>(B));
    std::vector<int> cand, idx(static_cast<size_t>(B));
    std::vector<V4> u;
    std::vector<int> own;
    for (size_t v = 0; v < V_; ++v) {
        std::fill(q.begin(), q.end(), V4::Zero());
        for (size_t f = 0; f < F_; ++f) {
            const V3& a = A_[f * V_ + v];
            for (int b = 0; b < B; ++b) q[size_t(b)].noalias() += bones_[size_t(b)].M[f].transpose() * a;
        }
        const V4 ph(P_[v].x(), P_[v].y(), P_[v].z(), 1.0);
        // Own-motion fit errors (up to the constant sum_f |a|^2).
        for (int b = 0; b < B; ++b) eb[size_t(b)] = ph.dot(Qof(b, b) * ph) - 2 * ph.dot(q[size_t(b)]);
        std::iota(idx.begin(), idx.end(), 0);
        std::partial_sort(idx.begin(), idx.begin() + extra, idx.end(),
                          [&](int a, int b) { return eb[size_t(a)] < eb[size_t(b)]; });
        cand.clear();
        for (int i = 0; i < nslot_[v]; ++i) cand.push_back(slot_bone_[v][i]);
        for (int i = 0; i < extra; ++i)
            if (std::find(cand.begin(), cand.end(), idx[size_t(i)]) == cand.end()) cand.push_back(idx[size_t(i)]);
        const int n = int(cand.size());
        Eigen::MatrixXd G = Eigen::MatrixXd::Zero(n, n);
        Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
        u.resize(size_t(n));
        own.resize(size_t(n));
        for (size_t li = 0; li < NL; ++li) {
            for (int i = 0; i < n; ++i) {
                u[size_t(i)] = K[li][size_t(cand[size_t(i)])] * ph;
                own[size_t(i)] = up[li][size_t(cand[size_t(i)])];
            }
            for (int i = 0; i < n; ++i) {
                h[i] += lam[li] * u[size_t(i)].dot(q[size_t(own[size_t(i)])]);
                for (int j = i; j < n; ++j)
                    G(i, j) += lam[li] * u[size_t(i)].dot(Qof(own[size_t(i)], own[size_t(j)]) * u[size_t(j)]);
            }
        }
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < i; ++j) G(i, j) = G(j, i);
        // Current weights' objective (up to the constant sum lambda |a|^2).
        Eigen::VectorXd w0 = Eigen::VectorXd::Zero(n);
        for (int i = 0; i < nslot_[v]; ++i) w0[i] = slot_w_[v][i];
        const double obj0 = w0.dot(G * w0) - 2 * h.dot(w0);
        Eigen::VectorXd w;
        std::vector<int> keep;
        if (sparse_weights(G, h, w, keep)) {
            const double obj = w.dot(G * w) - 2 * h.dot(w);
            if (obj < obj0 - 1e-12 * std::abs(obj0)) set_slots(v, keep, w, cand);
        }
        if (!opt_.update_bind) continue;
        // Bind: z_i = K_i [p; 1] = Kc_i p + kt_i; objective p'Hp - 2 g'p + const.
        M3 H = M3::Zero();
        V3 g = V3::Zero();
        for (size_t li = 0; li < NL; ++li) {
            for (int i = 0; i < nslot_[v]; ++i) {
                const int bi = slot_bone_[v][i];
                const M4& Ki = K[li][size_t(bi)];
                const int oi = up[li][size_t(bi)];
                const double wi = lam[li] * slot_w_[v][i];
                g += wi * Ki.leftCols<3>().transpose() * q[size_t(oi)];
                for (int j = 0; j < nslot_[v]; ++j) {
                    const int bj = slot_bone_[v][j];
                    const M4& Kj = K[li][size_t(bj)];
                    const M4& Qij = Qof(oi, up[li][size_t(bj)]);
                    const double wij = wi * slot_w_[v][j];
                    H += wij * Ki.leftCols<3>().transpose() * Qij * Kj.leftCols<3>();
                    g -= wij * Ki.leftCols<3>().transpose() * Qij * Kj.col(3);
                }
            }
        }
        const V3 p = H.ldlt().solve(g);
        if (!p.allFinite()) continue;
        auto objective = [&](const V3& x) { return x.dot(H * x) - 2 * g.dot(x); };
        if (objective(p) < objective(P_[v])) P_[v] = p;
    }
}

void Builder::refine(int sweeps, const std::function<void()>& tick) {
    for (int s = 0; s < sweeps; ++s) {
        refine_transforms(0);
        refine_weights_full();
        tick();
    }
}

// Float key times t_f = f / fps such that sample_frames yields exactly F frames.
std::vector<float> key_times(size_t F, double fps) {
    std::vector<float> t(F);
    for (size_t f = 0; f < F; ++f) t[f] = float(double(f) / fps);
    if (F > 1) {
        auto count = [&]() { return size_t(std::floor(double(t.back()) * fps + 1e-6)) + 1; };
        while (count() < F) t.back() = std::nextafter(t.back(), std::numeric_limits<float>::infinity());
    }
    return t;
}

// Area-weighted vertex normals of a triangle list (empty without triangles).
std::vector<glm::vec3> triangle_normals(const std::vector<glm::vec3>& p, const std::vector<uint32_t>& tri) {
    if (tri.empty()) return {};
    std::vector<glm::dvec3> n(p.size(), glm::dvec3(0.0));
    for (size_t i = 0; i + 2 < tri.size(); i += 3) {
        const glm::dvec3 a(p[tri[i]]), b(p[tri[i + 1]]), c(p[tri[i + 2]]);
        const glm::dvec3 x = glm::cross(b - a, c - a);
        for (int k = 0; k < 3; ++k) n[tri[i + k]] += x;
    }
    std::vector<glm::vec3> out(p.size());
    for (size_t v = 0; v < p.size(); ++v) {
        const double l = glm::length(n[v]);
        out[v] = l > 0 ? glm::vec3(n[v] / l) : glm::vec3(0, 0, 1);
    }
    return out;
}

// The Character (flat joints under one root node, one TRS clip) of a fit.
Character make_character(const VertexAnimation& an, const Builder& b, bool similarity) {
    Character c;
    c.name = "scratch";
    c.source = an.source;
    const int B = b.bone_count();
    const size_t V = an.vertex_count, F = an.frame_count;
    Node root;
    root.name = "scratch_root";
    root.gltf_index = 0;
    c.nodes.push_back(root);
    for (int j = 0; j < B; ++j) {
        Node n;
        n.name = "bone" + std::to_string(j);
        n.gltf_index = j + 1;
        n.parent = 0;
        const V3& ctr = b.bones()[size_t(j)].center;
        n.translation = glm::dvec3(ctr.x(), ctr.y(), ctr.z());
        c.nodes.push_back(n);
        c.joint_node.push_back(j + 1);
        c.joint_parent.push_back(-1);
        c.inverse_bind.push_back(glm::translate(glm::dmat4(1.0), -n.translation));
    }
    c.positions.resize(V);
    for (size_t v = 0; v < V; ++v) c.positions[v] = glm::vec3(b.bind()[v].x(), b.bind()[v].y(), b.bind()[v].z());
    c.triangles = an.triangles;
    c.normals = an.normals.size() == V ? an.normals : triangle_normals(c.positions, c.triangles);
    c.influences = kSlots;
    c.joints.assign(V * kSlots, 0);
    c.weights.assign(V * kSlots, 0.0f);
    for (size_t v = 0; v < V; ++v) {
        // Slots ordered for dropping: largest weight first.
        std::array<int, kSlots> ord{0, 1, 2, 3};
        const int n = b.nslot(v);
        for (int i = 1; i < n; ++i)  // insertion sort by weight, descending
            for (int k = i; k > 0 && b.slot_w(v, ord[k]) > b.slot_w(v, ord[k - 1]); --k) std::swap(ord[k], ord[k - 1]);
        double sum = 0;
        for (int i = 0; i < n; ++i) sum += b.slot_w(v, ord[i]);
        for (int i = 0; i < n; ++i) {
            c.joints[v * kSlots + i] = uint16_t(b.slot_bone(v, ord[i]));
            c.weights[v * kSlots + i] = float(b.slot_w(v, ord[i]) / sum);
        }
    }
    PrimitiveRange pr;
    pr.node = B + 1;
    pr.mesh = 0;
    pr.primitive = 0;
    pr.first = 0;
    pr.count = uint32_t(V);
    pr.skin = 0;
    c.primitives.push_back(pr);
    Clip clip;
    clip.name = "scratch";
    clip.gltf_index = 0;
    const std::vector<float> times = key_times(F, an.fps);
    for (int j = 0; j < B; ++j) {
        Channel t, r, s;
        t.node = r.node = s.node = j + 1;
        t.path = ChannelPath::Translation;
        r.path = ChannelPath::Rotation;
        s.path = ChannelPath::Scale;
        t.times = r.times = s.times = times;
        const V3& ctr = b.bones()[size_t(j)].center;
        glm::dquat prev(1, 0, 0, 0);
        for (size_t f = 0; f < F; ++f) {
            const M34& M = b.bones()[size_t(j)].M[f];
            // G = M * translate(center): translation M(center), rotation/scale of M.
            const V3 tr = xf(M, ctr);
            const double sc = std::cbrt(std::max(1e-300, M.leftCols<3>().determinant()));
            const M3 rot = M.leftCols<3>() / sc;
            glm::dmat3 g;
            for (int col = 0; col < 3; ++col)
                for (int row = 0; row < 3; ++row) g[col][row] = rot(row, col);
            glm::dquat q = glm::normalize(glm::quat_cast(g));
            if (glm::dot(q, prev) < 0) q = -q;  // shortest path between keys
            prev = q;
            t.values.insert(t.values.end(), {float(tr.x()), float(tr.y()), float(tr.z())});
            r.values.insert(r.values.end(), {float(q.x), float(q.y), float(q.z), float(q.w)});
            s.values.insert(s.values.end(), {float(sc), float(sc), float(sc)});
        }
        clip.channels.push_back(std::move(t));
        clip.channels.push_back(std::move(r));
        if (similarity) clip.channels.push_back(std::move(s));
    }
    clip.start = times.front();
    clip.end = times.back();
    c.clips.push_back(std::move(clip));
    return c;
}

ProgressiveSkin make_skin(const Character& c, const Builder& b, double diagonal) {
    ProgressiveSkin s;
    s.strategy = Strategy::Scratch;
    const int B = b.bone_count();
    s.order.resize(size_t(B));
    std::iota(s.order.begin(), s.order.end(), 0);
    s.parents.resize(size_t(B));
    for (int j = 0; j < B; ++j) s.parents[size_t(j)] = int16_t(b.bones()[size_t(j)].parent);
    s.corrections.assign(size_t(B), Mat34::identity());
    s.diagonal = diagonal;
    s.influences = c.influences;
    s.joints = c.joints;
    s.weights = c.weights;
    return s;
}

}  // namespace

std::vector<LodError> scratch_error_table(const Character& c, const ProgressiveSkin& s, const FrameSet& frames,
                                          const VertexAnimation& an, double diagonal) {
    if (frames.frame_count() != an.frame_count || c.vertex_count() != an.vertex_count)
        throw Error(an.source + ": skin and vertex animation do not match");
    const size_t V = an.vertex_count, F = an.frame_count;
    const int B = s.bone_count();
    // ||A - Abar||_F^2 for the distortion percentage.
    std::vector<glm::dvec3> mean(V, glm::dvec3(0.0));
    for (size_t f = 0; f < F; ++f)
        for (size_t v = 0; v < V; ++v) mean[v] += glm::dvec3(an.frame(f)[v]);
    double spread = 0;
    for (size_t v = 0; v < V; ++v) mean[v] /= double(F);
    for (size_t f = 0; f < F; ++f)
        for (size_t v = 0; v < V; ++v) {
            const glm::dvec3 d = glm::dvec3(an.frame(f)[v]) - mean[v];
            spread += glm::dot(d, d);
        }
    std::vector<LodError> table;
    std::vector<glm::vec3> rec(V);
    for (int k = 1; k <= B; ++k) {
        ErrorAccumulator acc(diagonal);
        for (size_t f = 0; f < F; ++f) {
            lod_positions(c, s, frames, f, k, rec);
            acc.add(std::span<const glm::vec3>(an.frame(f), V), rec);
        }
        const ErrorStats st = acc.stats();
        std::vector<int> up(static_cast<size_t>(B));
        for (int b = 0; b < B; ++b) up[b] = b < k ? b : up[s.parents[b]];
        double owners = 0;
        for (size_t v = 0; v < V; ++v) {
            int seen[8], n = 0;
            for (int i = 0; i < s.influences; ++i) {
                if (s.weights[v * s.influences + i] == 0.0f) continue;
                const int o = up[s.joints[v * s.influences + i]];
                if (std::find(seen, seen + n, o) == seen + n) seen[n++] = o;
            }
            owners += n;
        }
        LodError e{k, st.rms, st.max, st.rms_pct, st.max_pct, V ? owners / double(V) : 0.0, -1.0};
        if (spread > 0) e.distortion_pct = 100.0 * std::sqrt(st.rms * st.rms * double(V * F) / spread);
        table.push_back(e);
    }
    return table;
}

namespace {

// Resamples the fitted character's clip and evaluates the error table.
void finish(ScratchResult& r, const VertexAnimation& an, double diag) {
    r.frames = sample_frames(r.character, {select_clips(r.character, "all")}, an.fps);
    if (r.frames.frame_count() != an.frame_count)
        throw Error(an.source + ": internal: resampled " + std::to_string(r.frames.frame_count()) + " frames of " +
                    std::to_string(an.frame_count));
    r.skin.error = scratch_error_table(r.character, r.skin, r.frames, an, diag);
}

void set_corrections(ProgressiveSkin& s, const std::vector<M34>& C) {
    for (size_t j = 0; j < C.size() && j < s.corrections.size(); ++j) {
        if (j == 0) continue;  // bone 0 is always active
        for (int i = 0; i < 3; ++i)
            for (int k = 0; k < 4; ++k) s.corrections[j].m[i * 4 + k] = float(C[j](i, k));
    }
}

int first_increase(const std::vector<LodError>& t) {
    for (size_t k = 1; k < t.size(); ++k)
        if (t[k].rms > t[k - 1].rms) return int(k);
    return 0;
}

// Mean over k of log RMS: the figure Auto compares (every k counts alike).
double mean_log_rms(const std::vector<LodError>& t, int upto) {
    double s = 0;
    for (int k = 1; k <= upto; ++k) s += std::log(std::max(1e-300, t[size_t(std::min<int>(k, int(t.size())) - 1)].rms));
    return s / upto;
}

// The multi-level refit of b (progressive order, parents, corrections C),
// evaluated honestly by make(refitted builder, corrections, weights refitted).
// Where the table rises (a level got worse than the level below), that level
// joins the refitted levels and the refit continues for another
// multilevel_sweeps sweeps (at most twice); failing that, the refit of b
// without the weight update. Nothing when no refit gives a non-increasing
// table.
template <class Make>
std::optional<ScratchResult> refit_monotone(const Builder& b, const std::vector<M34>& C0, const ScratchOptions& opt,
                                            const Make& make) {
    std::vector<int> extra;
    const int tries = opt.multilevel_weights ? 3 : 0;
    std::optional<Builder> cur;  // the last refit with weights, continued by the next attempt
    std::vector<M34> Ccur;
    for (int attempt = 0; attempt <= tries; ++attempt) {
        const bool weights = attempt < tries;  // the last attempt without the weight update
        const bool warm = weights && cur.has_value();
        Builder b2 = warm ? std::move(*cur) : b;
        std::vector<M34> C = warm ? Ccur : C0;
        b2.multilevel_refit(C, opt.multilevel_sweeps, true, weights, extra);
        ScratchResult r = make(b2, C, weights);
        const std::vector<LodError>& t = r.skin.error;
        bool rises = false;
        for (size_t k = 1; k < t.size(); ++k)
            if (t[k].rms > t[k - 1].rms) {
                rises = true;
                if (std::find(extra.begin(), extra.end(), int(k) + 1) == extra.end()) extra.push_back(int(k) + 1);
            }
        if (!rises) return r;
        if (weights) {
            cur = std::move(b2);
            Ccur = std::move(C);
        }
    }
    return std::nullopt;
}

// Top-down: bones added one at a time (each splits weight from its parent),
// then SSDR refinement; the safety net cuts the skin at a rise of the table.
ScratchResult build_top_down(const VertexAnimation& an, const ScratchOptions& opt, double diag,
                             const std::function<void()>& tick,
                             const std::vector<std::vector<M34>>* motions = nullptr) {
    Builder b(an, opt);
    b.fit_root();
    tick();
    const double n = double(an.vertex_count) * double(an.frame_count);
    auto rms_pct = [&]() { return 100.0 * std::sqrt(b.total_error() / n) / diag; };
    int steps = 1;
    while (b.bone_count() < opt.max_bones) {
        if (opt.max_error_pct > 0 && rms_pct() <= opt.max_error_pct) break;
        if (!(motions ? b.add_bone_from(*motions) : b.add_bone())) break;
        tick();
        ++steps;
    }
    for (; steps < opt.max_bones; ++steps) tick();
    b.refine(opt.refine_sweeps, tick);
    if (opt.multilevel_sweeps > 0) {
        ScratchResult r0;
        r0.character = make_character(an, b, opt.similarity);
        r0.skin = make_skin(r0.character, b, diag);
        finish(r0, an, diag);
        auto make = [&](const Builder& b2, const std::vector<M34>& C, bool) {
            ScratchResult r2;
            r2.character = make_character(an, b2, opt.similarity);
            r2.skin = make_skin(r2.character, b2, diag);
            set_corrections(r2.skin, C);
            finish(r2, an, diag);
            return r2;
        };
        std::optional<ScratchResult> r2 =
            refit_monotone(b, std::vector<M34>(size_t(b.bone_count()), identity34()), opt, make);
        const int n = r0.skin.bone_count();
        if (r2 && (first_increase(r0.skin.error) || mean_log_rms(r2->skin.error, n) < mean_log_rms(r0.skin.error, n)))
            return std::move(*r2);
    }
    ScratchResult r;
    for (int attempt = 0;; ++attempt) {
        r.character = make_character(an, b, opt.similarity);
        r.skin = make_skin(r.character, b, diag);
        finish(r, an, diag);
        // Safety net: the table must be non-increasing (float rounding of the
        // keys could break a tie); drop the bones from the first increase on.
        const int bad = first_increase(r.skin.error);
        if (!bad || attempt > 4) break;
        b.truncate(bad);
    }
    return r;
}

// Collapse: full-detail decomposition (Builder::decompose), then the greedy
// collapse of progressive_skin.cpp (strategy Flatten: least-error order, new
// hierarchy, least-squares corrections) on the fitted character, re-expressed
// with joints in progressive order.
ScratchResult build_collapse(const VertexAnimation& an, const ScratchOptions& opt, double diag,
                             const std::function<void()>& tick, const std::function<void(int, int)>& collapse_progress,
                             std::vector<std::vector<M34>>* motions = nullptr) {
    const double n = double(an.vertex_count) * double(an.frame_count);
    double target_sq = 0;
    if (opt.max_error_pct > 0) target_sq = n * std::pow(opt.max_error_pct * diag / 100.0, 2);
    int bones = opt.max_bones;
    for (int attempt = 0;; ++attempt) {
        Builder b(an, opt);
        b.fit_root();
        b.decompose(bones, target_sq, opt.iterations, tick);
        if (motions && attempt == 0)
            for (const Bone& bone : b.bones()) motions->push_back(bone.M);
        ScratchResult r;
        Character c = make_character(an, b, opt.similarity);
        const FrameSet fr = sample_frames(c, {select_clips(c, "all")}, an.fps);
        ProgressiveSkin ps;
        if (b.bone_count() > 1) {
            BuildOptions bo;
            bo.strategy = Strategy::Flatten;
            bo.fit_corrections = true;
            bo.progress = collapse_progress;
            ps = build_progressive_skin(c, fr, bo);
            b.permute(ps.order);
            for (int j = 1; j < b.bone_count(); ++j) b.set_parent(j, ps.parents[size_t(j)]);
            r.character = make_character(an, b, opt.similarity);
            r.skin = std::move(ps);
            std::iota(r.skin.order.begin(), r.skin.order.end(), 0);
            if (opt.multilevel_sweeps > 0) {
                std::vector<M34> C(size_t(b.bone_count()));
                for (size_t j = 0; j < C.size(); ++j)
                    for (int i = 0; i < 3; ++i)
                        for (int k = 0; k < 4; ++k) C[j](i, k) = double(r.skin.corrections[j].m[i * 4 + k]);
                r.skin.strategy = Strategy::Scratch;
                r.skin.diagonal = diag;
                finish(r, an, diag);
                auto make = [&](const Builder& b2, const std::vector<M34>& Cn, bool weights) {
                    ScratchResult r2;
                    r2.character = make_character(an, b2, opt.similarity);
                    r2.skin = r.skin;
                    if (weights) {  // the refit changed the weights: largest first
                        r2.skin.joints = r2.character.joints;
                        r2.skin.weights = r2.character.weights;
                    }
                    set_corrections(r2.skin, Cn);
                    finish(r2, an, diag);
                    return r2;
                };
                std::optional<ScratchResult> r2 = refit_monotone(b, C, opt, make);
                const int n = r.skin.bone_count();
                if (r2 && (first_increase(r.skin.error) || mean_log_rms(r2->skin.error, n) < mean_log_rms(r.skin.error, n)))
                    r = std::move(*r2);
                const int bad = first_increase(r.skin.error);
                if (!bad || attempt > 3 || bones <= 1) return r;
                bones = bad;
                continue;
            }
        } else {
            r.character = std::move(c);
            r.skin = make_skin(r.character, b, diag);
        }
        r.skin.strategy = Strategy::Scratch;
        r.skin.diagonal = diag;
        finish(r, an, diag);
        const int bad = first_increase(r.skin.error);
        if (!bad || attempt > 3 || bones <= 1) return r;
        bones = bad;  // rebuild with fewer bones (rare: the collapse only adds error to the fit)
    }
}

}  // namespace

ScratchResult build_from_vertices(const VertexAnimation& an, const ScratchOptions& opt) {
    an.validate();
    if (opt.max_bones < 1 || opt.max_bones > 1024) throw Error(an.source + ": bone count must be in 1..1024");
    if (opt.max_error_pct < 0 || !std::isfinite(opt.max_error_pct)) throw Error(an.source + ": --max-error must be >= 0");
    if (opt.rest_frame >= 0 && size_t(opt.rest_frame) >= an.frame_count)
        throw Error(an.source + ": --rest-frame " + std::to_string(opt.rest_frame) + " out of range (" +
                    std::to_string(an.frame_count) + " frames)");
    if (opt.iterations < 0 || opt.refine_sweeps < 0) throw Error(an.source + ": iterations must be >= 0");
    double diag = an.diagonal > 0 ? an.diagonal : frame_diagonal(an, opt.rest_frame >= 0 ? size_t(opt.rest_frame) : 0);
    if (!(diag > 0)) diag = 1.0;  // a single point: report in units
    const bool td = opt.method == ScratchMethod::TopDown;
    const bool hy = opt.method == ScratchMethod::Auto || opt.method == ScratchMethod::Hybrid;
    const bool co = opt.method == ScratchMethod::Auto || opt.method == ScratchMethod::Collapse || hy;
    // Progress: decomposition splits + iterations + collapse steps, then
    // top-down bones + sweeps.
    const int co_steps = co ? 2 * opt.max_bones + opt.iterations : 0;
    const int td_steps = (td || hy) ? opt.max_bones + opt.refine_sweeps : 0;
    const int total = td_steps + co_steps;
    int step = 0;
    auto report = [&](int s) {
        step = std::clamp(s, step, total - 1);
        if (opt.progress) opt.progress(step, total);
    };
    auto tick = [&]() { report(step + 1); };
    // Keeps r when it is better (a table that is not non-increasing never is).
    std::optional<ScratchResult> best;
    auto offer = [&](ScratchResult&& r) {
        const int upto = std::max(r.skin.bone_count(), best ? best->skin.bone_count() : 0);
        if (!best || first_increase(best->skin.error) ||
            (!first_increase(r.skin.error) && mean_log_rms(r.skin.error, upto) < mean_log_rms(best->skin.error, upto)))
            best = std::move(r);
    };
    std::vector<std::vector<M34>> motions;  // the decomposition's bones, the hybrid's proposals
    if (co) {
        auto cprog = [&](int s, int t) { report(opt.max_bones + opt.iterations + (t > 0 ? s * opt.max_bones / t : 0)); };
        ScratchResult r = build_collapse(an, opt, diag, tick, cprog, hy ? &motions : nullptr);
        if (opt.method != ScratchMethod::Hybrid) offer(std::move(r));  // Hybrid: only the motions
        report(co_steps);
    }
    if (td) offer(build_top_down(an, opt, diag, tick));
    if (hy) offer(build_top_down(an, opt, diag, tick, &motions));
    if (opt.progress) opt.progress(total, total);
    return std::move(*best);
}

}  // namespace progskin
