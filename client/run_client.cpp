// run_client.cpp — progskin-client's session (run_client.h) over
// progskin::net::Client (client.h), a Run of named steps: connects,
// publishes the --publish characters (driven locally by a clip, walking a
// circle), displays every remote character at display_rate and, with
// --verify, measures what it displays against the reference (docs/metrics.md
// §2): server-driven clips at the clip time of the displayed tick; published
// characters at the publisher's source time of the displayed pose, in world
// space (root included).
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

// Display statistics of one instance id.
struct Acc {
    double k_sum = 0, sq = 0, n = 0, max = 0, jump = 0;
    int k_min = 1 << 30, k_max = 0;
    uint64_t frames = 0;
    std::vector<glm::vec3> prev_err;
    bool has_prev = false, published = false, received = false;
    std::string asset;
};

int find_asset(const Client& c, const std::string& spec) {
    const auto& names = c.asset_names();
    std::vector<size_t> same;
    for (size_t i = 0; i < names.size(); ++i)
        if (names[i] == spec) same.push_back(i);
    if (same.size() == 1) return int(same[0]);
    if (same.size() > 1) {  // never the first of several silently
        std::string list;
        for (size_t k = 0; k < same.size(); ++k) list += (k ? ", " : "") + std::to_string(same[k]);
        throw Error("--publish " + spec + ": " + std::to_string(same.size()) + " assets of the catalogue have that name (indices " +
                    list + "): give the index instead");
    }
    char* end = nullptr;
    const long i = std::strtol(spec.c_str(), &end, 10);
    if (end && *end == 0 && !spec.empty() && i >= 0 && size_t(i) < names.size()) return int(i);
    std::string all;
    for (size_t k = 0; k < names.size(); ++k) all += (k ? ", " : "") + names[k];
    throw Error("--publish " + spec + ": the server has no such asset (catalogue: " + all + ")");
}

uint64_t now_us64() { return uint64_t(now_seconds() * 1e6); }

ClientConfig client_config(const ClientOptions& opt) {
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
    return cfg;
}

// The rate of the last full second of a Client's per-second bins, kbit/s.
double last_second_kbps(const Client& client) {
    const auto bins = client.stats().per_second_bytes;
    return bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : 0.0;
}

// A run of progskin-client: the Client, its publishers and what was displayed.
class Run {
public:
    explicit Run(const ClientOptions& opt) : opt_(opt), client_(client_config(opt)) {
        std::vector<ServerAddress> servers{{opt.host, opt.port}};
        servers.insert(servers.end(), opt.failover.begin(), opt.failover.end());
        client_.connect(servers);
        if (opt.send_view) client_.set_view(opt.view);
        t_start_ = now_seconds();
    }

    ClientReport run() {
        try {
            loop();
        } catch (const std::exception& e) {
            // What was received until now is reported with the reason (never lost).
            rep_.error = e.what();
            rep_.server_goodbye = client_.fail_reason() == FailReason::SessionEnded;
            finish(false);
            throw ClientRunError(e.what(), rep_);
        }
        finish(true);
        return rep_;
    }

private:
    void loop() {
        for (;;) {
            const double now = now_seconds();
            client_.update(now);
            check_events();
            if (pubs_.empty() && !opt_.publish.empty() && catalogue_ready()) spawn_publishers();
            if (!pubs_.empty() && now >= next_publish_) publish(now);
            if (!stream_clock(now)) break;
            if (t_stream_ > 0) display(now);
            // Sleep until the next displayed frame (the game loop of this program).
            const double next = now + 1.0 / opt_.display_rate;
            const double wait = next - now_seconds();
            if (wait > 0) std::this_thread::sleep_for(std::chrono::duration<double>(wait));
        }
    }

