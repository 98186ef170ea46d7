// progskin_c.cpp — the C API (progskin.h) over progskin::net::Client
// (client/client.h). Every function catches every C++ exception at the
// boundary and turns it into a status, with the message in a thread-local
// string (psk_last_error). Nothing here allocates in psk_client_update or in
// the per-frame queries (characters, events): they hand out pointers into
// what the Client owns. What is converted for C (an asset's inverse binds,
// a clip sampler's scratch) is built once, on first request.
#define PSK_BUILDING 1
#include "progskin.h"

#include <cmath>
#include <cstring>
#include <exception>
#include <new>
#include <string>
#include <unordered_map>
#include <vector>

#include "animation.h"
#include "client.h"
#include "errors.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;

namespace {

// Per catalogue entry, what the C API converts for C once the asset is ready.
struct CAsset {
    bool built = false;
    std::vector<float> inverse_binds;        // bone_count * 12, progressive order
    bool sampler_built = false;
    std::vector<ClipSelection> clips;        // clip i alone; clips.back(): every clip together
    std::vector<glm::dmat4> joints;          // sampling scratch
};

// The last message of this thread; `empty` avoids touching the string on success.
thread_local std::string t_error;

psk_status ok() {
    if (!t_error.empty()) t_error.clear();  // keeps its capacity: no allocation
    return PSK_OK;
}

psk_status fail(psk_status s, const char* what) {
    try {
        t_error = what;
    } catch (...) {
        // out of memory while reporting: keep the previous text
    }
    return s;
}

psk_status fail(psk_status s, const std::string& what) { return fail(s, what.c_str()); }

// Runs f(fn), turning every exception into a status and a message; fn, the
// C function's name, is what PSK_NEED and the messages name (inside the
// lambda __func__ would be "operator()").
template <class F>
psk_status guard(const char* fn, F&& f) noexcept {
    try {
        return f(fn);
    } catch (const std::bad_alloc&) {
        return fail(PSK_ERR_MEMORY, std::string(fn) + ": out of memory");
    } catch (const progskin::Error& e) {
        return fail(PSK_ERR_ARGUMENT, std::string(fn) + ": " + e.what());
    } catch (const std::exception& e) {
        return fail(PSK_ERR_INTERNAL, std::string(fn) + ": " + e.what());
    } catch (...) {
        return fail(PSK_ERR_INTERNAL, std::string(fn) + ": unknown exception");
    }
}

bool is_finite(double v) { return std::isfinite(v); }

std::string str(const char* s) { return s ? std::string(s) : std::string(); }

}  // namespace

struct psk_client {
    explicit psk_client(const ClientConfig& cfg) : client(cfg) {}
    Client client;
    size_t next_event = 0;                // psk_client_poll_event's position in client.events()
    std::unordered_map<int, int> handle_asset;  // spawn handle -> asset index
    std::vector<CAsset> assets;           // sized to the catalogue on first request
};

