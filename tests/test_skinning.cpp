// skin_stream / skin_many (skinning.h) against a double-precision reference
// and SkinningJob::run, on every SIMD target Highway compiled that this CPU
// supports (each forced in turn), and their input validation.
#include <gtest/gtest.h>

#include <hwy/targets.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "skinning.h"

using namespace progskin;

namespace {

struct Mesh {
    std::vector<glm::vec3> pos, nrm;
    std::vector<uint16_t> joints;
    std::vector<float> weights;
    std::vector<Mat34> palette;
    int influences = 4;
};

// n vertices in [-1,1]^3, `influences` random joints among `bones`, random
// weights summing to 1 (some vertices with zero weights in the first slots or
// everywhere), a random rigid palette (rotation + translation in [-1,1]).
Mesh random_mesh(int n, int influences, int bones, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-1, 1), u01(0, 1);
    std::uniform_int_distribution<int> jb(0, bones - 1);
    Mesh m;
    m.influences = influences;
    for (int v = 0; v < n; ++v) {
        m.pos.push_back({u(rng), u(rng), u(rng)});
        m.nrm.push_back(glm::normalize(glm::vec3(u(rng), u(rng), u(rng)) + glm::vec3(0, 0, 1.8f)));
        float w[8], sum = 0;
        for (int i = 0; i < influences; ++i) sum += w[i] = u01(rng);
        if (v % 37 == 5) w[0] = 0, sum = 1;                            // a zero first weight
        if (v % 53 == 7) std::fill(w, w + influences, 0.0f), sum = 1;  // no weight at all
        for (int i = 0; i < influences; ++i) {
            m.joints.push_back(uint16_t(jb(rng)));
            m.weights.push_back(w[i] / sum);
        }
    }
    std::normal_distribution<double> g;
    for (int b = 0; b < bones; ++b) {
        const glm::dquat q = glm::normalize(glm::dquat(g(rng), g(rng), g(rng), g(rng)));
        glm::dmat4 t = glm::mat4_cast(q);
        t[3] = glm::dvec4(u(rng), u(rng), u(rng), 1);
        m.palette.push_back(Mat34::from_glm(t));
    }
    return m;
}

// Weight of slot s of vertex v as the stream stores it (dequantised; the last
// of K slots is 1 - the others), renormalised over the first k slots.
std::vector<double> stream_weights(const Mesh& m, size_t v, int K, int k, SkinWeightFormat f) {
    std::vector<double> w(static_cast<size_t>(K));
    float sum = 0;  // as build_skin_stream computes it, in float
    for (int s = 0; s < K; ++s) sum += m.weights[v * m.influences + s];
    double stored = 0;
    for (int s = 0; s < K - 1; ++s) {
        const float x = sum > 0 ? m.weights[v * m.influences + s] / sum : (s == 0 ? 1.0f : 0.0f);
        double q = x;
        if (f == SkinWeightFormat::U16) q = double(std::lround(std::clamp(x, 0.0f, 1.0f) * 65535.0f)) / 65535;
        if (f == SkinWeightFormat::U8) q = double(std::lround(std::clamp(x, 0.0f, 1.0f) * 255.0f)) / 255;
        stored += w[size_t(s)] = q;
    }
    w[size_t(K - 1)] = K == 1 ? 1.0 : 1.0 - stored;
    if (k < K) {
        double ks = 0;
        for (int s = 0; s < k; ++s) ks += w[size_t(s)];
        for (int s = 0; s < k; ++s) w[size_t(s)] = ks > 0 ? w[size_t(s)] / ks : (s == 0 ? 1.0 : 0.0);
    }
    w.resize(size_t(k));
    if (k == 1) w[0] = 1.0;
    return w;
}

