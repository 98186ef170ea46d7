// `progskin render FILE --clip C --time T --bones 1,2,4,all -o figure.png
//                 [--heatmap] [--width W --height H] [--azimuth A] [--elevation E]
//                 [--character N] [--flat]`
// One PNG with a panel per LOD (figure.h). For a plain glTF the progressive
// skin is built first (reorder strategy, default training set at 30 fps), as
// `progskin pose` does; a file written by `progskin build` is used as is.
#include <cmath>
#include <cstdio>
#include <algorithm>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "animation.h"
#include "cli_args.h"
#include "collapse.h"
#include "range_of_motion.h"
#include "errors.h"
#include "figure.h"
#include "gltf_export.h"
#include "image.h"
#include "renderer.h"

using namespace progskin;
using namespace progskin::render;

namespace {

const char* kRenderUsage = R"(usage: progskin render FILE [--clip SPEC] [--time T] [--bones 1,2,4,all] -o OUT.png
                      [--heatmap] [--width W] [--height H] [--azimuth DEG] [--elevation DEG]
                      [--character N] [--flat]
  One image, a panel per LOD: the frame at time T of clip SPEC skinned on the GPU
  with k bones (copy-down palette), labelled with k and this frame's RMS / max
  error against the full skin in % of the rest bounding-box diagonal.
  --heatmap colours vertices by that error; --flat ignores base colour textures.
  Defaults: clip auto (first default training group), T = middle of the clip,
  bones 1,2,4,all, W = 400 per panel, H = 520, azimuth 35, elevation 12.
)";

using Usage = cli::UsageError;

double number(const std::string& key, const std::string& v) { return cli::to_number(key, v); }

int integer(const std::string& key, const std::string& v, int lo, int hi) {
    const double d = number(key, v);
    if (d != std::floor(d) || d < lo || d > hi)
        throw Usage(key + ": '" + v + "' must be an integer in " + std::to_string(lo) + ".." + std::to_string(hi));
    return int(d);
}

}  // namespace

int render_command(int argc, char** argv) {
    try {
        const std::vector<std::string> flags = {"--heatmap", "--flat", "--help", "--quiet"};
        const std::vector<std::string> valued = {"--clip",    "--time",    "--bones",     "-o",
                                                 "--width",   "--height",  "--azimuth",   "--elevation",
                                                 "--character"};
        cli::Args args = cli::parse(argc, argv, 2, flags, valued);
        const std::vector<std::string>& pos = args.positional;
        std::map<std::string, std::string>& opt = args.opts;
        if (opt.count("--help")) {
            std::fputs(kRenderUsage, stdout);
            return 0;
        }
        if (pos.size() != 1) throw Usage("render needs exactly one input file");
        if (!opt.count("-o")) throw Usage("render needs -o OUT.png");
        const bool quiet = opt.count("--quiet") > 0;
        const int character = opt.count("--character") ? integer("--character", opt["--character"], 0, 1 << 20) : 0;

        ProgressiveAsset asset = load_progressive(pos[0], character);
        const Character& c = asset.character;
        if (!asset.progressive) {
            if (!quiet)
                std::fprintf(stderr,
                             "render: %s has no progressive skin; building one (the lower-error strategy, "
                             "30 fps; `progskin build` once to skip this)\n",
                             pos[0].c_str());
            asset.skin = build_best_progressive_skin(c, training_frames(c, default_training_set(c), 30.0));
            asset.progressive = true;
        }
        const ProgressiveSkin& s = asset.skin;
        const int B = s.bone_count();

        FigureOptions o;
        const std::string spec = opt.count("--clip") ? opt["--clip"] : "auto";
        if (spec == "auto") {
            const auto sets = default_training_set(c);
            if (!sets.empty()) o.clip = sets[0];
        } else {
            o.clip = select_clips(c, spec);
        }
        o.time = opt.count("--time") ? number("--time", opt["--time"]) : 0.5 * (o.clip.start + o.clip.end);
        const std::string bones = opt.count("--bones") ? opt["--bones"] : "1,2,4,all";
        size_t start = 0;
        while (start <= bones.size()) {
            const size_t comma = bones.find(',', start);
            const std::string item = bones.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
            o.bones.push_back(item == "all" ? B : integer("--bones", item, 1, B));
            if (comma == std::string::npos) break;
            start = comma + 1;
        }
        if (o.bones.empty() || o.bones.size() > 16) throw Usage("--bones: 1 to 16 comma-separated counts or all");
        o.heatmap = opt.count("--heatmap") > 0;
        o.textured = opt.count("--flat") == 0;
        if (opt.count("--width")) o.width = integer("--width", opt["--width"], 32, 16384);
        if (opt.count("--height")) o.height = integer("--height", opt["--height"], 160, 16384);
        if (opt.count("--azimuth")) o.azimuth = float(number("--azimuth", opt["--azimuth"]));
        if (opt.count("--elevation")) o.elevation = float(number("--elevation", opt["--elevation"]));
        std::string clip_name = spec;
        if (o.clip.clips.size() == 1) clip_name = c.clips[size_t(o.clip.clips[0])].name;
        char title[512];
        std::snprintf(title, sizeof title, "%s  |  clip %s, t = %.2f s  |  strategy %s%s", pos[0].substr(pos[0].find_last_of('/') + 1).c_str(),
                      clip_name.c_str(), o.time, strategy_name(s.strategy), o.heatmap ? "  |  error heat map" : "");
        o.title = title;

        std::string err;
        auto r = Renderer::create(&err);
        if (!r) throw Error("render: no OpenGL context: " + err);
        if (!quiet) std::fprintf(stderr, "render: %s\n", r->description().c_str());
        std::vector<PanelInfo> info;
        const Image img = render_lod_figure(*r, c, s, o, &info);
        const std::string out = opt["-o"];
        const std::string tmp = out + ".tmp.png";
        if (!write_png(img, tmp) || std::rename(tmp.c_str(), out.c_str()) != 0) {
            std::remove(tmp.c_str());
            throw Error(out + ": cannot write");
        }
        if (!quiet) {
            for (const PanelInfo& p : info)
                std::printf("  %3d bones: rms %.4f%%  max %.4f%% of diagonal (this frame)\n", p.bones, p.rms_pct,
                            p.max_pct);
            std::printf("wrote %s (%dx%d)\n", out.c_str(), img.width, img.height);
        }
        return 0;
    } catch (const Usage& e) {
        std::fprintf(stderr, "progskin render: %s\n%s", e.what(), kRenderUsage);
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "progskin render: %s\n", e.what());
        return 1;
    }
}
