// bench_records.cpp — bits per bone of the parent-relative record
// (proto/bone_record.h) against the absolute 12/14-byte record
// (proto/bone_codec.h), on each character's training clips sampled at the
// tick rate, and the error each costs (docs/metrics.md §2, RMS / max in % of
// the rest diagonal, every frame skinned from the decoded bits against the
// reference). Record bits only: no datagram, chunk, mask or root headers.
// Columns:
//   abs      the absolute record of today's stream (96 or 112 bits)
//   rel      parent-relative, closed loop, coded on its own (bone_record.h)
//   d1 d2 d4 predicted from the same bone's record 1, 2 or 4 ticks older
//            (write_predicted, one baseline)
//   l1 l2 l4 predicted linearly from the records a and 2a ticks older
//   same1 / same4  share of records equal to their one-baseline prediction
// Frames whose baselines fall before the clip's first frame are coded on
// their own (as a stream would with nothing acknowledged yet); every
// predicted record is decoded with read_predicted and checked against the
// encoder's integers.
//
// usage: bench_records [--rate HZ] [--json FILE] [FILE...]
//   FILE: glTF/glb characters (default: the bundled Fox and CesiumMan).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "bone_codec.h"
#include "bone_record.h"
#include "error_metric.h"
#include "errors.h"
#include "scene.h"
#include "skinning.h"

using namespace progskin;
using namespace progskin::net;

