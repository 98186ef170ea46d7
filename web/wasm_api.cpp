// wasm_api.cpp — the C ABI of the WebAssembly client (docs/browser.md): the
// socket-free ClientSession (client/session.h) behind plain functions the
// page's JavaScript (web/progskin.js) calls. The JavaScript only moves bytes:
// each WebSocket message it receives goes whole into pskw_receive (kind byte
// first, docs/protocol.md "WebSocket transport"), and each message
// pskw_take_outgoing lays out (kind byte first) goes whole onto the socket.
// The framing of control messages, Bind, Acks, Stats, assets, the display
// clock and palettes are all the session's, the same code as the native
// client (client/client.cpp drives it the same way).
//
// Ownership: a psk_web is created by pskw_create and freed by pskw_destroy.
// Every pointer returned into the wasm heap (palettes, roots, outgoing
// messages, asset arrays, strings) is valid until the next pskw_update,
// pskw_receive, pskw_take_outgoing or pskw_destroy on that psk_web, whichever
// comes first (asset arrays: as long as the psk_web lives); the heap may
// grow, so JavaScript takes a fresh view of HEAPU8 / HEAPF32 after each call.
// Bounds: a received message is at most 1 + 4 + 65536 bytes (refused beyond,
// the session fails), pending datagrams at most 4096 (older ones dropped and
// counted), indices are checked (out of range: 0 / nullptr).
#include <emscripten/emscripten.h>

#include <cstring>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "client_palette.h"
#include "session.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;

namespace {

constexpr size_t MAX_MESSAGE = 1 + 4 + 65536;  // kind + control length + largest control body
constexpr size_t MAX_PENDING_DATAGRAMS = 4096;

// Datagrams received over the WebSocket since the last update.
class Pending final : public DatagramSource {
public:
    bool next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) override {
        if (q_.empty()) return false;
        cur_ = std::move(q_.front().bytes);
        arrival = q_.front().arrival;
        q_.pop_front();
        bytes = cur_;
        from_server = true;  // the WebSocket is the server's
        return true;
    }
    void push(std::span<const uint8_t> d, double arrival) {
        if (q_.size() >= MAX_PENDING_DATAGRAMS) {
            q_.pop_front();
            ++dropped;
        }
        q_.push_back({{d.begin(), d.end()}, arrival});
    }
    uint64_t dropped = 0;

private:
    struct Item {
        std::vector<uint8_t> bytes;
        double arrival;
    };
    std::deque<Item> q_;
    std::vector<uint8_t> cur_;
};

// A character this page publishes: spawned from a clip of an asset, its pose
// sampled from the clip and its root walking a circle (run_client.cpp's
// --publish does the same).
struct Published {
    int handle = -1, asset = 0;
    ClipSelection selection;
    double start = 0;  // page clock (seconds) at the clip's start
    uint64_t start_us = 0;
    glm::dvec3 center{0.0};
    double radius = 0, speed = 0;
    std::vector<glm::dmat4> mats;
    std::vector<Mat34> skin;     // joint order (what publish sends)
    std::vector<Mat34> palette;  // progressive order (what the page draws: the server never sends a player its own)
    RootPose root;
    bool posed = false;
};

// An asset as the page sets up its mesh: the vertex stream with at most 4
// influences (three.js), in progressive bone indices, renormalised.
struct MeshData {
    bool built = false;
    std::vector<float> positions, normals;
    std::vector<uint32_t> indices;
    std::vector<uint16_t> joints4;
    std::vector<float> weights4;
    std::vector<float> inverse_binds;  // 12 per bone, progressive order
    std::vector<int32_t> order, parents;
    // Per morph target (at most MAX_MORPHS, the weights streamed): its
    // position deltas, dense (3 floats per vertex; three.js morphAttributes
    // with morphTargetsRelative).
    std::vector<std::vector<float>> morph_deltas;
};

}  // namespace

struct psk_web {
    Outbox out;
    std::unique_ptr<ClientSession> session;
    Pending pending;
    double max_kbps = 0;
    // outgoing WebSocket messages (pskw_take_outgoing)
    std::vector<uint8_t> out_bytes;
    std::vector<uint32_t> out_ends;
    std::vector<uint8_t> in;  // pskw_in_buffer
    float root[8] = {};
    double stats[12] = {};
    std::vector<Published> published;
    std::vector<MeshData> meshes;
    std::string text;
};

