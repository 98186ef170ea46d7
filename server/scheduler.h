// scheduler.h — per client and tick, how many bones of which instances to send
// (docs/metrics.md §4): the step that removes the most importance-weighted error per
// wire byte goes first, until the client's byte budget for the tick is spent.
//
// Cost model (docs/protocol.md "Scheduling"). The client shows the bones the
// server says (Chunk.show) and interpolates each bone between its own frames,
// so a bone need not travel every tick, nor with the bones before it: the
// scheduler keeps, per instance, the tick each bone was last sent and values
// each segment of the skin (ServerAsset::Segment: bone 0, then the steps of
// the hull of e(k)^2) in importance^2 x vertices x squared error per tick:
//   - a shown segment (refreshed a ticks ago) is worth refreshing now by
//     V = a (a + D) (G(a + D) - G(a)) / D, G its mean interpolation error
//     over a gap, D the whole ticks between the client's sends (the mean
//     interval, send_interval, rounded to the nearest; 1 below 1.5: on a
//     link where a datagram waits for the bucket to fill, about 3): the saving of a
//     refresh period of a instead of a + D ticks (the next send), per byte
//     the price a period-a schedule pays (Lagrangian condition); on the last
//     tick of the hold at least its show value (else it is dropped);
//   - a segment not shown (never sent, or past the hold) is worth its show
//     value max over p < HOLD_TICKS of p (C - G(p)), C its collapse error:
//     shown and refreshed every p ticks it saves C - G(p) per tick for one
//     refresh's bytes every p ticks.
// Shown segments are items of their own (the chunk's bone mask carries only
// the bones that are due); the segments not shown can only be shown in
// order, so they are offered as the steps of the upper concave hull of their
// cumulative (bytes, value); a step that does not fit is replaced by its
// segments one at a time (offer_single). Before the heap, the floor
// (ROOT_REFRESH_TICKS): bone 0 of every stale instance. A heap takes items of all instances by value per
// byte: their records, plus the instance's chunk header (WireCost::header:
// head and bone mask, one per instance and tick whatever bones it carries)
// for the first item of an instance in the tick; once an instance's header is
// paid its remaining items are offered again at their records-only ratio.
// Datagram overheads are charged by WireCost; equal ratios go to the instance
// sent least recently.
// Morph weights (FrameEncoder: quantised per tick) are one more item per
// instance and tick: the weights that are due, sent together in the chunk's
// morph block (1 + 3 bytes per weight). Weight m is due when its quantised
// value differs from the one last sent to this client, or when it was last
// sent MORPH_REFRESH_TICKS or more ago (or never), or when the datagram that
// carried it was lost (lost(): due as a stale one). The
// item is worth importance^2 x vertices x sum over due m of
// morph_importance_m^2 x (d_m^2 + [stale] r^2), d_m the change since last
// sent, r = MORPH_REFRESH_WEIGHT: the squared vertex error the client's stale
// weights cause per tick (cross terms between targets ignored). It is offered
// once bone 0 was sent (a chunk needs show >= 1), with the header like a shown
// segment, or at its bytes alone once the instance's header is paid. The
// greedy ends when no step left can fit (each takes at least its instance's
// smallest item, plus the header until paid); once no unpaid instance's
// header and smallest item fit, their steps leave the heap together.
// Cost: one pass over each instance's segments (and their bones) plus
// O(S log S) per client and tick for S steps popped; O(instances) when
// everything fits (fast path). Working memory in a Scratch the clients of
// one thread share; no allocation after warm-up.
#pragma once
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include <glm/geometric.hpp>

#include "baseline_book.h"
#include "frame_encoder.h"
#include "root_block.h"
#include "view.h"
#include "wire.h"

