// collapse.cpp — greedy collapse of an existing skin (docs/algorithms.md).
//
// State of the collapse: every vertex holds, per *owner* (an active bone that
// its weight currently follows), a homogeneous 4-vector u = sum of w_j * K_j *
// [v;1] over the joints j collapsed into that owner (K_j the composed
// corrections). The reconstruction of vertex v at frame f is
//     r(v,f) = sum_owners S_o(f) * u_{v,o}
// with S the skinning matrices. Collapsing bone c into a with correction C
// merges u_{v,c} into u_{v,a} as C * u_{v,c}. Its cost is the increase of the
// squared error sum over all vertices and frames; the best C solves a linear
// least-squares problem with 12 unknowns (see fit_correction).
#include "collapse.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "errors.h"
#include "error_metric.h"
#include "palette.h"
#include "skinning.h"

namespace progskin {

namespace {

using Vec4d = Eigen::Vector4d;
using Mat34d = Eigen::Matrix<double, 3, 4>;

Mat34d to_eigen(const Mat34& m) {
    Mat34d r;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) r(i, j) = m.m[i * 4 + j];
    return r;
}
Mat34 to_mat34(const Mat34d& m) {
    Mat34 r;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) r.m[i * 4 + j] = float(m(i, j));
    return r;
}
// C as a 4x4 affine from its 3x4 top rows.
Eigen::Matrix4d affine(const Mat34d& x) {
    Eigen::Matrix4d c = Eigen::Matrix4d::Identity();
    c.topRows<3>() = x;
    return c;
}
Mat34d identity34() {
    Mat34d x = Mat34d::Zero();
    x.leftCols<3>().setIdentity();
    return x;
}

struct Entry {
    int owner = -1;
    Vec4d u = Vec4d::Zero();
};

// Result of evaluating one candidate collapse c -> a.
struct Candidate {
    int target = -1;
    double cost = std::numeric_limits<double>::infinity();  // increase of the squared error sum
    Mat34d x = identity34();                                // correction C (top 3 rows)
    bool valid() const { return target >= 0; }
};

class Collapser {
public:
    Collapser(const Character& c, const FrameSet& frames, const BuildOptions& opt)
        : c_(c), fr_(frames), opt_(opt), V_(c.vertex_count()), F_(frames.frame_count()), B_(int(c.joint_count())),
          I_(c.influences) {
        if (B_ < 1) throw Error(c.source + ": character has no joints");
        if (F_ < 1) throw Error(c.source + ": no frames to build from");
        if (fr_.joint_count != B_) throw Error(c.source + ": frame set does not match the character");
        // Frame matrices in double, frame-major: S_[f*B + j].
        S_.resize(F_ * size_t(B_));
        for (size_t f = 0; f < F_; ++f)
            for (int j = 0; j < B_; ++j) S_[f * B_ + j] = to_eigen(fr_.frame(f)[j]);
        // Reference positions, vertex-major. The collapse works on constant
        // bind positions, so its reference is the unmorphed mesh skinned; with
        // morph targets the final table is measured on the morphed mesh
        // (build_progressive_skin).
        ref_.resize(V_ * F_);
        std::vector<glm::vec3> tmp(V_);
        for (size_t f = 0; f < F_; ++f) {
            skinned_bind_positions(c_, fr_, f, tmp);
            for (size_t v = 0; v < V_; ++v) ref_[v * F_ + f] = Eigen::Vector3d(tmp[v].x, tmp[v].y, tmp[v].z);
        }
        // Initial owners: one entry per distinct joint with non-zero weight.
        ent_.assign(V_ * I_, Entry{});
        supp_.assign(B_, {});
        for (size_t v = 0; v < V_; ++v) {
            const glm::vec3 p = c.positions[v];
            for (int i = 0; i < I_; ++i) {
                const float w = c.weights[v * I_ + i];
                if (w == 0.0f) continue;
                const int j = c.joints[v * I_ + i];
                Entry* e = find_or_add(v, j);
                e->u += double(w) * Vec4d(p.x, p.y, p.z, 1.0);
            }
            for (int i = 0; i < I_ && ent_[v * I_ + i].owner >= 0; ++i) supp_[ent_[v * I_ + i].owner].push_back(int(v));
        }
        // Sum of A^T A per bone over frames (normal equations of the fit).
        ata_.assign(B_, Eigen::Matrix3d::Zero());
        for (size_t f = 0; f < F_; ++f)
            for (int j = 0; j < B_; ++j) {
                const Eigen::Matrix3d A = S_[f * B_ + j].leftCols<3>();
                ata_[j] += A.transpose() * A;
            }
        active_.assign(B_, true);
        depth_.assign(B_, 0);
        for (int j = 0; j < B_; ++j)
            for (int p = c.joint_parent[j]; p >= 0; p = c.joint_parent[p]) ++depth_[j];
        vsq_.assign(V_, 0.0);
        vmax_.assign(V_, 0.0);
        for (size_t v = 0; v < V_; ++v) refresh_vertex_error(v);
    }

