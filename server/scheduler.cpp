// scheduler.cpp — see scheduler.h.
#include "scheduler.h"

#include <algorithm>
#include <cmath>

#include "wire.h"

namespace progskin::net {

size_t WireCost::datagrams(size_t payload) {
    // room for one split chunk header and the tail a record does not fill
    const size_t cap = MAX_DATAGRAM - kFrameOverhead - kChunk - 14;
    return std::max<size_t>(1, (payload + cap - 1) / cap);
}

size_t WireCost::wire(size_t payload) {
    size_t n = datagrams(payload);
    return payload + n * (kFrameOverhead + UDP_IP_OVERHEAD) + (n - 1) * kChunk;
}

std::vector<float> compute_importance(const ViewSpec& view, const std::vector<InstanceSpec>& instances,
                                      const std::vector<std::shared_ptr<ServerAsset>>& assets) {
    std::vector<float> imp(instances.size(), 0.0f);
    for (size_t i = 0; i < instances.size(); ++i) {
        const ServerAsset& a = *assets[instances[i].asset];
        if (!view.weights.empty()) {
            float w = 0.0f;
            for (const auto& [inst, weight] : view.weights)
                if (inst == int(i)) w = weight;
            imp[i] = std::max(0.0f, w) * float(1000.0 / a.diagonal);
        } else if (view.has_camera) {
            float d = std::max(glm::length(instances[i].position - view.camera), float(0.05 * a.diagonal));
            float t = std::tan(std::clamp(view.fov_y, 0.01f, 3.0f) * 0.5f);
            imp[i] = view.viewport_height / (2.0f * d * t);
        } else {
            imp[i] = float(1000.0 / a.diagonal);
        }
    }
    return imp;
}

static_assert(HOLD_TICKS < ServerAsset::kGapTable, "refresh tables cover every age below the hold");

void Scheduler::reset(size_t n) {
    state_.assign(n, State{});
    k_.assign(n, 0);
    steps_.assign(n, {});
    heap_.clear();
    heap_.reserve(n * 2);
    price_ = 0;
}

int Scheduler::shown(int instance, uint32_t tick) const {
    const State& s = state_[size_t(instance)];
    int k = 0;
    while (k < int(s.bone_tick.size()) && s.bone_tick[size_t(k)] != 0 && int32_t(tick - s.bone_tick[size_t(k)]) <= HOLD_TICKS) ++k;
    return k;
}

size_t Scheduler::select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                         std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out) {
    out.clear();
    const size_t n = frame.instances.size();
    if (state_.size() != n) reset(n);
    auto by_importance = [&](const Pick& a, const Pick& b) {
        return importance[a.instance] > importance[b.instance] ||
               (importance[a.instance] == importance[b.instance] && a.instance < b.instance);
    };

    // Fast path: every bone of every (important) instance fits.
    size_t full = 0;
    for (size_t i = 0; i < n; ++i) {
        const auto& e = frame.instances[i];
        if (!e.valid || importance[i] <= 0.0f) continue;
        full += WireCost::kChunk + size_t(e.bone_count) * e.record_size;
    }
    if (full == 0) return 0;
    if (WireCost::wire(full) <= budget) {
        for (size_t i = 0; i < n; ++i) {
            const auto& e = frame.instances[i];
            if (e.valid && importance[i] > 0.0f) out.push_back({int(i), e.bone_count, e.bone_count});
        }
        std::sort(out.begin(), out.end(), by_importance);
        price_ = 0;
        return WireCost::wire(full);
    }

    // Per instance: segment values (scheduler.h), then the upper concave hull
    // of the cumulative (bytes, value) from (0, 0).
    const double to30 = 30.0 / std::max(1.0f, tick_rate);
    heap_.clear();
    std::fill(k_.begin(), k_.end(), 0);
    for (size_t i = 0; i < n; ++i) {
        auto& hull = steps_[i];
        hull.clear();
        const auto& e = frame.instances[i];
        if (!e.valid || importance[i] <= 0.0f) continue;
        const ServerAsset& a = *assets[size_t(e.asset)];
        State& st = state_[i];
        if (st.bone_tick.size() != size_t(a.bone_count())) st.bone_tick.assign(size_t(a.bone_count()), 0);
        // Squared error in screen units, summed over the instance's vertices
        // (the RMS of GUIDE.md §2 pools all vertices of all characters).
        const double w = double(importance[i]) * double(importance[i]) * double(a.character.vertex_count());
        size_t bytes = 0;
        double value = 0;
        hull.push_back({0, 0, 0.0});
        for (size_t q = 0; q < a.segments.size(); ++q) {
            const ServerAsset::Segment& seg = a.segments[q];
            const size_t b = size_t(seg.to - seg.from) * size_t(e.record_size) + (q == 0 ? WireCost::kChunk : 0);
            const int m = std::clamp(e.model, 0, int(seg.gap.size()) - 1);
            const uint32_t last = st.bone_tick[size_t(seg.to - 1)];
            const int32_t age = int32_t(frame.tick - last);
            double v;
            if (last != 0 && age > 0 && age < HOLD_TICKS) {
                const double g = double(age) * to30;
                if (g == double(age)) v = seg.refresh[size_t(m)][size_t(age)];
                else v = g * (g + 1.0) * (seg.gap_at(m, g + 1.0) - seg.gap_at(m, g));
                // Last tick of the hold: without a refresh the segment is dropped,
                // so refreshing it is worth at least showing it.
                if (age == HOLD_TICKS - 1) v = std::max(v, seg.show_value[size_t(m)]);
            } else if (last != 0 && age <= 0) {
                v = 0;  // already sent this tick
            } else {
                // Not shown: worth its collapse error over the refresh period that
                // makes showing it most worthwhile (scene.h show_value).
                v = seg.show_value[size_t(m)];
            }
            bytes += b;
            value += w * v;
            HullPoint pt{seg.to, bytes, value};
            // Upper concave hull: drop points under the chord to the new point.
            while (hull.size() >= 2) {
                const HullPoint& p0 = hull[hull.size() - 2];
                const HullPoint& p1 = hull.back();
                const double cross = double(p1.bytes - p0.bytes) * (pt.value - p0.value) -
                                     double(pt.bytes - p0.bytes) * (p1.value - p0.value);
                if (cross >= 0) hull.pop_back();
                else break;
            }
            hull.push_back(pt);
        }
        if (hull.size() >= 2 && hull[1].value > hull[0].value) {
            const uint32_t stale = st.bone_tick[0] != 0 ? frame.tick - st.bone_tick[0] : UINT32_MAX;
            heap_.push_back({(hull[1].value - hull[0].value) / double(hull[1].bytes), int(i), 1, stale});
            std::push_heap(heap_.begin(), heap_.end());
        }
    }
    // Greedy over the instances' hull steps by value per byte.
    size_t payload = 0;
    double price = 0;
    while (!heap_.empty()) {
        std::pop_heap(heap_.begin(), heap_.end());
        const Step s = heap_.back();
        heap_.pop_back();
        const auto& e = frame.instances[size_t(s.instance)];
        const auto& hull = steps_[size_t(s.instance)];
        const HullPoint& from = hull[size_t(s.step - 1)];
        const HullPoint& to = hull[size_t(s.step)];
        size_t bytes = to.bytes - from.bytes;
        if (WireCost::wire(payload + bytes) > budget) {
            if (price == 0) price = s.ratio;
            // Take as many bones of this step as fit, then stop this instance.
            const size_t fixed = from.k == 0 ? WireCost::kChunk : 0;
            int k = to.k;
            while (k > from.k + 1 && WireCost::wire(payload + fixed + size_t(k - from.k) * size_t(e.record_size)) > budget) --k;
            bytes = fixed + size_t(k - from.k) * size_t(e.record_size);
            if (k <= from.k || WireCost::wire(payload + bytes) > budget) continue;
            payload += bytes;
            k_[size_t(s.instance)] = k;
            continue;
        }
        payload += bytes;
        k_[size_t(s.instance)] = to.k;
        if (size_t(s.step) + 1 < hull.size()) {
            const HullPoint& nx = hull[size_t(s.step) + 1];
            const double r = (nx.value - to.value) / double(nx.bytes - to.bytes);
            if (r > 0) {
                heap_.push_back({r, s.instance, s.step + 1, s.age});
                std::push_heap(heap_.begin(), heap_.end());
            }
        }
    }
    // The price of a byte, smoothed over about ten ticks (the budget per tick varies).
    price_ = 0.9 * price_ + 0.1 * price;  // informational (price())
    // Of two instances of one asset playing the same clip, the more important
    // one gets the longer prefix this tick (same bytes), so its bones are never
    // staler than the other's and it is never shown fewer (GUIDE.md §4).
    for (size_t i = 0; i < n; ++i)
        if (k_[i] > 0) out.push_back({int(i), 0, 0});
    for (size_t x = 0; x < out.size(); ++x) {
        const size_t i = size_t(out[x].instance);
        for (size_t y = x + 1; y < out.size(); ++y) {
            const size_t j = size_t(out[y].instance);
            if (frame.instances[i].asset != frame.instances[j].asset ||
                frame.instances[i].model != frame.instances[j].model || importance[i] == importance[j])
                continue;
            const size_t hi = importance[i] > importance[j] ? i : j, lo = hi == i ? j : i;
            if (k_[lo] > k_[hi]) std::swap(k_[lo], k_[hi]);
        }
    }
    for (Pick& pk : out) {
        // Shown from now on: this tick's bones and those refreshed within the hold.
        const size_t i = size_t(pk.instance);
        const auto& bt = state_[i].bone_tick;
        pk.k = k_[i];
        pk.show = pk.k;
        while (pk.show < int(bt.size()) && bt[size_t(pk.show)] != 0 && int32_t(frame.tick - bt[size_t(pk.show)]) < HOLD_TICKS)
            ++pk.show;
    }
    std::sort(out.begin(), out.end(), by_importance);
    return payload ? WireCost::wire(payload) : 0;
}

void Scheduler::sent(std::span<const Pick> picks, uint32_t tick) {
    for (const Pick& p : picks) {
        if (size_t(p.instance) >= state_.size()) continue;
        State& s = state_[size_t(p.instance)];
        s.k_last = p.k;
        if (s.bone_tick.size() < size_t(p.k)) s.bone_tick.resize(size_t(p.k), 0);
        for (int b = 0; b < p.k; ++b) s.bone_tick[size_t(b)] = tick;
    }
}

}  // namespace progskin::net
