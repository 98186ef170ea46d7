// The pacing of RateController (server/rate_controller.h) on its own: a
// sender that always uses the whole budget, at 30 ticks per second, never
// acknowledged (the estimate stays at the cap).
#include <gtest/gtest.h>

#include <algorithm>
#include <deque>

#include "rate_controller.h"
#include "wire.h"

using namespace progskin::net;

TEST(NetRate, PacingStaysUnderTheCapAndSlowLinksGetFullerDatagrams) {
    for (double cap : {8.0, 16.0, 24.0, 32.0, 64.0, 256.0, 2000.0}) {
        RateController rc(cap, cap);
        std::deque<size_t> window;  // wire bytes of the last 30 ticks
        size_t window_bytes = 0, max_window = 0, total = 0, datagrams = 0, smallest = SIZE_MAX;
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
            window.push_back(sent);
            window_bytes += sent;
            if (window.size() > 30) {
                window_bytes -= window.front();
                window.pop_front();
            }
            max_window = std::max(max_window, window_bytes);
        }
        const double second = cap * 125.0;
        EXPECT_LE(double(max_window), 1.04 * second + 1.0) << "cap " << cap;
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
