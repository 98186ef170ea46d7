// rate_controller.h — one client's sending rate: a cap (kbit/s, docs/metrics.md §3)
// and an estimate that adapts to measured loss and delay, never above the cap.
//
// What the path carries (carried_kbps()): the highest rate at which the
// client acknowledged bytes over the last kBwWindows 250 ms windows, each rate
// taken over the shortest span of 2 to kSpanWindows windows that holds at
// least kSpanDatagrams acknowledged datagrams (500 ms on a fast link, up to
// 3 s on a slow one, so that a window of one or two datagrams is not read as
// the link's rate). Behind a queue it reads the queue's output rate, the
// link's; on a path with room, the sender's own rate.
//
// A queue is an RTT above the smallest of the last 10-20 s (forgotten to the
// smallest of the last 10 s, so a queue that stands does not become the
// path's delay) by more than the larger of
// 25 ms, half the minimum and the time the largest datagram the bucket lets
// go takes at the rate carried (on a slow link a datagram's own time on the
// link varies with its size: 750 bytes at 48 kbit/s take 125 ms).
// Back off on loss > 20% over at least kLossSamples datagrams or 2 s (random
// loss is not congestion), on loss > 5% while the smoothed RTT shows such a
// queue (a queue that overflows swings below it at times), or on such a
// queue in the window's smallest RTT: to kBackoff (85%) of what the path carries,
// down to 50% for a queue of 500 ms or more (so that slow start's overshoot
// into a deep buffer drains in about a second; with nothing carried measured
// yet, to 80% of the estimate), then hold for
// two windows. A back-off never goes lower, so back-offs do not compound
// while a queue drains (to 95% of one window's deliveries, on a slow link one
// or two datagrams, they did: docs/performance.md "Behind a capped
// bottleneck").
// Probe up otherwise while the budget is used: slow start first, as TCP's
// (the estimate doubles every window in which the budget was used and the
// client acknowledged at least half of the window's target, until the first
// back-off or a window whose deliveries fall short); from then on by 10% +
// 4 kbit/s per window, by kQueueingStepKbps (3) while half a queue shows (so
// that the RTT shows a growing queue before it overflows, and so that clients
// sharing a bottleneck converge to equal parts), and never above kProbeGain
// (1.25) times what the path carries.
//
// Pacing is a token bucket in wire bytes: 10% of a second of the target deep,
// 12.5% (at most 1,000 bytes) below 80 kbit/s, or 470 bytes on slow links
// (below 38 kbit/s) — fewer, fuller datagrams, so that the ~140 bytes of a
// datagram's fixed cost (tables, seal, IP/UDP) do not eat the budget — filled
// at 1.04 x the target minus the depth per second (94% from 80 kbit/s up,
// 91.5% below, 81% at 16 kbit/s), so the wire bytes in any one second stay
// <= 1.04 * target <= 1.04 * cap. Never shallower than kMinDatagramBytes:
// below ~7 kbit/s the bucket is that deep and fills at 0.96 x the target (the
// mean stays under the cap; a datagram every 2 s at 1 kbit/s). A tick sends
// only when the bucket holds at least min(400, depth - one tick's fill)
// bytes, min(kFullerBytes = 750, ...) below kFullerBelowKbps = 80; after a
// loss (expedite()) below 80 kbit/s from 90 % of one tick's fill (at least
// kMinDatagramBytes), once: the lost datagram's bones, due again, then go a
// tick after the loss is known instead of a whole fuller datagram later
// (docs/performance.md "A loss sends its bones a tick after it is known").
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace progskin::net {

class RateController {
public:
    // The smallest datagram worth sending (datagram headers and the chunks of
    // bone 0 of a few characters): the bucket is never shallower, so that
    // every cap, down to the wire's 1 kbit/s, delivers the root level of its
    // characters at a reduced frame rate instead of nothing.
    static constexpr double kMinDatagramBytes = 240;
    // Below this target a tick sends from kFullerBytes in the bucket (on a
    // deeper bucket); the figures: docs/performance.md "Protocol 7".
    static constexpr double kFullerBelowKbps = 80, kFullerBytes = 750;
    // min_depth_bytes: a deeper bucket (bursts beyond 10% of a second) for
    // senders whose smallest useful datagram is larger (the RD baselines).
    RateController(double cap_kbps = 1000, double initial_kbps = 1000, double min_depth_bytes = 0);
    void set_cap(double cap_kbps);

    void refill(double dt_seconds);
    size_t budget() const;          // bytes allowed now (0: wait)
    // The sender wanted to send more than the budget allowed this tick (the
    // estimate may probe upward even if the bucket did not run dry).
    void mark_limited() { limited_ = true; }
    void spend(size_t wire_bytes);  // after sending
    // A datagram was found lost: below kFullerBelowKbps the next send goes
    // from 90 % of a tick's fill in the bucket (at least kMinDatagramBytes), not from
    // kFullerBytes, so that its bones, due again (Scheduler::lost), are not
    // left out for a whole further datagram's wait; until the next spend().
    // The bucket never goes below empty: the rate stays what it was.
    void expedite() { expedite_ = true; }
    bool expedited() const { return expedite_; }
    void on_sent(uint32_t seq, uint32_t send_us, size_t wire_bytes);
    void on_ack(uint32_t ack, uint32_t ack_bits, uint32_t echo_us, uint32_t hold_us, uint32_t now_us);
    // Re-evaluates the estimate; call every tick (acts every 250 ms).
    void update(double now_seconds);
    // The client's address changed (a NAT rebinding, once the new address
    // answered the Challenge): what was sent to the old address was lost to
    // the path, not to congestion. Forgets it (not counted lost), and the
    // delay and loss of the old path; back to the estimate held before the
    // switch (the highest of the last 2 s) in slow start, so the stream is
    // back at its rate at once instead of probing up from a collapsed one.
    void on_path_change();

    double cap_kbps() const { return cap_kbps_; }
    double estimate_kbps() const { return estimate_kbps_; }
    double target_kbps() const { return estimate_kbps_ < cap_kbps_ ? estimate_kbps_ : cap_kbps_; }
    // Loss is judged over at least this many datagrams (or 2 s, from 4).
    static constexpr uint64_t kLossSamples = 32;
    // Another floor (tests: 4 judges about every 250 ms window at a
    // datagram per tick, the rule before kLossSamples).
    void set_loss_samples(uint64_t n) { loss_samples_ = n; }
    double loss() const { return loss_; }       // the last judged loss fraction (kLossSamples)
    bool in_slow_start() const { return slow_start_; }
    // Off: probe by 10% per window from the start (the behaviour before slow
    // start, kept for comparisons; tests/test_net_rate.cpp).
    void set_slow_start(bool on) { slow_start_ = on; }
    double rtt_ms() const { return srtt_ms_; }
    // What the path was measured to carry (kbit/s; 0: nothing measured yet).
    double carried_kbps() const;
    static constexpr size_t kBwWindows = 10, kSpanWindows = 12;
    static constexpr uint64_t kSpanDatagrams = 10;
    static constexpr double kBackoff = 0.85, kProbeGain = 1.25, kQueueingStepKbps = 3.0;
    uint64_t acked() const { return acked_total_; }
    uint64_t lost() const { return lost_total_; }

private:
    struct Sent {
        uint32_t seq = 0, send_us = 0, bytes = 0;
        bool valid = false, acked = false, counted = false;
    };
    void mark(uint32_t seq);
    // update()'s steps: the loss judged (when enough datagrams were), the
    // window's span rate recorded, the estimate grown.
    bool judge_loss_now(double now);
    void push_span(double window);
    void grow(uint64_t judged, double delivered_kbps, bool queueing, double carried);
    double depth_bytes(double kbps) const;
    double fill_fraction(double kbps) const;
    double cap_kbps_, min_depth_, estimate_kbps_;
    double tokens_ = 0, fill_ = 0;
    bool expedite_ = false;  // expedite()
    bool limited_ = false;  // the budget ran out since the last update
    std::vector<Sent> ring_ = std::vector<Sent>(1024);
    uint32_t highest_acked_ = 0;
    bool any_ack_ = false;
    uint64_t win_acked_bytes_ = 0, win_acked_ = 0, win_lost_ = 0, acked_total_ = 0, lost_total_ = 0;
    uint64_t loss_acked_ = 0, loss_lost_ = 0;  // since the loss was last judged
    uint64_t loss_samples_ = kLossSamples;
    double loss_since_ = -1;
    double loss_ = 0, srtt_ms_ = 0, min_rtt_ms_ = 1e9, min_rtt_age_ = 0;
    double last_update_ = -1;
    // Per window, newest last: acknowledged bytes and datagrams, duration;
    // and the rate each window's span measured.
    struct Window {
        uint64_t bytes = 0, datagrams = 0;
        double seconds = 0;
    };
    std::array<Window, kSpanWindows> windows_{};
    std::array<double, kBwWindows> rates_{};
    size_t window_at_ = 0;
    double win_min_rtt_ms_ = 1e9, window_rtt_ms_ = 0;  // the smallest RTT of this window; of the last with one
    double period_min_rtt_ms_ = 1e9;  // the smallest since the minimum last forgot
    int hold_ = 0;  // windows to wait after a back-off
    bool slow_start_ = true;  // doubling until the first back-off or short delivery
    // The estimate at the last 8 updates (2 s): what on_path_change restores.
    std::array<double, 8> recent_{};
    size_t recent_at_ = 0;
};

}  // namespace progskin::net
