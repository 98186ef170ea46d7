// frame_encoder.cpp — see frame_encoder.h.
#include "frame_encoder.h"

#include <random>

#include <algorithm>
#include <atomic>
#include <utility>
#include <cmath>

#include "errors.h"
#include "root_block.h"

namespace progskin::net {

FrameEncoder::FrameEncoder(std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances,
                           float tick_rate)
    : assets_(std::move(assets)), tick_rate_(tick_rate) {
    std::random_device rd;
    while (world_tag_ == 0) world_tag_ = rd() & 0xffffffu;
    size_t max_joints = 0;
    for (const auto& a : assets_) {
        stride_ = std::max(stride_, size_t(a->bone_count()) * size_t(a->format.size()));
        max_bones_ = std::max(max_bones_, size_t(a->bone_count()));
        rel_stride_ = std::max(rel_stride_, (size_t(a->bone_count()) * size_t(kMaxRecordBits) + 7) / 8);
        max_joints = std::max(max_joints, a->character.joint_count());
        morph_stride_ = std::max(morph_stride_, std::min<size_t>(a->character.morphs.size(), MAX_MORPHS));
        max_morphs_ = std::max(max_morphs_, a->character.morphs.size());
    }
    max_joints_ = max_joints;
    set_pool(nullptr);
    std::vector<glm::dmat4> first(max_joints), last(max_joints);
    for (const auto& a : assets_) {
        auto& keys = keys_.emplace_back();
        for (const ClipSelection& sel : a->selections) {
            Keys& k = keys.emplace_back();
            k.times = linear_key_times(a->character, sel);
            std::vector<double> gaps;
            for (size_t i = 1; i < k.times.size(); ++i) gaps.push_back(k.times[i] - k.times[i - 1]);
            if (gaps.empty()) {
                k.times.clear();
            } else {
                std::nth_element(gaps.begin(), gaps.begin() + long(gaps.size() / 2), gaps.end());
                k.spacing = gaps[gaps.size() / 2];
            }
        }
        auto& flags = seamless_.emplace_back();
        const size_t J = a->character.joint_count();
        for (const ClipSelection& sel : a->selections) {
            sample_skinning_matrices(a->character, sel, sel.start, std::span<glm::dmat4>(first.data(), J));
            sample_skinning_matrices(a->character, sel, sel.end, std::span<glm::dmat4>(last.data(), J));
            // A point at the bind radius moves at most |dR| r + |dt| between them.
            double worst = 0;
            for (size_t j = 0; j < J; ++j) {
                double rot = 0, tr = 0;
                for (int c = 0; c < 3; ++c) {
                    for (int r = 0; r < 3; ++r) rot = std::max(rot, std::fabs(first[j][c][r] - last[j][c][r]));
                    tr = std::max(tr, std::fabs(first[j][3][c] - last[j][3][c]));
                }
                worst = std::max(worst, 3.0 * rot * a->bind_radius + 1.75 * tr);
            }
            flags.push_back(worst <= 1e-4 * a->diagonal ? 1 : 0);
        }
    }
    slots_.reserve(instances.size());
    for (size_t i = 0; i < instances.size(); ++i) {
        try {
            add_instance(instances[i]);
        } catch (const Error& e) {
            throw Error("instance " + std::to_string(i) + ": " + e.what());
        }
    }
}

int FrameEncoder::add_instance(const InstanceSpec& s) {
    if (s.asset < 0 || s.asset >= int(assets_.size())) throw Error("no asset " + std::to_string(s.asset));
    const ServerAsset& a = *assets_[s.asset];
    if (s.selection >= int(a.selections.size())) throw Error("no clip selection " + std::to_string(s.selection));
    if (!std::isfinite(s.speed) || !std::isfinite(s.time_offset)) throw Error("clip speed and offset must be finite");
    // Its Instance table must fit every InstanceAdded (MAX_INSTANCE_TABLE_BYTES).
    const size_t clips = s.selection >= 0 ? a.selections[size_t(s.selection)].clips.size() : s.announced_clips.size();
    if (clips > MAX_INSTANCE_CLIPS)
        throw Error("an instance plays at most " + std::to_string(MAX_INSTANCE_CLIPS) + " clips (" + std::to_string(clips) + " given)");
    std::lock_guard lock(mutex_);
    int id;
    // Reuse the id freed longest ago only once a few have been freed, so a
    // client rarely sees an id come back soon after it went.
    if (free_.size() > 64 || (!free_.empty() && slots_.size() >= MAX_INSTANCES)) {
        id = free_.front();
        free_.pop_front();
    } else if (slots_.size() < MAX_INSTANCES) {
        id = int(slots_.size());
        slots_.emplace_back();
    } else {
        throw Error("every instance id is taken (" + std::to_string(MAX_INSTANCES) + ")");
    }
    Slot& slot = slots_[size_t(id)];
    slot.spec = s;
    slot.active = true;
    ++slot.generation;
    if (slot.spec.world_id == 0)  // this node's tag | the slot's generation | the id: never the same twice in a process
        slot.spec.world_id = uint64_t(world_tag_) << 40 | uint64_t(slot.generation & 0xffffffu) << 16 | uint64_t(id);
    slot.live = s.selection < 0;
    slot.has_pose = false;
    slot.records.assign(size_t(a.bone_count()) * size_t(a.format.size()), 0);
    slot.exact.clear();
    slot.relative = false;
    slot.pose_seq = 0;
    slot.live_epoch = 0;
    ++slot.teleports;  // a new occupant of the slot is a discontinuity
    slot.has_root = false;
    slot.morphs.clear();
    slot.changed = true;
    slot.rel_ready = false;
    return id;
}

void FrameEncoder::remove_instance(int id) {
    std::lock_guard lock(mutex_);
    if (id < 0 || size_t(id) >= slots_.size() || !slots_[size_t(id)].active) return;
    slots_[size_t(id)].active = false;
    slots_[size_t(id)].records.clear();
    free_.push_back(id);
}

bool FrameEncoder::active(int id) const {
    std::lock_guard lock(mutex_);
    return id >= 0 && size_t(id) < slots_.size() && slots_[size_t(id)].active;
}

InstanceSpec FrameEncoder::spec(int id) const {
    std::lock_guard lock(mutex_);
    if (id < 0 || size_t(id) >= slots_.size() || !slots_[size_t(id)].active) throw Error("no instance " + std::to_string(id));
    return slots_[size_t(id)].spec;
}

bool FrameEncoder::spec_if_active(int id, InstanceSpec& out) const {
    std::lock_guard lock(mutex_);
    if (id < 0 || size_t(id) >= slots_.size() || !slots_[size_t(id)].active) return false;
    out = slots_[size_t(id)].spec;
    return true;
}

void FrameEncoder::generations(std::vector<uint32_t>& out) const {
    std::lock_guard lock(mutex_);
    out.resize(slots_.size());
    for (size_t i = 0; i < slots_.size(); ++i) out[i] = slots_[i].active ? slots_[i].generation : 0;
}

std::vector<int> FrameEncoder::active_ids() const {
    std::lock_guard lock(mutex_);
    std::vector<int> out;
    for (size_t i = 0; i < slots_.size(); ++i)
        if (slots_[i].active) out.push_back(int(i));
    return out;
}

size_t FrameEncoder::capacity() const {
    std::lock_guard lock(mutex_);
    return slots_.size();
}

EncoderStats FrameEncoder::stats() const {
    std::lock_guard lock(mutex_);
    return stats_;
}

double FrameEncoder::clip_time(int instance, double tick, int64_t* loops) const {
    std::lock_guard lock(mutex_);
    const auto& s = slots_.at(size_t(instance)).spec;
    if (loops) *loops = 0;
    if (s.selection < 0) return 0.0;
    return assets_[s.asset]->selections[s.selection].played(s.time_offset + tick / tick_rate_ * s.speed, s.once, loops);
}

bool FrameEncoder::push_pose(int instance, std::span<const Mat34> skinning) {
    std::lock_guard lock(mutex_);
    if (instance < 0 || size_t(instance) >= slots_.size() || !slots_[size_t(instance)].active)
        throw Error("push_pose: no instance " + std::to_string(instance));
    Slot& slot = slots_[size_t(instance)];
    const ServerAsset& a = *assets_[slot.spec.asset];
    if (skinning.size() != a.character.joint_count())
        throw Error("push_pose: instance " + std::to_string(instance) + " takes " + std::to_string(a.character.joint_count()) +
                    " matrices");
    const size_t rs = size_t(a.format.size());
    // Decomposed once, into the scratch: a refused pose leaves the slot's as it was.
    pushed_.resize(size_t(a.bone_count()));
    for (int b = 0; b < a.bone_count(); ++b) {
        pushed_[size_t(b)] = decompose(skinning[size_t(a.skin.order[b])]);
        if (!bone_in_range(pushed_[size_t(b)], a.format)) {
            ++stats_.poses_out_of_range;
            return false;
        }
    }
    slot.exact.swap(pushed_);
    for (int b = 0; b < a.bone_count(); ++b) encode_bone(slot.exact[size_t(b)], a.format, slot.records.data() + size_t(b) * rs);
    slot.live = slot.has_pose = true;
    slot.relative = false;
    slot.changed = true;
    return true;
}

FrameEncoder::Slot* FrameEncoder::pose_slot(int instance, uint32_t pose_seq, std::span<const int16_t> morphs) {
    if (instance < 0 || size_t(instance) >= slots_.size() || !slots_[size_t(instance)].active) return nullptr;
    Slot& slot = slots_[size_t(instance)];
    if (slot.has_pose && int32_t(pose_seq - slot.pose_seq) < 0) {
        ++stats_.stale_poses;
        return nullptr;
    }
    if (!morphs.empty() && morphs.size() != std::min<size_t>(assets_[slot.spec.asset]->character.morphs.size(), MAX_MORPHS))
        return nullptr;
    return &slot;
}

void FrameEncoder::take_pose(Slot& slot, uint32_t pose_seq, uint8_t epoch, std::span<const uint8_t, ROOT_BYTES> root,
                             std::span<const int16_t> morphs, bool relative) {
    std::copy(root.begin(), root.end(), slot.root.begin());
    if (!morphs.empty()) slot.morphs.assign(morphs.begin(), morphs.end());  // capacity kept after the first
    slot.relative = relative;
    slot.pose_seq = pose_seq;
    slot.live_epoch = epoch;
    slot.live = slot.has_pose = slot.has_root = true;
    slot.changed = true;
}

bool FrameEncoder::push_records(int instance, uint32_t pose_seq, uint8_t epoch, int first, std::span<const uint8_t> records,
                                std::span<const uint8_t, ROOT_BYTES> root, std::span<const int16_t> morphs) {
    std::lock_guard lock(mutex_);
    Slot* slot = pose_slot(instance, pose_seq, morphs);
    if (!slot) return false;
    const size_t rs = size_t(assets_[slot->spec.asset]->format.size());
    if (first < 0 || records.size() % rs != 0 || size_t(first) * rs + records.size() > slot->records.size()) return false;
    std::copy(records.begin(), records.end(), slot->records.begin() + long(size_t(first) * rs));
    slot->exact.clear();
    take_pose(*slot, pose_seq, epoch, root, morphs, false);
    return true;
}

bool FrameEncoder::push_relative(int instance, uint32_t pose_seq, uint8_t epoch, int first, std::span<const RecordInts> records,
                                 std::span<const uint8_t, ROOT_BYTES> root, std::span<const int16_t> morphs, uint8_t sample) {
    std::lock_guard lock(mutex_);
    Slot* slot = pose_slot(instance, pose_seq, morphs);
    if (!slot) return false;
    const size_t B = size_t(assets_[slot->spec.asset]->bone_count());
    if (first < 0 || size_t(first) + records.size() > B) return false;
    if (slot->rel.size() != B || !slot->relative) slot->rel.assign(B, RecordInts{});  // a bone not sent yet: the bind pose
    std::copy(records.begin(), records.end(), slot->rel.begin() + first);
    slot->sample = sample;
    take_pose(*slot, pose_seq, epoch, root, morphs, true);
    return true;
}

bool FrameEncoder::compose_live(Slot& slot, const ServerAsset& a, Work& w) {
    const RelativeFormat& f = a.relative;
    const size_t rs = size_t(a.format.size());
    for (int b = 0; b < a.bone_count(); ++b) {
        const BonePose rel = dequantise_record(slot.rel[size_t(b)], b, f);
        const int p = f.parents[size_t(b)];
        BonePose& m = w.model[size_t(b)];
        m = p < 0 ? rel : compose_relative(w.model[size_t(p)], rel);
        if (!bone_in_range(m, a.format)) {
            ++w.stats.poses_out_of_range;
            return false;
        }
    }
    for (int b = 0; b < a.bone_count(); ++b) encode_bone(w.model[size_t(b)], a.format, slot.records.data() + size_t(b) * rs);
    return true;
}

void FrameEncoder::set_pool(TickPool* pool) {
    std::lock_guard lock(mutex_);
    pool_ = pool;
    work_.resize(pool ? size_t(pool->threads()) : 1);
    for (Work& w : work_) {
        w.bits.reserve(rel_stride_);
        w.model.resize(max_bones_);
        w.decoded.resize(max_bones_);
        w.mats.resize(max_joints_);
        w.weights.resize(max_morphs_);
    }
}

bool FrameEncoder::set_root(int instance, const RootPose& root, bool teleport) {
    std::array<uint8_t, ROOT_BYTES> block;
    if (!encode_root(root, block.data())) return false;
    std::lock_guard lock(mutex_);
    if (instance < 0 || size_t(instance) >= slots_.size() || !slots_[size_t(instance)].active) return false;
    Slot& slot = slots_[size_t(instance)];
    slot.root = block;
    slot.has_root = true;
    slot.changed = true;
    if (teleport) ++slot.teleports;
    return true;
}

const EncodedFrame& FrameEncoder::encode(uint32_t tick) {
    std::lock_guard lock(mutex_);
    frame_.tick = tick;
    if (frame_.instances.size() < slots_.size()) {
        frame_.instances.resize(slots_.size());
        frame_.bytes.resize(slots_.size() * stride_);
        frame_.morph.resize(slots_.size() * morph_stride_, kNoWeight);
        frame_.rel.resize(slots_.size() * rel_stride_);
        frame_.bit_offsets.resize(slots_.size() * (max_bones_ + 1));
        frame_.ints.resize(slots_.size() * max_bones_);
        frame_.ring_bones = max_bones_;
        frame_.hist.resize(slots_.size() * kBaselineRing * max_bones_);
        frame_.hist_tick.resize(slots_.size() * kBaselineRing, 0);
        frame_.hist_gen.resize(slots_.size() * kBaselineRing, 0);
        frame_.hist_root.resize(slots_.size() * kBaselineRing);
        frame_.hist_has_root.resize(slots_.size() * kBaselineRing, 0);
        frame_.hist_sample.resize(slots_.size() * kBaselineRing, 0);
        const size_t had = frame_.predicted_.size();
        frame_.predicted_.resize(slots_.size() * kPredictedPerSlot);
        frame_.published_.resize(frame_.predicted_.size());
        for (size_t k = had; k < frame_.predicted_.size(); ++k) {
            frame_.predicted_[k].bits.reserve(rel_stride_ + 8);
            frame_.predicted_[k].offsets.resize(max_bones_ + 1);
        }
    }
    for (size_t k = 0; k < frame_.published_.n; ++k)  // coded again on first use this tick
        frame_.published_.v[k].store(0, std::memory_order_relaxed);
    frame_.epoch = (frame_.epoch + 1) & 0xFFFFF;
    if (frame_.epoch == 0) {  // the 20-bit epoch wrapped: no entry of the cache may match again
        for (size_t k = 0; k < EncodedFrame::OwnCache::kEntries; ++k) frame_.own_cache->entries[k].store(0, std::memory_order_relaxed);
        frame_.epoch = 1;
    }
    // Every slot by one thread, with that thread's scratch: a run of
    // kPoolRun slots at a time, so that threads share out a tick of mixed
    // clip and live characters.
    const size_t n = slots_.size();
    if (pool_ && pool_->threads() > 1 && n >= kPoolFrom) {
        std::atomic<size_t> next{0};
        auto job = [&](int t) {
            Work& w = work_[size_t(t)];
            for (size_t at = next.fetch_add(kPoolRun); at < n; at = next.fetch_add(kPoolRun))
                for (size_t i = at; i < std::min(n, at + kPoolRun); ++i) encode_slot(i, tick, w);
        };
        pool_->run(job);
    } else {
        for (size_t i = 0; i < n; ++i) encode_slot(i, tick, work_[0]);
    }
    for (Work& w : work_) {
        stats_.poses_out_of_range += std::exchange(w.stats.poses_out_of_range, 0);
        stats_.morphs_out_of_range += std::exchange(w.stats.morphs_out_of_range, 0);
        stats_.records_refused += std::exchange(w.stats.records_refused, 0);
    }
    frame_.grid.begin();
    for (size_t i = 0; i < slots_.size(); ++i)
        if (const EncodedInstance& e = frame_.instances[i]; e.active)
            frame_.grid.add({uint32_t(i), e.generation, e.owner, e.world, assets_[size_t(e.asset)]->diagonal});
    frame_.grid.finish();
    return frame_;
}

void FrameEncoder::encode_slot(size_t i, uint32_t tick, Work& w) {
    Slot& slot = slots_[i];
    auto& e = frame_.instances[i];
    e.active = slot.active;
    e.valid = false;
    if (!slot.active) return;
    const auto& s = slot.spec;
    const ServerAsset& a = *assets_[s.asset];
    e.asset = s.asset;
    e.bone_count = a.bone_count();
    e.record_size = a.format.size();
    e.offset = i * stride_;
    e.generation = slot.generation;
    e.owner = s.owner;
    e.morph_count = 0;
    e.morph_offset = i * morph_stride_;
    e.rel_offset = i * rel_stride_;
    e.bit_index = i * (max_bones_ + 1);
    uint8_t* out = frame_.bytes.data() + e.offset;
    e.model = slot.live || s.selection < 0 ? int(a.selections.size()) : s.selection;
    e.flags = uint8_t((a.format.scaled ? CHUNK_SCALED : 0) | (slot.has_root ? CHUNK_ROOT : 0));
    e.sample = 0;
    if (slot.has_root) {
        e.root = slot.root;
        e.world = decode_root(slot.root.data()).position;
    } else {
        e.world = glm::dvec3(s.position);
    }
    if (slot.changed || !slot.live) slot.changed_tick = tick;
    const bool changed = slot.changed;
    slot.changed = false;
    e.changed_tick = slot.changed_tick;
    if (slot.live) {
        if (!slot.has_pose) return;
        if (slot.relative && (changed || !slot.rel_ready) && !compose_live(slot, a, w)) {
            slot.rel_ready = false;
            return;  // counted; not sent this tick
        }
        std::copy(slot.records.begin(), slot.records.end(), out);
        if (changed || !slot.rel_ready) {
            const size_t rs = size_t(e.record_size);
            if (!slot.relative && slot.exact.size() == size_t(e.bone_count))
                std::copy(slot.exact.begin(), slot.exact.end(), w.model.begin());
            else if (!slot.relative)
                for (int b = 0; b < e.bone_count; ++b) w.model[size_t(b)] = decode_bone(out + size_t(b) * rs, a.format);
            slot.rel_ready = encode_relative(i, a, w);
            if (!slot.rel_ready) return;  // counted; not sent this tick
        }
        if (!slot.morphs.empty()) {
            e.morph_count = int(slot.morphs.size());
            std::copy(slot.morphs.begin(), slot.morphs.end(), frame_.morph.begin() + long(e.morph_offset));
        }
        e.epoch = uint8_t(slot.teleports + slot.live_epoch);
        e.sample = slot.relative ? slot.sample : 0;
        e.valid = true;
        keep_baseline(i, tick, slot.generation);
        return;
    }
    const int J = int(a.character.joint_count());
    std::span<glm::dmat4> mats(w.mats.data(), size_t(J));
    const ClipSelection& sel = a.selections[size_t(s.selection)];
    int64_t loops = 0;
    const double at_tick = sel.played(s.time_offset + double(tick) / tick_rate_ * s.speed, s.once, &loops);
    const double t = key_sample(s, sel, keys_[size_t(s.asset)][size_t(s.selection)], tick, at_tick, loops, e.sample);
    sample_skinning_matrices(a.character, sel, t, mats);
    const size_t rs = size_t(e.record_size);
    for (int b = 0; b < e.bone_count; ++b) {
        const BonePose p = decompose(Mat34::from_glm(mats[size_t(a.skin.order[b])]));
        if (!bone_in_range(p, a.format)) ++w.stats.poses_out_of_range;  // the box covers the clips: never expected
        encode_bone(p, a.format, out + size_t(b) * rs);
        w.model[size_t(b)] = p;
    }
    if (!encode_relative(i, a, w)) return;  // counted; not sent this tick
    if (!a.character.morphs.empty()) {
        sample_morph_weights(a.character, sel, t, std::span<float>(w.weights.data(), a.character.morphs.size()));
        e.morph_count = int(std::min<size_t>(a.character.morphs.size(), MAX_MORPHS));
        int32_t* q_out = frame_.morph.data() + e.morph_offset;
        for (int m = 0; m < e.morph_count; ++m) {
            int16_t q;
            if (encode_morph_weight(w.weights[size_t(m)], q)) {
                q_out[m] = q;
            } else {
                q_out[m] = kNoWeight;
                ++w.stats.morphs_out_of_range;
            }
        }
    }
    if (seamless_[size_t(s.asset)][size_t(s.selection)]) loops = 0;  // the wrap is no discontinuity
    e.epoch = uint8_t(int64_t(slot.teleports) + loops);
    e.valid = true;
    keep_baseline(i, tick, slot.generation);
}

// A linearly keyed clip moves along straight lines between its keys: a
// tick samples it at its latest key since the tick before (the kink there),
// else half a tick before the tick (on the line), so that the client's linear interpolation
// between the samples of adjacent ticks follows the clip (PoseBuffer).
// Not when keys come closer than a tick apart (one sample per tick cannot
// take every kink; the tick's own time then).
double FrameEncoder::key_sample(const InstanceSpec& s, const ClipSelection& sel, const Keys& keys, uint32_t tick, double t,
                                int64_t loops, uint8_t& sample) const {
    sample = 0;
    if (!key_samples_ || keys.times.empty() || !(s.speed > 0) || keys.spacing / s.speed * tick_rate_ < 1.0) return t;
    sample = 1;  // keyed (at the tick while the clip stands still: once, at its end)
    int64_t prev_loops = 0;
    const double step = double(s.speed) / tick_rate_;  // clip seconds per tick
    const double tp = sel.played(s.time_offset + double(tick - 1) / tick_rate_ * s.speed, s.once, &prev_loops);
    const bool wrapped = prev_loops != loops;
    const double lo = wrapped ? double(sel.start) - 1e-9 : tp;
    if (!(t > lo)) return t;
    const double k = latest_key_in(keys.times, lo, t);
    // No key since the tick before: half a tick before the tick (on the
    // straight piece, away from the samples on either side).
    const double ticks = std::isnan(k) ? 0.5 : std::clamp((t - k) / step, 0.0, 1.0);
    const int q = std::min(254, int(std::lround(ticks * 254)));
    sample = uint8_t(1 + q);
    return std::max(wrapped ? double(sel.start) : tp, t - double(q) / 254 * step);
}

bool FrameEncoder::encode_relative(size_t i, const ServerAsset& a, Work& w) {
    const EncodedInstance& e = frame_.instances[i];
    const size_t B = size_t(a.bone_count());
    w.bits.clear();
    std::span<uint32_t> offsets(frame_.bit_offsets.data() + e.bit_index, B + 1);
    if (!encode_pose(std::span<const BonePose>(w.model.data(), B), a.relative, w.bits, offsets,
                     std::span<BonePose>(w.decoded.data(), B), std::span<RecordInts>(frame_.ints.data() + i * max_bones_, B))) {
        ++w.stats.records_refused;
        return false;
    }
    std::copy(w.bits.begin(), w.bits.end(), frame_.rel.begin() + long(e.rel_offset));
    return true;
}

void FrameEncoder::keep_baseline(size_t i, uint32_t tick, uint32_t generation) {
    const size_t k = i * kBaselineRing + tick % kBaselineRing;
    std::copy(frame_.ints.begin() + long(i * max_bones_), frame_.ints.begin() + long((i + 1) * max_bones_),
              frame_.hist.begin() + long(k * max_bones_));
    frame_.hist_tick[k] = tick;
    frame_.hist_gen[k] = generation;
    const EncodedInstance& e = frame_.instances[i];
    frame_.hist_has_root[k] = (e.flags & CHUNK_ROOT) != 0;
    frame_.hist_sample[k] = e.sample;
    if (frame_.hist_has_root[k]) frame_.hist_root[k] = e.root;
}

const uint8_t* EncodedFrame::root_at(int i, uint32_t t) const {
    if (!ints_at(i, t)) return nullptr;
    const size_t k = size_t(i) * kBaselineRing + t % kBaselineRing;
    return hist_has_root[k] ? hist_root[k].data() : nullptr;
}

uint8_t EncodedFrame::sample_at(int i, uint32_t t) const {
    if (!ints_at(i, t)) return 0;
    return hist_sample[size_t(i) * kBaselineRing + t % kBaselineRing];
}

const RecordInts* EncodedFrame::ints_at(int i, uint32_t t) const {
    const size_t k = size_t(i) * kBaselineRing + t % kBaselineRing;
    if (int32_t(tick - t) < 0 || int32_t(tick - t) >= kBaselineRing || hist_tick[k] != t ||
        hist_gen[k] != instances[size_t(i)].generation)
        return nullptr;
    return hist.data() + k * ring_bones;
}

EncodedFrame::PublishedBases& EncodedFrame::PublishedBases::operator=(const PublishedBases& o) {
    if (this == &o) return *this;
    v = o.n ? std::make_unique<std::atomic<uint8_t>[]>(o.n) : nullptr;
    n = o.n;
    for (size_t k = 0; k < n; ++k) v[k].store(o.v[k].load(std::memory_order_acquire), std::memory_order_relaxed);
    return *this;
}

void EncodedFrame::PublishedBases::resize(size_t m) {
    if (m == n) return;
    std::unique_ptr<std::atomic<uint8_t>[]> w = m ? std::make_unique<std::atomic<uint8_t>[]>(m) : nullptr;
    for (size_t k = 0; k < m; ++k) w[k].store(k < n ? v[k].load(std::memory_order_relaxed) : uint8_t(0), std::memory_order_relaxed);
    v = std::move(w);
    n = m;
}

const PredictedRecords* EncodedFrame::predicted(int i, uint8_t base) const {
    const EncodedInstance& e = instances[size_t(i)];
    if (base == 0) return nullptr;  // (0 marks a free slot)
    const size_t k0 = size_t(i) * kPredictedPerSlot;
    std::atomic<uint8_t>* const held = published_.v.get() + k0;  // the slot's kPredictedPerSlot bases
    // Coded already this tick: found without the lock (acquire: its records
    // were written before its base was published).
    for (size_t k = 0; k < kPredictedPerSlot; ++k)
        if (held[k].load(std::memory_order_acquire) == base) return &predicted_[k0 + k];
    // Else under the lock, which every store of the slot's bases holds.
    std::lock_guard lock((*predicted_locks)[size_t(i) % predicted_locks->size()]);
    size_t free = kPredictedPerSlot;
    for (size_t k = 0; k < kPredictedPerSlot; ++k) {
        const uint8_t b = held[k].load(std::memory_order_relaxed);
        if (b == base) return &predicted_[k0 + k];  // coded meanwhile
        if (free == kPredictedPerSlot && b == 0) free = k;
    }
    if (free == kPredictedPerSlot) return nullptr;
    PredictedRecords& p = predicted_[k0 + free];
    Baseline from;
    p.usable = baseline(i, base, from) && e.valid;
    if (!p.usable) {
        held[free].store(base, std::memory_order_release);
        return &p;
    }
    p.bits.clear();
    BitWriter w(p.bits);
    const RecordInts* now = ints.data() + size_t(i) * ring_bones;
    const bool scaled = (e.flags & CHUNK_SCALED) != 0;
    for (int b = 0; b < e.bone_count; ++b) {
        p.offsets[size_t(b)] = uint32_t(w.bits());
        write_predicted(now[b], from.predict(b), scaled, w);
    }
    p.offsets[size_t(e.bone_count)] = uint32_t(w.bits());
    held[free].store(base, std::memory_order_release);
    return &p;
}

}  // namespace progskin::net

