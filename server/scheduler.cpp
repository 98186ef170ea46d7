// scheduler.cpp — see scheduler.h.
#include "scheduler.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>

#include "wire.h"

namespace progskin::net {

size_t WireCost::datagrams(size_t payload) {
    // room for one split chunk header and the tail a record does not fill
    const size_t cap = MAX_DATAGRAM - kFrameOverhead - kSplitChunk - 14;
    return std::max<size_t>(1, (payload + cap - 1) / cap);
}

size_t WireCost::wire(size_t payload) {
    size_t n = datagrams(payload);
    return payload + n * (kFrameOverhead + UDP_IP_OVERHEAD) + (n - 1) * kSplitChunk;
}

namespace {

using Weights = std::vector<std::pair<int, float>>;

// The view's weights sorted by instance, one per instance (the last one
// given wins): `w` itself when already so (read_view's), else a sorted copy.
const Weights& indexed_weights(const Weights& w, Weights& copy) {
    auto by_instance = [](const auto& a, const auto& b) { return a.first < b.first; };
    if (std::adjacent_find(w.begin(), w.end(), [](const auto& a, const auto& b) { return a.first >= b.first; }) == w.end())
        return w;  // strictly increasing
    copy = w;
    std::stable_sort(copy.begin(), copy.end(), by_instance);
    auto last = std::unique(copy.rbegin(), copy.rend(), [](const auto& a, const auto& b) { return a.first == b.first; });
    copy.erase(copy.begin(), last.base());
    return copy;
}

}  // namespace

// O(instances + weights): the weights are walked beside the slots, never
// scanned per instance (a View of thousands of weights costs what it is long).
void compute_importance(const ViewSpec& view, const EncodedFrame& frame,
                        const std::vector<std::shared_ptr<ServerAsset>>& assets, uint64_t viewer, std::vector<float>& imp,
                        const std::vector<uint32_t>* known) {
    imp.assign(frame.instances.size(), 0.0f);
    Weights copy;
    const Weights& weights = indexed_weights(view.weights, copy);
    size_t next = 0;  // first weight whose instance is >= the slot
    const float t = camera_tan(view);  // once per view, not per instance
    for (size_t i = 0; i < frame.instances.size(); ++i) {
        const EncodedInstance& e = frame.instances[i];
        while (next < weights.size() && weights[next].first < int(i)) ++next;
        if (!e.active || (viewer != 0 && e.owner == viewer)) continue;
        if (known && (i >= known->size() || (*known)[i] != e.generation)) continue;
        const ServerAsset& a = *assets[size_t(e.asset)];
        if (!weights.empty()) {
            const float w = next < weights.size() && weights[next].first == int(i) ? weights[next].second : 0.0f;
            imp[i] = std::max(0.0f, w) * float(1000.0 / a.diagonal);
        } else if (view.has_camera) {
            imp[i] = camera_importance(view, t, e.world, a.diagonal);
        } else {
            imp[i] = float(1000.0 / a.diagonal);
        }
    }
}

std::vector<float> compute_importance(const ViewSpec& view, const std::vector<InstanceSpec>& instances,
                                      const std::vector<std::shared_ptr<ServerAsset>>& assets) {
    EncodedFrame f;
    f.instances.resize(instances.size());
    for (size_t i = 0; i < instances.size(); ++i) {
        f.instances[i].active = true;
        f.instances[i].asset = instances[i].asset;
        f.instances[i].world = glm::dvec3(instances[i].position);
    }
    std::vector<float> imp;
    compute_importance(view, f, assets, 0, imp);
    return imp;
}

size_t morph_block_bytes(const std::array<uint64_t, 4>& mask) {
    if ((mask[0] | mask[1] | mask[2] | mask[3]) == 0) return 0;  // most chunks (std::popcount is a call without -mpopcnt)
    size_t n = 0;
    for (uint64_t w : mask) n += size_t(std::popcount(w));
    return n ? 1 + n * MORPH_ENTRY_BYTES : 0;
}

void Scheduler::morph_item(size_t i, const EncodedFrame& frame, const ServerAsset& a, double w) {
    MorphItem& it = sc_->morph[i];
    it = MorphItem{};
    const auto& e = frame.instances[i];
    if (e.morph_count == 0) return;
    State& st = state_[i];
    const size_t n = size_t(e.morph_count);
    if (st.morph_sent.size() != n) {
        st.morph_sent.assign(n, kNoWeight);
        st.morph_tick.assign(n, 0);
        st.morph_pending.assign(n, kNoWeight);
    }
    const std::span<const int32_t> q = frame.morphs(int(i));
    const double r2 = MORPH_REFRESH_WEIGHT * MORPH_REFRESH_WEIGHT;
    double value = 0;
    for (size_t m = 0; m < n; ++m) {
        st.morph_pending[m] = kNoWeight;
        if (q[m] == kNoWeight) continue;  // refused by the encoder this tick: nothing to send
        const bool never = st.morph_sent[m] == kNoWeight;
        const bool stale = never || int32_t(frame.tick - st.morph_tick[m]) >= MORPH_REFRESH_TICKS;
        const double d = double(q[m] - (never ? 0 : st.morph_sent[m])) / double(MORPH_WEIGHT_SCALE);
        if (d == 0 && !stale) continue;
        const double imp = m < a.morph_importance.size() ? a.morph_importance[m] : 0.0;
        value += imp * imp * (d * d + (stale ? r2 : 0.0));
        it.mask[m / 64] |= uint64_t(1) << (m % 64);
        st.morph_pending[m] = q[m];
    }
    it.value = w * value;
    it.bytes = morph_block_bytes(it.mask);
}

static_assert(HOLD_TICKS < ServerAsset::kGapTable, "the gap and refresh tables cover every age below the hold");

void Scheduler::reset(size_t n) {
    state_.assign(n, State{});
    generation_.assign(n, 0);
}

void Scheduler::Scratch::fit(size_t n) {
    if (slot.size() >= n) return;
    slot.resize(n);
    paid.resize(n, 0);
    chain_next.resize(n, 0);
    chain_tried.resize(n, 0);
    order_at.resize(n, 0);
    order_state.resize(n, 0);
    header.resize(n, 0);
    morph.resize(n);
    current.resize(n, 0);
    least.resize(n, SIZE_MAX);
    spent.resize(n, 0);
    floor_bytes.resize(n, 0);
    share_left.resize(n, 0);
}

// Slots added since the last tick: grow, keeping every other instance's
// state; a new instance in a slot (its generation changed): a fresh state.
void Scheduler::track_slots(const EncodedFrame& frame) {
    const size_t n = frame.instances.size();
    if (state_.size() != n) {
        state_.resize(n);
        generation_.resize(n, 0);
    }
    for (const uint32_t i : active_)
        if (generation_[i] != frame.instances[i].generation) {
            generation_[i] = frame.instances[i].generation;
            state_[i] = State{};
        }
    sc_->fit(n);
}

// The morph item of every important instance (morph_item); returns the
// payload of everything: every bone and due weight of those instances.
size_t Scheduler::morph_items(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                              std::span<const float> importance) {
    size_t full = 0;
    std::fill(group_full_.begin(), group_full_.end(), 0);
    // The first pass over this client's per-instance state this tick: the
    // state of instances a few ahead is fetched from memory meanwhile (each
    // client's state is cold: the other clients' ticks ran since).
    constexpr size_t kAhead = 4;
    for (size_t k = 0; k < active_.size(); ++k) {
        if (k + 2 * kAhead < active_.size()) {
            const uint32_t j = active_[k + 2 * kAhead];
            __builtin_prefetch(&state_[j]);
            __builtin_prefetch(reinterpret_cast<const char*>(&state_[j]) + 64);
            __builtin_prefetch(&sc_->slot[j]);
        }
        if (k + kAhead < active_.size()) {
            const State& ahead = state_[active_[k + kAhead]];
            if (!ahead.bone_tick.empty()) __builtin_prefetch(ahead.bone_tick.data());
        }
        const uint32_t i = active_[k];
        const auto& e = frame.instances[i];
        sc_->current[i] = 0;
        const ServerAsset& a = *assets[size_t(e.asset)];
        if (state_[i].bone_tick.size() != size_t(a.bone_count())) {
            state_[i].bone_tick.assign(size_t(a.bone_count()), 0);
            state_[i].prev_tick.assign(size_t(a.bone_count()), 0);
        }
        morph_item(i, frame, a, double(importance[i]) * double(importance[i]) * double(a.character.vertex_count()));
        sc_->current[i] = up_to_date(i, frame);
        if (sc_->current[i]) continue;  // nothing to send (the fast path and the greedy skip it)
        sc_->header[i] = header_of(frame, int(i));  // (offer_items reads it)
        const size_t bytes = sc_->header[i] + (record_bits(frame, int(i), 0, e.bone_count) + 7) / 8 + sc_->morph[i].bytes;
        full += bytes;
        if (const uint32_t g = group_of(i); g > 0) {
            if (group_full_.size() <= g) group_full_.resize(size_t(g) + 1, 0);
            group_full_[g] += bytes;
        }
    }
    return full;
}

bool Scheduler::up_to_date(size_t i, const EncodedFrame& frame) const {
    const auto& e = frame.instances[i];
    if (e.changed_tick == frame.tick || sc_->morph[i].value > 0) return false;
    const State& st = state_[i];
    for (int b = 0; b < e.bone_count; ++b) {
        const uint32_t t = st.bone_tick[size_t(b)];
        if (t == 0 || int32_t(t - e.changed_tick) < 0 || (b > 0 && int32_t(frame.tick - t) >= HOLD_TICKS - 1)) return false;
    }
    return true;
}

// The fast path: every bone and due weight of every important instance.
void Scheduler::pick_everything(const EncodedFrame& frame, bool except_over_share,
                                std::vector<Pick>& out) {
    for (const uint32_t i : active_) {
        const auto& e = frame.instances[i];
        if (!sc_->current[i] && !(except_over_share && over_share(i))) {
            out.push_back({int(i), e.bone_count, e.bone_count});
            out.back().morphs = sc_->morph[i].mask;
            sc_->morph[i].chosen = true;
        }
    }
}

// Instance i's segments as items: value and bytes (scheduler.h). Shown
// segments (a prefix) are refresh items on their own; the ones after them
// are offered as the steps of their hull (offer_chain). One pass over the
// segments (and over each segment's bones once), which also finds what
// offer_items offers: the best shown item by value per (records + chunk
// header) (offer_unpaid's choice before anything is taken), the first
// unshown segment and the smallest item.
Scheduler::Offer Scheduler::segment_items(size_t i, const EncodedFrame& frame, const ServerAsset& a, double w, double to30,
                                           double step) {
    const std::span<SegItem> items = items_of(i);
    const auto& e = frame.instances[i];
    const uint32_t* tick_of = state_[i].bone_tick.data();
    const uint32_t* bits = plan_ ? plan_->bit_prefix(frame, int(i)) : frame.bit_prefix(int(i));  // record_bits
    const bool changed_now = e.changed_tick == frame.tick;
    const double header = double(sc_->header[i]);
    const size_t n = items.size();  // a.segments.size(): offer_items placed them
    Offer o;
    o.unshown = n;
    bool shown = true;
    size_t cb = 0;
    double cv = 0;
    for (size_t q = 0; q < n; ++q) {
        const ServerAsset::Segment& seg = a.segments[q];
        const int m = std::clamp(e.model, 0, int(seg.gap.size()) - 1);
        const size_t b = std::max<size_t>(1, (size_t(bits[seg.to] - bits[seg.from]) + 7) / 8);  // the real bits of its records
        // Shown: bone 0 once received (the client never drops it), every
        // further bone up to here refreshed within the hold. Current: every
        // bone sent since the content last changed (a live character not
        // posed again): worth nothing until its hold runs out.
        bool current = !changed_now;
        for (int x = seg.from; x < seg.to && (shown || current); ++x) {
            const uint32_t t = tick_of[x];
            if (t == 0) {
                shown = current = false;
                break;
            }
            if (x > 0 && int32_t(frame.tick - t) >= HOLD_TICKS) shown = false;
            if (int32_t(t - e.changed_tick) < 0) current = false;
        }
        double v;
        bool idle = false;
        if (shown && current) {
            const int32_t age = int32_t(frame.tick - tick_of[seg.to - 1]);
            idle = q == 0 || age < HOLD_TICKS - 1;  // bone 0 is never dropped
            v = idle ? 0.0 : seg.show_value[size_t(m)];
        } else if (shown) {
            const int32_t age = std::max(1, int32_t(frame.tick - tick_of[seg.to - 1]));
            const double g = double(age) * to30;
            if (step > 1.0) {
                // Sends every D ticks: refreshing now against at the next
                // send, a period of a against a + D (scheduler.h).
                const double dg = step * to30;
                v = g * (g + dg) * (seg.gap_at(m, g + dg) - seg.gap_at(m, g)) / dg;
            } else if (g == double(age) && age < ServerAsset::kGapTable) v = seg.refresh[size_t(m)][size_t(age)];
            else v = g * (g + 1.0) * (seg.gap_at(m, g + 1.0) - seg.gap_at(m, g));
            // Last tick of the hold: without a refresh the segment is dropped,
            // so refreshing it is worth at least showing it.
            if (q > 0 && age >= HOLD_TICKS - 1) v = std::max(v, seg.show_value[size_t(m)]);
        } else {
            // Not shown: worth its collapse error over the refresh period that
            // makes showing it most worthwhile (scene.h show_value).
            v = seg.show_value[size_t(m)];
            if (o.unshown == n) o.unshown = q;
        }
        SegItem& it = items[q];
        it = {w * v, b, seg.from, seg.to, shown, false, false, idle};
        o.least = std::min(o.least, b);
        if (!shown) {  // the hull's first vertex after the first unshown segment, as extend_chain finds it
            cb += b;
            cv += it.value;
            const ChainPoint pt{int(q + 1), cb, cv};
            if (q == o.unshown || no_less_steep(ChainPoint{int(o.unshown), 0, 0.0}, o.hull, pt)) o.hull = pt;
        }
        if (shown && it.value > 0) {
            const double r = it.value / (double(it.bytes) + header);
            if (r > o.ratio) {
                o.ratio = r;
                o.best = int(q);
            }
        }
    }
    return o;
}

// The unshown segments of instance i can only be shown in order: the upper
// concave hull of their cumulative (bytes, value), its first step offered.
// The hull is built as the greedy walks it (extend_chain): one step is
// offered at a time, and most instances take none or one in a tick.
void Scheduler::offer_chain(size_t i, uint32_t age, const Offer& o) {
    const Chain chain = chain_of(i);
    chain.clear();
    if (o.unshown >= sc_->slot[i].n) return;
    chain.push_back({int(o.unshown), 0, 0.0});
    chain.push_back(o.hull);  // extend_chain's first step, found by segment_items
    if (chain[1].value > 0) {
        push({chain[1].value / double(chain[1].bytes + sc_->header[i]), int(i), 1, age, true, false});
        sc_->chain_next[i] = 1;
    }
}

// From p0, the step to pt has at least the value per byte of the step to
// best (cross product; the hull keeps the farther of equal ones).
bool Scheduler::no_less_steep(const ChainPoint& p0, const ChainPoint& best, const ChainPoint& pt) {
    return double(best.bytes - p0.bytes) * (pt.value - p0.value) - double(pt.bytes - p0.bytes) * (best.value - p0.value) >= 0;
}

// The hull's next vertex after chain_of(i).back(): the point after it whose
// step has the greatest value per byte (of equal ones the farthest, as the
// hull drops collinear points). O(segments after it).
bool Scheduler::extend_chain(size_t i) {
    const std::span<const SegItem> items = items_of(i);
    const Chain chain = chain_of(i);
    const ChainPoint p0 = chain.back();
    if (size_t(p0.end) >= items.size()) return false;
    size_t cb = p0.bytes;
    double cv = p0.value;
    ChainPoint best{};
    for (size_t q = size_t(p0.end); q < items.size(); ++q) {
        cb += items[q].bytes;
        cv += items[q].value;
        const ChainPoint pt{int(q + 1), cb, cv};
        if (q == size_t(p0.end) || no_less_steep(p0, best, pt)) best = pt;
    }
    chain.push_back(best);
    return true;
}

// Room in the scratch for instance i's n items, its hull (n + 1 points)
// and its order (n); the scratch grows only past its largest tick.
void Scheduler::place(size_t i, size_t n) {
    Scratch& sc = *sc_;
    Slot& s = sc_->slot[i];
    s.items = uint32_t(sc.items_used);
    s.chain = uint32_t(sc.chain_used);
    s.order = uint32_t(sc.order_used);
    s.n = uint16_t(n);
    s.chain_n = s.order_n = 0;
    sc.items_used += n;
    sc.chain_used += n + 1;
    sc.order_used += n;
    if (sc.items.size() < sc.items_used) sc.items.resize(sc.items_used);
    if (sc.chain.size() < sc.chain_used) sc.chain.resize(sc.chain_used);
    if (sc.order.size() < sc.order_used) sc.order.resize(sc.order_used);
}

// Every important instance's items offered to the heap (before any header is paid).
void Scheduler::offer_items(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                            std::span<const float> importance, float tick_rate, bool only_over_share) {
    const double to30 = 30.0 / std::max(1.0f, tick_rate);
    const double step = refresh_step();  // D (scheduler.h)
    sc_->heap.clear();
    sc_->items_used = sc_->chain_used = sc_->order_used = 0;
    least_unpaid_ = least_paid_ = SIZE_MAX;
    for (const uint32_t i : active_) {
        sc_->slot[i].n = 0;
        const auto& e = frame.instances[i];
        if (sc_->current[i] || (only_over_share && !over_share(i))) continue;
        const ServerAsset& a = *assets[size_t(e.asset)];
        place(i, a.segments.size());
        sc_->paid[i] = 0;
        sc_->chain_next[i] = 0;
        sc_->chain_tried[i] = 0;
        // sc_->header[i]: set by morph_items (every instance not up to date)
        const State& st = state_[i];
        // Squared error in screen units, summed over the instance's vertices
        // (the RMS of docs/metrics.md §2 pools all vertices of all characters).
        const double w = double(importance[i]) * double(importance[i]) * double(a.character.vertex_count());
        const uint32_t stale = st.bone_tick[0] != 0 ? frame.tick - st.bone_tick[0] : UINT32_MAX;
        const Offer o = segment_items(i, frame, a, w, to30, step);
        // The fewest bytes any of its steps can take (take_greedily's stop).
        const size_t least = std::min(o.least, sc_->morph[i].value > 0 ? sc_->morph[i].bytes : SIZE_MAX);
        sc_->least[i] = least;
        if (least != SIZE_MAX) least_unpaid_ = std::min(least_unpaid_, least + sc_->header[i]);
        if (o.best >= 0) push({o.ratio, int(i), o.best, stale, false, false});  // offer_unpaid's choice
        // The morph item: on its own only once bone 0 was sent (its chunk needs show >= 1).
        if (sc_->morph[i].value > 0 && st.bone_tick[0] != 0)
            push({sc_->morph[i].value / double(sc_->morph[i].bytes + sc_->header[i]), int(i), 0, stale, false, false, true});
        offer_chain(i, stale, o);
    }
}

// Greedy over the items by value per byte, within `budget` wire bytes.
void Scheduler::take_greedily(size_t budget, size_t payload) {
    taken_ = &payload;
    budget_ = budget;
    while (!sc_->heap.empty()) {  // (push keeps the heap a heap)
        // Nothing left can fit: every step takes at least the bytes of
        // its instance's smallest item (plus its chunk header until paid),
        // and the payload only grows (the refusals would be all that is left).
        const size_t least = std::max<size_t>(1, std::min(least_unpaid_, least_paid_));
        if (least > budget || WireCost::wire(payload + least) > budget) break;
        // No instance not paid yet can take anything (its header with its
        // smallest item does not fit): its steps leave the heap at once
        // rather than each being popped and refused.
        if (least_unpaid_ != SIZE_MAX && (least_unpaid_ > budget || WireCost::wire(payload + least_unpaid_) > budget)) {
            least_unpaid_ = SIZE_MAX;
            keep_paid_steps();
            continue;
        }
        const Step s = pop();
        const size_t inst = size_t(s.instance);
        if (s.floor && sc_->spent[inst] >= sc_->floor_bytes[inst]) {  // its floor is spent: it waits its turn by ratio
            push(s);
            continue;
        }
        if (!s.paid && sc_->paid[inst]) continue;  // offered again at its records-only ratio
        const size_t header = sc_->paid[inst] ? 0 : sc_->header[inst];
        if (s.morph) take_morph(s, header, budget, payload);
        else if (s.chain) take_chain_step(s, header, budget, payload);
        else take_segment(s, header, budget, payload);
    }
    taken_ = nullptr;
}

// The heap is a 4-ary max-heap (half the depth of a binary one; Step's order
// is total, so any heap pops the same sequence).
void Scheduler::Step::order_key() {
    assert(instance >= 0 && instance <= 0xFFFF && step >= 0 && step < 0x1000);
    // Every push has value > 0 (a quotient that underflowed to 0 ties at 0,
    // as the plain comparison of doubles tied it; nothing negative is pushed).
    const double r = ratio > 0 ? ratio : 0.0;
    key_hi = (uint64_t(floor) << 63) | std::bit_cast<uint64_t>(r);
    key_lo = (uint64_t(age) << 32) | (uint64_t(0xFFFF - (uint32_t(instance) & 0xFFFF)) << 16) |
             (uint64_t(0xFFF - (uint32_t(step) & 0xFFF)) << 4) | uint64_t(15 - kind());
}

void Scheduler::push(Step s) {
    const size_t i = size_t(s.instance);
    s.floor = sc_->spent[i] < sc_->floor_bytes[i];
    s.order_key();
    sc_->heap.push_back(s);
    size_t k = sc_->heap.size() - 1;
    while (k > 0) {
        const size_t parent = (k - 1) / 4;
        if (!(sc_->heap[parent] < s)) break;
        sc_->heap[k] = sc_->heap[parent];
        k = parent;
    }
    sc_->heap[k] = s;
}

Scheduler::Step Scheduler::pop() {
    const Step top = sc_->heap.front();
    const Step last = sc_->heap.back();
    sc_->heap.pop_back();
    if (!sc_->heap.empty()) sift_down(0, last);
    return top;
}

void Scheduler::sift_down(size_t k, const Step& s) {
    const size_t n = sc_->heap.size();
    for (;;) {
        const size_t c = 4 * k + 1;
        if (c >= n) break;
        size_t best = c;
        for (size_t j = c + 1; j < std::min(c + 4, n); ++j)
            if (sc_->heap[best] < sc_->heap[j]) best = j;
        if (!(s < sc_->heap[best])) break;
        sc_->heap[k] = sc_->heap[best];
        k = best;
    }
    sc_->heap[k] = s;
}

// The steps of paid instances at their records-only ratio, made a heap
// again (bottom up, O(steps)).
void Scheduler::keep_paid_steps() {
    std::vector<Step>& heap = sc_->heap;
    heap.erase(std::remove_if(heap.begin(), heap.end(), [&](const Step& s) { return !s.paid || !sc_->paid[size_t(s.instance)]; }),
               heap.end());
    if (heap.size() > 1)
        for (size_t k = (heap.size() - 2) / 4 + 1; k-- > 0;) sift_down(k, Step(heap[k]));  // from the last parent up
}

void Scheduler::charge(size_t inst, size_t bytes, size_t& payload) {
    payload += bytes;
    sc_->spent[inst] += bytes;
}

// Parts in proportion to importance x diagonal (the character's size on
// screen in pixels; 1000 for every character without a view), over the
// instances with something to send; O(instances).
void Scheduler::set_floors(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                           std::span<const float> importance, size_t budget) {
    for (const uint32_t i : active_) sc_->spent[i] = sc_->floor_bytes[i] = 0;
    if (floor_fraction_ <= 0) return;
    double total = 0;
    for (const uint32_t i : active_)
        if (!sc_->current[i]) total += double(importance[i]) * assets[size_t(frame.instances[i].asset)]->diagonal;
    const size_t overhead = WireCost::datagrams(budget) * (WireCost::kFrameOverhead + UDP_IP_OVERHEAD);
    if (total <= 0 || budget <= overhead) return;
    const double part = floor_fraction_ * double(budget - overhead) / total;
    for (const uint32_t i : active_)
        if (!sc_->current[i]) sc_->floor_bytes[i] = size_t(part * double(importance[i]) * assets[size_t(frame.instances[i].asset)]->diagonal);
}

// Whether instance `inst`'s group may take `bytes` more this tick (taking
// them); if not, the instance is marked: what it leaves is its share's doing.
bool Scheduler::share_allows(size_t inst, size_t bytes) {
    const uint32_t g = group_of(inst);
    if (g == 0) return true;
    if (group_spent_.size() <= g) group_spent_.resize(size_t(g) + 1, 0);
    if (group_spent_[g] + bytes > credit_of(g)) {
        sc_->share_left[inst] = 1;
        return false;
    }
    group_spent_[g] += bytes;
    return true;
}

void Scheduler::take_morph(const Step& s, size_t header, size_t budget, size_t& payload) {
    const size_t inst = size_t(s.instance);
    MorphItem& mi = sc_->morph[inst];
    if (mi.chosen || WireCost::wire(payload + mi.bytes + header) > budget || !share_allows(inst, mi.bytes + header)) return;
    charge(inst, mi.bytes + header, payload);
    mi.chosen = true;
    if (!sc_->paid[inst]) pay(s.instance, s.age);
}

void Scheduler::take_chain_step(const Step& s, size_t header, size_t budget, size_t& payload) {
    const size_t inst = size_t(s.instance);
    const Chain chain = chain_of(inst);
    const ChainPoint& p0 = chain[size_t(s.step - 1)];
    const ChainPoint& p1 = chain[size_t(s.step)];
    const size_t bytes = p1.bytes - p0.bytes + header;
    sc_->chain_next[inst] = 0;
    if (WireCost::wire(payload + bytes) > budget || !share_allows(inst, bytes)) {
        // A hull step may span many segments, more than the budget or the
        // owner's share can ever carry (the character stayed at 1 bone): its
        // segments are offered one at a time instead.
        if (p1.end - p0.end > 1) {
            sc_->chain_tried[inst] = 1;
            offer_single(s.instance, s.age);
        }
        return;
    }
    charge(inst, bytes, payload);
    for (int q = p0.end; q < p1.end; ++q) items_of(inst)[size_t(q)].chosen = true;
    if (!sc_->paid[inst]) pay(s.instance, s.age);
    if (size_t(s.step) + 1 < chain.size() || extend_chain(inst)) {
        const double r = step_ratio(chain, s.step + 1);
        if (r > 0) {
            push({r, s.instance, s.step + 1, s.age, true, true});
            sc_->chain_next[inst] = s.step + 1;
        }
    }
}

void Scheduler::take_segment(const Step& s, size_t header, size_t budget, size_t& payload) {
    const size_t inst = size_t(s.instance);
    SegItem& it = items_of(inst)[size_t(s.step)];
    if (s.single) {  // an unshown segment on its own: the next one follows it if it goes
        if (it.chosen || WireCost::wire(payload + it.bytes + header) > budget || !share_allows(inst, it.bytes + header)) return;
        charge(inst, it.bytes + header, payload);
        it.chosen = true;
        if (!sc_->paid[inst]) pay(s.instance, s.age);
        offer_single(s.instance, s.age);
        return;
    }
    if (it.chosen) {
        if (s.paid) offer_paid(s.instance, s.age);
        return;
    }
    const size_t bytes = it.bytes + header;
    if (WireCost::wire(payload + bytes) > budget || !share_allows(inst, bytes)) {  // a smaller item may still fit
        if (s.paid) {
            offer_paid(s.instance, s.age);
        } else {
            it.tried = true;
            offer_unpaid(s.instance, s.age);
        }
        return;
    }
    charge(inst, bytes, payload);
    it.chosen = true;
    if (!sc_->paid[inst]) pay(s.instance, s.age);
    else offer_paid(s.instance, s.age);
}

// Something was left unsent (zero-value bones too, so that the rate
// estimate keeps probing up to the full rate, where everything goes).
bool Scheduler::left_something() const {
    for (const uint32_t i : active_) {
        if (sc_->share_left[i]) continue;  // its owner's share, not the rate, held it back
        if (sc_->morph[i].value > 0 && !sc_->morph[i].chosen) return true;
        for (const SegItem& it : items_of(i))
            if (!it.chosen && !it.idle) return true;
    }
    return false;
}

// Picks: the chosen segments of each instance merged into ranges; show = the
// prefix of segments shown from now on (chosen now or refreshed within the hold).
void Scheduler::chosen_picks(std::vector<Pick>& out) const {
    for (const uint32_t i : active_) {
        const std::span<const SegItem> items = items_of(i);
        if (items.empty() || !sc_->paid[i]) continue;  // nothing taken (every take pays the instance's header)
        int show = 0;
        for (const SegItem& it : items) {
            if (!(it.chosen || it.shown)) break;
            show = it.to;
        }
        const size_t before = out.size();
        for (const SegItem& it : items) {
            if (!it.chosen) continue;
            if (out.size() > before && out.back().k == it.from) out.back().k = it.to;
            else out.push_back({int(i), it.to, 0, it.from});
        }
        if (sc_->morph[i].chosen && show > 0) {  // the morph block goes with the instance's first chunk
            if (out.size() == before) out.push_back({int(i), 0, 0, 0});
            out[before].morphs = sc_->morph[i].mask;
        }
        for (size_t x = before; x < out.size(); ++x) out[x].show = std::max(show, out.back().k);
    }
}

// Estimated wire bytes of picks sorted by instance: one chunk header per
// instance (its ranges are adjacent).
size_t Scheduler::estimate(const EncodedFrame& frame, std::span<const Pick> picks) const {
    size_t est = 0;
    for (size_t x = 0; x < picks.size(); ++x) {
        if (x == 0 || picks[x - 1].instance != picks[x].instance) est += header_of(frame, picks[x].instance);
        est += (record_bits(frame, picks[x].instance, picks[x].first, std::max(picks[x].first, picks[x].k)) + 7) / 8 + morph_block_bytes(picks[x].morphs);
    }
    return est ? WireCost::wire(est) : 0;
}

size_t Scheduler::select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                         std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out) {
    return select(frame, assets, importance, budget, tick_rate, out, own_);
}

