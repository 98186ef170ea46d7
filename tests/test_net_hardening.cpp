// test_net_hardening.cpp — "Hardening, round two: one player must never be
// able to hurt the others" (docs/protocol.md "Security"), each case on
// loopback with real sockets, TLS and sealed datagrams: the attacker is an
// ordinary TLS client sealing its own datagrams with the keys its own
// Welcome gave it (tests/net_attacker.h), from several loopback addresses,
// while an honest progskin client streams beside it. Every test fails on the
// server before these defences (the refusal it asserts was not there, or the
// honest client was dropped).
#include <gtest/gtest.h>
#include <poll.h>

#include <atomic>
#include <cstdio>
#include <numeric>
#include <thread>

#include "errors.h"
#include "net_attacker.h"
#include "net_test_support.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

namespace {

const std::string kCert = std::string(PROGSKIN_TEST_DATA) + "/tls/test_cert.pem";  // CN localhost, SAN 127.0.0.1
const std::string kKey = std::string(PROGSKIN_TEST_DATA) + "/tls/test_key.pem";

// The programs' defaults: TLS and sealed datagrams.
ServerConfig hardened(ServerConfig cfg = {}) {
    cfg.tls_cert_file = kCert;
    cfg.tls_key_file = kKey;
    cfg.seal_datagrams = true;
    return cfg;
}

ClientOptions honest_options(const RunningServer& s, double duration) {
    ClientOptions o = s.client(duration);
    o.tls = true;
    o.ca_file = kCert;
    o.name = "honest";
    return o;
}

// An honest progskin client on its own thread.
struct Honest {
    ClientReport report;
    std::string error;
    std::thread thread;
    explicit Honest(ClientOptions o) {
        thread = std::thread([this, o] {
            try {
                report = run_client(o);
            } catch (const std::exception& e) {
                error = e.what();
            }
        });
    }
    ~Honest() {
        if (thread.joinable()) thread.join();
    }
    void join() { thread.join(); }
    double mean(size_t from, size_t to) const {  // per-second rate over bins [from, to)
        to = std::min(to, report.per_second_kbps.size());
        if (from >= to) return 0;
        return std::accumulate(report.per_second_kbps.begin() + long(from), report.per_second_kbps.begin() + long(to), 0.0) /
               double(to - from);
    }
    void print(const char* what) const {
        std::printf("%s: honest client %s, %.0f kbit/s, longest gap %.0f ms, per second:", what, error.empty() ? "ok" : error.c_str(),
                    report.rate_kbps, report.max_gap_ms);
        for (double k : report.per_second_kbps) std::printf(" %.0f", k);
        std::printf("\n");
    }
};

// The assets in the shared cache, so that honest clients bind at once.
void warm(const RunningServer& s) { run_client(honest_options(s, 0.3)); }

uint64_t refusals(const RunningServer& s, const std::string& reason) {
    const ServerStats st = s.server->stats();
    auto it = st.refusals.find(reason);
    return it == st.refusals.end() ? 0 : it->second;
}

std::string source(int n) { return "127.0.0." + std::to_string(n); }

// Keeps attackers streaming: poses (when asked) and Acks every ~33 ms for `seconds`.
void keep_alive(std::vector<std::unique_ptr<Attacker>>& as, double seconds, bool pose) {
    const double end = now_seconds() + seconds;
    while (now_seconds() < end) {
        for (auto& a : as) {
            if (!a->welcomed()) continue;
            if (pose) a->pose_all();
            a->pump_and_ack();
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(30));
    }
}

}  // namespace

