// pose_buffer.cpp — see pose_buffer.h.
#include "pose_buffer.h"

#include <algorithm>
#include <cmath>

namespace progskin::net {

static bool newer(uint32_t a, uint32_t b) { return int32_t(a - b) > 0; }

double PoseBuffer::tick_time(uint32_t tick) const { return double(int32_t(tick - newest_)) + double(newest_); }
// A frame's bones were sampled sample_ticks(f.sample) < 1 before its tick:
// the order of sample times is the order of ticks.
double PoseBuffer::sample_time(const Frame& f) const { return tick_time(f.tick) - sample_ticks(f.sample); }


// The frames around display tick d that `use` accepts, within one epoch: a
// (newest at or before d), a0 (the one before a), c (first after d, same
// epoch as a) and c1 (the one after c). Without a, c and c1 share c's epoch.
// time(frame): its display tick (the sample's, or the tick's for roots).
template <class Frames, class Use, class Time>
static void neighbours(const Frames& frames, double d, Use&& use, Time&& time, const void*& a_, const void*& a0_,
                       const void*& c_, const void*& c1_) {
    using F = typename Frames::value_type;
    const F *a = nullptr, *c = nullptr;
    for (const auto& f : frames) {
        if (!f.used || !use(f)) continue;
        if (time(&f) <= d) {
            if (!a || newer(f.tick, a->tick)) a = &f;
        }
    }
    const F *a0 = nullptr, *c1 = nullptr;
    for (const auto& f : frames) {
        if (!f.used || !use(f) || (a && f.epoch != a->epoch)) continue;
        if (time(&f) <= d) {
            if (&f != a && (!a0 || newer(f.tick, a0->tick))) a0 = &f;
        } else if (!c || newer(c->tick, f.tick)) {
            c = &f;
        }
    }
    for (const auto& f : frames) {
        if (!f.used || !use(f) || !c || f.epoch != c->epoch || &f == c || time(&f) <= time(c)) continue;
        if (!c1 || newer(c1->tick, f.tick)) c1 = &f;
    }
    a_ = a, a0_ = a0, c_ = c, c1_ = c1;
}


PoseBuffer::PoseBuffer(RelativeFormat fmt, int morph_count) : bones_(fmt.bone_count()), fmt_(std::move(fmt)) {
    const int bone_count = bones_;
    morphs_ = std::max(0, morph_count);
    frames_.resize(kHistory);
    scratch_.resize(size_t(bone_count));
    for (auto& f : frames_) {
        f.bones.resize(bone_count);
        f.ints.resize(size_t(bone_count));
        f.have.assign(bone_count, 0);
        f.weights.assign(size_t(morphs_), 0.0f);
        f.whave.assign(size_t(morphs_), 0);
    }
    held_w_.assign(size_t(morphs_), 0.0f);
    held_w_tick_.assign(size_t(morphs_), 0);
    held_w_have_.assign(size_t(morphs_), 0);
    last_.resize(bone_count);
    last_tick_.assign(bone_count, 0);
    last_have_.assign(bone_count, 0);
}

const PoseBuffer::Frame* PoseBuffer::frame_at(uint32_t tick) const {
    for (const auto& f : frames_)
        if (f.used && f.tick == tick) return &f;
    return nullptr;
}

bool PoseBuffer::add_chunk(uint32_t tick, int first, int count, int total, const RecordRun& records, int show, uint8_t epoch,
                           std::span<const uint8_t> root, uint8_t sample) {
    if (show == 0) show = total;
    if (total < 1 || total > bones_ || first < 0 || count < 1 || first + count > total || show < total || show > bones_ ||
        records.scaled != fmt_.scaled)
        return false;
    // Decode the root and every record before anything changes (a predicted
    // one from its baseline frames: the chunk is refused when one is missing).
    std::array<uint8_t, ROOT_BYTES> abs_root;
    if (!root.empty()) {
        bool missing = false;
        if (!roots_.resolve(tick, root.data(), root.size(), abs_root.data(), &missing)) {
            if (missing) ++missing_baselines_;
            return false;
        }
    }
    const uint32_t age = records.base & kBaseAgeMask;
    const bool linear = (records.base & kBaseLinear) != 0;
    const Frame* b1 = age ? frame_at(tick - age) : nullptr;
    const Frame* b2 = age && linear ? frame_at(tick - 2 * age) : nullptr;
    BitReader in(records.data, records.bytes, records.bit);
    for (int i = 0; i < count; ++i) {
        const int b = first + i;
        RecordPrefix prefix;
        if (age && !read_prefix(in, prefix)) return false;
        if (prefix.kind != RecordPrefix::Standalone) {
            // The chunk's baseline, or the record's own (a bone refreshed at other ticks).
            const bool own = prefix.kind == RecordPrefix::Own;
            const uint32_t a = own ? (prefix.base & kBaseAgeMask) : age;
            const bool lin = own ? (prefix.base & kBaseLinear) != 0 : linear;
            const Frame* f1 = own ? frame_at(tick - a) : b1;
            const Frame* f2 = own ? (lin ? frame_at(tick - 2 * a) : nullptr) : b2;
            if (!f1 || !f1->have[size_t(b)] || (lin && (!f2 || !f2->have[size_t(b)]))) {
                ++missing_baselines_;
                return false;
            }
            const RecordInts pred = lin ? predict_record(f1->ints[size_t(b)], sample_age(a, sample, f1->sample),
                                                         &f2->ints[size_t(b)], sample_age(2 * a, sample, f2->sample))
                                        : predict_record(f1->ints[size_t(b)], a);
            if (!read_predicted(in, pred, fmt_.scaled, scratch_[size_t(i)])) return false;
            ++predicted_;
        } else if (!read_record(in, fmt_.scaled, scratch_[size_t(i)])) {
            return false;
        }
    }
    bool too_old = false;
    Frame* f = frame_for(tick, total, show, epoch, sample, &too_old);
    if (too_old) return true;  // too old to matter
    if (!f) return false;
    if (!root.empty()) {
        f->root = decode_root(abs_root.data());
        f->has_root = true;
        roots_.put(tick, abs_root.data());
    }
    last_gap_ = 0;
    for (int i = 0; i < count; ++i) {
        int b = first + i;
        f->ints[size_t(b)] = scratch_[size_t(i)];
        // Kept about the bone's pivot (the translation is the pivot's image),
        // so that interpolation turns the bone about its joint (pose()).
        BonePose rel = dequantise_record(scratch_[size_t(i)], b, fmt_);
        rel.t += rel.s * (rel.r * fmt_.pivots[size_t(b)]);
        f->bones[b] = rel;
        if (!f->have[b]) ++f->count;
        f->have[b] = 1;
        if (!last_have_[b] || !newer(last_tick_[b], tick)) {
            const int32_t gap = int32_t(tick - last_tick_[b]);
            if (last_have_[b] && gap <= HOLD_TICKS) last_gap_ = std::max(last_gap_, int(gap));
            last_[b] = f->bones[b];
            last_tick_[b] = tick;
            last_have_[b] = 1;
        }
    }
    if (!any_ || newer(tick, newest_)) newest_ = tick;
    if (!any_ || newer(first_, tick)) first_ = tick;
    any_ = true;
    return true;
}

PoseBuffer::Frame* PoseBuffer::frame_for(uint32_t tick, int total, int show, uint8_t epoch, uint8_t sample, bool* too_old) {
    *too_old = false;
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
        if (oldest->used && newer(oldest->tick, tick)) {
            *too_old = true;
            return nullptr;
        }
        if (oldest->used && oldest->has_weights)  // keep its weights as the fallback of older display times
            for (int m = 0; m < morphs_; ++m)
                if (oldest->whave[size_t(m)] && (!held_w_have_[size_t(m)] || !newer(held_w_tick_[size_t(m)], oldest->tick))) {
                    held_w_[size_t(m)] = oldest->weights[size_t(m)];
                    held_w_tick_[size_t(m)] = oldest->tick;
                    held_w_have_[size_t(m)] = 1;
                }
        f = oldest;
        f->used = true;
        f->tick = tick;
        f->total = total;
        f->show = show;
        f->count = 0;
        f->epoch = epoch;
        f->sample = sample;
        f->has_root = false;
        f->has_weights = false;
        std::fill(f->have.begin(), f->have.end(), 0);
        std::fill(f->whave.begin(), f->whave.end(), 0);
    }
    if (f->total != total || f->show != show || f->epoch != epoch || f->sample != sample) return nullptr;
    return f;
}

