// frame_encoder.cpp — see frame_encoder.h.
#include "frame_encoder.h"

#include <cmath>

#include "error.h"

namespace progskin::net {

FrameEncoder::FrameEncoder(std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
                           float tick_rate)
    : assets_(std::move(assets)), specs_(std::move(instances)), tick_rate_(tick_rate) {
    size_t offset = 0, max_joints = 0;
    frame_.instances.resize(specs_.size());
    for (size_t i = 0; i < specs_.size(); ++i) {
        const auto& s = specs_[i];
        if (s.asset < 0 || s.asset >= int(assets_.size())) throw Error("instance " + std::to_string(i) + ": no asset " + std::to_string(s.asset));
        const ServerAsset& a = *assets_[s.asset];
        if (s.selection >= int(a.selections.size())) throw Error("instance " + std::to_string(i) + ": no clip selection " + std::to_string(s.selection));
        auto& e = frame_.instances[i];
        e.asset = s.asset;
        e.bone_count = a.bone_count();
        e.record_size = a.format.size();
        e.offset = offset;
        offset += size_t(e.bone_count) * e.record_size;
        max_joints = std::max(max_joints, a.character.joint_count());
    }
    frame_.bytes.assign(offset, 0);
    scratch_.resize(max_joints);
    live_.resize(specs_.size());
}

double FrameEncoder::clip_time(int instance, double tick) const {
    const auto& s = specs_[instance];
    if (s.selection < 0) return 0.0;
    return assets_[s.asset]->selections[s.selection].looped(s.time_offset + tick / tick_rate_ * s.speed);
}

void FrameEncoder::push_pose(int instance, std::span<const Mat34> skinning) {
    if (instance < 0 || instance >= int(specs_.size())) throw Error("push_pose: no instance " + std::to_string(instance));
    const ServerAsset& a = *assets_[specs_[instance].asset];
    if (skinning.size() != a.character.joint_count())
        throw Error("push_pose: instance " + std::to_string(instance) + " takes " + std::to_string(a.character.joint_count()) + " matrices");
    std::lock_guard lock(live_mutex_);
    live_[instance].assign(skinning.begin(), skinning.end());
}

const EncodedFrame& FrameEncoder::encode(uint32_t tick) {
    frame_.tick = tick;
    for (size_t i = 0; i < specs_.size(); ++i) {
        const auto& s = specs_[i];
        const ServerAsset& a = *assets_[s.asset];
        auto& e = frame_.instances[i];
        const int J = int(a.character.joint_count());
        bool live = false;
        {
            std::lock_guard lock(live_mutex_);
            if (!live_[i].empty()) {
                live_copy_.assign(live_[i].begin(), live_[i].end());
                live = true;
            }
        }
        uint8_t* out = frame_.bytes.data() + e.offset;
        e.model = live || s.selection < 0 ? int(a.selections.size()) : s.selection;
        if (live) {
            for (int b = 0; b < e.bone_count; ++b)
                encode_bone(decompose(live_copy_[a.skin.order[b]]), a.format, out + size_t(b) * e.record_size);
            e.valid = true;
            continue;
        }
        if (s.selection < 0) {
            e.valid = false;
            continue;
        }
        std::span<glm::dmat4> mats(scratch_.data(), size_t(J));
        sample_skinning_matrices(a.character, a.selections[s.selection], clip_time(int(i), tick), mats);
        for (int b = 0; b < e.bone_count; ++b)
            encode_bone(decompose(Mat34::from_glm(mats[a.skin.order[b]])), a.format, out + size_t(b) * e.record_size);
        e.valid = true;
    }
    return frame_;
}

}  // namespace progskin::net