namespace progskin::net {

// Wire bytes (docs/metrics.md §3: UDP payload + 28 per datagram) of a frame stream
// carrying `payload` bytes of chunk headers and records in one tick.
struct WireCost {
    static constexpr size_t kFrameOverhead = FRAME_HEADER_BYTES;  // a Frame datagram's header (wire.h; datagram_packer.cpp checks)
    // A chunk head as the scheduler counts it (proto/chunk_head.h): the
    // instance code at a typical 3 bits (consecutive instances take 1, one
    // far from the previous up to 17; the packer counts the exact bits),
    // first (1 bit when 0), show, epoch and flags at 24, the mask's mode
    // bit. Since version 12 show, epoch and flags take 3 bits when they
    // match the previous chunk's (most do) and 27 at most; counting them at
    // 24, as before, gave a lower error than counting a typical 11 or 8 at
    // four of bench_net_rd's five caps below full rate (within 0.001 of it
    // at the fifth): counted lower, heads spread the records over more
    // characters (docs/performance.md "Head fields as the previous chunk's").
    static constexpr size_t kHeadBits = 3 + 1 + 24 + 1;
    // a chunk continued in another datagram (its sample byte, a head at its
    // largest (27 bits of fields, and up to 24 more of the next chunk's
    // when it no longer matches its predecessor), and it repeats the root
    // block)
    static constexpr size_t kSplitChunk = 1 + (17 + 9 + 27 + 24 + 1 + MAX_BONES + 7) / 8 + kRootAbsoluteBytes;
    // A head with its bone mask as a bitmap for an instance of `bones` bones
    // (at most: runs may code it shorter, a chunk starting at bone first > 0
    // has a shorter one), rounded up to a byte: the records follow it in one
    // bit stream, so a chunk's records are counted as whole bytes instead of
    // the per-chunk padding of earlier versions.
    static constexpr size_t header(int bones) { return (kHeadBits + size_t(bones) + 7) / 8; }
    // The same plus the root block when the instance's chunks carry one
    // (absolute; a client's plan may predict it: Scheduler::header_of) and
    // the sample byte when its pose was sampled at a key.
    static size_t header(const EncodedInstance& e) {
        return header(e.bone_count) + ((e.flags & CHUNK_ROOT) ? kRootAbsoluteBytes : 0) + (e.sample ? 1 : 0);
    }
    static size_t datagrams(size_t payload);
    static size_t wire(size_t payload);
};


// importance(c): pixels of screen error per model unit of vertex error
// (camera view), or weight * 1000 / diagonal (explicit weights; no view: weight 1).
// Over static instance specs (their positions), one per instance in order
// (tests, benchmarks: scenes whose instances never move).
std::vector<float> compute_importance(const ViewSpec& view, const std::vector<InstanceSpec>& instances,
                                      const std::vector<std::shared_ptr<ServerAsset>>& assets);
// Over the frame's slots, at each instance's current world position; 0 for
// inactive slots and for instances owned by `viewer` (a session never
// receives its own characters). `out` is resized to the slot count.
// known (optional): 0 too for every slot i whose generation is not
// (*known)[i] (an instance the client was not told about yet).
void compute_importance(const ViewSpec& view, const EncodedFrame& frame,
                        const std::vector<std::shared_ptr<ServerAsset>>& assets, uint64_t viewer, std::vector<float>& out,
                        const std::vector<uint32_t>* known = nullptr);

// One instance's importance seen from view's camera (compute_importance's):
// pixels per model unit at its distance, the distance no less than 5 % of
// its diagonal. t: camera_tan(view), once per view.
inline float camera_tan(const ViewSpec& view) { return std::tan(std::clamp(view.fov_y, 0.01f, 3.0f) * 0.5f); }
inline float camera_importance(const ViewSpec& view, float t, const glm::dvec3& world, double diagonal) {
    const float d = std::max(float(glm::length(world - glm::dvec3(view.camera))), float(0.05 * diagonal));
    return view.viewport_height / (2.0f * d * t);
}

inline constexpr int MORPH_REFRESH_TICKS = 30;        // a weight is re-sent at least this often
// The floor no character falls under: bone 0 (with the root block) of every
// important instance not sent for this many ticks (or never) is taken
// before the greedy, stalest first, while the budget allows it, whatever its
// value, within its owner's share (set_shares) but for the owner's first
// root of the tick, which a share thinner than a root chunk does not refuse.
// When the budget cannot carry them all, the stalest go first: every
// character's root is refreshed in turn, at the rate the budget allows; an
// owner of many characters gets no more than its share.
inline constexpr int ROOT_REFRESH_TICKS = 20;
inline constexpr double MORPH_REFRESH_WEIGHT = 1.0 / 64;  // the refresh's nominal weight error

struct Pick {
    int instance = 0;
    int k = 0;      // bones first..k-1 sent this tick (k <= first: none, the pick carries only morph weights)
    int show = 0;   // bones the client shows from this tick on (>= k; 0: k)
    int first = 0;  // (an instance may have several picks with disjoint ranges in one tick)
    std::array<uint64_t, 4> morphs{};  // bit m: morph weight m goes in the chunk's morph block
    bool has_morphs() const { return (morphs[0] | morphs[1] | morphs[2] | morphs[3]) != 0; }
};

// Bytes of a morph block carrying the weights set in `mask` (0 when none).
size_t morph_block_bytes(const std::array<uint64_t, 4>& mask);

class Scheduler {
public:
    // select()'s working memory: the items, hulls and orders of the
    // instances it offers and its heap, one tick's, laid out one after
    // another. select() alone uses it, so the clients ticked by one thread
    // share one (TickScratch), which stays in cache from one client's tick
    // to the next (each client's own per-instance arrays would be cold:
    // the other clients' ticks ran since). Grows to the largest tick, then
    // allocates no more.
    struct Scratch;
    void reset(size_t instance_count);
    // Fills `out` with picks (instance, bones first..k-1, show) in decreasing
    // importance, several disjoint ranges per instance possible, within budget
    // wire bytes. Returns the estimated wire bytes.
    size_t select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                  std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out);
    // The same in `scratch` (shared by the schedulers one thread runs).
    size_t select(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                  std::span<const float> importance, size_t budget, float tick_rate, std::vector<Pick>& out,
                  Scratch& scratch);
    // Records that `picks` went out at `tick`.
    void sent(std::span<const Pick> picks, uint32_t tick);
    // A datagram carrying bones [first, first + count) of instance
    // (generation) at `tick` was lost (BaselineBook::on_ack): each of those
    // bones still last sent at that tick goes back to the tick it was sent
    // before (0: never), which is what the client holds, so the next select
    // values it as due again (a lost refresh is sent again within a tick or
    // two instead of after the bone's next refresh period). morphs: the
    // instance's morph block of that tick was lost: each weight last sent
    // then is due again (as a stale one). O(count + morph weights).
    void lost(int instance, uint32_t generation, int first, int count, uint32_t tick, bool morphs = false);
    // Fair share for the next selects: the characters of one owner (group[i]
    // > 0, the same number for one owner; 0 or beyond the span: the server's
    // own, no limit) take at most share_bytes of payload per tick, and at most
    // budget / n where n counts the owners with something to send this tick
    // (the server's own characters as one): no owner takes more than an equal
    // part of a client's stream (0: no share at all). What a share leaves
    // unsent does not count as limited() (the rate does not probe up for it).
    // The span must outlive the selects.
    void set_shares(std::span<const uint32_t> group, size_t share_bytes) {
        group_ = group;
        share_bytes_ = share_bytes;
    }

