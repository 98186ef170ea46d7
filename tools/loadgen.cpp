// loadgen.cpp — see loadgen.h. Each of LoadOptions::threads lanes is one
// thread with its own io_context and its players (player i on lane i mod
// threads): the io_context (TCP, TLS) is polled, then every player of the
// lane whose turn is due is updated (its UDP socket read through the
// session, acks, its pose published); the loop sleeps 1 ms when nothing
// is due. Lane 0 runs on the calling thread and also steers the run
// (joins, the window, progress, stop); the other lanes follow its phase.
// What lanes share is read-only once set (options, grid step, the clip
// tables, the decoded assets: built under Shared::mutex), and each lane
// counts into its own histograms, merged after the threads are joined.
// Nothing is allocated per turn once steady (the sessions' Outboxes, the
// shared pose buffers and the histograms keep their size; a player's
// observation table grows only when characters come).
#include "loadgen.h"

#include <netinet/in.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>

#include <algorithm>
#include <asio.hpp>
#include <asio/ssl.hpp>
#include <cctype>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <openssl/evp.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <random>
#include <thread>

#include "asset_cache.h"
#include "crypto.h"
#include "errors.h"
#include "root_block.h"
#include "session.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;

namespace {

// Latency histogram: 0.1 ms bins up to 10 s (beyond: the last bin).
struct Histogram {
    static constexpr int kBins = 100000;
    std::vector<uint32_t> bins = std::vector<uint32_t>(kBins, 0);
    uint64_t n = 0;
    double max = 0;
    void add(double ms) {
        const int b = std::clamp(int(ms * 10.0), 0, kBins - 1);
        ++bins[size_t(b)];
        ++n;
        max = std::max(max, ms);
    }
    double at(double q) const {
        if (!n) return 0;
        const uint64_t want = uint64_t(std::ceil(q * double(n)));
        uint64_t c = 0;
        for (int b = 0; b < kBins; ++b) {
            c += bins[size_t(b)];
            if (c >= want) return (b + 0.5) / 10.0;
        }
        return max;
    }
    Percentiles summary() const { return {n, at(0.5), at(0.99), max}; }
    void merge(const Histogram& o) {
        for (size_t b = 0; b < bins.size(); ++b) bins[b] += o.bins[b];
        n += o.n;
        max = std::max(max, o.max);
    }
};

// Receives one datagram with the kernel's arrival time (as client.cpp).
ssize_t receive_stamped(int fd, uint8_t* buf, size_t cap, sockaddr_storage& addr, double& t) {
    iovec iov{buf, cap};
    alignas(cmsghdr) char control[128];
    msghdr msg{};
    msg.msg_name = &addr;
    msg.msg_namelen = sizeof addr;
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    const ssize_t n = ::recvmsg(fd, &msg, MSG_DONTWAIT);
    if (n < 0) return -1;
    t = now_seconds();
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c))
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            timespec ts, rt;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            ::clock_gettime(CLOCK_REALTIME, &rt);
            const double age = double(rt.tv_sec - ts.tv_sec) + 1e-9 * double(rt.tv_nsec - ts.tv_nsec);
            if (age > 0 && age < 5.0) t -= age;
        }
    if (msg.msg_flags & MSG_TRUNC) return ssize_t(cap);
    return n;
}

uint64_t root_source_us(const uint8_t* root) {
    uint64_t s = 0;
    for (int i = 0; i < 8; ++i) s |= uint64_t(root[18 + i]) << (8 * i);
    return s;
}

struct Shared;

// The shared poses of one asset: its clip sampled once at the tick rate
// over its loop (at most kMaxFrames), each player publishing the frame of
// its time: nothing sampled or allocated per turn.
struct ClipTable {
    std::vector<Mat34> table;  // frames x joints
    size_t joints = 0, frames = 0;
    double start = 0;
    ClipSelection sel;
    static constexpr size_t kMaxFrames = 3600;
};

// The run's phase, set by lane 0 (release) and followed by every lane.
enum Phase : int { kJoining = 0, kMeasuring = 1, kDone = 2 };

// What the players count in the window (per lane, merged at the end).
struct Counts {
    Histogram receipt, display, cross_receipt, cross_display;
    uint64_t bones_sum = 0, bones_n = 0, records = 0, bad_records = 0;
    uint64_t late = 0, turns = 0;
    void merge(const Counts& o) {
        receipt.merge(o.receipt);
        display.merge(o.display);
        cross_receipt.merge(o.cross_receipt);
        cross_display.merge(o.cross_display);
        bones_sum += o.bones_sum;
        bones_n += o.bones_n;
        records += o.records;
        bad_records += o.bad_records;
        late += o.late;
        turns += o.turns;
    }
};

// One thread's players and what they count (only that thread touches it
// while the lanes run).
struct Lane : Counts {
    int index = 0;
    asio::io_context io;
    double decoded_check = 0;  // the decoded rotations summed (keeps the decoding from being optimised away)
    bool in_window = false, window_done = false;
    std::vector<int> members;  // its players' indices (i, i + threads, ...), in start order
    int started = 0;           // members started so far
    // When each member next needs a look: its turn, its restart, or a
    // period on when its session ended. Scanned each pass instead of the
    // players themselves (cold: a session each).
    std::vector<double> due;
    double next_count = 0;     // when joined and failed are counted next
    std::mt19937 jitter{12345};
    // For lane 0's steering, published by the lane after each pass.
    std::atomic<int> n_started{0}, n_joined{0}, n_failed{0};
    std::atomic<uint64_t> n_samples{0};
};

// One remote character as one player sees it.
struct Obs {
    const ClientAsset* asset = nullptr;
    int publisher = -1;  // loadgen player index, -1: not one of ours
    bool nearest = false, cross = false, active = false;
    bool seen = false;   // a chunk arrived (ever)
    int show = 0;
    uint64_t last_source_us = 0;
    double last_arrival = -1, max_gap = 0;
    // the last roots received: tick and source time (display latency)
    std::array<uint32_t, 8> ring_tick{};
    std::array<uint64_t, 8> ring_src{};
    uint8_t ring_n = 0, ring_at = 0;
    std::unique_ptr<RootRing> roots;  // predicted root blocks' baselines (made at the first root)
};

struct Player final : DatagramSource, FrameSink {
    Shared& sh;
    Lane& lane;
    int index = 0, node = 0;
    Outbox out;
    ClientSession session;
    tcp::socket tcp_sock;
    udp::socket udp_sock;
    std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;
    std::string tls_error;
    udp::endpoint server_udp;
    std::vector<uint8_t> rx_chunk = std::vector<uint8_t>(16384), tx_inflight;
    bool reading = false, writing = false;
    alignas(16) uint8_t buf[2048];
    asio::ip::address_v4 source;  // bound source address (unspecified: the system's)
    bool use_source = false;

