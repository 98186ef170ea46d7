// The pacing of RateController (server/rate_controller.h) on its own: a
// sender that always uses the whole budget, at 30 ticks per second, never
// acknowledged (the estimate stays at the cap).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <deque>
#include <vector>

#include "rate_controller.h"
#include "wire.h"

using namespace progskin::net;

namespace {

// The largest one-second window (30 ticks) of wire bytes sent.
struct SecondWindow {
    std::deque<size_t> ticks;
    size_t bytes = 0, most = 0;
    void add(size_t sent) {
        ticks.push_back(sent);
        bytes += sent;
        if (ticks.size() > 30) {
            bytes -= ticks.front();
            ticks.pop_front();
        }
        most = std::max(most, bytes);
    }
};

}  // namespace

TEST(NetRate, PacingStaysUnderTheCapAndSlowLinksGetFullerDatagrams) {
    for (double cap : {8.0, 16.0, 24.0, 32.0, 64.0, 256.0, 2000.0}) {
        RateController rc(cap, cap);
        SecondWindow window;
        size_t total = 0, datagrams = 0, smallest = SIZE_MAX;
        const int ticks = 30 * 20;
        for (int t = 0; t < ticks; ++t) {
            rc.refill(1.0 / 30.0);
            size_t sent = 0;
            for (size_t b = rc.budget(); b > 0; b = rc.budget()) {
                const size_t d = std::min(b, MAX_DATAGRAM + UDP_IP_OVERHEAD);
                rc.spend(d);
                sent += d;
                ++datagrams;
                smallest = std::min(smallest, d);
                if (d < MAX_DATAGRAM + UDP_IP_OVERHEAD) break;
            }
            total += sent;
            window.add(sent);
        }
        const double second = cap * 125.0;
        EXPECT_LE(double(window.most), 1.04 * second + 1.0) << "cap " << cap;
        EXPECT_GE(double(total) / 20.0, 0.55 * second) << "cap " << cap;
        if (cap >= 64) {
            EXPECT_GE(double(total) / 20.0, 0.9 * second) << "cap " << cap;
        }
        // Slow links: datagrams of about 400 bytes, so the 108 bytes of
        // datagram headers stay about a quarter of them.
        if (cap <= 32) {
            EXPECT_GE(double(smallest), std::min(350.0, 0.34 * second)) << "cap " << cap;
        }
        EXPECT_GT(datagrams, 0u);
    }
}

// Below 80 kbit/s a tick sends once the bucket holds a fuller datagram
// (kFullerBytes); after a loss (expedite) the next tick that holds one
// tick's fill sends, once, and the pacing bound holds all the same.
TEST(NetRate, ALossSendsTheNextDatagramATickAfterIt) {
    RateController rc(64, 64);
    SecondWindow window;
    int last_send = -1, sends = 0;
    std::vector<int> plain_gaps, expedited_gaps;
    for (int t = 0; t < 30 * 20; ++t) {
        rc.refill(1.0 / 30.0);
        size_t sent = 0;
        if (const size_t b = rc.budget(); b > 0) {
            const bool expedited = rc.expedited();
            const size_t d = std::min(b, MAX_DATAGRAM + UDP_IP_OVERHEAD);
            rc.spend(d);
            EXPECT_FALSE(rc.expedited()) << "a send ends the expedite";
            sent = d;
            if (last_send >= 0 && t > 60) (expedited ? expedited_gaps : plain_gaps).push_back(t - last_send);
            last_send = t;
            // Every fourth datagram is found lost right after it went.
            if (++sends % 4 == 0) rc.expedite();
        }
        window.add(sent);
    }
    ASSERT_FALSE(plain_gaps.empty());
    ASSERT_FALSE(expedited_gaps.empty());
    // Fuller datagrams: 750 bytes take more than three ticks' fill at 64 kbit/s.
    for (int g : plain_gaps) EXPECT_GE(g, 3);
    for (int g : expedited_gaps) EXPECT_EQ(g, 1);
    EXPECT_LE(double(window.most), 1.04 * 64 * 125.0 + 1.0);
}