    // The per-character floor: every important instance with something to
    // send has its own items taken first, by its own value per byte, until it
    // has spent `fraction` of its part of the budget, its part being in
    // proportion to its size on screen (importance x diagonal: equal parts
    // without a view); the greedy over all instances takes the rest. It keeps
    // a character the greedy values little (an almost still one) from being
    // served worse than an equal static split of the stream would serve it
    // (bench_net_rd "Per character"), at some cost to the scene's total error.
    // 0: no floor (pure greedy); at most 1.
    void set_floor(double fraction) { floor_fraction_ = std::clamp(fraction, 0.0, 1.0); }
    // The mean interval in ticks between this client's select() calls (its
    // sends): a moving average (weight kIntervalWeight) of each interval,
    // each within 1..HOLD_TICKS; 1 until the second call.
    double send_interval() const { return interval_; }
    // D, the whole ticks to the next send that a shown segment's refresh
    // value compares with (scheduler.h): send_interval() rounded to the
    // nearest (rounded down, a steady send every 2 ticks, whose average
    // nears 2 from below, would read as 1 for good).
    double refresh_step() const { return std::floor(interval_ + 0.5); }
    static constexpr double kIntervalWeight = 0.25;
    // The client's record plan of the tick (baseline_book.h): what each bone
    // costs as it will go (predicted or standalone). nullptr: every record
    // standalone (EncodedFrame::record_bits). Set before select().
    void set_plan(const RecordPlan* plan) { plan_ = plan; }
    size_t record_bits(const EncodedFrame& frame, int i, int from, int to) const {
        return plan_ ? plan_->bits(frame, i, from, to) : frame.record_bits(i, from, to);
    }
    // A chunk header of instance i as it will go: Chunk, mask, and the root
    // block at its planned size (predicted for this client, or absolute).
    size_t header_of(const EncodedFrame& frame, int i) const {
        const EncodedInstance& e = frame.instances[size_t(i)];
        return plan_ ? WireCost::header(e.bone_count) + plan_->root_bytes(frame, i) + (e.sample ? 1 : 0) : WireCost::header(e);
    }