// Case 1: a Spawn of 16,000 clip indices (repeats included) made an
// InstanceAdded no client could accept: every client exited 1. Now such a
// Spawn is refused (more than MAX_INSTANCE_CLIPS, or a clip repeated), and
// nobody is disconnected, nor anybody who joins afterwards.
TEST(NetHardening, HugeSpawnsAreRefusedAndNobodyIsDropped) {
    RunningServer s({}, hardened());
    warm(s);
    Honest honest(honest_options(s, 5.0));
    std::this_thread::sleep_for(std::chrono::milliseconds(1000));
    Attacker a(source(2), s.server->tcp_port(), s.server->udp_port());
    ASSERT_TRUE(a.join()) << a.refused() << a.error();
    int refused = 0;
    for (int i = 0; i < 2; ++i) refused += a.spawn(0, std::vector<int32_t>(16000, 0)) < 0;  // clip 0, 16,000 times
    for (int i = 0; i < 16; ++i) refused += a.spawn(0, std::vector<int32_t>(1000, 0)) < 0;
    std::vector<int32_t> every_clip(default_assets()[0]->character.clips.size());
    std::iota(every_clip.begin(), every_clip.end(), 0);
    const bool distinct_ok = a.spawn(0, every_clip) >= 0;  // distinct clips, within the limit: a character
    std::vector<int32_t> twice = {0, 0};
    refused += a.spawn(0, twice) < 0;
    EXPECT_EQ(refused, 19);
    EXPECT_NE(a.refused().find("repeated"), std::string::npos) << a.refused();
    EXPECT_TRUE(distinct_ok);
    honest.join();
    honest.print("huge spawns");
    EXPECT_EQ(honest.error, "");
    ClientReport late;
    EXPECT_NO_THROW(late = run_client(honest_options(s, 1.0)));  // joins afterwards, sees the attacker's character
    EXPECT_GE(refusals(s, "spawn_invalid"), 19u);
    EXPECT_FALSE(a.server_closed());
}

// Case 2: many sessions from a few addresses, 16 characters each, posed and
// kept alive with sealed Acks. Characters per session (16) and per address
// (32) are bounded, refusals counted; the honest client keeps its stream.
TEST(NetHardening, CharactersPerSessionAndAddressAreBounded) {
    ServerConfig cfg = hardened();
    RunningServer s({}, cfg);
    warm(s);
    std::vector<std::unique_ptr<Attacker>> as;
    for (int addr = 2; addr <= 4; ++addr)
        for (int k = 0; k < 4; ++k) {
            as.push_back(std::make_unique<Attacker>(source(addr), s.server->tcp_port(), s.server->udp_port()));
            ASSERT_TRUE(as.back()->join()) << as.back()->refused();
            ASSERT_TRUE(as.back()->bind());
        }
    size_t accepted = 0, asked = 0;
    for (auto& a : as) {
        for (int c = 0; c < 17; ++c, ++asked) accepted += a->spawn(c % 2, {}) >= 0;
        EXPECT_LE(a->characters(), size_t(MAX_SPAWNED));
    }
    Honest honest(honest_options(s, 6.0));
    keep_alive(as, 6.5, true);
    honest.join();
    honest.print("posed characters from 12 sessions");
    std::printf("characters asked %zu, accepted %zu; refusals: per session %llu, per address %llu\n", asked, accepted,
                (unsigned long long)refusals(s, "characters_per_session"), (unsigned long long)refusals(s, "characters_per_address"));
    EXPECT_EQ(accepted, size_t(3 * cfg.max_characters_per_address));
    EXPECT_EQ(refusals(s, "characters_per_address") + refusals(s, "characters_per_session"), asked - accepted);
    EXPECT_EQ(honest.error, "");
    EXPECT_LT(honest.report.max_gap_ms, 1000.0);  // the target is 250 ms (docs/performance.md); the machine is shared
    for (double k : honest.report.per_second_kbps) EXPECT_GT(k, 50.0);
}

