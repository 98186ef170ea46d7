// attack_main.cpp — progskin-attack: the hostile mix of scripts/soak.sh
// against a progskin-server on this machine (loopback only: it connects
// from 127.0.0.2, 127.0.0.3, ... as many players). Built from the attacker
// of the hardening tests (tests/net_attacker.h); not installed.
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "cli_args.h"
#include "net_attacker.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

static const char* kUsage =
    "usage: progskin-attack --server 127.0.0.1:PORT [options]\n"
    "Attacks a progskin-server on this machine the way a hostile player would, from the\n"
    "loopback addresses 127.0.0.2 onwards, for the soak (scripts/soak.sh): an ordinary TLS\n"
    "client trusting anything, sealing its own datagrams with its Welcome's keys.\n"
    "\n"
    "  --server 127.0.0.1:PORT  the server's TCP port (its UDP port comes in the Welcome)\n"
    "  --duration S       seconds of attack (default 60)\n"
    "  --addresses N      source addresses 127.0.0.2 .. 127.0.0.(N+1) (default 4)\n"
    "  --posers N         sessions that spawn 16 characters each, pose them every tick,\n"
    "                     send a View of 4,096 weights and Ack everything (default 8)\n"
    "  --churn N          sessions that join, spawn, leave and join again (default 4)\n"
    "  --handshakes N     connections that never finish their TLS handshake (default 200)\n"
    "  --squatters N      sessions that never bind and rejoin whenever dropped (default 16)\n"
    "  --pullers N        sessions that download the assets and reconnect (default 1)\n"
    "  --no-tls           the server speaks plain TCP (--no-tls)\n"
    "  --help\n"
    "Prints a JSON summary on stdout. Exit codes: 0 done, 1 no session ever joined, 2 bad arguments.\n";

namespace {

struct Options {
    uint16_t port = 0;
    double duration = 60;
    int addresses = 4, posers = 8, churn = 4, handshakes = 200, squatters = 16, pullers = 1;
    bool tls = true;
};

int parse(int argc, char** argv, Options& o) {
    try {
        for (int i = 1; i < argc; ++i) {
            const std::string a = argv[i];
            auto need = [&]() -> std::string {
                if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
                return argv[++i];
            };
            if (a == "--help" || a == "-h") {
                std::fputs(kUsage, stdout);
                return 0;
            } else if (a == "--server") {
                o.port = loopback_port(a, need(), "the attack runs on loopback");
            } else if (a == "--duration") o.duration = cli::to_number(a, need());
            else if (a == "--addresses") o.addresses = cli::to_int(a, need());
            else if (a == "--posers") o.posers = cli::to_int(a, need());
            else if (a == "--churn") o.churn = cli::to_int(a, need());
            else if (a == "--handshakes") o.handshakes = cli::to_int(a, need());
            else if (a == "--squatters") o.squatters = cli::to_int(a, need());
            else if (a == "--pullers") o.pullers = cli::to_int(a, need());
            else if (a == "--no-tls") o.tls = false;
            else throw std::invalid_argument("unknown argument " + a);
        }
        if (o.port == 0) throw std::invalid_argument("--server is required");
        if (!(o.duration > 0)) throw std::invalid_argument("--duration must be > 0");
        if (o.addresses < 1 || o.addresses > 250) throw std::invalid_argument("--addresses must be 1..250");
        const std::pair<const char*, int> counts[] = {{"--posers", o.posers},         {"--churn", o.churn},
                                                      {"--handshakes", o.handshakes}, {"--squatters", o.squatters},
                                                      {"--pullers", o.pullers}};
        for (const auto& [name, n] : counts)
            if (n < 0) throw std::invalid_argument(std::string(name) + " must be >= 0");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin-attack: %s\n%s", e.what(), kUsage);
        return 2;
    }
    return -1;
}

struct Counts {
    uint64_t joins = 0, join_failures = 0, spawned = 0, spawn_refused = 0, handshakes_opened = 0, asset_bytes = 0, frames = 0;
};

class Mix {
public:
    explicit Mix(const Options& o) : o_(o) {
        int k = 0;
        auto make = [&](int n, std::vector<std::unique_ptr<Attacker>>& v) {
            for (int i = 0; i < n; ++i, ++k)
                v.push_back(std::make_unique<Attacker>("127.0.0." + std::to_string(2 + k % o.addresses), o.port, 0, o.tls));
        };
        make(o.posers, posers_);
        make(o.churn, churn_);
        make(o.handshakes, idle_);
        make(o.squatters, squat_);
        make(o.pullers, pull_);
    }

    void run() {
        const double end = now_seconds() + o_.duration;
        double churn_at = 0, idle_at = 0;
        while (now_seconds() < end) {
            const double now = now_seconds();
            for (auto& a : posers_) poser(*a);
            if (now >= churn_at) {  // every half second: one churner leaves and joins again, stalled handshakes topped up
                churn_at = now + 0.5;
                if (!churn_.empty()) churner(*churn_[next_churn_++ % churn_.size()]);
                for (auto& a : squat_)
                    if (!a->welcomed() || a->server_closed()) join(*a);
                for (auto& a : pull_) puller(*a);
            }
            if (now >= idle_at) {  // one byte per second on each stalled handshake; reopened when closed
                idle_at = now + 1.0;
                for (auto& a : idle_) {
                    a->open_idle({0x16});
                    ++c_.handshakes_opened;
                }
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(30));
        }
    }

    int report() const {
        std::printf("{\"joins\": %llu, \"join_failures\": %llu, \"characters_spawned\": %llu, \"spawns_refused\": %llu, "
                    "\"handshakes_opened\": %llu, \"asset_bytes\": %llu, \"frames\": %llu}\n",
                    (unsigned long long)c_.joins, (unsigned long long)c_.join_failures, (unsigned long long)c_.spawned,
                    (unsigned long long)c_.spawn_refused, (unsigned long long)c_.handshakes_opened,
                    (unsigned long long)c_.asset_bytes, (unsigned long long)c_.frames);
        return c_.joins > 0 ? 0 : 1;
    }

private:
    bool join(Attacker& a) {
        const bool ok = a.join(500);
        ++(ok ? c_.joins : c_.join_failures);
        return ok;
    }
    void spawn(Attacker& a, int n) {
        for (int i = 0; i < n && !a.server_closed(); ++i) ++(a.spawn(i % int(a.assets().size()), {}, 300) >= 0 ? c_.spawned : c_.spawn_refused);
    }
    void poser(Attacker& a) {
        if (!a.welcomed() || a.server_closed()) {
            if (!join(a) || !a.bind(500)) return;
            spawn(a, MAX_SPAWNED);
            a.view(MAX_VIEW_WEIGHTS);
        }
        a.pose_all();
        c_.frames += a.pump_and_ack();
    }
    void churner(Attacker& a) {
        a.disconnect();
        if (join(a) && a.bind(300)) spawn(a, 1);
    }
    void puller(Attacker& a) {
        if (!join(a)) return;
        for (size_t i = 0; i < a.assets().size() && !a.server_closed(); ++i) c_.asset_bytes += a.pull_asset(int(i), 300);
    }

    const Options& o_;
    std::vector<std::unique_ptr<Attacker>> posers_, churn_, idle_, squat_, pull_;
    size_t next_churn_ = 0;
    Counts c_;
};

}  // namespace

int main(int argc, char** argv) {
    Options o;
    if (int rc = parse(argc, argv, o); rc >= 0) return rc;
    Mix mix(o);
    mix.run();
    return mix.report();
}
