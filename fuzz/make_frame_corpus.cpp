// make_frame_corpus.cpp — writes the seed corpus of the frame-stream fuzz
// target (fuzz/corpus/frame): real datagrams of the default character set
// (progskin-server's scene without arguments) as the server packs them at
// several budgets, the same with a walking instance whose client acknowledges
// (predicted records and root blocks), frames carrying morph blocks (tests/data/skinned_morph.gltf
// as instance 5), and one Bind, BindAck, Ack, Challenge and ChallengeResponse;
// beside DIR, the control messages of players' characters (control/) and
// parent-relative bone records of the Fox (records/, fuzz_targets.h
// bone_records: absolute and predicted, plain and scaled).
//
//   build/fuzz/make_frame_corpus fuzz/corpus/frame
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include "bone_record.h"
#include "root_block.h"
#include "client_stream.h"
#include "control_messages.h"
#include "scene.h"
#include "server_core.h"
#include "wire.h"
#include "world_message.h"

using namespace progskin;
using namespace progskin::net;

static void write(const std::filesystem::path& dir, const std::string& name, const std::vector<uint8_t>& d) {
    std::ofstream(dir / name, std::ios::binary).write(reinterpret_cast<const char*>(d.data()), std::streamsize(d.size()));
}

static std::vector<uint8_t> finish(flatbuffers::FlatBufferBuilder& fbb, wire::DatagramBody type, flatbuffers::Offset<void> body) {
    fbb.Finish(wire::CreateDatagram(fbb, 9, 123456, type, body), wire::DatagramIdentifier());
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

// 40 ticks of a detached ClientStream per budget (bytes per tick); the
// datagrams of ticks 1, 14, 27 and 40 (first frames and refreshes) are written
// as PREFIX<budget>-t<tick>-<i>.
static void write_frames(ServerCore& core, std::initializer_list<size_t> budgets, const std::filesystem::path& dir,
                         const std::string& prefix) {
    for (size_t budget : budgets) {
        auto client = ClientStream::detached(core, 1, 1000);
        for (uint32_t t = 1; t <= 40; ++t) {
            DatagramCollector sink;
            client->send_frame(core.encoder().encode(t), budget, sink);
            if (t % 13 != 1) continue;
            for (size_t i = 0; i < sink.sent.size(); ++i)
                write(dir, prefix + std::to_string(budget) + "-t" + std::to_string(t) + "-" + std::to_string(i), sink.sent[i].bytes);
        }
    }
}

// Ticks 1..40 to one client that acknowledges every datagram at once
// (budget 500 and 20000 bytes in turn), so that later frames carry
// predicted records; before(t) runs before tick t is encoded. Ticks 1, 14,
// 27 and 40 are written as <prefix>t<tick>-<i>.
static void write_acked_frames(ServerCore& core, const std::filesystem::path& dir, const std::string& prefix,
                               const std::function<void(uint32_t)>& before) {
    auto client = ClientStream::detached(core, 1, 1000);
    for (uint32_t t = 1; t <= 40; ++t) {
        before(t);
        DatagramCollector sink;
        client->send_frame(core.encoder().encode(t), t % 2 ? 500 : 20000, sink);
        if (!sink.sent.empty()) client->acknowledge(client->seq() - 1, ~0u);
        if (t % 13 != 1) continue;
        for (size_t i = 0; i < sink.sent.size(); ++i)
            write(dir, prefix + "t" + std::to_string(t) + "-" + std::to_string(i), sink.sent[i].bytes);
    }
}

int main(int argc, char** argv) {
    if (argc != 2 || std::string(argv[1]) == "--help") {
        std::fprintf(stderr, "usage: make_frame_corpus DIR\nWrites the frame-stream fuzz seeds into DIR.\n");
        return argc == 2 ? 0 : 2;
    }
    const std::filesystem::path dir = argv[1];
    std::filesystem::create_directories(dir);
    std::vector<std::shared_ptr<ServerAsset>> assets = {load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
                                                        load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    // The server's session core without sockets: each budget's datagrams are
    // a ClientStream's (importance, selection, packing) at that budget per tick.
    ServerCore core(ServerConfig{}, assets, default_instances(assets));
    // Instance 1 placed in the world: its chunks carry a root block.
    RootPose placed;
    placed.position = {1234.5, 0.25, -9876.125};
    placed.rotation = glm::angleAxis(0.7f, glm::vec3(0, 1, 0));
    placed.source_us = 123456789;
    core.encoder().set_root(1, placed, false);
    write_frames(core, {200, 500, 1100, 20000}, dir, "frame-");
    {
        // Instance 1 walking, its client acknowledging every datagram at
        // once: later frames carry predicted records and root blocks
        // (baseline_book.h), written as frame-acked-t<tick>-<i>.
        ServerCore acore(ServerConfig{}, assets, default_instances(assets));
        write_acked_frames(acore, dir, "frame-acked-", [&](uint32_t t) {
            placed.position.x += 0.04;
            placed.rotation = glm::angleAxis(0.7f + 0.01f * float(t), glm::vec3(0, 1, 0));
            placed.source_us += 33333 + (t % 3) * 700;
            acore.encoder().set_root(1, placed, false);
        });
    }
    {
        // Key samples (ServerConfig::key_samples, protocol 8): every chunk
        // opens with its sample byte and the records are predicted along the
        // samples' times; written as frame-keyed-t<tick>-<i>.
        ServerConfig keyed;
        keyed.key_samples = true;
        ServerCore kcore(keyed, assets, default_instances(assets));
        write_acked_frames(kcore, dir, "frame-keyed-", [](uint32_t) {});
    }
    {
        // Morph blocks: tests/data/skinned_morph.gltf as instance 5 (the
        // fuzz target's 3-bone, 4-target buffer; slots 0-4 added and removed).
        std::vector<std::shared_ptr<ServerAsset>> morph = {
            load_server_asset(std::string(PROGSKIN_SOURCE_DIR) + "/tests/data/skinned_morph.gltf")};
        InstanceSpec talk;
        for (size_t s = 0; s < morph[0]->selections.size(); ++s)
            if (morph[0]->selections[s].clips.size() == 1 &&
                morph[0]->character.clips[size_t(morph[0]->selections[s].clips[0])].name == "talk")
                talk.selection = int(s);
        ServerCore mcore(ServerConfig{}, morph, std::vector<InstanceSpec>(6, talk));
        for (int i = 0; i < 5; ++i) mcore.remove_instance(i);
        write_frames(mcore, {150, 20000}, dir, "frame-morph-");
    }
    {
        // A player's pose acks (FRAME_ACKS): in front of a frame's payload,
        // and alone (a datagram with nothing else); "pose-acks".
        ServerCore pcore(ServerConfig{}, assets, default_instances(assets));
        auto client = ClientStream::detached(pcore, 1, 1000);
        DatagramCollector sink;
        client->send_frame(pcore.encoder().encode(1), 500, sink);
        FrameDatagram f;
        if (sink.sent.empty() || !read_frame_datagram(sink.sent[0].bytes, f)) {
            std::fprintf(stderr, "make_frame_corpus: no frame to carry pose acks\n");
            return 1;
        }
        const std::vector<wire::PoseAck> acks = {wire::PoseAck(1, 17), wire::PoseAck(3, 40000)};
        std::vector<uint8_t> d;
        write_frame_datagram(f.seq, f.send_time_us, f.tick, f.sampled, acks, f.payload, d);
        write(dir, "frame-pose-acks", d);
        write_frame_datagram(f.seq + 1, f.send_time_us, f.tick, false, acks, {}, d);
        write(dir, "pose-acks", d);
    }
    flatbuffers::FlatBufferBuilder fbb;
    std::vector<uint8_t> pad(64, 0);
    auto p = fbb.CreateVector(pad);
    write(dir, "bind", finish(fbb, wire::DatagramBody::Bind, wire::CreateBind(fbb, 0x1234, 0x5678, p).Union()));
    fbb.Clear();
    write(dir, "bind-ack", finish(fbb, wire::DatagramBody::BindAck, wire::CreateBindAck(fbb, 0x1234).Union()));
    fbb.Clear();
    write(dir, "ack", finish(fbb, wire::DatagramBody::Ack, wire::CreateAck(fbb, 0x1234, 0x5678, 40, 0xfffffffbu, 99, 250).Union()));
    fbb.Clear();
    std::vector<uint8_t> nonce(CHALLENGE_NONCE);
    for (size_t i = 0; i < nonce.size(); ++i) nonce[i] = uint8_t(17 * i + 3);
    auto nv = fbb.CreateVector(nonce);
    write(dir, "challenge", finish(fbb, wire::DatagramBody::Challenge, wire::CreateChallenge(fbb, 0x1234, nv).Union()));
    fbb.Clear();
    std::vector<uint8_t> pad32(32, 0);
    auto nv2 = fbb.CreateVector(nonce);
    auto p32 = fbb.CreateVector(pad32);
    write(dir, "challenge-response",
          finish(fbb, wire::DatagramBody::ChallengeResponse, wire::CreateChallengeResponse(fbb, 0x1234, 0x5678, nv2, p32).Union()));
    fbb.Clear();
    {
        // A Pose of 24 bones: standalone parent-relative records (bone 0
        // moved, the others at rest) and an absolute root block, and the same
        // predicted from a pose at rest, its root from the fuzz target's
        // baseline root (a walking one: fuzz_net_targets.cpp).
        std::array<uint8_t, ROOT_BYTES> abs{}, walking{}, next{};
        encode_root(placed, abs.data());
        encode_root(RootPose{{1.0, 0.0, 2.0}, {1, 0, 0, 0}, 1000000}, walking.data());
        encode_root(RootPose{{1.04, 0.0, 2.01}, {1, 0, 0, 0}, 1033400}, next.data());
        for (uint32_t base = 0; base < 2; ++base) {
            std::vector<uint8_t> root;
            write_root(base ? next.data() : abs.data(), base ? 1 : 0, base ? walking.data() : nullptr, nullptr, root);
            std::vector<uint8_t> rec;
            BitWriter w(rec);
            RecordInts moved;
            moved.rot[1] = 1200;
            moved.trans[0] = 35;
            moved.has_trans = true;
            for (int b = 0; b < 24; ++b)
                base ? void(write_predicted(b == 0 ? moved : RecordInts{}, RecordInts{}, false, w))
                     : void(write_record(b == 0 ? moved : RecordInts{}, false, w));
            fbb.Clear();
            auto r = fbb.CreateVector(root);
            auto v = fbb.CreateVector(rec);
            auto m = fbb.CreateVector(std::vector<int16_t>{0, 8192, 16384, -4096});
            write(dir, base ? "pose-predicted" : "pose",
                  finish(fbb, wire::DatagramBody::Pose, wire::CreatePose(fbb, 0x1234, 0x5678, 2, 17 + base, 1, 0, r, v, m, 24, base ? 16 : 0).Union()));
        }
    }
    {
        // Parent-relative records (fuzz/corpus/records, beside DIR): 4 ticks of
        // the Fox's 24 bones, each tick predicted from the one before.
        const std::filesystem::path rdir = dir.parent_path() / "records";
        std::filesystem::create_directories(rdir);
        const ServerAsset& fox = *assets[0];
        for (int scaled = 0; scaled < 2; ++scaled) {
            RecordFormat box = fox.format;
            box.scaled = scaled != 0;
            const RelativeFormat f = relative_format(fox.skin, fox.character, box);
            const size_t B = size_t(f.bone_count());
            std::vector<std::vector<RecordInts>> ticks;
            for (int t = 0; t < 4; ++t) {
                std::vector<glm::dmat4> mats(fox.character.joint_count());
                sample_skinning_matrices(fox.character, fox.selections[std::min<size_t>(1, fox.selections.size() - 1)], 0.1 * t, mats);
                std::vector<BonePose> model(B), decoded(B);
                for (size_t b = 0; b < B; ++b) {
                    model[b] = decompose(Mat34::from_glm(mats[size_t(fox.skin.order[b])]));
                    if (scaled) model[b].s = 1.0f + 0.05f * float(b % 4);
                }
                std::vector<uint8_t> bits;
                std::vector<uint32_t> offsets(B + 1);
                ticks.emplace_back(B);
                encode_pose(model, f, bits, offsets, decoded, ticks.back());
            }
            for (int predicted = 0; predicted < 2; ++predicted) {
                std::vector<uint8_t> out = {uint8_t(scaled | (predicted << 1))};
                BitWriter w(out);
                for (int t = 0; t < 4; ++t)
                    for (size_t b = 0; b < B; ++b) {
                        if (!predicted) write_record(ticks[size_t(t)][b], f.scaled, w);
                        else write_predicted(ticks[size_t(t)][b], predict_record(t ? ticks[size_t(t - 1)][b] : RecordInts{}, 1), f.scaled, w);
                    }
                write(rdir, std::string("fox") + (scaled ? "-scaled" : "") + (predicted ? "-predicted" : ""), out);
            }
        }
    }
    // Messages of another node of a world: fuzz/corpus/world (beside DIR), the
    // default scene's characters at three ticks, one of them a player's.
    {
        const std::filesystem::path wdir = dir.parent_path() / "world";
        std::filesystem::create_directories(wdir);
        const std::vector<InstanceSpec> scene = default_instances(assets);
        FrameEncoder enc(assets, scene, 30.0f);
        std::vector<uint8_t> bytes;
        for (uint32_t t = 1; t <= 40; ++t) {
            const EncodedFrame& f = enc.encode(t);
            if (t != 1 && t != 15 && t != 40) continue;
            std::vector<WorldCharacter> chars(scene.size());
            for (size_t i = 0; i < scene.size(); ++i) {
                world_character(f, int(i), RootPose{glm::dvec3(scene[i].position)}, chars[i]);
                chars[i].world_id = (uint64_t(0xabcdef) << 40) | (i + 1);
            }
            chars[1].published = true;
            chars[1].clips = {0};
            chars[1].publisher_start_us = 123456789;
            chars[1].walk_center = {1.0, 0.0, 2.0};
            chars[1].walk_radius = 3.0;
            chars[1].walk_speed = 1.4;
            write_world_message({7, catalogue_hash(assets), t}, chars, assets, bytes);
            write(wdir, "scene-t" + std::to_string(t), bytes);
        }
    }
    // Control messages of players' characters: fuzz/corpus/control (beside DIR).
    const std::filesystem::path cdir = dir.parent_path() / "control";
    std::filesystem::create_directories(cdir);
    auto control = [&](const std::string& name, wire::ControlBody type, flatbuffers::Offset<void> body) {
        fbb.Finish(wire::CreateControl(fbb, type, body), wire::ControlIdentifier());
        write(cdir, name, {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()});
        fbb.Clear();
    };
    fbb.Clear();
    {
        wire::Vec3 pos(1.5f, 0.0f, -2.0f);
        wire::Quat rot(0.0f, 0.38268343f, 0.0f, 0.92387953f);
        wire::DVec3 centre(100.0, 0.0, 50.0);
        std::vector<int32_t> clips = {0, 2};
        std::vector<flatbuffers::Offset<wire::Instance>> is;
        for (int i = 0; i < 3; ++i) {
            auto vc = fbb.CreateVector(clips);
            is.push_back(wire::CreateInstance(fbb, uint16_t(i), uint16_t(i % 2), &pos, vc, 0.0f, 3.4f, 0.5f * float(i), 1.0f, i == 2,
                                              &rot, i == 1, 123456789, &centre, 200.0, 1.4));
        }
        auto v = fbb.CreateVector(is);
        control("instance-added", wire::ControlBody::InstanceAdded, wire::CreateInstanceAdded(fbb, v).Union());
        std::vector<uint16_t> ids = {0, 2, 7};
        auto vi = fbb.CreateVector(ids);
        control("instance-removed", wire::ControlBody::InstanceRemoved, wire::CreateInstanceRemoved(fbb, vi).Union());
        auto vc = fbb.CreateVector(std::vector<int32_t>{});
        control("spawn", wire::ControlBody::Spawn,
                wire::CreateSpawn(fbb, 7, 1, vc, false, 1.0f, 987654321, &centre, 150.0, 1.4, &pos).Union());
        auto reason = fbb.CreateString("");
        control("spawned", wire::ControlBody::Spawned, wire::CreateSpawned(fbb, 7, true, 12, reason).Union());
        control("despawn", wire::ControlBody::Despawn, wire::CreateDespawn(fbb, 12).Union());
    }
    // The Welcome of the two assets (protocol 10: each Asset's t_step).
    build_welcome(fbb, assets, 1, 2, 7777, 30.0f, 256.0, nullptr, nullptr);
    write(cdir, "welcome", {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()});
    fbb.Clear();
    std::printf("make_frame_corpus: wrote %s, %s, records and world\n", dir.string().c_str(), cdir.string().c_str());
    return 0;
}
