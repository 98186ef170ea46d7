// datagram_packer.h — turns one client's picks of a tick into frame-stream
// datagrams (wire.h FrameDatagram) of at most MAX_DATAGRAM bytes, copying the
// pre-encoded parent-relative records' bits (no re-encoding). Adjacent picks of one instance
// share one chunk (its head, then its records: proto/chunk_head.h); a
// chunk that does not fit continues in the next datagram (its head's first)
// and repeats its root block (RecordPlan::root: predicted for this client,
// else absolute). Datagrams fill in pick order; within one, the chunks go
// out by increasing instance (the heads code the instances' differences).
// The size of a datagram is known exactly as it fills (HeadCodes).
#pragma once
#include <cstdint>
#include <span>
#include <vector>

#include "baseline_book.h"
#include "chunk_head.h"
#include "frame_encoder.h"
#include "scheduler.h"
#include "wire.h"

namespace progskin::net {

class DatagramPacker {
public:
    // Appends datagrams to `out` (each a complete buffer); `seq` is advanced per
    // datagram. Returns the wire bytes (payload + 28 per datagram). plan
    // (optional): the client's record plan (each character's baseline and
    // predicted bones; nullptr: standalone records); book (optional): told
    // which bones each datagram carries (acknowledgements make them baselines).
    // acks (optional, at most MAX_SPAWNED: write_frame_datagram throws
    // beyond): the pose acks of the first
    // datagram (with no picks, a datagram of its own that carries nothing else).
    size_t pack(const EncodedFrame& frame, std::span<const Pick> picks, uint32_t& seq,
                std::vector<std::vector<uint8_t>>& out, const RecordPlan* plan = nullptr, BaselineBook* book = nullptr,
                std::span<const wire::PoseAck> acks = {});
    // What n pose acks add to a datagram (their count byte and entries).
    static constexpr size_t pose_ack_bytes(size_t n) { return 1 + POSE_ACK_BYTES * n; }

private:
    struct Group;
    void pack_group(Group& group, uint32_t& seq, std::vector<std::vector<uint8_t>>& out, size_t& wire, BaselineBook* book);
    void write_records(Group& group, ChunkHead& head, size_t room_bits, uint32_t seq, BaselineBook* book);
    void flush(uint32_t tick, uint32_t& seq, std::vector<std::vector<uint8_t>>& out, size_t& wire);
    // The payload bytes of the datagram being filled, with `extra_bits` more in its bit stream.
    size_t payload_bytes(size_t codes_bits, size_t extra_bits) const {
        return (codes_bits + head_bits_ + recw_.bits() + extra_bits + 7) / 8 + blocks_.size();
    }
    std::vector<ChunkOut> chunks_;  // the datagram's chunks, in pick order
    std::vector<ChunkOut> sorted_;  // the same by instance (flush)
    HeadCodes codes_;               // their heads (instance codes and fields)
    size_t head_bits_ = 0;          // their heads' bits but what codes_ counts (first, the masks)
    std::vector<uint8_t> recs_;     // their records, one bit stream
    BitWriter recw_{recs_};
    std::vector<uint8_t> blocks_;   // their sample bytes, root and morph blocks
    std::vector<uint8_t> payload_;  // the payload (proto/chunk_head.h), at flush
    std::vector<uint8_t> root_;     // an absolute root block (a character the plan has not planned)
    std::span<const wire::PoseAck> acks_;  // still to go (the first datagram)
    size_t ack_bytes_ = 0;
    bool sampled_ = false;  // this pack's datagrams carry sample bytes (FRAME_SAMPLED)
};

}  // namespace progskin::net
