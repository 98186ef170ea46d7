#include "snapshot.h"

#include <cstdio>
#include <map>
#include <memory>

#include "image.h"
#include "renderer.h"
#include "mesh_data.h"
#include "progressive_skin.h"
#include "skinning.h"

namespace progskin::render {
namespace {

struct SnapshotState {
    std::unique_ptr<Renderer> renderer;
    std::map<std::pair<const Character*, const ProgressiveSkin*>, int> meshes;
};

SnapshotState& state() {
    static SnapshotState s;
    return s;
}

}  // namespace

void snapshot_reset() {
    state().meshes.clear();
    state().renderer.reset();
}

bool render_snapshot(const std::vector<SnapshotCharacter>& chars, const std::string& png_path,
                     const SnapshotOptions& o, std::string* error) {
    auto fail = [&](const std::string& m) {
        if (error) *error = m;
        return false;
    };
    if (chars.empty()) return fail("snapshot: no characters");
    SnapshotState& st = state();
    if (!st.renderer) {
        std::string e;
        st.renderer = Renderer::create(&e);
        if (!st.renderer) return fail("snapshot: no OpenGL context: " + e);
    }
    Renderer& r = *st.renderer;

    // World-space positions of every character (CPU skinning of the palette) for framing and labels.
    struct Item {
        const SnapshotCharacter* sc;
        int mesh;
        Bounds bounds;
    };
    std::vector<Item> items;
    Bounds all;
    std::vector<glm::vec3> tmp;
    for (const SnapshotCharacter& sc : chars) {
        if (!sc.character || !sc.skin) return fail("snapshot: character or skin missing");
        const Character& c = *sc.character;
        const ProgressiveSkin& s = *sc.skin;
        std::span<const glm::vec3> model_pos = sc.positions;
        if (!sc.palette.empty()) {
            if (int(sc.palette.size()) != s.bone_count()) return fail("snapshot: palette size != bone count");
            tmp.resize(c.vertex_count());
            if (sc.stream) {
                if (!skin_stream(*sc.stream, sc.palette, tmp)) return fail("snapshot: palette does not fit the stream");
            } else {
                const SkinningJob job = skinning_job(c, s, sc.palette, tmp);
                if (!job.validate()) return fail("snapshot: palette does not fit the skin");
                job.run();
            }
            model_pos = tmp;
        } else if (model_pos.size() != c.vertex_count()) {
            return fail("snapshot: neither a palette nor vertex_count() positions");
        }
        Item it{&sc, -1, {}};
        for (const glm::vec3& p : model_pos) it.bounds.add(sc.placement.transform_point(p));
        all.add(it.bounds.lo);
        all.add(it.bounds.hi);
        const auto key = std::make_pair(sc.character, sc.skin);
        auto found = st.meshes.find(key);
        if (found == st.meshes.end()) found = st.meshes.emplace(key, r.add_mesh(mesh_from_skin(c, s, o.textured))).first;
        it.mesh = found->second;
        items.push_back(it);
    }

    const int header = o.title.empty() ? 0 : 30;
    const int W = o.width, H = o.height - header;
    if (W < 16 || H < 16) return fail("snapshot: image too small");
    // Leave head room for the labels.
    Bounds framed = all;
    framed.hi.y += 0.12f * (all.hi.y - all.lo.y);
    const Camera cam = frame_bounds(framed, float(W) / float(H), o.azimuth, o.elevation, 30.0f, 0.92f);
    const Ground ground = ground_under(all);
    const glm::u8vec4 bg(238, 240, 245, 255), ink(30, 32, 40, 255);
    r.begin(W, H, cam, &ground, glm::vec3(bg) / 255.0f);
    for (const Item& it : items) {
        DrawParams d;
        d.palette = it.sc->palette;
        d.positions = it.sc->positions;
        d.model = it.sc->placement;
        d.textured = o.textured;
        if (!r.draw(it.mesh, d)) return fail("snapshot: drawing failed");
    }
    Image frame = r.finish();
    Image out(W, o.height, bg);
    blit(out, frame, 0, header);
    if (header) draw_text(out, 10, 8, o.title, ink, 2);
    const glm::mat4 vp = cam.proj * cam.view;
    for (const Item& it : items) {
        const glm::vec3 top(0.5f * (it.bounds.lo.x + it.bounds.hi.x), it.bounds.hi.y,
                            0.5f * (it.bounds.lo.z + it.bounds.hi.z));
        const glm::vec4 q = vp * glm::vec4(top, 1.0f);
        if (q.w <= 0) continue;
        const int x = int((q.x / q.w * 0.5f + 0.5f) * float(W));
        const int y = header + int((0.5f - q.y / q.w * 0.5f) * float(H));
        std::string text = std::to_string(it.sc->bones_received) + "/" + std::to_string(it.sc->skin->bone_count());
        if (!it.sc->label.empty()) text = it.sc->label + " " + text;
        const int tw = text_width(text, 2), th = 18;
        fill_rect(out, x - tw / 2 - 4, y - th - 8, tw + 8, th + 2, {255, 255, 255, 200});
        draw_text(out, x - tw / 2, y - th - 5, text, ink, 2);
    }
    if (!write_png(out, png_path)) return fail(png_path + ": cannot write");
    return true;
}

}  // namespace progskin::render