namespace {

// Seconds until an unlimited link carries 90% of what the sender wants
// (demand_kbps), starting from the server's initial estimate (1 Mbit/s): 30
// ticks per second, the sender sends min(budget, demand) in datagrams of at
// most MAX_DATAGRAM, every datagram acknowledged 2 ms later (the next tick).
// Measured over sliding 250 ms windows of delivered bytes.
double seconds_to_90_percent(double demand_kbps, bool slow_start) {
    RateController rc(50000, 1000);
    rc.set_slow_start(slow_start);
    const double tick = 1.0 / 30.0;
    uint32_t seq = 0;
    std::vector<uint32_t> to_ack;
    std::deque<size_t> window;  // bytes per tick, last 7.5 ticks ~ 250 ms
    size_t window_bytes = 0;
    double demand_bytes = demand_kbps * 125.0 * tick, backlog = 0;
    for (int t = 0; t < 30 * 20; ++t) {
        const double now = t * tick;
        const uint32_t now_us = uint32_t(now * 1e6);
        // Acks of the previous tick's datagrams (one cumulative ack with bits).
        if (!to_ack.empty()) {
            const uint32_t last = to_ack.back();
            uint32_t bits = 0;
            for (uint32_t s : to_ack)
                if (s != last && last - s <= 32) bits |= 1u << (last - s - 1);
            rc.on_ack(last, bits, now_us - 2000, 0, now_us);
            to_ack.clear();
        }
        rc.update(now);
        rc.refill(tick);
        backlog = demand_bytes;  // what this tick's frame holds; the rest waits for the next tick
        size_t sent = 0;
        for (size_t b = rc.budget(); b > 0 && backlog > 0; b = rc.budget()) {
            const size_t d = size_t(std::min({double(b), double(MAX_DATAGRAM + UDP_IP_OVERHEAD), backlog}));
            if (d == 0) break;
            rc.spend(d);
            rc.on_sent(++seq, now_us, d);
            to_ack.push_back(seq);
            sent += d;
            backlog -= double(d);
        }
        if (backlog > 1) rc.mark_limited();
        window.push_back(sent);
        window_bytes += sent;
        if (window.size() > 8) {
            window_bytes -= window.front();
            window.pop_front();
        }
        const double rate_kbps = double(window_bytes) * 8.0 / 1000.0 / (double(window.size()) * tick);
        if (window.size() == 8 && rate_kbps >= 0.9 * demand_kbps) return now;
    }
    return 1e9;
}

}  // namespace

TEST(NetRate, SlowStartReachesAnUnlimitedLinkFast) {
    for (double demand : {2300.0, 10000.0}) {
        const double before = seconds_to_90_percent(demand, false);
        const double after = seconds_to_90_percent(demand, true);
        std::printf("unlimited link, sender wants %.0f kbit/s: 90%% after %.2f s with slow start, %.2f s without\n",
                    demand, after, before);
        EXPECT_LT(after, before);
        EXPECT_LE(after, 1.5) << demand;
    }
}

TEST(NetRate, SlowStartEndsAtTheFirstLoss) {
    RateController rc(50000, 1000);
    ASSERT_TRUE(rc.in_slow_start());
    uint32_t seq = 0;
    // A window in which nothing is acknowledged but later datagrams are: loss.
    for (int t = 0; t < 15; ++t) {
        rc.refill(1.0 / 30.0);
        for (size_t b = rc.budget(); b > 0; b = rc.budget()) {
            const size_t d = std::min(b, MAX_DATAGRAM + UDP_IP_OVERHEAD);
            rc.spend(d);
            rc.on_sent(++seq, uint32_t(t * 33333), d);
        }
        rc.mark_limited();
        rc.update(t / 30.0);
    }
    rc.on_ack(seq, 0, uint32_t(14 * 33333), 0, uint32_t(15 * 33333));  // only the newest arrived
    const double before = rc.estimate_kbps();
    rc.update(1.0);
    EXPECT_FALSE(rc.in_slow_start());
    EXPECT_LT(rc.estimate_kbps(), before);
}

