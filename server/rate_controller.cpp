// rate_controller.cpp — see rate_controller.h.
#include "rate_controller.h"

#include <algorithm>

#include "wire.h"

namespace progskin::net {

static constexpr double kMinKbps = 8.0;

// Bucket depth: 10 % of a second of the target, and at least 470 bytes (room
// for ~400-byte datagrams, whose 108 bytes of datagram headers are then about
// a quarter of them) where that is at most 35 % of a second; min_depth for
// senders that need more; never less than kMinDatagramBytes, the smallest
// datagram worth sending (below ~5 kbit/s 35 % of a second is less: such a
// cap sent nothing at all). The fill makes up the rest of 1.04 x the target
// per second (at most 0.94), so any one-second window carries at most 1.04 x
// the target (unless min_depth alone exceeds 79 % of a second); on a link so
// slow that the bucket holds more than 35 % of a second, it fills at 0.96 x
// the target: the mean rate stays under the cap, one datagram may take more
// than a second of it.
// Below kFullerBelowKbps the bucket holds 12.5 % of a second (at most 1,000
// bytes) and a tick sends from kFullerBytes on (below).
double RateController::depth_bytes(double kbps) const {
    const double second = kbps * 125.0;
    const double fuller = kbps < kFullerBelowKbps ? std::min(1000.0, 0.125 * second) : 0.0;
    return std::max({min_depth_, 0.10 * second, std::min(470.0, 0.35 * second), fuller, kMinDatagramBytes});
}

double RateController::fill_fraction(double kbps) const {
    const double second = std::max(1.0, kbps * 125.0);
    const double depth = depth_bytes(kbps);
    if (depth > 0.35 * second && depth == kMinDatagramBytes) return 0.96;
    return std::clamp(1.04 - depth / second, 0.25, 0.94);
}

RateController::RateController(double cap_kbps, double initial_kbps, double min_depth_bytes)
    : cap_kbps_(cap_kbps), min_depth_(min_depth_bytes) {
    estimate_kbps_ = std::clamp(initial_kbps, kMinKbps, std::max(kMinKbps, cap_kbps));
}

void RateController::set_cap(double cap_kbps) {
    cap_kbps_ = std::max(kMinKbps, cap_kbps);
    estimate_kbps_ = std::min(estimate_kbps_, cap_kbps_);
}


void RateController::refill(double dt) {
    double t = target_kbps();
    fill_ = fill_fraction(t) * t * 125.0 * dt;
    tokens_ = std::min(depth_bytes(t), tokens_ + fill_);
}

size_t RateController::budget() const {
    // Send once the bucket holds 400 bytes, or earlier if the next refill would
    // overflow it (what overflows is rate never used).
    // Below kFullerBelowKbps from kFullerBytes: a datagram's fixed cost (the
    // Datagram and Frame tables, the seal, IP and UDP: some 140 bytes) is
    // then under a fifth of it (docs/performance.md "Protocol 7: predicted root blocks and fuller datagrams").
    const double t = target_kbps();
    double d = depth_bytes(t);
    const double fuller = expedite_ ? std::max(kMinDatagramBytes, std::min(0.9 * fill_, kFullerBytes)) : kFullerBytes;
    double min_send = std::max(0.0, std::min(t < kFullerBelowKbps ? fuller : 400.0, d - fill_));
    return tokens_ >= min_send && tokens_ > 0 ? size_t(tokens_) : 0;
}

void RateController::spend(size_t wire_bytes) {
    tokens_ -= double(wire_bytes);
    expedite_ = false;
    // A budget used to within one small datagram means the rate limited us.
    if (tokens_ < 200.0) limited_ = true;
}

void RateController::on_sent(uint32_t seq, uint32_t send_us, size_t wire_bytes) {
    Sent& s = ring_[seq % ring_.size()];
    if (s.valid && !s.counted) {  // overwritten before being judged: lost
        if (!s.acked) { ++win_lost_; ++lost_total_; }
    }
    s = Sent{seq, send_us, uint32_t(wire_bytes), true, false, false};
}

void RateController::mark(uint32_t seq) {
    Sent& s = ring_[seq % ring_.size()];
    if (s.valid && s.seq == seq && !s.acked) {
        s.acked = true;
        win_acked_bytes_ += s.bytes;
        if (!s.counted) {
            s.counted = true;
            ++win_acked_;
            ++acked_total_;
        }
    }
}

void RateController::on_ack(uint32_t ack, uint32_t bits, uint32_t echo_us, uint32_t hold_us, uint32_t now_us) {
    mark(ack);
    for (int i = 0; i < 32; ++i)
        if (bits & (1u << i)) mark(ack - 1 - uint32_t(i));
    if (!any_ack_ || int32_t(ack - highest_acked_) > 0) {
        highest_acked_ = ack;
        any_ack_ = true;
        double rtt = double(int32_t(now_us - echo_us - hold_us)) / 1000.0;
        if (rtt >= 0 && rtt < 10000) {
            srtt_ms_ = srtt_ms_ == 0 ? rtt : 0.875 * srtt_ms_ + 0.125 * rtt;
            min_rtt_ms_ = std::min(min_rtt_ms_, rtt);
            win_min_rtt_ms_ = std::min(win_min_rtt_ms_, rtt);
        }
    }
    // A datagram left out of this Ack while the 2 after it arrived is lost
    // (a late Ack of it still counts its bytes as delivered); datagrams
    // older than the ack window and not acked are lost.
    for (uint32_t i = 2; i < 32; ++i) {
        if (bits & (1u << i)) continue;
        Sent& s = ring_[(ack - 1 - i) % ring_.size()];
        if (s.valid && s.seq == ack - 1 - i && !s.counted && !s.acked) {
            s.counted = true;
            ++win_lost_;
            ++lost_total_;
        }
    }
    for (auto& s : ring_) {
        if (!s.valid || s.counted) continue;
        if (int32_t(highest_acked_ - s.seq) > 32) {
            s.counted = true;
            if (!s.acked) { ++win_lost_; ++lost_total_; }
        }
    }
}

void RateController::update(double now) {
    if (last_update_ < 0) last_update_ = now;
    if (now - last_update_ < 0.25) return;
    const uint64_t judged = win_acked_ + win_lost_;
    // Loss is judged over at least kLossSamples datagrams (or 2 s): over
    // one window's 8 datagrams at 30 a second, random loss of 10 % reads
    // "over 20 %" in one window of five, a back-off for nothing; over 32,
    // in one judgement of 24.
    const bool judge_loss = judge_loss_now(now);
    // The RTT includes the datagram's own time on the link, which on a slow
    // link is long and varies with its size (750 bytes at 48 kbit/s: 125
    // ms): a queue is read only beyond the largest datagram the bucket lets
    // go, at the rate last carried. Loss is congestion above 20%, or above 5%
    // while the RTT shows a queue: random loss has no queue behind it, a
    // queue that overflows has.
    const double carried_before = carried_kbps();
    const double largest_ms = carried_before > 0 ? std::min(double(MAX_DATAGRAM + UDP_IP_OVERHEAD), depth_bytes(target_kbps())) * 8.0 / carried_before : 0.0;
    // The queue: the window's smallest RTT above the smallest in 10 s (a
    // queue that stood all window long; one that drained shows at once,
    // where the smoothed RTT of a few acks a second lagged by seconds).
    if (win_min_rtt_ms_ < 1e9) window_rtt_ms_ = win_min_rtt_ms_;
    period_min_rtt_ms_ = std::min(period_min_rtt_ms_, win_min_rtt_ms_);
    win_min_rtt_ms_ = 1e9;
    const double queue_ms = window_rtt_ms_ > 0 && min_rtt_ms_ < 1e9 ? std::max(0.0, window_rtt_ms_ - min_rtt_ms_) : 0.0;
    const double queue_threshold_ms = std::max({25.0, 0.5 * min_rtt_ms_, largest_ms});
    const bool delay_growth = queue_ms > queue_threshold_ms;
    // (A queue that overflows swings: the window's smallest RTT can miss it;
    // the smoothed one does not.)
    const double mean_queue_ms = srtt_ms_ > 0 && min_rtt_ms_ < 1e9 ? srtt_ms_ - min_rtt_ms_ : 0.0;
    const bool lossy_queue = judge_loss && loss_ > 0.05 && mean_queue_ms > queue_threshold_ms;
    // What the client actually received over the window (acked wire bytes).
    const double window = now - last_update_;
    const double delivered_kbps = window > 0 ? double(win_acked_bytes_) * 8.0 / 1000.0 / window : 0.0;
    last_update_ = now;
    // This window's span: back from it, until kSpanDatagrams acknowledged.
    push_span(window);
    const double carried = carried_kbps();
    if (hold_ > 0) {
        --hold_;  // let the last back-off take effect before judging again
    } else if ((judge_loss && loss_ > 0.20) || delay_growth || lossy_queue) {
        hold_ = 2;
        slow_start_ = false;
        // Below what the path carries, so that its queue drains, and no
        // lower: a queue that takes longer than the hold to drain backs off
        // again to the same rate, not to 85% of 85%.
        // A long queue (slow start's overshoot into a deep buffer) drains
        // within about a second: to 1 - its seconds of what is carried, at
        // least half.
        const double drain = std::clamp(1.0 - queue_ms / 1000.0, 0.5, kBackoff);
        double e = estimate_kbps_ * 0.8;
        if (carried > 0) e = std::min(estimate_kbps_, drain * carried);
        else if (delivered_kbps > 0) e = std::min(e, 0.95 * delivered_kbps);  // nothing measured over a span yet
        estimate_kbps_ = std::max(kMinKbps, e);
        // A path that became slower is learnt from the last two spans on.
        std::fill(rates_.begin(), rates_.end() - 2, 0.0);
    } else if (limited_) {
        grow(judged, delivered_kbps, queue_ms > 0.5 * queue_threshold_ms, carried);
    }
    // Let the minimum RTT forget after ~10 s so a changed path is learnt:
    // to the smallest of the last 10 s (to the smoothed RTT, as before, a
    // queue that stood at that moment became the path's delay, and no queue
    // showed from then on).
    min_rtt_age_ += 0.25;
    if (min_rtt_age_ > 10.0) {
        min_rtt_age_ = 0;
        min_rtt_ms_ = period_min_rtt_ms_ < 1e9 ? period_min_rtt_ms_ : srtt_ms_ > 0 ? srtt_ms_ : 1e9;
        period_min_rtt_ms_ = 1e9;
    }
    win_acked_ = win_lost_ = win_acked_bytes_ = 0;
    limited_ = false;
    recent_[recent_at_++ % recent_.size()] = estimate_kbps_;
}

// Loss over at least kLossSamples datagrams (or 2 s) since it was last
// judged: whether it is judged now (loss_ then updated).
bool RateController::judge_loss_now(double now) {
    loss_acked_ += win_acked_;
    loss_lost_ += win_lost_;
    const uint64_t loss_judged = loss_acked_ + loss_lost_;
    if (loss_since_ < 0) loss_since_ = last_update_;
    const bool judge = loss_judged >= loss_samples_ || (loss_judged >= 4 && now - loss_since_ >= 2.0);
    if (judge) {
        loss_ = double(loss_lost_) / double(loss_judged);
        loss_acked_ = loss_lost_ = 0;
        loss_since_ = now;
    }
    return judge;
}

// This window's span: back from it, until kSpanDatagrams acknowledged; its
// rate joins rates_ (0 when too few datagrams were acknowledged).
void RateController::push_span(double window) {
    window_at_ = (window_at_ + 1) % kSpanWindows;
    windows_[window_at_] = Window{win_acked_bytes_, win_acked_, window};
    Window span;
    for (size_t k = 0; k < kSpanWindows; ++k) {
        const Window& w = windows_[(window_at_ + kSpanWindows - k) % kSpanWindows];
        span.bytes += w.bytes;
        span.datagrams += w.datagrams;
        span.seconds += w.seconds;
        if (k >= 1 && span.datagrams >= kSpanDatagrams) break;
    }
    std::rotate(rates_.begin(), rates_.begin() + 1, rates_.end());
    rates_.back() = span.datagrams >= kSpanDatagrams && span.seconds > 0 ? double(span.bytes) * 8.0 / 1000.0 / span.seconds : 0.0;
}

// A limited window without congestion: the estimate grows.
void RateController::grow(uint64_t judged, double delivered_kbps, bool queueing, double carried) {
    // Slow start: double while the client keeps up with what was sent
    // (at least half of the target acknowledged in the window; acks lag
    // by one RTT, so not all of it).
    if (slow_start_ && judged >= 4 && delivered_kbps < 0.5 * target_kbps()) slow_start_ = false;
    if (slow_start_ && judged >= 4) {
        estimate_kbps_ = std::min(cap_kbps_, estimate_kbps_ * 2.0);
        return;
    }
    // While the RTT shows a queue building (queueing), slowly (the RTT shows
    // the back-off's threshold before a queue of 200 ms overflows) and by
    // the same step whatever the rate: clients sharing a bottleneck then
    // converge to equal parts (each back-off takes the same fraction of
    // each), where a step in proportion to the rate kept whatever parts
    // they had.
    double e = queueing ? estimate_kbps_ + kQueueingStepKbps : estimate_kbps_ * 1.10 + 4.0;
    if (carried > 0) e = std::min(e, std::max(estimate_kbps_, kProbeGain * carried));  // not far above what gets through
    estimate_kbps_ = std::min(cap_kbps_, e);
}

double RateController::carried_kbps() const {
    double r = 0;
    for (double x : rates_) r = std::max(r, x);
    return r;
}

void RateController::on_path_change() {
    for (auto& s : ring_)
        if (s.valid) s.counted = true;  // neither acked nor lost: sent to a path that is gone
    win_acked_ = win_lost_ = win_acked_bytes_ = 0;
    windows_.fill(Window{});
    rates_.fill(0);
    loss_acked_ = loss_lost_ = 0;
    loss_since_ = -1;
    loss_ = 0;
    srtt_ms_ = window_rtt_ms_ = 0;
    min_rtt_ms_ = win_min_rtt_ms_ = period_min_rtt_ms_ = 1e9;
    min_rtt_age_ = 0;
    hold_ = 0;
    double before = estimate_kbps_;
    for (double e : recent_) before = std::max(before, e);
    estimate_kbps_ = std::clamp(before, kMinKbps, std::max(kMinKbps, cap_kbps_));
    slow_start_ = true;
}

}  // namespace progskin::net
