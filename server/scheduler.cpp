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

// Extra error of an interpolation gap of g frames (30 Hz) over consecutive frames.
static double gap_cost(const ServerAsset& a, double g) {
    const int last = int(a.gap_error.size()) - 1;
    if (last < 1) return a.motion / 30.0 * std::max(0.0, g - 1.0);
    if (g >= last) return a.gap_error[last] + a.motion / 30.0 * (g - last);
    int i = int(g);
    double f = g - i;
    return a.gap_error[i] + (a.gap_error[std::min(i + 1, last)] - a.gap_error[i]) * f;
}

void Scheduler::reset(size_t n) {
    state_.assign(n, State{});
    k_.assign(n, 0);
    heap_.clear();
    heap_.reserve(n * 2);
}

size_t Scheduler::select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                         std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out) {
    out.clear();
    tick_ = frame.tick;
    const size_t n = frame.instances.size();
    if (state_.size() != n) reset(n);

    // Fast path: every bone of every (important) instance fits.
    size_t full = 0;
    for (size_t i = 0; i < n; ++i) {
        const auto& e = frame.instances[i];
        if (!e.valid || importance[i] <= 0.0f) continue;
        full += WireCost::kChunk + size_t(e.bone_count) * e.record_size;
    }
    if (full == 0) return 0;
    auto by_importance = [&](const Pick& a, const Pick& b) {
        return importance[a.instance] > importance[b.instance] ||
               (importance[a.instance] == importance[b.instance] && a.instance < b.instance);
    };
    if (WireCost::wire(full) <= budget) {
        for (size_t i = 0; i < n; ++i) {
            const auto& e = frame.instances[i];
            if (e.valid && importance[i] > 0.0f) out.push_back({int(i), e.bone_count});
        }
        std::sort(out.begin(), out.end(), by_importance);
        return WireCost::wire(full);
    }

    // Greedy over steps by importance-weighted error removed per byte.
    heap_.clear();
    std::fill(k_.begin(), k_.end(), 0);
    for (size_t i = 0; i < n; ++i) {
        const auto& e = frame.instances[i];
        if (!e.valid || importance[i] <= 0.0f) continue;
        const ServerAsset& a = *assets[e.asset];
        const State& s = state_[i];
        // Skipping this tick widens the client's interpolation gap to age + 1 ticks.
        const double gap = double(frame.tick - s.last_tick) * 30.0 / std::max(1.0f, tick_rate);
        double stale = s.k_last > 0 ? a.skin.error[s.k_last - 1].rms + gap_cost(a, gap) : a.e1 + a.diagonal;
        // Best first target among k = 1 and the hull vertices.
        double best = -1;
        int best_to = 1, best_h = 0;
        double err = a.e1;
        for (int h = -1; h < int(a.hull.size()); ++h) {
            int to = h < 0 ? 1 : a.hull[h].to;
            if (h >= 0) err -= a.hull[h].gain;
            size_t bytes = WireCost::kChunk + size_t(to) * e.record_size;
            double r = importance[i] * std::max(0.0, stale - err) / double(bytes);
            if (r > best) {
                best = r;
                best_to = to;
                best_h = h + 1;
            }
        }
        if (best <= 0) continue;
        heap_.push_back({best, int(i), best_to, best_h, WireCost::kChunk + size_t(best_to) * e.record_size});
        std::push_heap(heap_.begin(), heap_.end());
    }
    size_t payload = 0;
    while (!heap_.empty()) {
        std::pop_heap(heap_.begin(), heap_.end());
        Step st = heap_.back();
        heap_.pop_back();
        const auto& e = frame.instances[st.instance];
        const ServerAsset& a = *assets[e.asset];
        int from = k_[st.instance];
        size_t bytes = st.bytes;
        int to = st.to;
        if (WireCost::wire(payload + bytes) > budget) {
            // Take as many bones of this step as fit, then stop this instance.
            size_t fixed = from == 0 ? WireCost::kChunk : 0;
            while (to > from + 1 && WireCost::wire(payload + fixed + size_t(to - from) * e.record_size) > budget) --to;
            bytes = fixed + size_t(to - from) * e.record_size;
            if (to <= from || WireCost::wire(payload + bytes) > budget) continue;
            payload += bytes;
            k_[st.instance] = to;
            continue;
        }
        payload += bytes;
        k_[st.instance] = to;
        if (st.hull_index < int(a.hull.size())) {
            const HullStep& h = a.hull[st.hull_index];
            size_t b = size_t(h.to - h.from) * e.record_size;
            double r = importance[st.instance] * h.gain / double(b);
            if (r > 0) {
                heap_.push_back({r, st.instance, h.to, st.hull_index + 1, b});
                std::push_heap(heap_.begin(), heap_.end());
            }
        }
    }
    for (size_t i = 0; i < n; ++i)
        if (k_[i] > 0) out.push_back({int(i), k_[i]});
    std::sort(out.begin(), out.end(), by_importance);
    // Among instances of one asset sent this tick, the strictly more important ones get
    // the larger k (same bytes: same record size, one chunk each).
    for (size_t i = 0; i < out.size(); ++i)
        for (size_t j = i + 1; j < out.size(); ++j)
            if (frame.instances[out[i].instance].asset == frame.instances[out[j].instance].asset && out[j].k > out[i].k &&
                importance[out[i].instance] > importance[out[j].instance])
                std::swap(out[i].k, out[j].k);
    return payload ? WireCost::wire(payload) : 0;
}

void Scheduler::sent(std::span<const Pick> picks, uint32_t tick) {
    for (const Pick& p : picks) {
        if (size_t(p.instance) >= state_.size()) state_.resize(size_t(p.instance) + 1);
        state_[p.instance].k_last = p.k;
        state_[p.instance].last_tick = tick;
    }
}

}  // namespace progskin::net