namespace {

const RemoteCharacter* character_at(psk_web* w, int i) {
    if (!w || !w->session) return nullptr;
    const auto chars = w->session->characters();
    if (i < 0 || size_t(i) >= chars.size()) return nullptr;
    return &chars[size_t(i)];
}

const ClientAsset* asset_at(psk_web* w, int a) {
    if (!w || !w->session) return nullptr;
    const auto& assets = w->session->assets();
    if (a < 0 || size_t(a) >= assets.size() || !assets[size_t(a)]) return nullptr;
    return assets[size_t(a)].get();
}

MeshData* mesh_of(psk_web* w, int a) {
    const ClientAsset* asset = asset_at(w, a);
    if (!asset) return nullptr;
    if (w->meshes.size() < w->session->assets().size()) w->meshes.resize(w->session->assets().size());
    MeshData& m = w->meshes[size_t(a)];
    if (m.built) return &m;
    const Character& c = asset->character;
    const ProgressiveSkin& s = asset->skin;
    const size_t n = c.vertex_count();
    m.positions.resize(n * 3);
    for (size_t v = 0; v < n; ++v)
        for (int k = 0; k < 3; ++k) m.positions[v * 3 + size_t(k)] = c.positions[v][k];
    if (c.normals.size() == n) {
        m.normals.resize(n * 3);
        for (size_t v = 0; v < n; ++v)
            for (int k = 0; k < 3; ++k) m.normals[v * 3 + size_t(k)] = c.normals[v][k];
    }
    m.indices = c.triangles;
    // The first 4 slots (the skin orders each vertex's influences so that
    // dropping the last ones costs least), renormalised.
    const int inf = s.influences;
    m.joints4.assign(n * 4, 0);
    m.weights4.assign(n * 4, 0.0f);
    for (size_t v = 0; v < n; ++v) {
        float sum = 0;
        for (int k = 0; k < std::min(inf, 4); ++k) {
            m.joints4[v * 4 + size_t(k)] = s.joints[v * size_t(inf) + size_t(k)];
            m.weights4[v * 4 + size_t(k)] = s.weights[v * size_t(inf) + size_t(k)];
            sum += m.weights4[v * 4 + size_t(k)];
        }
        if (sum > 0)
            for (int k = 0; k < 4; ++k) m.weights4[v * 4 + size_t(k)] /= sum;
        else
            m.weights4[v * 4] = 1;
    }
    const int B = s.bone_count();
    m.inverse_binds.resize(size_t(B) * 12);
    for (int b = 0; b < B; ++b) {
        const Mat34 ib = Mat34::from_glm(c.inverse_bind[size_t(s.order[size_t(b)])]);
        std::memcpy(&m.inverse_binds[size_t(b) * 12], ib.m, sizeof ib.m);
    }
    m.order.assign(s.order.begin(), s.order.end());
    m.parents.assign(s.parents.begin(), s.parents.end());
    const size_t targets = std::min<size_t>(c.morphs.size(), MAX_MORPHS);
    m.morph_deltas.assign(targets, std::vector<float>(n * 3, 0.0f));
    for (size_t t = 0; t < targets; ++t) {
        const MorphTarget& mt = c.morphs[t];
        for (size_t k = 0; k < mt.vertices.size() && k < mt.position_deltas.size(); ++k)
            if (mt.vertices[k] < n)
                for (int d = 0; d < 3; ++d) m.morph_deltas[t][size_t(mt.vertices[k]) * 3 + size_t(d)] = mt.position_deltas[k][d];
    }
    m.built = true;
    return &m;
}

void publish_all(psk_web* w, double now) {
    for (Published& p : w->published) {
        const ClientAsset* a = asset_at(w, p.asset);
        if (!a || w->session->instance_of(p.handle) < 0) continue;
        const double t = now - p.start;
        sample_skinning_matrices(a->character, p.selection, p.selection.looped(t), p.mats);
        for (size_t j = 0; j < p.mats.size(); ++j) p.skin[j] = Mat34::from_glm(p.mats[j]);
        RootPose root = walk_root(p.center, p.radius, p.speed, t);
        root.source_us = p.start_us + uint64_t(t * 1e6);
        w->session->publish(p.handle, root, p.skin, false, {});
        p.palette.resize(a->skin.order.size());
        for (size_t b = 0; b < p.palette.size(); ++b) p.palette[b] = p.skin[size_t(a->skin.order[b])];
        p.root = root;
        p.posed = true;
    }
}

}  // namespace