    ProgressiveSkin run() {
        struct Step {
            int bone, target;
            Mat34d x;
        };
        std::vector<Step> steps;
        std::vector<LodError> table(B_);
        table[B_ - 1] = current_error(B_);
        std::vector<Candidate> cache(B_);
        std::vector<char> dirty(B_, 1);
        for (int remaining = B_; remaining > 1; --remaining) {
            if (opt_.progress) opt_.progress(B_ - remaining, B_ - 1);
            int best = -1;
            if (opt_.strategy == Strategy::LeafPrune) {
                best = leaf_prune_next();
                cache[best] = evaluate(best, nearest_active_target(best), false);
            } else {
                for (int b = 0; b < B_; ++b) {
                    if (!is_candidate(b)) continue;
                    if (dirty[b] || !cache[b].valid() || !active_[cache[b].target]) {
                        cache[b] = best_candidate(b);
                        dirty[b] = 0;
                    }
                    if (!cache[b].valid()) continue;
                    if (best < 0 || cache[b].cost < cache[best].cost - 1e-12 * std::abs(cache[best].cost))
                        best = b;
                }
            }
            if (best < 0) throw Error(c_.source + ": no bone can be collapsed (disconnected skeleton?)");
            const Candidate cand = cache[best];
            // Everything owning a vertex that changes must be re-evaluated, as must
            // bones that targeted the collapsed one and the target itself.
            for (int v : supp_[best])
                for (int i = 0; i < I_; ++i)
                    if (ent_[v * I_ + i].owner >= 0) dirty[ent_[v * I_ + i].owner] = 1;
            for (int b = 0; b < B_; ++b)
                if (cache[b].target == best || cache[b].target == cand.target) dirty[b] = 1;
            dirty[cand.target] = 1;
            apply(best, cand.target, cand.x);
            steps.push_back({best, cand.target, cand.x});
            table[remaining - 2] = current_error(remaining - 1);
        }
        if (opt_.progress) opt_.progress(B_ - 1, B_ - 1);

        // Progressive order: the survivor first, then the collapsed bones in
        // reverse order of collapse.
        ProgressiveSkin s;
        s.strategy = opt_.strategy;
        s.diagonal = diagonal_;
        int root = -1;
        for (int b = 0; b < B_; ++b)
            if (active_[b]) root = b;
        s.order.push_back(root);
        for (auto it = steps.rbegin(); it != steps.rend(); ++it) s.order.push_back(it->bone);
        std::vector<int> prog_of(B_);
        for (int b = 0; b < B_; ++b) prog_of[s.order[b]] = b;
        s.parents.assign(B_, -1);
        s.corrections.assign(B_, Mat34::identity());
        for (const Step& st : steps) {
            s.parents[prog_of[st.bone]] = int16_t(prog_of[st.target]);
            s.corrections[prog_of[st.bone]] = to_mat34(st.x);
        }
        s.error = std::move(table);
        order_influences(s, prog_of);
        return s;
    }

    void set_diagonal(double d) { diagonal_ = d; }

private:
    Entry* find_or_add(size_t v, int owner) {
        Entry* e = &ent_[v * I_];
        for (int i = 0; i < I_; ++i) {
            if (e[i].owner == owner) return &e[i];
            if (e[i].owner < 0) {
                e[i].owner = owner;
                e[i].u.setZero();
                return &e[i];
            }
        }
        throw Error("internal: vertex owner table full");
    }

    // Position of vertex v at frame f from its owners (optionally skipping one).
    Eigen::Vector3d recon(size_t v, size_t f, int skip = -1) const {
        Eigen::Vector3d r = Eigen::Vector3d::Zero();
        const Mat34d* Sf = &S_[f * B_];
        for (int i = 0; i < I_; ++i) {
            const Entry& e = ent_[v * I_ + i];
            if (e.owner < 0) break;
            if (e.owner != skip) r += Sf[e.owner] * e.u;
        }
        return r;
    }

