// SpatialGrid (server/spatial_grid.h): every instance visited once, and the
// radius each ring reports holds: nobody within it is left unvisited, for
// crowds of any shape and centres inside, on the edge of and far outside
// the grid.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "spatial_grid.h"

using namespace progskin::net;

namespace {

struct Scene {
    std::vector<glm::dvec3> at;
};

// Crowds the grid must handle: uniform, one dense cluster in a sparse
// field, a line (no area), all in one point, one far outlier, non-finite.
std::vector<Scene> scenes() {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-500.0, 500.0), near(-2.0, 2.0);
    std::vector<Scene> out;
    Scene s;
    for (int k = 0; k < 600; ++k) s.at.push_back({u(rng), u(rng) * 0.01, u(rng)});
    out.push_back(s);
    s.at.clear();
    for (int k = 0; k < 400; ++k) s.at.push_back({near(rng), 0.0, near(rng)});
    for (int k = 0; k < 100; ++k) s.at.push_back({u(rng), 0.0, u(rng)});
    out.push_back(s);
    s.at.clear();
    for (int k = 0; k < 300; ++k) s.at.push_back({u(rng), 0.0, 3.0});
    out.push_back(s);
    s.at.clear();
    for (int k = 0; k < 50; ++k) s.at.push_back({1.0, 2.0, 3.0});
    out.push_back(s);
    s.at.clear();
    for (int k = 0; k < 200; ++k) s.at.push_back({u(rng), 0.0, u(rng)});
    s.at.push_back({1e12, 0.0, -1e12});
    s.at.push_back({std::numeric_limits<double>::quiet_NaN(), 0.0, 1.0});
    s.at.push_back({std::numeric_limits<double>::infinity(), 0.0, 1.0});
    out.push_back(s);
    s.at.clear();
    s.at.push_back({5.0, 0.0, 5.0});  // one
    out.push_back(s);
    out.push_back(Scene{});  // none
    return out;
}

double ground(const glm::dvec3& a, const glm::dvec3& b) { return std::hypot(a.x - b.x, a.z - b.z); }

}  // namespace

TEST(SpatialGrid, RingsVisitEveryoneOnceAndTheirRadiusHolds) {
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-700.0, 700.0);
    SpatialGrid grid;
    int checks = 0;
    for (const Scene& s : scenes()) {
        grid.begin();
        for (size_t i = 0; i < s.at.size(); ++i) grid.add({uint32_t(i), 0, 0, s.at[i], 1.0});
        grid.finish();
        ASSERT_TRUE(grid.built());
        std::vector<glm::dvec3> centres{{0, 0, 0}, {1.0, 2.0, 3.0}, {-3e4, 0, 2e4}, {499.9, 0, -499.9}};
        for (int k = 0; k < 20; ++k) centres.push_back({u(rng), 0.0, u(rng)});
        for (const glm::dvec3& c : centres) {
            std::vector<int> seen(s.at.size(), 0);
            bool ok = grid.rings(
                c, [&](std::span<const SpatialGrid::Entry> run) { for (const auto& e : run) ++seen.at(e.id); },
                [&](double radius) {
                    for (size_t i = 0; i < s.at.size(); ++i)
                        if (std::isfinite(s.at[i].x) && std::isfinite(s.at[i].z) && ground(s.at[i], c) <= radius) {
                            EXPECT_EQ(seen[i], 1) << "instance " << i << " within " << radius << " of the centre not visited";
                            ++checks;
                        }
                    return true;
                });
            ASSERT_TRUE(ok);
            for (size_t i = 0; i < s.at.size(); ++i) EXPECT_EQ(seen[i], 1) << "instance " << i;
        }
    }
    EXPECT_GT(checks, 10000);  // the radius claims were tested, not vacuous
}

// A few characters far from everybody (one player's, placed a million
// metres away) neither stretch the cells nor slow a search near the crowd:
// they are visited apart, and the radius claims still hold.
TEST(SpatialGrid, FarCharactersDoNotStretchTheCells) {
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1000.0, 1000.0);
    std::vector<glm::dvec3> at;
    for (int k = 0; k < 1000; ++k) at.push_back({u(rng), 0.0, u(rng)});
    at.push_back({1e6, 0.0, 1e6});
    at.push_back({-1e6, 0.0, 5.0});
    at.push_back({3.0, 0.0, 4e6});
    SpatialGrid grid;
    grid.begin();
    for (size_t i = 0; i < at.size(); ++i) grid.add({uint32_t(i), 0, 0, at[i], 1.0});
    grid.finish();
    ASSERT_TRUE(grid.built());
    EXPECT_LT(grid.cell(), 200.0);  // about 4 of the 1,000 per cell (126 m), not the far ones' span
    EXPECT_EQ(grid.everywhere().size(), 3u);
    for (const glm::dvec3 c : {glm::dvec3(0, 0, 0), glm::dvec3(1e6, 0, 1e6), glm::dvec3(-900, 0, 900)}) {
        std::vector<int> seen(at.size(), 0);
        size_t visited = 0;
        grid.rings(
            c, [&](std::span<const SpatialGrid::Entry> run) { for (const auto& e : run) ++seen.at(e.id), ++visited; },
            [&](double radius) {
                for (size_t i = 0; i < at.size(); ++i) {
                    if (std::hypot(at[i].x - c.x, at[i].z - c.z) <= radius) {
                        EXPECT_EQ(seen[i], 1) << "instance " << i;
                    }
                }
                return visited < 100;  // a search for about 100
            });
        if (c.x == 0) {
            EXPECT_LT(visited, 300u);
        }
    }
}

TEST(SpatialGrid, StopsWhenAskedAndRefusesCentresItCannotIndex) {
    SpatialGrid grid;
    grid.begin();
    for (int k = 0; k < 1000; ++k) grid.add({uint32_t(k), 0, 0, {double(k % 40) * 10.0, 0.0, double(k / 40) * 10.0}, 1.0});
    grid.finish();
    size_t visited = 0, rings = 0;
    grid.rings({200.0, 0.0, 120.0}, [&](std::span<const SpatialGrid::Entry> run) { visited += run.size(); }, [&](double) { return ++rings < 2; });
    EXPECT_EQ(rings, 2u);
    EXPECT_GT(visited, 0u);
    EXPECT_LT(visited, 200u);  // two rings of cells of about 4, not the world
    EXPECT_FALSE(grid.rings({std::nan(""), 0.0, 0.0}, [](std::span<const SpatialGrid::Entry>) {}, [](double) { return true; }));
    EXPECT_FALSE(grid.rings({1e300, 0.0, 0.0}, [](std::span<const SpatialGrid::Entry>) {}, [](double) { return true; }));
    // A span no cell count covers: not built, every query refused (the caller weighs every slot).
    grid.begin();
    grid.add({0, 0, 0, {-1.7e308, 0.0, 0.0}, 1.0});
    grid.add({1, 0, 0, {1.7e308, 0.0, 0.0}, 1.0});
    grid.finish();
    EXPECT_FALSE(grid.built());
    EXPECT_FALSE(grid.rings({0.0, 0.0, 0.0}, [](std::span<const SpatialGrid::Entry>) {}, [](double) { return true; }));
}
