// scene.cpp — see scene.h.
#include "scene.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <unistd.h>

#include "errors.h"
#include "error_metric.h"
#include "gltf_export.h"
#include "gltf_import.h"
#include "progressive_skin.h"
#include "scratch_build.h"
#include "skinning.h"
#include "vertex_animation.h"
#include "wire.h"

namespace progskin::net {

namespace fs = std::filesystem;

static std::vector<uint8_t> read_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open");
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

std::vector<HullStep> error_hull(const std::vector<double>& err) {
    // Points (k, e(k)) for k = 1..B; lower convex hull from k = 1 (monotone chain).
    std::vector<HullStep> steps;
    const int B = int(err.size());
    if (B <= 1) return steps;
    std::vector<int> h;  // hull vertex ks
    auto e = [&](int k) { return err[size_t(k - 1)]; };
    for (int k = 1; k <= B; ++k) {
        while (h.size() >= 2) {
            int a = h[h.size() - 2], b = h.back();
            // b is above segment a-k (or on it): drop it
            double cross = (b - a) * (e(k) - e(a)) - (k - a) * (e(b) - e(a));
            if (cross <= 0) h.pop_back();
            else break;
        }
        h.push_back(k);
    }
    for (size_t i = 1; i < h.size(); ++i)
        steps.push_back({h[i - 1], h[i], std::max(0.0, e(h[i - 1]) - e(h[i]))});
    return steps;
}

double ServerAsset::Segment::gap_at(int model, double g) const {
    const auto& t = gap[size_t(model)];
    const int last = kGapTable - 1;
    if (g <= 1) return 0;
    if (g >= last) return t[last] * (g / last) * (g / last);
    const int i = int(g);
    return t[size_t(i)] + (t[size_t(i + 1)] - t[size_t(i)]) * (g - i);
}

// Segments of the scheduler's cost model (scene.h): the hull of e(k)^2; per
// segment and clip selection, the collapse error over the selection's frames
// and the interpolation error over gaps of 2..16 frames, sampled at a quarter,
// half and three quarters of the gap from up to 24 start frames per selection.
static void build_segments(ServerAsset& a, const FrameSet& frames) {
    const Character& c = a.character;
    const ProgressiveSkin& s = a.skin;
    const size_t M = a.selections.size() + 1;  // models: selections, then all
    std::vector<double> mse;
    for (const auto& e : s.error) mse.push_back(e.rms * e.rms);
    std::vector<std::vector<double>> sel_mse(M);
    for (size_t m = 0; m + 1 < M; ++m)
        for (const auto& e : evaluate_error_table(c, s, sample_frames(c, {a.selections[m]}, 30.0))) sel_mse[m].push_back(e.rms * e.rms);
    sel_mse[M - 1] = mse;
    a.segments.clear();
    ServerAsset::Segment root;
    root.from = 0;
    root.to = 1;
    for (size_t m = 0; m < M; ++m) {
        const double e1 = sel_mse[m].empty() ? 0.0 : std::sqrt(sel_mse[m][0]);
        root.collapse.push_back((a.diagonal + e1) * (a.diagonal + e1));
    }
    a.segments.push_back(root);
    for (const HullStep& h : error_hull(mse)) {
        ServerAsset::Segment seg;
        seg.from = h.from;
        seg.to = h.to;
        for (size_t m = 0; m < M; ++m)
            seg.collapse.push_back(sel_mse[m].size() >= size_t(h.to)
                                       ? std::max(0.0, sel_mse[m][size_t(h.from - 1)] - sel_mse[m][size_t(h.to - 1)])
                                       : h.gain);
        a.segments.push_back(seg);
    }
    const size_t S = a.segments.size(), V = c.vertex_count(), J = c.joint_count();
    for (auto& seg : a.segments) seg.gap.assign(M, {});
    std::vector<int> seg_of_joint(J, 0);
    for (size_t g = 0; g < S; ++g)
        for (int b = a.segments[g].from; b < a.segments[g].to; ++b) seg_of_joint[size_t(s.order[size_t(b)])] = int(g);

    const int I = c.influences;
    std::vector<Mat34> diff(J);
    std::vector<BonePose> p0(J), pa(J), pb(J), p3(J);  // the frames around an interval, per joint
    std::vector<double> sum(S * M), samples(M), all(M);
    std::vector<size_t> sel_frames(M - 1, 0);
    for (int x : frames.selection_of_frame)
        if (x >= 0 && size_t(x) + 1 < M) ++sel_frames[size_t(x)];
    for (int g = 2; g < ServerAsset::kGapTable; ++g) {
        std::fill(sum.begin(), sum.end(), 0.0);
        std::fill(samples.begin(), samples.end(), 0.0);
        std::fill(all.begin(), all.end(), 0.0);
        for (size_t f = 0; f + size_t(g) < frames.frame_count(); ++f) {
            const int sel = frames.selection_of_frame[f];
            if (sel < 0 || size_t(sel) + 1 >= M || sel != frames.selection_of_frame[f + size_t(g)]) continue;
            if (f % std::max<size_t>(1, sel_frames[size_t(sel)] / 24) != 0) continue;
            // What the client does: cubic over the neighbours f - g and f + 2g
            // when they exist (same clip), else slerp/lerp.
            const bool cubic = f >= size_t(g) && f + 2 * size_t(g) < frames.frame_count() &&
                               frames.selection_of_frame[f - size_t(g)] == sel &&
                               frames.selection_of_frame[f + 2 * size_t(g)] == sel;
            for (size_t j = 0; j < J; ++j) {
                pa[j] = decompose(frames.frame(f)[j]);
                pb[j] = decompose(frames.frame(f + size_t(g))[j]);
                if (cubic) {
                    p0[j] = decompose(frames.frame(f - size_t(g))[j]);
                    p3[j] = decompose(frames.frame(f + 2 * size_t(g))[j]);
                }
            }
            int prev_h = 0;
            for (int q = 1; q <= 3; ++q) {
                const int h = std::clamp(int(std::lround(g * q / 4.0)), 1, g - 1);
                if (h == prev_h) continue;
                prev_h = h;
                const float alpha = float(h) / float(g);
                for (size_t j = 0; j < J; ++j) {
                    const Mat34 mm = compose(cubic ? interpolate_cubic(p0[j], pa[j], pb[j], p3[j], -double(g), 0.0, double(g),
                                                                       2.0 * g, double(h))
                                                   : interpolate(pa[j], pb[j], alpha));
                    for (int x = 0; x < 12; ++x) diff[j].m[x] = mm.m[x] - frames.frame(f + size_t(h))[j].m[x];
                }
                double* out = sum.data() + size_t(sel) * S;
                for (size_t v = 0; v < V; ++v) {
                    const glm::vec3 p = c.positions[v];
                    glm::vec3 err[8];
                    int segs[8], n = 0;
                    for (int k = 0; k < I && k < 8; ++k) {
                        const float w = c.weights[v * size_t(I) + size_t(k)];
                        if (w == 0.0f) continue;
                        const int j = c.joints[v * size_t(I) + size_t(k)];
                        const float* d = diff[size_t(j)].m;
                        glm::vec3 e{d[0] * p.x + d[1] * p.y + d[2] * p.z + d[3], d[4] * p.x + d[5] * p.y + d[6] * p.z + d[7],
                                    d[8] * p.x + d[9] * p.y + d[10] * p.z + d[11]};
                        int at = 0;
                        while (at < n && segs[at] != seg_of_joint[size_t(j)]) ++at;
                        if (at == n) {
                            segs[n] = seg_of_joint[size_t(j)];
                            err[n++] = glm::vec3(0.0f);
                        }
                        err[at] += w * e;
                    }
                    glm::vec3 total(0.0f);
                    for (int k = 0; k < n; ++k) {
                        out[size_t(segs[k])] += double(glm::dot(err[k], err[k]));
                        total += err[k];
                    }
                    all[size_t(sel)] += double(glm::dot(total, total));
                }
                samples[size_t(sel)] += double(V);
            }
        }
        for (size_t m = 0; m + 1 < M; ++m) {
            samples[M - 1] += samples[m];
            all[M - 1] += all[m];
            for (size_t q = 0; q < S; ++q) sum[(M - 1) * S + q] += sum[m * S + q];
        }
        for (size_t m = 0; m < M; ++m) {
            // Errors of bones that move together add up: scale the segments'
            // errors so that they sum to the error of all bones interpolated.
            double parts = 0;
            for (size_t q = 0; q < S; ++q) parts += sum[m * S + q];
            const double k = parts > 0 ? all[m] / parts : 1.0;
            for (size_t q = 0; q < S; ++q) sum[m * S + q] *= k;
        }
        for (size_t m = 0; m < M; ++m)
            for (size_t q = 0; q < S; ++q) {
                // Clips shorter than the gap: grow from the previous gap as g^2.
                auto& t = a.segments[q].gap[m];
                t[size_t(g)] = samples[m] > 0 ? sum[m * S + q] / samples[m] * double(g - 1) / double(g)
                                              : t[size_t(g - 1)] * double(g * g) / double((g - 1) * (g - 1));
            }
    }
    for (auto& seg : a.segments) {
        seg.refresh.assign(M, {});
        seg.show_value.assign(M, 0.0);
        for (size_t m = 0; m < M; ++m) {
            for (int x = 1; x < ServerAsset::kGapTable; ++x)
                seg.refresh[m][size_t(x)] = x * (x + 1.0) * (seg.gap_at(int(m), x + 1.0) - seg.gap_at(int(m), x));
            for (int p = 1; p < HOLD_TICKS; ++p)
                seg.show_value[m] = std::max(seg.show_value[m], p * (seg.collapse[m] - seg.gap[m][size_t(p)]));
        }
    }
}

void finish_server_asset(ServerAsset& a) {
    const Character& c = a.character;
    const ProgressiveSkin& s = a.skin;
    if (s.bone_count() < 1 || s.bone_count() > MAX_BONES)
        throw Error(a.path + ": " + std::to_string(s.bone_count()) + " bones (1.." + std::to_string(MAX_BONES) + " streamable)");
    a.diagonal = s.diagonal > 0 ? s.diagonal : rest_diagonal(c);
    if (!(a.diagonal > 0)) a.diagonal = 1;
    a.bind_radius = 0;
    for (const auto& p : c.positions) a.bind_radius = std::max(a.bind_radius, double(glm::length(p)));

    if (a.selections.empty()) a.selections = default_training_set(c);
    if (a.selections.empty()) a.selections.push_back(ClipSelection{});
    FrameSet frames = sample_frames(c, a.selections, 30.0);

    // Translation box and scale range of the skinning matrices.
    glm::vec3 lo(1e30f), hi(-1e30f);
    bool scaled = false;
    a.max_scale = 1;
    for (size_t f = 0; f < frames.frame_count(); ++f) {
        const Mat34* m = frames.frame(f);
        for (int j = 0; j < frames.joint_count; ++j) {
            glm::vec3 t{m[j].m[3], m[j].m[7], m[j].m[11]};
            lo = glm::min(lo, t);
            hi = glm::max(hi, t);
            BonePose p = decompose(m[j]);
            if (std::fabs(p.s - 1.0f) > 1e-4f) scaled = true;
            a.max_scale = std::max(a.max_scale, double(p.s));
        }
    }
    glm::vec3 ext = hi - lo;
    glm::vec3 margin = ext * 0.25f + glm::vec3(float(0.05 * a.diagonal));
    a.format.t_min = lo - margin;
    a.format.t_max = hi + margin;
    a.format.scaled = scaled;

    // RMS vertex motion per second between consecutive frames of one selection.
    std::vector<glm::vec3> p0(c.vertex_count()), p1(c.vertex_count());
    double sum = 0, n = 0;
    for (size_t f = 0; f + 1 < frames.frame_count(); ++f) {
        if (frames.selection_of_frame[f] != frames.selection_of_frame[f + 1]) continue;
        reference_positions(c, frames, f, p0);
        reference_positions(c, frames, f + 1, p1);
        double dt = frames.times[f + 1] - frames.times[f];
        if (!(dt > 0)) continue;
        for (size_t v = 0; v < p0.size(); ++v) {
            double d = glm::length(p1[v] - p0[v]) / dt;
            sum += d * d;
        }
        n += double(p0.size());
        if (n > 2e6) break;  // enough for an estimate
    }
    a.motion = n > 0 ? std::sqrt(sum / n) : 0.0;

    build_segments(a, frames);
}

// Morph targets: their importance (the scheduler's value of a weight) and a
// warning for the targets past what the wire carries (uint8 index).
static void prepare_morphs(ServerAsset& a, const std::string& path) {
    a.morph_importance = morph_importance(a.character);
    if (a.character.morphs.size() > size_t(MAX_MORPHS))
        a.warnings.push_back(path + ": " + std::to_string(a.character.morphs.size()) + " morph targets; only the first " +
                             std::to_string(MAX_MORPHS) + " are streamed (the others stay at weight 0)");
}

std::shared_ptr<ServerAsset> load_server_asset(const std::string& path) {
    auto a = std::make_shared<ServerAsset>();
    a->path = path;
    a->name = fs::path(path).filename().string();
    a->bytes = read_file(path);
    a->id = content_hash(a->bytes);
    ProgressiveAsset pa = load_progressive(path);
    a->character = std::move(pa.character);
    a->selections = default_training_set(a->character);
    if (pa.progressive && pa.skin.bone_count() == int(a->character.joint_count())) {
        a->skin = std::move(pa.skin);  // progressive glTF: joints already in progressive order
        a->progressive_file = true;
    } else {
        a->skin = build_progressive_skin(a->character, sample_frames(a->character, a->selections, 30.0));
    }
    prepare_morphs(*a, path);
    finish_server_asset(*a);
    return a;
}

namespace {

// x to 7 significant digits: the tables are a cost model, and the shortest
// decimal of the rounded value takes half the bytes of a full double.
double round7(double x) {
    if (x == 0 || !std::isfinite(x)) return x;
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.7g", x);
    return std::strtod(buf, nullptr);
}

nlohmann::json vec3_json(const glm::vec3& v) { return nlohmann::json::array({v.x, v.y, v.z}); }

nlohmann::json numbers_json(const double* x, size_t n) {
    nlohmann::json a = nlohmann::json::array();
    for (size_t i = 0; i < n; ++i) a.push_back(round7(x[i]));
    return a;
}

template <size_t N>
nlohmann::json rows_json(const std::vector<std::array<double, N>>& rows) {
    nlohmann::json a = nlohmann::json::array();
    for (const auto& r : rows) a.push_back(numbers_json(r.data(), N));
    return a;
}

// Reads a JSON array of numbers of exactly n entries into out; false otherwise.
bool read_numbers(const nlohmann::json& j, size_t n, double* out) {
    if (!j.is_array() || j.size() != n) return false;
    for (size_t i = 0; i < n; ++i) {
        if (!j[i].is_number()) return false;
        out[i] = j[i].get<double>();
        if (!std::isfinite(out[i])) return false;
    }
    return true;
}

}  // namespace

nlohmann::json server_tables_json(const ServerAsset& a) {
    nlohmann::json j;
    j["version"] = kServerTablesVersion;
    j["fps"] = 30;
    j["hold_ticks"] = HOLD_TICKS;  // constants the tables were computed with
    j["gap_table"] = ServerAsset::kGapTable;
    j["selections"] = a.selections.size();
    j["bones"] = a.bone_count();
    j["diagonal"] = a.diagonal;
    j["motion"] = a.motion;
    j["bind_radius"] = a.bind_radius;
    j["max_scale"] = a.max_scale;
    j["format"] = {{"t_min", vec3_json(a.format.t_min)}, {"t_max", vec3_json(a.format.t_max)}, {"scaled", a.format.scaled}};
    j["segments"] = nlohmann::json::array();
    for (const ServerAsset::Segment& s : a.segments)
        j["segments"].push_back({{"from", s.from},
                                 {"to", s.to},
                                 {"collapse", numbers_json(s.collapse.data(), s.collapse.size())},
                                 {"gap", rows_json(s.gap)},
                                 {"refresh", rows_json(s.refresh)},
                                 {"show_value", numbers_json(s.show_value.data(), s.show_value.size())}});
    return j;
}

bool read_server_tables(const nlohmann::json& j, ServerAsset& a, std::string* why) {
    auto no = [&](const std::string& w) {
        if (why) *why = w;
        return false;
    };
    if (!j.is_object()) return no("no stored server tables");
    if (j.value("version", 0) != kServerTablesVersion)
        return no("stored server tables are version " + std::to_string(j.value("version", 0)) + ", this server uses " +
                  std::to_string(kServerTablesVersion));
    const size_t M = a.selections.size() + 1;
    if (j.value("bones", -1) != a.bone_count() || j.value("selections", size_t(0)) != a.selections.size() ||
        j.value("fps", 0) != 30)
        return no("stored server tables do not match the character (bones, clip groups or fps)");
    if (j.value("hold_ticks", -1) != HOLD_TICKS || j.value("gap_table", -1) != ServerAsset::kGapTable)
        return no("stored server tables were computed with another HOLD_TICKS or gap table size");
    ServerAsset t;  // parsed into a scratch copy: `a` changes only when everything reads
    double v[3];
    t.diagonal = j.value("diagonal", 0.0);
    t.motion = j.value("motion", -1.0);
    t.bind_radius = j.value("bind_radius", -1.0);
    t.max_scale = j.value("max_scale", 0.0);
    if (!(t.diagonal > 0) || !(t.motion >= 0) || !(t.bind_radius >= 0) || !(t.max_scale > 0))
        return no("stored server tables have a bad diagonal, motion, bind radius or scale");
    const nlohmann::json& f = j.contains("format") ? j["format"] : nlohmann::json();
    if (!f.is_object() || !read_numbers(f.value("t_min", nlohmann::json()), 3, v)) return no("bad stored format");
    t.format.t_min = glm::vec3(float(v[0]), float(v[1]), float(v[2]));
    if (!read_numbers(f.value("t_max", nlohmann::json()), 3, v)) return no("bad stored format");
    t.format.t_max = glm::vec3(float(v[0]), float(v[1]), float(v[2]));
    t.format.scaled = f.value("scaled", false);
    const nlohmann::json& segs = j.contains("segments") ? j["segments"] : nlohmann::json();
    if (!segs.is_array() || segs.empty()) return no("no stored segments");
    int expect_from = 0;
    for (const nlohmann::json& sj : segs) {
        ServerAsset::Segment s;
        s.from = sj.value("from", -1);
        s.to = sj.value("to", -1);
        if (s.from != expect_from || s.to <= s.from || s.to > a.bone_count()) return no("stored segments do not tile the bones");
        expect_from = s.to;
        s.collapse.resize(M);
        s.show_value.resize(M);
        s.gap.resize(M);
        s.refresh.resize(M);
        if (!read_numbers(sj.value("collapse", nlohmann::json()), M, s.collapse.data()) ||
            !read_numbers(sj.value("show_value", nlohmann::json()), M, s.show_value.data()))
            return no("bad stored segment values");
        const nlohmann::json gap = sj.value("gap", nlohmann::json()), refresh = sj.value("refresh", nlohmann::json());
        if (!gap.is_array() || gap.size() != M || !refresh.is_array() || refresh.size() != M)
            return no("bad stored segment tables");
        for (size_t m = 0; m < M; ++m)
            if (!read_numbers(gap[m], ServerAsset::kGapTable, s.gap[m].data()) ||
                !read_numbers(refresh[m], ServerAsset::kGapTable, s.refresh[m].data()))
                return no("bad stored segment tables");
        t.segments.push_back(std::move(s));
    }
    if (expect_from != a.bone_count()) return no("stored segments do not cover every bone");
    a.diagonal = t.diagonal;
    a.motion = t.motion;
    a.bind_radius = t.bind_radius;
    a.max_scale = t.max_scale;
    a.format = t.format;
    a.segments = std::move(t.segments);
    return true;
}

std::string server_cache_dir() {
    if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/progskin";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/progskin";
    return "progskin-cache";
}

namespace {

// An --asset argument split into the file and the character index (-1: all).
// "FILE#N" names character N unless FILE#N itself is an existing file.
std::pair<std::string, int> split_asset_arg(const std::string& arg) {
    const size_t hash = arg.rfind('#');
    if (hash == std::string::npos || hash + 1 == arg.size() || fs::exists(arg)) return {arg, -1};
    const std::string digits = arg.substr(hash + 1);
    if (digits.find_first_not_of("0123456789") != std::string::npos || digits.size() > 6) return {arg, -1};
    return {arg.substr(0, hash), std::stoi(digits)};
}

// Frames the default training set takes at 30 fps (sample_frames' count), without sampling.
double training_frames(const Character& c) {
    double n = 0;
    for (const ClipSelection& sel : default_training_set(c))
        n += std::floor(std::max(0.0, double(sel.end) - double(sel.start)) * 30.0 + 1e-6) + 1.0;
    return n;
}

// Size problems of one imported character ("" when it can be served).
std::string character_problem(const Character& c, const std::string& label) {
    if (c.joint_count() > size_t(MAX_BONES))
        return label + ": " + std::to_string(c.joint_count()) + " joints, at most " + std::to_string(MAX_BONES) +
               " can be streamed";
    if (c.vertex_count() == 0) return label + ": the skinned meshes have no vertices";
    const double frames = training_frames(c);
    if (frames > double(kMaxSampledFrames))
        return label + ": its clips span " + std::to_string(size_t(frames)) + " frames at 30 fps, more than " +
               std::to_string(kMaxSampledFrames);
    return {};
}

// The skins of a character (those its skinned primitives use), in file order.
std::vector<int> skins_of(const Character& c) {
    std::vector<int> skins;
    for (const PrimitiveRange& r : c.primitives)
        if (!r.rigid && r.skin >= 0 && std::find(skins.begin(), skins.end(), r.skin) == skins.end()) skins.push_back(r.skin);
    std::sort(skins.begin(), skins.end());
    return skins;
}

// Checks one --asset argument, appending its characters or its problems.
void check_one(const std::string& arg, const AssetOptions& o, std::vector<PendingAsset>& out,
               std::vector<std::string>& problems) {
    const auto [path, index] = split_asset_arg(arg);
    std::vector<Character> chars;
    try {
        if (!fs::exists(path)) {
            problems.push_back(path + ": no such file");
            return;
        }
        const bool pc2 = path.size() >= 4 && (path.compare(path.size() - 4, 4, ".pc2") == 0 ||
                                               path.compare(path.size() - 4, 4, ".PC2") == 0);
        if (!pc2) {
            ImportOptions io;
            io.require_skin = false;
            chars = import_gltf(path, io);
        } else if (!o.from_vertices) {
            problems.push_back(path + ": a PC2 point cache has no skin: build one with `progskin build --from-vertices " +
                               path + " -o OUT.glb` and serve OUT.glb, or start progskin-server with --from-vertices");
            return;
        }
    } catch (const std::exception& e) {
        problems.push_back(e.what());
        return;
    }
    const std::string base = fs::path(path).filename().string();
    if (chars.empty()) {
        if (!o.from_vertices) {
            problems.push_back(path + ": no skin (no mesh uses a skin): the server streams skinned characters; build one "
                               "from its vertex animation with `progskin build --from-vertices " + path +
                               " -o OUT.glb` and serve OUT.glb, or start progskin-server with --from-vertices");
            return;
        }
        try {
            const VertexAnimation anim = load_vertex_animation(path);
            if (anim.vertex_count == 0 || anim.frame_count == 0) {
                problems.push_back(path + ": --from-vertices: no vertices or no frames to build a skin from");
                return;
            }
        } catch (const std::exception& e) {
            problems.push_back(std::string(e.what()) + " (--from-vertices)");
            return;
        }
        PendingAsset p;
        p.path = path;
        p.label = base;
        p.from_vertices = true;
        out.push_back(std::move(p));
        return;
    }
    if (index >= int(chars.size())) {
        problems.push_back(path + ": no character " + std::to_string(index) + " (the file has " +
                           std::to_string(chars.size()) + (chars.size() == 1 ? " character)" : " characters)"));
        return;
    }
    for (int i = 0; i < int(chars.size()); ++i) {
        if (index >= 0 && i != index) continue;
        PendingAsset p;
        p.path = path;
        p.character = i;
        p.characters_in_file = int(chars.size());
        p.label = chars.size() > 1 ? base + "#" + std::to_string(i) : base;
        const std::string problem = character_problem(chars[size_t(i)], p.label);
        if (!problem.empty()) {
            problems.push_back(path + (chars.size() > 1 ? " character " + std::to_string(i) : std::string()) + ": " +
                               problem.substr(p.label.size() + 2));
            continue;
        }
        try {
            p.progressive = read_progressive_extension(path, chars[size_t(i)], p.skin, &p.extension);
        } catch (const std::exception& e) {
            problems.push_back(e.what());
            continue;
        }
        p.imported = std::move(chars[size_t(i)]);
        out.push_back(std::move(p));
    }
}

}  // namespace

std::vector<std::string> check_server_assets(const std::vector<std::string>& args, const AssetOptions& options,
                                             std::vector<PendingAsset>& out) {
    std::vector<std::string> problems;
    out.clear();
    for (const std::string& arg : args) check_one(arg, options, out, problems);
    return problems;
}

namespace {

// Cache file of a plain file's build: content hash of the file, character, table version.
std::string cached_build_path(const PendingAsset& p, const std::string& cache, const std::vector<uint8_t>& bytes) {
    return (fs::path(cache) / (hex64(content_hash(bytes)) + "-c" + std::to_string(p.character) + "-t" +
                               std::to_string(kServerTablesVersion) + ".glb"))
        .string();
}

// Reads a cached build (a progressive copy of the file with the server tables)
// into a: the skin with its order mapped back to the file's joints, the
// tables. False when absent or not matching (then nothing in `a` changed).
bool load_cached_build(const PendingAsset& p, const std::string& cache, ServerAsset& a) {
    const std::string path = cached_build_path(p, cache, read_file(p.path));
    if (!fs::exists(path)) return false;
    try {
        Character cached = import_character(path, p.character);
        ProgressiveSkin skin;
        nlohmann::json ext;
        if (!read_progressive_extension(path, cached, skin, &ext) || !ext.contains("server")) return false;
        const Character& c = a.character;
        if (cached.joint_count() != c.joint_count() || cached.vertex_count() != c.vertex_count()) return false;
        // Cached joint b (progressive order) is the file's joint with the same node and inverse bind matrix.
        std::vector<int> order(cached.joint_count(), -1);
        std::vector<char> used(c.joint_count(), 0);
        for (size_t b = 0; b < cached.joint_count(); ++b) {
            const int node = cached.nodes[size_t(cached.joint_node[b])].gltf_index;
            for (size_t j = 0; j < c.joint_count() && order[b] < 0; ++j) {
                if (used[j] || c.nodes[size_t(c.joint_node[j])].gltf_index != node) continue;
                double d = 0;
                for (int x = 0; x < 4; ++x)
                    for (int y = 0; y < 4; ++y) d = std::max(d, std::abs(c.inverse_bind[j][x][y] - cached.inverse_bind[b][x][y]));
                if (d > 1e-4 * std::max(1.0, a.diagonal)) continue;
                order[b] = int(j);
                used[j] = 1;
            }
            if (order[b] < 0) return false;
        }
        skin.order = order;
        ServerAsset t = a;
        t.skin = std::move(skin);
        if (!read_server_tables(ext["server"], t)) return false;
        a = std::move(t);
        return true;
    } catch (const std::exception&) {
        return false;  // a damaged cache entry is rebuilt
    }
}

// Writes the build of a plain file to the cache; a failure only costs the next start.
void save_cached_build(const PendingAsset& p, const std::string& cache, ServerAsset& a) {
    try {
        fs::create_directories(cache);
        nlohmann::json extra;
        extra["server"] = server_tables_json(a);
        save_progressive(a.character, a.skin, cached_build_path(p, cache, read_file(p.path)),
                         "cached build of " + fs::path(p.path).filename().string(), extra);
    } catch (const std::exception& e) {
        a.warnings.push_back(p.path + ": cannot cache the build in " + cache + ": " + e.what());
    }
}

// The cache directory, created; when it cannot be (a read-only home), a
// per-user directory under the system's temporary directory, with a warning.
std::string usable_cache(const std::string& wanted, std::vector<std::string>& warnings) {
    std::error_code ec;
    fs::create_directories(wanted, ec);
    if (!ec && fs::is_directory(wanted)) return wanted;
    const std::string fallback = (fs::temp_directory_path() / ("progskin-cache-" + std::to_string(::getuid()))).string();
    fs::create_directories(fallback, ec);
    if (ec) throw Error("cannot create the cache directory " + wanted + " nor " + fallback + ": " + ec.message());
    warnings.push_back("cache directory " + wanted + " cannot be created; using " + fallback);
    return fallback;
}

}  // namespace

std::shared_ptr<ServerAsset> build_server_asset(const PendingAsset& p, const AssetOptions& options) {
    auto a = std::make_shared<ServerAsset>();
    const std::string cache = usable_cache(options.cache_dir.empty() ? server_cache_dir() : options.cache_dir, a->warnings);
    a->name = p.label;
    if (p.from_vertices) {
        // Build (or reuse) the progressive file and serve it like any progressive file.
        const uint64_t hash = content_hash(read_file(p.path));
        fs::create_directories(cache);
        const std::string out = (fs::path(cache) / (hex64(hash) + "-scratch" + std::to_string(options.scratch_bones) +
                                                     ".glb")).string();
        if (!fs::exists(out)) {
            ScratchOptions so;
            so.max_bones = options.scratch_bones;
            save_scratch(build_from_vertices(load_vertex_animation(p.path), so), out);
        }
        a->path = out;
        a->bytes = read_file(out);
        ProgressiveAsset pa = load_progressive(out);
        if (!pa.progressive) throw Error(out + ": the built file has no progressive skin");
        a->character = std::move(pa.character);
        a->skin = std::move(pa.skin);
        a->progressive_file = true;
    } else {
        a->path = p.path;
        a->bytes = read_file(p.path);
        if (p.character > 0) {
            // A client plays character 0 of what it downloads: serve a copy with this character's skins first.
            fs::create_directories(cache);
            const std::string out = (fs::path(cache) / (hex64(content_hash(a->bytes)) + "-character" +
                                                         std::to_string(p.character) + ".glb")).string();
            if (!fs::exists(out)) write_with_skins_first(p.path, skins_of(p.imported), out);
            a->bytes = read_file(out);
        }
        a->character = p.imported;
        if (p.progressive) {
            a->skin = p.skin;
            a->progressive_file = true;
        }
    }
    a->id = content_hash(a->bytes);
    a->selections = default_training_set(a->character);
    if (a->selections.empty()) a->selections.push_back(ClipSelection{});
    std::string why;
    if (a->progressive_file) {
        const nlohmann::json* tables = p.extension.contains("server") ? &p.extension["server"] : nullptr;
        if (!p.from_vertices && !(tables && read_server_tables(*tables, *a, &why))) {
            a->warnings.push_back(p.path + ": " + (why.empty() ? "no stored server tables" : why) +
                                  ": computed at start (rebuild the file with progskin build to store them)");
            finish_server_asset(*a);
        } else if (p.from_vertices) {
            // The scratch file's tables are kept beside it (.tables.json) once computed.
            const std::string side = a->path + ".tables-t" + std::to_string(kServerTablesVersion) + ".json";
            nlohmann::json stored;
            if (std::ifstream in(side); in) stored = nlohmann::json::parse(in, nullptr, false);
            if (!read_server_tables(stored, *a)) {
                finish_server_asset(*a);
                std::ofstream out(side + ".tmp");
                out << server_tables_json(*a).dump();
                out.close();
                std::error_code ec;
                if (out) fs::rename(side + ".tmp", side, ec);
            }
        }
    } else if (!load_cached_build(p, cache, *a)) {
        a->skin = build_progressive_skin(a->character, sample_frames(a->character, a->selections, 30.0));
        finish_server_asset(*a);
        save_cached_build(p, cache, *a);
    }
    prepare_morphs(*a, p.path);
    return a;
}

std::vector<InstanceSpec> crowd_layout(const std::vector<std::shared_ptr<ServerAsset>>& assets, int n) {
    std::vector<InstanceSpec> out;
    if (assets.empty() || n <= 0) return out;
    double spacing = 0;
    for (const auto& a : assets) spacing = std::max(spacing, a->diagonal);
    int side = int(std::ceil(std::sqrt(double(n))));
    for (int i = 0; i < n; ++i) {
        InstanceSpec s;
        s.asset = i % int(assets.size());
        const auto& a = *assets[s.asset];
        s.selection = (i / int(assets.size())) % int(a.selections.size());
        float dur = a.selections[s.selection].duration();
        s.time_offset = dur > 0 ? std::fmod(0.37f * float(i), dur) : 0.0f;
        s.position = glm::vec3(float((i % side) * spacing), 0.0f, float((i / side) * spacing));
        out.push_back(s);
    }
    return out;
}

std::vector<InstanceSpec> default_instances(const std::vector<std::shared_ptr<ServerAsset>>& assets) {
    std::vector<InstanceSpec> out;
    for (size_t a = 0; a < assets.size(); ++a)
        for (size_t s = 0; s < assets[a]->selections.size(); ++s) {
            InstanceSpec i;
            i.asset = int(a);
            i.selection = int(s);
            i.position = glm::vec3(float(out.size()) * float(assets[a]->diagonal), 0.0f, 0.0f);
            out.push_back(i);
        }
    return out;
}

std::vector<std::string> default_asset_paths(const std::string& hint_dir) {
    std::vector<fs::path> roots;
    fs::path p = hint_dir.empty() ? fs::current_path() : fs::path(hint_dir);
    for (int i = 0; i < 4 && !p.empty(); ++i) {
        roots.push_back(p / "assets");
        if (p == p.parent_path()) break;
        p = p.parent_path();
    }
    roots.push_back(fs::current_path() / "assets");
#ifdef PROGSKIN_ASSETS
    roots.push_back(PROGSKIN_ASSETS);
#endif
    for (const auto& r : roots) {
        if (fs::exists(r / "Fox.glb") && fs::exists(r / "CesiumMan.glb"))
            return {(r / "Fox.glb").string(), (r / "CesiumMan.glb").string()};
    }
    throw Error("default character set not found (assets/Fox.glb, assets/CesiumMan.glb); pass --asset FILE");
}

}  // namespace progskin::net