    void refresh_vertex_error(size_t v) {
        double s = 0, m = 0;
        for (size_t f = 0; f < F_; ++f) {
            const double e2 = (recon(v, f) - ref_[v * F_ + f]).squaredNorm();
            s += e2;
            m = std::max(m, e2);
        }
        vsq_[v] = s;
        vmax_[v] = m;
    }

    LodError current_error(int k) const {
        LodError e;
        e.bones = k;
        double s = 0, m = 0, owners = 0;
        for (size_t v = 0; v < V_; ++v) {
            s += vsq_[v];
            m = std::max(m, vmax_[v]);
            for (int i = 0; i < I_; ++i) {
                const Entry& en = ent_[v * I_ + i];
                if (en.owner < 0) break;
                if (std::abs(en.u[3]) > 1e-9) owners += 1;
            }
        }
        const double n = double(V_) * double(F_);
        e.rms = std::sqrt(s / n);
        e.max = std::sqrt(m);
        const double d = diagonal_ > 0 ? diagonal_ : 1.0;
        e.rms_pct = 100.0 * e.rms / d;
        e.max_pct = 100.0 * e.max / d;
        e.influences = V_ ? owners / double(V_) : 0.0;
        return e;
    }

    bool has_active_child(int b) const {
        for (int j = 0; j < B_; ++j)
            if (active_[j] && j != b && nearest_active_ancestor(j) == b) return true;
        return false;
    }
    int nearest_active_ancestor(int j) const {
        for (int p = c_.joint_parent[j]; p >= 0; p = c_.joint_parent[p])
            if (active_[p]) return p;
        return -1;
    }
    int active_count() const { return int(std::count(active_.begin(), active_.end(), true)); }

    bool is_candidate(int b) const {
        if (!active_[b] || active_count() < 2) return false;
        if (opt_.strategy == Strategy::Flatten) return true;
        // Hierarchy: the leaves of the active artist hierarchy only.
        if (opt_.strategy == Strategy::Hierarchy && has_active_child(b)) return false;
        // Reorder: any bone with an active artist ancestor (its active children
        // then hang from that ancestor); a bone without one only when another
        // such root-level bone remains, or when it has no active children.
        if (nearest_active_ancestor(b) >= 0) return true;
        for (int j = 0; j < B_; ++j)
            if (active_[j] && j != b && nearest_active_ancestor(j) < 0) return true;
        return !has_active_child(b);
    }

    // Reorder / leaf-prune target: the nearest active artist ancestor, or for a
    // root the first other active root.
    int nearest_active_target(int b) const {
        const int a = nearest_active_ancestor(b);
        if (a >= 0) return a;
        for (int j = 0; j < B_; ++j)
            if (active_[j] && j != b && nearest_active_ancestor(j) < 0) return j;
        for (int j = 0; j < B_; ++j)
            if (active_[j] && j != b) return j;
        return -1;
    }

    int leaf_prune_next() const {
        int best = -1;
        for (int b = 0; b < B_; ++b) {
            if (!active_[b] || has_active_child(b)) continue;
            if (best < 0 || depth_[b] > depth_[best] || (depth_[b] == depth_[best] && b > best)) best = b;
        }
        // Never drop the last root while other roots remain: handled by target choice.
        return best;
    }

    Candidate best_candidate(int b) {
        std::vector<int> targets;
        const int anc = nearest_active_ancestor(b);
        if (opt_.strategy == Strategy::Reorder || opt_.strategy == Strategy::Hierarchy) {
            if (anc >= 0) {
                targets.push_back(anc);
            } else {
                for (int j = 0; j < B_; ++j)
                    if (active_[j] && j != b && nearest_active_ancestor(j) < 0) targets.push_back(j);
            }
        } else {  // Flatten: the artist ancestor, then bones sharing vertices with b.
            std::vector<char> seen(B_, 0);
            if (anc >= 0) {
                targets.push_back(anc);
                seen[anc] = 1;
            }
            for (int v : supp_[b])
                for (int i = 0; i < I_; ++i) {
                    const int o = ent_[v * I_ + i].owner;
                    if (o < 0) break;
                    if (o != b && active_[o] && !seen[o]) {
                        seen[o] = 1;
                        targets.push_back(o);
                    }
                }
            if (targets.empty())
                for (int j = 0; j < B_; ++j)
                    if (active_[j] && j != b) targets.push_back(j);
        }
        Candidate best;
        for (int a : targets) {
            Candidate cand = evaluate(b, a, opt_.fit_corrections);
            if (!best.valid() || cand.cost < best.cost - 1e-12 * std::abs(best.cost)) best = cand;
        }
        return best;
    }

