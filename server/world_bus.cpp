// world_bus.cpp — see world_bus.h. libnats (Debian's libnats-dev) carries
// the messages; this file decides what goes on the bus and what comes off it.
#include "world_bus.h"

#include <nats/nats.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <random>
#include <string_view>
#include <unordered_map>
#include <unordered_set>

#include "bone_codec.h"
#include "errors.h"
#include "frame_encoder.h"
#include "server_core.h"

namespace progskin::net {

namespace {

// Owner of a foreign character (what makes it a published one for its
// observers): distinct per character, so that each gets its own share of an
// observer's stream. Which instances are foreign is kept apart (is_foreign).
constexpr uint64_t kForeignOwner = uint64_t(1) << 63;
constexpr uint8_t kHelloMagic[4] = {'P', 'S', 'K', 'H'};

void say(const std::string& s) { std::fprintf(stderr, "progskin-server: world: %s\n", s.c_str()); }

}  // namespace

// The NATS URL(s) as logs may show them: the credentials of each
// (nats://USER:PASSWORD@HOST or nats://TOKEN@HOST) replaced by "***".
std::string redact_nats_url(const std::string& urls) {
    std::string out;
    size_t start = 0;
    for (;;) {
        const size_t end = std::min(urls.find(',', start), urls.size());
        std::string u = urls.substr(start, end - start);
        const size_t scheme = u.find("://"), at = u.rfind('@');
        if (scheme != std::string::npos && at != std::string::npos && at > scheme + 3) u.replace(scheme + 3, at - scheme - 3, "***");
        out += u;
        if (end == urls.size()) break;
        out += ',';
        start = end + 1;
    }
    return out;
}

struct WorldBus::Impl {
    WorldConfig cfg;
    ServerCore& core;
    std::string shown_url;  // cfg.url as logs show it (redact_nats_url)
    uint16_t node_id = 0;
    uint64_t catalogue = 0;
    natsOptions* opts = nullptr;
    natsConnection* nc = nullptr;
    natsSubscription* all_cells = nullptr;              // `cell.>`: every cell (no view radius, or a client sees all)
    std::map<std::pair<int64_t, int64_t>, std::pair<natsSubscription*, double>> cell_subs;  // cell -> (sub, last wanted)
    natsSubscription* hellos = nullptr;
    double next_interest = 0;
    // Falling behind (messages dropped since the last interest pass): the
    // node follows only the nearest cell_limit cells it wants, halved at
    // each pass that saw drops, grown back by a quarter each second without.
    size_t cell_limit = kMaxCellSubscriptions;
    uint64_t dropped_seen = 0;
    double next_grow = 0, next_shed_report = 0;
    std::vector<glm::dvec3> centres;                    // interest()'s scratch
    std::vector<std::pair<int64_t, int64_t>> wanted;
    std::vector<std::pair<double, std::pair<int64_t, int64_t>>> by_distance;  // interest()'s scratch when shedding
    std::string cell_prefix, hello_subject;

    // libnats threads -> tick thread
    std::mutex queue_mutex;
    // First byte: 0 cell message, 1 hello; then the subject's hash (8 bytes,
    // the cell), then the message.
    std::deque<std::vector<uint8_t>> queue;
    size_t queued_bytes = 0;

    mutable std::mutex stats_mutex;
    WorldStats st;

    // Shutting down: libnats may still call back on its threads until the
    // connection's closed callback; they do nothing once `closing` is set,
    // and the destructor waits for `closed` before the Impl goes.
    std::atomic<bool> closing{false};
    std::mutex closed_mutex;
    std::condition_variable closed_cv;
    bool closed = false;

    struct Foreign {
        int local = -1;
        double last_seen = 0;
        uint32_t seq = 0;
    };
    std::map<uint32_t, Foreign> foreign;       // by node << 16 | the node's id
    std::vector<bool> is_foreign;               // by local instance id
    std::map<uint16_t, std::string> nodes;      // hellos heard (node id -> name)
    std::map<uint16_t, bool> refused_nodes;     // nodes of another catalogue (said once)
    double next_hello = 0;
    std::vector<uint8_t> out;                   // one message being written
    std::map<std::pair<int64_t, int64_t>, std::vector<WorldCharacter>> by_cell;
    std::vector<WorldCharacter> incoming;
    uint64_t dropped_said = 0;  // dropped messages already said (receive)
    uint64_t superseded_said = 0;
    std::unordered_set<uint64_t> newest;  // receive()'s scratch: (sender, cell) keys seen
    double next_drop_report = 0;

