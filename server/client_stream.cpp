// client_stream.cpp — see client_stream.h.
#include "client_stream.h"

#include <arpa/inet.h>
#include <net/if.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <sodium.h>

#include "control_messages.h"
#include "errors.h"
#include "server_core.h"

namespace progskin::net {

namespace {

bool equal_u64(uint64_t a, uint64_t b) { return sodium_memcmp(&a, &b, sizeof a) == 0; }

constexpr double LINGER_SECONDS = 1.0;     // Closing: time to write the last message
constexpr double CHALLENGE_SECONDS = 5.0;  // a Challenge's nonce is valid this long

}  // namespace

// ------------------------------------------------------------ PeerAddress --

std::string PeerAddress::ip_string() const {
    char text[INET6_ADDRSTRLEN + IF_NAMESIZE + 2] = {};
    if (!v6) {
        ::inet_ntop(AF_INET, ip.data(), text, sizeof text);
        return text;
    }
    ::inet_ntop(AF_INET6, ip.data(), text, INET6_ADDRSTRLEN);
    std::string s = text;
    if (scope != 0) {  // as asio: the interface name of a link-local address, else the number
        const bool link_local = (ip[0] == 0xfe && (ip[1] & 0xc0) == 0x80) || (ip[0] == 0xff && (ip[1] & 0x0f) == 0x02);
        char name[IF_NAMESIZE + 1] = {};
        s += '%';
        s += link_local && ::if_indextoname(scope, name) ? std::string(name) : std::to_string(scope);
    }
    return s;
}

PeerAddress PeerAddress::v4(uint32_t host_order_ip, uint16_t port) {
    PeerAddress a;
    for (int i = 0; i < 4; ++i) a.ip[size_t(i)] = uint8_t(host_order_ip >> (24 - 8 * i));
    a.port = port;
    return a;
}

// ---------------------------------------------------------------- session --

ClientStream::ClientStream(ServerCore& core, uint64_t id, uint64_t token, double now, PeerAddress remote)
    : core_(core), id_(id), token_(token), opened_(now), last_heard_(now), remote_(remote),
      rate_(core.config().max_kbps, std::min(core.config().initial_kbps, core.config().max_kbps)) {}

ClientStream::~ClientStream() = default;

std::unique_ptr<ClientStream> ClientStream::detached(ServerCore& core, uint64_t id, double kbps) {
    auto s = std::make_unique<ClientStream>(core, id, 0, 0.0);
    s->state_ = SessionState::Streaming;
    s->rate_ = RateController(kbps, kbps);
    s->adaptive_ = false;
    s->sync_instances();
    do {  // every instance announced (the messages dropped)
        s->out_.clear();
        s->queued_ = 0;
        s->announce_pending();
    } while (!s->out_.empty());
    return s;
}

void ClientStream::log(const std::string& s) const { core_.log(s); }

void ClientStream::close(const std::string& why) {
    if (state_ == SessionState::Closed) return;
    state_ = SessionState::Closed;
    despawn_all();
    close_reason_ = why;
    log("session " + hex64(id_) + " (" + name_ + ") closed: " + why);
}

void ClientStream::evict(const std::string& why, double now) {
    flatbuffers::FlatBufferBuilder fbb;
    build_goodbye(fbb, "evicted: " + why);
    log("session " + hex64(id_) + " (" + name_ + ") evicted: " + why);
    finish(fbb, "evicted: " + why, now);
}

void ClientStream::goodbye(const std::string& reason, double now) {
    flatbuffers::FlatBufferBuilder fbb;
    build_goodbye(fbb, reason);
    finish(fbb, reason, now);
}

void ClientStream::despawn_all() {
    for (const auto& o : owned_) core_.remove_instance(o.instance);
    owned_.clear();
}

// Queues one control message. A peer that does not read what it asked for
// is closed once max_queued_bytes are waiting.
void ClientStream::send(const flatbuffers::FlatBufferBuilder& fbb) {
    if (!is_open()) return;
    std::vector<uint8_t> msg;
    frame_control(fbb, msg);
    const size_t limit = core_.config().max_queued_bytes;
    if (queued_ + msg.size() > limit) {  // slow reader
        core_.count([](ServerStats& st) { ++st.backlog_closes; });
        close("control backlog over " + std::to_string(limit) + " bytes");
        return;
    }
    queued_ += msg.size();
    out_.push_back(std::move(msg));
}

// Sends a last message (Refuse or Goodbye) and closes once it is written,
// or after LINGER_SECONDS if the peer does not read it.
void ClientStream::finish(const flatbuffers::FlatBufferBuilder& last, const std::string& why, double now) {
    if (!is_open()) return;
    send(last);
    if (state_ == SessionState::Closed) return;
    state_ = SessionState::Closing;
    despawn_all();  // its characters leave with it
    close_reason_ = why;
    close_deadline_ = now + LINGER_SECONDS;
    if (out_.empty()) close(why);
}

void ClientStream::on_written() {
    if (out_.empty()) return;
    queued_ -= out_.front().size();
    out_.pop_front();
    if (out_.empty() && state_ == SessionState::Closing) close(close_reason_);
    else if (welcomed()) announce_pending();  // the next InstanceAdded batches as the client reads
}

void ClientStream::refuse(const std::string& reason, double now) {
    core_.count([](ServerStats& st) { ++st.refused; });
    flatbuffers::FlatBufferBuilder fbb;
    build_refuse(fbb, reason);
    log("refused: " + reason);
    finish(fbb, "refused: " + reason, now);
}

// A message over a budget or limit: counted by reason, the session closed.
bool ClientStream::refuse_message(const std::string& reason, const std::string& why) {
    core_.refused(reason);
    close(why);
    return false;
}

bool ClientStream::malformed(const std::string& why) {
    core_.count([](ServerStats& st) { ++st.malformed_control; });
    close(why);
    return false;
}

// ------------------------------------------------------------- control in --

bool ClientStream::accept_length(uint32_t n) {
    if (n >= 8 && n <= MAX_CONTROL_MESSAGE) return true;
    return malformed("bad control length " + std::to_string(n));
}

bool ClientStream::on_control(std::span<const uint8_t> body, double now) {
    const wire::Control* c = verify_control(body);
    if (!c) return malformed("malformed control message");
    // Control messages never extend a session's life: only Acks from the
    // bound address do (on_ack), so a TCP-only peer cannot hold a slot.
    const bool hello = c->body_type() == wire::ControlBody::Hello;
    if (c->body_type() != wire::ControlBody::Goodbye && hello != (state_ == SessionState::AwaitHello))
        return malformed("unexpected control message in this state");
    switch (c->body_type()) {
        case wire::ControlBody::Hello: return on_hello(*c->body_as_Hello(), now);
        case wire::ControlBody::AssetRequest: return on_asset_request(*c->body_as_AssetRequest(), now);
        case wire::ControlBody::View: return on_view(*c->body_as_View());
        case wire::ControlBody::Stats: return on_stats();
        case wire::ControlBody::Spawn: on_spawn(*c->body_as_Spawn(), now); return true;
        case wire::ControlBody::Despawn: return on_despawn(*c->body_as_Despawn());
        case wire::ControlBody::Goodbye: close("goodbye"); return false;
        default: return malformed("unexpected control message in this state");
    }
}

// Why a Hello is refused (empty: welcome); a connect token names the client.
std::string ClientStream::check_hello(const wire::Hello& h, double now) {
    if (h.version() != PROTOCOL_VERSION)
        return "protocol version " + std::to_string(h.version()) + " not supported; this server speaks version " +
               std::to_string(PROTOCOL_VERSION);
    if ((h.client_name() && h.client_name()->size() > MAX_NAME) || (h.token() && h.token()->size() > MAX_TOKEN))
        return "client name or token too long";
    std::string who;
    if (std::string why = core_.check_token(h.token(), who); !why.empty()) return why;
    name_ += who;
    const int max_clients = core_.config().max_clients;
    if (core_.welcomed_sessions() >= max_clients && !core_.make_room(*this, now)) {
        core_.refused("server_full");
        return "server full (" + std::to_string(max_clients) + " clients)";
    }
    return {};
}

bool ClientStream::on_hello(const wire::Hello& h, double now) {
    if (std::string why = check_hello(h, now); !why.empty()) {
        refuse(why, now);
        return false;
    }
    const ServerConfig& cfg = core_.config();
    name_ += h.client_name() ? h.client_name()->str() : "";
    const double cap = h.max_kbps() ? std::min(double(h.max_kbps()), cfg.max_kbps) : cfg.max_kbps;
    rate_ = RateController(cap, std::min(cap, cfg.initial_kbps));
    scheduler_.reset(0);
    if (cfg.seal_datagrams && !never_seal_) {
        tx_key_ = crypto::random_key();
        rx_key_ = crypto::random_key();
        sealer_ = std::make_unique<crypto::Sealer>(tx_key_);
        opener_ = std::make_unique<crypto::Opener>(rx_key_);
    }
    if (!send_welcome(cap, now)) return false;
    if (state_ == SessionState::Closed) return false;
    state_ = SessionState::Welcomed;
    welcomed_ = last_heard_ = now;
    log("session " + hex64(id_) + " (" + name_ + ") welcomed, cap " + std::to_string(int(cap)) + " kbit/s");
    return true;
}

bool ClientStream::send_welcome(double cap, double now) {
    flatbuffers::FlatBufferBuilder fbb(16384);
    build_welcome(fbb, core_.assets(), id_, token_, core_.udp_port(), core_.config().tick_rate, cap, sealer_ ? &tx_key_ : nullptr,
                  sealer_ ? &rx_key_ : nullptr);
    if (fbb.GetSize() > MAX_CONTROL_MESSAGE) {  // the catalogue alone (instances travel apart)
        refuse("Welcome would be " + std::to_string(fbb.GetSize()) + " bytes, over the " + std::to_string(MAX_CONTROL_MESSAGE) +
                   "-byte control message limit (too many assets)",
               now);
        return false;
    }
    send(fbb);
    sync_instances();
    return true;
}

bool ClientStream::on_asset_request(const wire::AssetRequest& r, double now) {
    const ServerAsset* a = nullptr;
    for (const auto& x : core_.assets())
        if (x->id == r.asset_id()) a = x.get();
    if (!a || r.offset() >= a->bytes.size() || r.length() == 0 || r.length() > MAX_ASSET_CHUNK)
        return malformed("bad asset request");
    const size_t n = std::min<size_t>(r.length(), a->bytes.size() - r.offset());
    asked_assets_ = now;
    asset_bytes_ += double(n);
    if (asset_bytes_ > core_.config().asset_bytes_factor * core_.total_asset_bytes() + MAX_ASSET_CHUNK)
        return refuse_message("asset_budget_session", "asset download limit");
    // Per address across its sessions and reconnects (ServerConfig::asset_bytes_per_minute).
    if (!core_.charge_assets(remote_, n, now))
        return refuse_message("asset_budget_address", "asset download limit of " + remote_.ip_string() + " per minute");
    flatbuffers::FlatBufferBuilder fbb(n + 128);
    build_asset_chunk(fbb, *a, r.offset(), n);
    core_.count([n](ServerStats& st) { st.asset_bytes_sent += n; });
    send(fbb);
    return true;
}

bool ClientStream::on_view(const wire::View& v) {
    if (std::string why = read_view(v, view_); !why.empty()) return refuse_message("view_too_large", why);
    if (v.max_kbps()) rate_.set_cap(std::min(double(v.max_kbps()), core_.config().max_kbps));
    return true;
}

bool ClientStream::on_stats() {
    flatbuffers::FlatBufferBuilder fbb;
    build_stats(fbb, rate_.target_kbps(), rate_.loss(), rate_.rtt_ms(), seq_);
    send(fbb);
    return true;
}

void ClientStream::spawned(uint32_t request, bool ok, int instance, const std::string& reason) {
    flatbuffers::FlatBufferBuilder fbb;
    build_spawned(fbb, request, ok, instance, reason);
    send(fbb);
    if (!ok) log("session " + hex64(id_) + " spawn refused: " + reason);
}



void ClientStream::on_spawn(const wire::Spawn& m, double now) {
    auto refuse_spawn = [&](const char* reason, const std::string& why) {
        core_.refused(reason);
        spawned(m.request(), false, 0, why);
    };
    if (owned_.size() >= size_t(MAX_SPAWNED))
        return refuse_spawn("characters_per_session", "this session owns " + std::to_string(MAX_SPAWNED) + " characters already");
    if (std::string why = core_.spawn_budget(*this); !why.empty()) return refuse_spawn("characters_per_address", why);
    InstanceSpec sp;
    if (std::string why = read_spawn(m, core_.assets(), id_, sp); !why.empty()) return refuse_spawn("spawn_invalid", why);
    int id;
    try {
        id = core_.add_instance(sp);
    } catch (const Error& e) {
        return refuse_spawn("spawn_invalid", e.what());
    }
    Owned o;
    o.instance = id;
    o.refilled = now;
    owned_.push_back(std::move(o));
    log("session " + hex64(id_) + " spawned " + core_.assets()[size_t(sp.asset)]->name + " as instance " + std::to_string(id));
    spawned(m.request(), true, id, "");
}

bool ClientStream::on_despawn(const wire::Despawn& m) {
    const int id = m.instance();
    auto it = std::find_if(owned_.begin(), owned_.end(), [&](const Owned& o) { return o.instance == id; });
    if (it == owned_.end()) return malformed("despawn of an instance this session does not own");
    core_.remove_instance(id);
    owned_.erase(it);
    log("session " + hex64(id_) + " despawned instance " + std::to_string(id));
    return true;
}

void ClientStream::sync_instances() {
    const uint64_t version = core_.instances_version();
    if (state_ == SessionState::Closed) return;
    if (instances_seen_ != version) {
        instances_seen_ = version;
        std::vector<uint32_t>& generations = core_.generations();
        core_.encoder().generations(generations);
        if (known_.size() < generations.size()) known_.resize(generations.size(), 0);
        std::vector<uint16_t> removed;
        pending_.clear();  // what is still to announce, as of this version
        pending_at_ = 0;
        for (size_t i = 0; i < known_.size(); ++i) {
            const uint32_t g = i < generations.size() ? generations[i] : 0;
            if (known_[i] == g) continue;
            if (known_[i] != 0) removed.push_back(uint16_t(i));
            known_[i] = 0;
            if (g != 0) pending_.emplace_back(int(i), g);
        }
        for (size_t at = 0; at < removed.size(); at += MAX_BATCH_REMOVED) {
            flatbuffers::FlatBufferBuilder fbb;
            build_instances_removed(fbb, std::span(removed).subspan(at, std::min(MAX_BATCH_REMOVED, removed.size() - at)));
            send(fbb);
        }
    }
    announce_pending();
}

void ClientStream::announce_pending() {
    const size_t limit = std::max(core_.config().max_queued_bytes / 2, MAX_CONTROL_MESSAGE + 4);
    std::vector<std::pair<int, InstanceSpec>> batch;  // id and spec, read once
    std::vector<size_t> at;                           // their places in pending_
    while (pending_at_ < pending_.size() && is_open() && queued_ + MAX_CONTROL_MESSAGE + 4 <= limit) {
        batch.clear();
        at.clear();
        for (size_t p = pending_at_; p < pending_.size() && batch.size() < MAX_BATCH_INSTANCES; ++p) {
            InstanceSpec sp;
            if (!core_.encoder().spec_if_active(pending_[p].first, sp) || sp.owner == id_) continue;  // gone, or its own
            batch.emplace_back(pending_[p].first, std::move(sp));
            at.push_back(p);
        }
        if (batch.empty()) {
            pending_at_ = pending_.size();
            break;
        }
        const size_t n = instances_per_message(core_.assets(), batch);  // cut by bytes
        pending_at_ = n < at.size() ? at[n] : pending_.size();
        for (size_t k = 0; k < n; ++k) known_[size_t(batch[k].first)] = pending_[at[k]].second;
        flatbuffers::FlatBufferBuilder fbb(MAX_CONTROL_MESSAGE);
        build_instances_added(fbb, core_.assets(), std::span(batch).first(n));
        send(fbb);
    }
}

// -------------------------------------------------------------- datagrams --

bool ClientStream::accepts(uint64_t token) const { return equal_u64(token_, token) && welcomed(); }

crypto::OpenResult ClientStream::open_sealed(std::span<const uint8_t> wire, std::vector<uint8_t>& plain) {
    uint64_t seq = 0;
    return opener_ ? crypto::open_datagram(*opener_, id_, PROTOCOL_VERSION, wire, plain, seq) : crypto::OpenResult::forged;
}

size_t ClientStream::send_datagram(std::span<const uint8_t> plain, const PeerAddress& to, DatagramSink& out,
                                   std::vector<uint8_t>& sealed) {
    if (!sealer_) {
        out.send(plain, to);
        return plain.size();
    }
    crypto::seal_datagram(*sealer_, id_, PROTOCOL_VERSION, plain, sealed);
    out.send(sealed, to);
    return sealed.size();
}

// Sends `fbb` to the datagram's source only if it is smaller than what came
// from there (never amplifies toward an unproven address; sealing adds the
// same 32 bytes to both).
void ClientStream::answer(const flatbuffers::FlatBufferBuilder& fbb, size_t size, const PeerAddress& from, bool unverified,
                          DatagramSink& out) {
    if (fbb.GetSize() >= size) return;
    const size_t sent = send_datagram({fbb.GetBufferPointer(), fbb.GetSize()}, from, out, core_.scratch().sealed);
    if (unverified) core_.count([&](ServerStats& st) { st.unverified_bytes_out += sent; });
}

void ClientStream::bind_ack(size_t size, const PeerAddress& from, DatagramSink& out) {
    flatbuffers::FlatBufferBuilder fbb(64);
    auto ba = wire::CreateBindAck(fbb, id_);
    fbb.Finish(wire::CreateDatagram(fbb, seq_, now_us32(), wire::DatagramBody::BindAck, ba.Union()), wire::DatagramIdentifier());
    answer(fbb, size, from, false, out);
}

DatagramVerdict ClientStream::on_datagram(const wire::Datagram& d, size_t size, const PeerAddress& from, double now,
                                          DatagramSink& out) {
    switch (d.body_type()) {
        case wire::DatagramBody::Bind: return on_bind(size, from, now, out);
        case wire::DatagramBody::ChallengeResponse:
            return on_challenge_response(*d.body_as_ChallengeResponse(), size, from, now, out);
        case wire::DatagramBody::Ack: return on_ack(*d.body_as_Ack(), from, now, out);
        case wire::DatagramBody::Pose: return on_pose(*d.body_as_Pose(), from, now);
        default: return DatagramVerdict::rejected;  // Frame / BindAck / Challenge are server -> client only
    }
}

DatagramVerdict ClientStream::on_bind(size_t size, const PeerAddress& from, double now, DatagramSink& out) {
    if (bound_ && peer_ == from) {  // already proven
        bind_ack(size, from, out);
        return DatagramVerdict::accepted;
    }
    // A new address: only a Challenge goes there until its nonce comes
    // back from it. The same nonce is repeated for repeated Binds.
    if (challenge_peer_ != from || now - challenge_sent_ > CHALLENGE_SECONDS) {
        randombytes_buf(challenge_nonce_.data(), challenge_nonce_.size());
        challenge_peer_ = from;
        challenge_sent_ = now;
    }
    flatbuffers::FlatBufferBuilder fbb(96);
    auto nv = fbb.CreateVector(challenge_nonce_.data(), challenge_nonce_.size());
    auto ch = wire::CreateChallenge(fbb, id_, nv);
    fbb.Finish(wire::CreateDatagram(fbb, seq_, now_us32(), wire::DatagramBody::Challenge, ch.Union()), wire::DatagramIdentifier());
    core_.count([](ServerStats& st) { ++st.challenges_sent; });
    answer(fbb, size, from, true, out);
    return DatagramVerdict::accepted;
}

DatagramVerdict ClientStream::on_challenge_response(const wire::ChallengeResponse& r, size_t size, const PeerAddress& from,
                                                    double now, DatagramSink& out) {
    if (!r.nonce() || r.nonce()->size() != CHALLENGE_NONCE || challenge_peer_ != from || now - challenge_sent_ > CHALLENGE_SECONDS ||
        sodium_memcmp(r.nonce()->data(), challenge_nonce_.data(), CHALLENGE_NONCE) != 0)
        return DatagramVerdict::rejected;
    const bool moved = bound_ && peer_ != from;
    if (moved) rate_.on_path_change();  // back to the rate before the switch (rate_controller.h)
    peer_ = from;
    bound_ = true;
    last_heard_ = now;
    challenge_sent_ = -1e300;  // one use
    if (state_ == SessionState::Welcomed) state_ = SessionState::Streaming;
    log("session " + hex64(id_) + (moved ? " moved to " : " bound to ") + from.to_string());
    bind_ack(size, from, out);
    return DatagramVerdict::accepted;
}

DatagramVerdict ClientStream::on_ack(const wire::Ack& a, const PeerAddress& from, double now, DatagramSink& out) {
    if (!bound_ || peer_ != from) return DatagramVerdict::rejected;  // counts only from the bound address
    last_heard_ = now;
    rate_.on_ack(a.ack(), a.ack_bits(), a.echo_time_us(), a.hold_us(), now_us32());
    // Bones of lost datagrams are due again (Scheduler::lost), unless a
    // selector of its own chooses what goes.
    lost_.clear();
    // Lost by time: sent 9/8 of the smoothed RTT before now (RFC 9002's
    // time threshold) while a later datagram arrived; at least 1 ms.
    const uint32_t loss_delay = rate_.rtt_ms() > 0 ? uint32_t(std::max(1000.0, 1125.0 * rate_.rtt_ms())) : 0;
    book_.on_ack(a.ack(), a.ack_bits(), selector_ ? nullptr : &lost_, now_us32(), loss_delay);
    if (core_.config().repair_lost && adaptive_) repair_again(a.ack(), loss_delay, out);
    // Below 80 kbit/s a send waits for a fuller datagram (rate_controller.h):
    // the lost bones go with the next tick's instead (RateController::expedite).
    if (!lost_.empty() && adaptive_) rate_.expedite();
    for (size_t k = 0; k < lost_.size(); ++k) {
        const BaselineBook::LostRun& r = lost_[k];
        scheduler_.lost(r.instance, r.generation, r.first, r.count, r.tick, r.morphs);
        if (k == 0 || lost_[k - 1].seq != r.seq) repair(r.seq, out);  // each datagram's runs are adjacent
    }
    return DatagramVerdict::accepted;
}

int ClientStream::repair_copies(double loss) {
    const double p = std::clamp(loss, 0.0, 1.0);
    int n = kRepairCopies;
    double miss = std::pow(p, double(n));
    while (n < kMaxRepairCopies && miss > kRepairMiss * (1 + 1e-9)) {  // (0.1^3 is 1e-3 and a rounding more)
        ++n;
        miss *= p;
    }
    return n;
}

void ClientStream::repair(uint32_t seq, DatagramSink& out) {
    if (!core_.config().repair_lost || last_limited_) return;  // on_ack: bound
    Kept& k = kept_[seq % kKeptSent];
    if (!k.valid || k.seq != seq || !book_.unacked(seq) || k.repairs >= kMaxRepairs ||
        int32_t(newest_tick_sent_ - k.tick) > kRepairTicks)
        return;
    const size_t wire = k.bytes.size() + UDP_IP_OVERHEAD, room = rate_.budget();
    if (room < wire) return;  // no room now: the scheduler sends its bones again (Scheduler::lost)
    // repair_copies copies where the budget holds them (else as many as it
    // does): a repair lost as well is found only an RTT later, after its
    // tick was shown.
    size_t copies = size_t(repair_copies(book_.first_loss()));
    while (copies > 1 && room < copies * wire) --copies;
    ++k.repairs;
    k.sent_us = now_us32();
    for (size_t c = 0; c < copies; ++c) out.send(k.bytes, peer_);
    rate_.spend(copies * wire);
    core_.count([&](ServerStats& st) {
        st.datagrams_repaired += copies;
        st.datagrams_sent += copies;
        st.wire_bytes_sent += copies * wire;
    });
}

void ClientStream::repair_again(uint32_t ack, uint32_t loss_delay_us, DatagramSink& out) {
    // A repair is lost (RFC 9002's time threshold, as for the first send):
    // the Ack leaves its datagram out (the book still has it unacknowledged)
    // while it acknowledges one first sent after the repair (the first send:
    // a repaired datagram's Ack may be of its original), and the repair
    // left at least loss_delay before now.
    uint32_t acked_first = 0;
    if (loss_delay_us == 0 || !book_.sent_time(ack, acked_first)) return;
    const uint32_t now = now_us32();
    for (const Kept& k : kept_) {
        const uint32_t d = ack - k.seq;  // 1..32: within the Ack's window
        if (k.valid && k.repairs > 0 && d >= 1 && d <= 32 && book_.unacked(k.seq) && int32_t(acked_first - k.sent_us) > 0 &&
            now - k.sent_us >= loss_delay_us)
            repair(k.seq, out);
    }
}

DatagramVerdict ClientStream::on_pose(const wire::Pose& p, const PeerAddress& from, double now) {
    if (!bound_ || peer_ != from || state_ != SessionState::Streaming) return DatagramVerdict::rejected;
    auto o = std::find_if(owned_.begin(), owned_.end(), [&](const Owned& x) { return x.instance == p.instance(); });
    if (o == owned_.end()) return DatagramVerdict::rejected;  // not this session's character (or despawned)
    const ServerAsset& a = *core_.assets()[size_t(core_.encoder().spec(o->instance).asset)];
    const int B = a.bone_count(), first = p.first(), count = p.count();
    // The root block (root_block.h): absolute, or (version 7) with a
    // baseline pose, age 1 and not linear: predicted from that pose's root.
    const size_t root_len = p.root() ? root_size(p.root()->data(), p.root()->size()) : 0;
    if (root_len == 0 || root_len != p.root()->size() || !p.records() || count < 1 || first + count > B || p.pose_seq() == 0)
        return DatagramVerdict::malformed;
    const uint8_t root_from = root_base(p.root()->data());
    if (root_from != 0 && (root_from != 1 || p.base_seq() == 0)) return DatagramVerdict::malformed;
    // Morph weights, when present: one per target (every int16 is a weight in [-2, 2)).
    const size_t morphs = std::min<size_t>(a.character.morphs.size(), MAX_MORPHS);
    if (p.morphs() && p.morphs()->size() != morphs) return DatagramVerdict::malformed;
    // Rate limit: a bucket of 2 s at twice the tick rate (poses beyond it
    // are dropped and counted, the newest wins anyway), before any decoding.
    const double rate = 2.0 * core_.config().tick_rate;
    o->tokens = std::min(2.0 * rate, o->tokens + (now - o->refilled) * rate);
    o->refilled = now;
    if (o->tokens < 1.0) {
        core_.count([](ServerStats& st) { ++st.poses_rate_limited; });
        return DatagramVerdict::accepted;
    }
    o->tokens -= 1.0;
    if (o->ints.size() != size_t(B) * kPoseRing) {  // the first Pose of this character
        o->ints.assign(size_t(B) * kPoseRing, RecordInts{});
        o->have.assign(size_t(B) * kPoseRing, 0);
        pose_ints_.reserve(size_t(B));
    }
    // The baseline: a pose held whole (the publisher predicts only from
    // acknowledged ones, so a miss is a broken or hostile publisher).
    const RecordInts* pred = nullptr;
    const uint8_t* base_root = nullptr;
    if (p.base_seq() != 0) {
        const size_t k = p.base_seq() % kPoseRing;
        if (o->seq[k] != p.base_seq() || o->received[k] != B) {
            core_.count([](ServerStats& st) { ++st.poses_missing_baseline; });
            return DatagramVerdict::accepted;
        }
        pred = o->ints.data() + k * size_t(B);
        base_root = o->roots[k].data();
    }
    std::array<uint8_t, ROOT_BYTES> root_abs;
    if (!read_root(p.root()->data(), root_len, root_from ? base_root : nullptr, nullptr, root_abs.data()))
        return DatagramVerdict::malformed;
    // Every record within its bounds (bone_record.h), then only zero padding.
    pose_ints_.resize(size_t(count));
    if (!read_pose_records({p.records()->data(), p.records()->size()}, a.relative.scaled,
                           pred ? std::span<const RecordInts>(pred + first, size_t(count)) : std::span<const RecordInts>(),
                           pose_ints_))
        return DatagramVerdict::malformed;
    // Kept as a baseline unless older than the ring's entry for it.
    const size_t k = p.pose_seq() % kPoseRing;
    if (o->seq[k] != p.pose_seq() && (o->seq[k] == 0 || int32_t(p.pose_seq() - o->seq[k]) > 0)) {
        o->seq[k] = p.pose_seq();
        o->received[k] = 0;
        std::fill(o->have.begin() + long(k * size_t(B)), o->have.begin() + long((k + 1) * size_t(B)), 0);
    }
    if (o->seq[k] == p.pose_seq()) {
        o->roots[k] = root_abs;
        for (int i = 0; i < count; ++i) {
            const size_t at = k * size_t(B) + size_t(first + i);
            o->ints[at] = pose_ints_[size_t(i)];
            if (!o->have[at]) ++o->received[k];
            o->have[at] = 1;
        }
        if (o->received[k] == B && (o->acked == 0 || int32_t(p.pose_seq() - o->acked) > 0)) o->acked = p.pose_seq();
    }
    std::span<const uint8_t, ROOT_BYTES> root(root_abs.data(), ROOT_BYTES);
    std::span<const int16_t> weights;
    if (p.morphs()) weights = {p.morphs()->data(), p.morphs()->size()};
    if (core_.encoder().push_relative(o->instance, p.pose_seq(), p.epoch(), first, pose_ints_, root, weights))
        core_.count([](ServerStats& st) { ++st.poses_received; });
    else
        core_.count([](ServerStats& st) { ++st.poses_stale; });
    return DatagramVerdict::accepted;
}

// ------------------------------------------------------------------- tick --

void ClientStream::update_importance(const EncodedFrame& frame, size_t most) {
    if (near_importance(frame, most)) return;
    near_valid_ = false;
    weighed_ = frame.instances.size();
    // At every instance's current world position; none for instances this
    // client was not told about (yet) or owns.
    compute_importance(view_, frame, core_.assets(), id_, importance_, &known_);
    // Beyond the view radius from every centre: not seen (O(instances x centres)).
    const double r = core_.config().view_radius;
    centres_.clear();
    if (r <= 0 || !view_centres(frame, centres_)) return;
    for (size_t i = 0; i < importance_.size(); ++i) {
        if (importance_[i] <= 0.0f) continue;
        const glm::dvec3& w = frame.instances[i].world;
        bool near = false;
        for (const glm::dvec3& c : centres_)
            near = near || (w.x - c.x) * (w.x - c.x) + (w.z - c.z) * (w.z - c.z) <= r * r;
        if (!near) importance_[i] = 0.0f;
    }
}

// A camera (no explicit weights) over the frame's grid: the instances ring
// by ring around the camera, until more than `most` of those weighed are
// more important than anybody further out can be (an instance beyond the
// ring's radius R is at least R away: at most the importance of one at R).
// bound_candidates then keeps the same `most` (and finds the same cut) as
// over every slot: every instance not weighed ranks below them.
bool ClientStream::near_importance(const EncodedFrame& frame, size_t most) {
    const float t = camera_tan(view_);
    const float height = view_.viewport_height;
    if (!view_.has_camera || !view_.weights.empty() || !frame.grid.built() || !(height > 0.0f) || !std::isfinite(height) ||
        !(t > 0.0f) || !std::isfinite(t))
        return false;
    // The rings weigh about twice `most` (a square of cells around a disc)
    // at two to three times the cost of an instance of the plain pass over
    // every slot (memory in the grid's order, not the slots'): where `most`
    // is a large part of the world, the plain pass is cheaper.
    if (frame.instances.size() < kGridFrom * most) return false;
    const double r = core_.config().view_radius;
    const glm::dvec3 cam(view_.camera);
    // Zero: after a tick of this path only the ones it weighed can be
    // non-zero (not the whole world's slots again).
    if (near_valid_ && importance_.size() <= frame.instances.size()) {
        for (const uint32_t i : near_) importance_[i] = 0.0f;
        importance_.resize(frame.instances.size(), 0.0f);
    } else {
        importance_.assign(frame.instances.size(), 0.0f);
    }
    near_valid_ = false;
    near_.clear();
    below_near_.clear();
    weighed_ = 0;
    size_t above = 0;  // weighed ones above the last ring's bound (a bound only falls: they stay above)
    auto weigh = [&](const SpatialGrid::Entry& e) {
        ++weighed_;
        const uint32_t i = e.id;
        if (id_ != 0 && e.owner == id_) return;
        if (i >= known_.size() || known_[i] != e.generation) return;  // not announced (yet)
        if (r > 0 && (e.world.x - cam.x) * (e.world.x - cam.x) + (e.world.z - cam.z) * (e.world.z - cam.z) > r * r) return;
        const float v = camera_importance(view_, t, e.world, e.diagonal);
        if (!(v > 0.0f)) return;
        importance_[i] = v;
        near_.push_back(i);
        below_near_.push_back(i);
    };
    auto more_rings = [&](double radius) {
        if (r > 0 && radius >= r) return false;  // every instance within the view radius weighed
        if (!(radius > 0)) return true;
        const float bound = height / (2.0f * float(radius) * t);  // camera_importance's at `radius`, rounded alike
        for (size_t k = 0; k < below_near_.size();)
            if (importance_[below_near_[k]] > bound) {
                ++above;
                below_near_[k] = below_near_.back();
                below_near_.pop_back();
            } else {
                ++k;
            }
        return above <= most;
    };
    // A run of entries: this client's announcements of them fetched first
    // (cold: the other clients' ticks ran since), then weighed.
    auto weigh_run = [&](std::span<const SpatialGrid::Entry> run) {
        for (const SpatialGrid::Entry& e : run)
            if (e.id < known_.size()) __builtin_prefetch(&known_[e.id]);
        for (const SpatialGrid::Entry& e : run) weigh(e);
    };
    if (!frame.grid.rings(cam, weigh_run, more_rings)) return false;
    near_valid_ = true;
    return true;
}

bool ClientStream::view_centres(const EncodedFrame& frame, std::vector<glm::dvec3>& out) const {
    if (view_.has_camera) {
        out.push_back(glm::dvec3(view_.camera));
        return true;
    }
    bool any = false;
    for (const EncodedInstance& e : frame.instances)
        if (e.active && e.owner == id_) {
            out.push_back(e.world);
            any = true;
        }
    return any;
}

TickResult ClientStream::tick(const EncodedFrame& frame, double now, double dt, DatagramSink& out) {
    return tick(frame, now, dt, out, core_.scratch());
}

TickResult ClientStream::tick(const EncodedFrame& frame, double now, double dt, DatagramSink& out, TickScratch& scratch) {
    rate_.refill(dt);
    if (adaptive_) rate_.update(now);
    const size_t budget = rate_.budget();
    if (!budget) {
        picks_.clear();
        return {};
    }
    return send_frame(frame, budget, out, scratch);
}

// A chunk of one bone of a placed character: what the least useful pick costs.
static constexpr size_t kSmallestChunk = WireCost::header(1) + 1 + kRootAbsoluteBytes + RecordFormat::kPlainSize;

size_t ClientStream::candidate_limit(size_t budget) const {
    return std::min<size_t>(size_t(std::max(1, core_.config().max_candidates)),
                            std::max<size_t>(kMinCandidates, budget / kSmallestChunk));
}

void ClientStream::bound_candidates(size_t most, uint32_t tick) {
    // Only those at or above a cut are ordered when at least `most` pass it:
    // the `most` most important are then all among them (every other one is
    // below each of them). The cut: most of the importance of the first left
    // out last tick (characters move little in a tick); else every one.
    candidates_.clear();
    below_.clear();
    const float cut = cut_;
    each_weighed([&](size_t i) {
        if (importance_[i] >= cut && importance_[i] > 0.0f) candidates_.push_back(i);
        else if (importance_[i] > 0.0f) below_.push_back(i);
    });
    if (candidates_.size() >= most) {
        for (const size_t i : below_) importance_[i] = 0.0f;
    } else {
        candidates_.insert(candidates_.end(), below_.begin(), below_.end());
    }
    cut_ = 0.0f;
    if (candidates_.size() <= most) return;
    // The `most` most important keep theirs; O(instances). Ties go in turn
    // (an order that rotates with the tick), so that a crowd of equally
    // important characters (no camera) shares the candidates over ticks
    // instead of the lowest ids taking them every tick.
    const size_t n = importance_.size(), turn = size_t(tick) % std::max<size_t>(1, n);
    auto more = [&](size_t a, size_t b) {
        return importance_[a] > importance_[b] || (importance_[a] == importance_[b] && (a + n - turn) % n < (b + n - turn) % n);
    };
    std::nth_element(candidates_.begin(), candidates_.begin() + long(most), candidates_.end(), more);
    cut_ = 0.8f * importance_[candidates_[most]];
    for (size_t c = most; c < candidates_.size(); ++c) importance_[candidates_[c]] = 0.0f;
}

TickResult ClientStream::send_frame(const EncodedFrame& frame, size_t budget, DatagramSink& out) {
    return send_frame(frame, budget, out, core_.scratch());
}

TickResult ClientStream::send_frame(const EncodedFrame& frame, size_t budget, DatagramSink& out, TickScratch& scratch) {
    const size_t most = candidate_limit(budget);
    update_importance(frame, most);
    bound_candidates(most, frame.tick);
    // The instances left with importance, ascending: from the few weighed
    // near the camera, else from every slot.
    weighed_list_.clear();
    each_weighed([&](size_t i) {
        if (importance_[i] > 0.0f) weighed_list_.push_back(uint32_t(i));
    });
    if (near_valid_) std::sort(weighed_list_.begin(), weighed_list_.end());  // (near_ is in the rings' order)
    const bool predict = core_.config().predict_records;
    RecordPlan& plan = scratch.plan;
    plan.begin(frame);
    plan_ = &plan;
    if (predict) {
        // A few instances ahead, their acknowledgements are fetched from
        // memory while the current one is planned (each client's book is cold).
        constexpr size_t kAhead = 4;
        const std::vector<uint32_t>& planned = weighed_list_;
        for (size_t k = 0; k < std::min(kAhead, planned.size()); ++k) book_.prefetch(int(planned[k]));
        for (size_t k = 0; k < planned.size(); ++k) {
            if (k + kAhead < planned.size()) book_.prefetch(int(planned[k + kAhead]));
            plan.plan(frame, int(planned[k]), book_);
        }
    }
    scheduler_.set_plan(predict ? &plan : nullptr);
    if (selector_) {
        selector_(frame, budget, picks_);
    } else {
        const ServerConfig& cfg = core_.config();
        scheduler_.set_shares(core_.owner_groups(), cfg.owner_share_kbps > 0 ? size_t(cfg.owner_share_kbps * 125.0 / cfg.tick_rate) : 0);
        scheduler_.set_floor(cfg.fair_floor);
        scheduler_.set_candidates(weighed_list_);
        scheduler_.select(frame, core_.assets(), importance_, budget, cfg.tick_rate, picks_, scratch.schedule);
        if (scheduler_.limited()) rate_.mark_limited();
    }
    // Pose acks that changed go with the first datagram; with nothing else
    // to send, alone, at most every kAloneAckTicks ticks.
    pose_acks_.clear();
    for (const Owned& o : owned_)
        if (o.acked != o.acked_sent) pose_acks_.emplace_back(uint16_t(o.instance), o.acked);
    if (picks_.empty() && (pose_acks_.empty() || frame.tick - pose_acks_tick_ < kAloneAckTicks)) return {};
    std::vector<std::vector<uint8_t>>& dgrams = scratch.datagrams;
    dgrams.clear();
    const uint32_t first_seq = seq_;
    size_t wire = scratch.packer.pack(frame, picks_, seq_, dgrams, predict ? &plan : nullptr, &book_, pose_acks_);
    if (!dgrams.empty() && !pose_acks_.empty()) {
        for (Owned& o : owned_) o.acked_sent = o.acked;
        if (picks_.empty()) pose_acks_tick_ = frame.tick;
    }
    for (size_t i = 0; i < dgrams.size(); ++i) {
        const size_t sent = send_datagram(dgrams[i], peer_, out, scratch.sealed);
        if (adaptive_) rate_.on_sent(first_seq + uint32_t(i), now_us32(), sent + UDP_IP_OVERHEAD);
        book_.sent_at(first_seq + uint32_t(i), now_us32());
        if (core_.config().repair_lost && adaptive_) {  // kept for a repair (ClientStream::repair)
            Kept& k = kept_[(first_seq + uint32_t(i)) % kKeptSent];
            k.seq = first_seq + uint32_t(i);
            k.tick = frame.tick;
            k.sent_us = now_us32();
            k.valid = true;
            k.repairs = 0;
            const std::span<const uint8_t> bytes = sealer_ ? std::span<const uint8_t>(scratch.sealed) : std::span<const uint8_t>(dgrams[i]);
            k.bytes.assign(bytes.begin(), bytes.end());
        }
        wire += sent - dgrams[i].size();  // the seal's 32 bytes count against the rate
    }
    rate_.spend(wire);
    if (!selector_) scheduler_.sent(picks_, frame.tick);
    newest_tick_sent_ = frame.tick;
    last_limited_ = selector_ || scheduler_.limited();
    return {dgrams.size(), wire};
}

bool ClientStream::expired(double now) const {
    const ServerConfig& cfg = core_.config();
    switch (state_) {
        case SessionState::Closing: return now > close_deadline_;
        case SessionState::AwaitHello: return now - opened_ > cfg.hello_timeout;
        // Unbound: client_timeout after Welcome, whatever arrives over TCP.
        case SessionState::Welcomed: return now - welcomed_ > cfg.client_timeout;
        // Streaming: client_timeout after the newest Ack from the bound address
        // as of the last time every datagram received had been read (so that a
        // busy server does not drop a client whose Acks wait in its queue).
        case SessionState::Streaming: return core_.heard_until(now) - last_heard_ > cfg.client_timeout;
        case SessionState::Closed: return false;
    }
    return false;
}

bool ClientStream::expire(double now) {
    switch (state_) {
        case SessionState::Closed: return false;
        case SessionState::Closing:  // the peer did not read its last message in time
            close(close_reason_ + " (not read)");
            return false;
        case SessionState::AwaitHello: close("timeout"); return true;
        case SessionState::Welcomed:
        case SessionState::Streaming: break;
    }
    flatbuffers::FlatBufferBuilder fbb;  // queued like any message: a peer that does not read cannot stall the tick
    build_goodbye(fbb, state_ == SessionState::Welcomed ? "timeout: UDP address not bound" : "timeout: no acks");
    finish(fbb, "timeout", now);
    return true;
}

}  // namespace progskin::net
