// pose_buffer.h — the client's newest bones of one instance: decoded frame
// chunks (datagram.fbs Chunk) merged per tick into a short history, and the
// pose at any display time by interpolation (slerp per bone) between the two
// frames around it, holding the newest value when nothing newer arrived.
#pragma once
#include <cstdint>
#include <vector>

#include "bone_codec.h"

namespace progskin::net {

class PoseBuffer {
public:
    static constexpr int kHistory = 32;  // frames kept per instance

    PoseBuffer() = default;
    PoseBuffer(int bone_count, RecordFormat fmt);

    // Decodes count records (fmt.size() bytes each) of bones first.. of the
    // frame at `tick` whose prefix has `total` bones. Returns false (and
    // changes nothing) when the chunk is inconsistent.
    bool add_chunk(uint32_t tick, int first, int count, int total, const uint8_t* records);

    bool empty() const { return !any_; }
    uint32_t newest_tick() const { return newest_; }
    // True once a frame at or before display tick d has been received (the
    // display starts `delay` after the first frame, not before it).
    bool covers(double d) const { return any_ && d >= double(int32_t(first_ - newest_)) + double(newest_); }
    // Bones shown at display tick d: the prefix present both in a kept frame at
    // or before d and in one after it (each bone interpolated between its own
    // frames), at least the newest frame's at or before d; 0 if none.
    int bones_at(double d) const;
    // Pose of bone b at display tick d; false if bone b was never received.
    bool pose(int b, double d, BonePose& out) const;
    int bone_count() const { return bones_; }

private:
    struct Frame {
        uint32_t tick = 0;
        int total = 0;     // bones chosen for this tick
        int ready = 0;     // contiguous prefix received
        bool used = false;
        std::vector<BonePose> bones;
        std::vector<uint8_t> have;
    };
    int bones_ = 0;
    RecordFormat fmt_;
    std::vector<Frame> frames_;
    std::vector<BonePose> last_;        // newest value of every bone
    std::vector<uint32_t> last_tick_;
    std::vector<uint8_t> last_have_;
    uint32_t newest_ = 0, first_ = 0;
    bool any_ = false;
};

}  // namespace progskin::net