    // Cost of collapsing b into a. With fit, the correction X minimises
    //   sum_{v,f} || A_f X y_v + t_f y_w - T_vf ||^2,
    // T_vf = ref_vf - (contribution of every owner but b), y_v = u_{v,b}, where
    // S_a(f) = [A_f | t_f]. Normal equations: kron(Y, sum_f A_f^T A_f) vec(X) =
    // vec(sum_f A_f^T P_f), Y = sum_v y y^T, P_f = sum_v (T_vf - t_f y_w) y^T.
    // A small ridge toward the identity keeps it defined for degenerate Y; the
    // plain copy (X = identity) is evaluated too and the better one kept.
    Candidate evaluate(int b, int a, bool fit) {
        Candidate out;
        out.target = a;
        const std::vector<int>& sv = supp_[b];
        if (sv.empty()) {
            out.cost = 0.0;
            return out;
        }
        Mat34d X = identity34();
        if (fit) {
            Eigen::Matrix4d Y = Eigen::Matrix4d::Zero();
            for (int v : sv) {
                const Vec4d& y = owner_u(v, b);
                Y += y * y.transpose();
            }
            std::vector<Mat34d> P(F_, Mat34d::Zero());
            for (int v : sv) {
                const Vec4d y = owner_u(v, b);
                for (size_t f = 0; f < F_; ++f) {
                    const Eigen::Vector3d T = ref_[v * F_ + f] - recon(v, f, b) - S_[f * B_ + a].col(3) * y[3];
                    P[f] += T * y.transpose();
                }
            }
            Mat34d R = Mat34d::Zero();
            for (size_t f = 0; f < F_; ++f) R += S_[f * B_ + a].leftCols<3>().transpose() * P[f];
            Eigen::Matrix<double, 12, 12> N;
            const Eigen::Matrix3d& G = ata_[a];
            for (int i = 0; i < 4; ++i)
                for (int j = 0; j < 4; ++j) N.block<3, 3>(3 * i, 3 * j) = Y(i, j) * G;
            const double lambda = 1e-10 * std::max(N.trace() / 12.0, 1e-30);
            N.diagonal().array() += lambda;
            Eigen::Matrix<double, 12, 1> rhs;
            const Mat34d I34 = identity34();
            for (int col = 0; col < 4; ++col)
                for (int row = 0; row < 3; ++row) rhs[3 * col + row] = R(row, col) + lambda * I34(row, col);
            const Eigen::Matrix<double, 12, 1> x = N.ldlt().solve(rhs);
            if (x.allFinite())
                for (int col = 0; col < 4; ++col)
                    for (int row = 0; row < 3; ++row) X(row, col) = x[3 * col + row];
        }
        // Exact evaluation of the fitted and the plain stand-in.
        const Mat34d I34 = identity34();
        double fitted = 0, plain = 0, old = 0;
        for (int v : sv) {
            const Vec4d y = owner_u(v, b);
            const Eigen::Vector3d xy_fit = X * y;
            const Eigen::Vector3d xy_plain = I34 * y;
            for (size_t f = 0; f < F_; ++f) {
                const Mat34d& Sa = S_[f * B_ + a];
                const Eigen::Vector3d T = ref_[v * F_ + f] - recon(v, f, b);
                const Eigen::Vector3d ta = Sa.col(3) * y[3];
                const Eigen::Matrix3d A = Sa.leftCols<3>();
                fitted += (A * xy_fit + ta - T).squaredNorm();
                plain += (A * xy_plain + ta - T).squaredNorm();
            }
            old += vsq_[v];
        }
        if (fit && fitted < plain) {
            out.cost = fitted - old;
            out.x = X;
        } else {
            out.cost = plain - old;
            out.x = I34;
        }
        return out;
    }