// Double-precision skinning of the stream's own weights: the exact answer the
// kernel rounds. Normals unnormalised unless `unit`.
void reference(const Mesh& m, int K, int k, SkinWeightFormat f, bool unit, std::vector<glm::dvec3>& op,
               std::vector<glm::dvec3>& on) {
    op.assign(m.pos.size(), {});
    on.assign(m.pos.size(), {});
    for (size_t v = 0; v < m.pos.size(); ++v) {
        const std::vector<double> w = stream_weights(m, v, K, k, f);
        double M[12] = {};
        for (int s = 0; s < k; ++s)
            for (int c = 0; c < 12; ++c) M[c] += w[size_t(s)] * m.palette[m.joints[v * m.influences + s]].m[c];
        const glm::dvec3 p(m.pos[v]), n(m.nrm[v]);
        for (int r = 0; r < 3; ++r) {
            op[v][r] = M[r * 4] * p.x + M[r * 4 + 1] * p.y + M[r * 4 + 2] * p.z + M[r * 4 + 3];
            on[v][r] = M[r * 4] * n.x + M[r * 4 + 1] * n.y + M[r * 4 + 2] * n.z;
        }
        if (unit && glm::length(on[v]) > 0) on[v] = glm::normalize(on[v]);
    }
}

double max_err(const std::vector<glm::vec3>& a, const std::vector<glm::dvec3>& b) {
    double e = 0;
    for (size_t i = 0; i < a.size(); ++i) e = std::max(e, glm::length(glm::dvec3(a[i]) - b[i]));
    return e;
}

void list_targets_once(const std::vector<int64_t>& targets) {
    static bool listed = false;
    if (listed) return;
    listed = true;
    std::printf("SIMD targets tested:");
    for (int64_t t : targets) std::printf(" %s", hwy::TargetName(t));
    std::printf("\n");
}

// Runs f once per SIMD target compiled into the library and supported here,
// with skin_stream forced onto it; restores the normal dispatch afterwards.
template <class F>
void for_each_target(F&& f) {
    const std::vector<int64_t> targets = hwy::SupportedAndGeneratedTargets();
    ASSERT_FALSE(targets.empty());
    list_targets_once(targets);
    for (int64_t t : targets) {
        hwy::SetSupportedTargetsForTest(t);
        hwy::GetChosenTarget().Update(hwy::SupportedTargets());
        SCOPED_TRACE(hwy::TargetName(t));
        EXPECT_EQ(std::string(skin_simd_target()), hwy::TargetName(t));
        f(hwy::TargetName(t));
    }
    hwy::SetSupportedTargetsForTest(0);
    hwy::GetChosenTarget().Update(hwy::SupportedTargets());
}

// Rounding tolerance of the float kernel against the double reference, for
// positions and normals of unit-sized meshes and unit translations.
constexpr double kTol = 2e-5;

}  // namespace

TEST(SkinStream, MatchesReferenceOnEveryTarget) {
    for_each_target([](const char* target) {
        for (int K : {1, 2, 3, 4, 8})
            for (int bones : {64, 300}) {  // u8 and u16 joints
                for (int n : {0, 1, 3, 5, 16, 17, 35, 1001}) {
                    const Mesh m = random_mesh(n, K, bones, uint32_t(K * 1000 + n + bones));
                    std::vector<glm::vec3> p(static_cast<size_t>(n)), nr(static_cast<size_t>(n));
                    for (SkinWeightFormat f : {SkinWeightFormat::F32, SkinWeightFormat::U16, SkinWeightFormat::U8}) {
                        SkinStream st;
                        ASSERT_TRUE(build_skin_stream(
                            st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, K, K, m.palette, p, nr}, f));
                        EXPECT_EQ(st.u8_joints(), n == 0 || st.max_joint() < 256);
                        for (int k = 1; k <= K; ++k)
                            for (bool unit : {false, true}) {
                                SCOPED_TRACE(std::string(target) + " K=" + std::to_string(K) + " k=" +
                                             std::to_string(k) + " n=" + std::to_string(n) + " bones=" +
                                             std::to_string(bones) + " format=" + std::to_string(int(f)) +
                                             (unit ? " unit" : ""));
                                std::fill(p.begin(), p.end(), glm::vec3(99));
                                std::fill(nr.begin(), nr.end(), glm::vec3(99));
                                SkinRunOptions o;
                                o.max_influences = k;
                                o.renormalize = unit;
                                ASSERT_TRUE(skin_stream(st, m.palette, p, nr, o));
                                std::vector<glm::dvec3> rp, rn;
                                reference(m, K, k, f, unit, rp, rn);
                                EXPECT_LE(max_err(p, rp), kTol);
                                EXPECT_LE(max_err(nr, rn), kTol);
                                // Positions only (the kernel without normals).
                                std::vector<glm::vec3> p2(size_t(n), glm::vec3(99));
                                ASSERT_TRUE(skin_stream(st, m.palette, p2, {}, o));
                                EXPECT_EQ(p, p2);
                            }
                    }
                }
            }
    });
}

