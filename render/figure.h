// figure.h — the LOD figure (the paper's Figure 1 for any character): one
// frame of a clip rendered with k = 1, 2, 4, ... bones beside the full rig,
// one panel per LOD, each labelled with its bone count and the error of that
// frame against the full-detail reference (docs/metrics.md §2: RMS and max distance
// in % of the rest bounding-box diagonal). Skinning runs in the vertex shader
// from the palette PaletteJob builds (copy-down with corrections); the CPU
// skins the same palette only to measure the error and frame the camera.
#pragma once
#include <string>
#include <vector>

#include "animation.h"
#include "character.h"
#include "image.h"
#include "progressive_skin.h"
#include "renderer.h"

namespace progskin::render {

struct FigureOptions {
    ClipSelection clip;           // what plays (empty = rest pose)
    double time = 0.0;            // absolute clip time
    std::vector<int> bones;       // one panel per entry; k <= 0 or k >= B means all bones
    bool heatmap = false;         // colour vertices by their error against the full skin
    int width = 0, height = 0;    // whole image; 0 = 400 px per panel x 520
    float azimuth = 35.0f, elevation = 12.0f;  // camera direction, degrees (0 = from +Z)
    std::string title;            // header line; empty = none
    bool textured = true;         // base colour textures when the asset has them
};

struct PanelInfo {
    int bones = 0;
    double rms = 0, max = 0;          // this frame, model units
    double rms_pct = 0, max_pct = 0;  // % of the rest bounding-box diagonal
};

// Renders the figure. info (optional) receives one entry per panel.
// Throws progskin::Error on bad input (no bones, palette invalid).
Image render_lod_figure(Renderer& r, const Character& c, const ProgressiveSkin& s, const FigureOptions& o,
                        std::vector<PanelInfo>* info = nullptr);

// CPU-skinned positions and normals of the skin with k bones at `joint_matrices`
// (per Character joint): the palette of lod_palette and SkinningJob.
void skin_lod_cpu(const Character& c, const ProgressiveSkin& s, std::span<const Mat34> joint_matrices, int k,
                  std::vector<glm::vec3>& positions, std::vector<glm::vec3>* normals = nullptr);

// Skinning matrices of every Character joint at time t of a clip selection.
std::vector<Mat34> joint_matrices_at(const Character& c, const ClipSelection& sel, double t);

}  // namespace progskin::render