namespace {

#define PSK_NEED(p)                                                                         \
    do {                                                                                    \
        if (!(p)) return fail(PSK_ERR_NULL, std::string(psk_fn) + ": " #p " is NULL");    \
    } while (0)

int asset_index(const Client& c, const ClientAsset* a) {
    const auto& all = c.assets();
    for (size_t i = 0; i < all.size(); ++i)
        if (all[i].get() == a) return int(i);
    return -1;
}

void fill_character(const Client& c, const RemoteCharacter& rc, psk_character* out) {
    std::memset(out, 0, sizeof *out);
    out->position[0] = rc.root.position.x;
    out->position[1] = rc.root.position.y;
    out->position[2] = rc.root.position.z;
    out->rotation[0] = rc.root.rotation.x;
    out->rotation[1] = rc.root.rotation.y;
    out->rotation[2] = rc.root.rotation.z;
    out->rotation[3] = rc.root.rotation.w;
    out->source_us = rc.root.source_us;
    out->display_tick = rc.display_tick;
    out->palette = rc.palette.empty() ? nullptr : rc.palette.data()->m;
    out->bone_count = int32_t(rc.palette.size());
    out->morph_weights = rc.morph_weights.empty() ? nullptr : rc.morph_weights.data();
    out->morph_count = int32_t(rc.morph_weights.size());
    out->instance = rc.instance;
    out->asset = asset_index(c, rc.asset);
    out->shown = rc.shown ? 1 : 0;
    out->bones = rc.bones;
    out->published = rc.publisher.published ? 1 : 0;
}

ClientConfig to_config(const psk_client_config& in) {
    ClientConfig c;
    if (in.name) c.name = in.name;
    c.token = str(in.token);
    c.cache_dir = str(in.cache_dir);
    c.ca_file = str(in.ca_file);
    c.pin_sha256 = str(in.pin_sha256);
    c.udp_via_host = str(in.udp_via_host);
    c.udp_via_port = uint16_t(in.udp_via_port);
    c.max_kbps = in.max_kbps;
    c.delay_ms = in.delay_ms;
    c.max_delay_ms = in.max_delay_ms;
    c.connect_timeout = in.connect_timeout;
    c.stream_timeout = in.stream_timeout;
    c.tls = in.tls != 0;
    c.insecure = in.insecure != 0;
    c.blend_frames = in.blend_frames;
    c.snap_to_ticks = in.snap_to_ticks != 0;
    c.protocol_version = uint16_t(in.protocol_version);
    return c;
}

// Every number of a config in its range; "" when it is.
std::string check_config(const psk_client_config& c) {
    if (!is_finite(c.max_kbps) || c.max_kbps < 0) return "max_kbps must be finite and >= 0";
    if (!is_finite(c.delay_ms) || c.delay_ms < 0 || c.delay_ms > 60000) return "delay_ms must be in [0, 60000]";
    if (!is_finite(c.max_delay_ms) || c.max_delay_ms < c.delay_ms || c.max_delay_ms > 60000)
        return "max_delay_ms must be in [delay_ms, 60000]";
    if (!is_finite(c.connect_timeout) || c.connect_timeout <= 0 || c.connect_timeout > 3600)
        return "connect_timeout must be in (0, 3600] seconds";
    if (!is_finite(c.stream_timeout) || c.stream_timeout <= 0 || c.stream_timeout > 3600)
        return "stream_timeout must be in (0, 3600] seconds";
    if (c.blend_frames < 0 || c.blend_frames > 1000) return "blend_frames must be in [0, 1000]";
    if (c.udp_via_port < 0 || c.udp_via_port > 65535) return "udp_via_port must be in [0, 65535]";
    if (c.udp_via_host && c.udp_via_port == 0) return "udp_via_host needs udp_via_port";
    if (c.protocol_version < 0 || c.protocol_version > 65535) return "protocol_version must be in [0, 65535]";
    return {};
}

// The C form of a ready asset (inverse binds in progressive order), built once.
CAsset& c_asset(psk_client& c, int index) {
    if (c.assets.size() < c.client.asset_names().size()) c.assets.resize(c.client.asset_names().size());
    CAsset& ca = c.assets[size_t(index)];
    const ClientAsset& a = *c.client.assets()[size_t(index)];
    if (!ca.built) {
        const int B = a.skin.bone_count();
        ca.inverse_binds.resize(size_t(B) * 12);
        for (int b = 0; b < B; ++b) {
            const Mat34 m = Mat34::from_glm(a.character.inverse_bind[size_t(a.skin.order[size_t(b)])]);
            std::memcpy(&ca.inverse_binds[size_t(b) * 12], m.m, sizeof m.m);
        }
        ca.built = true;
    }
    return ca;
}

void fill_asset(psk_client& c, int index, const ClientAsset& a, psk_asset* out) {
    const CAsset& ca = c_asset(c, index);
    const Character& ch = a.character;
    out->path = a.path.c_str();
    out->order = reinterpret_cast<const int32_t*>(a.skin.order.data());
    out->parents = a.skin.parents.data();
    out->inverse_binds = ca.inverse_binds.data();
    out->positions = ch.positions.empty() ? nullptr : &ch.positions[0].x;
    out->normals = ch.normals.empty() ? nullptr : &ch.normals[0].x;
    out->triangles = ch.triangles.empty() ? nullptr : ch.triangles.data();
    out->joints = a.skin.joints.empty() ? nullptr : a.skin.joints.data();
    out->weights = a.skin.weights.empty() ? nullptr : a.skin.weights.data();
    out->id = a.id;
    out->diagonal = a.diagonal;
    out->bone_count = a.skin.bone_count();
    out->joint_count = int32_t(ch.joint_count());
    out->vertex_count = int32_t(ch.vertex_count());
    out->triangle_count = int32_t(ch.triangles.size() / 3);
    out->influences = a.skin.influences;
    out->morph_count = int32_t(std::min<size_t>(ch.morphs.size(), MAX_MORPHS));
    out->clip_count = int32_t(ch.clips.size());
    out->ready = 1;
}

}  // namespace

static_assert(sizeof(int32_t) == sizeof(int), "psk_asset::order points at the client's int vector");
static_assert(sizeof(Mat34) == 12 * sizeof(float), "a palette is 12 floats per bone");
static_assert(sizeof(glm::vec3) == 3 * sizeof(float), "positions are 3 floats per vertex");

extern "C" {

const char* psk_version(void) { return PROGSKIN_C_VERSION; }

uint32_t psk_version_number(void) {
    return (uint32_t(PROGSKIN_C_VERSION_MAJOR) << 16) | (uint32_t(PROGSKIN_C_VERSION_MINOR) << 8) |
           uint32_t(PROGSKIN_C_VERSION_PATCH);
}

double psk_now(void) { return now_seconds(); }

const char* psk_last_error(void) { return t_error.c_str(); }

const char* psk_status_name(int s) {
    switch (s) {
        case PSK_OK: return "PSK_OK";
        case PSK_EMPTY: return "PSK_EMPTY";
        case PSK_NOT_READY: return "PSK_NOT_READY";
        case PSK_ERR_NULL: return "PSK_ERR_NULL";
        case PSK_ERR_ARGUMENT: return "PSK_ERR_ARGUMENT";
        case PSK_ERR_STATE: return "PSK_ERR_STATE";
        case PSK_ERR_CONNECT: return "PSK_ERR_CONNECT";
        case PSK_ERR_FAILED: return "PSK_ERR_FAILED";
        case PSK_ERR_MEMORY: return "PSK_ERR_MEMORY";
        case PSK_ERR_INTERNAL: return "PSK_ERR_INTERNAL";
        default: return "PSK_UNKNOWN_STATUS";
    }
}

psk_status psk_client_config_init(psk_client_config* config) {
    const char* psk_fn = __func__;
    PSK_NEED(config);
    const ClientConfig d;
    std::memset(config, 0, sizeof *config);
    config->max_kbps = d.max_kbps;
    config->delay_ms = d.delay_ms;
    config->max_delay_ms = d.max_delay_ms;
    config->connect_timeout = d.connect_timeout;
    config->stream_timeout = d.stream_timeout;
    config->blend_frames = d.blend_frames;
    config->tls = 1;  // like progskin-server: TLS unless asked otherwise
    return ok();
}

psk_client* psk_client_create(const psk_client_config* config) {
    psk_client* out = nullptr;
    const psk_status s = guard(__func__, [&]([[maybe_unused]] const char* psk_fn) -> psk_status {
        PSK_NEED(config);
        if (const std::string why = check_config(*config); !why.empty())
            return fail(PSK_ERR_ARGUMENT, "psk_client_create: " + why);
        out = new psk_client(to_config(*config));
        return ok();
    });
    return s == PSK_OK ? out : nullptr;
}

psk_status psk_client_destroy(psk_client* client) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        delete client;  // ~Client closes the connection
        return ok();
    });
}

