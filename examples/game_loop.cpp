// game_loop.cpp — a game's loop around progskin::net::Client: connect,
// spawn one character of the server's catalogue, publish its pose every
// frame (driven here by its clip, walking a circle), and print the other
// players' characters once a second. No thread of its own: one update()
// per frame. The spawn announces what the character plays (its clips, the
// start time on the clock of publish()'s source_us, the walk), so that a
// peer's `progskin-client --verify` measures what it displays against it.
//
//   progskin-server --no-scene &      # prints "TLS certificate sha256 HEX"
//   game_loop 127.0.0.1 7777 [seconds [HEX]]
// With HEX the control channel is TLS pinned to that certificate (and the
// datagrams sealed when the server seals); without it, plain TCP (a server
// started with --no-tls).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include <progskin/animation.h>
#include <progskin/client.h>  // everything a game needs (now_seconds too)

using namespace progskin;
using namespace progskin::net;

int main(int argc, char** argv) {
    if (argc < 3 || std::string(argv[1]) == "--help") {
        std::fprintf(argc < 3 ? stderr : stdout, "usage: game_loop HOST PORT [SECONDS [SHA256]]\n"
                     "Joins a progskin-server, publishes one walking character and prints the others.\n");
        return argc < 3 ? 2 : 0;
    }
    const double seconds = argc > 3 ? std::atof(argv[3]) : 10.0;
    ClientConfig cfg;
    if (argc > 4) {  // TLS, trusting the certificate with this fingerprint
        cfg.tls = true;
        cfg.pin_sha256 = argv[4];
    }
    Client client(cfg);
    try {
        client.connect(argv[1], uint16_t(std::atoi(argv[2])));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "game_loop: %s\n", e.what());
        return 1;
    }
    int me = -1;                       // spawn handle
    ClipSelection clip;                // what drives my character
    double walk_radius = 0, walk_speed = 0;  // my walk around the origin
    std::vector<glm::dmat4> joints;
    std::vector<Mat34> skinning;
    const double start = now_seconds();  // my clip's and my walk's time 0
    double next_print = start + 1.0;
    while (now_seconds() - start < seconds) {
        const double now = now_seconds();
        client.update(now);
        if (client.state() == ClientState::Failed) {
            std::fprintf(stderr, "game_loop: %s\n", client.error().c_str());
            return 1;
        }
        for (const ClientEvent& e : client.events()) {
            if (e.type == ClientEvent::Type::CharacterAdded) std::printf("+ character %d\n", e.instance);
            if (e.type == ClientEvent::Type::CharacterRemoved) std::printf("- character %d\n", e.instance);
            if (e.type == ClientEvent::Type::Spawned) std::printf("I am character %d\n", e.instance);
            if (e.type == ClientEvent::Type::SpawnRefused) std::fprintf(stderr, "spawn refused: %s\n", e.text.c_str());
        }
        // Spawn once the catalogue's first asset is here.
        if (me < 0 && !client.assets().empty() && client.assets()[0]) {
            const Character& c = client.assets()[0]->character;
            clip = select_clips(c, "all");
            joints.resize(c.joint_count());
            skinning.resize(c.joint_count());
            walk_radius = 5.0 * client.assets()[0]->diagonal;
            walk_speed = 0.75 * client.assets()[0]->diagonal;
            // What the others' references replay: these clips from `start`, this walk.
            SpawnSpec spec;
            spec.asset = 0;
            spec.clips = clip.clips;
            spec.start_us = uint64_t(start * 1e6);
            spec.walk_center = glm::dvec3(0.0);
            spec.walk_radius = walk_radius;
            spec.walk_speed = walk_speed;
            spec.position = glm::vec3(walk_root(spec.walk_center, walk_radius, walk_speed, now - start).position);
            me = client.spawn(spec);
        }
        // My pose this frame: the clip at my time, walking a circle.
        if (client.instance_of(me) >= 0) {
            const double t = now - start;
            const ClientAsset& a = *client.assets()[0];
            sample_skinning_matrices(a.character, clip, clip.looped(t), joints);
            for (size_t j = 0; j < joints.size(); ++j) skinning[j] = Mat34::from_glm(joints[j]);
            RootPose root = walk_root(glm::dvec3(0.0), walk_radius, walk_speed, t);
            root.source_us = uint64_t(now * 1e6);  // the clock of spec.start_us
            client.publish(me, root, skinning);
        }
        // The others: a renderer would upload rc.palette and place rc.root.
        if (now >= next_print) {
            next_print += 1.0;
            for (const RemoteCharacter& rc : client.characters())
                if (rc.shown)
                    std::printf("character %d (%s): %d bones at (%.2f, %.2f, %.2f)\n", rc.instance, rc.asset->name.c_str(),
                                rc.bones, rc.root.position.x, rc.root.position.y, rc.root.position.z);
            std::fflush(stdout);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(16));  // the game's frame
    }
    client.close();
    return 0;
}