    Impl(WorldConfig c, ServerCore& k) : cfg(std::move(c)), core(k), shown_url(redact_nats_url(cfg.url)) {
        std::random_device rd;
        while (node_id == 0) node_id = uint16_t(rd());
        catalogue = catalogue_hash(core.assets());
        cell_prefix = "progskin." + cfg.world + ".cell.";
        hello_subject = "progskin." + cfg.world + ".hello";
    }

    template <class F>
    void count(F f) {
        std::lock_guard lock(stats_mutex);
        f(st);
    }

    // ------------------------------------------------------- libnats side --
    static void on_message(natsConnection*, natsSubscription* sub, natsMsg* msg, void* closure) {
        auto* self = static_cast<Impl*>(closure);
        if (self->closing) {
            natsMsg_Destroy(msg);
            return;
        }
        const int n = natsMsg_GetDataLength(msg);
        const auto* data = reinterpret_cast<const uint8_t*>(natsMsg_GetData(msg));
        const uint8_t kind = sub == self->hellos ? 1 : 0;  // (a cell's subscription may come and go: not compared)
        {
            std::lock_guard lock(self->queue_mutex);
            if (self->queue.size() < self->cfg.queue_messages && self->queued_bytes + size_t(n) <= kQueueBytes && n >= 0 &&
                size_t(n) <= kWorldMaxMessage) {
                std::vector<uint8_t> m(size_t(n) + kQueuedHeader);
                m[0] = kind;
                const uint64_t cell = std::hash<std::string_view>{}(natsMsg_GetSubject(msg));
                std::memcpy(m.data() + 1, &cell, 8);
                if (n) std::memcpy(m.data() + kQueuedHeader, data, size_t(n));
                self->queued_bytes += m.size();
                self->queue.push_back(std::move(m));
                natsMsg_Destroy(msg);
                return;
            }
        }
        self->count([](WorldStats& s) { ++s.dropped; });
        natsMsg_Destroy(msg);
    }
    static void on_disconnected(natsConnection*, void* closure) {
        auto* self = static_cast<Impl*>(closure);
        if (self->closing) return;
        self->count([](WorldStats& s) { s.connected = false; });
        say("lost the bus (" + self->shown_url + "); reconnecting, local streaming goes on");
    }
    static void on_reconnected(natsConnection*, void* closure) {
        auto* self = static_cast<Impl*>(closure);
        if (self->closing) return;
        self->count([](WorldStats& s) { s.connected = true; });
        say("reconnected to the bus (" + self->shown_url + ")");
    }
    static void on_connected(natsConnection*, void* closure) { on_reconnected(nullptr, closure); }
    static void on_closed(natsConnection*, void* closure) {
        auto* self = static_cast<Impl*>(closure);
        std::lock_guard lock(self->closed_mutex);
        self->closed = true;
        self->closed_cv.notify_all();
    }

