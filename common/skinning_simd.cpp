// skinning_simd.cpp — skin_stream and skin_many (skinning.h), compiled once
// per x86 target (SSSE3, SSE4, AVX2, AVX-512, scalar) by Google Highway and
// dispatched at run time to the best one the CPU supports.
//
// Per group of 4 vertices: each vertex's 3x4 matrix is blended row-wise in
// kG vectors (AVX-512: rows 0-2 in one 16-lane vector; AVX2: rows 0|1 and
// 1|2; SSE4: one row each) by one load and one FMA per kept slot, with the
// weights converted to floats one block of 16 vertices ahead. Multiplying by
// (x, y, z, 1) (or (nx, ny, nz, 0)) and summing each 128-bit block gives one
// output coordinate; SumBlocks4 does that for 4 vertices at once (a 4x4
// transpose folded into the adds), and the block sums are permuted back to
// xyz xyz xyz xyz. No gathers: on Zen 4 a 16-lane gather moves about one
// element per cycle, which made the one-lane-per-vertex form 5x slower.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "skinning_simd.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep

#include <hwy/highway.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <type_traits>

#include "skinning.h"

#ifndef PROGSKIN_SKINNING_SIMD_ONCE
#define PROGSKIN_SKINNING_SIMD_ONCE
namespace progskin {
// The stream's arrays for the kernels (SkinStream's friend).
struct SkinStreamAccess {
    static const float* positions(const SkinStream& s) { return s.positions_.data(); }
    static const float* normals(const SkinStream& s) { return s.normals_.data(); }
    static const uint8_t* joints8(const SkinStream& s) { return s.joints8_.data(); }
    static const uint16_t* joints16(const SkinStream& s) { return s.joints16_.data(); }
    static const uint8_t* weights(const SkinStream& s) { return s.weights_.data(); }
    // The arrays match the header (always, for a stream from build_skin_stream).
    static bool consistent(const SkinStream& s) {
        if (s.count_ < 0 || s.influences_ < 1 || s.influences_ > 8 || int(s.weight_format_) > 2) return false;
        const size_t B = kSkinBlock, padded = (size_t(s.count_) + B - 1) / B * B, K = size_t(s.influences_);
        if (s.positions_.size() != padded * 3 + 4) return false;
        if (!s.normals_.empty() && s.normals_.size() != padded * 3 + 4) return false;
        if (s.joints8_.size() + s.joints16_.size() != padded * K) return false;
        const size_t wsize = s.weight_format_ == SkinWeightFormat::F32 ? 4 : s.weight_format_ == SkinWeightFormat::U16 ? 2 : 1;
        return s.weights_.size() == padded * (K - 1) * wsize;
    }
};
namespace {
struct SkinArgs {
    const SkinStream* s;
    const float* palette;  // Mat34 rows: 12 floats per joint (u16 joints), 16 (u8: copied, 64-byte aligned)
    float* out_p;          // count * 3
    float* out_n;          // count * 3 or null
    int m;                 // slots used, 1..s->influences
    bool renormalize;
};
}  // namespace
}  // namespace progskin
#endif

