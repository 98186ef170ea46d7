// Rendering tests (render/): off-screen OpenGL on whatever EGL gives, in CI
// Mesa's llvmpipe software rasteriser. Skipped only when no GL context can be
// created (or render/ was not built for lack of EGL/OpenGL/stb packages).
#include <gtest/gtest.h>

#ifndef PROGSKIN_HAVE_RENDER
TEST(Render, NotBuilt) { GTEST_SKIP() << "render/ not built (EGL, OpenGL or stb headers missing)"; }
#else

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "animation.h"
#include "figure.h"
#include "gltf_import.h"
#include "image.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "renderer.h"
#include "mesh_data.h"
#include "snapshot.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::render;
using namespace progskin::thresholds;

namespace {

const glm::vec3 kBg(0.2f, 0.4f, 0.8f);  // a background the Fox never has

struct Fixture {
    std::unique_ptr<Renderer> r;
    std::string error;
    Character c;
    ProgressiveSkin s;
    ClipSelection clip;
    double t = 0;
    std::vector<Mat34> joints;
    int mesh_flat = -1;
};

// One GL context and one Fox for all tests (the build takes a moment).
Fixture* fixture() {
    static std::unique_ptr<Fixture> f;
    static bool tried = false;
    if (!tried) {
        tried = true;
        auto x = std::make_unique<Fixture>();
        x->r = Renderer::create(&x->error);
        x->c = import_character(std::string(PROGSKIN_ASSETS) + "/Fox.glb");
        x->s = build_progressive_skin(x->c, sample_frames(x->c, default_training_set(x->c), 30.0));
        x->clip = select_clips(x->c, "Survey");
        x->t = 0.5 * (x->clip.start + x->clip.end);
        x->joints = joint_matrices_at(x->c, x->clip, x->t);
        if (x->r) x->mesh_flat = x->r->add_mesh(mesh_from_skin(x->c, x->s, false));
        f = std::move(x);
    }
    return f.get();
}

#define NEED_GL(f)                                                                  \
    Fixture* f = fixture();                                                         \
    if (!f->r) GTEST_SKIP() << "no OpenGL context: " << f->error;

bool is_background(const Image& img, int x, int y) {
    const uint8_t* p = img.at(x, y);
    return std::abs(p[0] - int(kBg.r * 255 + 0.5f)) <= 2 && std::abs(p[1] - int(kBg.g * 255 + 0.5f)) <= 2 &&
           std::abs(p[2] - int(kBg.b * 255 + 0.5f)) <= 2;
}

// Renders the Fox with k bones (GPU skinning, or CPU-skinned vertices) with no
// ground, under the camera framing the full pose.
Image render_k(Fixture& f, int k, bool gpu, int w = 320, int h = 240) {
    std::vector<glm::vec3> full, pos, nrm;
    skin_lod_cpu(f.c, f.s, f.joints, f.s.bone_count(), full);
    Bounds b;
    b.add(full);
    const Camera cam = frame_points(full, float(w) / float(h));
    f.r->begin(w, h, cam, nullptr, kBg);
    const std::vector<Mat34> palette = lod_palette(f.s, f.joints, k);
    DrawParams d;
    if (gpu) {
        d.palette = palette;
    } else {
        skin_lod_cpu(f.c, f.s, f.joints, k, pos, &nrm);
        d.positions = pos;
        d.normals = nrm;
    }
    EXPECT_TRUE(f.r->draw(f.mesh_flat, d));
    return f.r->finish();
}

double mean_abs_diff(const Image& a, const Image& b) {
    EXPECT_EQ(a.rgba.size(), b.rgba.size());
    double s = 0;
    for (size_t i = 0; i < a.rgba.size(); ++i) s += std::abs(int(a.rgba[i]) - int(b.rgba[i]));
    return s / double(a.rgba.size());
}

// Fraction of pixels whose colour differs clearly (any channel by more than 24).
double changed_fraction(const Image& a, const Image& b) {
    size_t n = 0;
    for (size_t i = 0; i < a.rgba.size(); i += 4)
        if (std::abs(int(a.rgba[i]) - int(b.rgba[i])) > 24 || std::abs(int(a.rgba[i + 1]) - int(b.rgba[i + 1])) > 24 ||
            std::abs(int(a.rgba[i + 2]) - int(b.rgba[i + 2])) > 24)
            ++n;
    return double(n) / double(a.width * a.height);
}

}  // namespace

TEST(Render, ImageIsNonEmptyAndCharacterFramed) {
    NEED_GL(f);
    const Image img = render_k(*f, f->s.bone_count(), true);
    ASSERT_EQ(img.width, 320);
    ASSERT_EQ(img.height, 240);
    int x0 = img.width, y0 = img.height, x1 = -1, y1 = -1;
    size_t fg = 0;
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x)
            if (!is_background(img, x, y)) {
                ++fg;
                x0 = std::min(x0, x);
                x1 = std::max(x1, x);
                y0 = std::min(y0, y);
                y1 = std::max(y1, y);
            }
    ASSERT_GT(fg, 0u) << "nothing drawn (" << f->r->description() << ")";
    // Framed: inside the image (not cut at any border) ...
    EXPECT_GT(x0, 0);
    EXPECT_GT(y0, 0);
    EXPECT_LT(x1, img.width - 1);
    EXPECT_LT(y1, img.height - 1);
    // ... and filling a reasonable part of it.
    const double bw = double(x1 - x0 + 1) / img.width, bh = double(y1 - y0 + 1) / img.height;
    EXPECT_GT(std::max(bw, bh), 0.6) << "bbox " << bw << " x " << bh;
    EXPECT_GT(double(fg) / (img.width * img.height), 0.08);
}

