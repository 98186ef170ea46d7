#include "figure.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "errors.h"
#include "error_metric.h"
#include "progressive_skin.h"
#include "skinning.h"

namespace progskin::render {

std::vector<Mat34> joint_matrices_at(const Character& c, const ClipSelection& sel, double t) {
    std::vector<glm::dmat4> m(c.joint_count());
    sample_skinning_matrices(c, sel, t, m);
    std::vector<Mat34> out;
    out.reserve(m.size());
    for (const auto& x : m) out.push_back(Mat34::from_glm(x));
    return out;
}

void skin_lod_cpu(const Character& c, const ProgressiveSkin& s, std::span<const Mat34> joint_matrices, int k,
                  std::vector<glm::vec3>& positions, std::vector<glm::vec3>* normals) {
    const std::vector<Mat34> palette = lod_palette(s, joint_matrices, k);
    if (palette.empty()) throw Error("invalid progressive skin (palette)");
    positions.resize(c.vertex_count());
    const bool with_normals = normals && c.normals.size() == c.vertex_count();
    if (normals) normals->resize(with_normals ? c.vertex_count() : 0);
    SkinningJob job = skinning_job(c, s, palette, positions);
    if (with_normals) {
        job.normals = c.normals;
        job.out_normals = *normals;
    }
    if (!job.validate()) throw Error("skinning job invalid for this skin");
    job.run();
}

namespace {

std::string pct(double v) {
    char b[32];
    if (v < 0.01)
        std::snprintf(b, sizeof b, "%.3f%%", v);
    else if (v < 10)
        std::snprintf(b, sizeof b, "%.2f%%", v);
    else
        std::snprintf(b, sizeof b, "%.1f%%", v);
    return b;
}

}  // namespace

Image render_lod_figure(Renderer& r, const Character& c, const ProgressiveSkin& s, const FigureOptions& o,
                        std::vector<PanelInfo>* info) {
    const int B = s.bone_count();
    if (B < 1 || o.bones.empty()) throw Error("render: nothing to draw (no bones or no panels)");
    const int n = int(o.bones.size());
    const int W = o.width > 0 ? o.width : 400 * n;
    const int H = o.height > 0 ? o.height : 520;
    const int header = o.title.empty() ? 0 : 30;
    const int label_band = 62;
    const int footer = o.heatmap ? 46 : 0;
    const int pw = W / n, ph = H - header - label_band - footer;
    if (pw < 16 || ph < 16) throw Error("render: image too small for " + std::to_string(n) + " panels");

    const std::vector<Mat34> joints = joint_matrices_at(c, o.clip, o.time);
    // Reference (docs/metrics.md §2): the original character, full detail.
    FrameSet one;
    one.joint_count = int(c.joint_count());
    one.times = {o.time};
    one.selection_of_frame = {0};
    one.skinning = joints;
    std::vector<glm::vec3> ref(c.vertex_count());
    reference_positions(c, one, 0, ref);
    const double diag = s.diagonal > 0 ? s.diagonal : rest_diagonal(c);

    struct Panel {
        int k;
        std::vector<Mat34> palette;
        std::vector<float> err;
        PanelInfo info;
    };
    std::vector<Panel> panels;
    Bounds bounds;
    bounds.add(ref);
    std::vector<glm::vec3> all_points = ref;
    float max_err = 0.0f;
    for (int want : o.bones) {
        Panel p;
        p.k = (want <= 0 || want > B) ? B : want;
        p.palette = lod_palette(s, joints, p.k);
        std::vector<glm::vec3> pos;
        skin_lod_cpu(c, s, joints, p.k, pos);
        bounds.add(pos);
        if (p.k < B) all_points.insert(all_points.end(), pos.begin(), pos.end());
        ErrorAccumulator acc(diag);
        acc.add(ref, pos);
        const ErrorStats st = acc.stats();
        p.info = {p.k, st.rms, st.max, st.rms_pct, st.max_pct};
        p.err.resize(pos.size());
        for (size_t v = 0; v < pos.size(); ++v) {
            p.err[v] = glm::length(pos[v] - ref[v]);
            max_err = std::max(max_err, p.err[v]);
        }
        panels.push_back(std::move(p));
    }

    const MeshData mesh = mesh_from_skin(c, s, o.textured);
    const int handle = r.add_mesh(mesh);
    const Camera cam = frame_points(all_points, float(pw) / float(ph), o.azimuth, o.elevation, 30.0f, 0.85f);
    const Ground ground = ground_under(bounds);
    const float scale = max_err > 0 ? max_err : 1.0f;

    const glm::u8vec4 bg(238, 240, 245, 255), ink(30, 32, 40, 255), soft(90, 94, 105, 255);
    Image out(pw * n, H, bg);
    if (header) draw_text(out, 10, 8, o.title, ink, 2);
    std::vector<glm::vec3> colors;
    for (int i = 0; i < n; ++i) {
        Panel& p = panels[size_t(i)];
        r.begin(pw, ph, cam, &ground, glm::vec3(bg) / 255.0f);
        DrawParams d;
        d.palette = p.palette;
        d.textured = o.textured;
        if (o.heatmap) {
            colors.resize(p.err.size());
            for (size_t v = 0; v < p.err.size(); ++v) colors[v] = heat_color(p.err[v] / scale);
            d.colors = colors;
        }
        if (!r.draw(handle, d)) throw Error("render: drawing the mesh failed");
        const Image img = r.finish();
        const int x0 = i * pw;
        blit(out, img, x0, header + label_band);
        const bool full = p.k == B;
        const std::string l1 = full ? "full rig, " + std::to_string(B) + " bones"
                                    : std::to_string(p.k) + (p.k == 1 ? " bone" : " bones") + " of " +
                                          std::to_string(B);
        const std::string l2 =
            full ? "reference" : "rms " + pct(p.info.rms_pct) + "   max " + pct(p.info.max_pct);
        draw_text(out, x0 + (pw - text_width(l1, 3)) / 2, header + 6, l1, ink, 3);
        draw_text(out, x0 + (pw - text_width(l2, 2)) / 2, header + 38, l2, soft, 2);
        if (i > 0) fill_rect(out, x0, header, 1, H - header - footer, {200, 203, 210, 255});
        if (info) info->push_back(p.info);
    }
    if (o.heatmap) {
        const int y = H - footer + 10, bar_w = std::min(300, pw * n / 3), x = 10 + text_width("error  0 ", 2);
        draw_text(out, 10, y + 4, "error  0 ", ink, 2);
        for (int k = 0; k < bar_w; ++k) {
            const glm::vec3 col = heat_color(float(k) / float(bar_w - 1)) * 255.0f;
            fill_rect(out, x + k, y, 1, 22, glm::u8vec4(glm::u8vec3(col), 255));
        }
        draw_text(out, x + bar_w + 8, y + 4,
                  pct(100.0 * scale / diag) + " of the bounding-box diagonal (this frame, vs. full skin)", ink, 2);
    }
    return out;
}

}  // namespace progskin::render
