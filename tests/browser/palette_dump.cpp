// palette_dump.cpp — progskin_palette_dump, the native side of the browser
// test (tests/browser/test_browser.mjs): a progskin::net::Client (plain TCP,
// display snapped to server ticks) that prints, as JSON lines on stdout, the
// palette it displays for every character at every server tick that is a
// multiple of EVERY (once per instance and tick), then a summary line. The
// page records the same (?snap_to_ticks=1&record_every=EVERY) and the test
// compares the two at the same ticks.
//
//   progskin_palette_dump HOST PORT SECONDS EVERY [MAX_KBPS]
//   {"instance":I,"tick":T,"bones":K,"fresh":F,"palette":[12 floats per bone...]}
// (fresh: RemoteCharacter::fresh_bones, the bones shown from a record of tick T)
//   {"summary":{"seconds":S,"wire_bytes":N,"characters":C,"bones_mean":B,"first_shown_after":S,"loss":L,"datagrams":N}}
// PROGSKIN_PIN set: TLS, trusting the certificate with that SHA-256;
// PROGSKIN_CACHE: the asset cache. Exit 1 when the client failed (the reason on stderr), 2 for bad arguments.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <set>
#include <string>
#include <thread>
#include <utility>

#include "client.h"

using namespace progskin::net;

int main(int argc, char** argv) {
    if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
        std::puts("usage: progskin_palette_dump HOST PORT SECONDS EVERY [MAX_KBPS]\n"
                  "Prints the displayed palette of every character at every EVERY-th server tick (JSON lines).");
        return 0;
    }
    if (argc < 5 || argc > 6) {
        std::fputs("usage: progskin_palette_dump HOST PORT SECONDS EVERY [MAX_KBPS]\n", stderr);
        return 2;
    }
    const int port = std::atoi(argv[2]), every = std::atoi(argv[4]);
    const double seconds = std::atof(argv[3]), kbps = argc == 6 ? std::atof(argv[5]) : 0;
    if (port <= 0 || port > 65535 || every <= 0 || !(seconds > 0 && seconds <= 600) || !(kbps >= 0)) {
        std::fputs("progskin_palette_dump: PORT 1..65535, SECONDS in (0, 600], EVERY >= 1, MAX_KBPS >= 0\n", stderr);
        return 2;
    }
    ClientConfig cfg;
    cfg.name = "progskin-palette-dump";
    cfg.snap_to_ticks = true;
    cfg.max_kbps = kbps;
    if (const char* c = std::getenv("PROGSKIN_CACHE")) cfg.cache_dir = c;
    if (const char* pin = std::getenv("PROGSKIN_PIN"); pin && *pin) {  // a TLS server: its certificate's SHA-256
        cfg.tls = true;
        cfg.pin_sha256 = pin;
    }
    Client client(cfg);
    client.connect(argv[1], uint16_t(port));
    std::set<std::pair<int, long>> done;
    double first = -1;
    const double start = now_seconds();
    double bones_sum = 0;
    long bones_n = 0;
    size_t shown = 0;
    for (;;) {
        const double now = now_seconds();
        client.update(now);
        if (client.state() == ClientState::Failed) {
            std::fprintf(stderr, "progskin_palette_dump: %s\n", client.error().c_str());
            return 1;
        }
        shown = 0;
        for (const RemoteCharacter& c : client.characters()) {
            if (!c.shown) continue;
            ++shown;
            bones_sum += c.bones;
            ++bones_n;
            const double t = c.display_tick;
            const long tick = std::lround(t);
            if (std::abs(t - double(tick)) > 1e-6 || tick % every != 0 || !done.insert({c.instance, tick}).second) continue;
            std::printf("{\"instance\":%d,\"tick\":%ld,\"bones\":%d,\"fresh\":%d,\"palette\":[", c.instance, tick, c.bones,
                        c.fresh_bones);
            for (size_t b = 0; b < c.palette.size(); ++b)
                for (int k = 0; k < 12; ++k) std::printf("%s%.9g", b || k ? "," : "", double(c.palette[b].m[k]));
            std::puts("]}");
        }
        if (shown && first < 0) first = now;
        if (now - start > seconds) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(4));
    }
    const ClientStats st = client.stats();
    std::printf("{\"summary\":{\"seconds\":%.3f,\"wire_bytes\":%llu,\"characters\":%zu,\"bones_mean\":%.3f,"
                "\"first_shown_after\":%.3f,\"loss\":%.6f,\"datagrams\":%llu}}\n",
                st.seconds, (unsigned long long)st.wire_bytes, shown, bones_n ? bones_sum / double(bones_n) : 0.0,
                first < 0 ? -1.0 : first - start, st.loss, (unsigned long long)st.datagrams);
    client.close();
    return 0;
}
