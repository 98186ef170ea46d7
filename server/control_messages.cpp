// control_messages.cpp — see control_messages.h.
#include "control_messages.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <sodium.h>

namespace progskin::net {

std::string read_spawn(const wire::Spawn& m, const ServerAssets& assets, uint64_t owner, InstanceSpec& sp) {
    if (m.asset() >= assets.size()) return "no asset " + std::to_string(m.asset());
    const ServerAsset& a = *assets[m.asset()];
    sp = InstanceSpec{};
    sp.asset = m.asset();
    sp.selection = -1;
    sp.owner = owner;
    sp.once = m.once();
    sp.speed = m.speed();
    if (m.clips()) {
        if (m.clips()->size() > MAX_INSTANCE_CLIPS)
            return std::to_string(m.clips()->size()) + " clips; a character plays at most " + std::to_string(MAX_INSTANCE_CLIPS);
        for (int c : *m.clips()) {
            if (c < 0 || size_t(c) >= a.character.clips.size()) return "no clip " + std::to_string(c) + " in " + a.name;
            if (std::find(sp.announced_clips.begin(), sp.announced_clips.end(), c) != sp.announced_clips.end())
                return "clip " + std::to_string(c) + " repeated";
            sp.announced_clips.push_back(c);
        }
    }
    sp.publisher_start_us = m.publisher_start_us();
    if (m.walk_center()) sp.walk_center = {m.walk_center()->x(), m.walk_center()->y(), m.walk_center()->z()};
    sp.walk_radius = m.walk_radius();
    sp.walk_speed = m.walk_speed();
    if (m.position()) sp.position = {m.position()->x(), m.position()->y(), m.position()->z()};
    if (!std::isfinite(sp.speed) || !std::isfinite(sp.walk_radius) || !std::isfinite(sp.walk_speed) ||
        !std::isfinite(sp.walk_center.x) || !std::isfinite(sp.walk_center.y) || !std::isfinite(sp.walk_center.z) ||
        !std::isfinite(sp.position.x) || !std::isfinite(sp.position.y) || !std::isfinite(sp.position.z))
        return "spawn values must be finite";
    if (!(std::fabs(sp.position.x) < 2e6f && std::fabs(sp.position.y) < 2e6f && std::fabs(sp.position.z) < 2e6f))
        return "spawn position outside the world (+-2,000 km)";
    return {};
}

std::string read_view(const wire::View& v, ViewSpec& vs) {
    if (v.weights() && v.weights()->size() > MAX_VIEW_WEIGHTS)
        return "View of " + std::to_string(v.weights()->size()) + " weights (at most " + std::to_string(MAX_VIEW_WEIGHTS) + ")";
    vs = ViewSpec{};
    if (v.camera()) {
        vs.camera = {v.camera()->x(), v.camera()->y(), v.camera()->z()};
        vs.has_camera = true;
    }
    if (v.fov_y() > 0) vs.fov_y = v.fov_y();
    if (v.viewport_height() > 0) vs.viewport_height = v.viewport_height();
    if (v.weights())
        for (const auto* w : *v.weights())
            if (std::isfinite(w->weight())) vs.weights.emplace_back(w->instance(), w->weight());
    // Indexed, not scanned: sorted by instance, the last weight of an instance named twice kept.
    std::stable_sort(vs.weights.begin(), vs.weights.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    auto last = std::unique(vs.weights.rbegin(), vs.weights.rend(), [](const auto& a, const auto& b) { return a.first == b.first; });
    vs.weights.erase(vs.weights.begin(), last.base());
    return {};
}

namespace {

// One Asset table (control.fbs) of the Welcome's catalogue.
flatbuffers::Offset<wire::Asset> asset_table(flatbuffers::FlatBufferBuilder& fbb, const ServerAsset& a) {
    const ProgressiveSkin& sk = a.skin;
    std::vector<int16_t> order(sk.order.begin(), sk.order.end());
    std::vector<float> corr;
    corr.reserve(sk.corrections.size() * 12);
    for (const Mat34& m : sk.corrections) corr.insert(corr.end(), m.m, m.m + 12);
    std::vector<wire::ErrorPoint> err;
    for (const auto& e : sk.error) err.emplace_back(float(e.rms), float(e.max));
    auto name = fbb.CreateString(a.name);
    auto vo = fbb.CreateVector(order);
    auto vp = fbb.CreateVector(sk.parents);
    auto vc = fbb.CreateVector(corr);
    auto ve = fbb.CreateVectorOfStructs(err);
    wire::Vec3 lo(a.format.t_min.x, a.format.t_min.y, a.format.t_min.z);
    wire::Vec3 hi(a.format.t_max.x, a.format.t_max.y, a.format.t_max.z);
    return wire::CreateAsset(fbb, a.id, name, a.bytes.size(), uint16_t(a.bone_count()), a.format.scaled, vo, vp, vc, ve,
                             float(a.diagonal), &lo, &hi, float(a.motion), a.format.scale, a.format.t_step);
}

// One Instance table (control.fbs) for an active instance.
flatbuffers::Offset<wire::Instance> instance_table(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets, int id,
                                                   const InstanceSpec& sp) {
    const ServerAsset& a = *assets[size_t(sp.asset)];
    std::vector<int32_t> clips;
    float start = 0, end = 0;
    if (sp.selection >= 0) {
        const ClipSelection& sel = a.selections[size_t(sp.selection)];
        clips.assign(sel.clips.begin(), sel.clips.end());
        start = sel.start;
        end = sel.end;
    } else {
        clips.assign(sp.announced_clips.begin(), sp.announced_clips.end());
        if (!clips.empty()) {
            const ClipSelection sel = make_selection(a.character, sp.announced_clips);
            start = sel.start;
            end = sel.end;
        }
    }
    wire::Vec3 pos(sp.position.x, sp.position.y, sp.position.z);
    wire::Quat rot(sp.rotation.x, sp.rotation.y, sp.rotation.z, sp.rotation.w);
    wire::DVec3 wc(sp.walk_center.x, sp.walk_center.y, sp.walk_center.z);
    auto vcl = fbb.CreateVector(clips);
    return wire::CreateInstance(fbb, uint16_t(id), uint16_t(sp.asset), &pos, vcl, start, end, sp.time_offset, sp.speed, sp.once,
                                &rot, sp.owner != 0, sp.publisher_start_us, &wc, sp.walk_radius, sp.walk_speed, sp.world_id);
}

}  // namespace

void build_welcome(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets, uint64_t session_id, uint64_t udp_token,
                   uint16_t udp_port, float tick_rate, double cap_kbps, const crypto::Key* tx_key, const crypto::Key* rx_key) {
    std::vector<flatbuffers::Offset<wire::Asset>> as;
    for (const auto& a : assets) as.push_back(asset_table(fbb, *a));
    auto va = fbb.CreateVector(as);
    auto sn = fbb.CreateString("progskin-server");
    flatbuffers::Offset<flatbuffers::Vector<uint8_t>> keys;
    if (tx_key && rx_key) {
        std::array<uint8_t, 2 * crypto::KEY_BYTES> k;
        std::copy(tx_key->begin(), tx_key->end(), k.begin());
        std::copy(rx_key->begin(), rx_key->end(), k.begin() + crypto::KEY_BYTES);
        keys = fbb.CreateVector(k.data(), k.size());
        sodium_memzero(k.data(), k.size());
    }
    auto w = wire::CreateWelcome(fbb, PROTOCOL_VERSION, session_id, udp_token, udp_port, tick_rate, uint32_t(cap_kbps), va, sn,
                                 keys);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Welcome, w.Union()), wire::ControlIdentifier());
}