// Random loss is not congestion: at 10 % loss on a link of about a datagram
// per tick, judged over a 250 ms window (8 datagrams) the estimate backed
// off in almost every 10 s run; judged over kLossSamples it backs off in
// few (each judgement of 32 reads over 20 % about one time in 24). Loss of
// 40 % still backs off within 2 s.
TEST(NetRate, RandomLossOfTenPercentRarelyBacksOff) {
    // One run: the smallest estimate and the time of the first back-off (-1: none).
    auto run = [](uint32_t seed, double loss, double seconds, uint64_t samples = RateController::kLossSamples) {
        RateController rc(300, 300);
        rc.set_slow_start(false);
        rc.set_loss_samples(samples);
        uint32_t seq = 0, rng = seed * 2654435761u + 1;
        std::vector<bool> got(1, false);
        double lowest = rc.estimate_kbps(), first_backoff = -1;
        for (double t = 0; t < seconds; t += 1.0 / 30.0) {
            rc.refill(1.0 / 30.0);
            uint32_t newest = 0;
            for (size_t b = rc.budget(); b > 0; b = rc.budget()) {
                const size_t d = std::min(b, MAX_DATAGRAM + UDP_IP_OVERHEAD);
                rc.spend(d);
                rc.on_sent(++seq, uint32_t(t * 1e6), d);
                rng = rng * 1664525u + 1013904223u;
                got.push_back(double(rng >> 8) / double(1u << 24) >= loss);
                if (got.back()) newest = seq;
            }
            if (newest) {  // one Ack per tick: the newest received and the 32 before
                uint32_t bits = 0;
                for (uint32_t i = 0; i < 32 && i + 1 < newest; ++i)
                    if (got[newest - 1 - i]) bits |= 1u << i;
                rc.on_ack(newest, bits, uint32_t(t * 1e6), 0, uint32_t(t * 1e6) + 20000);
            }
            rc.mark_limited();
            const double before = rc.estimate_kbps();
            rc.update(t);
            if (rc.estimate_kbps() < before && first_backoff < 0) first_backoff = t;
            lowest = std::min(lowest, rc.estimate_kbps());
        }
        return std::make_pair(lowest, first_backoff);
    };
    // Runs of 10 s at 10 % loss that backed off, of 20 seeds, and the lowest estimate.
    auto runs = [&](uint64_t samples) {
        int backed_off = 0;
        double lowest = 1e9;
        for (uint32_t seed = 1; seed <= 20; ++seed) {
            const auto [low, at] = run(seed, 0.10, 10.0, samples);
            backed_off += at >= 0 ? 1 : 0;
            lowest = std::min(lowest, low);
        }
        std::printf("10 %% random loss, judged over %llu datagrams: %d of 20 runs of 10 s backed off, lowest estimate %.0f kbit/s (cap 300)\n",
                    (unsigned long long)samples, backed_off, lowest);
        return backed_off;
    };
    runs(4);  // the rule before (for the record: docs/performance.md)
    const int backed_off = runs(RateController::kLossSamples);
    EXPECT_LE(backed_off, 12);
    for (uint32_t seed = 1; seed <= 5; ++seed) {
        const auto [low, at] = run(seed, 0.40, 3.0);
        EXPECT_GE(at, 0.0) << "40 % loss, seed " << seed;
        EXPECT_LE(at, 2.25) << "40 % loss, seed " << seed;
    }
}