HWY_BEFORE_NAMESPACE();
namespace progskin {
namespace HWY_NAMESPACE {
namespace {
namespace hn = hwy::HWY_NAMESPACE;

using DF = hn::CappedTag<float, kSkinBlock>;
using DI = hn::RebindToSigned<DF>;
using DU = hn::RebindToUnsigned<DF>;
using VF = hn::Vec<DF>;
using VI = hn::Vec<DI>;

#if HWY_TARGET == HWY_SCALAR
// No 128-bit vectors: the same arithmetic one vertex at a time.
template <class JT, int WF, bool kNormals>
HWY_NOINLINE void SkinT(const SkinArgs& a) {
    const SkinStream& st = *a.s;
    const size_t B = kSkinBlock, n = size_t(st.count());
    const int K = st.influences(), m = a.m;
    const JT* J;
    if constexpr (sizeof(JT) == 1) J = SkinStreamAccess::joints8(st);
    else J = SkinStreamAccess::joints16(st);
    const uint8_t* W = SkinStreamAccess::weights(st);
    for (size_t v = 0; v < n; ++v) {
        const size_t b0 = v / B * B, o = v % B;
        float w[8], sum = 0.0f;
        for (int s = 0; s < m && s < K - 1; ++s) {
            const size_t i = b0 * size_t(K - 1) + size_t(s) * B + o;
            if constexpr (WF == 0) std::memcpy(&w[s], W + i * 4, 4);
            else if constexpr (WF == 1) {
                uint16_t q;
                std::memcpy(&q, W + i * 2, 2);
                w[s] = float(q) * (1.0f / 65535.0f);
            } else w[s] = float(W[i]) * (1.0f / 255.0f);
            sum += w[s];
        }
        if (m == K) {
            w[K - 1] = 1.0f - sum;
        } else {
            const float inv = sum > 0.0f ? 1.0f / sum : 0.0f;
            for (int s = 0; s < m; ++s) w[s] *= inv;
            if (!(sum > 0.0f)) w[0] = 1.0f;
        }
        if (m == 1) w[0] = 1.0f;
        float M[12] = {};
        for (int s = 0; s < m; ++s) {
            const float* r = a.palette + size_t(J[b0 * size_t(K) + size_t(s) * B + o]) * 12;
            for (int c = 0; c < 12; ++c) M[c] += w[s] * r[c];
        }
        const float* p = SkinStreamAccess::positions(st) + v * 3;
        for (int r = 0; r < 3; ++r)
            a.out_p[v * 3 + r] = M[r * 4] * p[0] + M[r * 4 + 1] * p[1] + M[r * 4 + 2] * p[2] + M[r * 4 + 3];
        if constexpr (kNormals) {
            const float* q = SkinStreamAccess::normals(st) + v * 3;
            float o3[3];
            for (int r = 0; r < 3; ++r) o3[r] = M[r * 4] * q[0] + M[r * 4 + 1] * q[1] + M[r * 4 + 2] * q[2];
            float l2 = o3[0] * o3[0] + o3[1] * o3[1] + o3[2] * o3[2];
            const float sc = a.renormalize && l2 > 0.0f ? 1.0f / std::sqrt(l2) : 1.0f;
            for (int r = 0; r < 3; ++r) a.out_n[v * 3 + r] = o3[r] * sc;
        }
    }
}
#else
// Weight of element i of the weight stream (F32 = 0, U16 = 1, U8 = 2), L lanes.
template <int WF>
HWY_INLINE VF LoadWeight(const uint8_t* w, size_t i) {
    const DF df;
    if constexpr (WF == 0) {
        return hn::LoadU(df, reinterpret_cast<const float*>(w) + i);
    } else if constexpr (WF == 1) {
        const hn::Rebind<uint16_t, DF> d16;
        const VI q = hn::BitCast(DI(), hn::PromoteTo(DU(), hn::LoadU(d16, reinterpret_cast<const uint16_t*>(w) + i)));
        return hn::Mul(hn::ConvertTo(df, q), hn::Set(df, 1.0f / 65535.0f));
    } else {
        const hn::Rebind<uint8_t, DF> d8;
        const VI q = hn::BitCast(DI(), hn::PromoteTo(DU(), hn::LoadU(d8, w + i)));
        return hn::Mul(hn::ConvertTo(df, q), hn::Set(df, 1.0f / 255.0f));
    }
}

// The m weights of the 16 vertices of a block as floats, slot-major: the last
// of all K slots is 1 - the others; fewer slots are renormalised as
// SkinningJob does (a vertex whose kept weights sum to 0 keeps slot 0 at 1).
template <int WF>
HWY_INLINE void BlockWeights(const uint8_t* W, size_t wb, int K, int m, float (*wf)[kSkinBlock]) {
    const DF df;
    const size_t L = hn::Lanes(df);
    const VF one = hn::Set(df, 1.0f), zero = hn::Zero(df);
    for (size_t o = 0; o < kSkinBlock; o += L) {
        VF w[8], sum = zero;
        if (m == K) {
            for (int s = 0; s < K - 1; ++s) sum = hn::Add(sum, w[s] = LoadWeight<WF>(W, wb + size_t(s) * kSkinBlock + o));
            w[K - 1] = hn::Sub(one, sum);
        } else {
            for (int s = 0; s < m; ++s) sum = hn::Add(sum, w[s] = LoadWeight<WF>(W, wb + size_t(s) * kSkinBlock + o));
            const auto pos = hn::Gt(sum, zero);
            const VF inv = hn::IfThenElseZero(pos, hn::Div(one, hn::IfThenElse(pos, sum, one)));
            for (int s = 0; s < m; ++s) w[s] = hn::Mul(w[s], inv);
            w[0] = hn::IfThenElse(pos, w[0], one);
        }
        for (int s = 0; s < m; ++s) hn::Store(w[s], df, &wf[s][o]);
    }
}

// Per 128-bit block: (sum of a0's block, of a1's, of a2's, of a3's).
HWY_INLINE VF SumBlocks4(VF a0, VF a1, VF a2, VF a3) {
    const DF df;
    const hn::Repartition<uint64_t, DF> d64;
    const VF u0 = hn::Add(hn::InterleaveLower(df, a0, a1), hn::InterleaveUpper(df, a0, a1));
    const VF u1 = hn::Add(hn::InterleaveLower(df, a2, a3), hn::InterleaveUpper(df, a2, a3));
    const auto b0 = hn::BitCast(d64, u0), b1 = hn::BitCast(d64, u1);
    return hn::Add(hn::BitCast(df, hn::InterleaveLower(d64, b0, b1)), hn::BitCast(df, hn::InterleaveUpper(d64, b0, b1)));
}

// 1 / sqrt(l2) by the estimate and one Newton step. l2 is clamped to 1e-30
// (not lower: 0.5 l2 must not be denormal, which is slow), so a zero vector is
// scaled by a finite factor and stays zero without masks; a vector shorter than
// 1e-15 comes out shorter than 1.
template <class D, class V>
HWY_INLINE V RsqrtNewton(D d, V l2) {
    l2 = hn::Max(l2, hn::Set(d, 1e-30f));
    const V r = hn::ApproximateReciprocalSqrt(l2);
    return hn::Mul(r, hn::NegMulAdd(hn::Mul(hn::Set(d, 0.5f), l2), hn::Mul(r, r), hn::Set(d, 1.5f)));
}

// Vectors per 3x4 matrix: 1 (16 lanes: rows in blocks 0-2), 2 (8 lanes: rows
// 0|1 and 1|2), 3 (4 lanes: one row each).
constexpr size_t kLanes = hn::MaxLanes(DF());
constexpr int kG = kLanes >= 16 ? 1 : kLanes == 8 ? 2 : 3;
#ifndef HWY_UNROLL_G
#define HWY_UNROLL_G _Pragma("GCC unroll 3")
#endif
static_assert(kLanes >= 4, "skinning needs 128-bit vectors");

template <bool kAligned>
HWY_INLINE void LoadMatrix(const float* m, VF* M) {
    const DF df;
    if constexpr (kG == 1) {
        if constexpr (kAligned) M[0] = hn::Load(df, m);  // 16 floats, the last 4 zero
        else M[0] = hn::MaskedLoad(hn::FirstN(df, 12), df, m);
    } else if constexpr (kG == 2) {
        M[0] = hn::LoadU(df, m), M[1] = hn::LoadU(df, m + 4);
    } else {
        M[0] = hn::LoadU(df, m), M[1] = hn::LoadU(df, m + 4), M[2] = hn::LoadU(df, m + 8);
    }
}

// Writes 4 vertices (cnt <= 4 of them) of the block sums R (rows x, y, z as
// above) interleaved to out, renormalising first when asked.
template <int G = kG>
HWY_INLINE void Store4(const VF* R, float* out, size_t cnt, bool room16, bool renormalize) {
    const DF df;
    if constexpr (G == 1) {
        VF r = R[0];  // blocks: x(v0..3) y(v0..3) z(v0..3) -
        if (renormalize) {
            alignas(64) static constexpr int32_t kY[16] = {4, 5, 6, 7, 8, 9, 10, 11, 0, 1, 2, 3, 12, 13, 14, 15};
            alignas(64) static constexpr int32_t kZ[16] = {8, 9, 10, 11, 0, 1, 2, 3, 4, 5, 6, 7, 12, 13, 14, 15};
            const VF y = hn::TableLookupLanes(r, hn::SetTableIndices(df, kY));
            const VF z = hn::TableLookupLanes(r, hn::SetTableIndices(df, kZ));
            r = hn::Mul(r, RsqrtNewton(df, hn::MulAdd(r, r, hn::MulAdd(y, y, hn::Mul(z, z)))));
        }
        alignas(64) static constexpr int32_t kAoS[16] = {0, 4, 8, 1, 5, 9, 2, 6, 10, 3, 7, 11, 12, 13, 14, 15};
        const VF o = hn::TableLookupLanes(r, hn::SetTableIndices(df, kAoS));
        if (room16) hn::StoreU(o, df, out);
        else hn::BlendedStore(o, hn::FirstN(df, cnt * 3), df, out);
    } else {
        const hn::Full128<float> d4;
        hn::Vec<decltype(d4)> x, y, z;
        // DF and R under a type that depends on G, so that the branch not
        // taken is not checked (clang checks a discarded branch's
        // non-dependent code, where the vector widths do not match).
        using DG = std::conditional_t<G == 2, DF, DF>;
        const hn::Vec<DG>* RG = R;
        if constexpr (G == 2) {
            const hn::Half<DG> dh;
            x = hn::LowerHalf(dh, RG[0]), y = hn::UpperHalf(dh, RG[0]), z = hn::UpperHalf(dh, RG[1]);
        } else {
            x = RG[0], y = RG[1], z = RG[2];
        }
        if (renormalize) {
            const auto r = RsqrtNewton(d4, hn::MulAdd(x, x, hn::MulAdd(y, y, hn::Mul(z, z))));
            x = hn::Mul(x, r), y = hn::Mul(y, r), z = hn::Mul(z, r);
        }
        if (cnt == 4) {
            hn::StoreInterleaved3(x, y, z, d4, out);
        } else {
            alignas(16) float tmp[12];
            hn::StoreInterleaved3(x, y, z, d4, tmp);
            std::memcpy(out, tmp, cnt * 3 * sizeof(float));
        }
    }
}

// The joints of 4 consecutive vertices of one slot in one integer load.
template <class JT>
HWY_INLINE uint64_t Joints4(const JT* j) {
    if constexpr (sizeof(JT) == 1) {
        uint32_t x;
        std::memcpy(&x, j, 4);
        return x;
    } else {
        uint64_t x;
        std::memcpy(&x, j, 8);
        return x;
    }
}
template <class JT>
HWY_INLINE size_t JointOf(uint64_t j4, size_t i) {
    return size_t(j4 >> (i * 8 * sizeof(JT))) & ((size_t(1) << (8 * sizeof(JT))) - 1);
}

template <class JT, int WF, bool kNormals>
HWY_NOINLINE void SkinT(const SkinArgs& a) {
    const DF df;
    const DU du;
    const auto Joint = [](uint64_t j4, size_t i) { return JointOf<JT>(j4, i); };
    constexpr size_t B = kSkinBlock;
    const size_t n = size_t(a.s->count());
    const int K = a.s->influences(), m = a.m;
    const JT* J;
    if constexpr (sizeof(JT) == 1) J = SkinStreamAccess::joints8(*a.s);
    else J = SkinStreamAccess::joints16(*a.s);
    const uint8_t* W = SkinStreamAccess::weights(*a.s);
    const float* P = SkinStreamAccess::positions(*a.s);
    const float* N = SkinStreamAccess::normals(*a.s);
    const float* pal = a.palette;
    constexpr bool kAligned = sizeof(JT) == 1;  // SkinRun copied the palette to 64-byte rows
    constexpr size_t stride = kAligned ? 16 : 12;
    const VF one = hn::Set(df, 1.0f);
    // Lane 3 of every block: w = 1 for positions, 0 for normals.
    const auto wlane = hn::RebindMask(df, hn::Eq(hn::And(hn::Iota(du, 0), hn::Set(du, 3)), hn::Set(du, 3)));
    // Weights as floats, one block ahead of their use: the stores have left the
    // store queue by the time the broadcast loads read them.
    HWY_ALIGN float wf[2][8][B];
    if (m > 1) BlockWeights<WF>(W, 0, K, m, wf[0]);
    for (size_t b0 = 0; b0 < n; b0 += B) {
        const JT* jb = J + b0 * size_t(K);
        const float(*w)[B] = wf[(b0 / B) & 1];
        if (m > 1 && b0 + B < n) BlockWeights<WF>(W, (b0 + B) * size_t(K - 1), K, m, wf[((b0 / B) + 1) & 1]);
        const size_t bend = std::min(n - b0, B);
        for (size_t q = 0; q < bend; q += 4) {
            // Blend the matrices of 4 vertices, slot by slot (4 independent FMA chains).
            VF M[4][kG];
            uint64_t j4 = Joints4(jb + q);
#pragma GCC unroll 4
            for (size_t i = 0; i < 4; ++i) LoadMatrix<kAligned>(pal + Joint(j4, i) * stride, M[i]);
            if (m == 2 && K == 2) {
                // Two slots, w1 = 1 - w0: M1 + w0 (M0 - M1), one weight per vertex.
                j4 = Joints4(jb + B + q);
#pragma GCC unroll 4
                for (size_t i = 0; i < 4; ++i) {
                    VF M1[kG];
                    LoadMatrix<kAligned>(pal + Joint(j4, i) * stride, M1);
                    const VF w0 = hn::Set(df, w[0][q + i]);
                    HWY_UNROLL_G for (int g = 0; g < kG; ++g) M[i][g] = hn::MulAdd(w0, hn::Sub(M[i][g], M1[g]), M1[g]);
                }
            } else if (m > 1) {
#pragma GCC unroll 4
                for (size_t i = 0; i < 4; ++i) {
                    const VF w0 = hn::Set(df, w[0][q + i]);
                    HWY_UNROLL_G for (int g = 0; g < kG; ++g) M[i][g] = hn::Mul(w0, M[i][g]);
                }
                for (int s = 1; s < m; ++s) {
                    j4 = Joints4(jb + size_t(s) * B + q);
#pragma GCC unroll 4
                    for (size_t i = 0; i < 4; ++i) {
                        VF Ms[kG];
                        LoadMatrix<kAligned>(pal + Joint(j4, i) * stride, Ms);
                        const VF ws = hn::Set(df, w[s][q + i]);
                        HWY_UNROLL_G for (int g = 0; g < kG; ++g) M[i][g] = hn::MulAdd(ws, Ms[g], M[i][g]);
                    }
                }
            }
            VF A[4][kG], AN[4][kG];
#pragma GCC unroll 4
            for (size_t i = 0; i < 4; ++i) {
                const size_t v = b0 + q + i;
                const VF p = hn::IfThenElse(wlane, one, hn::LoadDup128(df, P + v * 3));
                HWY_UNROLL_G for (int g = 0; g < kG; ++g) A[i][g] = hn::Mul(M[i][g], p);
                if constexpr (kNormals) {
                    const VF nv = hn::IfThenZeroElse(wlane, hn::LoadDup128(df, N + v * 3));
                    HWY_UNROLL_G for (int g = 0; g < kG; ++g) AN[i][g] = hn::Mul(M[i][g], nv);
                }
            }
            const size_t v0 = b0 + q, cnt = std::min<size_t>(4, n - v0);
            const bool room16 = v0 + 6 <= n;  // 16 floats from v0 * 3 stay inside the output
            VF R[kG];
            HWY_UNROLL_G for (int g = 0; g < kG; ++g) R[g] = SumBlocks4(A[0][g], A[1][g], A[2][g], A[3][g]);
            Store4(R, a.out_p + v0 * 3, cnt, room16, false);
            if constexpr (kNormals) {
                HWY_UNROLL_G for (int g = 0; g < kG; ++g) R[g] = SumBlocks4(AN[0][g], AN[1][g], AN[2][g], AN[3][g]);
                Store4(R, a.out_n + v0 * 3, cnt, room16, a.renormalize);
            }
        }
    }
}

#endif  // HWY_TARGET == HWY_SCALAR

}  // namespace

void SkinRun(const SkinArgs& args) {
#if HWY_TARGET != HWY_SCALAR
    // Small palettes (every u8-joint skin) are copied to 64-byte rows first so
    // that no matrix load splits a cache line (half of them do at 48 bytes).
    alignas(64) float aligned[256 * 16];
    SkinArgs a = args;
    if (a.s->u8_joints()) {  // max_joint < 256
        for (size_t j = 0; j <= a.s->max_joint(); ++j) {
            std::memcpy(aligned + j * 16, a.palette + j * 12, 12 * sizeof(float));
            std::memset(aligned + j * 16 + 12, 0, 4 * sizeof(float));
        }
        a.palette = aligned;
    }
#else
    const SkinArgs& a = args;
#endif
    const bool nrm = a.out_n != nullptr;
    const int wf = int(a.s->weight_format());
#define PROGSKIN_SKIN_CASE(JT, WF)              \
    if (wf == WF) {                             \
        if (nrm) SkinT<JT, WF, true>(a);        \
        else SkinT<JT, WF, false>(a);           \
        return;                                 \
    }
    if (a.s->u8_joints()) {
        PROGSKIN_SKIN_CASE(uint8_t, 0)
        PROGSKIN_SKIN_CASE(uint8_t, 1)
        PROGSKIN_SKIN_CASE(uint8_t, 2)
    } else {
        PROGSKIN_SKIN_CASE(uint16_t, 0)
        PROGSKIN_SKIN_CASE(uint16_t, 1)
        PROGSKIN_SKIN_CASE(uint16_t, 2)
    }
#undef PROGSKIN_SKIN_CASE
}

const char* SkinTargetName() { return hwy::TargetName(HWY_TARGET); }

}  // namespace HWY_NAMESPACE
}  // namespace progskin
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace progskin {
static_assert(sizeof(glm::vec3) == 3 * sizeof(float) && sizeof(Mat34) == 12 * sizeof(float),
              "the kernels read vec3 and Mat34 arrays as floats");
HWY_EXPORT(SkinRun);
HWY_EXPORT(SkinTargetName);

namespace {
bool valid(const SkinStream& s, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
           std::span<glm::vec3> out_normals) {
    if (!SkinStreamAccess::consistent(s)) return false;
    if (palette.size() <= s.max_joint() || out_positions.size() != size_t(s.count())) return false;
    if (!out_normals.empty() && (out_normals.size() != size_t(s.count()) || !s.has_normals())) return false;
    return true;
}
}  // namespace

bool skin_stream(const SkinStream& s, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
                 std::span<glm::vec3> out_normals, const SkinRunOptions& options) {
    if (!valid(s, palette, out_positions, out_normals)) return false;
    const int m = options.max_influences <= 0 ? s.influences() : std::min(options.max_influences, s.influences());
    if (s.count() == 0) return true;
    const SkinArgs a{&s, reinterpret_cast<const float*>(palette.data()), reinterpret_cast<float*>(out_positions.data()),
                     out_normals.empty() ? nullptr : reinterpret_cast<float*>(out_normals.data()), m,
                     options.renormalize};
    HWY_DYNAMIC_DISPATCH(SkinRun)(a);
    return true;
}

bool skin_many(std::span<const SkinTask> tasks) {
    for (const SkinTask& t : tasks)
        if (!t.stream || !valid(*t.stream, t.palette, t.out_positions, t.out_normals)) return false;
    for (const SkinTask& t : tasks) skin_stream(*t.stream, t.palette, t.out_positions, t.out_normals, t.options);
    return true;
}

const char* skin_simd_target() { return HWY_DYNAMIC_DISPATCH(SkinTargetName)(); }

}  // namespace progskin
#endif  // HWY_ONCE
