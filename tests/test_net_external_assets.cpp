// test_net_external_assets.cpp — a character shipped as `.gltf` + `.bin` +
// image files (offline/self_contained.h): the server checks every external
// URI before building, serves one self-contained GLB that a real client on
// loopback downloads and displays, refuses what it cannot embed naming the
// asset and the URI; `progskin build` writes a self-contained GLB; a client
// that cannot load one asset of a catalogue keeps streaming the others.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "asset_cache.h"
#include "net_test_support.h"
#include "run_command.h"
#include "temp_dir.h"
#include "self_contained.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
namespace fs = std::filesystem;

namespace {

std::string asset(const std::string& name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }

std::vector<uint8_t> read_bytes(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}
void write_bytes(const fs::path& p, const std::vector<uint8_t>& b) {
    fs::create_directories(p.parent_path());
    std::ofstream f(p, std::ios::binary);
    f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}
uint32_t u32(const std::vector<uint8_t>& b, size_t at) {
    return uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 | uint32_t(b[at + 3]) << 24;
}

// A GLB's JSON and binary chunk.
struct Glb {
    nlohmann::json json;
    std::vector<uint8_t> bin;
};
Glb split_glb(const std::vector<uint8_t>& b) {
    Glb g;
    EXPECT_GE(b.size(), 20u);
    EXPECT_EQ(std::memcmp(b.data(), "glTF", 4), 0);
    const uint32_t n = u32(b, 12);
    g.json = nlohmann::json::parse(b.begin() + 20, b.begin() + 20 + n);
    if (20 + n + 8 <= b.size()) g.bin.assign(b.begin() + 20 + n + 8, b.begin() + 20 + n + 8 + u32(b, 20 + n));
    return g;
}

// A 2x2 RGBA PNG (a valid file, 73 bytes: red and green pixels).
const std::vector<uint8_t> kSmallPng = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52, 0x00, 0x00, 0x00,
    0x02, 0x00, 0x00, 0x00, 0x02, 0x08, 0x06, 0x00, 0x00, 0x00, 0x72, 0xb6, 0x0d, 0x24, 0x00, 0x00, 0x00, 0x10, 0x49,
    0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0xf8, 0xcf, 0xc0, 0xf0, 0x1f, 0x0a, 0x21, 0x14, 0x00, 0x45, 0xcc, 0x07, 0xf9,
    0x66, 0xcb, 0xff, 0x39, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

// The fixture: CesiumMan.glb exported as dir/avatar.gltf + dir/buffer.bin +
// its texture in dir/textures/skin.jpg + a small PNG dir/small.png (the
// material's emissive texture), as a social-VR avatar ships. `image_uri`
// and `buffer_uri` replace the URIs (bad fixtures). Returns the .gltf path.
struct Fixture {
    std::string buffer_uri = "buffer.bin", image_uri = "textures/skin.jpg", png_uri = "small.png";
    bool write_png = true;
};
std::string make_external_gltf(const fs::path& dir, const Fixture& f = {}) {
    fs::remove_all(dir);
    fs::create_directories(dir);
    Glb g = split_glb(read_bytes(asset("CesiumMan.glb")));
    nlohmann::json& j = g.json;
    // The JPEG out of the binary chunk into its own file.
    const nlohmann::json view = j["bufferViews"][j["images"][0]["bufferView"].get<size_t>()];
    const size_t at = view.value("byteOffset", size_t(0)), len = view["byteLength"].get<size_t>();
    write_bytes(dir / "textures/skin.jpg", std::vector<uint8_t>(g.bin.begin() + std::ptrdiff_t(at),
                                                                g.bin.begin() + std::ptrdiff_t(at + len)));
    j["images"][0] = {{"uri", f.image_uri}};
    j["images"].push_back({{"uri", f.png_uri}});
    j["textures"].push_back({{"source", 1}});
    j["materials"][0]["emissiveTexture"] = {{"index", 1}};
    if (f.write_png) write_bytes(dir / "small.png", kSmallPng);
    write_bytes(dir / "buffer.bin", g.bin);
    j["buffers"][0]["uri"] = f.buffer_uri;
    std::ofstream(dir / "avatar.gltf") << j.dump(2);
    return (dir / "avatar.gltf").string();
}

fs::path temp_dir(const std::string& name) {
    return progskin::testing::process_temp_dir("progskin_test_external_" + name + "_");
}

// Checks a GLB holds everything: one binary chunk, no external URI, the two
// images byte for byte.
void expect_self_contained(const std::vector<uint8_t>& bytes, const fs::path& fixture_dir) {
    const Glb g = split_glb(bytes);
    for (const auto& b : g.json["buffers"]) EXPECT_FALSE(b.contains("uri") && b["uri"].get<std::string>().rfind("data:", 0) != 0) << b;
    ASSERT_EQ(g.json["images"].size(), 2u);
    const std::vector<uint8_t> jpg = read_bytes(fixture_dir / "textures/skin.jpg");
    for (size_t i = 0; i < 2; ++i) {
        const auto& img = g.json["images"][i];
        ASSERT_FALSE(img.contains("uri")) << img;
        ASSERT_TRUE(img.contains("bufferView")) << img;
        const auto& v = g.json["bufferViews"][img["bufferView"].get<size_t>()];
        EXPECT_EQ(v["buffer"].get<int>(), 0);
        const size_t at = v.value("byteOffset", size_t(0)), len = v["byteLength"].get<size_t>();
        ASSERT_LE(at + len, g.bin.size());
        const std::vector<uint8_t> got(g.bin.begin() + std::ptrdiff_t(at), g.bin.begin() + std::ptrdiff_t(at + len));
        EXPECT_EQ(got, i == 0 ? jpg : kSmallPng) << "image " << i;
        EXPECT_EQ(img["mimeType"].get<std::string>(), i == 0 ? "image/jpeg" : "image/png");
    }
}

// A real server on loopback serving `assets` and `instances`, and one client
// with its own (empty) cache in `dir` for `duration` seconds: its report.
ClientReport stream_once(const std::vector<std::shared_ptr<ServerAsset>>& assets, const std::vector<InstanceSpec>& instances,
                         const fs::path& dir, double duration, bool verify) {
    ServerConfig cfg;
    cfg.bind_address = "127.0.0.1";
    cfg.port = 0;
    Server server(cfg, assets, instances);
    std::thread t([&] { server.run(); });
    ClientOptions co;
    co.host = "127.0.0.1";
    co.port = server.tcp_port();
    co.duration = duration;
    co.verify = verify;
    co.cache_dir = (dir / "client-cache").string();
    ClientReport r;
    EXPECT_NO_THROW(r = run_client(co));
    server.stop();
    t.join();
    return r;
}

}  // namespace