// A NAT rebinding: what went to the old address was neither acked nor lost
// to congestion. on_path_change forgets it and restores the estimate held
// before the switch, instead of backing off to what got through (nothing).
TEST(NetRate, RebindingRestoresTheRateHeldBeforeIt) {
    auto run = [](bool path_change) {
        RateController rc(50000, 400);
        rc.set_slow_start(false);
        uint32_t seq = 0;
        double t = 0;
        std::vector<bool> got(1, false);  // per seq: delivered
        auto tick = [&](bool delivered) {
            rc.refill(1.0 / 30.0);
            for (size_t b = rc.budget(); b > 0; b = rc.budget()) {
                const size_t d = std::min(b, MAX_DATAGRAM + UDP_IP_OVERHEAD);
                rc.spend(d);
                rc.on_sent(++seq, uint32_t(t * 1e6), d);
                got.push_back(delivered);
                if (!delivered) continue;
                uint32_t bits = 0;  // what the client received of the 32 before
                for (uint32_t i = 0; i < 32 && i + 1 < seq; ++i)
                    if (got[seq - 1 - i]) bits |= 1u << i;
                rc.on_ack(seq, bits, uint32_t(t * 1e6), 0, uint32_t(t * 1e6) + 2000);
            }
            rc.mark_limited();
            rc.update(t);
            t += 1.0 / 30.0;
        };
        for (int i = 0; i < 60; ++i) tick(true);  // 2 s on the old path
        const double before = rc.estimate_kbps();
        for (int i = 0; i < 33; ++i) tick(false);  // 1.1 s sent to an address that is gone
        if (path_change) rc.on_path_change();
        for (int i = 0; i < 15; ++i) tick(true);  // 0.5 s on the new path
        return std::make_pair(before, rc.estimate_kbps());
    };
    const auto [before, kept] = run(true);
    const auto [before_old, collapsed] = run(false);
    std::printf("rebinding: estimate %.0f kbit/s before, %.0f after 0.5 s on the new path (%.0f without on_path_change)\n", before,
                kept, collapsed);
    EXPECT_GE(kept, 0.95 * before);
    EXPECT_LT(collapsed, 0.75 * before_old);  // what the loss would have done
}

// Caps of a few kbit/s (the wire's smallest is 1): the bucket still holds a
// datagram worth sending (kMinDatagramBytes; it held 44 bytes at 1 kbit/s and
// 131 at 3, less than any frame: nothing was ever sent), one goes out every
// 2 s at most, and the mean rate stays under the cap.
TEST(NetRate, ASlowCapStillSendsADatagramEveryTwoSeconds) {
    for (double cap : {1.0, 2.0, 3.0, 5.0}) {
        RateController rc(cap, cap);
        size_t total = 0, datagrams = 0, smallest = SIZE_MAX;
        int last = 0, longest_gap = 0;
        const int ticks = 30 * 60;
        for (int t = 0; t < ticks; ++t) {
            rc.refill(1.0 / 30.0);
            if (const size_t b = rc.budget(); b > 0) {
                rc.spend(b);
                total += b;
                ++datagrams;
                smallest = std::min(smallest, b);
                longest_gap = std::max(longest_gap, t - last);
                last = t;
            }
        }
        const double second = cap * 125.0;
        EXPECT_GT(datagrams, 0u) << "cap " << cap;
        EXPECT_GE(double(smallest), 0.9 * RateController::kMinDatagramBytes) << "cap " << cap;  // less one tick's fill
        EXPECT_LE(longest_gap, 2 * 30 + 1) << "cap " << cap;
        EXPECT_LE(double(total) / 60.0, second) << "cap " << cap;
        EXPECT_GE(double(total) / 60.0, 0.8 * second) << "cap " << cap;
    }
}