    // own character
    int handle = -1, instance = -1, asset = -1;
    glm::dvec3 center{0.0};
    bool started = false, joined = false, failed = false;
    int attempt = 0;              // restarts so far (LoadOptions::retries)
    double restart_at = -1;       // a replacement waiting to start (>= 0)
    double next_turn = 0, joined_at = 0;
    int turns = 0;
    std::vector<int> nearest;  // player indices of its nearest set
    std::vector<Obs> obs;      // by instance id
    std::vector<const RootRing*> ring_of;  // obs[id].roots by id, for prefetch (no load of the Obs first)
    // window
    uint64_t bytes_at_start = 0;
    double kbps = 0;
    bool streamed_window = false;

    const ClipTable* clip_table = nullptr;  // its asset's, once looked up
    Player(Shared& s, Lane& l, int i, int n, const ClientConfig& cfg);
    void start(double now);
    void open_channel();
    void channel_ready() {
        session.on_channel_ready();
        flush();
        read_more();
    }
    bool check_pin();
    void flush();
    void write_next();
    void read_more();
    bool open_udp();
    void fail(FailReason why, const std::string& text) {
        session.fail(why, text);
        flush();
    }
    void turn(double now);
    void on_events(double now);
    void sample_display(double now);

    bool next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) override;
    void on_character(int id, const RemoteCharacter* rc) override;
    void on_chunk(int id, uint32_t tick, int show, std::span<const uint8_t> root, double arrival) override;
    void on_run(int id, int first, int count, const RecordRun& records) override;
    void prefetch(int id, uint32_t tick) override;
};

struct Shared {
    const LoadOptions& opt;
    std::unique_ptr<asio::ssl::context> ssl_ctx;
    std::string pin;  // normalised
    std::mutex mutex;  // assets, step and poses while they are set
    std::map<uint64_t, std::shared_ptr<ClientAsset>> assets;  // decoded once, by asset id
    int grid = 1;
    std::atomic<double> step{1.0};  // grid step, world units (from the asset's diagonal; set by the first spawn)
    bool step_set = false;
    std::atomic<int> phase{kJoining};
    std::atomic<bool> first_ready{false};  // player 0 spawned (or failed): the others may start
    double window_start = 0, window_end = 0;  // written by lane 0 before the phase that makes them valid
    std::map<int, std::unique_ptr<ClipTable>> poses;  // by asset index; never moved once made
    uint64_t start_us = 0;

    explicit Shared(const LoadOptions& o) : opt(o) {}
    // The node of player i (LoadOptions::bands).
    int node_of(int i) const {
        const int nodes = int(opt.servers.size());
        return opt.bands ? int(int64_t(i) * nodes / opt.players) : i % nodes;
    }
    int player_at(const glm::dvec3& c) const {
        const double st = step.load(std::memory_order_relaxed);
        const long gx = std::lround(c.x / st), gz = std::lround(c.z / st);
        if (gx < 0 || gz < 0 || gx >= grid || gz >= grid) return -1;
        return int(gz * grid + gx);
    }
    glm::dvec3 spot(int i) const {
        const double st = step.load(std::memory_order_relaxed);
        return {double(i % grid) * st, 0.0, double(i / grid) * st};
    }
    // The skinning matrices of asset `index` at `now` (its loop's frame);
    // `cache` keeps the caller's table (made once, under the mutex).
    std::span<const Mat34> pose(const ClientAsset& a, int index, double now, const ClipTable*& cache) {
        if (!cache) cache = make_pose(a, index);
        const ClipTable& p = *cache;
        const double u = p.sel.looped(now - double(start_us) * 1e-6) - p.start;
        const size_t f = std::min(p.frames - 1, size_t(std::max(0.0, u * opt.tick_rate)));
        return {p.table.data() + f * p.joints, p.joints};
    }
    const ClipTable* make_pose(const ClientAsset& a, int index) {
        std::lock_guard<std::mutex> lock(mutex);
        std::unique_ptr<ClipTable>& slot = poses[index];
        if (!slot) {
            slot = std::make_unique<ClipTable>();
            ClipTable& p = *slot;
            p.sel = select_clips(a.character, opt.clip);
            p.joints = a.character.joint_count();
            p.start = p.sel.start;
            const double length = std::max(0.0, double(p.sel.end - p.sel.start));
            p.frames = std::clamp<size_t>(size_t(std::ceil(length * opt.tick_rate)), 1, ClipTable::kMaxFrames);
            p.table.resize(p.frames * p.joints);
            std::vector<glm::dmat4> mats(p.joints);
            for (size_t f = 0; f < p.frames; ++f) {
                sample_skinning_matrices(a.character, p.sel, p.start + double(f) / opt.tick_rate, mats);
                for (size_t j = 0; j < p.joints; ++j) p.table[f * p.joints + j] = Mat34::from_glm(mats[j]);
            }
        }
        return slot.get();
    }
};

Player::Player(Shared& s, Lane& l, int i, int n, const ClientConfig& cfg)
    : sh(s), lane(l), index(i), node(n), session(cfg, out), tcp_sock(l.io), udp_sock(l.io) {
    SessionHooks hooks;
    hooks.frame_sink = this;
    hooks.load_asset = [&s](const wire::Asset* a, const std::string& path) {
        std::lock_guard<std::mutex> lock(s.mutex);
        auto& slot = s.assets[a->asset_id()];
        if (!slot) slot = load_client_asset(a, path);
        return slot;
    };
    session.set_hooks(std::move(hooks));
    out.datagram_bytes.reserve(4 * 1280);
    out.datagram_ends.reserve(8);
}

void Player::start(double now) {
    started = true;
    const ServerAddress& sa = sh.opt.servers[size_t(node)];
    session.start(now, sa.host + ":" + std::to_string(sa.port));
    open_channel();
    flush();
}