// The F32 stream against the scalar reference SkinningJob::run (which
// renormalises normals), and the quantisation error of U16/U8 weights.
TEST(SkinStream, AgreesWithSkinningJob) {
    for_each_target([](const char*) {
        for (int K : {1, 2, 4, 8}) {
            const Mesh m = random_mesh(777, K, 64, uint32_t(K));
            const size_t n = m.pos.size();
            std::vector<glm::vec3> p1(n), n1(n), p2(n), n2(n);
            for (int k = 1; k <= K; ++k) {
                SkinningJob sj{m.pos, m.nrm, m.joints, m.weights, K, k, m.palette, p1, n1};
                ASSERT_TRUE(sj.validate());
                sj.run();
                SkinStream st;
                ASSERT_TRUE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, K, K, m.palette, p2, n2},
                                              SkinWeightFormat::F32));
                SkinRunOptions o;
                o.max_influences = k;
                o.renormalize = true;
                ASSERT_TRUE(skin_stream(st, m.palette, p2, n2, o));
                double ep = 0, en = 0;
                for (size_t v = 0; v < n; ++v) {
                    ep = std::max(ep, double(glm::length(p1[v] - p2[v])));
                    en = std::max(en, double(glm::length(n1[v] - n2[v])));
                }
                EXPECT_LE(ep, kTol) << "K=" << K << " k=" << k;
                EXPECT_LE(en, kTol) << "K=" << K << " k=" << k;
                // Quantised weights: |dw| <= 0.5/65535 (U16) or 0.5/255 (U8) per stored slot and the
                // sum of those on the last; points move by at most sum |dw_i| * |M_i p - M_last p|,
                // |M_i p - M_last p| <= 2 (|p| + 1) < 5.5 here. (A run-time limit k < K divides
                // that by the kept weight sum, so this bound is for k == K.)
                for (SkinWeightFormat f : {SkinWeightFormat::U16, SkinWeightFormat::U8}) {
                    if (k < K) continue;
                    SkinStream q;
                    ASSERT_TRUE(build_skin_stream(q, SkinningJob{m.pos, {}, m.joints, m.weights, K, K, m.palette, p2, {}}, f));
                    ASSERT_TRUE(skin_stream(q, m.palette, p2, {}, o));
                    double e = 0;
                    for (size_t v = 0; v < n; ++v) e = std::max(e, double(glm::length(p1[v] - p2[v])));
                    const double dw = f == SkinWeightFormat::U16 ? 0.5 / 65535 : 0.5 / 255;
                    EXPECT_LE(e, 2 * (K - 1) * dw * 5.5 + kTol) << "K=" << K << " k=" << k << " format " << int(f);
                    static int printed = 0;  // once, on the first target
                    if (printed++ < 8)
                        std::printf("quantised weights %s, %d influences: max position error %.2e (bound %.2e)\n",
                                    f == SkinWeightFormat::U16 ? "U16" : "U8", K, e, 2 * (K - 1) * dw * 5.5);
                }
            }
        }
    });
}

TEST(SkinStream, RenormalisedNormalsAreUnit) {
    for_each_target([](const char* target) {
        Mesh m = random_mesh(4096, 4, 64, 99);
        for (size_t v = 3; v < m.nrm.size(); v += 101) m.nrm[v] = glm::vec3(0);  // zero normals stay zero
        std::vector<glm::vec3> p(m.pos.size()), nr(m.pos.size());
        SkinStream st;
        ASSERT_TRUE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, 4, 4, m.palette, p, nr}));
        SkinRunOptions o;
        o.renormalize = true;
        ASSERT_TRUE(skin_stream(st, m.palette, p, nr, o));
        double e = 0;
        for (size_t v = 0; v < nr.size(); ++v) {
            if (m.nrm[v] == glm::vec3(0)) {
                EXPECT_EQ(nr[v], glm::vec3(0));
                continue;
            }
            e = std::max(e, std::abs(double(glm::length(glm::dvec3(nr[v]))) - 1.0));
        }
        EXPECT_LE(e, 1e-6);  // rsqrt estimate + one Newton step
        std::printf("%s: renormalised normals, max | |n| - 1 | = %.2e\n", target, e);
    });
}

