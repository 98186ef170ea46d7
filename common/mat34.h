// mat34.h — small value types shared by the offline and runtime code.
//
// Mat34 is the runtime bone-matrix format: a 3x4 affine matrix stored row-major
// (m[r*4+c]); the implicit fourth row is (0,0,0,1). It is what the palette holds,
// what skinning reads and what the streaming code decodes into.
#pragma once
#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>
#include <cmath>

namespace progskin {

struct Mat34 {
    float m[12];

    static Mat34 identity() {
        return {{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0}};
    }
    static Mat34 from_glm(const glm::mat4& a) {  // glm is column-major: a[col][row]
        Mat34 r;
        for (int row = 0; row < 3; ++row)
            for (int c = 0; c < 4; ++c) r.m[row * 4 + c] = a[c][row];
        return r;
    }
    static Mat34 from_glm(const glm::dmat4& a) {
        Mat34 r;
        for (int row = 0; row < 3; ++row)
            for (int c = 0; c < 4; ++c) r.m[row * 4 + c] = static_cast<float>(a[c][row]);
        return r;
    }
    glm::mat4 to_glm() const {
        glm::mat4 a(1.0f);
        for (int row = 0; row < 3; ++row)
            for (int c = 0; c < 4; ++c) a[c][row] = m[row * 4 + c];
        return a;
    }
    glm::vec3 transform_point(const glm::vec3& p) const {
        return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
    }
    glm::vec3 transform_vector(const glm::vec3& p) const {
        return {m[0] * p.x + m[1] * p.y + m[2] * p.z,
                m[4] * p.x + m[5] * p.y + m[6] * p.z,
                m[8] * p.x + m[9] * p.y + m[10] * p.z};
    }
};

// a * b for affine 3x4 matrices (as 4x4 with last row 0,0,0,1).
inline Mat34 mul(const Mat34& a, const Mat34& b) {
    Mat34 r;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 4; ++j) {
            float s = a.m[i * 4 + 0] * b.m[0 * 4 + j] + a.m[i * 4 + 1] * b.m[1 * 4 + j] +
                      a.m[i * 4 + 2] * b.m[2 * 4 + j];
            if (j == 3) s += a.m[i * 4 + 3];
            r.m[i * 4 + j] = s;
        }
    }
    return r;
}

// (1-t)*a + t*b, element-wise (the on/off blend of a bone's matrix).
inline Mat34 lerp(const Mat34& a, const Mat34& b, float t) {
    Mat34 r;
    for (int i = 0; i < 12; ++i) r.m[i] = a.m[i] + (b.m[i] - a.m[i]) * t;
    return r;
}

inline bool finite(const glm::dvec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

}  // namespace progskin
