// run_client.cpp — progskin-client's session over progskin::net::Client
// (client.h): connects, publishes the --publish characters (driven locally
// by a clip, walking a circle), displays every remote character at
// display_rate and, with --verify, measures what it displays against the
// reference (docs/metrics.md §2): server-driven clips at the clip time of the
// displayed tick; published characters at the publisher's source time of
// the displayed pose, in world space (root included).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>
#include <thread>

#include "animation.h"
#include "run_client.h"
#include "error_metric.h"
#include "skinning.h"
#include "errors.h"
#include "wire.h"

namespace progskin::net {

namespace {

// One character this client publishes.
struct Published {
    PublishOptions opt;
    int asset = -1, handle = -1;
    ClipSelection selection;
    double walk_radius = 0, walk_speed = 0;
    glm::dvec3 center{0.0};
    uint64_t start_us = 0;
    std::vector<glm::dmat4> mats;
    std::vector<Mat34> skin;
    std::vector<float> morphs;  // every target's weight (none when the character has no morphs)
};

int find_asset(const Client& c, const std::string& spec) {
    const auto& names = c.asset_names();
    for (size_t i = 0; i < names.size(); ++i)
        if (names[i] == spec) return int(i);
    char* end = nullptr;
    const long i = std::strtol(spec.c_str(), &end, 10);
    if (end && *end == 0 && !spec.empty() && i >= 0 && size_t(i) < names.size()) return int(i);
    std::string all;
    for (size_t k = 0; k < names.size(); ++k) all += (k ? ", " : "") + names[k];
    throw Error("--publish " + spec + ": the server has no such asset (catalogue: " + all + ")");
}

uint64_t now_us64() { return uint64_t(now_seconds() * 1e6); }

}  // namespace

ClientReport run_client(const ClientOptions& opt) {
    ClientConfig cfg;
    cfg.name = opt.name;
    cfg.token = opt.token;
    cfg.max_kbps = opt.max_kbps;
    cfg.udp_via_host = opt.udp_via_host;
    cfg.udp_via_port = opt.udp_via_port;
    cfg.delay_ms = opt.delay_ms;
    cfg.max_delay_ms = opt.max_delay_ms;
    cfg.blend_frames = opt.blend_frames;
    cfg.snap_to_ticks = opt.snap_to_ticks;
    cfg.cache_dir = opt.cache_dir;
    cfg.protocol_version = opt.protocol_version;
    cfg.connect_timeout = opt.connect_timeout;
    cfg.tls = opt.tls;
    cfg.ca_file = opt.ca_file;
    cfg.pin_sha256 = opt.pin_sha256;
    cfg.insecure = opt.insecure;
    cfg.on_download = opt.on_download;
    Client client(cfg);
    client.connect(opt.host, opt.port);
    if (opt.send_view) client.set_view(opt.view);

    ClientReport rep;
    std::vector<Published> pubs;
    size_t cap_index = 0;
    double t_stream = 0, end_time = 0, next_snapshot = 0, next_publish = 0;
    uint64_t display_count = 0;
    const double t_start = now_seconds();

    // Display statistics per instance id.
    struct Acc {
        double k_sum = 0, sq = 0, n = 0, max = 0, jump = 0;
        int k_min = 1 << 30, k_max = 0;
        uint64_t frames = 0;
        std::vector<glm::vec3> prev_err;
        bool has_prev = false, published = false, received = false;
        std::string asset;
    };
    std::map<int, Acc> acc;
    std::vector<double> latencies;
    std::vector<glm::vec3> shown, ref, morphed, ref_morphed;
    std::vector<float> ref_weights;
    std::vector<glm::dmat4> ref_mats;
    std::vector<Mat34> ref_pal;

    for (;;) {
        const double now = now_seconds();
        client.update(now);
        if (client.state() == ClientState::Failed) throw Error(client.error());
        if (client.state() == ClientState::Closed) throw Error("the session closed");
        for (const ClientEvent& e : client.events()) {
            if (e.type == ClientEvent::Type::SpawnRefused)
                throw Error("the server refused to spawn " + (e.asset >= 0 && size_t(e.asset) < client.asset_names().size()
                                                                  ? client.asset_names()[size_t(e.asset)]
                                                                  : std::string("a character")) +
                            ": " + e.text);
        }
        // Spawn the --publish characters once the catalogue is ready.
        if (pubs.empty() && !opt.publish.empty() && !client.asset_names().empty()) {
            bool ready = true;
            for (const auto& a : client.assets()) ready = ready && a != nullptr;
            if (ready) {
                int k = 0;
                for (const PublishOptions& po : opt.publish) {
                    Published p;
                    p.opt = po;
                    p.asset = find_asset(client, po.asset);
                    const ClientAsset& a = *client.assets()[size_t(p.asset)];
                    p.selection = po.clip.empty() ? select_clips(a.character, "all") : select_clips(a.character, po.clip);
                    const double diag = a.diagonal;
                    p.walk_radius = po.walk * diag;
                    p.walk_speed = po.walk > 0 ? 0.75 * diag : 0.0;  // about 1.4 m/s for a 1.9 m character
                    // Publishers of one client walk around different centres.
                    p.center = glm::dvec3(double(k) * 3.0 * diag, 0.0, 0.0);
                    p.start_us = now_us64();
                    SpawnSpec s;
                    s.asset = p.asset;
                    s.clips = p.selection.clips;
                    s.start_us = p.start_us;
                    s.walk_center = p.center;
                    s.walk_radius = p.walk_radius;
                    s.walk_speed = p.walk_speed;
                    s.position = glm::vec3(walk_root(p.center, p.walk_radius, p.walk_speed, 0.0).position);
                    p.handle = client.spawn(s);
                    p.mats.resize(a.character.joint_count());
                    p.skin.resize(a.character.joint_count());
                    p.morphs.resize(a.character.morphs.size());
                    pubs.push_back(std::move(p));
                    ++k;
                }
                rep.published = int(pubs.size());
            }
        }
        // Publish at publish_rate.
        if (!pubs.empty() && now >= next_publish) {
            next_publish = std::max(next_publish + 1.0 / opt.publish_rate, now - 0.5 / opt.publish_rate);
            for (Published& p : pubs) {
                const ClientAsset& a = *client.assets()[size_t(p.asset)];
                const uint64_t t_us = now_us64();
                const double t = double(int64_t(t_us - p.start_us)) * 1e-6;
                sample_skinning_matrices(a.character, p.selection, p.selection.looped(t), p.mats);
                for (size_t j = 0; j < p.mats.size(); ++j) p.skin[j] = Mat34::from_glm(p.mats[j]);
                RootPose root = walk_root(p.center, p.walk_radius, p.walk_speed, t);
                root.source_us = t_us;
                if (!p.morphs.empty()) sample_morph_weights(a.character, p.selection, p.selection.looped(t), p.morphs);
                client.publish(p.handle, root, p.skin, false,
                               std::span<const float>(p.morphs).first(std::min<size_t>(p.morphs.size(), MAX_MORPHS)));
            }
        }
        const auto chars = client.characters();
        bool any = false;
        for (const auto& c : chars) any = any || c.shown;
        const bool streaming = client.state() == ClientState::Streaming;
        // Streaming time counts from the first character displayed, or for a
        // publisher from the bound stream (it may be alone in the world).
        if (t_stream == 0 && (any || (streaming && rep.published > 0))) {
            t_stream = now;
            end_time = now + opt.duration;
            next_snapshot = now;
        }
        if (t_stream == 0 && streaming && now - t_start > opt.connect_timeout)
            throw Error("no frames received from the server's UDP port");
        if (t_stream == 0 && now - t_start > opt.connect_timeout + 600.0) throw Error("no frames received from the server");
        if (t_stream > 0 && now >= end_time) break;
        if (t_stream > 0 && cap_index < opt.cap_schedule.size() && now - t_stream >= opt.cap_schedule[cap_index].first) {
            client.set_max_kbps(opt.cap_schedule[cap_index].second);
            ++cap_index;
        }
        // Statistics of this displayed frame.
        if (t_stream > 0) {
            const bool warm = now - t_stream >= opt.warmup;
            const bool verify_now = opt.verify && (display_count % size_t(std::max(1, opt.verify_every)) == 0);
            ++display_count;
            for (const RemoteCharacter& c : chars) {
                Acc& a = acc[c.instance];
                a.received = a.received || c.shown;
                a.asset = c.asset ? c.asset->name : "";
                a.published = c.publisher.published;
                if (!c.shown || !warm) continue;
                a.k_sum += c.bones;
                a.k_min = std::min(a.k_min, c.bones);
                a.k_max = std::max(a.k_max, c.bones);
                ++a.frames;
                if (c.publisher.published) latencies.push_back((now - double(c.root.source_us) * 1e-6) * 1000.0);
                if (!verify_now || c.clip.selection.clips.empty()) continue;
                const Character& ch = c.asset->character;
                shown.resize(ch.vertex_count());
                {
                    // glTF: morph targets on the bind positions (the streamed weights), then the skin.
                    SkinningJob sj = skinning_job(ch, c.asset->skin, c.palette, shown);
                    if (!ch.morphs.empty() && c.morph_weights.size() == ch.morphs.size()) {
                        morphed.resize(ch.vertex_count());
                        morph_positions(ch, c.morph_weights, morphed);
                        sj.positions = morphed;
                    }
                    sj.run();
                }
                double clip_t;
                RootPose ref_root;
                if (c.publisher.published) {
                    const double t = double(int64_t(c.root.source_us - c.publisher.start_us)) * 1e-6;
                    clip_t = c.clip.at(t);
                    ref_root = walk_root(c.publisher.walk_center, c.publisher.walk_radius, c.publisher.walk_speed, t);
                } else {
                    clip_t = c.clip.clip_time(c.display_tick, client.tick_rate());
                    ref_root = c.root;
                }
                ref_mats.resize(ch.joint_count());
                ref_pal.resize(ch.joint_count());
                sample_skinning_matrices(ch, c.clip.selection, clip_t, ref_mats);
                for (size_t j = 0; j < ch.joint_count(); ++j) ref_pal[j] = Mat34::from_glm(ref_mats[j]);
                ref.resize(ch.vertex_count());
                {
                    // docs/metrics.md §2 reference: the morph targets at the clip's weights, then the skin.
                    SkinningJob rj = skinning_job(ch, ref_pal, ref);
                    if (!ch.morphs.empty()) {
                        ref_weights.resize(ch.morphs.size());
                        sample_morph_weights(ch, c.clip.selection, clip_t, ref_weights);
                        ref_morphed.resize(ch.vertex_count());
                        morph_positions(ch, ref_weights, ref_morphed);
                        rj.positions = ref_morphed;
                    }
                    rj.run();
                }
                const double scale = 100.0 / c.asset->diagonal;
                double jump = 0;
                if (a.prev_err.size() != shown.size()) a.prev_err.assign(shown.size(), glm::vec3(0.0f));
                const glm::dquat qs(c.root.rotation), qr(ref_root.rotation);
                for (size_t j = 0; j < shown.size(); ++j) {
                    // World space: each side placed by its own root.
                    const glm::dvec3 ws = c.root.position + qs * glm::dvec3(shown[j]);
                    const glm::dvec3 wr = ref_root.position + qr * glm::dvec3(ref[j]);
                    const glm::vec3 e = glm::vec3(ws - wr);
                    const double pct = glm::length(e) * scale;
                    a.sq += pct * pct;
                    a.max = std::max(a.max, pct);
                    if (a.has_prev) jump = std::max(jump, double(glm::length(e - a.prev_err[j])) * scale);
                    a.prev_err[j] = e;
                }
                a.n += double(shown.size());
                a.has_prev = opt.verify_every <= 1;
                a.jump = std::max(a.jump, jump);
            }
            if (opt.on_snapshot && opt.snapshot_every > 0 && warm && now >= next_snapshot) {
                next_snapshot = now + opt.snapshot_every;
                DisplaySnapshot snap;
                snap.seconds = now - t_stream;
                const auto bins = client.stats().per_second_bytes;
                snap.rate_kbps = bins.size() >= 2 ? bins[bins.size() - 2] * 8.0 / 1000.0 : 0.0;
                for (const RemoteCharacter& c : chars)
                    if (c.shown)
                        snap.characters.push_back({c.instance, &c.asset->character, &c.asset->skin, &c.asset->stream, c.palette,
                                                   glm::vec3(c.root.position), c.bones, c.morph_weights});
                if (!snap.characters.empty()) opt.on_snapshot(snap);
            }
            if (opt.verbose && display_count % size_t(std::max(1.0, opt.display_rate)) == 0) {
                const auto bins = client.stats().per_second_bytes;
                std::fprintf(stderr, "progskin-client: %.1f s, %.1f kbit/s last second, %zu characters\n", now - t_stream,
                             bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : 0.0, chars.size());
            }
        }
        // Sleep until the next displayed frame (the game loop of this program).
        const double next = now + 1.0 / opt.display_rate;
        const double wait = next - now_seconds();
        if (wait > 0) std::this_thread::sleep_for(std::chrono::duration<double>(wait));
    }
    for (Published& p : pubs) client.despawn(p.handle);
    client.update(now_seconds());
    const ClientStats st = client.stats();
    client.close("done");

    rep.seconds = t_stream > 0 ? now_seconds() - t_stream : 0;
    rep.datagrams = st.datagrams;
    rep.malformed = st.malformed;
    rep.duplicates = st.duplicates;
    rep.loss = st.loss;
    rep.rtt_ms = st.rtt_ms;
    rep.estimate_kbps = st.estimate_kbps;
    rep.delay_ms = st.delay_ms;
    rep.asset_bytes_downloaded = st.asset_bytes_downloaded;
    rep.assets_cached = st.assets_cached;
    rep.download_seconds = st.download_seconds;
    rep.poses_sent = st.poses_sent;
    const double stream_seconds = st.seconds;
    double total = 0;
    for (size_t i = 0; i < st.per_second_bytes.size(); ++i) {
        total += st.per_second_bytes[i];
        if (i + 1 < st.per_second_bytes.size() && double(i + 1) <= stream_seconds) {  // full one-second bins
            rep.per_second_kbps.push_back(st.per_second_bytes[i] * 8 / 1000);
            rep.rate_max_kbps = std::max(rep.rate_max_kbps, st.per_second_bytes[i] * 8 / 1000);
        }
    }
    rep.rate_kbps = stream_seconds > 0 ? total * 8 / 1000 / stream_seconds : 0;
    double kmin = 1e9, kmax = 0, ksum = 0, all_sq = 0, all_n = 0, all_max = 0, r_sq = 0, r_n = 0, r_max = 0;
    int counted = 0;
    for (const auto& [id, a] : acc) {
        InstanceReport ir;
        ir.instance = id;
        ir.asset = a.asset;
        ir.frames = a.frames;
        ir.published = a.published;
        if (a.received) ++rep.characters;
        if (a.published && a.received) ++rep.remote_characters;
        if (a.frames) {
            ir.bones_mean = a.k_sum / double(a.frames);
            ir.bones_min = a.k_min;
            ir.bones_max = a.k_max;
            ++counted;
            ksum += ir.bones_mean;
            kmin = std::min(kmin, ir.bones_mean);
            kmax = std::max(kmax, ir.bones_mean);
        }
        if (a.n > 0) {
            ir.rms_pct = std::sqrt(a.sq / a.n);
            ir.max_pct = a.max;
            ir.max_jump_pct = a.jump;
            all_sq += a.sq;
            all_n += a.n;
            all_max = std::max(all_max, a.max);
            rep.max_jump_pct = std::max(rep.max_jump_pct, a.jump);
            if (a.published) {
                r_sq += a.sq;
                r_n += a.n;
                r_max = std::max(r_max, a.max);
            }
        }
        rep.instances.push_back(ir);
    }
    rep.bones_mean = counted ? ksum / counted : 0;
    rep.bones_min = counted ? kmin : 0;
    rep.bones_max = counted ? kmax : 0;
    if (all_n > 0) {
        rep.rms_pct = std::sqrt(all_sq / all_n);
        rep.max_pct = all_max;
    }
    if (r_n > 0) {
        rep.remote_rms_pct = std::sqrt(r_sq / r_n);
        rep.remote_max_pct = r_max;
    }
    if (!latencies.empty()) {
        std::sort(latencies.begin(), latencies.end());
        rep.latency_ms_p50 = latencies[latencies.size() / 2];
        rep.latency_ms_p99 = latencies[std::min(latencies.size() - 1, size_t(double(latencies.size()) * 0.99))];
    }
    return rep;
}

static void num_or_null(std::ostringstream& o, double v) {
    if (v >= 0) o << v;
    else o << "null";
}

std::string report_json(const ClientReport& r) {
    std::ostringstream o;
    o.precision(6);
    o << "{\"seconds\": " << r.seconds << ", \"rate_kbps\": " << r.rate_kbps << ", \"datagrams\": " << r.datagrams
      << ", \"loss\": " << r.loss << ", \"characters\": " << r.characters << ", \"bones_mean\": " << r.bones_mean
      << ", \"bones_min\": " << r.bones_min << ", \"bones_max\": " << r.bones_max << ", \"rms_pct\": ";
    num_or_null(o, r.rms_pct);
    o << ", \"max_pct\": ";
    num_or_null(o, r.max_pct);
    o << ", \"rate_max_kbps\": " << r.rate_max_kbps << ", \"max_jump_pct\": " << r.max_jump_pct
      << ", \"delay_ms_max\": " << r.delay_ms << ", \"rtt_ms\": " << r.rtt_ms << ", \"estimate_kbps\": " << r.estimate_kbps
      << ", \"malformed\": " << r.malformed << ", \"duplicates\": " << r.duplicates
      << ", \"asset_bytes_downloaded\": " << r.asset_bytes_downloaded << ", \"assets_cached\": " << r.assets_cached << ", \"download_seconds\": " << r.download_seconds
      << ", \"published\": " << r.published << ", \"poses_sent\": " << r.poses_sent << ", \"remote\": {\"characters\": "
      << r.remote_characters << ", \"rms_pct\": ";
    num_or_null(o, r.remote_rms_pct);
    o << ", \"max_pct\": ";
    num_or_null(o, r.remote_max_pct);
    o << ", \"latency_ms_p50\": ";
    num_or_null(o, r.latency_ms_p50);
    o << ", \"latency_ms_p99\": ";
    num_or_null(o, r.latency_ms_p99);
    o << "}, \"per_second_kbps\": [";
    for (size_t i = 0; i < r.per_second_kbps.size(); ++i) o << (i ? ", " : "") << r.per_second_kbps[i];
    o << "], \"instances\": [";
    for (size_t i = 0; i < r.instances.size(); ++i) {
        const auto& x = r.instances[i];
        o << (i ? ", " : "") << "{\"instance\": " << x.instance << ", \"asset\": \"" << x.asset << "\", \"bones_mean\": " << x.bones_mean
          << ", \"bones_min\": " << x.bones_min << ", \"bones_max\": " << x.bones_max << ", \"rms_pct\": " << x.rms_pct
          << ", \"max_pct\": " << x.max_pct << ", \"max_jump_pct\": " << x.max_jump_pct << ", \"frames\": " << x.frames
          << ", \"published\": " << (x.published ? "true" : "false") << "}";
    }
    o << "]}";
    return o.str();
}

std::string report_text(const ClientReport& r) {
    char b[512];
    std::snprintf(b, sizeof b,
                  "%.1f s: %.1f kbit/s (max %.1f over 1 s), %llu datagrams, loss %.1f%%, %d characters, bones mean %.1f "
                  "(min %.1f, max %.1f)",
                  r.seconds, r.rate_kbps, r.rate_max_kbps, (unsigned long long)r.datagrams, 100 * r.loss, r.characters,
                  r.bones_mean, r.bones_min, r.bones_max);
    std::string s = b;
    if (r.rms_pct >= 0) {
        std::snprintf(b, sizeof b, ", error RMS %.4f%% max %.4f%% of diagonal", r.rms_pct, r.max_pct);
        s += b;
    }
    if (r.remote_characters > 0) {
        std::snprintf(b, sizeof b, "; %d remote published characters", r.remote_characters);
        s += b;
        if (r.remote_rms_pct >= 0) {
            std::snprintf(b, sizeof b, ", error RMS %.4f%% max %.4f%%", r.remote_rms_pct, r.remote_max_pct);
            s += b;
        }
        if (r.latency_ms_p50 >= 0) {
            std::snprintf(b, sizeof b, ", latency p50 %.1f ms p99 %.1f ms", r.latency_ms_p50, r.latency_ms_p99);
            s += b;
        }
    }
    return s + "\n";
}

}  // namespace progskin::net