void Player::open_channel() {
    const ServerAddress& sa = sh.opt.servers[size_t(node)];
    asio::error_code ec;
    const auto addr = asio::ip::make_address(sa.host, ec);
    tcp::endpoint ep;
    if (ec) {
        tcp::resolver r(lane.io);
        auto res = r.resolve(sa.host, std::to_string(sa.port), ec);
        if (ec || res.empty()) return fail(FailReason::Unreachable, "cannot resolve " + sa.host + ": " + ec.message());
        ep = *res.begin();
    } else {
        ep = tcp::endpoint(addr, sa.port);
    }
    tcp_sock.open(ep.protocol(), ec);
    if (!ec && use_source) tcp_sock.bind(tcp::endpoint(source, 0), ec);
    if (ec) return fail(FailReason::Unreachable, "cannot open a TCP socket: " + ec.message());
    if (sh.ssl_ctx) {
        tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(tcp_sock, *sh.ssl_ctx);
        if (!sh.opt.ca_file.empty()) {
            asio::ssl::host_name_verification by_name(sa.host);
            tls->set_verify_callback([this, by_name](bool pre, asio::ssl::verify_context& vc) {
                if (!pre) {
                    if (tls_error.empty())
                        tls_error = X509_verify_cert_error_string(X509_STORE_CTX_get_error(vc.native_handle()));
                    return false;
                }
                if (!by_name(pre, vc)) {
                    if (tls_error.empty()) tls_error = "the certificate is not for " + sh.opt.servers[size_t(node)].host;
                    return false;
                }
                return true;
            });
        }
    }
    tcp_sock.async_connect(ep, [this](asio::error_code e) {
        if (!session.running()) return;
        const ServerAddress& sa = sh.opt.servers[size_t(node)];
        if (e) return fail(FailReason::Unreachable, "cannot connect to " + sa.host + ":" + std::to_string(sa.port) + ": " + e.message());
        asio::error_code ig;
        tcp_sock.set_option(tcp::no_delay(true), ig);
        if (!tls) return channel_ready();
        session.on_transport_connected();
        tls->async_handshake(asio::ssl::stream_base::client, [this](asio::error_code he) {
            if (!session.running()) return;
            if (he) {
                if (!tls_error.empty()) return fail(FailReason::TlsUntrusted, "server certificate not trusted: " + tls_error);
                return fail(FailReason::TlsHandshake, "TLS handshake failed: " + he.message());
            }
            if (check_pin()) channel_ready();
        });
    });
}

bool Player::check_pin() {
    if (sh.pin.empty()) return true;
    X509* cert = SSL_get1_peer_certificate(tls->native_handle());
    if (!cert) {
        fail(FailReason::TlsUntrusted, "the server sent no certificate");
        return false;
    }
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    const int ok = X509_digest(cert, EVP_sha256(), md, &len);
    X509_free(cert);
    const std::string got = ok ? crypto::to_hex({md, len}) : std::string();
    if (got != sh.pin) {
        fail(FailReason::TlsUntrusted, "server certificate fingerprint " + got + " does not match the pinned " + sh.pin);
        return false;
    }
    return true;
}

void Player::flush() {
    asio::error_code ig;
    if (udp_sock.is_open())
        for (size_t i = 0; i < out.datagrams(); ++i)
            udp_sock.send_to(asio::buffer(out.datagram(i).data(), out.datagram(i).size()), server_udp, 0, ig);
    out.clear_datagrams();
    write_next();
    if (!session.running()) {
        tcp_sock.close(ig);
        udp_sock.close(ig);
    }
}

void Player::write_next() {
    if (writing || out.control.empty() || !tcp_sock.is_open()) return;
    writing = true;
    std::swap(out.control, tx_inflight);
    auto done = [this](asio::error_code ec, size_t) {
        writing = false;
        if (ec) return fail(FailReason::ChannelLost, "control channel: " + ec.message());
        tx_inflight.clear();
        write_next();
    };
    if (tls) asio::async_write(*tls, asio::buffer(tx_inflight), done);
    else asio::async_write(tcp_sock, asio::buffer(tx_inflight), done);
}

void Player::read_more() {
    if (reading) return;
    reading = true;
    auto done = [this](asio::error_code ec, size_t n) {
        reading = false;
        if (!session.running()) return;
        if (ec == asio::error::eof || ec == asio::ssl::error::stream_truncated) session.on_channel_closed();
        else if (ec) session.fail(FailReason::ChannelLost, "control channel: " + ec.message());
        else session.on_control_bytes({rx_chunk.data(), n}, now_seconds());
        on_events(now_seconds());
        flush();
        if (session.running()) read_more();
    };
    if (tls) tls->async_read_some(asio::buffer(rx_chunk), done);
    else tcp_sock.async_read_some(asio::buffer(rx_chunk), done);
}

bool Player::open_udp() {
    asio::error_code ec;
    udp_sock.open(udp::v4(), ec);
    if (!ec) udp_sock.bind(udp::endpoint(use_source ? source : asio::ip::address_v4::any(), 0), ec);
    if (ec) {
        fail(FailReason::Unreachable, "cannot open a UDP socket: " + ec.message());
        return false;
    }
    udp_sock.non_blocking(true, ec);
    udp_sock.set_option(asio::socket_base::receive_buffer_size(1 << 20), ec);
    int on = 1;
    ::setsockopt(udp_sock.native_handle(), SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
    asio::error_code ig;
    const tcp::endpoint peer = tcp_sock.remote_endpoint(ig);
    if (ig) {
        fail(FailReason::ChannelLost, "control channel: " + ig.message());
        return false;
    }
    server_udp = udp::endpoint(peer.address(), session.udp_port());
    return true;
}

bool Player::next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) {
    if (!udp_sock.is_open()) return false;
    sockaddr_storage addr{};
    const ssize_t got = receive_stamped(udp_sock.native_handle(), buf, sizeof buf, addr, arrival);
    if (got < 0) return false;
    bytes = {buf, size_t(got)};
    from_server = false;
    if (addr.ss_family == AF_INET) {
        const auto* in = reinterpret_cast<const sockaddr_in*>(&addr);
        from_server = ntohs(in->sin_port) == server_udp.port() &&
                      ntohl(in->sin_addr.s_addr) == server_udp.address().to_v4().to_uint();
    }
    return true;
}

// ----------------------------------------------------------- the sink --
void Player::on_character(int id, const RemoteCharacter* rc) {
    if (id < 0 || id > 65535) return;
    if (obs.size() <= size_t(id)) obs.resize(size_t(id) + 1);
    Obs& o = obs[size_t(id)];
    o = Obs{};
    if (size_t(id) < ring_of.size()) ring_of[size_t(id)] = nullptr;
    if (!rc) return;
    o.active = true;
    o.asset = rc->asset;
    if (!rc->publisher.published) return;
    const int p = sh.player_at(rc->publisher.walk_center);
    if (p < 0 || p == index) return;  // not ours, or this player's own
    o.publisher = p;
    o.cross = sh.node_of(p) != node;
    o.nearest = std::find(nearest.begin(), nearest.end(), p) != nearest.end();
}

