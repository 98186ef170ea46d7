// spatial_grid.cpp — see spatial_grid.h.
#include "spatial_grid.h"

#include <algorithm>

namespace progskin::net {

// The box most of the points lie in: their 5th to 95th percentiles on x
// and z, widened by that span on each side. A point outside it (a
// character placed far from everybody) has no cell but goes to
// everywhere(): a few far points do not stretch every cell (one player
// could otherwise put the whole world in one cell, and every client's
// search back to weighing all of it).
void SpatialGrid::keep_outliers_apart() {
    const size_t n = pts_.size();
    if (n < kOutliersFrom) return;
    auto box = [&](auto coord, double& lo, double& hi) {
        scratch_.resize(n);
        for (size_t k = 0; k < n; ++k) scratch_[k] = coord(pts_[k]);
        const size_t a = n / 20, b = n - 1 - n / 20;
        std::nth_element(scratch_.begin(), scratch_.begin() + long(a), scratch_.end());
        lo = scratch_[a];
        std::nth_element(scratch_.begin(), scratch_.begin() + long(b), scratch_.end());
        hi = scratch_[b];
        const double span = hi - lo;
        lo -= span;
        hi += span;
    };
    double x0, x1, z0, z1;
    box([](const Entry& e) { return e.world.x; }, x0, x1);
    box([](const Entry& e) { return e.world.z; }, z0, z1);
    size_t kept = 0;
    for (size_t k = 0; k < n; ++k) {
        const Entry& e = pts_[k];
        if (e.world.x >= x0 && e.world.x <= x1 && e.world.z >= z0 && e.world.z <= z1) pts_[kept++] = e;
        else everywhere_.push_back(e);
    }
    pts_.resize(kept);
}

void SpatialGrid::finish() {
    built_ = false;
    keep_outliers_apart();
    const size_t n = pts_.size();
    double x1 = 0, z1 = 0;
    x0_ = z0_ = 0;
    if (n > 0) {
        x0_ = x1 = pts_[0].world.x;
        z0_ = z1 = pts_[0].world.z;
        for (const Entry& q : pts_) {
            x0_ = std::min(x0_, q.world.x);
            x1 = std::max(x1, q.world.x);
            z0_ = std::min(z0_, q.world.z);
            z1 = std::max(z1, q.world.z);
        }
    }
    const double w = x1 - x0_, h = z1 - z0_;
    if (!std::isfinite(w) || !std::isfinite(h)) return;  // a span no double cell count indexes: not built (every query falls back)
    // About kPerCell instances a cell over the bounding rectangle; no side
    // of more than `cells` cells, so that there are at most 3 cells + 1
    // (w h / c^2 <= cells, w / c <= cells, h / c <= cells).
    const double cells = double(std::max<size_t>(1, n / kPerCell));
    double c = std::max({std::sqrt(w * h / cells), w / cells, h / cells});
    if (!(c > 0)) c = 1.0;  // all in one place
    cell_ = c;
    // Each point's cell by the formula rings() uses for its centre (no
    // clamp: the rings' radius proof needs both on one formula).
    cell_of_.resize(2 * n);
    nx_ = nz_ = 1;
    for (size_t k = 0; k < n; ++k) {
        const int64_t x = index_of(pts_[k].world.x, x0_), z = index_of(pts_[k].world.z, z0_);
        cell_of_[2 * k] = uint32_t(x);
        cell_of_[2 * k + 1] = uint32_t(z);
        nx_ = std::max(nx_, x + 1);
        nz_ = std::max(nz_, z + 1);
    }
    start_.assign(size_t(nx_ * nz_) + 1, 0);
    for (size_t k = 0; k < n; ++k) {
        const uint32_t cell = uint32_t(int64_t(cell_of_[2 * k + 1]) * nx_ + int64_t(cell_of_[2 * k]));
        cell_of_[k] = cell;  // (k <= 2k: the pair is read before it is overwritten)
        ++start_[size_t(cell) + 1];
    }
    for (size_t c2 = 1; c2 < start_.size(); ++c2) start_[c2] += start_[c2 - 1];
    ids_.resize(n);
    // Counting sort, stable: each cell's ids in the order added.
    for (size_t k = 0; k < n; ++k) ids_[start_[cell_of_[k]]++] = pts_[k];
    for (size_t c2 = start_.size() - 1; c2 > 0; --c2) start_[c2] = start_[c2 - 1];
    start_[0] = 0;
    built_ = true;
}

}  // namespace progskin::net