bool PoseBuffer::add_morphs(uint32_t tick, int total, int show, uint8_t epoch, const uint8_t* block, uint8_t sample) {
    if (show == 0) show = total;
    if (!block || total < 1 || total > bones_ || show < total || show > bones_) return false;
    const int n = block[0];
    for (int i = 0; i < n; ++i)
        if (block[1 + size_t(i) * MORPH_ENTRY_BYTES] >= morphs_) return false;
    bool too_old = false;
    Frame* f = frame_for(tick, total, show, epoch, sample, &too_old);
    if (too_old) return true;
    if (!f) return false;
    for (int i = 0; i < n; ++i) {
        const uint8_t* e = block + 1 + size_t(i) * MORPH_ENTRY_BYTES;
        f->weights[e[0]] = decode_morph_weight(int16_t(uint16_t(e[1] | (e[2] << 8))));
        f->whave[e[0]] = 1;
    }
    f->has_weights = true;
    return true;
}

float PoseBuffer::weight_as_of(const Frame& at, int m) const {
    const Frame* best = nullptr;
    for (const auto& f : frames_) {
        if (!f.used || !f.has_weights || !f.whave[size_t(m)] || newer(f.tick, at.tick)) continue;
        if (!best || newer(f.tick, best->tick)) best = &f;
    }
    if (best) return best->weights[size_t(m)];
    return held_w_have_[size_t(m)] ? held_w_[size_t(m)] : 0.0f;
}

