// probe_util.h — helpers shared by the stand-alone experiment programs in
// docs/experiments (not part of the library): environment switches, Mat34 to
// Eigen, affine 3x4 algebra and the weighted rigid Procrustes fit.
#pragma once
#include <Eigen/Dense>
#include <cstdlib>
#include <string>
#include <vector>

#include "mat34.h"
#include "vertex_animation.h"

namespace probe {

using M34 = Eigen::Matrix<double, 3, 4>;
using V3 = Eigen::Vector3d;

// Integer / real environment switch, d when unset.
inline int envi(const char* n, int d) {
    const char* s = std::getenv(n);
    return s ? std::atoi(s) : d;
}
inline double envd(const char* n, double d) {
    const char* s = std::getenv(n);
    return s ? std::atof(s) : d;
}
inline M34 to_e(const progskin::Mat34& m) {
    M34 r;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) r(i, j) = m.m[i * 4 + j];
    return r;
}
// m applied to the point p.
inline V3 xf(const M34& m, const V3& p) { return m.leftCols<3>() * p + m.col(3); }
// a * b for affine 3x4 matrices.
inline M34 mul(const M34& a, const M34& b) {
    M34 r;
    r.leftCols<3>() = a.leftCols<3>() * b.leftCols<3>();
    r.col(3) = a.leftCols<3>() * b.col(3) + a.col(3);
    return r;
}
// Weighted rigid Procrustes: argmin sum w |R x + t - y|^2 over rotations R
// (identity when the weights sum to 0).
inline M34 procrustes(const std::vector<V3>& x, const std::vector<V3>& y, const std::vector<double>& w) {
    double W = 0;
    V3 cx = V3::Zero(), cy = V3::Zero();
    for (size_t i = 0; i < x.size(); ++i) W += w[i], cx += w[i] * x[i], cy += w[i] * y[i];
    M34 r = M34::Zero();
    r.leftCols<3>().setIdentity();
    if (W <= 0) return r;
    cx /= W, cy /= W;
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < x.size(); ++i) S += w[i] * (y[i] - cy) * (x[i] - cx).transpose();
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;
    r.leftCols<3>() = svd.matrixU() * D * svd.matrixV().transpose();
    r.col(3) = cy - r.leftCols<3>() * cx;
    return r;
}

// The issue-4 comparison's input: a skinned glTF's clips played together at
// 30 fps as vertex animation, and the diagonal its errors are measured in.
inline progskin::VertexAnimation load_all_clips(const std::string& path, double* diagonal) {
    progskin::VertexAnimationOptions vo;
    vo.fps = 30;
    vo.clip = "all";
    progskin::VertexAnimation an = progskin::load_vertex_animation(path, vo);
    *diagonal = an.diagonal > 0 ? an.diagonal : progskin::frame_diagonal(an, 0);
    return an;
}

}  // namespace probe
