// client_palette.cpp — see client_palette.h.
#include "client_palette.h"

#include <cmath>

#include "error.h"
#include "error_metric.h"
#include "progressive_skin.h"
#include "skinning.h"

namespace progskin::net {

void remap_skin_vertices(const Character& c, ProgressiveSkin& skin) {
    const int B = skin.bone_count();
    if (size_t(B) != c.joint_count()) throw Error(c.source + ": skin has " + std::to_string(B) + " bones, file " +
                                                  std::to_string(c.joint_count()) + " joints");
    std::vector<int> inv(B, -1);
    for (int b = 0; b < B; ++b) {
        int j = skin.order[b];
        if (j < 0 || j >= B || inv[j] >= 0) throw Error(c.source + ": bad progressive order");
        inv[j] = b;
    }
    skin.influences = c.influences;
    skin.joints.resize(c.joints.size());
    for (size_t i = 0; i < c.joints.size(); ++i) skin.joints[i] = uint16_t(inv[c.joints[i]]);
    skin.weights = c.weights;
}

double ClipInfo::clip_time(double tick, double tick_rate) const {
    return selection.looped(time_offset + tick / tick_rate * speed);
}

InstanceView::InstanceView(std::shared_ptr<const ClientAsset> asset, ClipInfo clip, int blend_frames)
    : asset_(std::move(asset)), clip_(std::move(clip)), buffer_(asset_->skin.bone_count(), asset_->format) {
    const int B = asset_->skin.bone_count();
    blend_frames_ = std::max(1, blend_frames);
    blender_ = LodBlender(B, blend_frames_, 1);
    own_.resize(B);
    palette_.resize(B, Mat34::identity());
}

bool InstanceView::display(double d) {
    int k = buffer_.bones_at(d);
    if (k == 0) return false;
    if (!started_) {
        blender_ = LodBlender(asset_->skin.bone_count(), blend_frames_, k);  // first frame: no fade-in from nothing
        started_ = true;
    }
    blender_.set_target(k);
    blender_.step();
    const int n = blender_.needed();
    BonePose p, pp;
    for (int b = 0; b < n; ++b) {
        double held = 0;
        const int parent = asset_->skin.parents[b];
        if (buffer_.pose(b, d, p, &held)) {
            own_[b] = compose(p);
            // Nothing newer carries this bone yet: hold it relative to its
            // progressive parent (which may be fresher), not frozen in model space.
            if (held < d && parent >= 0 && buffer_.pose(parent, held, pp))
                own_[b] = mul(own_[parent], mul(compose(inverse(pp)), own_[b]));
        } else {  // never received: stand in from the parent
            int parent = asset_->skin.parents[b];
            own_[b] = parent >= 0 ? mul(own_[parent], asset_->skin.corrections[b]) : Mat34::identity();
        }
    }
    PaletteJob job;
    job.parents = asset_->skin.parents;
    job.corrections = asset_->skin.corrections;
    job.own = std::span<const Mat34>(own_.data(), size_t(n));
    job.presence = blender_.presence();
    job.out = palette_;
    job.run();
    return true;
}

void InstanceView::skin(std::vector<glm::vec3>& out) const {
    const Character& c = asset_->character;
    out.resize(c.vertex_count());
    skinning_job(c, asset_->skin, palette_, out).run();
}

void InstanceView::reference(double clip_time, std::vector<glm::vec3>& out) const {
    const Character& c = asset_->character;
    out.resize(c.vertex_count());
    if (!c.morphs.empty()) {  // GUIDE.md §2 reference: morph targets at the clip's weights, then the skin
        reference_positions(c, sample_pose(c, clip_.selection, clip_time), 0, out);
        return;
    }
    ref_mats_.resize(c.joint_count());
    ref_palette_.resize(c.joint_count());
    sample_skinning_matrices(c, clip_.selection, clip_time, ref_mats_);
    for (size_t j = 0; j < c.joint_count(); ++j) ref_palette_[j] = Mat34::from_glm(ref_mats_[j]);
    skinning_job(c, ref_palette_, out).run();
}

}  // namespace progskin::net