    // The report of what was received; `clean`: the run reached its end
    // (its characters are despawned first).
    void finish(bool clean) {
        if (clean) {
            for (Published& p : pubs_) client_.despawn(p.handle);
            client_.update(now_seconds());
        }
        const ClientStats st = client_.stats();
        client_.close("done");
        rep_.seconds = t_stream_ > 0 ? now_seconds() - t_stream_ : 0;
        report_stream(st);
        report_instances();
    }

    void check_events() {
        if (client_.state() == ClientState::Failed) throw Error(client_.error());
        if (client_.state() == ClientState::Closed) throw Error("the session closed");
        for (const ClientEvent& e : client_.events()) {
            if (e.type == ClientEvent::Type::AssetFailed) asset_failed(e);
            if (e.type == ClientEvent::Type::SpawnRefused)
                throw Error("the server refused to spawn " + (e.asset >= 0 && size_t(e.asset) < client_.asset_names().size()
                                                                  ? client_.asset_names()[size_t(e.asset)]
                                                                  : std::string("a character")) +
                            ": " + e.text);
        }
    }

    // An asset this client cannot load: said on stderr, reported; the session goes on.
    void asset_failed(const ClientEvent& e) {
        const std::string name =
            e.asset >= 0 && size_t(e.asset) < client_.asset_names().size() ? client_.asset_names()[size_t(e.asset)] : "?";
        std::fprintf(stderr, "progskin-client: %s (its characters are not shown; the others are)\n", e.text.c_str());
        rep_.assets_failed.emplace_back(name, e.text);
        failed_assets_.push_back(e.asset);
    }
    bool asset_failed(int i) const { return std::find(failed_assets_.begin(), failed_assets_.end(), i) != failed_assets_.end(); }

    // Every asset loaded or failed.
    bool catalogue_ready() const {
        if (client_.asset_names().empty()) return false;
        for (size_t i = 0; i < client_.assets().size(); ++i)
            if (!client_.assets()[i] && !asset_failed(int(i))) return false;
        return true;
    }

    // Spawns the --publish characters (once the catalogue is ready).
    void spawn_publishers() {
        int k = 0;
        for (const PublishOptions& po : opt_.publish) {
            Published p;
            p.opt = po;
            p.asset = find_asset(client_, po.asset);
            if (asset_failed(p.asset))
                throw Error("--publish " + po.asset + ": this client could not load that asset");
            const ClientAsset& a = *client_.assets()[size_t(p.asset)];
            p.selection = po.clip.empty() ? select_clips(a.character, "all") : select_clips(a.character, po.clip);
            const double diag = a.diagonal;
            p.walk_radius = po.walk * diag;
            p.walk_speed = po.walk > 0 ? 0.75 * diag : 0.0;  // about 1.4 m/s for a 1.9 m character
            // Publishers of one client walk around different centres.
            p.center = glm::dvec3(double(k) * 3.0 * diag, 0.0, 0.0);
            p.start_us = now_us64();
            p.handle = client_.spawn({.asset = p.asset,
                                      .clips = p.selection.clips,
                                      .start_us = p.start_us,
                                      .walk_center = p.center,
                                      .walk_radius = p.walk_radius,
                                      .walk_speed = p.walk_speed,
                                      .position = glm::vec3(walk_root(p.center, p.walk_radius, p.walk_speed, 0.0).position)});
            p.mats.resize(a.character.joint_count());
            p.skin.resize(a.character.joint_count());
            p.morphs.resize(a.character.morphs.size());
            pubs_.push_back(std::move(p));
            ++k;
        }
        rep_.published = int(pubs_.size());
    }

