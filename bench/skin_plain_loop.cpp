#include "skin_plain_loop.h"

#include <cmath>

namespace progskin::bench {

void skin_plain_loop(const float* pos, const float* nrm, const uint16_t* joints, const float* weights,
                     int influences, const Mat34* palette, float* out_p, float* out_n, size_t count) {
    for (size_t v = 0; v < count; ++v) {
        float m[12] = {};
        for (int i = 0; i < influences; ++i) {
            const float w = weights[v * influences + i];
            const float* b = palette[joints[v * influences + i]].m;
            for (int c = 0; c < 12; ++c) m[c] += w * b[c];
        }
        const float* p = pos + v * 3;
        for (int r = 0; r < 3; ++r)
            out_p[v * 3 + r] = m[r * 4] * p[0] + m[r * 4 + 1] * p[1] + m[r * 4 + 2] * p[2] + m[r * 4 + 3];
        if (nrm) {
            const float* n = nrm + v * 3;
            float o[3];
            for (int r = 0; r < 3; ++r) o[r] = m[r * 4] * n[0] + m[r * 4 + 1] * n[1] + m[r * 4 + 2] * n[2];
            const float l = std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
            const float s = l > 0.0f ? 1.0f / l : 0.0f;
            for (int r = 0; r < 3; ++r) out_n[v * 3 + r] = o[r] * s;
        }
    }
}

}  // namespace progskin::bench