extern "C" {

// A client with a bandwidth cap (0: the server's maximum), a minimum display
// delay (ms) and, when snap_to_ticks, display exactly on server ticks.
EMSCRIPTEN_KEEPALIVE psk_web* pskw_create(double max_kbps, double delay_ms, int snap_to_ticks) {
    auto* w = new psk_web;
    ClientConfig cfg;
    cfg.name = "progskin-browser";
    cfg.max_kbps = max_kbps > 0 ? max_kbps : 0;
    if (delay_ms > 0) cfg.delay_ms = delay_ms;
    cfg.snap_to_ticks = snap_to_ticks != 0;
    cfg.cache_dir = "/cache";  // Emscripten's in-memory file system
    cfg.tls = false;           // the WebSocket (TLS, if any, is the browser's)
    w->max_kbps = cfg.max_kbps;
    w->session = std::make_unique<ClientSession>(cfg, w->out);
    return w;
}

EMSCRIPTEN_KEEPALIVE void pskw_destroy(psk_web* w) { delete w; }

// The WebSocket is being opened (the connect timeout counts from now); peer
// names the server in messages.
EMSCRIPTEN_KEEPALIVE void pskw_start(psk_web* w, double now, const char* peer) {
    w->session->start(now, peer ? peer : "");
    w->session->on_transport_connected();
}
// The WebSocket is open: Hello.
EMSCRIPTEN_KEEPALIVE void pskw_open(psk_web* w) { w->session->on_channel_ready(); }
// The WebSocket closed or failed.
EMSCRIPTEN_KEEPALIVE void pskw_closed(psk_web* w) {
    if (w->session->running()) w->session->on_channel_closed();
}
EMSCRIPTEN_KEEPALIVE void pskw_close(psk_web* w, const char* reason) { w->session->close(reason ? reason : "closed"); }

// Where JavaScript writes a received message of `size` bytes (nullptr when
// over the bound: the caller then calls pskw_receive with that size, which fails the session).
EMSCRIPTEN_KEEPALIVE uint8_t* pskw_in_buffer(psk_web* w, int size) {
    if (size < 0 || size_t(size) > MAX_MESSAGE) return nullptr;
    w->in.resize(size_t(size));
    return w->in.data();
}
// One whole WebSocket message (kind byte first) of `size` bytes, written to
// pskw_in_buffer: a control message to the session, a datagram queued for
// the next update. Returns 0, or -1 when the message is malformed (the
// session then fails with the reason).
EMSCRIPTEN_KEEPALIVE int pskw_receive(psk_web* w, int size, double now) {
    if (size < 1 || size_t(size) > MAX_MESSAGE || size_t(size) != w->in.size()) {
        w->session->fail(FailReason::BadServerData, "WebSocket message of " + std::to_string(size) + " bytes refused");
        return -1;
    }
    const std::span<const uint8_t> body(w->in.data() + 1, w->in.size() - 1);
    if (w->in[0] == 1) {
        w->session->on_control_bytes(body, now);
    } else if (w->in[0] == 2 && body.size() <= MAX_DATAGRAM) {
        w->pending.push(body, now);
    } else {
        w->session->fail(FailReason::BadServerData, "WebSocket message of unknown kind " + std::to_string(w->in[0]) +
                                                        " or a datagram over " + std::to_string(MAX_DATAGRAM) + " bytes");
        return -1;
    }
    return 0;
}

// Once per animation frame: the pending datagrams, timeouts, Acks, Stats,
// the display clock and every palette; then the poses of the characters this
// page publishes. Returns the state (ClientState: 0 Idle, 1 Connecting,
// 2 Streaming, 3 Closed, 4 Failed).
EMSCRIPTEN_KEEPALIVE int pskw_update(psk_web* w, double now) {
    w->session->update(now, &w->pending);
    if (w->session->phase() == SessionPhase::Streaming) publish_all(w, now);
    w->session->clear_events();
    return int(w->session->state());
}
EMSCRIPTEN_KEEPALIVE int pskw_state(psk_web* w) { return int(w->session->state()); }
EMSCRIPTEN_KEEPALIVE const char* pskw_error(psk_web* w) { return w->session->error().c_str(); }

// Lays out what the session has to send as WebSocket messages (kind 1: one
// framed control message; kind 2: one datagram) and returns how many;
// pskw_outgoing / pskw_outgoing_size give each. The outbox is emptied.
EMSCRIPTEN_KEEPALIVE int pskw_take_outgoing(psk_web* w) {
    w->out_bytes.clear();
    w->out_ends.clear();
    Outbox& o = w->out;
    size_t at = 0;
    while (o.control.size() - at >= 4) {
        uint32_t n = 0;
        read_length({o.control.data() + at, 4}, n);
        if (o.control.size() - at < 4 + size_t(n)) break;
        w->out_bytes.push_back(1);
        w->out_bytes.insert(w->out_bytes.end(), o.control.begin() + std::ptrdiff_t(at),
                            o.control.begin() + std::ptrdiff_t(at + 4 + n));
        w->out_ends.push_back(uint32_t(w->out_bytes.size()));
        at += 4 + n;
    }
    o.control.erase(o.control.begin(), o.control.begin() + std::ptrdiff_t(at));
    for (size_t i = 0; i < o.datagrams(); ++i) {
        const auto d = o.datagram(i);
        w->out_bytes.push_back(2);
        w->out_bytes.insert(w->out_bytes.end(), d.begin(), d.end());
        w->out_ends.push_back(uint32_t(w->out_bytes.size()));
    }
    o.clear_datagrams();
    return int(w->out_ends.size());
}
EMSCRIPTEN_KEEPALIVE const uint8_t* pskw_outgoing(psk_web* w, int i) {
    if (i < 0 || size_t(i) >= w->out_ends.size()) return nullptr;
    return w->out_bytes.data() + (i ? w->out_ends[size_t(i) - 1] : 0);
}
EMSCRIPTEN_KEEPALIVE int pskw_outgoing_size(psk_web* w, int i) {
    if (i < 0 || size_t(i) >= w->out_ends.size()) return 0;
    return int(w->out_ends[size_t(i)] - (i ? w->out_ends[size_t(i) - 1] : 0));
}

// ------------------------------------------------------------ characters --
EMSCRIPTEN_KEEPALIVE int pskw_character_count(psk_web* w) { return int(w->session->characters().size()); }
EMSCRIPTEN_KEEPALIVE int pskw_character_instance(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? c->instance : -1;
}
// Index of its asset in the catalogue (-1: unknown).
EMSCRIPTEN_KEEPALIVE int pskw_character_asset(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    if (!c || !c->asset) return -1;
    const auto& assets = w->session->assets();
    for (size_t a = 0; a < assets.size(); ++a)
        if (assets[a].get() == c->asset) return int(a);
    return -1;
}
// 1 when a pose exists at the display time (palette valid).
EMSCRIPTEN_KEEPALIVE int pskw_character_shown(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c && c->shown ? 1 : 0;
}
// Bones shown (the LOD target), and the palette's size (every bone of the skin).
EMSCRIPTEN_KEEPALIVE int pskw_character_bones(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? c->bones : 0;
}
// RemoteCharacter::fresh_bones: of the bones shown, those whose records of
// the ticks around the display time are here.
EMSCRIPTEN_KEEPALIVE int pskw_character_fresh_bones(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? c->fresh_bones : 0;
}
EMSCRIPTEN_KEEPALIVE int pskw_character_palette_size(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? int(c->palette.size()) : 0;
}
// 12 floats per bone (3x4 row-major, Mat34), progressive order, relative to the root.
EMSCRIPTEN_KEEPALIVE const float* pskw_character_palette(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c && !c->palette.empty() ? c->palette.data()->m : nullptr;
}
// The server tick displayed.
EMSCRIPTEN_KEEPALIVE double pskw_character_tick(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? c->display_tick : -1;
}
// Morph weights displayed (one per morph target of the asset, as
// pskw_asset_morph_count; apply before skinning), valid until the next update.
EMSCRIPTEN_KEEPALIVE int pskw_character_morph_count(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c ? int(std::min<size_t>(c->morph_weights.size(), MAX_MORPHS)) : 0;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_character_morph_weights(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    return c && !c->morph_weights.empty() ? c->morph_weights.data() : nullptr;
}
// World root: position x y z, rotation x y z w, and 1 when its publisher
// announced it (a player's character), else 0.
EMSCRIPTEN_KEEPALIVE const float* pskw_character_root(psk_web* w, int i) {
    const RemoteCharacter* c = character_at(w, i);
    if (!c) return nullptr;
    for (int k = 0; k < 3; ++k) w->root[k] = float(c->root.position[k]);
    w->root[3] = c->root.rotation.x;
    w->root[4] = c->root.rotation.y;
    w->root[5] = c->root.rotation.z;
    w->root[6] = c->root.rotation.w;
    w->root[7] = c->publisher.published ? 1.0f : 0.0f;
    return w->root;
}

// ---------------------------------------------------------------- assets --
EMSCRIPTEN_KEEPALIVE int pskw_asset_count(psk_web* w) { return int(w->session->asset_names().size()); }
EMSCRIPTEN_KEEPALIVE int pskw_asset_ready(psk_web* w, int a) { return asset_at(w, a) ? 1 : 0; }
EMSCRIPTEN_KEEPALIVE const char* pskw_asset_name(psk_web* w, int a) {
    if (a < 0 || size_t(a) >= w->session->asset_names().size()) return "";
    return w->session->asset_names()[size_t(a)].c_str();
}
EMSCRIPTEN_KEEPALIVE double pskw_asset_diagonal(psk_web* w, int a) {
    const ClientAsset* x = asset_at(w, a);
    return x ? x->diagonal : 0;
}
EMSCRIPTEN_KEEPALIVE int pskw_asset_clip_count(psk_web* w, int a) {
    const ClientAsset* x = asset_at(w, a);
    return x ? int(x->character.clips.size()) : 0;
}
EMSCRIPTEN_KEEPALIVE int pskw_asset_vertex_count(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? int(m->positions.size() / 3) : 0;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_asset_positions(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->positions.data() : nullptr;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_asset_normals(psk_web* w, int a) {  // nullptr: none
    MeshData* m = mesh_of(w, a);
    return m && !m->normals.empty() ? m->normals.data() : nullptr;
}
EMSCRIPTEN_KEEPALIVE int pskw_asset_index_count(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? int(m->indices.size()) : 0;
}
EMSCRIPTEN_KEEPALIVE const uint32_t* pskw_asset_indices(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->indices.data() : nullptr;
}
// 4 progressive bone indices and 4 weights per vertex (summing to 1).
EMSCRIPTEN_KEEPALIVE const uint16_t* pskw_asset_joints4(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->joints4.data() : nullptr;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_asset_weights4(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->weights4.data() : nullptr;
}
// Morph targets (at most MAX_MORPHS) and each one's position deltas, dense:
// 3 floats per vertex of the asset's vertex stream.
EMSCRIPTEN_KEEPALIVE int pskw_asset_morph_count(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? int(m->morph_deltas.size()) : 0;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_asset_morph_deltas(psk_web* w, int a, int t) {
    MeshData* m = mesh_of(w, a);
    return m && t >= 0 && size_t(t) < m->morph_deltas.size() ? m->morph_deltas[size_t(t)].data() : nullptr;
}
// The progressive skin: B bones, the Character joint of each (joint order),
// progressive parents, and inverse binds (12 floats per bone, progressive order).
EMSCRIPTEN_KEEPALIVE int pskw_asset_bone_count(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? int(m->order.size()) : 0;
}
EMSCRIPTEN_KEEPALIVE const int32_t* pskw_asset_joint_order(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->order.data() : nullptr;
}
EMSCRIPTEN_KEEPALIVE const int32_t* pskw_asset_parents(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->parents.data() : nullptr;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_asset_inverse_binds(psk_web* w, int a) {
    MeshData* m = mesh_of(w, a);
    return m ? m->inverse_binds.data() : nullptr;
}

// ----------------------------------------------------------------- stats --
// [0] seconds since the first frame, [1] datagrams, [2] wire bytes,
// [3] loss, [4] rtt ms, [5] server estimate kbps, [6] display delay ms,
// [7] rate kbps over the last full second, [8] asset bytes downloaded,
// [9] malformed, [10] datagrams dropped here (pending bound), [11] cap kbps.
EMSCRIPTEN_KEEPALIVE const double* pskw_stats(psk_web* w, double now) {
    const ClientStats st = w->session->stats(now);
    double* s = w->stats;
    s[0] = st.seconds;
    s[1] = double(st.datagrams);
    s[2] = double(st.wire_bytes);
    s[3] = st.loss;
    s[4] = st.rtt_ms;
    s[5] = st.estimate_kbps;
    s[6] = st.delay_ms;
    const auto& bins = st.per_second_bytes;
    s[7] = bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : (bins.empty() ? 0 : bins.back() * 8 / 1000);
    s[8] = double(st.asset_bytes_downloaded);
    s[9] = double(st.malformed);
    s[10] = double(w->pending.dropped);
    s[11] = w->max_kbps;
    return s;
}

EMSCRIPTEN_KEEPALIVE void pskw_set_max_kbps(psk_web* w, double kbps) {
    w->max_kbps = kbps > 0 ? kbps : 0;
    w->session->set_max_kbps(w->max_kbps);
}

// Spawns a character of catalogue asset `asset` playing its clip `clip`
// (-1: every clip together) whose root walks a circle of `walk` bounding-box
// diagonals around (x, 0, z), and publishes its pose every update once
// spawned. Returns a handle (>= 0), or -1 when the asset is not ready or the
// clip does not exist.
EMSCRIPTEN_KEEPALIVE int pskw_spawn_clip(psk_web* w, int asset, int clip, double x, double z, double walk,
                                         double now) {
    const ClientAsset* a = asset_at(w, asset);
    if (!a) return -1;
    if (clip >= int(a->character.clips.size()) || clip < -1) return -1;
    Published p;
    p.asset = asset;
    p.selection = select_clips(a->character, clip < 0 ? std::string("all") : std::to_string(clip));
    p.start = now;
    p.start_us = uint64_t(now * 1e6);
    p.center = {x, 0.0, z};
    p.radius = walk > 0 ? walk * a->diagonal : 0;
    p.speed = walk > 0 ? 0.75 * a->diagonal : 0;
    p.mats.resize(a->character.joint_count());
    p.skin.resize(a->character.joint_count());
    p.handle = w->session->spawn({.asset = asset,
                                  .clips = p.selection.clips,
                                  .start_us = p.start_us,
                                  .walk_center = p.center,
                                  .walk_radius = p.radius,
                                  .walk_speed = p.speed,
                                  .position = glm::vec3(walk_root(p.center, p.radius, p.speed, 0.0).position)});
    const int h = p.handle;
    w->published.push_back(std::move(p));
    return h;
}
// The instance a spawned handle got (-1 until the server's Spawned).
EMSCRIPTEN_KEEPALIVE int pskw_instance_of(psk_web* w, int handle) { return w->session->instance_of(handle); }
EMSCRIPTEN_KEEPALIVE int pskw_published_count(psk_web* w) { return int(w->published.size()); }

// The page's own characters, k in [0, pskw_published_count): the server
// never streams a player its own characters back, so the page draws them
// from the pose it publishes. Instance (-1 until spawned), asset, palette
// (progressive order, 12 floats per bone; nullptr until first published),
// its size, and the root (as pskw_character_root, the last value 1).
EMSCRIPTEN_KEEPALIVE int pskw_own_instance(psk_web* w, int k) {
    if (k < 0 || size_t(k) >= w->published.size()) return -1;
    return w->session->instance_of(w->published[size_t(k)].handle);
}
EMSCRIPTEN_KEEPALIVE int pskw_own_asset(psk_web* w, int k) {
    if (k < 0 || size_t(k) >= w->published.size()) return -1;
    return w->published[size_t(k)].asset;
}
EMSCRIPTEN_KEEPALIVE int pskw_own_palette_size(psk_web* w, int k) {
    if (k < 0 || size_t(k) >= w->published.size() || !w->published[size_t(k)].posed) return 0;
    return int(w->published[size_t(k)].palette.size());
}
EMSCRIPTEN_KEEPALIVE const float* pskw_own_palette(psk_web* w, int k) {
    if (k < 0 || size_t(k) >= w->published.size() || !w->published[size_t(k)].posed) return nullptr;
    return w->published[size_t(k)].palette.data()->m;
}
EMSCRIPTEN_KEEPALIVE const float* pskw_own_root(psk_web* w, int k) {
    if (k < 0 || size_t(k) >= w->published.size() || !w->published[size_t(k)].posed) return nullptr;
    const RootPose& r = w->published[size_t(k)].root;
    for (int i = 0; i < 3; ++i) w->root[i] = float(r.position[i]);
    w->root[3] = r.rotation.x;
    w->root[4] = r.rotation.y;
    w->root[5] = r.rotation.z;
    w->root[6] = r.rotation.w;
    w->root[7] = 1.0f;
    return w->root;
}

}  // extern "C"
