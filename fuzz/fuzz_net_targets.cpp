// fuzz_net_targets.cpp — the frame-stream entry point of fuzz_targets.h.
#include <array>

#include "asset_cache.h"
#include "bone_codec.h"
#include "bone_record.h"
#include "control_messages.h"
#include "crypto.h"
#include "fuzz_targets.h"
#include "pose_buffer.h"
#include "root_block.h"
#include "server.h"
#include "session.h"
#include "wire.h"
#include "world_message.h"

namespace progskin::fuzz {

int frame_stream(const uint8_t* data, size_t size) {
    using namespace progskin::net;
    {  // The same bytes as a sealed datagram (--seal-datagrams) under a fixed key:
       // refused (no input carries a valid tag) without reading out of bounds.
        static crypto::Opener opener(crypto::Key{});
        static std::vector<uint8_t> plain;
        uint64_t seq = 0;
        const uint64_t id = crypto::sealed_session_id({data, size});
        FrameDatagram fd;
        if (crypto::open_datagram(opener, id, PROTOCOL_VERSION, {data, size}, plain, seq) == crypto::OpenResult::ok &&
            !verify_datagram(plain) && !read_frame_datagram(plain, fd))
            return 0;
    }
    FrameDatagram frame;
    if (is_frame_datagram({data, size})) {
        if (!read_frame_datagram({data, size}, frame)) return 0;
        const FrameDatagram* f = &frame;
        [[maybe_unused]] static volatile uint64_t acks;
        for (size_t i = 0; i < f->pose_ack_count(); ++i) acks = f->pose_ack(i).instance() ^ f->pose_ack(i).pose_seq();
        // The scene of fuzz/corpus/frame (make_frame_corpus.cpp): the default
        // character set, 3 Fox (24 bones) then a CesiumMan (19), 12-byte
        // records; instance 4 a 19-bone asset with scaled records;
        // instance 5 tests/data/skinned_morph.gltf (3 bones, 4 morph targets,
        // chunks with morph blocks).
        RecordFormat plain, scaled;
        scaled.scaled = true;
        static const RelativeFormat f24 = chain_format(24, plain), f19 = chain_format(19, plain),
                                    f19s = chain_format(19, scaled), f3 = chain_format(3, plain);
        std::array<PoseBuffer, 6> buffers = {PoseBuffer(f24), PoseBuffer(f24), PoseBuffer(f24),
                                             PoseBuffer(f19), PoseBuffer(f19s), PoseBuffer(f3, 4)};
        std::array<PoseTarget, 6> targets;
        for (size_t i = 0; i < buffers.size(); ++i) targets[i] = {&buffers[i], (i == 4 ? scaled : plain).size()};
        // The client's frame application (client/session.h), epochs and roots included.
        const FrameApplied applied = apply_frame(*f, targets);
        if (!applied.read) return 0;
        for (const PoseBuffer& b : buffers) {
            BonePose p;
            RootPose rp;
            const double t = double(f->tick);
            for (int bone = 0; bone < b.bone_count(); ++bone) b.pose(bone, t - 0.5, p);
            (void)b.bones_at(t);
            (void)b.root(t - 0.5, rp);
            std::array<float, 4> w;
            b.weights_at(t - 0.5, std::span<float>(w.data(), size_t(b.morph_count())));
        }
        // Accepted: a chunk applied, or refused only for want of a baseline
        // (a predicted record or root this fresh receiver never had), or
        // pose acks alone.
        return applied.applied > 0 || applied.missing_baselines > 0 || (f->payload.empty() && f->pose_ack_count() > 0);
    }
    const wire::Datagram* d = verify_datagram({data, size});
    if (!d) return 0;
    // Ack, Bind, BindAck, Challenge, ChallengeResponse: verified tables, every field read.
    [[maybe_unused]] static volatile uint64_t sink;
    if (const wire::Ack* a = d->body_as_Ack()) {
        sink = a->session_id() ^ a->token() ^ a->ack() ^ a->ack_bits() ^ a->echo_time_us() ^ a->hold_us();
        return 1;
    }
    if (const wire::Bind* b = d->body_as_Bind()) {
        sink = b->session_id() ^ b->token() ^ (b->pad() ? b->pad()->size() : 0);
        return 1;
    }
    if (const wire::BindAck* b = d->body_as_BindAck()) {
        sink = b->session_id();
        return 1;
    }
    if (const wire::Challenge* c = d->body_as_Challenge()) {
        sink = c->session_id() ^ (c->nonce() && c->nonce()->size() == CHALLENGE_NONCE ? c->nonce()->Get(15) : 0);
        return 1;
    }
    if (const wire::ChallengeResponse* r = d->body_as_ChallengeResponse()) {
        sink = r->session_id() ^ r->token() ^ (r->nonce() ? r->nonce()->size() : 0) ^ (r->pad() ? r->pad()->size() : 0);
        return 1;
    }
    // Pose: what the server checks before using a player's pose
    // (client_stream.cpp on_pose): the root block, the records as a chain of
    // up to 255 bones, standalone or predicted from a pose at rest.
    if (const wire::Pose* p = d->body_as_Pose()) {
        sink = p->session_id() ^ p->token() ^ p->instance() ^ p->pose_seq() ^ p->epoch() ^ p->first();
        if (!p->root() || !p->records() || p->count() < 1 || p->first() + p->count() > 255) return 0;
        const size_t root_len = root_size(p->root()->data(), p->root()->size());
        if (root_len == 0 || root_len != p->root()->size()) return 0;
        // Predicted (from the baseline pose's root: a walking one), or absolute.
        std::array<uint8_t, ROOT_BYTES> abs, base_root{};
        const RootPose walking{{1.0, 0.0, 2.0}, {1, 0, 0, 0}, 1000000};
        encode_root(walking, base_root.data());
        const uint8_t from = root_base(p->root()->data());
        if ((from != 0 && (from != 1 || p->base_seq() == 0)) ||
            !read_root(p->root()->data(), root_len, from ? base_root.data() : nullptr, nullptr, abs.data()))
            return 0;
        const RootPose r = decode_root(abs.data());
        sink = uint64_t(int64_t(r.position.x)) ^ r.source_us;  // within +-2,147 km: an int64 holds it
        std::array<RecordInts, 255> ints, rest{};
        const std::span<RecordInts> out(ints.data(), p->count());
        if (!read_pose_records({p->records()->data(), p->records()->size()}, false,
                               p->base_seq() ? std::span<const RecordInts>(rest.data(), p->count()) : std::span<const RecordInts>(), out))
            return 0;
        for (const RecordInts& x : out) sink = uint64_t(x.rot[0]) ^ uint64_t(x.trans[2]);
        if (p->morphs())
            for (int16_t w : *p->morphs()) sink = uint64_t(int64_t(decode_morph_weight(w) * 16384.0f));
        return 1;
    }
    return 0;
}

int control_message(const uint8_t* data, size_t size) {
    using namespace progskin::net;
    const wire::Control* c = verify_control({data, size});
    if (!c) return 0;
    [[maybe_unused]] static volatile uint64_t sink;
    switch (c->body_type()) {
        case wire::ControlBody::InstanceAdded: {
            const auto* m = c->body_as_InstanceAdded();
            if (!m->instances()) return 1;
            RemoteCharacter rc;
            for (const wire::Instance* in : *m->instances())
                if (!read_instance(*in, 2, rc).empty()) return 0;
            return 1;
        }
        case wire::ControlBody::InstanceRemoved: {
            const auto* m = c->body_as_InstanceRemoved();
            if (m->ids())
                for (uint16_t id : *m->ids()) sink = id;
            return 1;
        }
        case wire::ControlBody::Spawn: {
            static const std::vector<std::shared_ptr<ServerAsset>> catalogue = {std::make_shared<ServerAsset>(),
                                                                                std::make_shared<ServerAsset>()};
            InstanceSpec spec;
            return read_spawn(*c->body_as_Spawn(), catalogue, 1, spec).empty() ? 1 : 0;
        }
        case wire::ControlBody::Spawned: {
            const auto* m = c->body_as_Spawned();
            sink = m->request() ^ m->instance() ^ m->ok() ^ (m->reason() ? m->reason()->size() : 0);
            return 1;
        }
        case wire::ControlBody::Despawn: sink = c->body_as_Despawn()->instance(); return 1;
        case wire::ControlBody::Welcome: {
            // Every asset's record format as the client reads it before any
            // download (client/asset_cache.h read_asset_format).
            const auto* m = c->body_as_Welcome();
            if (!m->assets()) return 1;
            for (const wire::Asset* a : *m->assets()) {
                RecordFormat f;
                if (!read_asset_format(*a, f).empty()) return 0;
                sink = uint64_t(f.size()) ^ uint64_t(f.t_step * 1e6f);
            }
            return 1;
        }
        default: return 1;  // verified; the other tables' fields are read by the sessions' tests
    }
}

int bone_records(const uint8_t* data, size_t size) {
    using namespace progskin::net;
    if (size < 1) return 0;
    static const RelativeFormat f = [] {
        RelativeFormat r;
        for (int b = 0; b < 24; ++b) {
            r.parents.push_back(int16_t(b == 0 ? -1 : (b - 1) / 2));
            r.pivots.push_back(glm::vec3(0.0f, 0.1f * float(b), 0.02f * float(b % 3)));
        }
        r.t_step = 1e-3f;
        return r;
    }();
    const bool scaled = data[0] & 1, predicted = data[0] & 2;
    RelativeFormat fs = f;
    fs.scaled = scaled;
    BitReader in(data + 1, size - 1);
    std::array<RecordInts, 24> prev{};
    std::array<BonePose, 24> pose{};
    for (int pass = 0; pass < 4; ++pass) {
        for (size_t b = 0; b < 24; ++b) {
            RecordInts r;
            const bool ok = predicted ? read_predicted(in, predict_record(prev[b], 1), scaled, r) : read_record(in, scaled, r);
            if (!ok) return 0;
            prev[b] = r;
            const int p = fs.parents[b];
            pose[b] = compose_relative(p >= 0 ? pose[size_t(p)] : BonePose{}, dequantise_record(r, int(b), fs));
            if (!std::isfinite(pose[b].t.x) || !std::isfinite(pose[b].r.w) || !(pose[b].s > 0)) return 0;
        }
    }
    uint64_t rest = 0;
    const int left = int(in.size() - in.at());
    return left < 8 && in.get(left, rest) && rest == 0 ? 1 : 0;
}

int world_message(const uint8_t* data, size_t size) {
    using namespace progskin::net;
    static const ServerAssets catalogue = {load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
                                           load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    static FrameEncoder encoder = [] {
        InstanceSpec live;
        live.selection = -1;
        std::vector<InstanceSpec> specs(2, live);
        specs[1].asset = 1;
        return FrameEncoder(catalogue, specs, 30.0f);
    }();
    static uint32_t seq = 0, tick = 0;
    static std::vector<WorldCharacter> chars;
    WorldHeader h;
    if (!read_world_message({data, size}, catalogue, h, chars).empty()) return 0;
    for (const WorldCharacter& c : chars)
        encoder.push_relative(int(c.asset), ++seq, c.epoch, 0, c.ints, c.root, c.morphs, c.sample);
    encoder.encode(++tick);
    return 1;
}

}  // namespace progskin::fuzz
