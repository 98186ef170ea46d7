// server_core.cpp — see server_core.h.
#include "server_core.h"

#include <algorithm>
#include <cstdio>

#include <sodium.h>

#include "errors.h"
#include "web_endpoint.h"

namespace progskin::net {

namespace {

// 64 bits from the operating system's cryptographic generator (libsodium).
uint64_t random_u64() {
    uint64_t v = 0;
    while (v == 0) randombytes_buf(&v, sizeof v);
    return v;
}

// Constant-time comparison of two strings of any lengths: compares their
// BLAKE2b digests, so neither the content nor the length leaks through timing.
bool equal_secret(const std::string& a, const std::string& b) {
    unsigned char ha[32], hb[32];
    crypto_generichash(ha, sizeof ha, reinterpret_cast<const unsigned char*>(a.data()), a.size(), nullptr, 0);
    crypto_generichash(hb, sizeof hb, reinterpret_cast<const unsigned char*>(b.data()), b.size(), nullptr, 0);
    return sodium_memcmp(ha, hb, sizeof ha) == 0;
}

}  // namespace

ServerCore::ServerCore(ServerConfig c, ServerAssets a, std::vector<InstanceSpec> instances)
    : cfg_(std::move(c)), assets_(a), encoder_(a, std::move(instances), cfg_.tick_rate) {
    if (!(cfg_.tick_rate > 0 && cfg_.tick_rate <= 240)) throw Error("tick rate must be in (0, 240]");
    encoder_.set_key_samples(cfg_.key_samples);
    if (assets_.empty()) throw Error("server: no assets");
    if (cfg_.threads < 0 || cfg_.threads > TickPool::kMaxThreads)
        throw Error("server: threads must be in [0, " + std::to_string(TickPool::kMaxThreads) + "] (0: the machine's cores)");
    if (sodium_init() < 0) throw Error("server: libsodium could not be initialised");
    if (cfg_.tls_cert_file.empty() != cfg_.tls_key_file.empty())
        throw Error("server: TLS needs both a certificate and a private key file");
    if (cfg_.seal_datagrams && !tls()) throw Error("server: sealed datagrams need TLS (their keys travel in the Welcome)");
    if (cfg_.web_port > 65535) throw Error("server: web port must be in [0, 65535]");
    // With TLS the WebSocket endpoint is wss:// with the same certificate (web_endpoint.h).
    if (!cfg_.token_public_key.empty() && !cfg_.token.empty())
        throw Error("server: an access token and connect tokens both travel in Hello.token; configure one");
    if (!cfg_.token_public_key.empty()) {
        if (!crypto::from_hex(cfg_.token_public_key, token_key_))
            throw Error("server: the connect token public key must be 64 hex digits");
        connect_tokens_ = true;
    }
    for (const auto& x : assets_) total_asset_bytes_ += double(x->bytes.size());
}

void ServerCore::log(const std::string& s) const {
    if (cfg_.verbose) std::fprintf(stderr, "progskin-server: %s\n", s.c_str());
}

ServerStats ServerCore::stats() const {
    const EncoderStats es = encoder_.stats();
    std::lock_guard lock(stats_mutex_);
    ServerStats s = stats_;
    s.poses_out_of_range = es.poses_out_of_range;
    s.morphs_out_of_range = es.morphs_out_of_range;
    return s;
}

int ServerCore::view_centres(std::vector<glm::dvec3>& out) {
    std::lock_guard lock(mutex_);
    const EncodedFrame& frame = encoder_.frame();
    int clients = 0;
    for (const auto& [id, entry] : sessions_) {
        const SessionState st = entry.stream->state();
        if (st != SessionState::Welcomed && st != SessionState::Streaming) continue;
        if (!entry.stream->view_centres(frame, out)) return -1;
        ++clients;
    }
    return clients;
}

int ServerCore::add_instance(const InstanceSpec& spec) {
    const int id = encoder_.add_instance(spec);
    ++instances_version_;
    return id;
}

void ServerCore::remove_instance(int id) {
    encoder_.remove_instance(id);
    ++instances_version_;
}

// --------------------------------------------------------------- sessions --

std::shared_ptr<ClientStream> ServerCore::open(const PeerAddress& remote, double now) {
    uint64_t id;
    do id = random_u64();
    while (sessions_.count(id));
    auto s = std::make_shared<ClientStream>(*this, id, random_u64(), now, remote);
    int same = 0;
    for (auto& [other, e] : sessions_)
        if (e.stream->is_open() && e.remote.same_ip(remote)) ++same;
    sessions_[id] = {s, remote};
    count([](ServerStats& st) { ++st.sessions_total; });
    if (!admit_connection(remote, now)) {  // closed without a word, no handshake spent on it
        refused("connect_rate");
        s->close("connection rate from " + remote.ip_string());
    } else if (cfg_.max_per_address > 0 && same >= cfg_.max_per_address) {
        refused("connections_per_address");
        if (tls()) {  // no handshake spent on it: closed without a message
            count([](ServerStats& st) { ++st.refused; });
            s->close("too many connections from " + remote.ip_string());
        } else {
            s->refuse("too many connections from " + remote.ip_string() + " (" + std::to_string(cfg_.max_per_address) + ")", now);
        }
    } else {
        limit_handshakes();
    }
    return s;
}

// ---------------------------------------------------------------- budgets --

void ServerCore::refused(const std::string& reason) {
    count([&](ServerStats& st) { ++st.refusals[reason]; });
}

double ServerCore::asset_bucket_bytes() const {
    return cfg_.asset_bytes_per_minute > 0 ? cfg_.asset_bytes_per_minute
                                           : 64.0 * total_asset_bytes_ + double(MAX_ASSET_CHUNK);
}

// The address's buckets, refilled to `now`; created full. Null when the
// table is full of addresses still in use (kMaxAddresses): not tracked.
ServerCore::AddressBudget* ServerCore::budget_of(const PeerAddress& remote, double now) {
    constexpr size_t kMaxAddresses = 65536;
    auto it = addresses_.find(remote);
    if (it == addresses_.end()) {
        if (addresses_.size() >= kMaxAddresses) prune_addresses(now);
        if (addresses_.size() >= kMaxAddresses) return nullptr;
        PeerAddress key = remote;
        key.port = 0;
        it = addresses_.emplace(key, AddressBudget{8.0 * cfg_.connects_per_second, now, asset_bucket_bytes(), now}).first;
    }
    AddressBudget& b = it->second;
    b.connects = std::min(8.0 * cfg_.connects_per_second, b.connects + (now - b.connects_at) * cfg_.connects_per_second);
    b.connects_at = now;
    const double assets = asset_bucket_bytes();
    b.assets = std::min(assets, b.assets + (now - b.assets_at) * assets / 60.0);
    b.assets_at = now;
    return &b;
}

bool ServerCore::admit_connection(const PeerAddress& remote, double now) {
    if (cfg_.connects_per_second <= 0) return true;
    AddressBudget* b = budget_of(remote, now);
    if (!b) return true;
    if (b->connects < 1.0) return false;
    b->connects -= 1.0;
    return true;
}

bool ServerCore::charge_assets(const PeerAddress& remote, size_t n, double now) {
    AddressBudget* b = budget_of(remote, now);
    if (!b) return true;
    if (b->assets < double(n)) return false;
    b->assets -= double(n);
    return true;
}

// Addresses whose buckets are full again and that hold no session are forgotten.
void ServerCore::prune_addresses(double now) {
    std::map<PeerAddress, int, IpLess> in_use;
    for (const auto& [id, e] : sessions_) ++in_use[e.remote];
    const double assets = asset_bucket_bytes();
    for (auto it = addresses_.begin(); it != addresses_.end();) {
        const AddressBudget& b = it->second;
        const bool full = b.connects + (now - b.connects_at) * cfg_.connects_per_second >= 8.0 * cfg_.connects_per_second &&
                          b.assets + (now - b.assets_at) * assets / 60.0 >= assets;
        if (full && !in_use.count(it->first)) it = addresses_.erase(it);
        else ++it;
    }
}

// More connections before Hello than max_handshakes: the oldest go first (a
// slow or stalled handshake has had the longest time; an honest one takes
// milliseconds).
void ServerCore::limit_handshakes() {
    if (cfg_.max_handshakes <= 0) return;
    std::vector<ClientStream*> waiting;
    for (auto& [id, e] : sessions_)
        if (e.stream->state() == SessionState::AwaitHello) waiting.push_back(e.stream.get());
    if (waiting.size() <= size_t(cfg_.max_handshakes)) return;
    const size_t over = waiting.size() - size_t(cfg_.max_handshakes);
    std::nth_element(waiting.begin(), waiting.begin() + long(over - 1), waiting.end(),
                     [](const ClientStream* a, const ClientStream* b) { return a->opened_at() < b->opened_at(); });
    for (size_t i = 0; i < over; ++i) {
        refused("handshake_evicted");
        waiting[i]->close("handshake evicted: " + std::to_string(cfg_.max_handshakes) + " in progress");
    }
}

std::string ServerCore::spawn_budget(const ClientStream& s) const {
    if (cfg_.max_characters_per_address <= 0) return {};
    size_t n = 0;
    for (const auto& [id, e] : sessions_)
        if (e.stream->is_open() && e.remote.same_ip(s.remote())) n += e.stream->owned_count();
    if (n < size_t(cfg_.max_characters_per_address)) return {};
    return "the players at " + s.remote().ip_string() + " own " + std::to_string(n) + " characters (at most " +
           std::to_string(cfg_.max_characters_per_address) + " per address)";
}

// Who goes when the server is full (ServerConfig::evict_after): the oldest
// session still unbound that long after its Welcome and not downloading, else
// the one silent longest (no Ack that long), else the newest of the address
// holding the most sessions if it holds more than the newcomer's address + 1.
ClientStream* ServerCore::eviction_candidate(const ClientStream& newcomer, double now, std::string& reason) {
    const double grace = cfg_.evict_after;
    ClientStream *unbound = nullptr, *idle = nullptr;
    std::map<PeerAddress, std::pair<int, ClientStream*>, IpLess> per_ip;  // welcomed sessions, the newest
    for (auto& [id, e] : sessions_) {
        ClientStream* s = e.stream.get();
        if (s == &newcomer || !s->welcomed()) continue;
        if (s->state() == SessionState::Welcomed && now - s->welcomed_at() > grace && now - s->last_asset_request() > grace &&
            (!unbound || s->welcomed_at() < unbound->welcomed_at()))
            unbound = s;
        if (s->state() == SessionState::Streaming && heard_until(now) - s->last_heard() > grace &&
            (!idle || s->last_heard() < idle->last_heard()))
            idle = s;
        auto& [n, newest] = per_ip[e.remote];
        ++n;
        if (!newest || s->welcomed_at() > newest->welcomed_at()) newest = s;
    }
    if (unbound) return reason = "evicted_unbound", unbound;
    if (idle) return reason = "evicted_idle", idle;
    const auto mine = per_ip.find(newcomer.remote());
    const int own = mine == per_ip.end() ? 0 : mine->second.first;
    auto heaviest = std::max_element(per_ip.begin(), per_ip.end(),
                                     [](const auto& a, const auto& b) { return a.second.first < b.second.first; });
    if (heaviest != per_ip.end() && heaviest->second.first > own + 1) return reason = "evicted_address_share", heaviest->second.second;
    return nullptr;
}

bool ServerCore::make_room(const ClientStream& newcomer, double now) {
    std::string reason;
    ClientStream* s = eviction_candidate(newcomer, now, reason);
    if (!s) return false;
    refused(reason);
    s->evict("server full, " + reason.substr(8) + " session evicted for a newcomer", now);
    return true;
}

double ServerCore::heard_until(double now) const {
    if (drained_ < 0 || now - drained_ > 2.0 * cfg_.client_timeout) return now;
    return std::min(now, drained_);
}

// One number per owning session, 0 for the server's characters. (Sessions,
// not addresses: players behind one NAT keep a share each; what one address
// can add in all is bounded by its characters, max_characters_per_address.)
void ServerCore::update_owner_groups(const EncodedFrame* frame) {
    owner_groups_.clear();
    if (!frame) return;
    owner_groups_.resize(frame->instances.size(), 0);
    std::map<uint64_t, uint32_t> groups;
    for (size_t i = 0; i < frame->instances.size(); ++i) {
        const EncodedInstance& e = frame->instances[i];
        if (e.active && e.owner != 0) owner_groups_[i] = groups.emplace(e.owner, uint32_t(groups.size() + 1)).first->second;
    }
}

void ServerCore::erase(uint64_t id, double now) {
    if (sessions_.erase(id)) {
        closed_recently_.emplace_back(id, now);
        if (closed_recently_.size() > kClosedRemembered) closed_recently_.pop_front();
    }
}

bool ServerCore::closed_recently(uint64_t id, double now) {
    while (!closed_recently_.empty() && closed_recently_.front().second < now - kClosedRememberSeconds)
        closed_recently_.pop_front();
    for (const auto& [closed, at] : closed_recently_)
        if (closed == id) return true;
    return false;
}

int ServerCore::welcomed_sessions() const {
    int n = 0;
    for (const auto& [id, e] : sessions_)
        if (e.stream->welcomed()) ++n;
    return n;
}

std::string ServerCore::check_token(const flatbuffers::String* token, std::string& who) {
    if (!cfg_.token.empty() && (!token || !equal_secret(token->str(), cfg_.token))) return "bad or missing access token";
    if (!connect_tokens_) return {};
    crypto::ConnectToken ct;
    const uint64_t now_unix = crypto::unix_now();
    std::string why = token ? crypto::verify_connect_token(token->str(), token_key_, now_unix, cfg_.public_address, ct)
                            : std::string("missing connect token");
    if (why.empty() && !token_replays_.first_use(ct, now_unix)) why = "connect token already used";
    if (!why.empty()) {
        count([](ServerStats& st) { ++st.tokens_refused; });
        return why;
    }
    who = "client " + std::to_string(ct.client_id) + " ";
    return {};
}

// -------------------------------------------------------------- datagrams --

// The session a client -> server datagram names, when its token matches and
// it is Welcomed or Streaming (and, sealed, the session whose key opened it).
// The session id and token a client -> server datagram names; false for the
// server -> client bodies (Frame, BindAck, Challenge).
static bool session_and_token(const wire::Datagram& d, uint64_t& id, uint64_t& token) {
    switch (d.body_type()) {
        case wire::DatagramBody::Bind: id = d.body_as_Bind()->session_id(), token = d.body_as_Bind()->token(); return true;
        case wire::DatagramBody::ChallengeResponse:
            id = d.body_as_ChallengeResponse()->session_id(), token = d.body_as_ChallengeResponse()->token();
            return true;
        case wire::DatagramBody::Ack: id = d.body_as_Ack()->session_id(), token = d.body_as_Ack()->token(); return true;
        case wire::DatagramBody::Pose: id = d.body_as_Pose()->session_id(), token = d.body_as_Pose()->token(); return true;
        default: return false;
    }
}

uint64_t ServerCore::datagram_session(const wire::Datagram& d) {
    uint64_t id = 0, token = 0;
    return session_and_token(d, id, token) ? id : 0;
}

// Session `id` (sealed: the one whose key opened the datagram) is saying
// goodbye or was erased in the last kClosedRememberSeconds: what its client
// sent meanwhile (an Ack crossing the Goodbye) is late, not an attack.
bool ServerCore::ending(const ClientStream* sealed_by, uint64_t id, double now) {
    if (sealed_by) return !sealed_by->is_open();
    auto it = sessions_.find(id);
    return it != sessions_.end() ? !it->second.stream->is_open() : closed_recently(id, now);
}

ClientStream* ServerCore::route(const wire::Datagram& d, ClientStream* sealed_by) {
    uint64_t id = 0, token = 0;
    if (!session_and_token(d, id, token)) return nullptr;
    auto it = sessions_.find(id);
    if (it == sessions_.end() || !it->second.stream->accepts(token)) return nullptr;
    ClientStream* s = it->second.stream.get();
    return sealed_by && s != sealed_by ? nullptr : s;  // sealed under another session's key
}

void ServerCore::on_datagram(std::span<const uint8_t> bytes, const PeerAddress& from, double now, DatagramSink& out) {
    count([](ServerStats& st) { ++st.datagrams_received; });
    const size_t n = bytes.size();
    auto reject = [&](bool malformed) {
        count([&](ServerStats& st) {
            if (malformed) ++st.malformed_datagrams;
            else ++st.rejected_datagrams;
            st.unverified_bytes_in += n;
        });
    };
    // A datagram of a session closed in the last kClosedRememberSeconds (its
    // last Ack crossing the Goodbye): dropped, counted apart from attacks.
    auto late = [&] { count([&](ServerStats& st) { ++st.late_datagrams; }); };
    ClientStream* sealed_by = nullptr;  // seal_datagrams: the session whose key opened it
    // A WebSocket session's datagrams come through its connection, never
    // sealed (ClientStream::never_seal); one naming a sealed session is refused below.
    const bool web = WebEndpoint::is_web(from);
    if (cfg_.seal_datagrams && !web) {
        auto it = sessions_.find(crypto::sealed_session_id(bytes));
        if (it == sessions_.end() && closed_recently(crypto::sealed_session_id(bytes), now)) return late();
        if (it == sessions_.end()) return reject(false);  // unsealed, or no such session
        const crypto::OpenResult opened = it->second.stream->open_sealed(bytes, opened_);
        if (opened == crypto::OpenResult::replayed)
            return count([&](ServerStats& st) {
                ++st.stale_datagrams;
                st.unverified_bytes_in += n;
            });
        if (opened != crypto::OpenResult::ok) return reject(false);  // forged
        sealed_by = it->second.stream.get();
        bytes = opened_;
    }
    const wire::Datagram* d = verify_datagram(bytes);
    if (!d) return reject(true);
    ClientStream* s = route(*d, sealed_by);
    if (!s && ending(sealed_by, datagram_session(*d), now)) return late();
    if (!s || (web && s->sealed())) return reject(false);
    const DatagramVerdict v = s->on_datagram(*d, bytes.size(), from, now, out);
    if (v != DatagramVerdict::accepted) reject(v == DatagramVerdict::malformed);
}

// ------------------------------------------------------------------- tick --

void ServerCore::set_pool(TickPool* pool) {
    pool_ = pool;
    encoder_.set_pool(pool);  // the tick's encode on the same threads, before the clients' ticks
    const size_t n = pool ? size_t(pool->threads()) : 0;
    pool_scratch_.clear();
    for (size_t i = 0; i < n; ++i) pool_scratch_.push_back(std::make_unique<TickScratch>());
    totals_.assign(std::max<size_t>(n, 1), ThreadTotals{});
}

TickResult ServerCore::tick_streams(std::span<ClientStream* const> streams, const EncodedFrame& frame, double now, double dt,
                                    DatagramSink& out) {
    TickResult all;
    if (!pool_ || pool_->threads() == 1 || streams.size() < 2) {
        for (ClientStream* s : streams) {
            const TickResult r = s->tick(frame, now, dt, out, pool_ ? *pool_scratch_[0] : scratch_);
            all.datagrams += r.datagrams;
            all.wire_bytes += r.wire_bytes;
        }
        return all;
    }
    // Sessions are taken a few at a time from a shared counter (a slow one
    // does not hold up a whole share); each goes to exactly one thread.
    constexpr size_t kBatch = 4;
    std::atomic<size_t> next{0};
    auto job = [&](int w) {
        ThreadTotals& t = totals_[size_t(w)];
        t = {};
        TickScratch& scratch = *pool_scratch_[size_t(w)];
        for (size_t at = next.fetch_add(kBatch); at < streams.size(); at = next.fetch_add(kBatch))
            for (size_t i = at; i < std::min(streams.size(), at + kBatch); ++i) {
                const TickResult r = streams[i]->tick(frame, now, dt, out, scratch);
                t.datagrams += r.datagrams;
                t.wire_bytes += r.wire_bytes;
            }
    };
    pool_->run(job);
    for (const ThreadTotals& t : totals_) {
        all.datagrams += t.datagrams;
        all.wire_bytes += t.wire_bytes;
    }
    return all;
}

// The tick's serial part before the sessions' ticks: instances announced,
// the frame encoded (when anyone streams), owner groups, address pruning;
// streaming_ gets the sessions to tick, `drop` those whose time is up.
const EncodedFrame* ServerCore::prepare_tick(double now, std::vector<std::shared_ptr<ClientStream>>& drop) {
    bool any = false;
    for (auto& [id, e] : sessions_) {
        if (e.stream->state() == SessionState::Streaming) any = true;
        if (e.stream->welcomed()) e.stream->sync_instances();
    }
    // A node of a world encodes every tick: its characters go on the bus (world_bus.h).
    const EncodedFrame* frame = any || !cfg_.nats_url.empty() ? &encoder_.encode(tick_) : nullptr;
    update_owner_groups(frame);
    if (now - pruned_at_ >= 1.0) {
        prune_addresses(now);
        pruned_at_ = now;
    }
    streaming_.clear();
    for (auto& [id, e] : sessions_) {
        if (e.stream->expired(now)) drop.push_back(e.stream);
        else if (e.stream->state() == SessionState::Streaming && frame) streaming_.push_back(e.stream.get());
    }
    // Whose datagrams go first turns with the tick: clients behind one
    // bottleneck (a household's link) otherwise always met its queue in the
    // same order, the first one's datagrams always found room and the last
    // one's the drops (two clients through a 128 kbit/s relay: 118 and 7
    // kbit/s; docs/performance.md "Behind a capped bottleneck").
    if (!streaming_.empty()) std::rotate(streaming_.begin(), streaming_.begin() + long(tick_ % streaming_.size()), streaming_.end());
    return frame;
}

void ServerCore::tick(double now, DatagramSink& out, const std::function<void(const EncodedFrame&)>& encoded) {
    const double t0 = now_seconds();
    const double dt = last_tick_time_ > 0 ? std::min(0.25, now - last_tick_time_) : 1.0 / cfg_.tick_rate;
    last_tick_time_ = now;
    ++tick_;
    std::vector<std::shared_ptr<ClientStream>> drop;
    const EncodedFrame* frame = prepare_tick(now, drop);
    if (frame && encoded) encoded(*frame);
    TickResult sent;
    if (frame) sent = tick_streams(streaming_, *frame, now, dt, out);
    uint64_t timeouts = 0;
    for (auto& s : drop)
        if (s->expire(now)) ++timeouts;
    const double t1 = now_seconds();
    count([&](ServerStats& st) {
        ++st.ticks;
        st.datagrams_sent += sent.datagrams;
        st.wire_bytes_sent += sent.wire_bytes;
        st.timeouts += timeouts;
        st.tick_seconds += t1 - t0;
        uint64_t active = 0;
        for (auto& [id, e] : sessions_)
            if (e.stream->is_open()) ++active;
        st.sessions_active = active;
    });
}

}  // namespace progskin::net