psk_status psk_client_connect(psk_client* client, const char* host, uint16_t port) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(host);
        if (port == 0) return fail(PSK_ERR_ARGUMENT, "psk_client_connect: port 0");
        if (!*host) return fail(PSK_ERR_ARGUMENT, "psk_client_connect: empty host");
        if (client->client.state() != ClientState::Idle)
            return fail(PSK_ERR_STATE, "psk_client_connect: the client was connected already (one connect per client)");
        try {
            client->client.connect(host, port);
        } catch (const progskin::Error& e) {
            return fail(PSK_ERR_CONNECT, std::string("psk_client_connect: ") + e.what());
        }
        if (client->client.state() == ClientState::Failed)
            return fail(PSK_ERR_FAILED, "psk_client_connect: " + client->client.error());
        return ok();
    });
}

psk_status psk_client_connect_list(psk_client* client, const char* servers) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(servers);
        if (client->client.state() != ClientState::Idle)
            return fail(PSK_ERR_STATE, "psk_client_connect_list: the client was connected already (one connect per client)");
        std::vector<progskin::net::ServerAddress> list;
        try {
            list = progskin::net::parse_server_list(servers);
        } catch (const progskin::Error& e) {
            return fail(PSK_ERR_ARGUMENT, std::string("psk_client_connect_list: ") + e.what());
        }
        try {
            client->client.connect(list);
        } catch (const progskin::Error& e) {
            return fail(PSK_ERR_CONNECT, std::string("psk_client_connect_list: ") + e.what());
        }
        if (client->client.state() == ClientState::Failed)
            return fail(PSK_ERR_FAILED, "psk_client_connect_list: " + client->client.error());
        return ok();
    });
}

