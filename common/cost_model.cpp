// cost_model.cpp — see cost_model.h.
#include "cost_model.h"

namespace progskin {

double CostSegment::gap_at(int model, double g) const {
    const auto& t = gap[size_t(model)];
    const int last = kGapTable - 1;
    if (g <= 1) return 0;
    if (g >= last) return t[last] * (g / last) * (g / last);
    const int i = int(g);
    return t[size_t(i)] + (t[size_t(i + 1)] - t[size_t(i)]) * (g - i);
}

}  // namespace progskin