namespace {

// Senders behind one bottleneck: a FIFO link of `link_kbps` that drops what
// arrives while more than `queue_ms` of bytes wait (as progskin-netem
// --rate-kbps --queue-ms), `delay_ms` each way, 30 ticks per second, each
// sender starting at its own time and always wanting `demand_kbps`, its
// client acknowledging each tick what arrived (with its hold time, as
// ClientSession does). The senders take turns to send first in a tick.
// Figures per sender over the seconds from `from` on.
struct Bottleneck {
    double delivered_kbps = 0, loss = 0, lowest_estimate = 1e9, mean_queue_ms = 0;
};

std::vector<Bottleneck> through_bottleneck(double link_kbps, double queue_ms, double delay_ms, double demand_kbps,
                                           std::vector<double> starts = {0.0}, double seconds = 40, double from = 5) {
    struct InFlight {
        size_t sender;
        uint32_t seq;
        double arrive, sent;
        size_t bytes;
    };
    struct AckMsg {
        double at;
        uint32_t ack, bits;
        double echo, hold;
    };
    struct Sender {
        RateController rc{100000, 1000};
        std::deque<AckMsg> acks;
        std::vector<bool> got = std::vector<bool>(1, false);
        double credit = 0, newest_sent = 0, newest_arrive = 0, queued_ms = 0;
        uint32_t seq = 0, newest = 0;
        size_t delivered = 0, sent = 0, dropped = 0, queued = 0;
        Bottleneck r;
    };
    std::vector<Sender> senders(starts.size());
    std::deque<InFlight> link;
    double link_free = 0;
    const double tick = 1.0 / 30.0;
    for (int k = 0; k * tick < seconds; ++k) {
        const double t = k * tick;
        const bool measured = t >= from;
        while (!link.empty() && link.front().arrive <= t) {
            const InFlight p = link.front();
            link.pop_front();
            Sender& s = senders[p.sender];
            s.got[p.seq] = true;
            if (measured) s.delivered += p.bytes;
            if (p.seq > s.newest) {
                s.newest = p.seq;
                s.newest_sent = p.sent;
                s.newest_arrive = p.arrive;
            }
        }
        for (size_t turn = 0; turn < senders.size(); ++turn) {
            const size_t i = (turn + size_t(k)) % senders.size();
            Sender& s = senders[i];
            if (t < starts[i]) continue;
            RateController& rc = s.rc;
            if (s.newest) {
                uint32_t bits = 0;
                for (uint32_t j = 0; j < 32 && j + 1 < s.newest; ++j)
                    if (s.got[s.newest - 1 - j]) bits |= 1u << j;
                s.acks.push_back({t + delay_ms / 1000, s.newest, bits, s.newest_sent, t - s.newest_arrive});
            }
            while (!s.acks.empty() && s.acks.front().at <= t) {
                const AckMsg a = s.acks.front();
                s.acks.pop_front();
                rc.on_ack(a.ack, a.bits, uint32_t(a.echo * 1e6), uint32_t(a.hold * 1e6), uint32_t(a.at * 1e6));
            }
            rc.refill(tick);
            rc.update(t);
            if (measured) s.r.lowest_estimate = std::min(s.r.lowest_estimate, rc.estimate_kbps());
            s.credit = std::min(s.credit + demand_kbps * 125.0 * tick, 5000.0);
            if (s.credit > double(rc.budget()) + 100) rc.mark_limited();  // the scheduler had more than the budget
            for (size_t b = rc.budget(); b > 0 && s.credit > 100; b = rc.budget()) {
                const size_t d = std::min<size_t>({b, MAX_DATAGRAM + UDP_IP_OVERHEAD, size_t(s.credit) + 60});
                rc.spend(d);
                s.credit -= double(d);
                rc.on_sent(++s.seq, uint32_t(t * 1e6), d);
                s.got.push_back(false);
                if (measured) ++s.sent;
                link_free = std::max(link_free, t);
                if (link_free - t > queue_ms / 1000) {
                    if (measured) ++s.dropped;
                    continue;
                }
                link_free += double(d) * 8.0 / (link_kbps * 1000.0);
                if (measured) {
                    s.queued_ms += 1000 * (link_free - t);
                    ++s.queued;
                }
                link.push_back({i, s.seq, link_free + delay_ms / 1000, t, d});
            }
        }
    }
    std::vector<Bottleneck> out;
    for (Sender& s : senders) {
        s.r.delivered_kbps = double(s.delivered) * 8.0 / 1000.0 / (seconds - from);
        s.r.loss = s.sent ? double(s.dropped) / double(s.sent) : 0.0;
        s.r.mean_queue_ms = s.queued ? s.queued_ms / double(s.queued) : 0.0;
        out.push_back(s.r);
    }
    return out;
}

}  // namespace