    // The pose of every published character (at publish_rate).
    void publish(double now) {
        next_publish_ = std::max(next_publish_ + 1.0 / opt_.publish_rate, now - 0.5 / opt_.publish_rate);
        for (Published& p : pubs_) {
            const ClientAsset& a = *client_.assets()[size_t(p.asset)];
            const uint64_t t_us = now_us64();
            const double t = double(int64_t(t_us - p.start_us)) * 1e-6;
            sample_skinning_matrices(a.character, p.selection, p.selection.looped(t), p.mats);
            for (size_t j = 0; j < p.mats.size(); ++j) p.skin[j] = Mat34::from_glm(p.mats[j]);
            RootPose root = walk_root(p.center, p.walk_radius, p.walk_speed, t);
            root.source_us = t_us;
            if (!p.morphs.empty()) sample_morph_weights(a.character, p.selection, p.selection.looped(t), p.morphs);
            client_.publish(p.handle, root, p.skin, false,
                            std::span<const float>(p.morphs).first(std::min<size_t>(p.morphs.size(), MAX_MORPHS)));
        }
    }

    // Streaming time counts from the first character displayed, or for a
    // publisher from the bound stream (it may be alone in the world). Throws
    // when nothing comes; false once options.duration has passed; applies
    // the cap schedule.
    bool stream_clock(double now) {
        bool any = false;
        for (const auto& c : client_.characters()) any = any || c.shown;
        const bool streaming = client_.state() == ClientState::Streaming;
        if (t_stream_ == 0 && (any || (streaming && rep_.published > 0))) {
            t_stream_ = now;
            end_time_ = now + opt_.duration;
            next_snapshot_ = now;
        }
        if (t_stream_ == 0 && streaming && now - t_start_ > opt_.connect_timeout)
            throw Error("no frames received from the server's UDP port");
        if (t_stream_ == 0 && now - t_start_ > opt_.connect_timeout + 600.0) throw Error("no frames received from the server");
        if (t_stream_ > 0 && now >= end_time_) return false;
        if (t_stream_ > 0 && cap_index_ < opt_.cap_schedule.size() && now - t_stream_ >= opt_.cap_schedule[cap_index_].first) {
            client_.set_max_kbps(opt_.cap_schedule[cap_index_].second);
            ++cap_index_;
        }
        return true;
    }

    // Statistics of this displayed frame, a snapshot when due, the verbose line.
    void display(double now) {
        const auto chars = client_.characters();
        const bool warm = now - t_stream_ >= opt_.warmup;
        const bool verify_now = opt_.verify && verify_this(display_count_, size_t(std::max(1, opt_.verify_every)));
        ++display_count_;
        for (const RemoteCharacter& c : chars) {
            Acc& a = acc_[c.instance];
            a.received = a.received || c.shown;
            a.asset = c.asset ? c.asset->name : "";
            a.published = c.publisher.published;
            if (!c.shown || !warm) continue;
            a.k_sum += c.bones;
            a.k_min = std::min(a.k_min, c.bones);
            a.k_max = std::max(a.k_max, c.bones);
            ++a.frames;
            if (c.publisher.published) latencies_.push_back((now - double(c.root.source_us) * 1e-6) * 1000.0);
            // The reference: the clip it plays; a server-driven instance
            // without a clip holds its rest pose. A player's character
            // without announced clips has no reference (its live pose).
            if (verify_now && (!c.clip.selection.clips.empty() || !c.publisher.published)) verify(c, a);
        }
        if (opt_.on_snapshot && opt_.snapshot_every > 0 && warm && now >= next_snapshot_) snapshot(now, chars);
        if (opt_.verbose && display_count_ % size_t(std::max(1.0, opt_.display_rate)) == 0) {
            char err[96] = "";
            if (sec_n_ > 0)  // --verify: the displayed error since the line before
                std::snprintf(err, sizeof err, ", error RMS %.4f%% max %.4f%%", std::sqrt(sec_sq_ / sec_n_), sec_max_);
            std::fprintf(stderr, "progskin-client: %.1f s, %.1f kbit/s last second, %zu characters%s\n", now - t_stream_,
                         last_second_kbps(client_), chars.size(), err);
            sec_sq_ = sec_n_ = sec_max_ = 0;
        }
    }

