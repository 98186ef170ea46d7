#include "palette.h"

#include <algorithm>
#include <immintrin.h>

namespace progskin {

namespace {
// a * b for 3x4 affine matrices, four lanes at a time (row i of the result is
// sum_k a[i][k] * row_k(b) plus a[i][3] in the translation lane).
inline Mat34 mul_simd(const Mat34& a, const Mat34& b) {
    const __m128 b0 = _mm_loadu_ps(b.m), b1 = _mm_loadu_ps(b.m + 4), b2 = _mm_loadu_ps(b.m + 8);
    const __m128 t = _mm_set_ps(1.0f, 0.0f, 0.0f, 0.0f);
    Mat34 r;
    for (int i = 0; i < 3; ++i) {
        const float* ai = a.m + 4 * i;
        __m128 row = _mm_mul_ps(_mm_set1_ps(ai[0]), b0);
        row = _mm_add_ps(row, _mm_mul_ps(_mm_set1_ps(ai[1]), b1));
        row = _mm_add_ps(row, _mm_mul_ps(_mm_set1_ps(ai[2]), b2));
        row = _mm_add_ps(row, _mm_mul_ps(_mm_set1_ps(ai[3]), t));
        _mm_storeu_ps(r.m + 4 * i, row);
    }
    return r;
}
}  // namespace

bool PaletteJob::validate() const {
    const size_t B = parents.size();
    if (B == 0 || out.size() != B) return false;
    if (!corrections.empty() && corrections.size() != B) return false;
    if (own.empty() || own.size() > B) return false;
    if (!presence.empty() && presence.size() != own.size()) return false;
    if (parents[0] != -1) return false;
    for (size_t b = 1; b < B; ++b)
        if (parents[b] < 0 || size_t(parents[b]) >= b) return false;
    return true;
}

void PaletteJob::run() const {
    const size_t B = parents.size(), n = own.size();
    out[0] = own[0];
    for (size_t b = 1; b < B; ++b) {
        const Mat34& up = out[size_t(parents[b])];
        const bool has_own = b < n;
        const float p = (has_own && !presence.empty()) ? presence[b] : 1.0f;
        if (has_own && p >= 1.0f) {
            out[b] = own[b];
            continue;
        }
        Mat34 stand_in = corrections.empty() ? up : mul_simd(up, corrections[b]);
        out[b] = (has_own && p > 0.0f) ? lerp(stand_in, own[b], p) : stand_in;
    }
}

LodBlender::LodBlender(int bone_count, int blend_frames, int initial_k)
    : presence_(size_t(std::max(bone_count, 1)), 0.0f), frames_(std::max(blend_frames, 1)) {
    target_ = std::clamp(initial_k, 1, int(presence_.size()));
    for (int b = 0; b < target_; ++b) presence_[size_t(b)] = 1.0f;
    update_needed();
}

void LodBlender::set_target(int k) { target_ = std::clamp(k, 1, int(presence_.size())); }

void LodBlender::step() {
    const float d = 1.0f / float(frames_);
    for (size_t b = 0; b < presence_.size(); ++b) {
        float& p = presence_[b];
        p = int(b) < target_ ? std::min(1.0f, p + d) : std::max(0.0f, p - d);
    }
    presence_[0] = 1.0f;
    update_needed();
}

bool LodBlender::settled() const {
    for (size_t b = 0; b < presence_.size(); ++b)
        if (presence_[b] != (int(b) < target_ ? 1.0f : 0.0f)) return false;
    return true;
}

void LodBlender::update_needed() {
    int n = 1;
    for (size_t b = 0; b < presence_.size(); ++b)
        if (presence_[b] > 0.0f) n = int(b) + 1;
    needed_ = n;
}

}  // namespace progskin