void PoseBuffer::weights_at(double d, std::span<float> out) const {
    const void *pa, *pa0, *pc, *pc1;
    auto time = [&](const Frame* f) { return sample_time(*f); };
    neighbours(frames_, d, [](const Frame&) { return true; }, time, pa, pa0, pc, pc1);
    const Frame *a = static_cast<const Frame*>(pa), *c = static_cast<const Frame*>(pc);
    const int n = std::min(morphs_, int(out.size()));
    for (int m = 0; m < n; ++m) {
        if (a && c) {
            const float u = float((d - time(a)) / (time(c) - time(a)));
            const float wa = weight_as_of(*a, m), wc = weight_as_of(*c, m);
            out[size_t(m)] = wa + (wc - wa) * u;
        } else if (a || c) {
            out[size_t(m)] = weight_as_of(a ? *a : *c, m);
        } else {
            out[size_t(m)] = held_w_have_[size_t(m)] ? held_w_[size_t(m)] : 0.0f;
        }
    }
}

double PoseBuffer::sample_of(uint32_t t) const {
    const Frame* f = frame_at(t);
    return f ? sample_time(*f) : tick_time(t);
}

double PoseBuffer::needed_from(uint32_t tick, int b) const {
    const Frame* at = nullptr;
    const Frame* before = nullptr;   // the newest kept frame before `tick` that carries bone b
    const Frame* before2 = nullptr;  // the one before that
    for (const auto& f : frames_) {
        if (!f.used) continue;
        if (f.tick == tick) {
            at = &f;
        } else if (int32_t(tick - f.tick) > 0 && b >= 0 && size_t(b) < f.have.size() && f.have[size_t(b)]) {
            if (!before || int32_t(f.tick - before->tick) > 0) {
                before2 = before;
                before = &f;
            } else if (!before2 || int32_t(f.tick - before2->tick) > 0) {
                before2 = &f;
            }
        }
    }
    // As last_gap: a frame more than HOLD_TICKS before shows the bone again
    // rather than refreshing it, and the display never interpolates across
    // an epoch (a wrap, a teleport): the frame was needed from its own tick.
    if (!before || int32_t(tick - before->tick) > HOLD_TICKS || (at && at->epoch != before->epoch)) return tick_time(tick);
    // The cubic between `before` and the frame before it takes this one as
    // its outer neighbour (pose_about_pivot's c1); without it that span is
    // linear (at the full rate tens of times the cubic's error: a repair
    // that came as the display entered that span): needed from there (an
    // epoch only moves on, so one of another epoch has none of its own before it).
    if (before2 && before2->epoch == before->epoch && int32_t(before->tick - before2->tick) <= HOLD_TICKS)
        return sample_time(*before2);
    return sample_time(*before);
}