    // --verify-every n: every n-th displayed frame, the phase moving on by
    // one every n verified frames. A fixed phase would verify a stream that
    // sends every n ticks (or every divisor or multiple of n) only at its
    // sent ticks, or only between them, whichever the clocks' offset gives
    // (docs/performance.md "Every displayed tick verified").
    static bool verify_this(size_t frame, size_t n) { return n <= 1 || frame % n == (frame / (n * n)) % n; }

    // The displayed vertices of c against its reference, in world space
    // (docs/metrics.md §2): a server-driven clip at the displayed tick's clip
    // time; a published character at its publisher's source time, root included.
    void verify(const RemoteCharacter& c, Acc& a) {
        const Character& ch = c.asset->character;
        shown_.resize(ch.vertex_count());
        {
            // glTF: morph targets on the bind positions (the streamed weights), then the skin.
            SkinningJob sj = skinning_job(ch, c.asset->skin, c.palette, shown_);
            if (!ch.morphs.empty() && c.morph_weights.size() == ch.morphs.size()) {
                morphed_.resize(ch.vertex_count());
                morph_positions(ch, c.morph_weights, morphed_);
                sj.positions = morphed_;
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
            clip_t = c.clip.clip_time(c.pose_tick, client_.tick_rate());
            ref_root = c.root;
        }
        reference(ch, c.clip.selection, clip_t);
        const double scale = 100.0 / c.asset->diagonal;
        double jump = 0;
        if (a.prev_err.size() != shown_.size()) a.prev_err.assign(shown_.size(), glm::vec3(0.0f));
        const glm::dquat qs(c.root.rotation), qr(ref_root.rotation);
        for (size_t j = 0; j < shown_.size(); ++j) {
            // World space: each side placed by its own root.
            const glm::dvec3 ws = c.root.position + qs * glm::dvec3(shown_[j]);
            const glm::dvec3 wr = ref_root.position + qr * glm::dvec3(ref_[j]);
            const glm::vec3 e = glm::vec3(ws - wr);
            const double pct = glm::length(e) * scale;
            a.sq += pct * pct;
            a.max = std::max(a.max, pct);
            sec_sq_ += pct * pct;
            sec_max_ = std::max(sec_max_, pct);
            if (a.has_prev) jump = std::max(jump, double(glm::length(e - a.prev_err[j])) * scale);
            a.prev_err[j] = e;
        }
        a.n += double(shown_.size());
        sec_n_ += double(shown_.size());
        a.has_prev = opt_.verify_every <= 1;
        a.jump = std::max(a.jump, jump);
    }

    // ref_: the full-detail vertices of the selection at clip time t.
    void reference(const Character& ch, const ClipSelection& selection, double clip_t) {
        ref_mats_.resize(ch.joint_count());
        ref_pal_.resize(ch.joint_count());
        sample_skinning_matrices(ch, selection, clip_t, ref_mats_);
        for (size_t j = 0; j < ch.joint_count(); ++j) ref_pal_[j] = Mat34::from_glm(ref_mats_[j]);
        ref_.resize(ch.vertex_count());
        // docs/metrics.md §2 reference: the morph targets at the clip's weights, then the skin.
        SkinningJob rj = skinning_job(ch, ref_pal_, ref_);
        if (!ch.morphs.empty()) {
            ref_weights_.resize(ch.morphs.size());
            sample_morph_weights(ch, selection, clip_t, ref_weights_);
            ref_morphed_.resize(ch.vertex_count());
            morph_positions(ch, ref_weights_, ref_morphed_);
            rj.positions = ref_morphed_;
        }
        rj.run();
    }

    void snapshot(double now, std::span<const RemoteCharacter> chars) {
        next_snapshot_ = now + opt_.snapshot_every;
        DisplaySnapshot snap;
        snap.seconds = now - t_stream_;
        snap.rate_kbps = last_second_kbps(client_);
        for (const RemoteCharacter& c : chars)
            if (c.shown)
                snap.characters.push_back({c.instance, &c.asset->character, &c.asset->skin, &c.asset->stream, c.palette,
                                           glm::vec3(c.root.position), c.bones, c.morph_weights});
        if (!snap.characters.empty()) opt_.on_snapshot(snap);
    }

    // What the Client counted: datagrams, rates per full second, downloads.
    void report_stream(const ClientStats& st) {
        rep_.datagrams = st.datagrams;
        rep_.malformed = st.malformed;
        rep_.duplicates = st.duplicates;
        rep_.predicted_records = st.predicted_records;
        rep_.missing_baselines = st.missing_baselines;
        rep_.loss = st.loss;
        rep_.rtt_ms = st.rtt_ms;
        rep_.estimate_kbps = st.estimate_kbps;
        rep_.delay_ms = st.delay_ms;
        rep_.asset_bytes_downloaded = st.asset_bytes_downloaded;
        rep_.assets_cached = st.assets_cached;
        rep_.download_seconds = st.download_seconds;
        rep_.poses_sent = st.poses_sent;
        rep_.poses_predicted = st.poses_predicted;
        rep_.pose_kbps = st.seconds > 0 ? double(st.pose_wire_bytes) * 8.0 / 1000.0 / st.seconds : 0.0;
        rep_.max_gap_ms = st.max_gap_ms;
        rep_.failovers = st.failovers;
        rep_.failover_seconds_to_stream = st.failover_seconds;
        const double stream_seconds = st.seconds;
        double total = 0;
        for (size_t i = 0; i < st.per_second_bytes.size(); ++i) {
            total += st.per_second_bytes[i];
            if (i + 1 < st.per_second_bytes.size() && double(i + 1) <= stream_seconds) {  // full one-second bins
                rep_.per_second_kbps.push_back(st.per_second_bytes[i] * 8 / 1000);
                rep_.rate_max_kbps = std::max(rep_.rate_max_kbps, st.per_second_bytes[i] * 8 / 1000);
            }
        }
        rep_.rate_kbps = stream_seconds > 0 ? total * 8 / 1000 / stream_seconds : 0;
    }

    // What was displayed: per instance, then over all (and over the remote
    // published ones), and the latency percentiles.
    void report_instances() {
        double kmin = 1e9, kmax = 0, ksum = 0, all_sq = 0, all_n = 0, all_max = 0, r_sq = 0, r_n = 0, r_max = 0;
        int counted = 0;
        for (const auto& [id, a] : acc_) {
            InstanceReport ir;
            ir.instance = id;
            ir.asset = a.asset;
            ir.frames = a.frames;
            ir.published = a.published;
            if (a.received) ++rep_.characters;
            if (a.published && a.received) ++rep_.remote_characters;
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
                rep_.max_jump_pct = std::max(rep_.max_jump_pct, a.jump);
                if (a.published) {
                    r_sq += a.sq;
                    r_n += a.n;
                    r_max = std::max(r_max, a.max);
                }
            }
            rep_.instances.push_back(ir);
        }
        rep_.bones_mean = counted ? ksum / counted : 0;
        rep_.bones_min = counted ? kmin : 0;
        rep_.bones_max = counted ? kmax : 0;
        if (all_n > 0) {
            rep_.rms_pct = std::sqrt(all_sq / all_n);
            rep_.max_pct = all_max;
        }
        if (r_n > 0) {
            rep_.remote_rms_pct = std::sqrt(r_sq / r_n);
            rep_.remote_max_pct = r_max;
        }
        if (!latencies_.empty()) {
            std::sort(latencies_.begin(), latencies_.end());
            rep_.latency_ms_p50 = latencies_[latencies_.size() / 2];
            rep_.latency_ms_p99 = latencies_[std::min(latencies_.size() - 1, size_t(double(latencies_.size()) * 0.99))];
        }
    }