    // The instances of non-zero importance, ascending, when the caller has
    // them (ClientStream: the nearest found by the frame's grid): the next
    // select walks them instead of scanning the importance of every slot.
    // Applies to the next select only; the span must outlive it.
    void set_candidates(std::span<const uint32_t> ascending) {
        candidates_ = ascending;
        has_candidates_ = true;
    }

    // The last select left something unsent (so the rate estimate may probe up).
    bool limited() const { return limited_; }

private:
    const RecordPlan* plan_ = nullptr;
    std::span<const uint32_t> candidates_;  // set_candidates
    bool has_candidates_ = false;
    struct State {
        std::vector<uint32_t> bone_tick;  // per progressive bone, tick last sent (0: never)
        std::vector<uint32_t> prev_tick;  // per progressive bone, the tick it was sent before bone_tick (lost)
        std::vector<int32_t> morph_sent;  // per morph weight, quantised value last sent (kNoWeight: never)
        std::vector<uint32_t> morph_tick; // tick it was sent
        std::vector<int32_t> morph_pending;  // chosen by the last select (committed by sent)
    };
    struct MorphItem {
        double value = 0;   // importance-weighted squared error removed per tick
        size_t bytes = 0;   // morph block
        std::array<uint64_t, 4> mask{};
        bool chosen = false;
    };
    // Fills the scratch's morph[i] (due weights, value, bytes) and State::morph_pending.
    void morph_item(size_t i, const EncodedFrame& frame, const ServerAsset& a, double w);
    struct Step {
        double ratio;
        int instance;
        int step;      // shown segment: index into its items; chain step: index into its hull
        uint32_t age;  // ticks since the instance was last sent (ties go to the stalest)
        bool chain;    // a step of the unshown segments' hull
        bool paid;     // ratio without the chunk header (offered once the instance's header is paid)
        bool morph = false;  // the instance's morph item (morph_)
        bool single = false; // one unshown segment on its own (its hull step did not fit)
        bool floor = false;  // its instance is under its floor (set_floor): goes before every other step
        // A total order (ties of ratio and age go to the lower instance,
        // then the lower step): the picks do not depend on the heap's history.
        // The order is that of (floor, ratio, age, -instance, -step, -kind)
        // packed by push() into two words (order_key), so that the heap
        // compares two integers: ratio >= 0 (its IEEE bits order as the
        // values; every push has a positive value), instance <= 65535
        // (MAX_INSTANCES), step < 4096 (items and hull steps: at most one
        // per bone, MAX_BONES).
        uint64_t key_hi = 0, key_lo = 0;
        bool operator<(const Step& o) const { return key_hi < o.key_hi || (key_hi == o.key_hi && key_lo < o.key_lo); }
        void order_key();
        int kind() const { return (chain ? 1 : 0) | (paid ? 2 : 0) | (morph ? 4 : 0) | (single ? 8 : 0); }
    };
    struct SegItem {
        double value;    // importance-weighted squared error removed per tick
        size_t bytes;    // records
        int from, to;    // bones
        bool shown;      // the client shows it now
        bool chosen;     // sent this tick
        bool tried;      // offered with the chunk header and did not fit
        bool idle = false;  // the client has its current content and its hold is not running out: nothing to send
    };
    // Each instance has at most one shown item and one chain step in the heap
    // at a time. Before its chunk header is paid: its best shown item by value
    // per (records + header) (offer_unpaid); once paid (pay): its shown items
    // in order of value per record byte, the next offered when one is taken
    // or does not fit (offer_paid), and its chain step at the records-only ratio.
    // The steps of select: slots tracked, morph items (and the fast path's
    // payload), the items offered, the greedy loop, the picks.
    void track_slots(const EncodedFrame& frame);
    // The client has every bone of instance i as it is now (sent since its
    // content last changed) and no hold runs out this tick: it needs nothing.
    bool up_to_date(size_t i, const EncodedFrame& frame) const;
    size_t morph_items(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                       std::span<const float> importance);
    // except_over_share: not the instances of groups over their share.
    void pick_everything(const EncodedFrame& frame, bool except_over_share,
                         std::vector<Pick>& out);
    // only_over_share: the instances of groups over their share only.
    void offer_items(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                     std::span<const float> importance, float tick_rate, bool only_over_share);
    struct ChainPoint {
        int end;       // items [previous end, end) of the instance
        size_t bytes;  // cumulative
        double value;  // cumulative
    };
    // What offer_items offers of an instance, found as its items are made.
    struct Offer {
        int best = -1;        // the shown item of best value per (records + header), -1: none
        double ratio = 0;     // its ratio
        size_t unshown = 0;   // the first segment not shown (the segment count: none)
        size_t least = SIZE_MAX;  // the smallest item's bytes
        ChainPoint hull{};    // the hull's vertex after the first unshown segment's start (extend_chain)
    };
    // step: D of a shown segment's refresh value (refresh_step()).
    Offer segment_items(size_t i, const EncodedFrame& frame, const ServerAsset& a, double w, double to30, double step);
    void offer_chain(size_t i, uint32_t age, const Offer& o);
    void place(size_t i, size_t n);  // room in the scratch for instance i's n items (offer_items)
    bool extend_chain(size_t i);  // appends the hull's next vertex to chain_of(i); false at the end
    void take_greedily(size_t budget, size_t payload);  // payload: already taken
    // The floor (ROOT_REFRESH_TICKS): bone 0 of the stale instances, stalest
    // first, within budget. Returns the payload taken.
    size_t take_stale_roots(const EncodedFrame& frame, size_t budget, size_t payload);
    // Offers the first unshown, unchosen segment of instance i on its own.
    void offer_single(int instance, uint32_t age);
    void take_morph(const Step& s, size_t header, size_t budget, size_t& payload);
    void take_chain_step(const Step& s, size_t header, size_t budget, size_t& payload);
    void take_segment(const Step& s, size_t header, size_t budget, size_t& payload);
    bool left_something() const;
    void chosen_picks(std::vector<Pick>& out) const;
    size_t estimate(const EncodedFrame& frame, std::span<const Pick> picks) const;
    void offer_unpaid(int instance, uint32_t age);
    void pay(int instance, uint32_t age);
    void offer_paid(int instance, uint32_t age);
    // During take_stale_roots and take_greedily: the payload taken so far
    // and the budget. The payload only grows, so an item whose bytes do not
    // fit now never will: the offers skip it (fits) instead of pushing it
    // for the greedy to pop and refuse (the tail of a full budget would
    // otherwise pop every item of every instance once).
    const size_t* taken_ = nullptr;
    size_t budget_ = 0;
    bool fits(size_t bytes) const { return !taken_ || WireCost::wire(*taken_ + bytes) <= budget_; }
    std::vector<State> state_;
    std::vector<uint32_t> generation_;              // per instance: the slot generation state_ belongs to
    // Where each instance's items, hull and order lie in the scratch this
    // tick (offer_items places them; n 0: not offered).
    struct Slot {
        uint32_t items = 0, chain = 0, order = 0;
        uint16_t n = 0;        // items (one per segment)
        uint16_t chain_n = 0;  // hull points walked (at most n + 1)
        uint16_t order_n = 0;  // shown items ordered (at most n)
    };
    std::span<SegItem> items_of(size_t i) const { return {sc_->items.data() + sc_->slot[i].items, sc_->slot[i].n}; }
    // Instance i's hull points so far (upper hull over its unshown segments).
    struct Chain {
        ChainPoint* p;
        uint16_t* n;
        size_t size() const { return *n; }
        ChainPoint& operator[](size_t k) const { return p[k]; }
        const ChainPoint& back() const { return p[*n - 1]; }
        void push_back(const ChainPoint& c) const { p[(*n)++] = c; }
        void clear() const { *n = 0; }
    };
    Chain chain_of(size_t i) { return {sc_->chain.data() + sc_->slot[i].chain, &sc_->slot[i].chain_n}; }
    // Value per record byte of hull step c (from point c - 1 to c).
    static double step_ratio(const Chain& chain, int c);
    static bool no_less_steep(const ChainPoint& p0, const ChainPoint& best, const ChainPoint& pt);
    // The fewest payload bytes a step can take: per offered instance, its
    // smallest item (records or morph block); over the instances offered,
    // that plus the chunk header; over the paid ones, that alone.
    size_t least_unpaid_ = SIZE_MAX, least_paid_ = SIZE_MAX;
    // This tick's instances (valid, importance > 0), ascending: the only
    // ones any per-instance pass reads or writes (per-instance arrays hold
    // stale values for the others).
    std::vector<uint32_t> active_;
public:
    // One select's working state, per instance id: valid for this tick's
    // instances (active_) once select wrote it, stale for every other one.
    // It lives here rather than in each Scheduler because the clients of a
    // thread tick one after another: one thread's arrays stay in cache,
    // each client's own would be cold (the other clients' ticks ran since;
    // 1,000 clients x 13 arrays over their candidates is far beyond the
    // last-level cache). Nothing in it outlives the select (sent() and
    // lost() read the client's State only).
    struct Scratch {
        std::vector<SegItem> items;
        std::vector<ChainPoint> chain;
        std::vector<int> order;  // per instance (from its second paid offer): shown items by value per byte, at slot[i].order
        std::vector<Step> heap;
        size_t items_used = 0, chain_used = 0, order_used = 0;  // this tick's
        std::vector<Slot> slot;
        std::vector<uint8_t> paid;         // chunk header paid this tick
        std::vector<int> chain_next;       // chain step offered now (0: none)
        std::vector<uint8_t> chain_tried;  // a hull step did not fit (singles offered)
        std::vector<size_t> order_at;      // next in its order to offer
        std::vector<uint8_t> order_state;  // since paid: 0 no offer yet, 1 one (a scan), 2 its order sorted
        std::vector<size_t> header;        // chunk header as it will go (header_of)
        std::vector<MorphItem> morph;
        std::vector<uint8_t> current;      // up_to_date this tick
        std::vector<size_t> least;         // its smallest item's bytes
        std::vector<size_t> floor_bytes;   // payload its own items go first for (set_floor)
        std::vector<size_t> spent;         // payload taken this tick
        std::vector<uint8_t> share_left;   // an item was left for its group's share
        void fit(size_t instances);        // every per-instance array at least this long
    };

private:
    Scratch own_;             // select()'s scratch when the caller gives none
    Scratch* sc_ = &own_;     // this select()'s
    // Offers step s (its floor flag set from its instance's spending).
    void push(Step s);
    Step pop();  // the greatest step (the heap not empty)
    void sift_down(size_t k, const Step& s);  // places s at k or below
    void keep_paid_steps();  // drops the steps of instances not paid (and the unpaid offers of paid ones)
    // Instance inst takes `bytes` more payload (payload, its floor's count).
    void charge(size_t inst, size_t bytes, size_t& payload);
    // Each offered instance's floor this tick (set_floor), from the budget.
    void set_floors(const EncodedFrame& frame, const std::vector<std::shared_ptr<ServerAsset>>& assets,
                    std::span<const float> importance, size_t budget);
    double floor_fraction_ = 0;
    uint32_t last_select_tick_ = 0;  // the tick of the last select() (0: none yet)
    double interval_ = 1.0;          // send_interval()
    std::vector<std::pair<uint32_t, size_t>> stale_;  // take_stale_roots: (age, instance)
    bool limited_ = false;
    // Fair share (set_shares): per group, payload taken this tick; per
    // instance, whether an item was left for its group's share.
    uint32_t group_of(size_t i) const { return share_bytes_ && i < group_.size() ? group_[i] : 0; }
    bool share_allows(size_t inst, size_t bytes);  // takes `bytes` from the group's share, or marks the instance
    bool over_share(size_t i) const {
        const uint32_t g = group_of(i);
        return g > 0 && g < group_full_.size() && group_full_[g] > share_now_;
    }
    std::vector<size_t> group_full_;  // per group: the payload of all its instances' due content this tick
    std::span<const uint32_t> group_;
    size_t share_bytes_ = 0;
    size_t share_now_ = 0;  // this tick's: share_bytes_, at most budget / owners with content
    std::vector<size_t> group_spent_;
    // Per group: payload it may take this tick (its share each tick, kept
    // up to kShareDepth across ticks when the share is thinner); what it
    // takes is spent at the end of select.
    std::vector<size_t> group_credit_;
    static constexpr size_t kShareDepth = 512;
    size_t credit_of(uint32_t g) const { return g < group_credit_.size() ? std::max(group_credit_[g], share_now_) : share_now_; }
};

}  // namespace progskin::net
