#include "skinning.h"

#include <algorithm>
#include <cmath>

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

// ---- packed SoA skinning -------------------------------------------------
// Layout per block of 8 vertices: pos[3][8], nrm[3][8], then for each slot s:
// jnt[s][8], wgt[s][8]. Weights are renormalised over the packed slots at pack
// time. Padding lanes have weight 1 on joint 0 and position 0.

constexpr int kLanes = 8;

PackedSkin pack_skin(std::span<const glm::vec3> positions, std::span<const glm::vec3> normals,
                     std::span<const uint16_t> joints, std::span<const float> weights, int influences,
                     int max_influences) {
    PackedSkin p;
    p.count = int(positions.size());
    p.influences = std::clamp(max_influences, 1, influences);
    const size_t blocks = (positions.size() + kLanes - 1) / kLanes;
    p.pos.assign(blocks * 3 * kLanes, 0.0f);
    p.nrm.assign(blocks * 3 * kLanes, 0.0f);
    p.wgt.assign(blocks * size_t(p.influences) * kLanes, 0.0f);
    p.jnt.assign(blocks * size_t(p.influences) * kLanes, 0);
    for (size_t v = 0; v < positions.size(); ++v) {
        const size_t b = v / kLanes, l = v % kLanes;
        for (int c = 0; c < 3; ++c) {
            p.pos[(b * 3 + c) * kLanes + l] = positions[v][c];
            p.nrm[(b * 3 + c) * kLanes + l] = normals.empty() ? 0.0f : normals[v][c];
        }
        float sum = 0.0f;
        for (int s = 0; s < p.influences; ++s) sum += weights[v * influences + s];
        for (int s = 0; s < p.influences; ++s) {
            float w = weights[v * influences + s];
            w = sum > 0.0f ? w / sum : (s == 0 ? 1.0f : 0.0f);
            p.wgt[(b * p.influences + s) * kLanes + l] = w;
            p.jnt[(b * p.influences + s) * kLanes + l] = joints[v * influences + s];
            p.max_joint = std::max(p.max_joint, joints[v * influences + s]);
        }
    }
    for (size_t v = positions.size(); v < blocks * kLanes; ++v)  // padding lanes
        p.wgt[((v / kLanes) * p.influences) * kLanes + v % kLanes] = 1.0f;
    return p;
}

// Blend the slot matrices of 8 lanes into acc[12][8], then transform. The
// per-lane loops have no dependencies so the compiler vectorises them.
template <int S>
static void skin_block(const float* __restrict pos, const float* __restrict nrm, const uint16_t* __restrict jnt,
                       const float* __restrict wgt, int slots, const Mat34* __restrict pal, float* __restrict out_p,
                       float* __restrict out_n) {
    const int ns = S > 0 ? S : slots;
    alignas(32) float acc[12][kLanes];
    for (int e = 0; e < 12; ++e)
        for (int l = 0; l < kLanes; ++l) acc[e][l] = 0.0f;
    for (int s = 0; s < ns; ++s) {
        const uint16_t* js = jnt + s * kLanes;
        const float* ws = wgt + s * kLanes;
        for (int e = 0; e < 12; ++e)
            for (int l = 0; l < kLanes; ++l) acc[e][l] += ws[l] * pal[js[l]].m[e];
    }
    const float* px = pos;
    const float* py = pos + kLanes;
    const float* pz = pos + 2 * kLanes;
    for (int r = 0; r < 3; ++r)
        for (int l = 0; l < kLanes; ++l)
            out_p[r * kLanes + l] =
                acc[r * 4][l] * px[l] + acc[r * 4 + 1][l] * py[l] + acc[r * 4 + 2][l] * pz[l] + acc[r * 4 + 3][l];
    if (out_n) {
        const float* nx = nrm;
        const float* ny = nrm + kLanes;
        const float* nz = nrm + 2 * kLanes;
        float o[3][kLanes];
        for (int r = 0; r < 3; ++r)
            for (int l = 0; l < kLanes; ++l)
                o[r][l] = acc[r * 4][l] * nx[l] + acc[r * 4 + 1][l] * ny[l] + acc[r * 4 + 2][l] * nz[l];
        for (int l = 0; l < kLanes; ++l) {
            const float len2 = o[0][l] * o[0][l] + o[1][l] * o[1][l] + o[2][l] * o[2][l];
            const float inv = len2 > 0.0f ? 1.0f / std::sqrt(len2) : 0.0f;
            for (int r = 0; r < 3; ++r) out_n[r * kLanes + l] = o[r][l] * inv;
        }
    }
}

template <int S>
static void skin_all(const PackedSkin& p, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
                     std::span<glm::vec3> out_normals) {
    const size_t blocks = (size_t(p.count) + kLanes - 1) / kLanes;
    const bool normals = !out_normals.empty();
    alignas(32) float op[3][kLanes], on[3][kLanes];
    for (size_t b = 0; b < blocks; ++b) {
        skin_block<S>(&p.pos[b * 3 * kLanes], &p.nrm[b * 3 * kLanes], &p.jnt[b * p.influences * kLanes],
                      &p.wgt[b * p.influences * kLanes], p.influences, palette.data(), &op[0][0],
                      normals ? &on[0][0] : nullptr);
        const size_t first = b * kLanes;
        const size_t n = std::min<size_t>(kLanes, size_t(p.count) - first);
        for (size_t l = 0; l < n; ++l) {
            out_positions[first + l] = {op[0][l], op[1][l], op[2][l]};
            if (normals) out_normals[first + l] = {on[0][l], on[1][l], on[2][l]};
        }
    }
}

bool skin_packed(const PackedSkin& p, std::span<const Mat34> palette, std::span<glm::vec3> out_positions,
                 std::span<glm::vec3> out_normals) {
    if (palette.size() <= p.max_joint || out_positions.size() != size_t(p.count)) return false;
    if (!out_normals.empty() && out_normals.size() != size_t(p.count)) return false;
    switch (p.influences) {
        case 1: skin_all<1>(p, palette, out_positions, out_normals); break;
        case 2: skin_all<2>(p, palette, out_positions, out_normals); break;
        case 4: skin_all<4>(p, palette, out_positions, out_normals); break;
        default: skin_all<0>(p, palette, out_positions, out_normals); break;
    }
    return true;
}

}  // namespace progskin
