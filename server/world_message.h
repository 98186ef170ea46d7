// world_message.h — the bytes a node of a world publishes on the bus for one
// spatial cell and tick (docs/protocol.md "World bus"): its own characters in
// that cell, each as the encoder already encoded it (its parent-relative
// records and root block), with what observers need to announce it. One
// message per non-empty cell per tick. Pure functions over flat byte spans,
// no bus.
//
// The records are the sending encoder's own integers (bone_record.h, every
// bone standalone, closed loop against its decoded parent): a node that
// composes them and codes them again gets the same integers (version 3), so a
// character from another node streams exactly as it would from this one.
// (Version 2 carried the 16-bit absolute records of bone_codec.h, whose
// translation step over the box of every rigid pose is 1.75-1.9 x coarser.)
//
// Layout (little-endian):
//   header  "PSKW" | version u8 (3) | 0 u8 | node u16 | catalogue u64 | tick u32 | count u16
//   count x character:
//     id u16 (the node's instance id) | world_id u64 (nonzero) | asset u16 | epoch u8 | flags u8 (1: a player's)
//     | sample u8 (EncodedInstance::sample: 0 the tick's pose, else a key's) | bones u8 | record_bytes u16
//     | root [ROOT_BYTES] | records [record_bytes]: bones standalone parent-relative
//       records (bone_record.h write_record), bit-packed, zero bits to the byte's end
//     | morphs u8 | morph weights i16 x morphs
//     | clips u8 | clip indices i32 x clips | publisher_start_us u64
//     | walk_center f64 x3 | walk_radius f64 | walk_speed f64
// Decoding checks every count against the catalogue (bones of the asset,
// morphs, MAX_INSTANCE_CLIPS), record_bytes against bones x kMaxRecordBits,
// every record within its bounds (read_pose_records) and the message's
// length: a message that does not parse to its last byte is refused whole.
#pragma once
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "bone_record.h"
#include "control_messages.h"
#include "frame_encoder.h"
#include "scene.h"
#include "wire.h"

namespace progskin::net {

inline constexpr size_t kWorldMaxCharacters = 4096;  // per message (a cell of one node)
inline constexpr size_t kWorldMaxMessage = 1 << 20;  // bytes

struct WorldCharacter {
    uint16_t id = 0;  // the sending node's instance id
    uint64_t world_id = 0;  // InstanceSpec::world_id (nonzero)
    uint16_t asset = 0;
    uint8_t epoch = 0;
    uint8_t sample = 0;      // the pose's sample byte (a clip sampled at its keys)
    bool published = false;  // a player's character (else the node's own, a clip or a game's)
    std::array<uint8_t, ROOT_BYTES> root{};
    // The records' bit stream: written, its first record_bits bits (the rest
    // of the last byte goes as zeros); read, the bytes in the message.
    std::span<const uint8_t> records;
    size_t record_bits = 0;
    std::vector<RecordInts> ints;       // read: the bones' records, decoded and checked
    std::vector<int16_t> morphs;        // empty: none
    std::vector<int> clips;             // announced to observers
    uint64_t publisher_start_us = 0;
    std::array<double, 3> walk_center{};
    double walk_radius = 0, walk_speed = 0;
};

struct WorldHeader {
    uint16_t node = 0;
    uint64_t catalogue = 0;
    uint32_t tick = 0;
};

// Appends one message to `out` (cleared first). O(bytes).
void write_world_message(const WorldHeader& h, std::span<const WorldCharacter> chars, const ServerAssets& assets,
                         std::vector<uint8_t>& out);
// Reads a message; "" and `h`, `chars` filled (records point into `bytes`),
// or what is wrong. O(bytes).
std::string read_world_message(std::span<const uint8_t> bytes, const ServerAssets& assets, WorldHeader& h,
                               std::vector<WorldCharacter>& chars);
// The same against a catalogue hash already computed (catalogue_hash(assets)):
// what a node calls for every message.
std::string read_world_message(std::span<const uint8_t> bytes, const ServerAssets& assets, uint64_t catalogue,
                               WorldHeader& h, std::vector<WorldCharacter>& chars);

// Slot i of an encoded frame as the bus carries it: id, asset, epoch, the
// root block (the frame's when its chunks carry one, else `placed`), the
// parent-relative records of the tick (pointing into the frame) and the
// morph weights (none when any was refused). False when `placed` is outside
// the root block's range. The caller sets world_id and the player's fields.
bool world_character(const EncodedFrame& frame, int i, const RootPose& placed, WorldCharacter& c);

// The catalogue's identity: the asset ids in order (every node of a world
// serves the same catalogue).
uint64_t catalogue_hash(const ServerAssets& assets);

}  // namespace progskin::net