    Vec4d owner_u(int v, int b) const {
        for (int i = 0; i < I_; ++i) {
            const Entry& e = ent_[size_t(v) * I_ + i];
            if (e.owner == b) return e.u;
            if (e.owner < 0) break;
        }
        return Vec4d::Zero();
    }

    void apply(int b, int a, const Mat34d& x) {
        const Eigen::Matrix4d C = affine(x);
        for (int v : supp_[b]) {
            Entry* e = &ent_[size_t(v) * I_];
            int ib = -1;
            for (int i = 0; i < I_ && e[i].owner >= 0; ++i)
                if (e[i].owner == b) ib = i;
            if (ib < 0) continue;
            const Vec4d moved = C * e[ib].u;
            // Remove entry b (keep entries packed), then add into a.
            int last = ib;
            while (last + 1 < I_ && e[last + 1].owner >= 0) ++last;
            e[ib] = e[last];
            e[last] = Entry{};
            find_or_add(size_t(v), a)->u += moved;
            refresh_vertex_error(size_t(v));
        }
        std::vector<int> merged;
        std::set_union(supp_[a].begin(), supp_[a].end(), supp_[b].begin(), supp_[b].end(),
                       std::back_inserter(merged));
        supp_[a] = std::move(merged);
        supp_[b].clear();
        active_[b] = false;
    }

    // Per vertex: order the influence slots so that dropping the last ones
    // (their weight moved, by renormalisation, to the ones kept) costs least:
    // greedy backward elimination on up to 64 evenly spread frames.
    void order_influences(ProgressiveSkin& s, const std::vector<int>& prog_of) const {
        s.influences = I_;
        s.joints.assign(V_ * I_, 0);
        s.weights.assign(V_ * I_, 0.0f);
        const size_t nf = std::min<size_t>(F_, 64);
        std::vector<size_t> fs(nf);
        for (size_t i = 0; i < nf; ++i) fs[i] = nf > 1 ? i * (F_ - 1) / (nf - 1) : 0;
        std::vector<std::pair<int, float>> slots;
        std::vector<Eigen::Vector3d> contrib;  // per slot per sampled frame: M_j v
        for (size_t v = 0; v < V_; ++v) {
            slots.clear();
            for (int i = 0; i < I_; ++i)
                if (c_.weights[v * I_ + i] != 0.0f) slots.push_back({c_.joints[v * I_ + i], c_.weights[v * I_ + i]});
            const size_t n = slots.size();
            contrib.assign(n * nf, Eigen::Vector3d::Zero());
            const glm::vec3 p = c_.positions[v];
            const Vec4d ph(p.x, p.y, p.z, 1.0);
            for (size_t i = 0; i < n; ++i)
                for (size_t k = 0; k < nf; ++k) contrib[i * nf + k] = S_[fs[k] * B_ + slots[i].first] * ph;
            std::vector<char> kept(n, 1);
            std::vector<int> dropped;  // in drop order
            for (size_t round = 1; round < n; ++round) {
                int best = -1;
                double best_cost = 0;
                for (size_t cand = 0; cand < n; ++cand) {
                    if (!kept[cand]) continue;
                    double wsum = 0;
                    for (size_t i = 0; i < n; ++i)
                        if (kept[i] && i != cand) wsum += slots[i].second;
                    if (wsum <= 0) continue;
                    double cost = 0;
                    for (size_t k = 0; k < nf; ++k) {
                        Eigen::Vector3d r = Eigen::Vector3d::Zero();
                        for (size_t i = 0; i < n; ++i)
                            if (kept[i] && i != cand) r += (slots[i].second / wsum) * contrib[i * nf + k];
                        cost += (r - ref_[v * F_ + fs[k]]).squaredNorm();
                    }
                    if (best < 0 || cost < best_cost) {
                        best = int(cand);
                        best_cost = cost;
                    }
                }
                if (best < 0) break;
                kept[best] = 0;
                dropped.push_back(best);
            }
            std::vector<int> order;
            for (size_t i = 0; i < n; ++i)
                if (kept[i]) order.push_back(int(i));
            for (auto it = dropped.rbegin(); it != dropped.rend(); ++it) order.push_back(*it);
            for (size_t i = 0; i < order.size(); ++i) {
                s.joints[v * I_ + i] = uint16_t(prog_of[slots[order[i]].first]);
                s.weights[v * I_ + i] = slots[order[i]].second;
            }
        }
    }

