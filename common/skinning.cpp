#include "skinning.h"

#include <algorithm>
#include <cmath>
#include <immintrin.h>

namespace progskin {

bool SkinningJob::validate() const {
    const size_t n = positions.size();
    if (influences < 1 || influences > 8 || max_influences < 1) return false;
    if (joints.size() != n * size_t(influences) || weights.size() != n * size_t(influences)) return false;
    if (out_positions.size() != n) return false;
    if (!out_normals.empty() && normals.size() != n) return false;
    if (!out_normals.empty() && out_normals.size() != n) return false;
    for (uint16_t j : joints)
        if (j >= palette.size()) return false;
    return !palette.empty();
}

void SkinningJob::run() const {
    const int I = influences, K = std::min(max_influences, influences);
    const bool do_normals = !out_normals.empty();
    for (size_t v = 0; v < positions.size(); ++v) {
        const uint16_t* jv = &joints[v * I];
        const float* wv = &weights[v * I];
        float sum = 0.0f;
        for (int i = 0; i < K; ++i) sum += wv[i];
        const float inv = sum > 0.0f ? 1.0f / sum : 0.0f;
        glm::vec3 p(0.0f), nrm(0.0f);
        if (inv == 0.0f) {
            p = palette[jv[0]].transform_point(positions[v]);
            if (do_normals) nrm = palette[jv[0]].transform_vector(normals[v]);
        } else {
            for (int i = 0; i < K; ++i) {
                const float w = wv[i] * inv;
                if (w == 0.0f) continue;
                const Mat34& m = palette[jv[i]];
                p += w * m.transform_point(positions[v]);
                if (do_normals) nrm += w * m.transform_vector(normals[v]);
            }
        }
        out_positions[v] = p;
        if (do_normals) {
            const float l = std::sqrt(glm::dot(nrm, nrm));
            out_normals[v] = l > 0.0f ? nrm / l : nrm;
        }
    }
}

// ---- packed SIMD skinning ----------------------------------------------

PackedSkin pack_skin(std::span<const glm::vec3> positions, std::span<const glm::vec3> normals,
                     std::span<const uint16_t> joints, std::span<const float> weights, int influences,
                     int max_influences) {
    PackedSkin p;
    p.count = int(positions.size());
    p.influences = std::clamp(max_influences, 1, influences);
    const size_t n = positions.size(), m = size_t(p.influences);
    p.pos.resize(n * 4);
    p.nrm.resize(n * 4);
    p.wgt.resize(n * m);
    p.jnt.resize(n * m);
    for (size_t v = 0; v < n; ++v) {
        const glm::vec3 nv = normals.empty() ? glm::vec3(0.0f) : normals[v];
        const float pr[4] = {positions[v].x, positions[v].y, positions[v].z, 1.0f};
        const float nr[4] = {nv.x, nv.y, nv.z, 0.0f};
        std::copy(pr, pr + 4, &p.pos[v * 4]);
        std::copy(nr, nr + 4, &p.nrm[v * 4]);
        float sum = 0.0f;
        for (size_t s = 0; s < m; ++s) sum += weights[v * influences + s];
        for (size_t s = 0; s < m; ++s) {
            const float w = weights[v * influences + s];
            p.wgt[v * m + s] = sum > 0.0f ? w / sum : (s == 0 ? 1.0f : 0.0f);
            p.jnt[v * m + s] = joints[v * influences + s];
            p.max_joint = std::max(p.max_joint, p.jnt[v * m + s]);
        }
    }
    return p;
}

namespace {

// One vertex: blend the rows of its matrices, transform position and normal.
// FMA selects fused multiply-add (compiled for AVX2+FMA) or mul+add (SSE2).
#define PROGSKIN_SKIN_KERNEL(NAME, ATTR, MADD)                                                                  \
    template <int S>                                                                                             \
    ATTR void NAME(const PackedSkin& p, const Mat34* __restrict pal, glm::vec3* __restrict op,                   \
                   glm::vec3* __restrict on) {                                                                   \
        const int ns = S > 0 ? S : p.influences;                                                                 \
        const float* __restrict pos = p.pos.data();                                                              \
        const float* __restrict nrm = p.nrm.data();                                                              \
        const float* __restrict wgt = p.wgt.data();                                                              \
        const uint16_t* __restrict jnt = p.jnt.data();                                                           \
        const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));                                      \
        for (int v = 0; v < p.count; ++v) {                                                                      \
            const float* m0 = pal[jnt[0]].m;                                                                     \
            __m128 w = _mm_set1_ps(wgt[0]);                                                                      \
            __m128 r0 = _mm_mul_ps(w, _mm_loadu_ps(m0));                                                         \
            __m128 r1 = _mm_mul_ps(w, _mm_loadu_ps(m0 + 4));                                                     \
            __m128 r2 = _mm_mul_ps(w, _mm_loadu_ps(m0 + 8));                                                     \
            for (int s = 1; s < ns; ++s) {                                                                       \
                const float* m = pal[jnt[s]].m;                                                                  \
                w = _mm_set1_ps(wgt[s]);                                                                         \
                r0 = MADD(w, _mm_loadu_ps(m), r0);                                                               \
                r1 = MADD(w, _mm_loadu_ps(m + 4), r1);                                                           \
                r2 = MADD(w, _mm_loadu_ps(m + 8), r2);                                                           \
            }                                                                                                    \
            const __m128 x = _mm_loadu_ps(pos);                                                                  \
            __m128 a = _mm_mul_ps(r0, x), b = _mm_mul_ps(r1, x), c = _mm_mul_ps(r2, x);                          \
            __m128 ab = _mm_hadd_ps(a, b), cc = _mm_hadd_ps(c, c);                                               \
            alignas(16) float res[4];                                                                            \
            _mm_store_ps(res, _mm_hadd_ps(ab, cc));                                                              \
            op[v] = glm::vec3(res[0], res[1], res[2]);                                                           \
            if (on) {                                                                                            \
                const __m128 nx = _mm_loadu_ps(nrm);                                                             \
                a = _mm_mul_ps(r0, nx), b = _mm_mul_ps(r1, nx), c = _mm_mul_ps(r2, nx);                          \
                ab = _mm_hadd_ps(a, b), cc = _mm_hadd_ps(c, c);                                                  \
                __m128 t = _mm_and_ps(_mm_hadd_ps(ab, cc), xyz);                                                      \
                __m128 sq = _mm_mul_ps(t, t);                                                                    \
                sq = _mm_hadd_ps(sq, sq);                                                                        \
                sq = _mm_hadd_ps(sq, sq);                                                                        \
                const float len2 = _mm_cvtss_f32(sq);                                                            \
                if (len2 > 0.0f) t = _mm_div_ps(t, _mm_sqrt_ps(_mm_set1_ps(len2)));                              \
                _mm_store_ps(res, t);                                                                            \
                on[v] = glm::vec3(res[0], res[1], res[2]);                                                       \
            }                                                                                                    \
            pos += 4, nrm += 4, wgt += ns, jnt += ns;                                                            \
        }                                                                                                        \
    }

