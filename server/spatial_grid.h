// spatial_grid.h — a tick's instances bucketed by ground cell (world x, z),
// built once per tick (FrameEncoder::encode) and read by every client's tick
// (ClientStream::update_importance): a client with a camera weighs the
// instances of the cells around it, ring by ring outwards, until a ring's
// radius proves that nobody further out can be among its candidates
// (ServerConfig::max_candidates), instead of weighing every slot of the
// world. Each client's tick then costs O(its neighbourhood), not
// O(world): the difference between a world of 1,000 players and one of
// 10,000 (docs/scaling.md).
//
// Cells are square, sized so that the cells hold about kPerCell instances
// each on average over the instances' bounding rectangle, and never more
// than 3 n / kPerCell + 1 of them (an elongated crowd gets longer cells, not
// more of them). A position that is not finite has no cell, nor has one far
// outside the box most positions lie in (from 16 instances: their 5th to
// 95th percentiles on x and z, widened by that span on each side, so that
// one far character cannot stretch every cell): everywhere() lists those,
// and every query visits them first.
// Cost: finish() O(n + cells); rings() O(cells visited + instances in them
// + those of everywhere()).
// No allocation after the largest tick.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include <glm/vec3.hpp>

namespace progskin::net {

class SpatialGrid {
public:
    static constexpr size_t kPerCell = 4;
    // What a query reads of an instance, kept in the grid cell by cell (a
    // client's weighing walks memory in order, not the frame's slots).
    struct Entry {
        uint32_t id = 0;          // slot
        uint32_t generation = 0;  // EncodedInstance::generation
        uint64_t owner = 0;       // EncodedInstance::owner
        glm::dvec3 world{0.0};
        double diagonal = 0;      // its asset's
    };
    // Build: begin(), add() each instance, finish().
    void begin() {
        pts_.clear();
        everywhere_.clear();
        built_ = false;
    }
    void add(const Entry& e) {
        if (std::isfinite(e.world.x) && std::isfinite(e.world.z)) pts_.push_back(e);
        else everywhere_.push_back(e);
    }
    void finish();
    bool built() const { return built_; }
    double cell() const { return cell_; }
    std::span<const Entry> everywhere() const { return everywhere_; }

    // Visits every instance ring by ring around p, a run of entries at a
    // time (visit(std::span<const Entry>): the cells of a ring's row lie
    // side by side, so a caller may fetch what it reads of a whole run
    // before it weighs them): ring k holds
    // the cells at Chebyshev distance k from p's cell; after each ring it
    // calls done(radius), every instance whose ground distance to p is at
    // most `radius` having been visited by then (radius k x cell, less a
    // rounding margin). Stops when done returns false or the grid is
    // covered. Returns false, having visited nothing, when p is not finite
    // or too far from the grid to index a cell: the caller weighs every slot.
    template <class Visit, class Done>
    bool rings(const glm::dvec3& p, Visit&& visit, Done&& done) const;

private:
    std::vector<Entry> pts_;         // as added
    std::vector<Entry> everywhere_;  // no cell (a position not finite)
    std::vector<uint32_t> start_;    // per cell (row-major, z rows), first index into ids_; one more at the end
    std::vector<Entry> ids_;         // the entries by cell
    std::vector<uint32_t> cell_of_;  // finish's scratch: each point's cell
    std::vector<double> scratch_;    // keep_outliers_apart's
    static constexpr size_t kOutliersFrom = 16;
    void keep_outliers_apart();  // moves the points far outside the box of most to everywhere_
    double x0_ = 0, z0_ = 0, cell_ = 1;
    int64_t nx_ = 0, nz_ = 0;
    bool built_ = false;
    int64_t index_of(double v, double v0) const { return int64_t(std::floor((v - v0) / cell_)); }
    template <class Visit>
    void visit_cells(int64_t z, int64_t x0, int64_t x1, Visit& visit) const {
        if (z < 0 || z >= nz_) return;
        x0 = std::max<int64_t>(x0, 0);
        x1 = std::min<int64_t>(x1, nx_ - 1);
        if (x0 > x1) return;
        // Row-major cells: those of one row from x0 to x1 hold one run of entries.
        const uint32_t from = start_[size_t(z * nx_ + x0)], to = start_[size_t(z * nx_ + x1) + 1];
        if (to > from) visit(std::span<const Entry>(ids_.data() + from, to - from));
    }
};

template <class Visit, class Done>
bool SpatialGrid::rings(const glm::dvec3& p, Visit&& visit, Done&& done) const {
    if (!built_ || !std::isfinite(p.x) || !std::isfinite(p.z)) return false;
    const double fx = std::floor((p.x - x0_) / cell_), fz = std::floor((p.z - z0_) / cell_);
    constexpr double kFar = double(int64_t(1) << 40);  // cell indices stay exact and their sums far from overflow
    if (!(std::fabs(fx) < kFar && std::fabs(fz) < kFar)) return false;
    const int64_t cx = int64_t(fx), cz = int64_t(fz);
    if (!everywhere_.empty()) visit(std::span<const Entry>(everywhere_));
    // The first ring that meets the grid, and the ring that covers it.
    const int64_t dx = cx < 0 ? -cx : cx >= nx_ ? cx - (nx_ - 1) : 0;
    const int64_t dz = cz < 0 ? -cz : cz >= nz_ ? cz - (nz_ - 1) : 0;
    const int64_t first = std::max(dx, dz);
    const int64_t last = std::max(std::max(cx, nx_ - 1 - cx), std::max(cz, nz_ - 1 - cz));
    for (int64_t k = first; k <= last; ++k) {
        if (k == 0) {
            visit_cells(cz, cx, cx, visit);
        } else {
            visit_cells(cz - k, cx - k, cx + k, visit);
            visit_cells(cz + k, cx - k, cx + k, visit);
            const int64_t z0 = std::max<int64_t>(cz - k + 1, 0), z1 = std::min<int64_t>(cz + k - 1, nz_ - 1);
            if (cx - k >= 0 && cx - k < nx_)
                for (int64_t z = z0; z <= z1; ++z) visit_cells(z, cx - k, cx - k, visit);
            if (cx + k >= 0 && cx + k < nx_)
                for (int64_t z = z0; z <= z1; ++z) visit_cells(z, cx + k, cx + k, visit);
        }
        // An instance in no ring up to k lies more than k cells from p on x
        // or z (exact arithmetic); the margin covers the floors' rounding.
        if (k < last && !done((double(k) - 1e-6) * cell_)) return true;
    }
    return true;
}

}  // namespace progskin::net