TEST(SkinStream, RefusesBadInput) {
    const Mesh m = random_mesh(20, 4, 8, 5);
    std::vector<glm::vec3> p(20), nr(20), short_out(19);
    SkinStream st;
    // build: span sizes, influence counts
    EXPECT_FALSE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, 5, 4, m.palette, p, nr}));
    EXPECT_FALSE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, 4, 0, m.palette, p, nr}));
    EXPECT_FALSE(build_skin_stream(st, SkinningJob{m.pos, short_out, m.joints, m.weights, 4, 4, m.palette, p, nr}));
    EXPECT_FALSE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, {m.joints.data(), 79}, m.weights, 4, 4, m.palette, p, nr}));
    EXPECT_EQ(st.count(), 0);
    ASSERT_TRUE(build_skin_stream(st, SkinningJob{m.pos, m.nrm, m.joints, m.weights, 4, 4, m.palette, p, nr}));
    // run: palette, outputs
    EXPECT_FALSE(skin_stream(st, {m.palette.data(), st.max_joint()}, p, nr));
    EXPECT_FALSE(skin_stream(st, m.palette, short_out, nr));
    EXPECT_FALSE(skin_stream(st, m.palette, p, short_out));
    EXPECT_TRUE(skin_stream(st, m.palette, p, nr));
    // normals asked of a stream without them
    SkinStream no_n;
    ASSERT_TRUE(build_skin_stream(no_n, SkinningJob{m.pos, {}, m.joints, m.weights, 4, 2, m.palette, p, {}}));
    EXPECT_FALSE(skin_stream(no_n, m.palette, p, nr));
    EXPECT_TRUE(skin_stream(no_n, m.palette, p, {}));
    // a default (never built) stream is refused; a built one of no vertices fits empty outputs
    EXPECT_FALSE(skin_stream(SkinStream{}, m.palette, p));
    EXPECT_FALSE(skin_stream(SkinStream{}, m.palette, {}));
    SkinStream none;
    ASSERT_TRUE(build_skin_stream(none, SkinningJob{{}, {}, {}, {}, 4, 4, m.palette, {}, {}}));
    EXPECT_TRUE(skin_stream(none, m.palette, {}));
    EXPECT_FALSE(skin_stream(none, m.palette, p));
    // skin_many validates every task before writing anything
    std::vector<glm::vec3> a(20, glm::vec3(7)), b(20, glm::vec3(7));
    std::vector<SkinTask> tasks = {{&st, m.palette, a, {}, {}}, {nullptr, m.palette, b, {}, {}}};
    EXPECT_FALSE(skin_many(tasks));
    EXPECT_EQ(a[0], glm::vec3(7));
    tasks[1].stream = &no_n;
    tasks[1].out_normals = nr;
    EXPECT_FALSE(skin_many(tasks));
    EXPECT_EQ(a[0], glm::vec3(7));
    tasks[1].out_normals = {};
    EXPECT_TRUE(skin_many(tasks));
    EXPECT_NE(a[0], glm::vec3(7));
    EXPECT_NE(b[0], glm::vec3(7));
}

TEST(SkinStream, ManyCharactersMatchOneByOne) {
    const Mesh m1 = random_mesh(500, 4, 24, 1), m2 = random_mesh(333, 8, 19, 2);
    std::vector<glm::vec3> p1(500), n1(500), p2(333), q1(500), r1(500), q2(333);
    SkinStream s1, s2;
    ASSERT_TRUE(build_skin_stream(s1, SkinningJob{m1.pos, m1.nrm, m1.joints, m1.weights, 4, 4, m1.palette, p1, n1}));
    ASSERT_TRUE(build_skin_stream(s2, SkinningJob{m2.pos, {}, m2.joints, m2.weights, 8, 8, m2.palette, p2, {}}));
    SkinRunOptions lim;
    lim.max_influences = 3;
    std::vector<SkinTask> tasks = {{&s1, m1.palette, p1, n1, {}}, {&s2, m2.palette, p2, {}, lim}};
    ASSERT_TRUE(skin_many(tasks));
    ASSERT_TRUE(skin_stream(s1, m1.palette, q1, r1));
    ASSERT_TRUE(skin_stream(s2, m2.palette, q2, {}, lim));
    EXPECT_EQ(p1, q1);
    EXPECT_EQ(n1, r1);
    EXPECT_EQ(p2, q2);
}