// Case 3: one session's characters, posed every tick, raised every other
// client's stream by what they cost (16 characters: about 1.3 Mbit/s). Now
// they take at most owner_share_kbps of each observer's stream.
TEST(NetHardening, OneSessionsCharactersTakeAtMostItsShare) {
    ServerConfig cfg = hardened();
    RunningServer s({}, cfg);
    warm(s);
    Honest honest(honest_options(s, 9.0));
    std::this_thread::sleep_for(std::chrono::milliseconds(3000));
    std::vector<std::unique_ptr<Attacker>> as;
    as.push_back(std::make_unique<Attacker>(source(2), s.server->tcp_port(), s.server->udp_port()));
    ASSERT_TRUE(as[0]->join());
    ASSERT_TRUE(as[0]->bind());
    for (int c = 0; c < 16; ++c) ASSERT_GE(as[0]->spawn(c % 2, {}), 0) << as[0]->refused();
    keep_alive(as, 6.5, true);
    honest.join();
    honest.print("16 characters of one session");
    ASSERT_EQ(honest.error, "");
    ASSERT_GE(honest.report.per_second_kbps.size(), 8u);
    const double before = honest.mean(1, 3), after = honest.mean(5, 8);
    std::printf("honest stream %.0f -> %.0f kbit/s (share %.0f kbit/s)\n", before, after, cfg.owner_share_kbps);
    EXPECT_LT(after - before, 1.3 * cfg.owner_share_kbps + 40.0);  // datagram headers on top of the share's payload
    int shown = 0;  // they are shown all the same
    for (const InstanceReport& i : honest.report.instances)
        if (i.published && i.frames > 0 && i.bones_mean >= 1.0) ++shown;
    EXPECT_EQ(shown, 16);
    EXPECT_GT(after - before, 0.1 * cfg.owner_share_kbps);
}

// Case 4: a View of 8,000 weights from many sessions was scanned once per
// instance per tick (100 % CPU, the honest stream fell to 0.8-2 Mbit/s). Now
// a View holds at most MAX_VIEW_WEIGHTS (more closes that session, counted)
// and its weights are indexed: Views of 4,096 weights from 8 streaming
// sessions on a 1,000-instance scene leave the honest stream whole.
TEST(NetHardening, ViewWeightsAreBoundedAndIndexed) {
    RunningServer s(crowd_layout(default_assets(), 1000), hardened());
    warm(s);
    std::vector<std::unique_ptr<Attacker>> as;
    for (int k = 0; k < 8; ++k) {
        as.push_back(std::make_unique<Attacker>(source(2 + k % 2), s.server->tcp_port(), s.server->udp_port()));
        ASSERT_TRUE(as.back()->join());
        ASSERT_TRUE(as.back()->bind());
        as.back()->view(MAX_VIEW_WEIGHTS);
    }
    Attacker over(source(4), s.server->tcp_port(), s.server->udp_port());
    ASSERT_TRUE(over.join());
    over.view(8000);
    ClientOptions o = honest_options(s, 5.0);
    o.max_kbps = 2000;
    Honest honest(o);
    keep_alive(as, 5.5, false);
    honest.join();
    honest.print("Views of 4,096 weights from 8 sessions, 1,000 instances");
    EXPECT_TRUE(over.server_closed());
    EXPECT_EQ(refusals(s, "view_too_large"), 1u);
    EXPECT_EQ(honest.error, "");
    EXPECT_LT(honest.report.max_gap_ms, 1000.0);
    ASSERT_GE(honest.report.per_second_kbps.size(), 4u);
    EXPECT_GT(honest.mean(1, 4), 1000.0);  // its 2 Mbit/s cap is the limit, not the server
}