// A link slower than the sender wants (docs/performance.md "Behind a capped
// bottleneck"): the estimate settles near the link's rate instead of
// swinging far above it and, after the back-offs, far below (to 95% of one
// 250 ms window's deliveries, the estimate fell to 3-7 kbit/s behind a 48
// kbit/s link with a 1 s queue, and carried 55-60% of it).
TEST(NetRate, ABottleneckIsFilledWithoutCollapsing) {
    struct Link {
        double kbps, queue_ms, delay_ms, demand;
    };
    for (const Link l : {Link{64, 200, 10, 110}, Link{48, 1000, 10, 110}, Link{32, 500, 20, 110}, Link{256, 100, 10, 400},
                         Link{1000, 50, 5, 3000}}) {
        const Bottleneck b = through_bottleneck(l.kbps, l.queue_ms, l.delay_ms, l.demand)[0];
        std::printf("link %4.0f kbit/s, %4.0f ms queue: delivered %6.1f kbit/s (%3.0f %%), loss %.3f, mean queue %3.0f ms, lowest estimate %.1f\n",
                    l.kbps, l.queue_ms, b.delivered_kbps, 100 * b.delivered_kbps / l.kbps, b.loss, b.mean_queue_ms, b.lowest_estimate);
        EXPECT_GE(b.delivered_kbps, 0.85 * l.kbps) << l.kbps << " kbit/s";
        EXPECT_LE(b.loss, 0.10) << l.kbps << " kbit/s";
        EXPECT_GE(b.lowest_estimate, 0.5 * l.kbps) << l.kbps << " kbit/s";
    }
}

// Two clients behind one bottleneck (a household's link): the second, which
// starts 5 s later into the first one's queue, gets a fair part of it. With
// the controller before 2026-11-28 the first kept the link (90 and 11 kbit/s
// at 128, 212 and 23 at 256): its back-offs went to what the last window
// delivered, and its minimum RTT forgot to the smoothed RTT, so a standing
// queue became the path's delay and no queue showed from then on.
TEST(NetRate, TwoClientsShareABottleneck) {
    struct Link {
        double kbps, queue_ms, delay_ms, demand;
    };
    for (const Link l : {Link{128, 200, 10, 110}, Link{256, 200, 10, 400}, Link{1000, 200, 5, 2000}}) {
        const std::vector<Bottleneck> b = through_bottleneck(l.kbps, l.queue_ms, l.delay_ms, l.demand, {0.0, 5.0}, 60, 10);
        std::printf("link %4.0f kbit/s, %3.0f ms queue, two clients: %6.1f and %6.1f kbit/s, loss %.3f and %.3f\n", l.kbps,
                    l.queue_ms, b[0].delivered_kbps, b[1].delivered_kbps, b[0].loss, b[1].loss);
        EXPECT_GE(b[0].delivered_kbps + b[1].delivered_kbps, 0.85 * l.kbps) << l.kbps << " kbit/s";
        for (const Bottleneck& x : b) {
            EXPECT_GE(x.delivered_kbps, 0.25 * l.kbps) << l.kbps << " kbit/s";
            EXPECT_LE(x.loss, 0.10) << l.kbps << " kbit/s";
        }
    }
}
