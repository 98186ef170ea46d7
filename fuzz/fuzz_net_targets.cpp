// fuzz_net_targets.cpp — the frame-stream entry point of fuzz_targets.h.
#include <array>

#include "bone_codec.h"
#include "crypto.h"
#include "frame_reader.h"
#include "fuzz_targets.h"
#include "pose_buffer.h"
#include "wire.h"

namespace progskin::fuzz {

int frame_stream(const uint8_t* data, size_t size) {
    using namespace progskin::net;
    {  // The same bytes as a sealed datagram (--seal-datagrams) under a fixed key:
       // refused (no input carries a valid tag) without reading out of bounds.
        static crypto::Opener opener(crypto::Key{});
        static std::vector<uint8_t> plain;
        uint64_t seq = 0;
        const uint64_t id = crypto::sealed_session_id({data, size});
        if (crypto::open_datagram(opener, id, PROTOCOL_VERSION, {data, size}, plain, seq) == crypto::OpenResult::ok &&
            !verify_datagram(plain))
            return 0;
    }
    const wire::Datagram* d = verify_datagram({data, size});
    if (!d) return 0;
    if (const wire::Frame* f = d->body_as_Frame()) {
        // The scene of fuzz/corpus/frame (make_frame_corpus.cpp): the default
        // character set, 3 Fox (24 bones) then a CesiumMan (19), 12-byte
        // records; instance 4 a 19-bone asset with scaled (14-byte) records.
        RecordFormat plain, scaled;
        scaled.scaled = true;
        std::array<PoseBuffer, 5> buffers = {PoseBuffer(24, plain), PoseBuffer(24, plain), PoseBuffer(24, plain),
                                             PoseBuffer(19, plain), PoseBuffer(19, scaled)};
        auto record_size = [&](uint16_t i) { return i < buffers.size() ? (i == 4 ? scaled : plain).size() : 0; };
        int accepted = 0;
        const bool ok = read_frame(*f, record_size, [&](uint16_t i, int first, int count, int show, const uint8_t* rec) {
            accepted += buffers[i].add_chunk(f->tick(), first, count, show, rec, show);
        });
        if (!ok) return 0;
        for (const PoseBuffer& b : buffers) {
            BonePose p;
            const double t = double(f->tick());
            for (int bone = 0; bone < b.bone_count(); ++bone) b.pose(bone, t - 0.5, p);
            (void)b.bones_at(t);
        }
        return accepted > 0;
    }
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
    return 0;
}

}  // namespace progskin::fuzz
