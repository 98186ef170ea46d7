// client_palette.h — what the client displays: per instance, the palette of
// the progressive skin at the display time (own matrices of the bones the
// LodBlender needs, interpolated by the PoseBuffer; copy-down with corrections
// for the rest, PaletteJob), skinned on the CPU (SkinningJob) when verifying,
// and compared with the reference (the asset's clip evaluated at full detail
// at the same clip time; docs/metrics.md §2). Internal to the client library
// (ClientAsset and ClipInfo, which games see, are in client_asset.h).
#pragma once
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "character.h"
#include "client_asset.h"
#include "palette.h"
#include "pose_buffer.h"
#include "progressive_skin.h"

namespace progskin::net {

// Fills skin.joints/weights from the character's vertex stream remapped to
// progressive indices (skin.order must be set). Throws Error on a bad order.
void remap_skin_vertices(const Character& c, ProgressiveSkin& skin);
// The same for an asset (its character and skin), then builds asset.stream.
void remap_skin_vertices(ClientAsset& asset);

class InstanceView {
public:
    // tick_rate: the server's, to place a looping clip's wraps on the display
    // clock (PoseBuffer::set_boundary).
    InstanceView(std::shared_ptr<const ClientAsset> asset, ClipInfo clip, int blend_frames, double tick_rate = 30);
    InstanceView(const InstanceView&) = delete;
    InstanceView& operator=(const InstanceView&) = delete;

    PoseBuffer& buffer() { return buffer_; }
    const ClientAsset& asset() const { return *asset_; }
    const ClipInfo& clip() const { return clip_; }

    // One displayed frame at display tick d: updates the blender, builds the
    // palette. Returns false when nothing was received yet.
    bool display(double d);
    int target_bones() const { return blender_.target(); }
    std::span<const Mat34> palette() const { return palette_; }

    // Morph weights displayed (one per morph target of the character, 0 for
    // targets never received or past MAX_MORPHS), updated by display().
    std::span<const float> morph_weights() const { return weights_; }
    // CPU skinning of the current palette into positions (all vertices): the
    // bind positions morphed by morph_weights() first when the character has
    // morph targets (then the scalar SkinningJob, else skin_stream).
    void skin(std::vector<glm::vec3>& out) const;
    // Reference vertices at clip time t (full detail, original weights).
    void reference(double clip_time, std::vector<glm::vec3>& out) const;

private:
    std::shared_ptr<const ClientAsset> asset_;
    ClipInfo clip_;
    PoseBuffer buffer_;
    LodBlender blender_;
    bool started_ = false;
    int blend_frames_ = 8;
    double tick_rate_ = 30;
    std::vector<Mat34> own_, palette_;
    std::vector<float> weights_;              // displayed morph weights
    mutable std::vector<glm::vec3> morphed_;  // morphed bind positions (skin)
    mutable std::vector<glm::dmat4> ref_mats_;
    // Boundary gaps of a looping clip: the clip's own motion from an anchor
    // frame to the display time, per bone relative to its progressive parent
    // (R(d) = R(anchor) Rclip(anchor)^-1 Rclip(d), client_palette.cpp carried).
    std::vector<glm::dmat4> local_d_, local_anchor_;
    double local_d_at_ = -1e300, local_anchor_at_ = -1e300;
    const Mat34& carried(int bone, double anchor, double d, Mat34& scratch);
    mutable std::vector<Mat34> ref_palette_;
};

}  // namespace progskin::net
