#include "skinning.h"

#include <algorithm>
#include <cmath>
#include <cstring>

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

// ---- fast skinning: the stream layout (kernels in skinning_simd.cpp) ----

bool build_skin_stream(SkinStream& out, const SkinningJob& src, SkinWeightFormat format) {
    out = SkinStream{};
    const size_t n = src.positions.size();
    const int I = src.influences;
    if (I < 1 || I > 8 || src.max_influences < 1) return false;
    if (src.joints.size() != n * size_t(I) || src.weights.size() != n * size_t(I)) return false;
    if (!src.normals.empty() && src.normals.size() != n) return false;
    if (n > size_t(INT32_MAX) - kSkinBlock) return false;
    const int K = std::min(src.max_influences, I);
    const size_t B = kSkinBlock, blocks = (n + B - 1) / B;
    uint16_t max_joint = 0;
    for (size_t v = 0; v < n; ++v)
        for (int s = 0; s < K; ++s) max_joint = std::max(max_joint, src.joints[v * I + s]);
    out.count_ = int(n);
    out.influences_ = K;
    const bool has_normals = !src.normals.empty(), u8 = max_joint < 256;
    out.weight_format_ = format;
    out.max_joint_ = max_joint;
    // xyz per vertex, padded to whole blocks plus one vector (kernels read 4 floats at a time).
    out.positions_.assign(blocks * B * 3 + 4, 0.0f);
    if (has_normals) out.normals_.assign(blocks * B * 3 + 4, 0.0f);
    (u8 ? out.joints8_.assign(blocks * B * K, 0) : out.joints16_.assign(blocks * B * K, 0));
    const size_t wsize = format == SkinWeightFormat::F32 ? 4 : format == SkinWeightFormat::U16 ? 2 : 1;
    out.weights_.assign(blocks * B * size_t(K - 1) * wsize, 0);
    for (size_t v = 0; v < n; ++v) {
        const size_t b = v / B, o = v % B;
        for (int c = 0; c < 3; ++c) {
            out.positions_[v * 3 + c] = src.positions[v][c];
            if (has_normals) out.normals_[v * 3 + c] = src.normals[v][c];
        }
        float sum = 0.0f;
        for (int s = 0; s < K; ++s) sum += src.weights[v * I + s];
        for (int s = 0; s < K; ++s) {
            const size_t at = b * B * K + size_t(s) * B + o;
            const uint16_t j = src.joints[v * I + s];
            if (u8) out.joints8_[at] = uint8_t(j);
            else out.joints16_[at] = j;
            if (s == K - 1) break;  // the last weight is 1 - the others
            const float w = sum > 0.0f ? src.weights[v * I + s] / sum : (s == 0 ? 1.0f : 0.0f);
            const size_t wi = b * B * (K - 1) + size_t(s) * B + o;
            if (format == SkinWeightFormat::F32) {
                std::memcpy(&out.weights_[wi * 4], &w, 4);
            } else if (format == SkinWeightFormat::U16) {
                const uint16_t q = uint16_t(std::lround(std::clamp(w, 0.0f, 1.0f) * 65535.0f));
                std::memcpy(&out.weights_[wi * 2], &q, 2);
            } else {
                out.weights_[wi] = uint8_t(std::lround(std::clamp(w, 0.0f, 1.0f) * 255.0f));
            }
        }
    }
    return true;
}

}  // namespace progskin
