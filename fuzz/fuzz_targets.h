// fuzz_targets.h — entry points for fuzzing the parts that read bytes from
// outside: glTF files (the importer and the pose sampler) and the frame
// stream (the datagram verifier, the frame layout reader, the pose buffer),
// the control messages, the bone records and the world bus's messages. Each must return
// normally for every input: bad input is a progskin::Error or a rejected
// buffer, never a crash, a hang or an unbounded allocation.
//
// libFuzzer drivers: fuzz/fuzz_main.cpp (scripts/fuzz.sh). Their corpora live
// in fuzz/corpus/ and tests/test_fuzz_corpus.cpp replays them in every CI run.
#pragma once
#include <cstddef>
#include <cstdint>

namespace progskin::fuzz {

// Writes the bytes to a temporary .glb (when they start with the GLB magic) or
// .gltf file, imports every character, samples a few poses. Returns 1 when the
// file was accepted, 0 when it was refused with an Error.
int gltf_import(const uint8_t* data, size_t size);

// (fuzz_net_targets.cpp, built with the streaming library.) Treats the bytes
// as one received UDP datagram the way the client does: verify_datagram, then
// for a Frame read_frame (proto/frame_reader.h) into the PoseBuffers of a
// fixed scene (instances 0..4: 24 and 19 bones, 12-byte records, the last
// 14-byte records) and a few interpolated poses; for an Ack, Bind, BindAck,
// Challenge or ChallengeResponse its fields; and the bytes as a sealed
// datagram (crypto.h open_datagram, a fixed key). Returns 1 when the
// datagram was accepted (a Frame: read, and a chunk applied or refused for
// a baseline these fresh buffers do not hold), 0 when it was dropped.
int frame_stream(const uint8_t* data, size_t size);

// (fuzz_net_targets.cpp.) Treats the bytes as one control message body (TCP,
// after its length) the way each side reads it: verify_control, then the
// client's read_instance for every InstanceAdded entry (a catalogue of 2
// assets), the server's read_spawn for a Spawn (2 assets without clips), and
// every field of InstanceRemoved, Spawned, Despawn. Returns 1 when the
// message was accepted, 0 when it was refused.
int control_message(const uint8_t* data, size_t size);

// (fuzz_net_targets.cpp.) Treats the bytes as parent-relative bone records
// (proto/bone_record.h): byte 0 bit 0 scaled, bit 1 predicted (each record
// predicted from the previous one read for the same bone, as the baseline of
// one tick before; the first pass from zero), then the bit stream: 4 passes
// over a fixed 24-bone tree, each record read_record / read_predicted,
// dequantised and composed with its parent's pose. Returns 1 when the 96
// records leave fewer than 8 bits, all zero (padding), 0 when the stream was
// refused.
int bone_records(const uint8_t* data, size_t size);

// (fuzz_net_targets.cpp.) Treats the bytes as one message of another node
// of a world (server/world_message.h) the way a node reads it:
// read_world_message against a catalogue of the bundled Fox and CesiumMan,
// then each character's records pushed (push_relative, as WorldBus does)
// into a live instance of its asset, and one encode. Returns 1 when the
// message was accepted, 0 when it was refused whole.
int world_message(const uint8_t* data, size_t size);

}  // namespace progskin::fuzz