size_t Scheduler::select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                         std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out,
                         Scratch& scratch) {
    sc_ = &scratch;
    out.clear();
    // The interval between this client's sends (send_interval()): a
    // shown segment's refresh competes with waiting until the next send.
    if (last_select_tick_ != 0) {
        const double d = std::clamp(double(int32_t(frame.tick - last_select_tick_)), 1.0, double(HOLD_TICKS));
        interval_ = (1.0 - kIntervalWeight) * interval_ + kIntervalWeight * d;
    }
    last_select_tick_ = frame.tick;
    // The instances this tick weighs (valid, importance > 0), ascending:
    // every per-instance pass below walks them only, so a client's tick
    // costs O(its candidates), not O(the world's instances), beyond this
    // one pass over the importance.
    active_.clear();
    if (has_candidates_) {
        for (const uint32_t i : candidates_)
            if (i < importance.size() && i < frame.instances.size() && importance[i] > 0.0f && frame.instances[i].valid)
                active_.push_back(i);
        has_candidates_ = false;
        candidates_ = {};
    } else {
        for (size_t i = 0; i < importance.size() && i < frame.instances.size(); ++i)
            if (importance[i] > 0.0f && frame.instances[i].valid) active_.push_back(uint32_t(i));
    }
    track_slots(frame);
    auto by_importance = [&](const Pick& a, const Pick& b) {
        return importance[a.instance] > importance[b.instance] ||
               (importance[a.instance] == importance[b.instance] && a.instance < b.instance);
    };
    // Morph items (the weights that are due, scheduler.h), then the fast
    // path: every bone and due weight of every (important) instance fits.
    const size_t full = morph_items(frame, assets, importance);
    limited_ = false;
    if (full == 0) return 0;
    for (const uint32_t i : active_) sc_->share_left[i] = 0;
    std::fill(group_spent_.begin(), group_spent_.end(), 0);
    // The share this tick: the configured one, and no more than an equal part
    // of the budget among the owners with something to send (the server's
    // own characters count as one): a fair share of this client's stream.
    size_t owners = 0, grouped = 0;
    for (size_t g = 1; g < group_full_.size(); ++g) {
        owners += group_full_[g] > 0;
        grouped += group_full_[g];
    }
    owners += full > grouped;
    share_now_ = owners ? std::min(share_bytes_, budget / owners) : share_bytes_;
    // Each group's credit: its share every tick, kept up to one chunk's
    // worth (kShareDepth) when the share is thinner than that, so that many
    // owners of an equal thin share each send a chunk every few ticks
    // rather than none ever (200 one-character players at 256 kbit/s: 5
    // bytes a tick each).
    if (group_credit_.size() < group_full_.size()) group_credit_.resize(group_full_.size(), 0);
    for (size_t g = 1; g < group_full_.size(); ++g) {
        const size_t depth = std::max(share_now_, std::min(group_full_[g], kShareDepth));
        group_credit_[g] = std::min(group_credit_[g] + share_now_, depth);
    }
    // What the shares let through: a group's payload beyond its share never goes.
    size_t free_payload = full, shared = 0;
    bool over = false;
    for (size_t g = 1; g < group_full_.size(); ++g)
        if (group_full_[g] > share_now_) {
            over = true;
            free_payload -= group_full_[g];
            shared += share_now_;
        }
    if (!over && WireCost::wire(full) <= budget) {
        pick_everything(frame, false, out);
        std::sort(out.begin(), out.end(), by_importance);
        return WireCost::wire(full);
    }
    if (over && WireCost::wire(free_payload + shared) <= budget) {
        // All but what the shares hold back fits: everything of the other
        // instances, and the greedy within their shares for the groups over
        // them. Not limited (the rate does not grow for what a share holds).
        pick_everything(frame, true, out);
        set_floors(frame, assets, importance, budget);
        offer_items(frame, assets, importance, tick_rate, true);
        take_greedily(budget, take_stale_roots(frame, budget, free_payload));
    } else {
        set_floors(frame, assets, importance, budget);
        offer_items(frame, assets, importance, tick_rate, false);
        take_greedily(budget, take_stale_roots(frame, budget, 0));
        limited_ = left_something();
    }
    for (size_t g = 1; g < group_spent_.size() && g < group_credit_.size(); ++g)
        group_credit_[g] -= std::min(group_credit_[g], group_spent_[g]);
    chosen_picks(out);
    std::stable_sort(out.begin(), out.end(), by_importance);
    return estimate(frame, out);
}