#define PROGSKIN_MADD_SSE(a, b, c) _mm_add_ps(_mm_mul_ps(a, b), c)
#define PROGSKIN_MADD_FMA(a, b, c) _mm_fmadd_ps(a, b, c)
PROGSKIN_SKIN_KERNEL(skin_sse, __attribute__((target("sse3"))), PROGSKIN_MADD_SSE)
PROGSKIN_SKIN_KERNEL(skin_fma, __attribute__((target("avx2,fma"))), PROGSKIN_MADD_FMA)

template <int S>
void skin_dispatch(const PackedSkin& p, const Mat34* pal, glm::vec3* op, glm::vec3* on) {
    static const bool fma = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    if (fma)
        skin_fma<S>(p, pal, op, on);
    else
        skin_sse<S>(p, pal, op, on);
}

}  // namespace

bool skin_packed(const PackedSkin& p, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
                 std::span<glm::vec3> out_normals) {
    if (palette.size() <= p.max_joint || out_positions.size() != size_t(p.count)) return false;
    if (!out_normals.empty() && out_normals.size() != size_t(p.count)) return false;
    glm::vec3* on = out_normals.empty() ? nullptr : out_normals.data();
    switch (p.influences) {
        case 1: skin_dispatch<1>(p, palette.data(), out_positions.data(), on); break;
        case 2: skin_dispatch<2>(p, palette.data(), out_positions.data(), on); break;
        case 4: skin_dispatch<4>(p, palette.data(), out_positions.data(), on); break;
        default: skin_dispatch<0>(p, palette.data(), out_positions.data(), on); break;
    }
    return true;
}

}  // namespace progskin