    void connect() {
        auto check = [](natsStatus s, const char* what) {
            if (s != NATS_OK) throw Error(std::string("world bus: ") + what + ": " + natsStatus_GetText(s));
        };
        check(natsOptions_Create(&opts), "options");
        check(natsOptions_SetURL(opts, cfg.url.c_str()), ("bad URL " + shown_url).c_str());
        check(natsOptions_SetName(opts, ("progskin " + cfg.node).c_str()), "name");
        check(natsOptions_SetAllowReconnect(opts, true), "reconnect");
        check(natsOptions_SetMaxReconnect(opts, -1), "reconnect");
        check(natsOptions_SetReconnectWait(opts, 250), "reconnect wait");
        check(natsOptions_SetReconnectBufSize(opts, 8 << 20), "reconnect buffer");
        check(natsOptions_SetNoEcho(opts, true), "no echo");  // never our own messages back
        const bool secure = cfg.url.rfind("tls://", 0) == 0 || !cfg.ca_file.empty() || !cfg.cert_file.empty();
        if (secure) {
            check(natsOptions_SetSecure(opts, true), "TLS (a libnats built without TLS?)");
            if (!cfg.ca_file.empty())
                check(natsOptions_LoadCATrustedCertificates(opts, cfg.ca_file.c_str()), ("CA file " + cfg.ca_file).c_str());
            if (!cfg.cert_file.empty())
                check(natsOptions_LoadCertificatesChain(opts, cfg.cert_file.c_str(), cfg.key_file.c_str()),
                      ("certificate " + cfg.cert_file + " and key " + cfg.key_file).c_str());
        }
        check(natsOptions_SetDisconnectedCB(opts, on_disconnected, this), "callback");
        check(natsOptions_SetReconnectedCB(opts, on_reconnected, this), "callback");
        check(natsOptions_SetClosedCB(opts, on_closed, this), "callback");
        // First try once: a NATS server that is up but refuses this node (TLS
        // required or not trusted, authorisation) is an error at start, not
        // a retry for ever; one that is not up yet is retried in the background.
        natsStatus s = natsConnection_Connect(&nc, opts);
        if (s == NATS_NO_SERVER || s == NATS_TIMEOUT) {  // not up (or not answering) yet
            check(natsOptions_SetRetryOnFailedConnect(opts, true, on_connected, this), "retry");
            s = natsConnection_Connect(&nc, opts);
        }
        if (s != NATS_OK && s != NATS_NOT_YET_CONNECTED) {
            const char* detail = nats_GetLastError(nullptr);
            throw Error("world bus: cannot join " + shown_url + ": " + natsStatus_GetText(s) +
                        (detail && *detail ? std::string(" (") + detail + ")" : std::string()) +
                        (s == NATS_SSL_ERROR ? "; is its certificate signed by --nats-ca?"
                         : s == NATS_SECURE_CONNECTION_REQUIRED ? "; it needs TLS: tls://HOST:PORT and --nats-ca"
                         : s == NATS_SECURE_CONNECTION_WANTED ? "; it does not offer TLS: nats://HOST:PORT"
                         : s == NATS_PROTOCOL_ERROR && secure && cfg.cert_file.empty()
                             ? "; does it verify its clients' certificates (--nats-cert, --nats-key)?"
                             : ""));
        }
        if (s == NATS_OK) count([](WorldStats& w) { w.connected = true; });
        check(natsConnection_Subscribe(&hellos, nc, hello_subject.c_str(), on_message, this), "subscribe");
        check(natsSubscription_SetPendingLimits(hellos, int(cfg.queue_messages), int(kQueueBytes)), "pending limits");
        say("node " + cfg.node + " joins world " + cfg.world + " on " + shown_url + (s == NATS_OK ? "" : " (not up yet: retrying)"));
    }

    void publish(const std::string& subject, const std::vector<uint8_t>& bytes) {
        if (natsConnection_Publish(nc, subject.c_str(), bytes.data(), int(bytes.size())) == NATS_OK)
            count([&](WorldStats& s) {
                ++s.messages_out;
                s.bytes_out += bytes.size();
            });
        else count([](WorldStats& s) { ++s.publish_failed; });
    }