namespace progskin::net {

bool EncodedFrame::baseline(int i, uint8_t base, Baseline& out) const {
    const uint32_t age = base & kBaseAgeMask;
    const bool linear = (base & kBaseLinear) != 0;
    const EncodedInstance& e = instances[size_t(i)];
    out.b1 = age ? ints_at(i, tick - age) : nullptr;
    out.b2 = linear ? ints_at(i, tick - 2 * age) : nullptr;
    if (!out.b1 || (linear && !out.b2)) return false;
    // Linear: along the samples' times (sample_age; 254 age and 508 age at ticks).
    out.a1 = linear ? sample_age(age, e.sample, sample_at(i, tick - age)) : age;
    out.a2 = linear ? sample_age(2 * age, e.sample, sample_at(i, tick - 2 * age)) : 0;
    return true;
}

bool EncodedFrame::own_prediction(int i, int b, uint8_t base, RecordInts& pred) const {
    Baseline from;
    if (b < 0 || b >= instances[size_t(i)].bone_count || !baseline(i, base, from)) return false;
    pred = from.predict(b);
    return true;
}

// The own-bits cache's key (without the bits: epoch, slot, bone, base
// index), 0 when not cached; and its entry.
static uint64_t own_key(uint32_t epoch, int i, int b, uint8_t base) {
    const uint32_t age = base & kBaseAgeMask;
    const uint64_t linear = (base & kBaseLinear) ? 1 : 0;
    if (!(age >= 1 && age <= kMaxBaseAge && i >= 0 && i < 0x10000 && b >= 0 && b < 0x100)) return 0;
    return (uint64_t(epoch) << 44) | (uint64_t(i) << 28) | (uint64_t(b) << 20) | (uint64_t((age - 1) * 2 + linear) << 15);
}
static size_t own_slot(uint64_t key) {
    return size_t((key * 0x9E3779B97F4A7C15ull) >> 40) & (EncodedFrame::OwnCache::kEntries - 1);
}

static constexpr int kRootKeyBone = 255;
static_assert(MAX_BONES <= kRootKeyBone, "bone 255 of the own-bits cache is the root block's");

size_t EncodedFrame::write_root_block(int i, uint8_t base, std::vector<uint8_t>& out) const {
    const uint32_t age = base & kBaseAgeMask;
    const uint8_t* b1 = age ? root_at(i, tick - age) : nullptr;
    const uint8_t* b2 = age && (base & kBaseLinear) ? root_at(i, tick - 2 * age) : nullptr;
    return write_root(instances[size_t(i)].root.data(), base, b1, b2, out);
}

// The length the cache holds under `key` (0: not cached) this tick, else
// compute()'s (SIZE_MAX: none), kept for the next asker.
template <class Compute>
static size_t cached_length(EncodedFrame::OwnCache& cache, uint64_t key, Compute compute) {
    constexpr uint64_t kBitsMask = 0xFFF, kKeyMask = ~kBitsMask & ~(uint64_t(7) << 12);
    std::atomic<uint64_t>* const entry = key ? &cache.entries[own_slot(key)] : nullptr;
    if (entry) {
        const uint64_t v = entry->load(std::memory_order_relaxed);
        if ((v & kKeyMask) == key) return (v & kBitsMask) == kBitsMask ? SIZE_MAX : size_t(v & kBitsMask);
    }
    const size_t n = compute();
    if (entry && (n == SIZE_MAX || n < kBitsMask)) entry->store(key | (n == SIZE_MAX ? kBitsMask : uint64_t(n)), std::memory_order_relaxed);
    return n;
}

size_t EncodedFrame::root_block_bytes(int i, uint8_t base) const {
    return cached_length(*own_cache, own_key(epoch, i, kRootKeyBone, base), [&] {
        thread_local std::vector<uint8_t> scratch;  // (grows once per thread)
        scratch.clear();
        return write_root_block(i, base, scratch);
    });
}

void EncodedFrame::own_prefetch(int i, int b, uint8_t base) const {
    if (const uint64_t key = own_key(epoch, i, b, base)) __builtin_prefetch(&own_cache->entries[own_slot(key)]);
}

size_t EncodedFrame::own_bits(int i, int b, uint8_t base) const {
    return cached_length(*own_cache, own_key(epoch, i, b, base), [&] {
        RecordInts pred;
        if (!own_prediction(i, b, base, pred)) return SIZE_MAX;
        return predicted_bits(ints[size_t(i) * ring_bones + size_t(b)], pred, (instances[size_t(i)].flags & CHUNK_SCALED) != 0);
    });
}

}  // namespace progskin::net