psk_status psk_client_update(psk_client* client, double now) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        if (!is_finite(now)) return fail(PSK_ERR_ARGUMENT, "psk_client_update: now is not finite");
        client->client.update(now);
        client->next_event = 0;
        if (client->client.state() == ClientState::Failed)
            return fail(PSK_ERR_FAILED, client->client.error().c_str());
        return ok();
    });
}

psk_status psk_client_close(psk_client* client, const char* reason) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        client->client.close(reason ? reason : "done");
        client->next_event = client->client.events().size();
        return ok();
    });
}

psk_status psk_client_state(const psk_client* client, psk_state* state) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(state);
    *state = psk_state(int(client->client.state()));
    return ok();
}

psk_status psk_client_fail_reason(const psk_client* client, psk_fail_reason* reason) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(reason);
    *reason = psk_fail_reason(int(client->client.fail_reason()));
    return ok();
}

psk_status psk_client_poll_event(psk_client* client, psk_event* event) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(event);
    const auto events = client->client.events();
    if (client->next_event >= events.size()) {
        ok();
        return PSK_EMPTY;
    }
    const ClientEvent& e = events[client->next_event++];
    event->text = e.text.c_str();
    event->type = int32_t(e.type) + 1;  // ClientEvent::Type starts at Connected = 0
    event->instance = e.instance;
    event->asset = e.asset;
    event->handle = e.handle;
    return ok();
}

psk_status psk_client_character_count(const psk_client* client, int* count) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(count);
    *count = int(client->client.characters().size());
    return ok();
}

psk_status psk_client_character(const psk_client* client, int index, psk_character* character) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(character);
    const auto all = client->client.characters();
    if (index < 0 || size_t(index) >= all.size())
        return fail(PSK_ERR_ARGUMENT, "psk_client_character: index " + std::to_string(index) + " outside [0, " +
                                          std::to_string(all.size()) + ")");
    fill_character(client->client, all[size_t(index)], character);
    return ok();
}

psk_status psk_client_find_character(const psk_client* client, int instance, psk_character* character) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(character);
    const RemoteCharacter* rc = client->client.character(instance);
    if (!rc) return fail(PSK_ERR_ARGUMENT, "psk_client_find_character: no character " + std::to_string(instance));
    fill_character(client->client, *rc, character);
    return ok();
}

psk_status psk_client_character_world_id(const psk_client* client, int instance, uint64_t* world_id) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(world_id);
    const RemoteCharacter* rc = client->client.character(instance);
    if (!rc) return fail(PSK_ERR_ARGUMENT, "psk_client_character_world_id: no character " + std::to_string(instance));
    *world_id = rc->world_id;
    return ok();
}

psk_status psk_client_asset_count(const psk_client* client, int* count) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(count);
    *count = int(client->client.asset_names().size());
    return ok();
}