double Scheduler::step_ratio(const Chain& chain, int c) {
    return (chain[size_t(c)].value - chain[size_t(c - 1)].value) / double(chain[size_t(c)].bytes - chain[size_t(c - 1)].bytes);
}

void Scheduler::offer_unpaid(int instance, uint32_t age) {
    const std::span<SegItem> items = items_of(size_t(instance));
    const double header = double(sc_->header[size_t(instance)]);
    int best = -1;
    double best_ratio = 0;
    for (size_t q = 0; q < items.size(); ++q) {
        SegItem& it = items[q];
        if (!it.shown || it.chosen || it.tried || !(it.value > 0)) continue;
        if (!fits(it.bytes + sc_->header[size_t(instance)])) {
            it.tried = true;  // what the greedy would find when it popped it
            continue;
        }
        const double r = it.value / (double(it.bytes) + header);
        if (r > best_ratio) {
            best_ratio = r;
            best = int(q);
        }
    }
    if (best < 0) return;
    push({best_ratio, instance, best, age, false, false});
}

void Scheduler::offer_single(int instance, uint32_t age) {
    const size_t i = size_t(instance);
    const std::span<const SegItem> items = items_of(i);
    size_t u = 0;
    while (u < items.size() && (items[u].shown || items[u].chosen)) ++u;
    if (u == items.size() || !(items[u].value > 0)) return;
    if (!fits(items[u].bytes + (sc_->paid[i] ? 0 : sc_->header[i]))) return;  // nor will the ones after it go
    const double header = sc_->paid[i] ? 0.0 : double(sc_->header[i]);
    Step st{items[u].value / (double(items[u].bytes) + header), instance, int(u), age, false, sc_->paid[i] != 0};
    st.single = true;
    push(st);
}