namespace {

struct Row {
    std::string character;
    int bones = 0;
    size_t frames = 0;
    double abs_bits = 0, rel_bits = 0;
    double delta[3] = {0, 0, 0}, linear[3] = {0, 0, 0}, same[3] = {0, 0, 0};
    ErrorStats abs_err, rel_err;
};

constexpr int kAges[3] = {1, 2, 4};

bool equal(const RecordInts& a, const RecordInts& b) {
    for (int i = 0; i < 3; ++i)
        if (a.rot[i] != b.rot[i] || (a.has_trans ? a.trans[i] : 0) != (b.has_trans ? b.trans[i] : 0)) return false;
    return (a.has_scale ? a.scale : 0) == (b.has_scale ? b.scale : 0);
}

Row measure(const std::string& file, double rate) {
    auto a = load_server_asset(file);
    const Character& c = a->character;
    const ProgressiveSkin& s = a->skin;
    const size_t B = size_t(s.bone_count());
    const RelativeFormat f = relative_format(s, c, a->format);
    const FrameSet frames = sample_frames(c, a->selections, rate);
    Row row;
    row.character = c.name.empty() ? file : c.name;
    row.bones = int(B);
    row.frames = frames.frame_count();
    row.abs_bits = a->format.size() * 8;
    std::vector<std::vector<RecordInts>> ints(frames.frame_count(), std::vector<RecordInts>(B));
    std::vector<BonePose> model(B), decoded(B);
    std::vector<uint32_t> offsets(B + 1);
    std::vector<glm::vec3> ref(c.vertex_count()), got(c.vertex_count()), old(c.vertex_count());
    std::vector<Mat34> pal(c.joint_count()), pal_old(c.joint_count());
    ErrorAccumulator rel(rest_diagonal(c)), abs_(rest_diagonal(c));
    size_t rel_bits = 0, pred_bits[2][3] = {{0, 0, 0}, {0, 0, 0}}, same[3] = {0, 0, 0};
    uint8_t rec[RecordFormat::kScaledSize];
    for (size_t fr = 0; fr < frames.frame_count(); ++fr) {
        for (size_t b = 0; b < B; ++b) model[b] = decompose(frames.frame(fr)[size_t(s.order[b])]);
        std::vector<uint8_t> bits;
        if (!encode_pose(model, f, bits, offsets, decoded, ints[fr]))
            throw Error(file + ": frame " + std::to_string(fr) + " cannot be coded relative to its parents");
        rel_bits += offsets[B];
        for (int m = 0; m < 2; ++m)
            for (int k = 0; k < 3; ++k) {
                const size_t age = size_t(kAges[k]), need = age * size_t(m + 1);
                const bool in_clip = fr >= need && frames.selection_of_frame[fr - need] == frames.selection_of_frame[fr];
                if (!in_clip) {
                    pred_bits[m][k] += offsets[B];
                    continue;
                }
                std::vector<uint8_t> pb;
                BitWriter w(pb);
                std::vector<RecordInts> preds(B);
                for (size_t b = 0; b < B; ++b) {
                    preds[b] = m == 0 ? predict_record(ints[fr - age][b], uint32_t(age))
                                      : predict_record(ints[fr - age][b], uint32_t(age), &ints[fr - need][b], uint32_t(need));
                    write_predicted(ints[fr][b], preds[b], f.scaled, w);
                    if (m == 0 && equal(ints[fr][b], preds[b])) ++same[k];
                }
                pred_bits[m][k] += w.bits();
                BitReader r(pb.data(), pb.size());
                for (size_t b = 0; b < B; ++b) {
                    RecordInts back;
                    if (!read_predicted(r, preds[b], f.scaled, back) || !equal(back, ints[fr][b]))
                        throw Error(file + ": a predicted record did not decode to its integers");
                }
            }
        if (fr % 3 != 0) continue;  // the error on every third frame
        reference_positions(c, frames, fr, ref);
        for (size_t b = 0; b < B; ++b) {
            const size_t j = size_t(s.order[b]);
            pal[j] = compose(decoded[b]);
            encode_bone(model[b], a->format, rec);
            pal_old[j] = compose(decode_bone(rec, a->format));
        }
        skinning_job(c, pal, got).run();
        skinning_job(c, pal_old, old).run();
        rel.add(ref, got);
        abs_.add(ref, old);
    }
    const double n = double(frames.frame_count() * B);
    row.rel_bits = double(rel_bits) / n;
    for (int k = 0; k < 3; ++k) {
        row.delta[k] = double(pred_bits[0][k]) / n;
        row.linear[k] = double(pred_bits[1][k]) / n;
        row.same[k] = double(same[k]) / n;
    }
    row.rel_err = rel.stats();
    row.abs_err = abs_.stats();
    return row;
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string> files;
    double rate = 30;
    std::string json_path;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--help" || a == "-h") {
            std::printf("usage: bench_records [--rate HZ] [--json FILE] [FILE...]\n"
                        "Bits per bone of the parent-relative record (on its own, and predicted from records 1, 2\n"
                        "and 4 ticks older) against the absolute record, and the error of each (RMS / max in %% of\n"
                        "the rest diagonal). FILE: glTF/glb characters (default: the bundled Fox and CesiumMan);\n"
                        "--rate: tick rate in Hz (default 30); --json: also write the rows as JSON.\n");
            return 0;
        }
        if (a == "--rate" || a == "--json") {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "bench_records: %s needs a value\n", a.c_str());
                return 2;
            }
            const std::string v = argv[++i];
            if (a == "--json") {
                json_path = v;
                continue;
            }
            char* end = nullptr;
            rate = std::strtod(v.c_str(), &end);
            if (end == v.c_str() || *end || !(rate > 0 && rate <= 1000)) {
                std::fprintf(stderr, "bench_records: --rate: %s is not a rate in (0, 1000] Hz\n", v.c_str());
                return 2;
            }
            continue;
        }
        if (!a.empty() && a[0] == '-') {
            std::fprintf(stderr, "bench_records: unknown option %s (--help)\n", a.c_str());
            return 2;
        }
        files.push_back(a);
    }
    if (files.empty()) files = {std::string(PROGSKIN_ASSETS) + "/Fox.glb", std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb"};
    nlohmann::json out = nlohmann::json::array();
    int rc = 0;
    std::printf("| character | bones | frames | abs | rel | d1 | d2 | d4 | l1 | l2 | l4 | same1 | same4 | abs RMS / max %% | rel RMS / max %% |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (const auto& file : files) {
        try {
            std::fprintf(stderr, "bench_records: %s ...\n", file.c_str());
            const Row r = measure(file, rate);
            std::printf("| %s | %d | %zu | %.0f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.0f%% | %.0f%% | %.5f / %.5f | %.5f / %.5f |\n",
                        r.character.c_str(), r.bones, r.frames, r.abs_bits, r.rel_bits, r.delta[0], r.delta[1], r.delta[2],
                        r.linear[0], r.linear[1], r.linear[2], 100 * r.same[0], 100 * r.same[2], r.abs_err.rms_pct,
                        r.abs_err.max_pct, r.rel_err.rms_pct, r.rel_err.max_pct);
            std::fflush(stdout);
            out.push_back({{"file", file}, {"character", r.character}, {"bones", r.bones}, {"frames", r.frames},
                           {"abs_bits", r.abs_bits}, {"rel_bits", r.rel_bits},
                           {"delta_bits", {r.delta[0], r.delta[1], r.delta[2]}},
                           {"linear_bits", {r.linear[0], r.linear[1], r.linear[2]}},
                           {"unchanged", {r.same[0], r.same[1], r.same[2]}}, {"ages", {1, 2, 4}},
                           {"abs_rms_pct", r.abs_err.rms_pct}, {"abs_max_pct", r.abs_err.max_pct},
                           {"rel_rms_pct", r.rel_err.rms_pct}, {"rel_max_pct", r.rel_err.max_pct}});
        } catch (const std::exception& e) {
            std::fprintf(stderr, "bench_records: %s\n", e.what());
            out.push_back({{"file", file}, {"error", e.what()}});
            rc = 1;
        }
    }
    if (!json_path.empty()) {
        std::ofstream j(json_path);
        j << out.dump(2) << "\n";
        if (!j) {
            std::fprintf(stderr, "bench_records: cannot write %s\n", json_path.c_str());
            return 1;
        }
    }
    return rc;
}