    const ClientOptions& opt_;
    Client client_;
    ClientReport rep_;
    std::vector<Published> pubs_;
    size_t cap_index_ = 0;
    double t_stream_ = 0, end_time_ = 0, next_snapshot_ = 0, next_publish_ = 0;
    uint64_t display_count_ = 0;
    double sec_sq_ = 0, sec_n_ = 0, sec_max_ = 0;  // --verbose with --verify: the error since the last line
    double t_start_ = 0;  // connect() returned
    std::map<int, Acc> acc_;  // by instance id
    std::vector<int> failed_assets_;  // catalogue indices (AssetFailed)
    std::vector<double> latencies_;
    std::vector<glm::vec3> shown_, ref_, morphed_, ref_morphed_;
    std::vector<float> ref_weights_;
    std::vector<glm::dmat4> ref_mats_;
    std::vector<Mat34> ref_pal_;
};

}  // namespace

ClientReport run_client(const ClientOptions& opt) { return Run(opt).run(); }

// s as a JSON string literal (quotes, backslashes and control characters escaped).
static std::string json_string(const std::string& s) {
    std::string o = "\"";
    for (const char ch : s) {
        const unsigned char c = static_cast<unsigned char>(ch);
        if (c == '"' || c == '\\') o += '\\', o += ch;
        else if (c < 0x20) {
            char b[8];
            std::snprintf(b, sizeof b, "\\u%04x", c);
            o += b;
        } else o += ch;
    }
    return o + "\"";
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
    o << ", \"rate_max_kbps\": " << r.rate_max_kbps << ", \"max_gap_ms\": " << r.max_gap_ms << ", \"max_jump_pct\": " << r.max_jump_pct
      << ", \"delay_ms_max\": " << r.delay_ms << ", \"rtt_ms\": " << r.rtt_ms << ", \"estimate_kbps\": " << r.estimate_kbps
      << ", \"malformed\": " << r.malformed << ", \"duplicates\": " << r.duplicates
      << ", \"predicted_records\": " << r.predicted_records << ", \"missing_baselines\": " << r.missing_baselines
      << ", \"asset_bytes_downloaded\": " << r.asset_bytes_downloaded << ", \"assets_cached\": " << r.assets_cached << ", \"download_seconds\": " << r.download_seconds
      << ", \"published\": " << r.published << ", \"poses_sent\": " << r.poses_sent
      << ", \"poses_predicted\": " << r.poses_predicted << ", \"pose_kbps\": " << r.pose_kbps << ", \"remote\": {\"characters\": "
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
        o << (i ? ", " : "") << "{\"instance\": " << x.instance << ", \"asset\": " << json_string(x.asset) << ", \"bones_mean\": " << x.bones_mean
          << ", \"bones_min\": " << x.bones_min << ", \"bones_max\": " << x.bones_max << ", \"rms_pct\": ";
        num_or_null(o, x.rms_pct);
        o << ", \"max_pct\": ";
        num_or_null(o, x.max_pct);
        o << ", \"max_jump_pct\": ";
        num_or_null(o, x.max_jump_pct);
        o << ", \"frames\": " << x.frames
          << ", \"published\": " << (x.published ? "true" : "false") << "}";
    }
    o << "], \"assets_failed\": [";
    for (size_t i = 0; i < r.assets_failed.size(); ++i)
        o << (i ? ", " : "") << "{\"asset\": " << json_string(r.assets_failed[i].first)
          << ", \"error\": " << json_string(r.assets_failed[i].second) << "}";
    o << "], \"failover\": {\"count\": " << r.failovers << ", \"seconds_to_stream\": " << r.failover_seconds_to_stream << "}";
    o << ", \"error\": " << json_string(r.error) << ", \"server_goodbye\": " << (r.server_goodbye ? "true" : "false") << "}";
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
    if (r.failovers > 0) {
        std::snprintf(b, sizeof b, "; %d failovers (streaming again within %.2f s)", r.failovers, r.failover_seconds_to_stream);
        s += b;
    }
    return s + "\n";
}

}  // namespace progskin::net