psk_status psk_client_asset(psk_client* client, int index, psk_asset* asset) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(asset);
        const auto& names = client->client.asset_names();
        if (index < 0 || size_t(index) >= names.size())
            return fail(PSK_ERR_ARGUMENT, "psk_client_asset: index " + std::to_string(index) + " outside the catalogue (" +
                                              std::to_string(names.size()) + " assets)");
        std::memset(asset, 0, sizeof *asset);
        asset->name = names[size_t(index)].c_str();
        const auto& all = client->client.assets();
        if (size_t(index) >= all.size() || !all[size_t(index)]) {
            fail(PSK_NOT_READY, "psk_client_asset: " + names[size_t(index)] + " is not downloaded yet");
            return PSK_NOT_READY;
        }
        fill_asset(*client, index, *all[size_t(index)], asset);
        return ok();
    });
}

psk_status psk_client_sample_clip(psk_client* client, int asset, int clip, double t, float* out, int capacity) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(out);
        const auto& all = client->client.assets();
        if (asset < 0 || size_t(asset) >= all.size())
            return fail(PSK_ERR_ARGUMENT, "psk_client_sample_clip: no asset " + std::to_string(asset));
        if (!all[size_t(asset)]) return fail(PSK_NOT_READY, "psk_client_sample_clip: the asset is not downloaded yet");
        if (!is_finite(t)) return fail(PSK_ERR_ARGUMENT, "psk_client_sample_clip: t is not finite");
        const Character& ch = all[size_t(asset)]->character;
        if (clip < -1 || clip >= int(ch.clips.size()))
            return fail(PSK_ERR_ARGUMENT, "psk_client_sample_clip: clip " + std::to_string(clip) + " outside [-1, " +
                                              std::to_string(ch.clips.size()) + ")");
        if (capacity < 0 || size_t(capacity) < ch.joint_count() * 12)
            return fail(PSK_ERR_ARGUMENT, "psk_client_sample_clip: capacity " + std::to_string(capacity) + " < " +
                                              std::to_string(ch.joint_count() * 12) + " floats");
        CAsset& ca = c_asset(*client, asset);
        if (!ca.sampler_built) {
            for (int i = 0; i < int(ch.clips.size()); ++i) ca.clips.push_back(make_selection(ch, {i}));
            ca.clips.push_back(select_clips(ch, "all"));
            ca.joints.resize(ch.joint_count());
            ca.sampler_built = true;
        }
        const ClipSelection& sel = clip < 0 ? ca.clips.back() : ca.clips[size_t(clip)];
        sample_skinning_matrices(ch, sel, sel.looped(t), ca.joints);
        for (size_t j = 0; j < ca.joints.size(); ++j) std::memcpy(out + j * 12, Mat34::from_glm(ca.joints[j]).m, 12 * sizeof(float));
        return ok();
    });
}

psk_status psk_spawn_spec_init(psk_spawn_spec* spec) {
    const char* psk_fn = __func__;
    PSK_NEED(spec);
    std::memset(spec, 0, sizeof *spec);
    spec->speed = 1;
    return ok();
}

psk_status psk_client_spawn(psk_client* client, const psk_spawn_spec* spec, int* handle) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(spec);
        PSK_NEED(handle);
        *handle = -1;
        const ClientState st = client->client.state();
        if (st != ClientState::Connecting && st != ClientState::Streaming)
            return fail(PSK_ERR_STATE, "psk_client_spawn: the client is not connected");
        const size_t n = client->client.asset_names().size();
        if (n == 0) return fail(PSK_NOT_READY, "psk_client_spawn: not welcomed yet (wait for PSK_EVENT_CONNECTED)");
        if (spec->asset < 0 || size_t(spec->asset) >= n)
            return fail(PSK_ERR_ARGUMENT, "psk_client_spawn: no asset " + std::to_string(spec->asset) + " in the catalogue (" +
                                              std::to_string(n) + " assets)");
        if (spec->clip_count < 0 || spec->clip_count > 64 || (spec->clip_count > 0 && !spec->clips))
            return fail(PSK_ERR_ARGUMENT, "psk_client_spawn: clip_count must be in [0, 64] with clips");
        for (double v : {spec->walk_center[0], spec->walk_center[1], spec->walk_center[2], spec->walk_radius,
                         spec->walk_speed, double(spec->speed), double(spec->position[0]), double(spec->position[1]),
                         double(spec->position[2])})
            if (!is_finite(v)) return fail(PSK_ERR_ARGUMENT, "psk_client_spawn: a number is not finite");
        SpawnSpec s;
        s.asset = spec->asset;
        s.clips.assign(spec->clips, spec->clips + spec->clip_count);
        s.once = spec->once != 0;
        s.speed = spec->speed;
        s.start_us = spec->start_us;
        s.walk_center = {spec->walk_center[0], spec->walk_center[1], spec->walk_center[2]};
        s.walk_radius = spec->walk_radius;
        s.walk_speed = spec->walk_speed;
        s.position = {spec->position[0], spec->position[1], spec->position[2]};
        *handle = client->client.spawn(s);
        client->handle_asset[*handle] = spec->asset;
        return ok();
    });
}

