// client_palette.cpp — see client_palette.h.
#include "client_palette.h"

#include <algorithm>
#include <cmath>

#include "errors.h"
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

double ClipInfo::at(double u) const { return selection.played(u, once); }

void remap_skin_vertices(ClientAsset& a) {
    remap_skin_vertices(a.character, a.skin);
    std::vector<glm::vec3> none;
    if (!build_skin_stream(a.stream, skinning_job(a.character, a.skin, {}, none), SkinWeightFormat::U16))
        throw Error(a.character.source + ": vertex stream does not fit the skin");
}

double ClipInfo::clip_time(double tick, double tick_rate) const { return at(time_offset + tick / tick_rate * speed); }

InstanceView::InstanceView(std::shared_ptr<const ClientAsset> asset, ClipInfo clip, int blend_frames, double tick_rate)
    : asset_(std::move(asset)), clip_(std::move(clip)), buffer_(relative_format(asset_->skin, asset_->character, asset_->format), int(std::min<size_t>(asset_->character.morphs.size(), MAX_MORPHS))),
      tick_rate_(tick_rate) {
    // A looping clip wraps where offset + tick / rate * speed crosses a
    // multiple of its duration: the one between two frames' ticks.
    if (!clip_.once && !clip_.selection.clips.empty() && clip_.selection.duration() > 0 && clip_.speed > 0)
        buffer_.set_boundary(
            [](const void* ctx, double ta, double tc) {
                const auto* v = static_cast<const InstanceView*>(ctx);
                const double dur = v->clip_.selection.duration(), rate = v->tick_rate_, speed = v->clip_.speed;
                const double ua = v->clip_.time_offset + ta / rate * speed, uc = v->clip_.time_offset + tc / rate * speed;
                const double n = std::floor(uc / dur);
                if (n * dur <= ua) return std::nan("");  // no wrap between them
                return (n * dur - v->clip_.time_offset) / speed * rate;
            },
            this);
    const int B = asset_->skin.bone_count();
    blend_frames_ = std::max(1, blend_frames);
    blender_ = LodBlender(B, blend_frames_, 1);
    own_.resize(B);
    palette_.resize(B, Mat34::identity());
    weights_.assign(asset_->character.morphs.size(), 0.0f);  // targets past MAX_MORPHS stay 0 (not streamed)
    if (!weights_.empty()) morphed_.resize(asset_->character.vertex_count());
}

bool InstanceView::display(double d) {
    int k = buffer_.bones_at(d);
    if (k == 0) return false;
    if (buffer_.morph_count() > 0) buffer_.weights_at(d, std::span<float>(weights_.data(), size_t(buffer_.morph_count())));
    if (!started_) {
        blender_ = LodBlender(asset_->skin.bone_count(), blend_frames_, k);  // first frame: no fade-in from nothing
        started_ = true;
    }
    blender_.set_target(k);
    blender_.step();
    const int n = blender_.needed();
    BonePose p;
    const bool local = !clip_.selection.clips.empty();  // a clip the client holds too
    // Each bone's pose relative to its progressive parent, composed down the
    // prefix (parents[b] < b): a bone nothing newer carries yet is held
    // relative to its parent (which may be fresher), not frozen in model space.
    for (int b = 0; b < n; ++b) {
        double anchor = 0;
        const int parent = asset_->skin.parents[b];
        if (buffer_.pose(b, d, p, nullptr, local ? &anchor : nullptr)) {
            Mat34 rel = compose(p);
            if (local && !std::isnan(anchor)) {  // across a wrap: carried along the clip from the anchor frame
                Mat34 scratch;
                rel = mul(rel, carried(b, anchor, d, scratch));
            }
            own_[b] = parent >= 0 ? mul(own_[parent], rel) : rel;
        } else {  // never received: stand in from the parent
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

// R(anchor)^-1 R(d) for bone b, R(t) = L_parent(t)^-1 L_b(t) its skinning
// matrix relative to its progressive parent's in the clip at the clip time of
// display tick t (L_b alone for bone 0); each time evaluated once.
const Mat34& InstanceView::carried(int b, double anchor, double d, Mat34& out) {
    const Character& c = asset_->character;
    auto eval = [&](double tick, std::vector<glm::dmat4>& mats, double& at) {
        if (at == tick) return;
        mats.resize(c.joint_count());
        sample_skinning_matrices(c, clip_.selection, clip_.clip_time(tick, tick_rate_), mats);
        at = tick;
    };
    eval(anchor, local_anchor_, local_anchor_at_);
    eval(d, local_d_, local_d_at_);
    const size_t j = size_t(asset_->skin.order[size_t(b)]);
    const int parent = asset_->skin.parents[size_t(b)];
    auto relative = [&](const std::vector<glm::dmat4>& m) {
        return parent >= 0 ? glm::inverse(m[size_t(asset_->skin.order[size_t(parent)])]) * m[j] : m[j];
    };
    out = Mat34::from_glm(glm::inverse(relative(local_anchor_)) * relative(local_d_));
    return out;
}

void InstanceView::skin(std::vector<glm::vec3>& out) const {
    const Character& c = asset_->character;
    out.resize(c.vertex_count());
    if (!weights_.empty()) {  // glTF: morph targets on the bind positions, then the skin
        morph_positions(c, weights_, morphed_);
        SkinningJob job = skinning_job(c, asset_->skin, palette_, out);
        job.positions = morphed_;
        job.normals = {};
        job.out_normals = {};
        if (!job.validate()) throw Error(c.source + ": palette does not fit the skin");
        job.run();
        return;
    }
    if (!skin_stream(asset_->stream, palette_, out))
        throw Error(c.source + ": palette or vertex stream does not fit the skin");
}

void InstanceView::reference(double clip_time, std::vector<glm::vec3>& out) const {
    const Character& c = asset_->character;
    out.resize(c.vertex_count());
    if (!c.morphs.empty()) {  // docs/metrics.md §2 reference: morph targets at the clip's weights, then the skin
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