size_t Scheduler::take_stale_roots(const EncodedFrame& frame, size_t budget, size_t payload) {
    taken_ = &payload;
    budget_ = budget;
    stale_.clear();
    for (const size_t i : active_) {
        if (sc_->slot[i].n == 0 || items_of(i)[0].chosen) continue;  // not offered this tick (or up to date)
        const uint32_t t = state_[i].bone_tick.empty() ? 0 : state_[i].bone_tick[0];
        const uint32_t age = t == 0 ? UINT32_MAX : frame.tick - t;
        if (age >= uint32_t(ROOT_REFRESH_TICKS)) stale_.push_back({age, i});
    }
    std::sort(stale_.begin(), stale_.end(), [](const auto& a, const auto& b) { return a.first > b.first || (a.first == b.first && a.second < b.second); });
    for (const auto& [age, i] : stale_) {
        SegItem& it = items_of(i)[0];
        const size_t bytes = it.bytes + (sc_->paid[i] ? 0 : sc_->header[i]);
        if (WireCost::wire(payload + bytes) > budget) continue;  // a smaller one may still fit
        // Within the owner's share, except its first root of the tick: every
        // owner gets one even when shares are thinner than a root chunk, and
        // no owner gets more than its share (many characters buy nothing).
        const uint32_t g = group_of(i);
        if (g > 0) {
            if (group_spent_.size() <= g) group_spent_.resize(size_t(g) + 1, 0);
            if (group_spent_[g] > 0 && group_spent_[g] + bytes > credit_of(g)) continue;
            group_spent_[g] += bytes;
        }
        charge(i, bytes, payload);
        it.chosen = true;
        if (!sc_->paid[i]) pay(int(i), age);
    }
    taken_ = nullptr;
    return payload;
}