int PoseBuffer::bones_at(double d) const {
    const Frame* newest_before = nullptr;
    const Frame* first_after = nullptr;
    for (const auto& f : frames_) {
        if (!f.used || f.count == 0) continue;
        const double t = tick_time(f.tick);
        if (t <= d) {
            if (!newest_before || newer(f.tick, newest_before->tick)) newest_before = &f;
        } else if (!first_after || newer(first_after->tick, f.tick)) {
            first_after = &f;
        }
    }
    const Frame* f = newest_before ? newest_before : first_after;
    if (!f) return 0;
    // show >= total >= the bones this frame carries, all of which were received.
    int have = 0;
    while (have < f->show && last_have_[size_t(have)]) ++have;
    return have;
}

int PoseBuffer::bones_recorded(double d, int bones) const {
    if (!any_ || !std::isfinite(d)) return 0;
    const double lo = std::floor(d);
    const Frame* a = nullptr;
    const Frame* c = nullptr;
    for (const auto& f : frames_) {
        if (!f.used) continue;
        const double t = tick_time(f.tick);
        if (t == lo) a = &f;
        else if (t == lo + 1) c = &f;
    }
    if (!a || (d != lo && !c)) return 0;
    int n = 0;
    for (int b = 0; b < std::min(bones, bones_); ++b)
        n += a->have[size_t(b)] && (d == lo || c->have[size_t(b)]) ? 1 : 0;
    return n;
}

bool PoseBuffer::pose(int b, double d, BonePose& out, double* held_at, double* anchor_at) const {
    if (!pose_about_pivot(b, d, out, held_at, anchor_at)) return false;
    out.t -= out.s * (out.r * fmt_.pivots[size_t(b)]);
    return true;
}