void Player::on_chunk(int id, uint32_t tick, int show, std::span<const uint8_t> block, double arrival) {
    if (size_t(id) >= obs.size()) return;
    Obs& o = obs[size_t(id)];
    if (o.publisher < 0) return;
    o.seen = true;
    o.show = show;
    if (lane.in_window) {
        lane.bones_sum += uint64_t(show);
        ++lane.bones_n;
        if (o.nearest) {
            const double from = std::max(o.last_arrival, sh.window_start);
            o.max_gap = std::max(o.max_gap, arrival - from);
        }
    }
    o.last_arrival = arrival;
    if (block.empty()) return;
    // The root block, absolute or predicted from this character's earlier roots.
    if (!o.roots) {
        o.roots = std::make_unique<RootRing>();
        if (ring_of.size() <= size_t(id)) ring_of.resize(size_t(id) + 1, nullptr);
        ring_of[size_t(id)] = o.roots.get();
    }
    std::array<uint8_t, ROOT_BYTES> root;
    if (!o.roots->resolve(tick, block.data(), block.size(), root.data())) {
        ++lane.bad_records;
        return;
    }
    o.roots->put(tick, root.data());
    const uint64_t src = root_source_us(root.data());
    if (src <= o.last_source_us) return;
    o.last_source_us = src;
    o.ring_tick[o.ring_at] = tick;
    o.ring_src[o.ring_at] = src;
    o.ring_at = uint8_t((o.ring_at + 1) % o.ring_tick.size());
    o.ring_n = uint8_t(std::min<size_t>(o.ring_n + 1u, o.ring_tick.size()));
    if (!lane.in_window) return;
    const double ms = (arrival - double(src) * 1e-6) * 1000.0;
    (o.cross ? lane.cross_receipt : lane.receipt).add(ms);
}

// A frame's chunks are announced while it is checked: the lines on_chunk
// will touch (the character's Obs and root ring entries) are fetched for
// all of them at once, not one miss after another.
void Player::prefetch(int id, uint32_t tick) {
    if (size_t(id) >= obs.size()) return;
    const char* o = reinterpret_cast<const char*>(&obs[size_t(id)]);
    for (size_t at = 0; at < sizeof(Obs); at += 64) __builtin_prefetch(o + at);
    if (size_t(id) < ring_of.size() && ring_of[size_t(id)]) ring_of[size_t(id)]->prefetch(tick);
}

// Reads every record (what the client's pose buffer does first with them):
// a standalone one to its integers, a predicted one (from a baseline the
// player would hold) its residuals' syntax; invalid ones are counted.
void Player::on_run(int id, int, int count, const RecordRun& records) {
    if (size_t(id) >= obs.size() || !obs[size_t(id)].asset) return;
    BitReader in(records.data, records.bytes, records.bit);
    const bool with_base = (records.base & kBaseAgeMask) != 0;
    int64_t check = 0;
    for (int k = 0; k < count; ++k) {
        BitReader peek = in;  // a predicted record: its syntax (its baseline is not kept here)
        RecordPrefix prefix;
        if (with_base && (!read_prefix(peek, prefix) || prefix.kind != RecordPrefix::Standalone)) {
            if (!skip_record(in, records.scaled, true)) {
                ++lane.bad_records;
                return;
            }
            continue;
        }
        in = peek;  // past the standalone prefix (if any)
        RecordInts r;
        if (!read_record(in, records.scaled, r)) {
            ++lane.bad_records;
            return;
        }
        check += r.rot[0];
    }
    lane.decoded_check += float(check & 0xff);
    lane.records += uint64_t(count);
}

// ----------------------------------------------------------- the turn --
void Player::on_events(double now) {
    for (const ClientEvent& e : session.events()) {
        if (e.type == ClientEvent::Type::Spawned && e.handle == handle) {
            instance = e.instance;
        } else if (e.type == ClientEvent::Type::SpawnRefused) {
            fail(FailReason::BadServerData, "spawn refused: " + e.text);
        }
    }
    session.clear_events();
    if (handle < 0 && session.welcomed()) {
        const auto& names = session.asset_names();
        if (asset < 0) {
            for (size_t i = 0; i < names.size(); ++i)
                if (names[i] == sh.opt.asset) asset = int(i);
            char* end = nullptr;
            const long i = std::strtol(sh.opt.asset.c_str(), &end, 10);
            if (asset < 0 && end && *end == 0 && i >= 0 && size_t(i) < names.size()) asset = int(i);
            if (asset < 0) return fail(FailReason::Config, "the server has no asset " + sh.opt.asset);
        }
        const auto& a = session.assets()[size_t(asset)];
        if (!a) return;  // not downloaded yet
        const double diag = a->diagonal;
        {
            std::lock_guard<std::mutex> lock(sh.mutex);
            if (!sh.step_set) {  // the first spawn sets the grid step from its asset
                sh.step.store(sh.opt.spacing * diag, std::memory_order_relaxed);
                sh.step_set = true;
            }
        }
        center = sh.spot(index);
        SpawnSpec spec;
        spec.asset = asset;
        spec.clips = select_clips(a->character, sh.opt.clip).clips;
        spec.start_us = sh.start_us;
        spec.walk_center = center;
        spec.walk_radius = sh.opt.walk * diag;
        spec.walk_speed = sh.opt.walk > 0 ? 0.75 * diag : 0.0;
        spec.position = glm::vec3(walk_root(center, spec.walk_radius, spec.walk_speed, now - double(sh.start_us) * 1e-6).position);
        handle = session.spawn(spec);
        ViewSpec v;
        v.has_camera = true;
        v.camera = glm::vec3(center) + glm::vec3(0.0f, float(0.5 * diag), 0.0f);
        session.set_view(v);
    }
}

void Player::turn(double now) {
    session.clear_events();
    if (session.welcomed() && !udp_sock.is_open() && session.running() && !open_udp()) return;
    session.update(now, this);
    on_events(now);
    if (instance >= 0 && session.phase() == SessionPhase::Streaming) {
        if (!joined) {
            joined = true;
            joined_at = now;
        }
        const ClientAsset& a = *session.assets()[size_t(asset)];
        const std::span<const Mat34> skin = sh.pose(a, asset, now, clip_table);
        const double t = now - double(sh.start_us) * 1e-6;
        const double diag = a.diagonal;
        RootPose root = walk_root(center, sh.opt.walk * diag, sh.opt.walk > 0 ? 0.75 * diag : 0.0, t);
        root.source_us = uint64_t(now * 1e6);
        session.publish(handle, root, skin, false, {});
    }
    if (lane.in_window && (++turns % std::max(1, int(sh.opt.tick_rate / 10))) == 0) sample_display(now);
    flush();
    if (session.phase() == SessionPhase::Failed && !failed) failed = true;
}

// Display latency of the nearest set (see loadgen.h).
void Player::sample_display(double now) {
    const double d = session.display_tick(now);
    if (!std::isfinite(d)) return;
    for (Obs& o : obs) {
        if (!o.nearest || o.ring_n < 1) continue;
        // newest and the ring in tick order: find a <= d < c
        int newest = (o.ring_at + int(o.ring_tick.size()) - 1) % int(o.ring_tick.size());
        double src = -1;
        const double tn = double(o.ring_tick[size_t(newest)]);
        if (d >= tn) {
            src = double(o.ring_src[size_t(newest)]);
        } else {
            double ta = -1e300, tc = 1e300;
            double sa = 0, sc = 0;
            for (int k = 0; k < o.ring_n; ++k) {
                const double tk = double(int32_t(o.ring_tick[size_t(k)] - uint32_t(tn))) + tn;
                if (tk <= d && tk > ta) ta = tk, sa = double(o.ring_src[size_t(k)]);
                if (tk > d && tk < tc) tc = tk, sc = double(o.ring_src[size_t(k)]);
            }
            if (ta < -1e299) continue;  // older than the ring
            src = tc > 1e299 ? sa : sa + (sc - sa) * (d - ta) / (tc - ta);
        }
        const double ms = (now - src * 1e-6) * 1000.0;
        (o.cross ? lane.cross_display : lane.display).add(ms);
    }
}