    const Character& c_;
    const FrameSet& fr_;
    BuildOptions opt_;
    size_t V_, F_;
    int B_, I_;
    double diagonal_ = 1.0;
    std::vector<Mat34d> S_;
    std::vector<Eigen::Vector3d> ref_;
    std::vector<Entry> ent_;
    std::vector<std::vector<int>> supp_;
    std::vector<Eigen::Matrix3d> ata_;
    std::vector<bool> active_;
    std::vector<int> depth_;
    std::vector<double> vsq_, vmax_;
};

}  // namespace

ProgressiveSkin build_progressive_skin(const Character& c, const FrameSet& frames, const BuildOptions& options) {
    BuildOptions opt = options;
    if (opt.strategy == Strategy::LeafPrune) opt.fit_corrections = false;
    if (opt.strategy == Strategy::Scratch) throw Error("build_progressive_skin: use build_from_vertices for 'scratch'");
    Collapser col(c, frames, opt);
    col.set_diagonal(rest_diagonal(c));
    ProgressiveSkin s = col.run();
    // Morph targets: a LOD keeps the frame's morph weights exact, so its error
    // is the skinning error on the morphed mesh, measured against the full
    // reference (morphs, then the full skin).
    if (!c.morphs.empty()) s.error = evaluate_error_table(c, s, frames);
    return s;
}

double mean_rms(const std::vector<LodError>& table) {
    double sum = 0;
    for (const LodError& e : table) sum += e.rms;
    return table.empty() ? 0.0 : sum / double(table.size());
}

double rd_area(const std::vector<LodError>& table, const std::vector<double>& bits, double until) {
    if (table.empty() || bits.size() != table.size()) return 0.0;
    double area = table[0].rms * bits[0], at = 0;  // e(1) while bone 0's bits arrive
    for (size_t k = 0; k < table.size(); ++k) {
        at += bits[k];
        const double next = k + 1 < table.size() ? at + bits[k + 1] : std::max(until, at);
        area += table[k].rms * (next - at);
    }
    return area;
}

ProgressiveSkin build_best_progressive_skin(const Character& c, const FrameSet& frames, const BuildOptions& options,
                                            StrategyChoice* choice) {
    // Reorder and flatten; with the stream's bits, hierarchy too.
    std::vector<Strategy> tried = {Strategy::Reorder, Strategy::Flatten};
    if (options.bone_bits) tried.push_back(Strategy::Hierarchy);
    const int n = int(tried.size());
    std::vector<ProgressiveSkin> skins;
    for (int i = 0; i < n; ++i) {
        BuildOptions opt = options;
        opt.strategy = tried[size_t(i)];
        if (options.progress) opt.progress = [&progress = options.progress, i, n](int s, int t) { progress(i * t + s, n * t); };
        skins.push_back(build_progressive_skin(c, frames, opt));
    }
    StrategyChoice ch;
    ch.reorder_mean_rms = mean_rms(skins[0].error);
    ch.flatten_mean_rms = mean_rms(skins[1].error);
    size_t best = ch.flatten_mean_rms < ch.reorder_mean_rms ? 1 : 0;
    if (options.bone_bits) {
        std::vector<std::vector<double>> bits;
        double until = 0;
        bool ok = true;
        for (const ProgressiveSkin& s : skins) {
            bits.push_back(options.bone_bits(s));
            ok = ok && bits.back().size() == s.error.size();
            double sum = 0;
            for (double b : bits.back()) sum += b;
            until = std::max(until, sum);
        }
        if (ok) {
            ch.by_rate = true;
            ch.hierarchy_mean_rms = mean_rms(skins[2].error);
            std::vector<double> area(skins.size()), total(skins.size(), 0.0);
            for (size_t i = 0; i < skins.size(); ++i) {
                area[i] = rd_area(skins[i].error, bits[i], until);
                for (double b : bits[i]) total[i] += b;
            }
            ch.reorder_area = area[0], ch.flatten_area = area[1], ch.hierarchy_area = area[2];
            ch.reorder_bits = total[0], ch.flatten_bits = total[1], ch.hierarchy_bits = total[2];
            best = 0;  // ties: reorder, then flatten
            for (size_t i = 1; i < skins.size(); ++i)
                if (area[i] < area[best]) best = i;
        }
    }
    ch.chosen = tried[best];
    if (choice) *choice = ch;
    return std::move(skins[best]);
}

}  // namespace progskin
