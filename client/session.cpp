// session.cpp — see session.h. The session: Hello -> Welcome (or Refuse) ->
// InstanceAdded/Removed at any time -> AssetRequest/AssetChunk for uncached
// assets -> View -> UDP Bind until BindAck or a Frame -> frames + Acks (+
// Stats each second), Spawn/Spawned/Despawn and Pose datagrams for the
// player's own characters -> Goodbye. When the Welcome carries datagram keys
// (64 bytes: server->client, client->server), every datagram sent is sealed
// and every one received must open (proto/crypto.h); anything else is
// dropped and counted as malformed.
#include "session.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <set>

#include "asset_cache.h"
#include "errors.h"
#include "crypto.h"
#include "frame_reader.h"

namespace progskin::net {

namespace fs = std::filesystem;

std::string read_instance(const wire::Instance& in, size_t catalogue_size, RemoteCharacter& rc) {
    if (in.asset() >= catalogue_size) return "asset " + std::to_string(in.asset()) + " is not in the catalogue";
    rc = RemoteCharacter{};
    rc.instance = in.id();
    if (in.clips()) {
        if (in.clips()->size() > MAX_INSTANCE_CLIPS) return std::to_string(in.clips()->size()) + " clips (at most " + std::to_string(MAX_INSTANCE_CLIPS) + ")";
        for (int c : *in.clips()) {
            if (c < 0) return "negative clip index";
            if (std::find(rc.clip.selection.clips.begin(), rc.clip.selection.clips.end(), c) != rc.clip.selection.clips.end())
                return "clip " + std::to_string(c) + " repeated";
            rc.clip.selection.clips.push_back(c);
        }
    }
    rc.clip.selection.start = in.clip_start();
    rc.clip.selection.end = in.clip_end();
    rc.clip.time_offset = in.time_offset();
    rc.clip.speed = in.speed();
    rc.clip.once = rc.once = in.once();
    auto finite = [](double v) { return std::isfinite(v); };
    if (!finite(in.clip_start()) || !finite(in.clip_end()) || in.clip_end() < in.clip_start() || !finite(in.time_offset()) ||
        !finite(in.speed()))
        return "clip times not finite or reversed";
    if (in.position()) {
        rc.root.position = glm::dvec3(in.position()->x(), in.position()->y(), in.position()->z());
        if (!finite(rc.root.position.x) || !finite(rc.root.position.y) || !finite(rc.root.position.z)) return "position not finite";
    }
    if (in.rotation()) {
        const glm::quat q(in.rotation()->w(), in.rotation()->x(), in.rotation()->y(), in.rotation()->z());
        const float len = glm::length(q);
        if (!std::isfinite(len) || std::fabs(len - 1.0f) > 1e-3f) return "rotation is not a unit quaternion";
        rc.root.rotation = q / len;
    }
    rc.publisher.published = in.published();
    rc.world_id = in.world_id();
    rc.publisher.start_us = in.publisher_start_us();
    if (in.walk_center()) rc.publisher.walk_center = {in.walk_center()->x(), in.walk_center()->y(), in.walk_center()->z()};
    rc.publisher.walk_radius = in.walk_radius();
    rc.publisher.walk_speed = in.walk_speed();
    if (!finite(rc.publisher.walk_center.x) || !finite(rc.publisher.walk_center.y) || !finite(rc.publisher.walk_center.z) ||
        !finite(rc.publisher.walk_radius) || !finite(rc.publisher.walk_speed))
        return "walk not finite";
    return {};
}

FrameApplied apply_frame(const FrameDatagram& f, std::span<const PoseTarget> instances) {
    FrameApplied r;
    auto record_size = [&](uint16_t i) -> int {
        return i < instances.size() && instances[i].buffer ? instances[i].record_size : 0;
    };
    const double tick = double(f.tick);
    uint8_t epoch = 0, sample = 0;
    std::span<const uint8_t> root;
    auto on_chunk = [&](const wire::Chunk& c, uint8_t chunk_sample, std::span<const uint8_t> chunk_root, const uint8_t* morph) {
        epoch = c.epoch();
        sample = chunk_sample;
        root = chunk_root;
        // Morph weights (sparse: the others keep their values), PoseBuffer::add_morphs.
        if (!morph) return;
        if (instances[c.instance()].buffer->add_morphs(f.tick, c.show(), c.show(), c.epoch(), morph, sample)) ++r.applied;
        else ++r.refused;
    };
    auto run = [&](uint16_t i, int first, int count, int show, const RecordRun& rec) {
        PoseBuffer& b = *instances[i].buffer;
        r.record_bits += rec.bits;
        const bool had = !b.empty();
        const uint32_t prev = b.newest_tick();
        const uint64_t missing = b.missing_baselines(), predicted = b.predicted();
        if (!b.add_chunk(f.tick, first, count, show, rec, show, epoch, root, sample)) {
            if (b.missing_baselines() != missing) ++r.missing_baselines;
            else ++r.refused;
            return;
        }
        r.predicted += int(b.predicted() - predicted);
        ++r.applied;
        if (!had) return;
        // The gap since the instance's newest frame and the gap since these
        // bones' previous frames (deep bones are refreshed less often, scheduler.h).
        // A frame older than the newest (late, or a repair) was needed from
        // the frame before it on; another run or datagram of the newest
        // tick, from that tick (and its bones' gaps, below).
        const int32_t newer = int32_t(f.tick - prev);
        double since = newer > 0 ? double(prev) : newer == 0 ? tick : b.needed_from(f.tick, first);
        if (b.last_gap() > 0) since = std::min(since, tick - b.last_gap());
        r.reach_from = std::min(r.reach_from, since);
    };
    // Every chunk is checked before any is applied (proto/frame_reader.h).
    r.read = read_frame(f, record_size, run, on_chunk, &r.unknown_chunks);
    return r;
}

// ------------------------------------------------------------ AckWindow --
bool ClientSession::AckWindow::duplicate(uint32_t seq) const {
    if (!started) return false;
    const int32_t diff = int32_t(seq - ack);
    return diff == 0 || (diff < 0 && diff >= -32 && (bits & (1u << (-diff - 1))));
}

void ClientSession::AckWindow::add(uint32_t seq) {
    if (!started) {
        started = true;
        ack = seq;
        bits = 0;
        min_seq = max_seq = seq;
    } else if (int32_t(seq - ack) > 0) {
        const uint32_t shift = seq - ack;
        uint32_t nb = shift >= 32 ? 0 : (bits << shift);
        if (shift <= 32) nb |= 1u << (shift - 1);
        bits = nb;
        ack = seq;
    } else {
        const uint32_t back = ack - seq - 1;
        if (back < 32) bits |= 1u << back;
    }
    if (int32_t(seq - max_seq) > 0) max_seq = seq;
    if (int32_t(min_seq - seq) > 0) min_seq = seq;
    ++unique;
}

// -------------------------------------------------------------- phases --
ClientSession::ClientSession(ClientConfig cfg, Outbox& out, double (*clock)())
    : cfg_(std::move(cfg)), out_(out), clock_(clock), cap_(cfg_.max_kbps) {}

ClientSession::~ClientSession() = default;

ClientState ClientSession::state() const {
    switch (phase_) {
        case SessionPhase::Idle: return ClientState::Idle;
        case SessionPhase::Streaming: return ClientState::Streaming;
        case SessionPhase::Closed: return ClientState::Closed;
        case SessionPhase::Failed: return ClientState::Failed;
        default: return ClientState::Connecting;
    }
}

void ClientSession::raise(ClientEvent::Type t, int instance, int asset, int handle, std::string text) {
    events_.push_back({t, instance, asset, handle, std::move(text)});
}

void ClientSession::fail(FailReason why, const std::string& text) {
    if (phase_ == SessionPhase::Failed || phase_ == SessionPhase::Closed) return;
    if (phase_ == SessionPhase::Streaming && lost_at_ == 0) lost_at_ = clock_();  // a stream was lost (failover counts from here)
    phase_ = SessionPhase::Failed;
    fail_reason_ = why;
    error_ = text;
    raise(ClientEvent::Type::Failed, -1, -1, -1, text);
}

bool ClientSession::can_fail_over() const {
    if (phase_ != SessionPhase::Failed) return false;
    switch (fail_reason_) {
        case FailReason::Unreachable:
        case FailReason::TlsHandshake:
        case FailReason::Timeout:
        case FailReason::Refused:
        case FailReason::ChannelLost:
        case FailReason::SessionEnded:
        case FailReason::StreamLost: return true;
        default: return false;  // Config, TlsUntrusted, BadServerData, LocalIo: the next server would not help
    }
}

void ClientSession::restart(double now, std::string peer) {
    if (!can_fail_over()) return;
    for (size_t id = 0; id < remotes_.size(); ++id) remove_remote(int(id));
    if (lost_at_ > 0) ++st_.failovers;
    // The Failed event becomes a FailedOver one: the session goes on.
    for (auto it = events_.rbegin(); it != events_.rend(); ++it)
        if (it->type == ClientEvent::Type::Failed) {
            it->type = ClientEvent::Type::FailedOver;
            it->text += "; connecting to " + peer;
            break;
        }
    if (window_.started) {
        loss_span_before_ += uint64_t(window_.max_seq - window_.min_seq) + 1;
        loss_unique_before_ += window_.unique;
    }
    window_ = AckWindow{};
    for (Own& o : own_) {
        o.instance = -1;
        o.request = 0;
        ++o.epoch;  // a discontinuity for its observers
    }
    for (CatalogueEntry& e : catalogue_)
        if (!e.ready && !e.failed) {  // a download starts over
            e.bytes = {};
            e.requested = 0;
            e.in_flight = 0;
        }
    phase_ = SessionPhase::OpeningChannel;
    fail_reason_ = FailReason::None;
    error_.clear();
    started_ = now;
    peer_ = std::move(peer);
    rx_.clear();
    session_ = udp_token_ = 0;
    udp_port_ = 0;
    sealer_.reset();
    opener_.reset();
    welcome_ = nullptr;
    ack_echo_ = 0;
    ack_arrival_ = last_ack_sent_ = next_bind_ = last_datagram_ = 0;
    since_ack_ = 0;
    ack_now_ = false;
    tick_offset_ = -1e300;
    last_display_time_ = needed_delay_ = 0;
    shown_dirty_ = true;
}

void ClientSession::start(double now, std::string peer) {
    started_ = now;
    peer_ = std::move(peer);
    phase_ = SessionPhase::OpeningChannel;
}

void ClientSession::on_transport_connected() {
    if (phase_ == SessionPhase::OpeningChannel) phase_ = SessionPhase::Handshaking;
}

void ClientSession::on_channel_ready() {
    if (phase_ != SessionPhase::OpeningChannel && phase_ != SessionPhase::Handshaking) return;
    phase_ = SessionPhase::AwaitWelcome;
    flatbuffers::FlatBufferBuilder b;
    auto name = b.CreateString(cfg_.name.substr(0, MAX_NAME));
    auto token = b.CreateString(cfg_.token.substr(0, MAX_TOKEN));
    auto h = wire::CreateHello(b, cfg_.protocol_version ? cfg_.protocol_version : PROTOCOL_VERSION, name, token,
                               uint32_t(std::max(0.0, cfg_.max_kbps)));
    b.Finish(wire::CreateControl(b, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    send(b);
}

void ClientSession::on_channel_closed() {
    fail(FailReason::ChannelLost, was_welcomed() || cfg_.tls ? "the server closed the control connection"
                                                              : "the server closed the control connection before its Welcome "
                                                                "(does it expect TLS?)");
}

void ClientSession::close(const std::string& reason) {
    if (!running()) return;
    if (channel_open()) {
        flatbuffers::FlatBufferBuilder b;
        build_goodbye(b, reason);
        frame_control(b, out_.control);
    }
    phase_ = SessionPhase::Closed;
    raise(ClientEvent::Type::Closed, -1, -1, -1, reason);
    shown_.clear();
    shown_ids_.clear();
}

void ClientSession::clear_events() { events_.clear(); }

// -------------------------------------------------------------- output --
void ClientSession::send(const flatbuffers::FlatBufferBuilder& b) {
    if (channel_open()) frame_control(b, out_.control);  // appends
}

void ClientSession::send_datagram(const flatbuffers::FlatBufferBuilder& b) {
    std::span<const uint8_t> bytes{b.GetBufferPointer(), b.GetSize()};
    if (sealer_) {
        crypto::seal_datagram(*sealer_, session_, PROTOCOL_VERSION, bytes, sealed_buf_);
        bytes = sealed_buf_;
    }
    out_.datagram_bytes.insert(out_.datagram_bytes.end(), bytes.begin(), bytes.end());
    out_.datagram_ends.push_back(uint32_t(out_.datagram_bytes.size()));
}

// ------------------------------------------------------------- control --
void ClientSession::on_control_bytes(std::span<const uint8_t> bytes, double now) {
    if (!channel_open()) return;
    rx_.insert(rx_.end(), bytes.begin(), bytes.end());
    size_t at = 0;
    while (channel_open()) {
        uint32_t n = 0;
        if (!read_length({rx_.data() + at, rx_.size() - at}, n)) break;
        if (n < 8 || n > MAX_CONTROL_MESSAGE)
            return fail(FailReason::BadServerData, "server sent a control message of " + std::to_string(n) + " bytes");
        if (rx_.size() - at < 4 + size_t(n)) break;
        rx_body_.assign(rx_.begin() + long(at) + 4, rx_.begin() + long(at) + 4 + n);
        at += 4 + size_t(n);
        handle_control(rx_body_, now);
    }
    rx_.erase(rx_.begin(), rx_.begin() + long(std::min(at, rx_.size())));
}

void ClientSession::handle_control(std::vector<uint8_t>& body, double now) {
    const wire::Control* c = verify_control(body);
    if (!c) return fail(FailReason::BadServerData, "server sent a malformed control message");
    switch (c->body_type()) {
        case wire::ControlBody::Refuse: {
            const wire::Refuse* r = c->body_as_Refuse();
            return fail(FailReason::Refused,
                        "server refused the connection: " + (r->reason() ? r->reason()->str() : std::string("no reason")));
        }
        case wire::ControlBody::Welcome:
            if (was_welcomed()) return fail(FailReason::BadServerData, "server sent a second Welcome");
            welcome_body_ = std::move(body);
            return on_welcome(verify_control(welcome_body_)->body_as_Welcome(), now);
        case wire::ControlBody::AssetChunk: return on_asset_chunk(*c->body_as_AssetChunk(), now);
        case wire::ControlBody::InstanceAdded:
            if (!was_welcomed()) return fail(FailReason::BadServerData, "server sent instances before Welcome");
            if (c->body_as_InstanceAdded()->instances())
                for (const wire::Instance* in : *c->body_as_InstanceAdded()->instances())
                    if (!on_instance_added(*in)) return;
            return;
        case wire::ControlBody::InstanceRemoved:
            if (c->body_as_InstanceRemoved()->ids())
                for (uint16_t id : *c->body_as_InstanceRemoved()->ids()) remove_remote(id);
            return;
        case wire::ControlBody::Spawned: return on_spawned(*c->body_as_Spawned());
        case wire::ControlBody::Stats:
            st_.rtt_ms = c->body_as_Stats()->rtt_ms();
            st_.estimate_kbps = c->body_as_Stats()->estimate_kbps();
            return;
        case wire::ControlBody::Goodbye: {
            const auto* g = c->body_as_Goodbye();
            const std::string why = g->reason() ? g->reason()->str() : std::string();
            // The server ends a session it timed out or refused: the stream is lost.
            return fail(FailReason::SessionEnded, "the server ended the session" + (why.empty() ? std::string() : ": " + why));
        }
        default: return fail(FailReason::BadServerData, "server sent an unexpected control message");
    }
}

void ClientSession::on_welcome(const wire::Welcome* w, double now) {
    if (w->version() != PROTOCOL_VERSION)
        return fail(FailReason::BadServerData, "server speaks protocol version " + std::to_string(w->version()));
    tick_rate_ = w->tick_rate();
    if (!(tick_rate_ > 0 && tick_rate_ <= 1000)) return fail(FailReason::BadServerData, "server sent a bad tick rate");
    if (const auto* keys = w->datagram_keys(); keys && keys->size() > 0) {
        if (!crypto::available()) return fail(FailReason::Config, crypto::UNAVAILABLE);
        if (!cfg_.tls) return fail(FailReason::BadServerData, "server sent datagram keys over an unencrypted channel");
        if (keys->size() != 2 * crypto::KEY_BYTES) return fail(FailReason::BadServerData, "server sent datagram keys of the wrong size");
        crypto::Key down{}, up{};
        std::copy(keys->begin(), keys->begin() + crypto::KEY_BYTES, down.begin());
        std::copy(keys->begin() + crypto::KEY_BYTES, keys->end(), up.begin());
        opener_ = std::make_unique<crypto::Opener>(down);
        sealer_ = std::make_unique<crypto::Sealer>(up);
    }
    phase_ = SessionPhase::Binding;
    welcome_ = w;
    session_ = w->session_id();
    udp_token_ = w->udp_token();
    udp_port_ = w->udp_port();
    base_delay_ = cfg_.delay_ms / 1000.0 * tick_rate_;
    max_delay_ = std::max(base_delay_, cfg_.max_delay_ms / 1000.0 * tick_rate_);
    delay_ticks_ = base_delay_;
    st_.per_second_bytes.reserve(3600);  // an hour of per-second rate bins without reallocating
    next_stats_ = now + 1.0;
    if (!catalogue_.empty()) {  // failover: the same world, the same catalogue
        if (!same_catalogue(*w))
            return fail(FailReason::BadServerData, "server " + peer_ + " serves another catalogue than the server before it");
        raise(ClientEvent::Type::Connected);
        if (view_set_) view_dirty_ = true;
        respawn_own();
        return start_downloads();
    }
    if (w->assets())
        for (const wire::Asset* a : *w->assets()) {
            CatalogueEntry e;
            e.name = a->name() ? a->name()->str() : "asset.glb";
            e.id = a->asset_id();
            e.size = a->size();
            catalogue_.push_back(std::move(e));
            asset_names_.push_back(catalogue_.back().name);
        }
    assets_.assign(catalogue_.size(), nullptr);
    raise(ClientEvent::Type::Connected);
    if (view_set_) view_dirty_ = true;
    start_downloads();
}

bool ClientSession::same_catalogue(const wire::Welcome& w) const {
    const size_t n = w.assets() ? w.assets()->size() : 0;
    if (n != catalogue_.size()) return false;
    for (size_t i = 0; i < n; ++i)
        if (w.assets()->Get(flatbuffers::uoffset_t(i))->asset_id() != catalogue_[i].id) return false;
    return true;
}

// After a failover's Welcome: the player's characters, spawned again.
void ClientSession::respawn_own() {
    for (Own& o : own_)
        if (!o.gone && !o.refused) {
            o.request = next_request_++;
            send_spawn(o);
        }
}

// -------------------------------------------------------------- assets --
// Finds cached assets, then downloads the others one after another.
void ClientSession::start_downloads() {
    cache_ = cfg_.cache_dir.empty() ? default_cache_dir() : cfg_.cache_dir;
    std::error_code ec;
    fs::create_directories(cache_, ec);
    for (size_t i = 0; i < catalogue_.size(); ++i) {
        CatalogueEntry& e = catalogue_[i];
        if (e.ready || e.failed) continue;  // loaded before a failover
        std::string path;
        for (const bool glb : {true, false})
            if (const std::string p = cached_asset_path(cache_, e.id, glb); path.empty() && fs::exists(p) &&
                                                                             content_hash(read_file(p)) == e.id)
                path = p;
        if (!path.empty()) {
            ++st_.assets_cached;
            asset_loaded(i, path);
            if (phase_ == SessionPhase::Failed) return;
        } else if (e.size == 0 || e.size > MAX_ASSET_BYTES) {
            return fail(FailReason::BadServerData, "server announced asset " + e.name + " of " + std::to_string(e.size) +
                                                       " bytes (the limit is " + std::to_string(MAX_ASSET_BYTES) + ")");
        }
    }
    downloading_ = 0;
    last_progress_ = clock_();
    request_chunks();
}

void ClientSession::request_chunks() {
    while (downloading_ < catalogue_.size() && (catalogue_[downloading_].ready || catalogue_[downloading_].failed)) ++downloading_;
    if (downloading_ >= catalogue_.size()) return;
    CatalogueEntry& e = catalogue_[downloading_];
    while (e.in_flight < 4 && e.requested < e.size) {
        flatbuffers::FlatBufferBuilder b;
        const uint32_t len = uint32_t(std::min<uint64_t>(MAX_ASSET_CHUNK, e.size - e.requested));
        auto r = wire::CreateAssetRequest(b, e.id, e.requested, len);
        b.Finish(wire::CreateControl(b, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
        send(b);
        e.requested += len;
        ++e.in_flight;
    }
}

void ClientSession::on_asset_chunk(const wire::AssetChunk& ch, double now) {
    if (downloading_ >= catalogue_.size()) return fail(FailReason::BadServerData, "server sent an asset chunk nobody asked for");
    CatalogueEntry& e = catalogue_[downloading_];
    // Chunks come in request order: each must continue the bytes so far,
    // so memory grows with what arrives, never with the declared size.
    if (ch.asset_id() != e.id || !ch.data() || ch.offset() != e.bytes.size() || ch.data()->size() == 0 ||
        ch.offset() + ch.data()->size() > e.size)
        return fail(FailReason::BadServerData, "server sent a bad asset chunk for " + e.name);
    e.bytes.insert(e.bytes.end(), ch.data()->begin(), ch.data()->end());
    st_.asset_bytes_downloaded += ch.data()->size();
    --e.in_flight;
    last_progress_ = now;
    if (cfg_.on_download) cfg_.on_download(e.name, e.bytes.size(), e.size);
    if (e.bytes.size() < e.size) return request_chunks();
    if (content_hash(e.bytes) != e.id) return fail(FailReason::BadServerData, "downloaded " + e.name + " does not match its content hash");
    const std::string path = cached_asset_path(cache_, e.id, is_glb(e.bytes));
    if (const std::string why = write_cached_asset(path, e.bytes, this); !why.empty()) return fail(FailReason::LocalIo, why);
    asset_loaded(downloading_, path);
    request_chunks();
}

void ClientSession::asset_loaded(size_t i, const std::string& path) {
    try {
        const wire::Asset* a = welcome_->assets()->Get(flatbuffers::uoffset_t(i));
        assets_[i] = hooks_.load_asset ? hooks_.load_asset(a, path) : load_client_asset(a, path);
        if (!assets_[i]) throw Error("not loaded");
    } catch (const std::exception& e) {
        // One asset this client cannot load costs its characters only: the others stream on.
        catalogue_[i].failed = true;
        catalogue_[i].bytes = {};
        if (all_assets_ready()) st_.download_seconds = clock_() - started_;
        raise(ClientEvent::Type::AssetFailed, -1, int(i), -1, std::string("asset ") + catalogue_[i].name + ": " + e.what());
        return;
    }
    catalogue_[i].ready = true;
    catalogue_[i].bytes = {};
    if (all_assets_ready()) st_.download_seconds = clock_() - started_;
    raise(ClientEvent::Type::AssetReady, -1, int(i));
    for (size_t id = 0; id < remotes_.size(); ++id)
        if (remotes_[id].active && remotes_[id].asset == int(i)) make_view(id);
}

bool ClientSession::all_assets_ready() const {
    for (const auto& e : catalogue_)
        if (!e.ready && !e.failed) return false;
    return was_welcomed();
}

// ----------------------------------------------------------- instances --
bool ClientSession::on_instance_added(const wire::Instance& in) {
    RemoteCharacter rc;
    const std::string why = read_instance(in, catalogue_.size(), rc);
    if (!why.empty()) {
        fail(FailReason::BadServerData, "server sent a bad instance: " + why);
        return false;
    }
    if (remotes_.size() <= in.id()) {
        remotes_.resize(size_t(in.id()) + 1);
        targets_.resize(remotes_.size());
    }
    Remote& r = remotes_[in.id()];
    if (r.active) remove_remote(in.id());  // announced again: a new character in that slot
    r = Remote{};
    r.active = true;
    r.asset = in.asset();
    r.rc = std::move(rc);
    if (catalogue_[size_t(r.asset)].ready) make_view(in.id());
    return true;
}

void ClientSession::make_view(size_t id) {
    Remote& r = remotes_[id];
    if (r.view || r.announced) return;
    const auto& a = assets_[size_t(r.asset)];
    for (int c : r.rc.clip.selection.clips)
        if (size_t(c) >= a->character.clips.size()) return fail(FailReason::BadServerData, "server sent an unknown clip index");
    if (hooks_.frame_sink) {  // no pose history, no palette: the sink takes the frames
        r.rc.asset = a.get();
        r.announced = true;
        raise(ClientEvent::Type::CharacterAdded, r.rc.instance, r.asset);
        hooks_.frame_sink->on_character(int(id), &r.rc);
        return;
    }
    r.view = std::make_unique<InstanceView>(a, r.rc.clip, cfg_.blend_frames, tick_rate_);
    targets_[id] = {&r.view->buffer(), a->format.size()};
    r.rc.asset = a.get();
    r.announced = true;
    shown_dirty_ = true;
    raise(ClientEvent::Type::CharacterAdded, r.rc.instance, r.asset);
}

void ClientSession::remove_remote(int id) {
    if (id < 0 || size_t(id) >= remotes_.size() || !remotes_[size_t(id)].active) return;
    Remote& r = remotes_[size_t(id)];
    if (r.announced) raise(ClientEvent::Type::CharacterRemoved, id, r.asset);
    if (r.announced && hooks_.frame_sink) hooks_.frame_sink->on_character(id, nullptr);
    r = Remote{};
    targets_[size_t(id)] = {};
    shown_dirty_ = true;
}

bool ClientSession::has_characters() const {
    for (const auto& r : remotes_)
        if (r.active) return true;
    return false;
}

const RemoteCharacter* ClientSession::character(int instance) const {
    for (const auto& c : shown_)
        if (c.instance == instance) return &c;
    return nullptr;
}

// ------------------------------------------------------------ datagrams --
void ClientSession::on_datagram(std::span<const uint8_t> bytes, bool from_server, double t) {
    if (!welcomed()) return;
    std::span<const uint8_t> plain = bytes;
    if (opener_) {  // sealed session: unsealed, forged and replayed datagrams are dropped
        uint64_t seq = 0;
        const crypto::OpenResult r =
            from_server ? crypto::open_datagram(*opener_, session_, PROTOCOL_VERSION, bytes, opened_buf_, seq, crypto::Stale::authenticate)
                        : crypto::OpenResult::forged;
        // The server's sealing, of a sequence already opened (or older than
        // the window): the network duplicated it (or someone replayed it),
        // as an unsealed duplicate; anything else that fails is malformed.
        if (r == crypto::OpenResult::replayed) {
            ++st_.duplicates;
            return;
        }
        if (r != crypto::OpenResult::ok) {
            ++st_.malformed;
            return;
        }
        plain = opened_buf_;
    }
    if (is_frame_datagram(plain)) {  // the frame stream (version 13: not a FlatBuffer)
        FrameDatagram f;
        if (!from_server || !read_frame_datagram(plain, f)) {
            ++st_.malformed;
            return;
        }
        last_datagram_ = t;
        return handle_frame(f, bytes.size(), t);
    }
    const wire::Datagram* d = verify_datagram(plain);
    if (!d || !from_server) {
        ++st_.malformed;
        return;
    }
    last_datagram_ = t;
    switch (d->body_type()) {
        case wire::DatagramBody::BindAck: phase_ = SessionPhase::Streaming; return;
        case wire::DatagramBody::Challenge: {  // return routability: echo the nonce
            const wire::Challenge* ch = d->body_as_Challenge();
            if (ch->session_id() == session_ && ch->nonce() && ch->nonce()->size() == CHALLENGE_NONCE) {
                fbb_.Clear();
                build_challenge_response(fbb_, session_, udp_token_, {ch->nonce()->data(), ch->nonce()->size()});
                send_datagram(fbb_);
            } else {
                ++st_.malformed;
            }
            return;
        }
        default: ++st_.malformed; return;
    }
}

// n: bytes received (sealed: crypto::SEAL_OVERHEAD more than the datagram); t: arrival.
void ClientSession::handle_frame(const FrameDatagram& f, size_t n, double t) {
    const uint32_t seq = f.seq;
    if (window_.duplicate(seq)) {
        ++st_.duplicates;
        return;
    }
    const FrameApplied a = hooks_.frame_sink ? sink_frame(f, t) : apply_frame(f, targets_);
    if (!a.read) {
        ++st_.malformed;
        return;
    }
    apply_pose_acks(f);
    st_.malformed += uint64_t(a.refused);
    st_.unknown_chunks += uint64_t(a.unknown_chunks);
    st_.predicted_records += uint64_t(a.predicted);
    st_.missing_baselines += uint64_t(a.missing_baselines);
    // Cover the gaps these runs filled (the display delay, display()).
    if (tick_offset_ > -1e299 && a.reach_from < double(f.tick))
        needed_delay_ = std::max(needed_delay_, t * tick_rate_ + tick_offset_ - a.reach_from);
    if (!window_.started && st_.datagrams == 0) t_first_ = t;  // the first frame ever (failovers keep it)
    if (lost_at_ > 0) {  // the first frame after a failover
        st_.failover_seconds = std::max(st_.failover_seconds, t - lost_at_);
        lost_at_ = 0;
    }
    // A datagram with a record whose baseline this client does not hold is
    // not acknowledged: the server then never predicts from what it carried
    // (baseline_book.h), so the stream heals instead of refusing on.
    if (a.missing_baselines > 0) return;
    // A gap (a datagram skipped, or one that fills a gap) is acknowledged at
    // the next update rather than up to 33 ms later (QUIC's immediate
    // acknowledgement of out-of-order packets, RFC 9000 13.2.1): the server
    // learns of a loss, and repairs it, a tick sooner.
    if (window_.started && seq != window_.ack + 1) ack_now_ = true;
    window_.add(seq);
    if (seq == window_.ack) {
        ack_echo_ = f.send_time_us;
        ack_arrival_ = t;
    }
    phase_ = SessionPhase::Streaming;
    ++since_ack_;
    if (st_.datagrams > 0) st_.max_gap_ms = std::max(st_.max_gap_ms, 1000.0 * (t - last_frame_at_));
    last_frame_at_ = t;
    ++st_.datagrams;
    st_.wire_bytes += n + UDP_IP_OVERHEAD;
    const size_t bin = size_t(t - t_first_);
    if (st_.per_second_bytes.size() <= bin) st_.per_second_bytes.resize(bin + 1, 0.0);
    st_.per_second_bytes[bin] += double(n + UDP_IP_OVERHEAD);
    tick_offset_ = std::max(tick_offset_, double(f.tick) - t * tick_rate_);
}

// A frame read for the FrameSink (session.h): the checks of apply_frame
// (read_frame; a chunk whose show exceeds its asset's bones is refused, as
// PoseBuffer::add_chunk refuses it), no pose buffer.
FrameApplied ClientSession::sink_frame(const FrameDatagram& f, double arrival) {
    FrameApplied r;
    auto asset_of = [&](uint16_t i) -> const ClientAsset* {
        return i < remotes_.size() && remotes_[i].announced ? remotes_[i].rc.asset : nullptr;
    };
    FrameSink& sink = *hooks_.frame_sink;
    auto record_size = [&](uint16_t i) -> int {  // (read_frame asks once per chunk, in its check pass)
        const ClientAsset* a = asset_of(i);
        if (a) sink.prefetch(i, f.tick);
        return a ? a->format.size() : 0;
    };
    bool refused = false;  // the current chunk's
    auto on_chunk = [&](const wire::Chunk& c, uint8_t, std::span<const uint8_t> root, const uint8_t*) {
        refused = c.show() > asset_of(c.instance())->skin.bone_count();
        if (!refused) sink.on_chunk(c.instance(), f.tick, c.show(), root, arrival);
    };
    auto run = [&](uint16_t i, int first, int count, int, const RecordRun& rec) {
        if (refused) {
            ++r.refused;
            return;
        }
        r.record_bits += rec.bits;
        ++r.applied;
        sink.on_run(i, first, count, rec);
    };
    r.read = read_frame(f, record_size, run, on_chunk, &r.unknown_chunks);
    return r;
}

// -------------------------------------------------------------- update --
void ClientSession::update(double now, DatagramSource* source) {
    if (!running()) {
        shown_.clear();
        shown_ids_.clear();
        return;
    }
    if (!welcomed()) {
        if (now - started_ > cfg_.connect_timeout) {
            if (phase_ == SessionPhase::AwaitWelcome) fail(FailReason::Timeout, "no answer from the server");
            else fail(FailReason::Timeout, (phase_ == SessionPhase::Handshaking ? "TLS handshake with " : "cannot connect to ") +
                                               peer_ + ": timed out");
        }
        return;
    }
    if (view_dirty_) send_view();
    // Bind until bound; bind again after 1 s without a datagram (the
    // address may have changed: NAT rebinding), every 0.2 s. UDP right after
    // Welcome: the server drops a session that is not bound 10 s after its
    // Welcome, and a download may take longer (frames of characters whose
    // asset is not ready are skipped).
    const bool bound = phase_ == SessionPhase::Streaming;
    if ((!bound || (has_characters() && now - last_datagram_ > 1.0)) && now >= next_bind_) {
        fbb_.Clear();
        build_bind(fbb_, session_, udp_token_);  // padded: always larger than its BindAck or Challenge
        send_datagram(fbb_);
        next_bind_ = now + 0.2;
    }
    std::span<const uint8_t> bytes;
    bool from_server = false;
    double arrival = 0;
    while (source && source->next(bytes, from_server, arrival)) on_datagram(bytes, from_server, arrival);
    if (!stream_checks(now)) return;
    if (window_.started && since_ack_ > 0 && (since_ack_ >= 8 || ack_now_ || now - last_ack_sent_ > 0.033)) send_ack(now);
    if (now >= next_stats_) send_stats(now);
    display(now);
}

// The downloads' progress, the bind and the stream: false (Failed) when one
// stopped for too long.
bool ClientSession::stream_checks(double now) {
    if (!all_assets_ready()) {
        if (now - last_progress_ > cfg_.connect_timeout) {
            const CatalogueEntry& e = catalogue_[downloading_];
            fail(FailReason::Timeout, "timed out downloading " + e.name + " (" + std::to_string(e.bytes.size()) + " of " +
                                          std::to_string(e.size) + " bytes)");
            return false;
        }
    } else if (phase_ != SessionPhase::Streaming && now - started_ > cfg_.connect_timeout) {
        fail(FailReason::Timeout, "no answer from the server's UDP port");
        return false;
    }
    if (window_.started && now - last_datagram_ > cfg_.stream_timeout && has_characters()) {
        fail(FailReason::StreamLost, "lost the stream: no datagram for " + std::to_string(int(now - last_datagram_)) + " s");
        return false;
    }
    return true;
}

void ClientSession::send_ack(double now) {
    fbb_.Clear();
    const uint32_t hold = uint32_t(std::max(0.0, (now - ack_arrival_) * 1e6));
    auto a = wire::CreateAck(fbb_, session_, udp_token_, window_.ack, window_.bits, ack_echo_, hold);
    fbb_.Finish(wire::CreateDatagram(fbb_, 0, now_us32(), wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
    send_datagram(fbb_);
    since_ack_ = 0;
    ack_now_ = false;
    last_ack_sent_ = now;
}

void ClientSession::send_stats(double now) {
    flatbuffers::FlatBufferBuilder& b = ctl_fbb_;
    b.Clear();
    wire::StatsBuilder sb(b);
    const auto& bins = st_.per_second_bytes;
    sb.add_rate_kbps(float(bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : 0));
    auto s = sb.Finish();
    b.Finish(wire::CreateControl(b, wire::ControlBody::Stats, s.Union()), wire::ControlIdentifier());
    send(b);
    next_stats_ = now + 1.0;
}

ClientStats ClientSession::stats(double now) const {
    ClientStats s = st_;
    s.seconds = window_.started ? now - t_first_ : 0;
    const uint64_t span = (window_.started ? uint64_t(window_.max_seq - window_.min_seq) + 1 : 0) + loss_span_before_;
    const uint64_t unique = window_.unique + loss_unique_before_;
    s.loss = span ? std::max(0.0, 1.0 - double(unique) / double(span)) : 0;
    return s;
}

// The display clock: at least delay_ms behind the newest frame, raised
// to cover the gaps between an instance's frames (plus their lateness) so
// the display interpolates rather than holds (a late frame, or a repair,
// counts from the frame before it: the display needed it from there); it
// changes by at most 25% of the elapsed time (the clock runs at
// 0.75x..1.25x while it adapts), up to max_delay_ms.
double ClientSession::display_tick(double now) const {
    if (!window_.started) return std::numeric_limits<double>::quiet_NaN();
    return now * tick_rate_ + tick_offset_ - delay_ticks_;
}

void ClientSession::display(double now) {
    if (shown_dirty_ && !hooks_.frame_sink) {
        shown_.clear();
        shown_ids_.clear();
        for (const auto& r : remotes_)
            if (r.active && r.view) {
                shown_.push_back(r.rc);
                shown_ids_.push_back(r.rc.instance);
            }
        shown_dirty_ = false;
    }
    if (!window_.started) return;
    const double elapsed = last_display_time_ > 0 ? (now - last_display_time_) * tick_rate_ : 0;
    last_display_time_ = now;
    const double target = std::clamp(needed_delay_ + 0.5, base_delay_, max_delay_);
    const double step = 0.25 * elapsed;
    delay_ticks_ += std::clamp(target - delay_ticks_, -step, step);
    needed_delay_ *= std::pow(kDelayMemory, elapsed / tick_rate_);  // forget over about ten seconds
    st_.delay_ms = std::max(st_.delay_ms, delay_ticks_ / tick_rate_ * 1000.0);
    double d = now * tick_rate_ + tick_offset_ - delay_ticks_;
    if (cfg_.snap_to_ticks) d = std::floor(d);
    if (hooks_.frame_sink) return;  // the clock only: no palettes
    for (size_t k = 0; k < shown_.size(); ++k) {
        InstanceView& v = *remotes_[size_t(shown_ids_[k])].view;
        RemoteCharacter& rc = shown_[k];
        // Snapped: each frame as it came, at its sample's time (key samples
        // come a little before their tick; the root is the tick's).
        const double di = cfg_.snap_to_ticks && d >= 0 && !v.buffer().empty() ? v.buffer().sample_of(uint32_t(int64_t(d))) : d;
        rc.shown = v.buffer().covers(d) && v.display(di);
        rc.display_tick = d;
        rc.pose_tick = di;
        if (rc.shown) {
            rc.palette = v.palette();
            rc.morph_weights = v.morph_weights();
            rc.bones = v.target_bones();
            rc.fresh_bones = v.buffer().bones_recorded(d, rc.bones);
            RootPose root;
            if (v.buffer().root(d, root)) rc.root = root;
        } else {
            rc.palette = {};
            rc.morph_weights = {};
            rc.bones = 0;
            rc.fresh_bones = 0;
        }
    }
}

// ---------------------------------------------------------- view, cap --
void ClientSession::set_view(const ViewSpec& view) {
    if (view.weights.size() > MAX_VIEW_WEIGHTS)  // the server would end the session
        throw Error("a View carries at most " + std::to_string(MAX_VIEW_WEIGHTS) + " weights (" + std::to_string(view.weights.size()) +
                    " given)");
    view_ = view;
    view_set_ = true;
    view_dirty_ = was_welcomed();
}

void ClientSession::set_max_kbps(double kbps) {
    cap_ = std::max(0.0, kbps);
    view_set_ = true;
    view_dirty_ = was_welcomed();
}

void ClientSession::send_view() {
    flatbuffers::FlatBufferBuilder b;
    std::vector<wire::InstanceWeight> ws;
    for (const auto& [i, wt] : view_.weights) ws.emplace_back(uint16_t(i), wt);
    auto vw = b.CreateVectorOfStructs(ws);
    wire::Vec3 cam(view_.camera.x, view_.camera.y, view_.camera.z);
    wire::ViewBuilder vb(b);
    if (view_.has_camera) vb.add_camera(&cam);
    vb.add_fov_y(view_.fov_y);
    vb.add_viewport_height(view_.viewport_height);
    vb.add_weights(vw);
    vb.add_max_kbps(uint32_t(std::max(0.0, cap_)));
    auto v = vb.Finish();
    b.Finish(wire::CreateControl(b, wire::ControlBody::View, v.Union()), wire::ControlIdentifier());
    send(b);
    view_dirty_ = false;
}

// ------------------------------------------------------ own characters --
ClientSession::Own* ClientSession::find_own(int handle) {
    for (auto& o : own_)
        if (o.handle == handle && !o.gone) return &o;
    return nullptr;
}

int ClientSession::instance_of(int handle) const {
    for (const auto& o : own_)
        if (o.handle == handle && !o.gone && !o.refused) return o.instance;
    return -1;
}

int ClientSession::spawn(const SpawnSpec& spec) {
    Own o;
    o.handle = int(own_.size()) + 1;
    o.asset = spec.asset;
    o.request = next_request_++;
    o.spec = spec;
    own_.push_back(o);
    std::string why;  // what the server would refuse, refused here
    if (!was_welcomed()) why = "not connected yet";
    else if (spec.asset < 0 || size_t(spec.asset) >= catalogue_.size()) why = "no asset " + std::to_string(spec.asset) + " in the catalogue";
    else if (catalogue_[size_t(spec.asset)].failed) why = "asset " + catalogue_[size_t(spec.asset)].name + " could not be loaded";
    else if (spec.clips.size() > MAX_INSTANCE_CLIPS) why = "at most " + std::to_string(MAX_INSTANCE_CLIPS) + " clips";
    else if (std::set<int>(spec.clips.begin(), spec.clips.end()).size() != spec.clips.size()) why = "a clip repeated";
    if (!why.empty()) {
        own_.back().refused = true;
        raise(ClientEvent::Type::SpawnRefused, -1, spec.asset, o.handle, why);
        return o.handle;
    }
    send_spawn(own_.back());
    return o.handle;
}

void ClientSession::send_spawn(const Own& o) {
    const SpawnSpec& spec = o.spec;
    flatbuffers::FlatBufferBuilder b;
    std::vector<int32_t> clips(spec.clips.begin(), spec.clips.end());
    auto vc = b.CreateVector(clips);
    wire::DVec3 wc(spec.walk_center.x, spec.walk_center.y, spec.walk_center.z);
    wire::Vec3 pos(spec.position.x, spec.position.y, spec.position.z);
    auto s = wire::CreateSpawn(b, o.request, uint16_t(spec.asset), vc, spec.once, spec.speed, spec.start_us, &wc, spec.walk_radius,
                               spec.walk_speed, &pos);
    b.Finish(wire::CreateControl(b, wire::ControlBody::Spawn, s.Union()), wire::ControlIdentifier());
    send(b);
}

void ClientSession::on_spawned(const wire::Spawned& m) {
    auto it = std::find_if(own_.begin(), own_.end(), [&](const Own& o) { return o.request == m.request(); });
    if (it == own_.end()) return fail(FailReason::BadServerData, "server answered a spawn request that was never made");
    if (m.ok() && it->gone) {  // despawned before the answer came
        flatbuffers::FlatBufferBuilder b;
        auto d = wire::CreateDespawn(b, m.instance());
        b.Finish(wire::CreateControl(b, wire::ControlBody::Despawn, d.Union()), wire::ControlIdentifier());
        send(b);
        return;
    }
    if (m.ok()) {
        it->instance = m.instance();
        it->acked = 0;  // this server holds none of its poses yet
        raise(ClientEvent::Type::Spawned, it->instance, it->asset, it->handle);
    } else {
        it->refused = true;
        raise(ClientEvent::Type::SpawnRefused, -1, it->asset, it->handle, m.reason() ? m.reason()->str() : "");
    }
}

void ClientSession::despawn(int handle) {
    Own* o = find_own(handle);
    if (!o) return;
    o->gone = true;
    if (o->instance < 0) return;
    flatbuffers::FlatBufferBuilder b;
    auto d = wire::CreateDespawn(b, uint16_t(o->instance));
    b.Finish(wire::CreateControl(b, wire::ControlBody::Despawn, d.Union()), wire::ControlIdentifier());
    send(b);
}

bool ClientSession::publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport,
                            std::span<const float> morph_weights) {
    Own* o = find_own(handle);
    if (!o || o->instance < 0 || phase_ != SessionPhase::Streaming) return false;
    const auto& a = assets_[size_t(o->asset)];
    if (!a || skinning.size() != a->character.joint_count()) return false;
    std::array<uint8_t, ROOT_BYTES> rb;
    const RecordFormat& fmt = a->format;
    const int B = a->skin.bone_count();
    if (o->fmt.bone_count() != B) {  // the first pose of this character
        o->fmt = relative_format(a->skin, a->character, fmt);
        o->ring.assign(size_t(B) * POSE_BASELINES, RecordInts{});
        o->ring_seq.fill(0);
        // The scratch at its worst case once (publish() allocates nothing after).
        pose_bits_.reserve(std::max(pose_bits_.capacity(), size_t(B) * size_t(kMaxRecordBits) / 8 + 16));
        pose_chunk_.reserve(MAX_DATAGRAM);
        pose_root_.reserve(kRootMaxBytes);
    }
    pose_model_.resize(size_t(B));
    pose_decoded_.resize(size_t(B));
    pose_offsets_.resize(size_t(B) + 1);
    bool ok = encode_root(root, rb.data());
    // A pose outside the asset's box is refused (the world bus carries the
    // absolute records of bone_codec.h), never clamped.
    for (int b = 0; ok && b < B; ++b) {
        pose_model_[size_t(b)] = decompose(skinning[size_t(a->skin.order[size_t(b)])]);
        ok = bone_in_range(pose_model_[size_t(b)], fmt);
    }
    if (!morph_weights.empty()) {
        if (morph_weights.size() != std::min<size_t>(a->character.morphs.size(), MAX_MORPHS)) return false;
        pose_morphs_.resize(morph_weights.size());
        for (size_t m = 0; ok && m < morph_weights.size(); ++m) ok = encode_morph_weight(morph_weights[m], pose_morphs_[m]);
    }
    const uint32_t seq = o->pose_seq + 1;
    std::span<RecordInts> ints(o->ring.data() + size_t(seq % POSE_BASELINES) * size_t(B), size_t(B));
    // Closed loop against the decoded parents, the integers into the ring.
    pose_bits_.clear();
    ok = ok && encode_pose(pose_model_, o->fmt, pose_bits_, pose_offsets_, pose_decoded_, ints);
    if (!ok) {
        o->ring_seq[seq % POSE_BASELINES] = 0;
        ++st_.poses_refused;
        return false;
    }
    o->ring_seq[seq % POSE_BASELINES] = seq;
    o->ring_root[seq % POSE_BASELINES] = rb;
    // Predicted from the newest pose the server holds whole, when it is
    // young enough to still be among its baselines and still in the ring.
    uint32_t base = o->acked;
    if (base != 0 && (int32_t(seq - base) <= 0 || seq - base >= POSE_BASELINES || o->ring_seq[base % POSE_BASELINES] != base))
        base = 0;
    if (base != 0) {
        const RecordInts* pred = o->ring.data() + size_t(base % POSE_BASELINES) * size_t(B);
        pose_bits_.clear();
        BitWriter w(pose_bits_);
        for (int b = 0; b < B; ++b) {
            pose_offsets_[size_t(b)] = uint32_t(w.bits());
            write_predicted(ints[size_t(b)], pred[b], o->fmt.scaled, w);
        }
        pose_offsets_[size_t(B)] = uint32_t(w.bits());
        ++st_.poses_predicted;
    }
    // The root block: predicted from the baseline pose's root (age 1), else absolute.
    pose_root_.clear();
    write_root(rb.data(), base != 0 ? 1 : 0, base != 0 ? o->ring_root[base % POSE_BASELINES].data() : nullptr, nullptr,
               pose_root_);
    if (teleport) ++o->epoch;
    o->pose_seq = seq;
    // As many bones per datagram as fit (a character of a few hundred bones takes one).
    const size_t free_bytes = MAX_DATAGRAM - POSE_OVERHEAD - pose_root_.size();
    const size_t morph_bytes = morph_weights.empty() ? 0 : sizeof(int16_t) * pose_morphs_.size();  // with bone 0
    for (int first = 0; first < B;) {
        const size_t room = 8 * (free_bytes - (first == 0 ? morph_bytes : 0));
        int end = first + 1;  // one record always fits (kMaxRecordBits)
        while (end < B && pose_offsets_[size_t(end) + 1] - pose_offsets_[size_t(first)] <= room) ++end;
        pose_chunk_.clear();
        BitWriter w(pose_chunk_);
        copy_bits(pose_bits_.data(), pose_offsets_[size_t(first)], pose_offsets_[size_t(end)] - pose_offsets_[size_t(first)], w);
        fbb_.Clear();
        auto rv = fbb_.CreateVector(pose_root_.data(), pose_root_.size());
        auto rec = fbb_.CreateVector(pose_chunk_.data(), pose_chunk_.size());
        flatbuffers::Offset<flatbuffers::Vector<int16_t>> mv;  // the weights go with the first bones
        if (first == 0 && !morph_weights.empty()) mv = fbb_.CreateVector(pose_morphs_.data(), pose_morphs_.size());
        auto p = wire::CreatePose(fbb_, session_, udp_token_, uint16_t(o->instance), seq, o->epoch, uint8_t(first), rv, rec, mv,
                                  uint16_t(end - first), base);
        fbb_.Finish(wire::CreateDatagram(fbb_, 0, now_us32(), wire::DatagramBody::Pose, p.Union()), wire::DatagramIdentifier());
        const size_t before = out_.datagram_bytes.size();
        send_datagram(fbb_);
        st_.pose_wire_bytes += out_.datagram_bytes.size() - before + UDP_IP_OVERHEAD;
        first = end;
    }
    ++st_.poses_sent;
    return true;
}

// The frame's pose acks: the newest pose of each of this player's characters the
// server holds whole (the newest of those seen wins: frames may arrive out of order).
void ClientSession::apply_pose_acks(const FrameDatagram& f) {
    for (size_t i = 0; i < f.pose_ack_count(); ++i) {
        const wire::PoseAck k = f.pose_ack(i);
        for (Own& o : own_)
            if (o.instance == int(k.instance()) && k.pose_seq() != 0 && int32_t(k.pose_seq() - o.pose_seq) <= 0 &&
                (o.acked == 0 || int32_t(k.pose_seq() - o.acked) > 0))
                o.acked = k.pose_seq();
    }
}

}  // namespace progskin::net