std::string node_name(const LoadOptions& o, int node) {
    return o.servers[size_t(node)].host + ":" + std::to_string(o.servers[size_t(node)].port);
}

double cpu_now() {
    rusage u{};
    ::getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

}  // namespace

namespace {

void check_options(const LoadOptions& opt) {
    if (opt.servers.empty()) throw Error("no server given");
    if (opt.players < 1 || opt.players > LoadOptions::kMaxPlayers)
        throw Error("players must be in 1.." + std::to_string(LoadOptions::kMaxPlayers));
    if (!(opt.duration > 0 && opt.duration <= 86400) || !(opt.settle >= 0 && opt.settle <= 600))
        throw Error("duration must be in (0, 86400] s, settle in [0, 600] s");
    if (!(opt.tick_rate > 0 && opt.tick_rate <= 240)) throw Error("tick rate must be in (0, 240]");
    if (!(opt.connect_rate > 0 && opt.connect_rate <= 10000)) throw Error("connect rate must be in (0, 10000]");
    if (opt.retries < 0 || opt.retries > 10) throw Error("retries must be in 0..10");
    if (opt.threads < 1 || opt.threads > LoadOptions::kMaxThreads) throw Error("threads must be in 1.." + std::to_string(LoadOptions::kMaxThreads));
    if (!(opt.max_kbps >= 0) || !(opt.delay_ms >= 0 && opt.delay_ms <= 5000) || !(opt.walk >= 0 && opt.walk <= 1000) ||
        !(opt.spacing > 0 && opt.spacing <= 1000) || opt.see < 0 || !(opt.starve_s > 0) || opt.addresses > 250)
        throw Error("an option is out of range");
}

// The TLS client context every player's stream shares (pin or CA as progskin-client).
void setup_tls(const LoadOptions& opt, Shared& sh) {
    for (char ch : opt.pin_sha256)
        if (ch != ':') sh.pin.push_back(char(std::tolower(static_cast<unsigned char>(ch))));
    if (!sh.pin.empty() && (sh.pin.size() != 64 || sh.pin.find_first_not_of("0123456789abcdef") != std::string::npos))
        throw Error("the pinned certificate fingerprint must be 64 hex digits (SHA-256)");
    if (opt.ca_file.empty() && sh.pin.empty() && !opt.insecure)
        throw Error("TLS needs a way to trust the server's certificate: --ca, --pin or --insecure");
    sh.ssl_ctx = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_client);
    sh.ssl_ctx->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 |
                            asio::ssl::context::no_sslv3 | asio::ssl::context::no_tlsv1 | asio::ssl::context::no_tlsv1_1);
    if (!opt.ca_file.empty()) {
        asio::error_code ec;
        sh.ssl_ctx->load_verify_file(opt.ca_file, ec);
        if (ec) throw Error("cannot read the CA file " + opt.ca_file + ": " + ec.message());
        sh.ssl_ctx->set_verify_mode(asio::ssl::verify_peer);
    } else {
        sh.ssl_ctx->set_verify_mode(asio::ssl::verify_none);  // pinned or insecure: checked after the handshake
    }
}

// One run: the players, the loop, the window, the report.
class Run {
public:
    Run(const LoadOptions& o, const std::atomic<bool>* stop) : opt(o), stop_(stop), sh(o) {
        check_options(opt);
        rep.players = opt.players;
        rep.nodes = int(opt.servers.size());
        rep.threads = opt.threads;
        sh.grid = int(std::ceil(std::sqrt(double(opt.players))));
        sh.start_us = uint64_t(now_seconds() * 1e6);
        if (opt.tls) setup_tls(opt, sh);
        for (int k = 0; k < opt.threads; ++k) {
            lanes.push_back(std::make_unique<Lane>());
            lanes.back()->index = k;
            lanes.back()->jitter.seed(uint32_t(12345 + k));
        }
        make_players();
        layout_nearest();
    }
    LoadReport run() {
        t0 = now_seconds();
        period = 1.0 / opt.tick_rate;
        next_progress = t0 + opt.progress_s;
        std::vector<std::thread> threads;
        for (size_t k = 1; k < lanes.size(); ++k) threads.emplace_back([this, k] { lane_loop(*lanes[k]); });
        lane_loop(*lanes[0]);  // lane 0 steers: it ends the run
        for (auto& t : threads) t.join();
        summarise();
        for (auto& p : players)
            if (p->session.running()) {
                p->session.close("loadgen done");
                p->flush();
            }
        for (auto& l : lanes) l->io.poll();
        return rep;
    }

private:
    const LoadOptions& opt;
    const std::atomic<bool>* stop_;
    Shared sh;
    LoadReport rep;
    std::vector<std::unique_ptr<Lane>> lanes;
    std::vector<std::unique_ptr<Player>> players;  // player i on lane i mod threads
    // Players replaced by a restart, per lane: kept until the end, as asio
    // handlers may still refer to them (each returns at once: its session is over).
    std::vector<std::vector<std::unique_ptr<Player>>> replaced;
    std::atomic<int> retried_{0};
    bool window_done_ = false;  // the window ran to its end (lane 0's, then summarise's)
    ClientConfig cfg_;
    int see = 0;
    double t0 = 0, period = 0, all_joined_at = 0, cpu_start = 0, next_progress = 0;  // (lane 0's)

    template <class... A>
    void log(const char* fmt, A... args) {
        std::fprintf(stderr, "progskin-loadgen: %6.1f s  ", now_seconds() - t0);
        std::fprintf(stderr, fmt, args...);
        std::fputc('\n', stderr);
    }
    int lane_sum(std::atomic<int> Lane::*field) const {
        int n = 0;
        for (const auto& l : lanes) n += ((*l).*field).load(std::memory_order_acquire);
        return n;
    }

