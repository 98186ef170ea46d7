// frame_encoder.h — once per tick, samples every instance once and encodes all
// its bones once (bone_codec.h records, progressive order). Clients then only
// select prefixes and copy these bytes (scheduler.h, datagram_packer.h).
#pragma once
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "scene.h"

namespace progskin::net {

struct EncodedInstance {
    int asset = 0;
    int bone_count = 0;
    int record_size = 12;
    size_t offset = 0;      // into EncodedFrame::bytes
    bool valid = false;     // false: live instance with no pose pushed yet
    int model = 0;          // cost model of the scheduler: ServerAsset::Segment index (selection, or live)
};

struct EncodedFrame {
    uint32_t tick = 0;
    std::vector<EncodedInstance> instances;
    std::vector<uint8_t> bytes;  // records of every instance, B * record_size each
    const uint8_t* records(int i) const { return bytes.data() + instances[i].offset; }
};

class FrameEncoder {
public:
    FrameEncoder(std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
                 float tick_rate);
    // Samples and encodes every instance at `tick`. No allocation after the first call.
    const EncodedFrame& encode(uint32_t tick);
    const EncodedFrame& frame() const { return frame_; }

    // Clip time of an instance at a tick (start + wrap(offset + tick/rate*speed)).
    double clip_time(int instance, double tick) const;
    // Live pose: skinning matrices in the Character's joint order; used from
    // the next encode() on instead of the clip. Thread-safe.
    void push_pose(int instance, std::span<const Mat34> skinning);

    const std::vector<InstanceSpec>& instances() const { return specs_; }
    const std::vector<std::shared_ptr<ServerAsset>>& assets() const { return assets_; }

private:
    std::vector<std::shared_ptr<ServerAsset>> assets_;
    std::vector<InstanceSpec> specs_;
    float tick_rate_;
    EncodedFrame frame_;
    std::vector<glm::dmat4> scratch_;
    std::mutex live_mutex_;
    std::vector<std::vector<Mat34>> live_;  // per instance, empty if none pushed
    std::vector<Mat34> live_copy_;
};

}  // namespace progskin::net
