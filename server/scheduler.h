// scheduler.h — per client and tick, how many bones of which instances to send
// (GUIDE.md §4): the step that removes the most importance-weighted error per
// wire byte goes first, until the client's byte budget for the tick is spent.
//
// Error model of an instance on the client: a fresh frame with k bones shows
// e(k) (the skin's RMS error table, along its lower convex hull); frames sent
// g ticks apart show in between about e(k_last) + gap_error(g) (the client
// interpolates; ServerAsset::gap_error, extended by the motion beyond 16
// frames). So the first step of an instance (0 -> k') is worth
// importance * (e(k_last) + gap_error(age) - e(k')) and every
// further hull step k -> k'' importance * (e(k) - e(k'')). Bytes per step:
// record_size per bone + a 6-byte chunk header for the first step; datagram
// overheads are charged by WireCost. Among instances of one asset sent in a
// tick, k is then made non-increasing in importance (swapping k keeps the
// bytes). Cost: O(S log S) per client and tick for S
// steps taken; O(instances) when everything fits (fast path). No allocation
// after warm-up.
#pragma once
#include <cstdint>
#include <span>
#include <vector>

#include "frame_encoder.h"

namespace progskin::net {

// Wire bytes (GUIDE.md rate: UDP payload + 28 per datagram) of a frame stream
// carrying `payload` bytes of chunk headers and records in one tick.
struct WireCost {
    static constexpr size_t kFrameOverhead = 80;  // Datagram + Frame FlatBuffer tables (datagram_packer.cpp checks)
    static constexpr size_t kChunk = 6;           // one Chunk struct
    static size_t datagrams(size_t payload);
    static size_t wire(size_t payload);
};

// The client's view (control.fbs View), decoded.
struct ViewSpec {
    glm::vec3 camera{0.0f, 0.0f, 0.0f};
    float fov_y = 0.8f;              // radians
    float viewport_height = 1080.0f; // pixels
    std::vector<std::pair<int, float>> weights;  // explicit per-instance weights (instance, weight)
    bool has_camera = false;
};

// importance(c): pixels of screen error per model unit of vertex error
// (camera view), or weight * 1000 / diagonal (explicit weights; no view: weight 1).
std::vector<float> compute_importance(const ViewSpec& view, const std::vector<InstanceSpec>& instances,
                                      const std::vector<std::shared_ptr<ServerAsset>>& assets);

struct Pick {
    int instance = 0;
    int k = 0;
};

class Scheduler {
public:
    void reset(size_t instance_count);
    // Fills `out` with (instance, k) in decreasing importance, k >= 1, within
    // budget wire bytes. Returns the estimated wire bytes.
    size_t select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                  std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out);
    // Records that `picks` went out at `tick`.
    void sent(std::span<const Pick> picks, uint32_t tick);

    int last_k(int instance) const { return state_[instance].k_last; }

private:
    struct State {
        int k_last = 0;          // bones of the last frame sent (0: never)
        uint32_t last_tick = 0;
    };
    struct Step {
        double ratio;
        int instance;
        int to;
        int hull_index;  // next hull step index after taking this
        size_t bytes;
        bool operator<(const Step& o) const { return ratio < o.ratio; }
    };
    std::vector<State> state_;
    std::vector<int> k_;
    std::vector<Step> heap_;
    uint32_t tick_ = 0;
};

}  // namespace progskin::net