    // Every player, on its node (round-robin), lane and source address.
    void make_players() {
        bool loopback = true;
        for (const auto& s : opt.servers) loopback = loopback && s.host.rfind("127.", 0) == 0;
        const int addresses = opt.addresses >= 0 ? opt.addresses : loopback ? std::min(250, (opt.players + 15) / 16) : 0;
        rep.addresses = addresses;
        ClientConfig cfg;
        cfg.tls = opt.tls;
        cfg.insecure = opt.insecure;
        cfg.token = opt.token;
        cfg.cache_dir = opt.cache_dir;
        cfg.max_kbps = opt.max_kbps;
        cfg.delay_ms = opt.delay_ms;
        cfg.max_delay_ms = opt.delay_ms;
        cfg.connect_timeout = opt.connect_timeout;
        players.reserve(size_t(opt.players));
        replaced.resize(lanes.size());
        for (int i = 0; i < opt.players; ++i) lanes[size_t(i) % lanes.size()]->members.push_back(i);
        for (auto& l : lanes) l->due.assign(l->members.size(), 0.0);
        cfg_ = cfg;
        for (int i = 0; i < opt.players; ++i) {
            cfg.name = "loadgen" + std::to_string(i);
            auto p = std::make_unique<Player>(sh, *lanes[size_t(i) % lanes.size()], i, sh.node_of(i), cfg);
            if (addresses > 0) {
                p->use_source = true;
                p->source = asio::ip::address_v4((127u << 24) | uint32_t(2 + i % addresses));
            }
            players.push_back(std::move(p));
        }
    }

    // Each player's nearest set: the `see` closest others by grid spot.
    void layout_nearest() {
        see = std::min(opt.see, opt.players - 1);
        rep.see = see;
        std::vector<std::pair<double, int>> d(size_t(opt.players));
        for (int i = 0; i < opt.players; ++i) {
            const glm::dvec3 ci(double(i % sh.grid), 0, double(i / sh.grid));
            for (int j = 0; j < opt.players; ++j) {
                const glm::dvec3 cj(double(j % sh.grid), 0, double(j / sh.grid));
                d[size_t(j)] = {j == i ? 1e300 : glm::length(ci - cj), j};
            }
            std::partial_sort(d.begin(), d.begin() + see, d.end());
            auto& n = players[size_t(i)]->nearest;
            for (int k = 0; k < see; ++k) n.push_back(d[size_t(k)].second);
            std::sort(n.begin(), n.end());
        }
    }

    // The lane's players in start order: player i at t0 + i / connect_rate,
    // player 0 first and alone until its assets are cached (it spawned).
    void start_players(Lane& l, double now) {
        if (l.index == 0 && !sh.first_ready.load(std::memory_order_relaxed) && (players[0]->handle >= 0 || players[0]->failed))
            sh.first_ready.store(true, std::memory_order_release);
        const bool first_ready = sh.first_ready.load(std::memory_order_acquire);
        while (size_t(l.started) < l.members.size()) {
            const int i = l.members[size_t(l.started)];
            if (i != 0 && !(first_ready && now - t0 >= double(i) / opt.connect_rate)) break;
            Player& p = *players[size_t(i)];
            p.next_turn = now + period * double(i % 97) / 97.0;
            p.start(now);
            ++l.started;
            if (i == 0) break;
        }
    }

    // The lane's turns that are due; returns when the next one is.
    double turns(Lane& l, double now) {
        double next_due = now + 0.001;
        for (int k = 0; k < l.started; ++k) {
            double& due = l.due[size_t(k)];
            if (now >= due) {
                const int i = l.members[size_t(k)];
                look_at(l, i, now);
                const Player& q = *players[size_t(i)];  // (a restart replaced it)
                due = q.restart_at >= 0 ? q.restart_at : q.session.running() ? q.next_turn : now + period;
            }
            next_due = std::min(next_due, due);
        }
        return next_due;
    }

    // Player i, due: its start after a restart's backoff, a restart once its
    // session failed before streaming, or its turn.
    void look_at(Lane& l, int i, double now) {
        Player& p = *players[size_t(i)];
        if (p.restart_at >= 0) {  // a replacement waiting for its start
            if (now >= p.restart_at) {
                p.restart_at = -1;
                p.start(now);
            }
        } else if (!p.session.running()) {
            if (!p.failed && p.session.phase() == SessionPhase::Failed) p.failed = true;
            if (p.failed && !p.joined && p.attempt < opt.retries && sh.phase.load(std::memory_order_acquire) == kJoining)
                restart(l, i, now);
        } else if (now >= p.next_turn) {
            ++l.turns;
            if (now - p.next_turn > period) ++l.late;
            p.next_turn = std::max(p.next_turn + period, now);
            p.turn(now);
        }
    }

    // The lane's joined and failed players, for lane 0's steering (every 50 ms).
    void count(Lane& l, double now) {
        if (now < l.next_count) return;
        l.next_count = now + 0.05;
        int joined = 0, failed = 0;
        for (const int i : l.members) {
            joined += players[size_t(i)]->joined ? 1 : 0;
            failed += players[size_t(i)]->failed ? 1 : 0;
        }
        l.n_joined.store(joined, std::memory_order_release);
        l.n_failed.store(failed, std::memory_order_release);
    }

    // Player i failed before streaming: a fresh player (session, sockets) in
    // its place, started after a backoff of 0.5 s x 2^attempt, +-25 %.
    void restart(Lane& l, int i, double now) {
        std::unique_ptr<Player>& slot = players[size_t(i)];
        Player& old = *slot;
        asio::error_code ig;  // its sockets closed now (pending handlers end: its session is over)
        old.tcp_sock.close(ig);
        old.udp_sock.close(ig);
        if (opt.verbose) log("player %d failed (%s): starting it again", i, old.session.error().c_str());
        ClientConfig cfg = cfg_;
        cfg.name = "loadgen" + std::to_string(i);
        auto p = std::make_unique<Player>(sh, l, i, old.node, cfg);
        p->use_source = old.use_source;
        p->source = old.source;
        p->nearest = old.nearest;
        p->next_turn = old.next_turn;
        p->attempt = old.attempt + 1;
        p->started = true;
        const double backoff = 0.5 * double(1 << std::min(old.attempt, 6));
        p->restart_at = now + backoff * std::uniform_real_distribution<double>(0.75, 1.25)(l.jitter);
        replaced[size_t(l.index)].push_back(std::move(slot));
        slot = std::move(p);
        retried_.fetch_add(1, std::memory_order_relaxed);
    }

    // The lane follows lane 0's phase: its players' window opens and closes.
    void follow_phase(Lane& l, double now) {
        const int phase = sh.phase.load(std::memory_order_acquire);
        if (phase >= kMeasuring && !l.in_window && !l.window_done) {
            l.in_window = true;
            l.late = l.turns = 0;
            for (const int i : l.members) {
                Player& p = *players[size_t(i)];
                p.bytes_at_start = p.session.stats(now).wire_bytes;
                p.streamed_window = p.joined && p.session.running();
                for (Obs& o : p.obs) o.max_gap = 0;
            }
            if (opt.on_window) opt.on_window(true);
        }
        if (phase >= kDone && l.in_window) {
            l.in_window = false;
            l.window_done = true;
            if (opt.on_window) opt.on_window(false);
        }
    }