void Scheduler::pay(int instance, uint32_t age) {
    const size_t i = size_t(instance);
    sc_->paid[i] = 1;
    least_paid_ = std::min(least_paid_, sc_->least[i]);
    sc_->order_state[i] = 0;
    offer_paid(instance, age);
    if (sc_->morph[i].value > 0 && !sc_->morph[i].chosen) {
        push({sc_->morph[i].value / double(sc_->morph[i].bytes), instance, 0, age, false, true, true});
    }
    if (const int c = sc_->chain_next[i]; c > 0) {
        push({step_ratio(chain_of(i), c), instance, c, age, true, true});
    } else if (sc_->chain_tried[i]) {
        offer_single(instance, age);  // its hull step did not fit: the segments one at a time, header paid
    }
}

// The paid instance's best shown item by value per record byte (of equal
// ones the first) among those not taken that fit. Most paid instances get
// one offer in a tick: it is a scan. From the second offer on the items
// are sorted once (by ratio, then index: the scan's choice) and walked.
void Scheduler::offer_paid(int instance, uint32_t age) {
    const size_t i = size_t(instance);
    const std::span<const SegItem> items = items_of(i);
    auto before = [&](int a, int b) {
        const double l = items[size_t(a)].value * double(items[size_t(b)].bytes);
        const double r = items[size_t(b)].value * double(items[size_t(a)].bytes);
        return l > r || (l == r && a < b);
    };
    auto eligible = [&](const SegItem& it) { return it.shown && !it.chosen && it.value > 0; };
    int best = -1;
    if (sc_->order_state[i] == 0) {
        sc_->order_state[i] = 1;
        for (size_t q = 0; q < items.size(); ++q)
            if (eligible(items[q]) && fits(items[q].bytes) && (best < 0 || before(int(q), best))) best = int(q);
    } else {
        int* const order = sc_->order.data() + sc_->slot[i].order;
        size_t& at = sc_->order_at[i];
        if (sc_->order_state[i] == 1) {
            sc_->order_state[i] = 2;
            uint16_t n = 0;
            for (size_t q = 0; q < items.size(); ++q)
                if (eligible(items[q])) order[n++] = int(q);
            sc_->slot[i].order_n = n;
            std::sort(order, order + n, before);
            at = 0;
        }
        // Passed over for good: taken, or too big (the budget only shrinks).
        const size_t n = sc_->slot[i].order_n;
        while (at < n && (items[size_t(order[at])].chosen || !fits(items[size_t(order[at])].bytes))) ++at;
        if (at < n) best = order[at++];
    }
    if (best < 0) return;
    const SegItem& it = items[size_t(best)];
    push({it.value / double(it.bytes), instance, best, age, false, true});
}

