// pose_buffer.cpp — see pose_buffer.h.
#include "pose_buffer.h"

#include <algorithm>

namespace progskin::net {

static bool newer(uint32_t a, uint32_t b) { return int32_t(a - b) > 0; }

PoseBuffer::PoseBuffer(int bone_count, RecordFormat fmt) : bones_(bone_count), fmt_(fmt) {
    frames_.resize(kHistory);
    for (auto& f : frames_) {
        f.bones.resize(bone_count);
        f.have.assign(bone_count, 0);
    }
    last_.resize(bone_count);
    last_tick_.assign(bone_count, 0);
    last_have_.assign(bone_count, 0);
}

bool PoseBuffer::add_chunk(uint32_t tick, int first, int count, int total, const uint8_t* records) {
    if (total < 1 || total > bones_ || first < 0 || count < 1 || first + count > total) return false;
    Frame* f = nullptr;
    for (auto& x : frames_)
        if (x.used && x.tick == tick) f = &x;
    if (!f) {
        // Replace an unused slot or the oldest frame, unless this tick is older than all kept.
        Frame* oldest = nullptr;
        for (auto& x : frames_) {
            if (!x.used) { oldest = &x; break; }
            if (!oldest || newer(oldest->tick, x.tick)) oldest = &x;
        }
        if (oldest->used && newer(oldest->tick, tick)) return true;  // too old to matter
        f = oldest;
        f->used = true;
        f->tick = tick;
        f->total = total;
        f->ready = 0;
        std::fill(f->have.begin(), f->have.end(), 0);
    }
    if (f->total != total) return false;
    for (int i = 0; i < count; ++i) {
        int b = first + i;
        f->bones[b] = decode_bone(records + size_t(i) * fmt_.size(), fmt_);
        f->have[b] = 1;
        if (!last_have_[b] || !newer(last_tick_[b], tick)) {
            last_[b] = f->bones[b];
            last_tick_[b] = tick;
            last_have_[b] = 1;
        }
    }
    while (f->ready < f->total && f->have[f->ready]) ++f->ready;
    if (!any_ || newer(tick, newest_)) newest_ = tick;
    if (!any_ || newer(first_, tick)) first_ = tick;
    any_ = true;
    return true;
}

int PoseBuffer::bones_at(double d) const {
    // Bones that can be shown at d: those present in a kept frame at or before
    // d and in one after it (interpolated per bone), or, when nothing newer
    // arrived yet, those of the newest frame before d (held).
    int before = 0, after = 0, newest_before = 0;
    const Frame* nb = nullptr;
    for (const auto& f : frames_) {
        if (!f.used || f.ready == 0) continue;
        double t = double(int32_t(f.tick - newest_)) + double(newest_);
        if (t <= d) {
            before = std::max(before, f.ready);
            if (!nb || newer(f.tick, nb->tick)) nb = &f;
        } else {
            after = std::max(after, f.ready);
        }
    }
    newest_before = nb ? nb->ready : 0;
    if (before == 0) return after;
    if (after == 0) return newest_before;
    return std::max(newest_before, std::min(before, after));
}

bool PoseBuffer::pose(int b, double d, BonePose& out) const {
    const Frame* a = nullptr;
    const Frame* c = nullptr;
    for (const auto& f : frames_) {
        if (!f.used || f.ready <= b) continue;
        double t = double(int32_t(f.tick - newest_)) + double(newest_);
        if (t <= d) {
            if (!a || newer(f.tick, a->tick)) a = &f;
        } else if (!c || newer(c->tick, f.tick)) {
            c = &f;
        }
    }
    if (a && c) {
        double ta = double(int32_t(a->tick - newest_)) + double(newest_);
        double tc = double(int32_t(c->tick - newest_)) + double(newest_);
        out = interpolate(a->bones[b], c->bones[b], float((d - ta) / (tc - ta)));
        return true;
    }
    if (a) { out = a->bones[b]; return true; }   // hold the newest
    if (c) { out = c->bones[b]; return true; }
    if (last_have_[b]) { out = last_[b]; return true; }
    return false;
}

}  // namespace progskin::net