    // Lane 0's steering, once a pass: joins, the window, progress, the end.
    // Returns false once the run is over.
    bool steer(double now) {
        if (stop_ && stop_->load()) {
            rep.error = "stopped";
            return false;
        }
        const int started = lane_sum(&Lane::n_started), joined = lane_sum(&Lane::n_joined), failed = lane_sum(&Lane::n_failed);
        const double join_deadline = t0 + opt.connect_timeout + double(opt.players) / opt.connect_rate + 30.0;
        if (!all_joined_at && started == opt.players && (joined + failed == opt.players || now > join_deadline)) {
            all_joined_at = now;
            rep.join_seconds = now - t0;
            log("%d of %d players joined (%d failed); measuring in %.1f s", joined, opt.players, failed, opt.settle);
        }
        const int phase = sh.phase.load(std::memory_order_relaxed);
        if (phase == kJoining && all_joined_at && now >= all_joined_at + opt.settle) {
            sh.window_start = now;
            cpu_start = cpu_now();
            sh.phase.store(kMeasuring, std::memory_order_release);
        }
        if (phase == kMeasuring && now >= sh.window_start + opt.duration) {
            sh.window_end = now;
            rep.cpu_seconds = cpu_now() - cpu_start;
            window_done_ = true;
            return false;
        }
        if (opt.progress_s > 0 && now >= next_progress) {
            next_progress = now + opt.progress_s;
            uint64_t samples = 0;
            for (const auto& l : lanes) samples += l->n_samples.load(std::memory_order_relaxed);
            const Lane& l0 = *lanes[0];  // (the other lanes' histograms are theirs until the end)
            log("%d started, %d streaming, %d failed, %d restarts, %llu receipt samples, p99 %.1f ms%s%s", started, joined,
                failed, retried_.load(std::memory_order_relaxed), (unsigned long long)samples,
                std::max(l0.receipt.at(0.99), l0.cross_receipt.at(0.99)), lanes.size() > 1 ? " (thread 0)" : "",
                phase == kMeasuring ? " (measuring)" : "");
        }
        if (!all_joined_at && started == opt.players && failed == opt.players) {
            rep.error = "every player failed";
            return false;
        }
        return true;
    }