TEST(ExternalAssets, ServerServesOneSelfContainedGlbThatARealClientDisplays) {
    const fs::path dir = temp_dir("serve");
    const std::string gltf = make_external_gltf(dir);
    AssetOptions o;
    o.cache_dir = (dir / "cache").string();
    std::vector<PendingAsset> pending;
    const auto problems = check_server_assets({gltf}, o, pending);
    ASSERT_TRUE(problems.empty()) << problems.front();
    ASSERT_EQ(pending.size(), 1u);
    const auto avatar = build_server_asset(pending[0], o);
    expect_self_contained(avatar->bytes, dir);
    EXPECT_EQ(avatar->character.vertex_count(), default_assets()[1]->character.vertex_count());

    // Served beside the Fox; a real client with an empty cache downloads both and shows both.
    std::vector<std::shared_ptr<ServerAsset>> assets = {default_assets()[0], avatar};
    std::vector<InstanceSpec> instances(2);
    instances[1].asset = 1;
    instances[1].position = glm::vec3(3.0f, 0.0f, 0.0f);
    const ClientReport r = stream_once(assets, instances, dir, 2.0, true);
    EXPECT_TRUE(r.assets_failed.empty()) << r.assets_failed.front().second;
    EXPECT_EQ(r.asset_bytes_downloaded, assets[0]->bytes.size() + avatar->bytes.size());
    EXPECT_EQ(r.characters, 2);
    bool avatar_shown = false;
    for (const auto& i : r.instances)
        if (i.asset == "avatar.gltf") {
            avatar_shown = i.frames > 0;
            EXPECT_GE(i.rms_pct, 0.0) << "the avatar was not verified";
            EXPECT_LT(i.rms_pct, 1.0) << "the avatar displayed far from its reference";
        }
    EXPECT_TRUE(avatar_shown);
    // The client's cached copy holds no reference to a file beside it, and
    // is named .glb (its bytes are a GLB, though the catalogue says
    // avatar.gltf): engines pick their loader by the extension.
    const std::string cached = cached_asset_path((dir / "client-cache").string(), avatar->id, true);
    ASSERT_TRUE(fs::exists(cached)) << cached;
    EXPECT_FALSE(fs::exists(cached_asset_path((dir / "client-cache").string(), avatar->id, false)));
    expect_self_contained(read_bytes(cached), dir);
}

