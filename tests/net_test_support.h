// net_test_support.h — shared by tests/test_net_*.cpp: assets loaded once per
// test binary, a server on an ephemeral loopback port run on its own thread,
// and a per-test asset cache directory.
#pragma once
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "client_palette.h"
#include "error_metric.h"
#include "run_client.h"
#include "scene.h"
#include "server.h"
#include "session.h"
#include "temp_dir.h"
#include "wire.h"

namespace progskin::net::testing {

inline std::vector<std::shared_ptr<ServerAsset>>& default_assets() {
    static std::vector<std::shared_ptr<ServerAsset>> a = {
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    return a;
}

// What the client does with one Frame, without the network: the session's
// apply_frame (client/session.h) into the views' pose buffers, instance i
// being views[i].
inline FrameApplied apply_frame(const FrameDatagram& f, std::vector<std::unique_ptr<InstanceView>>& views) {
    std::vector<PoseTarget> targets;
    for (auto& v : views) targets.push_back({&v->buffer(), v->asset().format.size()});
    return net::apply_frame(f, targets);
}

// The fields of a Frame datagram the server wrote (wire.h
// read_frame_datagram); std::nullopt when it is not one that reads.
inline std::optional<FrameDatagram> frame_of(std::span<const uint8_t> d) {
    FrameDatagram f;
    if (!read_frame_datagram(d, f)) return std::nullopt;
    return f;
}

// What a client holds after downloading a server asset (without the network).
inline std::shared_ptr<ClientAsset> client_asset(const ServerAsset& s) {
    auto c = std::make_shared<ClientAsset>();
    c->name = s.name;
    c->character = s.character;
    c->skin.order = s.skin.order;
    c->skin.parents = s.skin.parents;
    c->skin.corrections = s.skin.corrections;
    c->skin.error = s.skin.error;
    remap_skin_vertices(*c);
    c->format = s.format;
    c->diagonal = rest_diagonal(c->character);
    return c;
}

// A Hello control message (unframed, as ClientStream::on_control takes it)
// at this protocol version, named "unit", asking max_kbps (0: no cap).
inline std::vector<uint8_t> hello(uint32_t max_kbps = 0) {
    flatbuffers::FlatBufferBuilder fbb;
    auto name = fbb.CreateString("unit");
    auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, name, 0, max_kbps);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
    return {fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()};
}

// ServerConfig::threads for the tests' servers that ask for no count of
// their own: $PROGSKIN_TEST_THREADS when set (scripts/tsan.sh: 3), else 0
// (the machine's cores, as progskin-server).
inline int test_threads() {
    const char* v = std::getenv("PROGSKIN_TEST_THREADS");
    return v && *v ? std::atoi(v) : 0;
}

class RunningServer {
public:
    explicit RunningServer(std::vector<InstanceSpec> instances = {}, ServerConfig cfg = {}) {
        cfg.bind_address = "127.0.0.1";
        cfg.port = 0;
        if (cfg.threads == 0) cfg.threads = test_threads();
        if (instances.empty()) instances = default_instances(default_assets());
        server = std::make_unique<Server>(cfg, default_assets(), instances);
        thread = std::thread([this] { server->run(); });
    }
    ~RunningServer() {
        server->stop();
        thread.join();
    }
    ClientOptions client(double duration) const {
        ClientOptions o;
        o.host = "127.0.0.1";
        o.port = server->tcp_port();
        o.duration = duration;
        o.cache_dir = cache_dir();
        return o;
    }
    static std::string cache_dir() {
        static std::string d = [] {
            const auto p = progskin::testing::process_temp_dir("progskin-test-cache-");
            std::filesystem::create_directories(p);
            return p.string();
        }();
        return d;
    }
    std::unique_ptr<Server> server;
    std::thread thread;
};

}  // namespace progskin::net::testing
