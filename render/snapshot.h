// snapshot.h — a picture of what a streaming client displays.
//
// The client hands over every character it shows, already posed: either its
// palette (B matrices in the skin's progressive order, what PaletteJob built
// from the received bones) for GPU skinning, or vertices it skinned itself.
// Each character is labelled above its head with the bones it received.
// The characters share one camera that frames them all and a ground grid.
//
// Not thread-safe: the GL context lives in the first thread that calls
// render_snapshot (it is created on the first call and reused; meshes are
// cached per (character, skin) address pair, so keep those objects alive and
// unchanged between calls, or call snapshot_reset() when they change).
#pragma once
#include <span>
#include <string>
#include <vector>

#include "character.h"
#include "mat34.h"
#include "progressive_skin.h"

namespace progskin::render {

struct SnapshotCharacter {
    const Character* character = nullptr;  // mesh, normals, materials (read from character->source)
    const ProgressiveSkin* skin = nullptr;  // vertex stream in progressive bone indices
    std::span<const Mat34> palette;         // B matrices, progressive order (GPU skinning), or empty and:
    std::span<const glm::vec3> positions;   // vertices skinned by the caller (model space), vertex_count()
    const SkinStream* stream = nullptr;     // the skin's stream (skinning.h) when the caller has one: the
                                            // palette is CPU-skinned by skin_stream, else by SkinningJob
    Mat34 placement = Mat34::identity();    // model -> world (where this character stands)
    int bones_received = 0;                 // shown as "k/B"
    std::string label;                      // optional extra text, e.g. the character's id
};

struct SnapshotOptions {
    int width = 1280, height = 720;
    float azimuth = 20.0f, elevation = 25.0f;  // degrees; 0 azimuth = looking from +Z
    std::string title;                          // header text, e.g. "t = 12.3 s  rate 48 kB/s"
    bool textured = true;
};

// Renders and writes png_path. False (and *error) when there is nothing to
// draw, no GL context can be created or the file cannot be written.
bool render_snapshot(const std::vector<SnapshotCharacter>& chars, const std::string& png_path,
                     const SnapshotOptions& options = {}, std::string* error = nullptr);

// Drops the cached renderer and meshes (next call starts afresh).
void snapshot_reset();

}  // namespace progskin::render