TEST(Render, CpuAndGpuSkinningAgree) {
    NEED_GL(f);
    for (int k : {1, 3, f->s.bone_count()}) {
        const Image gpu = render_k(*f, k, true), cpu = render_k(*f, k, false);
        const double d = mean_abs_diff(gpu, cpu);
        EXPECT_LT(d, 0.5) << "k=" << k << ": mean |GPU - CPU| per channel " << d;
        EXPECT_LT(changed_fraction(gpu, cpu), 0.002) << "k=" << k;
    }
}

TEST(Render, LowerLodsDifferWhereTheErrorTableSaysSo) {
    NEED_GL(f);
    const int B = f->s.bone_count();
    const auto& table = f->s.error;  // e(k) at index k-1, over the training frames
    ASSERT_EQ(int(table.size()), B);
    const Image full = render_k(*f, B, true);
    // The full rig renders like itself (the rasteriser is deterministic).
    EXPECT_EQ(mean_abs_diff(full, render_k(*f, B, true)), 0.0);
    auto changed = [&](int k) { return changed_fraction(render_k(*f, k, true), full); };

    // Where the table says k bones leave a visible error (RMS > 0.5% of the
    // diagonal), the picture differs from the full rig.
    const double c1 = changed(1);
    for (int k : {1, 2, 4}) {
        const double ck = k == 1 ? c1 : changed(k);
        std::printf("  k=%d: table rms %.3f%%, pixels changed vs full rig %.2f%%\n", k, table[size_t(k - 1)].rms_pct,
                    100 * ck);
        if (table[size_t(k - 1)].rms_pct > 0.5) {
            EXPECT_GT(ck, 0.002) << "k=" << k;
        }
    }
    // The first k whose error is under a quarter of e(1) changes less of the picture than 1 bone.
    for (int k = 2; k < B; ++k)
        if (table[size_t(k - 1)].rms_pct < 0.25 * table[0].rms_pct) {
            const double ck = changed(k);
            std::printf("  k=%d: table rms %.3f%%, pixels changed %.2f%%\n", k, table[size_t(k - 1)].rms_pct, 100 * ck);
            EXPECT_LT(ck, c1) << "k=" << k;
            break;
        }
    // The first k with (almost) no error left: (almost) no visible change.
    for (int k = 1; k <= B; ++k)
        if (table[size_t(k - 1)].max_pct < 0.01) {
            const double ck = changed(k);
            std::printf("  k=%d: table max %.4f%%, pixels changed %.3f%%\n", k, table[size_t(k - 1)].max_pct, 100 * ck);
            EXPECT_LT(ck, 0.001) << "k=" << k;
            break;
        }
}

TEST(Render, FigureHasAPanelPerLodWithErrors) {
    NEED_GL(f);
    FigureOptions o;
    o.clip = f->clip;
    o.time = f->t;
    o.bones = {1, 2, 4, f->s.bone_count()};
    o.heatmap = true;
    o.title = "test";
    std::vector<PanelInfo> info;
    const Image img = render_lod_figure(*f->r, f->c, f->s, o, &info);
    EXPECT_EQ(img.width, 1600);
    EXPECT_EQ(img.height, 520);
    ASSERT_EQ(info.size(), 4u);
    EXPECT_GT(info[0].rms_pct, info[3].rms_pct);
    EXPECT_LT(info[3].max_pct, kLosslessPct);  // the full rig is the reference
    const std::string path = (std::filesystem::temp_directory_path() / "progskin_test_figure.png").string();
    ASSERT_TRUE(write_png(img, path));
    EXPECT_GT(std::filesystem::file_size(path), 10000u);
    std::filesystem::remove(path);
}

TEST(Render, SnapshotOfTwoCharacters) {
    NEED_GL(f);
    const std::vector<Mat34> full = lod_palette(f->s, f->joints, f->s.bone_count());
    const std::vector<Mat34> low = lod_palette(f->s, f->joints, 2);
    std::vector<SnapshotCharacter> chars(2);
    chars[0].character = chars[1].character = &f->c;
    chars[0].skin = chars[1].skin = &f->s;
    chars[0].palette = full;
    chars[0].bones_received = f->s.bone_count();
    chars[1].palette = low;
    chars[1].bones_received = 2;
    chars[1].placement.m[3] = 150.0f;  // 150 units along +x
    const std::string path = (std::filesystem::temp_directory_path() / "progskin_test_snapshot.png").string();
    SnapshotOptions o;
    o.width = 480;
    o.height = 270;
    o.title = "snapshot test";
    std::string err;
    ASSERT_TRUE(render_snapshot(chars, path, o, &err)) << err;
    EXPECT_GT(std::filesystem::file_size(path), 5000u);
    std::filesystem::remove(path);
    snapshot_reset();
}

#endif  // PROGSKIN_HAVE_RENDER