    // ------------------------------------------------------- tick side --
    void interest(double now);
    natsSubscription* subscribe(const std::string& subject) {
        natsSubscription* sub = nullptr;
        if (natsConnection_Subscribe(&sub, nc, subject.c_str(), on_message, this) != NATS_OK) return nullptr;
        natsSubscription_SetPendingLimits(sub, int(cfg.queue_messages), int(kQueueBytes));
        return sub;
    }
    // Messages libnats dropped for a subscription (its pending limit, the
    // same bound as the queue's: the tick thread slower than the bus) are
    // counted as dropped too: read at every tick and before it goes.
    std::unordered_map<natsSubscription*, int64_t> lib_dropped_seen;
    void harvest_dropped(natsSubscription* sub) {
        int64_t d = 0;
        if (!sub || natsSubscription_GetDropped(sub, &d) != NATS_OK) return;
        int64_t& seen = lib_dropped_seen[sub];
        if (d > seen) count([&](WorldStats& s) { s.dropped += uint64_t(d - seen); });
        seen = std::max(seen, d);
    }
    void unsubscribe(natsSubscription*& sub) {
        if (!sub) return;
        harvest_dropped(sub);
        lib_dropped_seen.erase(sub);
        natsSubscription_Unsubscribe(sub);
        natsSubscription_Destroy(sub);
        sub = nullptr;
    }
    void publish_own(const EncodedFrame& frame);
    void receive(double now);
    void take_cell(std::span<const uint8_t> bytes, double now);
    void take_hello(std::span<const uint8_t> bytes);
    void expire(double now);
    void hello(double now);
};

// This node's characters, batched by cell: one message per non-empty cell.
void WorldBus::Impl::publish_own(const EncodedFrame& frame) {
    by_cell.clear();
    const ServerAssets& assets = core.assets();
    InstanceSpec spec;
    for (size_t i = 0; i < frame.instances.size(); ++i) {
        const EncodedInstance& e = frame.instances[i];
        if (!e.valid || (i < is_foreign.size() && is_foreign[i]) || !core.encoder().spec_if_active(int(i), spec)) continue;
        WorldCharacter c;
        if (!world_character(frame, int(i), RootPose{glm::dvec3(spec.position), spec.rotation}, c)) continue;
        c.world_id = spec.world_id;
        c.published = spec.owner != 0;
        if (c.published) {  // a player's: what it announced, for its observers' references
            c.clips = spec.announced_clips;
            c.publisher_start_us = spec.publisher_start_us;
            c.walk_center = {spec.walk_center.x, spec.walk_center.y, spec.walk_center.z};
            c.walk_radius = spec.walk_radius;
            c.walk_speed = spec.walk_speed;
        }
        const auto cell = std::make_pair(int64_t(std::floor(e.world.x / cfg.cell_size)), int64_t(std::floor(e.world.z / cfg.cell_size)));
        by_cell[cell].push_back(std::move(c));
    }
    for (auto& [cell, list] : by_cell) {
        if (list.empty()) continue;
        for (size_t at = 0; at < list.size(); at += kWorldMaxCharacters) {
            const size_t n = std::min(kWorldMaxCharacters, list.size() - at);
            write_world_message({node_id, catalogue, frame.tick}, std::span(list).subspan(at, n), assets, out);
            publish(cell_prefix + std::to_string(cell.first) + "." + std::to_string(cell.second), out);
        }
    }
}

// Interest management, every kInterestPeriod: the cells within the view
// radius of this node's clients' centres (ServerCore::view_centres), each a
// subscription of its own, kept kInterestLinger after it was last wanted (a
// character walking along a cell edge does not make it come and go); every
// cell (one wildcard subscription) without a radius, when a client has no
// centre, or beyond kMaxCellSubscriptions. No client: no cell.
void WorldBus::Impl::interest(double now) {
    if (now < next_interest) return;
    next_interest = now + kInterestPeriod;
    const double r = core.config().view_radius;
    centres.clear();
    wanted.clear();
    const int clients = core.view_centres(centres);  // -1: a client sees everything
    bool all = r <= 0 ? clients != 0 : clients < 0;  // without a radius: every cell while anybody is connected
    for (const glm::dvec3& c : centres) {
        if (all || r <= 0) break;
        const int64_t x0 = int64_t(std::floor((c.x - r) / cfg.cell_size)), x1 = int64_t(std::floor((c.x + r) / cfg.cell_size));
        const int64_t z0 = int64_t(std::floor((c.z - r) / cfg.cell_size)), z1 = int64_t(std::floor((c.z + r) / cfg.cell_size));
        if ((x1 - x0 + 1) * (z1 - z0 + 1) > int64_t(kMaxCellSubscriptions)) {
            all = true;
            break;
        }
        for (int64_t x = x0; x <= x1; ++x)
            for (int64_t z = z0; z <= z1; ++z) wanted.emplace_back(x, z);
        if (wanted.size() > 4 * kMaxCellSubscriptions) {  // clients close together want the same cells: count them once
            std::sort(wanted.begin(), wanted.end());
            wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
        }
    }
    std::sort(wanted.begin(), wanted.end());
    wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
    if (wanted.size() > kMaxCellSubscriptions) all = true;
    // Behind: fewer cells, the nearest to the clients' centres first.
    uint64_t dropped = 0;
    count([&](WorldStats& s) { dropped = s.dropped; });
    if (dropped > dropped_seen && !all && !wanted.empty()) {
        cell_limit = std::max<size_t>(1, std::min(cell_limit, wanted.size()) / 2);
        next_grow = now + 1.0;
    } else if (now >= next_grow && cell_limit < kMaxCellSubscriptions) {
        cell_limit = std::min(kMaxCellSubscriptions, cell_limit + std::max<size_t>(1, cell_limit / 4));
        next_grow = now + 1.0;
    }
    dropped_seen = dropped;
    size_t shed = 0;
    if (!all && wanted.size() > cell_limit) {
        // Each cell's squared distance to the nearest centre, once.
        by_distance.clear();
        for (const auto& cell : wanted) {
            const double cx = (double(cell.first) + 0.5) * cfg.cell_size, cz = (double(cell.second) + 0.5) * cfg.cell_size;
            double best = 1e300;
            for (const glm::dvec3& c : centres) best = std::min(best, (c.x - cx) * (c.x - cx) + (c.z - cz) * (c.z - cz));
            by_distance.emplace_back(best, cell);
        }
        std::nth_element(by_distance.begin(), by_distance.begin() + long(cell_limit), by_distance.end());
        shed = wanted.size() - cell_limit;
        wanted.resize(cell_limit);
        for (size_t k = 0; k < cell_limit; ++k) wanted[k] = by_distance[k].second;
        std::sort(wanted.begin(), wanted.end());
        for (auto it = cell_subs.begin(); it != cell_subs.end();) {  // the shed ones go now, not after the linger
            if (!std::binary_search(wanted.begin(), wanted.end(), it->first)) {
                unsubscribe(it->second.first);
                it = cell_subs.erase(it);
            } else {
                ++it;
            }
        }
        if (now >= next_shed_report) {
            say("fell behind on the bus: following the nearest " + std::to_string(cell_limit) + " of " +
                std::to_string(cell_limit + shed) + " cells its clients want");
            next_shed_report = now + 5.0;
        }
    }
    if (all) {
        if (!all_cells && !(all_cells = subscribe(cell_prefix + ">"))) count([](WorldStats& s) { ++s.subscribe_failed; });
        for (auto& [cell, sub] : cell_subs) unsubscribe(sub.first);
        cell_subs.clear();
    } else {
        for (const auto& cell : wanted) {
            auto [it, fresh] = cell_subs.try_emplace(cell, nullptr, now);
            it->second.second = now;
            if (fresh && !(it->second.first = subscribe(cell_prefix + std::to_string(cell.first) + "." + std::to_string(cell.second)))) {
                count([](WorldStats& s) { ++s.subscribe_failed; });
                cell_subs.erase(it);
            }
        }
        for (auto it = cell_subs.begin(); it != cell_subs.end();) {
            if (now - it->second.second > kInterestLinger) {
                unsubscribe(it->second.first);
                it = cell_subs.erase(it);
            } else {
                ++it;
            }
        }
        unsubscribe(all_cells);
    }
    count([&](WorldStats& s) {
        s.cells = all_cells ? -1 : int(cell_subs.size());
        s.cells_shed = int(shed);
    });
}

void WorldBus::Impl::receive(double now) {
    harvest_dropped(hellos);
    harvest_dropped(all_cells);
    for (const auto& [cell, sub] : cell_subs) harvest_dropped(sub.first);
    std::deque<std::vector<uint8_t>> got;
    {
        std::lock_guard lock(queue_mutex);
        got.swap(queue);
        queued_bytes = 0;
    }
    // A node behind the bus (more than one message of a sender's cell since
    // the last tick) takes only the newest of each: each message holds the
    // whole cell of its sender at its tick, so the older ones are superseded
    // (a character that left the cell is in its new cell's message). The
    // work per tick is then bounded by the cells, not by the backlog.
    newest.clear();
    for (size_t i = got.size(); i-- > 0;) {
        std::vector<uint8_t>& m = got[i];
        if (m[0] != 0 || m.size() < kQueuedHeader + 8 || std::memcmp(m.data() + kQueuedHeader, "PSKW", 4) != 0) continue;
        uint64_t cell;
        std::memcpy(&cell, m.data() + 1, 8);
        const uint64_t node = uint64_t(m[kQueuedHeader + 6]) | uint64_t(m[kQueuedHeader + 7]) << 8;
        if (!newest.insert(cell ^ (node * 0x9E3779B97F4A7C15ull)).second) {
            m.clear();  // superseded
            count([](WorldStats& s) { ++s.superseded; });
        }
    }
    // Fell behind (the queue was full, messages dropped): say so, at most every 5 s.
    if (now >= next_drop_report) {
        uint64_t dropped = 0;
        count([&](WorldStats& s) { dropped = s.dropped; });
        uint64_t superseded = 0;
        count([&](WorldStats& s) { superseded = s.superseded; });
        if (dropped > dropped_said || superseded > superseded_said) {
            say("fell behind on the bus: " + std::to_string(dropped - dropped_said) +
                " messages dropped (foreign characters show older poses or go), " +
                std::to_string(superseded - superseded_said) + " skipped for a newer one of the same cell");
            dropped_said = dropped;
            superseded_said = superseded;
            next_drop_report = now + 5.0;
        }
    }
    for (const auto& m : got) {
        if (m.empty()) continue;  // superseded
        count([&](WorldStats& s) {
            ++s.messages_in;
            s.bytes_in += m.size() - kQueuedHeader;
        });
        const std::span<const uint8_t> body(m.data() + kQueuedHeader, m.size() - kQueuedHeader);
        if (m[0] == 1) take_hello(body);
        else take_cell(body, now);
    }
}

// Another node's cell: each character into the scene (added when new).
void WorldBus::Impl::take_cell(std::span<const uint8_t> bytes, double now) {
    WorldHeader h;
    const std::string why = read_world_message(bytes, core.assets(), catalogue, h, incoming);
    if (!why.empty()) {
        const bool other = why == "another catalogue";
        count([&](WorldStats& s) { ++(other ? s.refused : s.malformed); });
        if (other && !refused_nodes[h.node]) {
            refused_nodes[h.node] = true;
            say("node " + (nodes.count(h.node) ? nodes[h.node] : std::to_string(h.node)) +
                " serves another catalogue: its characters are refused (start every node with the same assets)");
        }
        return;
    }
    for (const WorldCharacter& c : incoming) {
        const uint32_t key = uint32_t(h.node) << 16 | c.id;
        auto it = foreign.find(key);
        if (it == foreign.end()) {
            InstanceSpec sp;
            sp.asset = c.asset;
            sp.selection = -1;
            sp.owner = c.published ? kForeignOwner | key : 0;  // a player's stays one (its own share)
            sp.announced_clips = c.clips;
            sp.publisher_start_us = c.publisher_start_us;
            sp.walk_center = {c.walk_center[0], c.walk_center[1], c.walk_center[2]};
            sp.walk_radius = c.walk_radius;
            sp.walk_speed = c.walk_speed;
            sp.position = glm::vec3(decode_root(c.root.data()).position);
            sp.world_id = c.world_id;  // its own node's: one id for the character on every node
            try {
                it = foreign.emplace(key, Foreign{core.add_instance(sp), now, 0}).first;
            } catch (const Error&) {  // every instance id taken
                count([](WorldStats& s) { ++s.dropped; });
                continue;
            }
            const size_t local = size_t(it->second.local);
            if (is_foreign.size() <= local) is_foreign.resize(local + 1, false);
            is_foreign[local] = true;
            count([](WorldStats& s) { ++s.foreign_added; });
        }
        Foreign& f = it->second;
        f.last_seen = now;
        // Composed and coded again, they give the same integers (world_message.h).
        core.encoder().push_relative(f.local, ++f.seq, c.epoch, 0, c.ints, c.root, c.morphs, c.sample);
    }
}

void WorldBus::Impl::take_hello(std::span<const uint8_t> bytes) {
    if (bytes.size() < 4 + 2 + 8 + 1 || std::memcmp(bytes.data(), kHelloMagic, 4) != 0 || bytes.size() != 15u + bytes[14]) {
        count([](WorldStats& s) { ++s.malformed; });
        return;
    }
    uint16_t node;
    uint64_t cat;
    std::memcpy(&node, bytes.data() + 4, 2);
    std::memcpy(&cat, bytes.data() + 6, 8);
    const std::string name(reinterpret_cast<const char*>(bytes.data() + 15), bytes[14]);
    if (nodes.emplace(node, name).second) {
        say("node " + name + " is in world " + cfg.world + (cat == catalogue ? "" : " with another catalogue: refused"));
        count([](WorldStats& s) { ++s.nodes_seen; });
    }
}

// Foreign characters not heard from for kForeignTimeout: gone (their node died, left or lost the bus).
void WorldBus::Impl::expire(double now) {
    for (auto it = foreign.begin(); it != foreign.end();) {
        if (now - it->second.last_seen > kForeignTimeout) {
            core.remove_instance(it->second.local);
            is_foreign[size_t(it->second.local)] = false;
            count([](WorldStats& s) { ++s.foreign_removed; });
            it = foreign.erase(it);
        } else {
            ++it;
        }
    }
    count([&](WorldStats& s) { s.foreign = int(foreign.size()); });
}

void WorldBus::Impl::hello(double now) {
    if (now < next_hello) return;
    next_hello = now + 1.0;
    out.assign(kHelloMagic, kHelloMagic + 4);
    out.resize(15);
    std::memcpy(out.data() + 4, &node_id, 2);
    std::memcpy(out.data() + 6, &catalogue, 8);
    const std::string name = cfg.node.substr(0, 255);
    out[14] = uint8_t(name.size());
    out.insert(out.end(), name.begin(), name.end());
    publish(hello_subject, out);
}

WorldBus::WorldBus(WorldConfig cfg, ServerCore& core) : impl_(std::make_unique<Impl>(std::move(cfg), core)) {
    if (impl_->cfg.world.empty() || impl_->cfg.world.find_first_of(".*> \t") != std::string::npos)
        throw Error("world name '" + impl_->cfg.world + "': no dots, spaces, * or >");
    if (!(impl_->cfg.cell_size > 0)) throw Error("world cell size must be > 0");
    if (impl_->cfg.queue_messages < 1 || impl_->cfg.queue_messages > WorldConfig::kMaxQueueMessages)
        throw Error("world bus queue of " + std::to_string(impl_->cfg.queue_messages) + " messages: must be in [1, " +
                    std::to_string(WorldConfig::kMaxQueueMessages) + "]");
    impl_->connect();
}

WorldBus::~WorldBus() {
    if (!impl_) return;
    impl_->closing = true;
    for (auto& [cell, sub] : impl_->cell_subs) natsSubscription_Destroy(sub.first);
    for (natsSubscription* s : {impl_->all_cells, impl_->hellos})
        if (s) natsSubscription_Destroy(s);
    if (impl_->nc) {
        natsConnection_Close(impl_->nc);
        // The closed callback is libnats' last: after it no callback holds the Impl.
        std::unique_lock lock(impl_->closed_mutex);
        impl_->closed_cv.wait_for(lock, std::chrono::seconds(5), [&] { return impl_->closed; });
        lock.unlock();
        natsConnection_Destroy(impl_->nc);
    }
    if (impl_->opts) natsOptions_Destroy(impl_->opts);
}

void WorldBus::before_tick(double now) {
    impl_->interest(now);
    impl_->receive(now);
    impl_->expire(now);
    impl_->hello(now);
}

void WorldBus::publish(const EncodedFrame& frame) { impl_->publish_own(frame); }

WorldStats WorldBus::stats() const {
    std::lock_guard lock(impl_->stats_mutex);
    return impl_->st;
}

}  // namespace progskin::net