bool PoseBuffer::pose_about_pivot(int b, double d, BonePose& out, double* held_at, double* anchor_at) const {
    if (held_at) *held_at = d + 1.0;
    if (anchor_at) *anchor_at = std::nan("");
    const void *pa, *pa0, *pc, *pc1;
    auto time = [&](const Frame* f) { return sample_time(*f); };
    neighbours(frames_, d, [&](const Frame& f) { return f.have[size_t(b)] != 0; }, time, pa, pa0, pc, pc1);
    const Frame *a = static_cast<const Frame*>(pa), *a0 = static_cast<const Frame*>(pa0), *c = static_cast<const Frame*>(pc),
                *c1 = static_cast<const Frame*>(pc1);
    if (a && c) {
        // The stream's interpolation policy (pose.h), but linear between the
        // samples of adjacent ticks of a linearly keyed clip (one of them at
        // its key since the tick before: the clip is straight between them).
        const bool keyed = (a->sample || c->sample) && c->tick - a->tick == 1;
        const bool outer = a0 && c1 && !keyed;
        out = interpolate_between(outer ? &a0->bones[b] : nullptr, a->bones[b], c->bones[b], outer ? &c1->bones[b] : nullptr,
                                  outer ? time(a0) : 0.0, time(a), time(c), outer ? time(c1) : 0.0, d);
        return true;
    }
    if (a && boundary_) {
        // Between two epochs? The first frame after d carrying bone b (of
        // another epoch, as none of a's follows), and the ones after it.
        auto step = [&](const Frame* from, bool forward) {  // the next frame of from's epoch carrying b
            const Frame* best = nullptr;
            for (const auto& f : frames_) {
                if (!f.used || !f.have[size_t(b)] || f.epoch != from->epoch || &f == from) continue;
                if (forward ? time(&f) <= time(from) : time(&f) >= time(from)) continue;
                if (!best || (forward ? newer(best->tick, f.tick) : newer(f.tick, best->tick))) best = &f;
            }
            return best;
        };
        const Frame* n = nullptr;
        for (const auto& f : frames_)
            if (f.used && f.have[size_t(b)] && time(&f) > d && (!n || newer(n->tick, f.tick))) n = &f;
        // Past a known boundary with nothing of the next epoch here yet (its
        // first frames lost or late): the caller carries the newest frame
        // along the clip across the boundary, rather than holding the old
        // epoch's pose where the new one has already begun.
        if (!n && anchor_at && d > time(a)) {
            const double w = boundary_(boundary_ctx_, time(a), d);
            if (w > time(a) && w <= d) {
                out = a->bones[b];
                *anchor_at = time(a);
                return true;
            }
        }
        const double w = n ? boundary_(boundary_ctx_, time(a), time(n)) : std::nan("");
        if (n && w > time(a) && w <= time(n)) {
            // Extrapolate the side of the display time from its two nearest
            // frames (linear: a quadratic follows the kinks of keyframed
            // motion worse, measured on Fox's Run cut mid-stride).
            const Frame* p0 = d < w ? a : n;
            if (anchor_at) {
                out = p0->bones[b];
                *anchor_at = time(p0);
                return true;
            }
            const Frame* p1 = step(p0, d >= w);
            if (p1)
                out = interpolate(p0->bones[b], p1->bones[b], float((d - time(p0)) / (time(p1) - time(p0))));
            else
                out = p0->bones[b];
            return true;
        }
    }
    if (a) {  // hold the newest (of its epoch)
        out = a->bones[b];
        if (held_at) *held_at = time(a);
        return true;
    }
    if (c) { out = c->bones[b]; return true; }
    if (last_have_[b]) { out = last_[b]; return true; }
    return false;
}

bool PoseBuffer::root(double d, RootPose& out) const {
    const void *pa, *pa0, *pc, *pc1;
    auto time = [&](const Frame* f) { return tick_time(f->tick); };  // roots are the tick's
    neighbours(frames_, d, [](const Frame& f) { return f.has_root; }, time, pa, pa0, pc, pc1);
    const Frame *a = static_cast<const Frame*>(pa), *a0 = static_cast<const Frame*>(pa0), *c = static_cast<const Frame*>(pc);
    if (a && c) {
        out = interpolate(a->root, c->root, (d - time(a)) / (time(c) - time(a)));
        return true;
    }
    // Past the newest root of its epoch: carried on along the two newest for
    // at most kRootExtrapolationTicks, then held (a walking character held
    // in place lags by its speed times the wait).
    // (Not when a root of another epoch follows d: a teleport is no motion.)
    bool later = false;
    for (const auto& f : frames_) later = later || (f.used && f.has_root && time(&f) > d);
    if (a && a0 && !later && root_extrapolation_ > 0) {
        const double span = time(a) - time(a0), h = std::min(d - time(a), root_extrapolation_);
        if (span > 0 && span <= double(HOLD_TICKS) && h > 0) {
            out = interpolate(a0->root, a->root, 1.0 + h / span);
            return true;
        }
    }
    if (a || c) {
        out = (a ? a : c)->root;
        return true;
    }
    return false;
}

}  // namespace progskin::net
