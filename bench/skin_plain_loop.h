// skin_plain_loop.h — the "plain loop" baseline for bench_skinning:
// per vertex, blend the 3x4 matrices of its influences with their weights,
// transform the position, and the normal by the 3x3 part, then renormalise
// the normal; one vertex at a time, floats. skin_plain_loop.cpp is compiled
// -O2 without -march (bench/CMakeLists.txt), whatever the build type.
#pragma once
#include <cstddef>
#include <cstdint>

#include "mat34.h"

namespace progskin::bench {
// nrm/out_n may be null (positions only).
void skin_plain_loop(const float* pos, const float* nrm, const uint16_t* joints, const float* weights,
                     int influences, const Mat34* palette, float* out_p, float* out_n, size_t count);
}  // namespace progskin::bench