TEST(ExternalAssets, WhatCannotBeEmbeddedIsRefusedNamingTheAssetAndTheUri) {
    AssetOptions o;
    o.cache_dir = (temp_dir("refuse") / "cache").string();
    struct Case {
        Fixture f;
        std::string uri, why;
    };
    Fixture missing;
    missing.write_png = false;
    Fixture escape;
    escape.buffer_uri = "../buffer.bin";
    Fixture absolute;
    absolute.image_uri = "/etc/passwd";
    Fixture remote;
    remote.png_uri = "https://example.com/small.png";
    const Case cases[] = {{missing, "small.png", "missing"},
                          {escape, "../buffer.bin", "outside"},
                          {absolute, "/etc/passwd", "absolute"},
                          {remote, "https://example.com/small.png", "relative file names"}};
    int n = 0;
    for (const Case& c : cases) {
        const std::string gltf = make_external_gltf(temp_dir("refuse" + std::to_string(n++)), c.f);
        std::vector<PendingAsset> pending;
        const auto problems = check_server_assets({asset("Fox.glb"), gltf}, o, pending);
        ASSERT_EQ(problems.size(), 1u) << c.uri;
        EXPECT_NE(problems[0].find("avatar.gltf"), std::string::npos) << problems[0];
        EXPECT_NE(problems[0].find("\"" + c.uri + "\""), std::string::npos) << problems[0];
        EXPECT_NE(problems[0].find(c.why), std::string::npos) << problems[0];
        EXPECT_EQ(pending.size(), 1u);  // the Fox is fine
    }
}

TEST(ExternalAssets, BuildWritesASelfContainedGlb) {
    const std::string tool = std::string(PROGSKIN_BIN_DIR) + "/tools/progskin";
    if (!fs::exists(tool)) GTEST_SKIP() << tool << " not built";
    const fs::path dir = temp_dir("build");
    const std::string gltf = make_external_gltf(dir);
    const fs::path out = dir / "elsewhere/out.glb";  // another folder: nothing beside it to refer to
    fs::create_directories(out.parent_path());
    const CmdResult r = run(tool + " build " + gltf + " -o " + out.string());
    ASSERT_EQ(r.code, 0) << r.out;
    expect_self_contained(read_bytes(out), dir);
    // A missing image: the build fails naming it, and writes nothing.
    fs::remove(dir / "small.png");
    const fs::path out2 = dir / "elsewhere/out2.glb";
    const CmdResult bad = run(tool + " build " + gltf + " -o " + out2.string());
    EXPECT_NE(bad.code, 0) << bad.out;
    EXPECT_NE(bad.out.find("small.png"), std::string::npos) << bad.out;
    EXPECT_FALSE(fs::exists(out2));
}

TEST(ExternalAssets, AClientThatCannotLoadOneAssetStreamsTheOthers) {
    // A server serving the fixture's .gltf as it is (what servers did before
    // embedding): the client cannot load it, says so, and shows the Fox.
    const fs::path dir = temp_dir("one_bad");
    const std::string gltf = make_external_gltf(dir);
    AssetOptions o;
    o.cache_dir = (dir / "cache").string();
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({gltf}, o, pending).empty());
    auto broken = build_server_asset(pending[0], o);
    broken->bytes = read_bytes(gltf);
    broken->id = content_hash(broken->bytes);
    std::vector<std::shared_ptr<ServerAsset>> assets = {broken, default_assets()[0]};
    std::vector<InstanceSpec> instances(2);
    instances[0].asset = 0;
    instances[1].asset = 1;
    const ClientReport r = stream_once(assets, instances, dir, 1.5, false);
    ASSERT_EQ(r.assets_failed.size(), 1u);
    EXPECT_EQ(r.assets_failed[0].first, "avatar.gltf");
    EXPECT_NE(r.assets_failed[0].second.find("buffer.bin"), std::string::npos) << r.assets_failed[0].second;
    EXPECT_EQ(r.characters, 1);  // the Fox
    ASSERT_EQ(r.instances.size(), 1u);
    EXPECT_EQ(r.instances[0].asset, "Fox.glb");
    EXPECT_GT(r.instances[0].frames, 0u);
    const std::string json = report_json(r);
    EXPECT_NE(json.find("\"assets_failed\": [{\"asset\": \"avatar.gltf\""), std::string::npos) << json;
    EXPECT_TRUE(nlohmann::json::parse(json, nullptr, false).is_object()) << json;
}