psk_status psk_client_instance_of(const psk_client* client, int handle, int* instance) {
    const char* psk_fn = __func__;
    PSK_NEED(client);
    PSK_NEED(instance);
    *instance = client->client.instance_of(handle);
    return ok();
}

namespace {
// What publish would refuse that can be named without the codec: a value
// that is not finite, a root beyond 2,000 km, a zero root rotation, a morph
// weight outside [-2, 2).
// Empty when none (the codec's own range is checked by Client::publish).
std::string check_publish_values(const psk_root& root, const float* skinning, int joint_count, const float* morphs,
                                 int morph_count) {
    for (int i = 0; i < 3; ++i)
        if (!is_finite(root.position[i]) || std::abs(root.position[i]) > 2.0e6)
            return "root position[" + std::to_string(i) + "] is not finite or beyond 2,000 km (the root is coded in mm, 32 bits)";
    double q2 = 0;
    for (int i = 0; i < 4; ++i) {
        if (!is_finite(root.rotation[i])) return "root rotation[" + std::to_string(i) + "] is not finite";
        q2 += double(root.rotation[i]) * root.rotation[i];
    }
    if (q2 < 1e-12) return "root rotation is the zero quaternion (identity is x y z w = 0 0 0 1)";
    for (int j = 0; j < joint_count; ++j)
        for (int k = 0; k < 12; ++k)
            if (!is_finite(skinning[size_t(j) * 12 + size_t(k)]))
                return "skinning matrix of joint " + std::to_string(j) + ", float " + std::to_string(k) + " is not finite";
    for (int m = 0; morphs && m < morph_count; ++m)
        if (int16_t q = 0; !progskin::net::encode_morph_weight(morphs[m], q))
            return "morph weight " + std::to_string(m) + " is " + std::to_string(morphs[m]) + ", outside [-2, 2)";
    return {};
}
}  // namespace

psk_status psk_client_publish(psk_client* client, int handle, const psk_root* root, const float* skinning,
                              int joint_count, const float* morph_weights, int morph_count, int teleport) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(root);
        PSK_NEED(skinning);
        const auto h = client->handle_asset.find(handle);
        if (h == client->handle_asset.end())
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: handle " + std::to_string(handle) + " was not spawned");
        if (morph_count < 0 || (morph_count > 0 && !morph_weights))
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: morph_count < 0, or morph_weights NULL");
        const auto& all = client->client.assets();
        const ClientAsset* a = size_t(h->second) < all.size() ? all[size_t(h->second)].get() : nullptr;
        if (!a) return fail(PSK_NOT_READY, "psk_client_publish: the asset is not downloaded yet");
        if (joint_count != int(a->character.joint_count()))
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: joint_count " + std::to_string(joint_count) + ", the asset has " +
                                              std::to_string(a->character.joint_count()) + " joints");
        const size_t morphs = std::min<size_t>(a->character.morphs.size(), MAX_MORPHS);
        if (morph_count != 0 && size_t(morph_count) != morphs)
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: morph_count " + std::to_string(morph_count) + ", the asset has " +
                                              std::to_string(morphs) + " morph targets");
        if (client->client.instance_of(handle) < 0 || client->client.state() != ClientState::Streaming)
            return fail(PSK_NOT_READY, "psk_client_publish: not spawned yet, or the stream is not bound");
        if (const std::string why = check_publish_values(*root, skinning, joint_count, morph_weights, morph_count); !why.empty())
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: " + why);
        RootPose r;
        r.position = {root->position[0], root->position[1], root->position[2]};
        r.rotation = glm::quat(root->rotation[3], root->rotation[0], root->rotation[1], root->rotation[2]);
        r.source_us = root->source_us;
        const std::span<const Mat34> m(reinterpret_cast<const Mat34*>(skinning), size_t(joint_count));
        const std::span<const float> w(morph_weights, morph_weights ? size_t(morph_count) : 0);
        if (!client->client.publish(handle, r, m, teleport != 0, w))
            return fail(PSK_ERR_ARGUMENT, "psk_client_publish: a joint's translation or scale is outside the codec's range "
                                          "(skinning matrices are joint world times inverse bind, in the asset's units)");
        return ok();
    });
}