void Scheduler::sent(std::span<const Pick> picks, uint32_t tick) {
    for (const Pick& p : picks) {
        if (size_t(p.instance) >= state_.size()) continue;
        State& s = state_[size_t(p.instance)];
        if (s.bone_tick.size() < size_t(p.k)) s.bone_tick.resize(size_t(p.k), 0);
        if (s.prev_tick.size() < s.bone_tick.size()) s.prev_tick.resize(s.bone_tick.size(), 0);
        for (int b = std::max(0, p.first); b < p.k; ++b) {
            if (s.bone_tick[size_t(b)] != tick) s.prev_tick[size_t(b)] = s.bone_tick[size_t(b)];
            s.bone_tick[size_t(b)] = tick;
        }
        for (size_t m = 0; m < s.morph_pending.size() && m < size_t(MAX_MORPHS); ++m)
            if ((p.morphs[m / 64] >> (m % 64) & 1) && s.morph_pending[m] != kNoWeight) {
                s.morph_sent[m] = s.morph_pending[m];
                s.morph_tick[m] = tick;
            }
    }
}

void Scheduler::lost(int instance, uint32_t generation, int first, int count, uint32_t tick, bool morphs) {
    if (instance < 0 || size_t(instance) >= state_.size() || generation_[size_t(instance)] != generation || first < 0) return;
    State& s = state_[size_t(instance)];
    if (morphs)  // stale: refreshed as soon as the budget allows (morph_item)
        for (size_t m = 0; m < s.morph_tick.size() && m < s.morph_sent.size(); ++m)
            if (s.morph_sent[m] != kNoWeight && s.morph_tick[m] == tick) s.morph_tick[m] = tick - MORPH_REFRESH_TICKS;
    if (count < 1) return;
    const size_t end = std::min(s.bone_tick.size(), std::min(s.prev_tick.size(), size_t(first) + size_t(count)));
    for (size_t b = size_t(first); b < end; ++b)
        if (s.bone_tick[b] == tick) s.bone_tick[b] = s.prev_tick[b];
}

}  // namespace progskin::net