size_t instance_table_bound(const ServerAssets& assets, const InstanceSpec& sp) {
    const ServerAsset& a = *assets[size_t(sp.asset)];
    const size_t clips = sp.selection >= 0 ? a.selections[size_t(sp.selection)].clips.size() : sp.announced_clips.size();
    return MAX_INSTANCE_TABLE_BYTES - 4 * (MAX_INSTANCE_CLIPS - std::min(clips, MAX_INSTANCE_CLIPS));
}

// The Control and InstanceAdded tables, the vector's length, the buffer's
// identifier and alignment: what an InstanceAdded holds besides its Instance tables.
static constexpr size_t kInstanceAddedOverhead = 64;
static_assert(MAX_BATCH_REMOVED * 2 + kInstanceAddedOverhead <= MAX_CONTROL_MESSAGE, "InstanceRemoved fits");
static_assert(MAX_INSTANCE_TABLE_BYTES + kInstanceAddedOverhead <= MAX_CONTROL_MESSAGE, "one Instance fits");

size_t instances_per_message(const ServerAssets& assets, std::span<const std::pair<int, InstanceSpec>> added) {
    size_t bytes = kInstanceAddedOverhead, n = 0;
    while (n < added.size() && n < MAX_BATCH_INSTANCES) {
        const size_t b = instance_table_bound(assets, added[n].second);
        if (bytes + b > MAX_CONTROL_MESSAGE) break;
        bytes += b;
        ++n;
    }
    return n;
}

void build_instances_added(flatbuffers::FlatBufferBuilder& fbb, const ServerAssets& assets,
                           std::span<const std::pair<int, InstanceSpec>> added) {
    std::vector<flatbuffers::Offset<wire::Instance>> is;
    for (const auto& [id, spec] : added) is.push_back(instance_table(fbb, assets, id, spec));
    auto v = fbb.CreateVector(is);
    auto m = wire::CreateInstanceAdded(fbb, v);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::InstanceAdded, m.Union()), wire::ControlIdentifier());
}

void build_instances_removed(flatbuffers::FlatBufferBuilder& fbb, std::span<const uint16_t> ids) {
    auto v = fbb.CreateVector(ids.data(), ids.size());
    auto r = wire::CreateInstanceRemoved(fbb, v);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::InstanceRemoved, r.Union()), wire::ControlIdentifier());
}

void build_spawned(flatbuffers::FlatBufferBuilder& fbb, uint32_t request, bool ok, int instance, const std::string& reason) {
    auto r = fbb.CreateString(reason);
    auto m = wire::CreateSpawned(fbb, request, ok, uint16_t(ok ? instance : 0), r);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Spawned, m.Union()), wire::ControlIdentifier());
}

void build_asset_chunk(flatbuffers::FlatBufferBuilder& fbb, const ServerAsset& a, uint64_t offset, size_t n) {
    auto data = fbb.CreateVector(a.bytes.data() + offset, n);
    auto ch = wire::CreateAssetChunk(fbb, a.id, offset, a.bytes.size(), data);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetChunk, ch.Union()), wire::ControlIdentifier());
}

void build_stats(flatbuffers::FlatBufferBuilder& fbb, double estimate_kbps, double loss, double rtt_ms, uint32_t sent_datagrams) {
    wire::StatsBuilder sb(fbb);
    sb.add_estimate_kbps(float(estimate_kbps));
    sb.add_loss(float(loss));
    sb.add_rtt_ms(float(rtt_ms));
    sb.add_sent_datagrams(sent_datagrams);
    auto so = sb.Finish();
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Stats, so.Union()), wire::ControlIdentifier());
}

}  // namespace progskin::net