    // One lane's loop until the run is over (lane 0: until it ends it).
    void lane_loop(Lane& l) {
        for (;;) {
            if (l.index != 0 && sh.phase.load(std::memory_order_acquire) == kDone) break;
            l.io.poll();
            l.io.restart();
            const double now = now_seconds();
            follow_phase(l, now);
            start_players(l, now);
            const double next_due = turns(l, now);
            count(l, now);
            l.n_started.store(l.started, std::memory_order_release);
            l.n_samples.store(l.receipt.n + l.cross_receipt.n, std::memory_order_relaxed);
            if (l.index == 0 && !steer(now)) {
                sh.phase.store(kDone, std::memory_order_release);
                follow_phase(l, now);
                break;
            }
            // Idle: a whole millisecond (the turns due meanwhile go together,
            // at most 1 ms late: one wake-up for several, not one each).
            if (next_due > now_seconds()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        follow_phase(l, now_seconds());
    }

    // Player p's nearest-set pairs in the window (see loadgen.h "starved"); true when one starved.
    bool pairs_of(const Player& p) {
        bool starved = false;
        for (int q : p.nearest) {
            const Player& pub = *players[size_t(q)];
            if (!pub.streamed_window || !pub.session.running()) continue;
            ++rep.pairs;
            const Obs* o = nullptr;
            for (const Obs& x : p.obs)
                if (x.publisher == q) o = &x;
            double gap = rep.window_seconds;
            if (o && o->last_arrival >= sh.window_start) gap = std::max(o->max_gap, sh.window_end - o->last_arrival);
            rep.max_gap_ms = std::max(rep.max_gap_ms, gap * 1000.0);
            if (gap > opt.starve_s) {
                ++rep.starved_pairs;
                starved = true;
            }
        }
        return starved;
    }

    // One player's counts into the report; its rate when it streamed the whole window.
    void add_player(Player& p, double end, std::vector<double>& rates, double& loss_sum) {
        const ClientStats st = p.session.stats(end);
        rep.joined += p.joined ? 1 : 0;
        const std::string who = "player " + std::to_string(p.index) + " (" + node_name(opt, p.node) + "): ";
        if (p.failed || p.session.phase() == SessionPhase::Failed) {
            ++rep.failed;
            if (rep.errors.size() < 20) rep.errors.push_back(who + p.session.error());
        } else if (!p.joined && rep.errors.size() < 20) {
            rep.errors.push_back(who + "never streamed");
        }
        rep.frames += st.datagrams;
        rep.malformed += st.malformed;
        rep.duplicates += st.duplicates;
        rep.poses_sent += st.poses_sent;
        rep.poses_refused += st.poses_refused;
        loss_sum += st.loss;
        if (window_done_ && p.streamed_window && p.session.running()) {
            p.kbps = double(st.wire_bytes - p.bytes_at_start) * 8.0 / 1000.0 / rep.window_seconds;
            rates.push_back(p.kbps);
            rep.starved_players += pairs_of(p) ? 1 : 0;
        }
    }

    void summarise() {
        const double end = sh.window_end > 0 ? sh.window_end : now_seconds();
        rep.window_seconds = window_done_ ? sh.window_end - sh.window_start : 0;
        rep.retried = retried_.load();
        Counts all;  // the lanes' (their threads are joined)
        for (const auto& l : lanes) all.merge(*l);
        std::vector<double> rates;
        double seen_sum = 0, bones_sum = 0, loss_sum = 0;
        uint64_t bones_n = 0;
        rep.seen_min = see;
        for (auto& pp : players) {
            add_player(*pp, end, rates, loss_sum);
            int seen = 0;
            for (const Obs& o : pp->obs) {
                if (!o.nearest) continue;
                seen += o.seen ? 1 : 0;
                bones_sum += double(o.show);
                ++bones_n;
            }
            rep.seen_min = std::min(rep.seen_min, seen);
            seen_sum += seen;
        }
        rep.seen_mean = seen_sum / double(opt.players);
        rep.all_seen = rep.seen_min == see;
        rep.bones_nearest_mean = bones_n ? bones_sum / double(bones_n) : 0;
        rep.bones_mean = all.bones_n ? double(all.bones_sum) / double(all.bones_n) : 0;
        rep.loss_mean = loss_sum / double(opt.players);
        rep.records = all.records;
        rep.bad_records = all.bad_records;
        if (!rates.empty()) {
            rep.rate_kbps_min = *std::min_element(rates.begin(), rates.end());
            rep.rate_kbps_max = *std::max_element(rates.begin(), rates.end());
            double s = 0;
            for (double r : rates) s += r;
            rep.rate_kbps_mean = s / double(rates.size());
        }
        rep.receipt_ms = all.receipt.summary();
        rep.display_ms = all.display.summary();
        rep.cross_receipt_ms = all.cross_receipt.summary();
        rep.cross_display_ms = all.cross_display.summary();
        rep.late_turns = all.turns ? double(all.late) / double(all.turns) : 0;
        rep.turns = all.turns;
        rep.grid_step = sh.step.load();
        if (rep.error.empty()) {
            if (rep.failed > 0) rep.error = std::to_string(rep.failed) + " player(s) failed: " + rep.errors.front();
            else if (rep.joined < opt.players) rep.error = std::to_string(opt.players - rep.joined) + " player(s) never streamed";
            else if (!window_done_) rep.error = "no measurement window";
        }
        rep.ok = rep.error.empty();
    }
};

}  // namespace

LoadReport run_loadgen(const LoadOptions& opt, const std::atomic<bool>* stop) { return Run(opt, stop).run(); }

static nlohmann::json pct(const Percentiles& p) {
    return {{"samples", p.samples}, {"p50", p.p50}, {"p99", p.p99}, {"max", p.max}};
}

std::string report_json(const LoadReport& r, const LoadOptions& o) {
    nlohmann::json j;
    j["ok"] = r.ok;
    j["error"] = r.error;
    j["errors"] = r.errors;
    std::vector<std::string> servers;
    for (const auto& s : o.servers) servers.push_back(s.host + ":" + std::to_string(s.port));
    j["servers"] = servers;
    j["players"] = r.players;
    j["nodes"] = r.nodes;
    j["threads"] = r.threads;
    j["source_addresses"] = r.addresses;
    j["placement"] = o.bands ? "bands" : "round-robin";
    j["grid_step"] = r.grid_step;
    j["joined"] = r.joined;
    j["failed"] = r.failed;
    j["retried"] = r.retried;
    j["join_seconds"] = r.join_seconds;
    j["window_seconds"] = r.window_seconds;
    j["tick_rate"] = o.tick_rate;
    j["max_kbps"] = o.max_kbps;
    j["delay_ms"] = o.delay_ms;
    j["rate_kbps"] = {{"mean", r.rate_kbps_mean}, {"min", r.rate_kbps_min}, {"max", r.rate_kbps_max}};
    j["bones"] = {{"mean", r.bones_mean}, {"nearest_mean", r.bones_nearest_mean}};
    j["nearest"] = {{"see", r.see}, {"seen_min", r.seen_min}, {"seen_mean", r.seen_mean}, {"all_seen", r.all_seen}};
    j["latency_ms"] = {{"receipt", pct(r.receipt_ms)},
                       {"display", pct(r.display_ms)},
                       {"cross_node_receipt", pct(r.cross_receipt_ms)},
                       {"cross_node_display", pct(r.cross_display_ms)}};
    j["starved"] = {{"players", r.starved_players}, {"pairs", r.starved_pairs}, {"of_pairs", r.pairs},
                    {"threshold_s", o.starve_s}, {"max_gap_ms", r.max_gap_ms}};
    j["frames"] = r.frames;
    j["records"] = r.records;
    j["bad_records"] = r.bad_records;
    j["malformed"] = r.malformed;
    j["duplicates"] = r.duplicates;
    j["loss_mean"] = r.loss_mean;
    j["poses"] = {{"sent", r.poses_sent}, {"refused", r.poses_refused}};
    j["loadgen"] = {{"cpu_seconds", r.cpu_seconds},
                    {"cpu_share", r.window_seconds > 0 ? r.cpu_seconds / r.window_seconds : 0.0},
                    {"late_turns", r.late_turns},
                    {"turns", r.turns},
                    {"cpu_us_per_turn", r.turns ? 1e6 * r.cpu_seconds / double(r.turns) : 0.0}};
    return j.dump(2) + "\n";
}

std::string report_table(const LoadReport& r, const LoadOptions& o) {
    char b[2048];
    std::string s;
    std::snprintf(b, sizeof b,
                  "players %d on %d node(s) from %d source address(es), %d thread(s): %d joined, %d failed, %d restarts (join %.1f s, window %.1f s)\n",
                  r.players, r.nodes, r.addresses, r.threads, r.joined, r.failed, r.retried, r.join_seconds, r.window_seconds);
    s += b;
    std::snprintf(b, sizeof b, "%-22s %10s %10s %10s\n", "", "mean/p50", "min/p99", "max");
    s += b;
    std::snprintf(b, sizeof b, "%-22s %10.1f %10.1f %10.1f\n", "rate kbit/s", r.rate_kbps_mean, r.rate_kbps_min, r.rate_kbps_max);
    s += b;
    auto row = [&](const char* name, const Percentiles& p) {
        std::snprintf(b, sizeof b, "%-22s %10.1f %10.1f %10.1f  (%llu samples)\n", name, p.p50, p.p99, p.max,
                      (unsigned long long)p.samples);
        s += b;
    };
    row("receipt ms", r.receipt_ms);
    row("display ms", r.display_ms);
    row("cross-node receipt ms", r.cross_receipt_ms);
    row("cross-node display ms", r.cross_display_ms);
    std::snprintf(b, sizeof b, "bones shown: %.1f mean per chunk, %.1f mean over the nearest %d\n", r.bones_mean,
                  r.bones_nearest_mean, r.see);
    s += b;
    std::snprintf(b, sizeof b, "nearest %d seen: min %d, mean %.1f (%s)\n", r.see, r.seen_min, r.seen_mean,
                  r.all_seen ? "all" : "NOT all");
    s += b;
    std::snprintf(b, sizeof b, "starved (> %.1f s without a frame of a nearest character): %d players, %llu of %llu pairs, longest gap %.0f ms\n",
                  o.starve_s, r.starved_players, (unsigned long long)r.starved_pairs, (unsigned long long)r.pairs, r.max_gap_ms);
    s += b;
    std::snprintf(b, sizeof b, "frames %llu, records %llu (%llu bad), malformed %llu, duplicates %llu, loss %.4f, poses %llu (%llu refused)\n",
                  (unsigned long long)r.frames, (unsigned long long)r.records, (unsigned long long)r.bad_records,
                  (unsigned long long)r.malformed, (unsigned long long)r.duplicates, r.loss_mean,
                  (unsigned long long)r.poses_sent, (unsigned long long)r.poses_refused);
    s += b;
    std::snprintf(b, sizeof b, "loadgen CPU %.2f s over the window (%.0f %% of a core; %.1f us per player turn), %.1f %% of turns late\n",
                  r.cpu_seconds, r.window_seconds > 0 ? 100.0 * r.cpu_seconds / r.window_seconds : 0.0,
                  r.turns ? 1e6 * r.cpu_seconds / double(r.turns) : 0.0, 100.0 * r.late_turns);
    s += b;
    if (!r.ok) s += "FAILED: " + r.error + "\n";
    return s;
}

}  // namespace progskin::net