psk_status psk_client_despawn(psk_client* client, int handle) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        if (client->handle_asset.erase(handle) == 0)
            return fail(PSK_ERR_ARGUMENT, "psk_client_despawn: handle " + std::to_string(handle) + " was not spawned");
        client->client.despawn(handle);
        return ok();
    });
}

psk_status psk_client_set_view(psk_client* client, const psk_view* view) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(view);
        if (view->weight_count < 0 || view->weight_count > 65536 ||
            (view->weight_count > 0 && (!view->weight_instances || !view->weights)))
            return fail(PSK_ERR_ARGUMENT, "psk_client_set_view: weight_count must be in [0, 65536] with both arrays");
        ViewSpec v;
        v.camera = {view->camera[0], view->camera[1], view->camera[2]};
        v.fov_y = view->fov_y;
        v.viewport_height = view->viewport_height;
        v.has_camera = view->has_camera != 0;
        if (v.has_camera && (!is_finite(v.camera.x) || !is_finite(v.camera.y) || !is_finite(v.camera.z) || !is_finite(v.fov_y) ||
                             v.fov_y <= 0 || v.fov_y >= 3.14159f || !is_finite(v.viewport_height) || v.viewport_height <= 0))
            return fail(PSK_ERR_ARGUMENT, "psk_client_set_view: the camera needs finite numbers, fov_y in (0, pi), "
                                          "viewport_height > 0");
        for (int i = 0; i < view->weight_count; ++i) {
            if (!is_finite(view->weights[i]) || view->weights[i] < 0)
                return fail(PSK_ERR_ARGUMENT, "psk_client_set_view: weight " + std::to_string(i) + " is not finite and >= 0");
            v.weights.emplace_back(view->weight_instances[i], view->weights[i]);
        }
        client->client.set_view(v);
        return ok();
    });
}

psk_status psk_client_set_max_kbps(psk_client* client, double kbps) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        if (!is_finite(kbps) || kbps < 0) return fail(PSK_ERR_ARGUMENT, "psk_client_set_max_kbps: kbps must be finite and >= 0");
        client->client.set_max_kbps(kbps);
        return ok();
    });
}

psk_status psk_client_stats(const psk_client* client, psk_stats* stats) {
    return guard(__func__, [&]([[maybe_unused]] const char* psk_fn) {
        PSK_NEED(client);
        PSK_NEED(stats);
        const ClientStats s = client->client.stats();
        std::memset(stats, 0, sizeof *stats);
        stats->seconds = s.seconds;
        stats->loss = s.loss;
        stats->rtt_ms = s.rtt_ms;
        stats->estimate_kbps = s.estimate_kbps;
        stats->delay_ms = s.delay_ms;
        stats->download_seconds = s.download_seconds;
        stats->datagrams = s.datagrams;
        stats->wire_bytes = s.wire_bytes;
        stats->asset_bytes_downloaded = s.asset_bytes_downloaded;
        stats->poses_sent = s.poses_sent;
        stats->poses_refused = s.poses_refused;
        stats->assets_cached = s.assets_cached;
        return ok();
    });
}

}  // extern "C"