// Case 5: squatters that reconnect whenever dropped (and others that bind and
// Ack) kept a full server full: a real player was refused "server full".
// Now a Hello on a full server evicts an unbound session, else a silent one,
// else one of the address holding the most: the player gets in every time.
TEST(NetHardening, ReconnectingSquattersCannotKeepAPlayerOut) {
    ServerConfig cfg = hardened();
    cfg.max_clients = 12;
    cfg.client_timeout = 3.0;
    cfg.evict_after = 1.0;
    RunningServer s({}, cfg);
    warm(s);
    std::vector<std::unique_ptr<Attacker>> as;
    for (int k = 0; k < 12; ++k) as.push_back(std::make_unique<Attacker>(source(2 + k % 3), s.server->tcp_port(), s.server->udp_port()));
    std::atomic<bool> stop{false};
    std::atomic<int> rejoins{0};
    std::thread squat([&] {
        while (!stop) {
            for (size_t k = 0; k < as.size() && !stop; ++k) {
                Attacker& a = *as[k];
                if (!a.welcomed() || a.server_closed()) {  // dropped or evicted: straight back
                    if (a.join(500) && k % 2 == 0) a.bind(500);
                    ++rejoins;
                }
                if (a.bound()) a.pump_and_ack();
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(2500));
    int joined = 0;
    std::string last;
    for (int i = 0; i < 5; ++i) {
        try {
            run_client(honest_options(s, 1.0));
            ++joined;
        } catch (const std::exception& e) {
            last = e.what();
        }
    }
    stop = true;
    squat.join();
    std::printf("player joined %d of 5 beside 12 squatters (%d rejoins); evicted: unbound %llu, idle %llu, address share %llu\n",
                joined, rejoins.load(), (unsigned long long)refusals(s, "evicted_unbound"),
                (unsigned long long)refusals(s, "evicted_idle"), (unsigned long long)refusals(s, "evicted_address_share"));
    EXPECT_EQ(joined, 5) << last;
    EXPECT_GE(refusals(s, "evicted_unbound") + refusals(s, "evicted_idle") + refusals(s, "evicted_address_share"), 5u);
}

// Case 6: thousands of connections that never finish their TLS handshake
// held memory and descriptors, and nothing limited the connection rate. Now
// at most max_handshakes are in progress (the oldest go), and each address
// opens at most connects_per_second (8 s of burst): the player still joins.
TEST(NetHardening, HandshakesInProgressAndConnectionRateAreBounded) {
    ServerConfig cfg = hardened();
    cfg.max_handshakes = 64;
    RunningServer s({}, cfg);
    warm(s);
    std::vector<std::unique_ptr<Attacker>> idle;
    for (int k = 0; k < 400; ++k) {
        idle.push_back(std::make_unique<Attacker>(source(2 + k % 4), s.server->tcp_port(), s.server->udp_port()));
        idle.back()->open_idle({0x16});  // the first byte of a TLS record, and nothing more
    }
    int joined = 0;
    for (int i = 0; i < 3; ++i) {
        try {
            run_client(honest_options(s, 0.5));
            ++joined;
        } catch (const std::exception&) {
        }
    }
    const uint64_t evicted = refusals(s, "handshake_evicted");
    // One address, faster than its rate: the burst goes through, the rest is closed at once.
    std::vector<std::unique_ptr<Attacker>> burst;
    for (int k = 0; k < 400; ++k) {
        burst.push_back(std::make_unique<Attacker>(source(9), s.server->tcp_port(), s.server->udp_port()));
        burst.back()->open_idle();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const uint64_t rate_refused = refusals(s, "connect_rate");
    std::printf("400 stalled handshakes: %llu evicted, player joined %d of 3; 400 connections at once from one address: %llu refused\n",
                (unsigned long long)evicted, joined, (unsigned long long)rate_refused);
    EXPECT_EQ(joined, 3);
    EXPECT_GE(evicted, 400u - 64u);
    EXPECT_GE(rate_refused, 400u - 256u - 32u);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    EXPECT_LE(s.server->stats().sessions_active, 64u + 1u);  // counted at each tick
}

// Case 7: reconnecting after each download allowance pulled the assets
// again and again (2.3 Gbit/s). Now asset bytes are counted per address
// across reconnects (asset_bytes_per_minute): beyond it the session closes.
TEST(NetHardening, AssetBytesPerAddressAreBoundedAcrossReconnects) {
    ServerConfig cfg = hardened();
    double catalogue = 0;
    for (const auto& a : default_assets()) catalogue += double(a->bytes.size());
    cfg.asset_bytes_per_minute = 2 * catalogue;
    RunningServer s({}, cfg);
    uint64_t pulled = 0;
    int sessions = 0;
    const double t0 = now_seconds();
    while (now_seconds() - t0 < 3.0) {
        Attacker a(source(2), s.server->tcp_port(), s.server->udp_port());
        if (!a.join()) continue;
        ++sessions;
        for (size_t i = 0; i < a.assets().size() && !a.server_closed(); ++i) pulled += a.pull_asset(int(i), 1000);
    }
    const double seconds = now_seconds() - t0;
    const double allowed = cfg.asset_bytes_per_minute * (1.0 + seconds / 60.0) + 4 * MAX_ASSET_CHUNK;  // + requests in flight
    std::printf("asset pulls from one address over %d sessions in %.1f s: %.0f KB (allowed %.0f KB)\n", sessions, seconds,
                double(pulled) / 1e3, allowed / 1e3);
    EXPECT_LE(double(pulled), allowed);
    EXPECT_GE(refusals(s, "asset_budget_address"), 1u);
    // Another address downloads everything.
    ClientOptions o = honest_options(s, 0.5);
    o.cache_dir = RunningServer::cache_dir() + "/fresh-" + std::to_string(s.server->tcp_port());
    ClientReport r;
    EXPECT_NO_THROW(r = run_client(o));
    EXPECT_GE(double(r.asset_bytes_downloaded), catalogue);
}

// Case 8: the InstanceAdded burst of a 16,000-instance scene was over the
// session's output limit: every joining session was closed. Now it is paced
// within the limit as the client reads.
TEST(NetHardening, SixteenThousandInstancesCanBeJoined) {
    RunningServer s(crowd_layout(default_assets(), 16000), hardened());
    ClientConfig cfg;
    cfg.tls = true;
    cfg.ca_file = kCert;
    cfg.cache_dir = RunningServer::cache_dir();
    cfg.max_kbps = 2000;
    Client client(cfg);
    client.connect("127.0.0.1", s.server->tcp_port());
    size_t most = 0;
    int shown = 0;
    const double t0 = now_seconds();
    while (now_seconds() - t0 < 60 && (most < 16000 || shown == 0)) {
        client.update(now_seconds());
        ASSERT_NE(client.state(), ClientState::Failed) << client.error();
        most = std::max(most, client.characters().size());
        shown = 0;
        for (const RemoteCharacter& c : client.characters()) shown += c.shown;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    std::printf("16,000 instances announced in %.1f s\n", now_seconds() - t0);
    EXPECT_EQ(most, 16000u);
    EXPECT_GT(shown, 0);
    EXPECT_EQ(s.server->stats().backlog_closes, 0u);
    client.close();
}

namespace {

// A UDP relay standing in for a NAT (as in test_net_security.cpp), counting
// the bytes it relays to the client in 100 ms bins.
class CountingRelay {
public:
    explicit CountingRelay(uint16_t server_port)
        : server_(asio::ip::make_address("127.0.0.1"), server_port), front_(io_), up_(std::make_unique<asio::ip::udp::socket>(io_)) {
        front_.open(asio::ip::udp::v4());
        front_.bind({asio::ip::make_address("127.0.0.1"), 0});
        open_up();
        t0_ = now_seconds();
        thread_ = std::thread([this] { loop(); });
    }
    ~CountingRelay() {
        running_ = false;
        thread_.join();
    }
    uint16_t port() const { return front_.local_endpoint().port(); }
    void nat_change() { change_ = true; }
    double elapsed() const { return now_seconds() - t0_; }
    std::vector<uint64_t> bins() {
        std::lock_guard lock(mutex_);
        return bins_;
    }

private:
    void open_up() {
        up_ = std::make_unique<asio::ip::udp::socket>(io_);
        up_->open(asio::ip::udp::v4());
        up_->bind({asio::ip::make_address("127.0.0.1"), 0});
    }
    void loop() {
        uint8_t buf[2048];
        while (running_) {
            if (change_.exchange(false)) open_up();
            pollfd p[2] = {{front_.native_handle(), POLLIN, 0}, {up_->native_handle(), POLLIN, 0}};
            if (::poll(p, 2, 5) <= 0) continue;
            asio::error_code ec;
            asio::ip::udp::endpoint from;
            if (p[0].revents) {
                const size_t n = front_.receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec) {
                    client_ = from;
                    up_->send_to(asio::buffer(buf, n), server_, 0, ec);
                }
            }
            if (p[1].revents) {
                const size_t n = up_->receive_from(asio::buffer(buf), from, 0, ec);
                if (!ec && client_.port()) {
                    front_.send_to(asio::buffer(buf, n), client_, 0, ec);
                    std::lock_guard lock(mutex_);
                    const size_t bin = size_t(elapsed() * 10);
                    if (bins_.size() <= bin) bins_.resize(bin + 1, 0);
                    bins_[bin] += n + UDP_IP_OVERHEAD;
                }
            }
        }
    }
    asio::ip::udp::endpoint server_, client_;
    asio::io_context io_;
    asio::ip::udp::socket front_;
    std::unique_ptr<asio::ip::udp::socket> up_;
    std::atomic<bool> running_{true}, change_{false};
    std::mutex mutex_;
    std::vector<uint64_t> bins_;
    double t0_ = 0;
    std::thread thread_;
};

}  // namespace

// Case 9: after a NAT rebinding the stream came back at 20-95 kbit/s (339
// before): what was sent to the old address counted as loss. Now the rate
// is back to its pre-switch value within 2 s of the rebinding.
TEST(NetHardening, RateRecoversWithinTwoSecondsOfARebinding) {
    RunningServer s({}, hardened());
    warm(s);
    CountingRelay relay(s.server->udp_port());
    ClientOptions o = honest_options(s, 7.0);
    o.udp_via_host = "127.0.0.1";
    o.udp_via_port = relay.port();
    Honest honest(o);
    std::this_thread::sleep_for(std::chrono::milliseconds(3000));
    const double change = relay.elapsed();
    relay.nat_change();
    std::this_thread::sleep_for(std::chrono::milliseconds(3500));
    honest.join();
    const std::vector<uint64_t> bins = relay.bins();
    const size_t c = size_t(change * 10);
    ASSERT_GT(bins.size(), c + 35);
    auto kbps = [&](size_t from, size_t to) {  // bins [from, to)
        uint64_t b = 0;
        for (size_t i = from; i < to && i < bins.size(); ++i) b += bins[i];
        return double(b) * 8 / 1000 / (double(to - from) / 10);
    };
    const double before = kbps(c - 15, c);
    size_t resumed = c + 1;
    while (resumed < bins.size() && bins[resumed] == 0) ++resumed;
    const double after = kbps(resumed + 10, resumed + 20);  // the second second after the rebinding
    std::printf("rebinding: %.0f kbit/s before, stream back %.1f s after the switch, %.0f kbit/s in its second second\n", before,
                double(resumed - c) / 10, after);
    EXPECT_EQ(honest.error, "");
    EXPECT_GE(after, 0.85 * before);
}

// The CI scenario: a saturating attacker mix (sessions posing the most
// characters they may, Views of 4,096 weights, asset pulls with reconnects,
// stalled handshakes, reconnecting squatters) while an honest client
// streams: it keeps its stream, at about its rate alone.
TEST(NetHardening, SaturatingAttackerWhileAnHonestClientStreams) {
    ServerConfig cfg = hardened();
    cfg.max_clients = 24;
    RunningServer s({}, cfg);
    warm(s);
    Honest alone(honest_options(s, 4.0));
    alone.join();
    ASSERT_EQ(alone.error, "");
    std::vector<std::unique_ptr<Attacker>> posers;
    for (int k = 0; k < 6; ++k) {
        posers.push_back(std::make_unique<Attacker>(source(2 + k % 2), s.server->tcp_port(), s.server->udp_port()));
        ASSERT_TRUE(posers.back()->join());
        ASSERT_TRUE(posers.back()->bind());
        for (int c = 0; c < 16; ++c) posers.back()->spawn(c % 2, {}, 500);
        posers.back()->view(MAX_VIEW_WEIGHTS);
    }
    std::atomic<bool> stop{false};
    std::thread churn([&] {  // stalled handshakes, squatters and asset pulls, reconnecting
        std::vector<std::unique_ptr<Attacker>> idle, squat;
        int k = 0;
        while (!stop) {
            idle.push_back(std::make_unique<Attacker>(source(4 + k % 2), s.server->tcp_port(), s.server->udp_port()));
            idle.back()->open_idle({0x16});
            if (idle.size() > 200) idle.erase(idle.begin());
            if (squat.size() < 16) squat.push_back(std::make_unique<Attacker>(source(6 + k % 2), s.server->tcp_port(), s.server->udp_port()));
            for (auto& a : squat)
                if (!a->welcomed() || a->server_closed()) a->join(300);
            Attacker puller(source(8), s.server->tcp_port(), s.server->udp_port());
            if (puller.join(300)) puller.pull_asset(k % 2, 200);
            ++k;
        }
    });
    Honest honest(honest_options(s, 8.0));
    keep_alive(posers, 8.5, true);
    honest.join();
    stop = true;
    churn.join();
    alone.print("alone");
    honest.print("under attack");
    const ServerStats st = s.server->stats();
    std::printf("refusals:");
    for (const auto& [k, v] : st.refusals) std::printf(" %s %llu", k.c_str(), (unsigned long long)v);
    std::printf("\n");
    EXPECT_EQ(honest.error, "");
    EXPECT_LT(honest.report.max_gap_ms, 1000.0);
    ASSERT_GE(honest.report.per_second_kbps.size(), 6u);
    for (double k : honest.report.per_second_kbps) EXPECT_GT(k, 0.3 * alone.report.rate_kbps);
    EXPECT_GT(st.refusals_total(), 0u);
}

// A session of `a` joined, bound, with a character of asset 0 spawned (inst).
static void spawn_publisher(Attacker& a, int& inst) {
    ASSERT_TRUE(a.join()) << a.refused();
    ASSERT_TRUE(a.bind());
    inst = a.spawn(0, {});
    ASSERT_GE(inst, 0);
}

// The server's counter `field` once it reaches `want` (a's datagrams
// pumped and acknowledged meanwhile), or after 100 rounds.
static uint64_t settle_stat(RunningServer& s, Attacker& a, uint64_t ServerStats::*field, uint64_t want) {
    for (int i = 0; i < 100 && s.server->stats().*field < want; ++i) a.pump_and_ack(20);
    return s.server->stats().*field;
}

// Reordering on the uplink: pose A + 8 overtakes pose A + 7, which is
// predicted from A (the newest the server acknowledged; the publisher's
// window is POSE_BASELINES = 8). A + 8 must not take A's place: A + 7 still
// decodes, as it would have arrived in order.
TEST(NetHardening, APoseOvertakenByTheNextStillFindsItsBaseline) {
    RunningServer s({}, hardened());
    Attacker a(source(2), s.server->tcp_port(), s.server->udp_port());
    int inst = -1;
    ASSERT_NO_FATAL_FAILURE(spawn_publisher(a, inst));
    const int B = a.bones(0);
    auto settle = [&](uint64_t ServerStats::*field, uint64_t want) { return settle_stat(s, a, field, want); };
    a.pump_and_ack(500);  // the pose rate limit's bucket fills
    a.pose(inst, 0);      // pose A: whole, standalone (all-zero records but bone 0)
    const uint32_t base = a.pose_seq();
    ASSERT_EQ(settle(&ServerStats::poses_received, 1), 1u);
    std::vector<uint8_t> standalone;
    {
        BitWriter w(standalone);
        for (int b = 0; b < B; ++b) write_record(RecordInts{}, false, w);
    }
    a.set_pose_seq(base + 7);  // A + 8 first, whole
    a.pose_raw(inst, standalone, B);
    ASSERT_EQ(settle(&ServerStats::poses_received, 2), 2u);
    std::vector<uint8_t> same;  // every record "as predicted": one bit each
    {
        BitWriter w(same);
        for (int b = 0; b < B; ++b) w.put(1, 1);
    }
    a.set_pose_seq(base + 6);  // then A + 7, predicted from A
    a.pose_raw(inst, same, B, 0, base);
    // Decoded, then stale (older than A + 8, which the character shows):
    // not dropped for want of its baseline, not malformed.
    EXPECT_EQ(settle(&ServerStats::poses_stale, 1), 1u);
    const ServerStats st = s.server->stats();
    EXPECT_EQ(st.poses_missing_baseline, 0u);
    EXPECT_EQ(st.malformed_datagrams, 0u);
    EXPECT_EQ(st.poses_received, 2u);
}

// Published poses are parent-relative records predicted from poses the
// server acknowledged (docs/protocol.md "Pose"). A Pose predicted from a pose
// the server does not hold whole is dropped and counted, never decoded
// against something else; records that do not read, run past the bones,
// leave bytes over or set a padding bit are malformed; none of it costs the
// sender its session, and the pose before them stays.
TEST(NetHardening, HostilePoseRecordsAreDroppedAndCounted) {
    RunningServer s({}, hardened());
    Attacker a(source(2), s.server->tcp_port(), s.server->udp_port());
    int inst = -1;
    ASSERT_NO_FATAL_FAILURE(spawn_publisher(a, inst));
    const int B = a.bones(0);
    auto standalone = [&](int count, bool pad_bit) {
        std::vector<uint8_t> bits;
        BitWriter w(bits);
        for (int b = 0; b < count; ++b) write_record(RecordInts{}, false, w);
        if (pad_bit) {
            if (w.bits() % 8 == 0) w.put(0, 1);  // room for a padding bit
            bits.back() |= 0x80;
        }
        return bits;
    };
    auto settle = [&](uint64_t ServerStats::*field, uint64_t want) { return settle_stat(s, a, field, want); };
    a.pump_and_ack(500);  // the pose rate limit's bucket fills (2 poses per tick)
    a.pose(inst, 0);      // a whole, valid pose (standalone)
    const uint32_t held = a.pose_seq();
    EXPECT_EQ(settle(&ServerStats::poses_received, 1), 1u);
    const uint64_t malformed0 = s.server->stats().malformed_datagrams;
    // Predicted from a pose that was never sent, and from one sent but far in the past.
    a.pose_raw(inst, standalone(B, false), B, 0, a.pose_seq() + 1000);
    a.pose_raw(inst, standalone(B, false), B, 0, 1u << 31);
    EXPECT_EQ(settle(&ServerStats::poses_missing_baseline, 2), 2u);
    // Malformed: a padding bit, bytes left over, too few bits, more bones than the
    // character has, a count of zero.
    a.pose_raw(inst, standalone(B, true), B);
    std::vector<uint8_t> over = standalone(B, false);
    over.push_back(0);
    a.pose_raw(inst, over, B);
    a.pose_raw(inst, standalone(B - 1, false), B);
    a.pose_raw(inst, standalone(B, false), B, 1);
    a.pose_raw(inst, standalone(1, false), 0);
    // Root blocks: the old 26 bytes, an absolute block with a byte too many,
    // a predicted one without a baseline pose, one predicted at age 2 (a Pose
    // predicts its root only from pose base_seq, age 1), one linear.
    std::array<uint8_t, ROOT_BYTES> abs{};
    encode_root(RootPose{{1.0, 0.0, 3.0}, {1, 0, 0, 0}, 5}, abs.data());
    a.pose_raw(inst, standalone(B, false), B, 0, 0, std::vector<uint8_t>(abs.begin(), abs.end()));
    std::vector<uint8_t> long_root;
    write_root(abs.data(), 0, nullptr, nullptr, long_root);
    long_root.push_back(0);
    a.pose_raw(inst, standalone(B, false), B, 0, 0, long_root);
    std::vector<uint8_t> from1, from2, linear;
    write_root(abs.data(), 1, abs.data(), nullptr, from1);
    write_root(abs.data(), 2, abs.data(), nullptr, from2);
    write_root(abs.data(), 1 | kBaseLinear, abs.data(), abs.data(), linear);
    a.pose_raw(inst, standalone(B, false), B, 0, 0, from1);
    a.pose_raw(inst, standalone(B, false), B, 0, held, from2);
    a.pose_raw(inst, standalone(B, false), B, 0, held, linear);
    EXPECT_EQ(settle(&ServerStats::malformed_datagrams, malformed0 + 10), malformed0 + 10);
    EXPECT_EQ(s.server->stats().poses_received, 1u);
    EXPECT_EQ(s.server->stats().poses_rate_limited, 0u);
    // The session is still there: a valid pose is taken.
    a.pose(inst, 0);
    EXPECT_EQ(settle(&ServerStats::poses_received, 2), 2u);
    EXPECT_FALSE(a.server_closed());
}
