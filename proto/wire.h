// wire.h — constants, framing and verification shared by every peer of the
// streaming protocol (docs/protocol.md).
//
// Control messages (TCP) are FlatBuffers "Control" buffers (control.fbs), each
// preceded by a 4-byte little-endian length. UDP datagrams are FlatBuffers
// "Datagram" buffers (datagram.fbs) but the frame stream's, which have a
// fixed 13-byte header of their own (FrameDatagram, below). Every received
// buffer goes through verify_control / verify_datagram (flatbuffers::Verifier
// with depth and table limits) or read_frame_datagram before any field is
// read.
#pragma once
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "control_generated.h"
#include "datagram_generated.h"
#include "pose.h"  // kHoldTicks

namespace progskin::net {

inline constexpr uint16_t PROTOCOL_VERSION = 13;
inline constexpr size_t MAX_DATAGRAM = 1200;          // UDP payload limit, bytes
inline constexpr size_t UDP_IP_OVERHEAD = 28;         // IPv4 + UDP headers (docs/metrics.md §3)
inline constexpr size_t MAX_CONTROL_MESSAGE = 65536;  // control message body limit
inline constexpr size_t MAX_ASSET_CHUNK = 32768;      // AssetRequest.length limit
inline constexpr size_t MAX_NAME = 64;                // Hello.client_name
inline constexpr size_t MAX_TOKEN = 256;              // Hello.token
inline constexpr int MAX_BONES = 255;                 // bones per character on the wire
inline constexpr size_t CHALLENGE_NONCE = 16;          // Challenge.nonce bytes
inline constexpr int HOLD_TICKS = kHoldTicks;                // a bone stays shown this many ticks after its newest frame
inline constexpr uint8_t CHUNK_ROOT = 1, CHUNK_SCALED = 2;   // Chunk.flags
inline constexpr uint8_t CHUNK_MORPH = 4;             // Chunk.flags: a morph block follows the root block
// Chunk.flags bits 3-6: the age of the chunk's baseline (1..15 ticks, 0: every
// record standalone), bit 7: linear (docs/protocol.md "Bone record").
inline constexpr uint8_t CHUNK_AGE_SHIFT = 3, CHUNK_AGE = 0x78, CHUNK_LINEAR = 0x80;
// A chunk's sample byte (version 8, Frame.sampled; docs/protocol.md "Frame"):
// 0, its bones are the pose at the frame's tick; v >= 1, the pose of a
// linearly keyed clip sampled (v - 1) / 254 ticks before the tick (at a key),
// interpolated linearly to the sample of an adjacent tick. The offset in
// ticks, 0 for 0.
inline constexpr double sample_ticks(uint8_t v) { return v ? double(v - 1) / 254.0 : 0.0; }
inline constexpr int MAX_MORPHS = 255;                // morph targets streamed per character (uint8 index and count)
inline constexpr size_t MORPH_ENTRY_BYTES = 3;        // morph block entry: uint8 index, int16 weight
// Morph weight on the wire (docs/protocol.md "Morph block"): int16
// little-endian = round(w * MORPH_WEIGHT_SCALE), so w in [-2, 2 - 1/16384]
// with a step of 1/16384 (error <= 3.1e-5 of a unit weight). A weight that is
// not finite or outside the range is refused (false), never clamped.
inline constexpr float MORPH_WEIGHT_SCALE = 16384.0f;
inline bool encode_morph_weight(float w, int16_t& out) {
    if (!(w >= -2.0f && w <= 32767.0f / MORPH_WEIGHT_SCALE)) return false;  // NaN fails too
    const float q = w * MORPH_WEIGHT_SCALE;
    out = int16_t(q >= 0 ? q + 0.5f : q - 0.5f);
    return true;
}
inline float decode_morph_weight(int16_t q) { return float(q) / MORPH_WEIGHT_SCALE; }
inline constexpr size_t ROOT_BYTES = 26;              // an absolute root (Pose.root; a chunk codes it: root_block.h)
inline constexpr int MAX_SPAWNED = 16;                // characters one session may own
// Published poses a server keeps per character as baselines of predicted Pose
// records (docs/protocol.md "Pose"); a publisher predicts only from an
// acknowledged pose fewer than this many poses older than the one it sends.
inline constexpr uint32_t POSE_BASELINES = 8;
// The fixed part of a Pose datagram (tables, ids, sequence numbers): what a
// publisher leaves free of records, root block and morph weights.
inline constexpr size_t POSE_OVERHEAD = 120;
inline constexpr size_t MAX_INSTANCES = 65535;        // instance ids are uint16 (0xFFFF unused)
// Lists in control messages (docs/protocol.md "Limits"): every list a peer
// sends has a limit the receiver checks on arrival, and every message a
// server builds from them fits MAX_CONTROL_MESSAGE by construction.
inline constexpr size_t MAX_INSTANCE_CLIPS = 64;      // Spawn.clips / Instance.clips (distinct indices)
inline constexpr size_t MAX_VIEW_WEIGHTS = 4096;      // View.weights (distinct instances)
inline constexpr size_t MAX_BATCH_INSTANCES = 1024;   // Instance tables per InstanceAdded (the verifier allows 4096 tables)
inline constexpr size_t MAX_BATCH_REMOVED = 16000;    // ids per InstanceRemoved (32 KB)
// The most bytes one Instance table (with MAX_INSTANCE_CLIPS clips) adds to
// an InstanceAdded: InstanceAdded batches are cut by it (tests check it).
inline constexpr size_t MAX_INSTANCE_TABLE_BYTES = 208 + 4 * MAX_INSTANCE_CLIPS;

// The Frame datagram (version 13, docs/protocol.md "Frame"): the frame
// stream's datagram is not a FlatBuffer (a Datagram's tables cost 76 to 81
// bytes; this header 13), all integers little-endian:
//   byte 0       flags: bit 0 set (FRAME_KIND: a FlatBuffers datagram opens
//                with its root offset, a multiple of 4, so its bit 0 is
//                clear), bit 1 FRAME_SAMPLED (each chunk's blocks open with
//                its sample byte), bit 2 FRAME_ACKS (pose acks follow the
//                header); bits 3-7 clear
//   bytes 1-4    seq: the datagram's sequence number (as Datagram.seq)
//   bytes 5-8    send_time_us (as Datagram.send_time_us)
//   bytes 9-12   tick: the server tick of every pose in the datagram
//   FRAME_ACKS:  uint8 n (1..MAX_SPAWNED), then n pose acks of 6 bytes:
//                uint16 instance, uint32 pose_seq (as Frame.pose_acks was)
//   the rest     the payload (frame_reader.h; may be empty), at most
//                MAX_DATAGRAM bytes in all.
inline constexpr uint8_t FRAME_KIND = 1, FRAME_SAMPLED = 2, FRAME_ACKS = 4;
inline constexpr size_t FRAME_HEADER_BYTES = 13;
inline constexpr size_t POSE_ACK_BYTES = 6;
// A received Frame datagram's fields (its spans point into the datagram).
struct FrameDatagram {
    uint32_t seq = 0, send_time_us = 0, tick = 0;
    bool sampled = false;
    std::span<const uint8_t> acks;     // pose acks, POSE_ACK_BYTES each
    std::span<const uint8_t> payload;  // chunk heads, records, blocks (frame_reader.h)
    size_t pose_ack_count() const { return acks.size() / POSE_ACK_BYTES; }
    wire::PoseAck pose_ack(size_t i) const;
};
// Whether a datagram claims to be a Frame (its first byte's bit 0).
inline bool is_frame_datagram(std::span<const uint8_t> d) { return !d.empty() && (d[0] & FRAME_KIND) != 0; }
// Reads a Frame datagram's header: false when it is not one, is shorter than
// its header (and acks), longer than MAX_DATAGRAM, has a reserved flag set,
// or an ack count of 0 or above MAX_SPAWNED. The payload is read by
// read_frame (frame_reader.h). O(1).
bool read_frame_datagram(std::span<const uint8_t> d, FrameDatagram& out);
// Writes one (out is replaced). acks: at most MAX_SPAWNED (else
// std::invalid_argument). The caller keeps the whole within MAX_DATAGRAM
// (DatagramPacker). O(bytes).
void write_frame_datagram(uint32_t seq, uint32_t send_time_us, uint32_t tick, bool sampled,
                          std::span<const wire::PoseAck> acks, std::span<const uint8_t> payload, std::vector<uint8_t>& out);

// FNV-1a 64 of bytes: the asset id (content hash; not cryptographic).
uint64_t content_hash(std::span<const uint8_t> bytes);
std::string hex64(uint64_t v);

// Checks a received control body / datagram: the FlatBuffers verifier, then
// a body of a type this version knows and present (the verifier passes a
// union type without its table). Returns the root or nullptr.
const wire::Control* verify_control(std::span<const uint8_t> body);
const wire::Datagram* verify_datagram(std::span<const uint8_t> datagram);

// Appends the 4-byte little-endian length and the finished builder's bytes.
void frame_control(const flatbuffers::FlatBufferBuilder& fbb, std::vector<uint8_t>& out);
// Reads the length prefix; returns false if fewer than 4 bytes are present.
bool read_length(std::span<const uint8_t> in, uint32_t& length);

// Microseconds of a monotonic clock, wrapping (Datagram.send_time_us).
uint32_t now_us32();
double now_seconds();  // monotonic seconds

// Helpers building the small messages both sides send.
void build_goodbye(flatbuffers::FlatBufferBuilder& fbb, const std::string& reason);
// The Goodbye reason of a server that stops cleanly (SIGINT/SIGTERM,
// Server::stop); a client reports it as the server's goodbye, not a crash.
inline constexpr const char* kShutdownReason = "shutdown: the server is stopping";
// How long Server::stop waits for its Goodbyes to be written before it closes the sockets.
inline constexpr double kShutdownLingerSeconds = 1.0;
void build_refuse(flatbuffers::FlatBufferBuilder& fbb, const std::string& reason);
// Datagrams a client sends to bind its UDP address (docs/protocol.md "Bind"):
// the Bind (padded so that it is larger than any answer) and the answer to a
// Challenge, echoing its nonce (padded so that it is larger than BindAck).
void build_bind(flatbuffers::FlatBufferBuilder& fbb, uint64_t session_id, uint64_t token);
void build_challenge_response(flatbuffers::FlatBufferBuilder& fbb, uint64_t session_id, uint64_t token,
                              std::span<const uint8_t> nonce);

}  // namespace progskin::net
