// test_gltf_validator.cpp — the Khronos glTF validator (npm gltf-validator,
// scripts/gltf_validator) on every kind of file progskin writes: `progskin
// build` outputs (.glb and .gltf, with morph targets, several skins),
// `--from-vertices` outputs, the server's copy of a file with another
// character first and its cache of a plain build. Each must have 0 errors and
// no more UNUSED_OBJECT than its input already had. Skipped, saying why, when
// node or the validator module is not installed (scripts/setup.sh installs it).
#include <gtest/gtest.h>

#include "run_command.h"

#include <array>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <unistd.h>

#include "gltf_export.h"
#include "gltf_import.h"
#if __has_include("scene.h")
#include "scene.h"
#define PROGSKIN_TEST_SERVER_FILES 1
#endif

namespace fs = std::filesystem;

namespace {


std::string asset(const std::string& name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }
std::string data(const std::string& name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }
std::string validator_dir() { return std::string(PROGSKIN_ASSETS) + "/../scripts/gltf_validator"; }
std::string progskin_bin() { return std::string(PROGSKIN_BIN_DIR) + "/tools/progskin"; }

// Why the validator cannot run here ("" when it can).
std::string validator_missing() {
    if (run("node --version").code != 0) return "node is not installed (apt-get install nodejs npm)";
    if (!fs::exists(validator_dir() + "/node_modules/gltf-validator"))
        return "npm module gltf-validator missing: cd scripts/gltf_validator && npm ci (or scripts/setup.sh)";
    return {};
}

// Validator report of each file: path -> JSON line of validate.mjs.
std::map<std::string, nlohmann::json> validate(const std::vector<std::string>& files) {
    std::string cmd = "node " + validator_dir() + "/validate.mjs";
    for (const std::string& f : files) cmd += " '" + f + "'";
    const CmdResult r = run(cmd);
    EXPECT_EQ(r.code, 0) << r.out;
    std::map<std::string, nlohmann::json> out;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) {
        if (line.empty() || line[0] != '{') continue;
        const nlohmann::json j = nlohmann::json::parse(line);
        out[j["file"].get<std::string>()] = j;
    }
    return out;
}

int code_count(const nlohmann::json& report, const char* code) {
    return report.contains("codes") && report["codes"].contains(code) ? report["codes"][code].get<int>() : 0;
}

}  // namespace

TEST(GltfValidator, EveryWrittenFileIsValid) {
    const std::string missing = validator_missing();
    if (!missing.empty()) GTEST_SKIP() << "glTF validator not available: " << missing;
    if (!std::ifstream(progskin_bin()).good()) GTEST_SKIP() << progskin_bin() << " not built";
    const fs::path dir = fs::temp_directory_path() / ("progskin_validator_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::vector<std::pair<std::string, std::string>> written;  // (output, input)
    auto build = [&](const std::string& in, const std::string& out, const std::string& flags) {
        const std::string path = (dir / out).string();
        const CmdResult r = run(progskin_bin() + " build " + flags + " " + in + " -o " + path + " --quiet");
        ASSERT_EQ(r.code, 0) << r.out;
        written.push_back({path, in});
    };
    build(asset("Fox.glb"), "fox.glb", "");
    build(asset("CesiumMan.glb"), "cesium.glb", "");
    build(asset("RiggedSimple.gltf"), "rigged.gltf", "--plain-copy");
    build(data("skinned_morph.gltf"), "morph.glb", "");
    build(data("multi_skin.gltf"), "multi.glb", "--character 1");
    // Character 0 shares a mesh with character 1 and lists a joint under two
    // inverse binds: the output copies the mesh and adds a helper joint node.
    build(data("multi_skin.gltf"), "multi0.glb", "");
    build(asset("AnimatedMorphSphere.gltf"), "sphere.glb", "--from-vertices --bones 3");
    build(asset("CesiumMan.glb"), "cesium_scratch.glb", "--from-vertices --bones 3");
    {
        const std::string path = (dir / "multi_second_first.glb").string();
        progskin::write_with_skins_first(data("multi_skin.gltf"), {3}, path);
        written.push_back({path, data("multi_skin.gltf")});
    }
#ifdef PROGSKIN_TEST_SERVER_FILES
    {
        progskin::net::AssetOptions o;
        o.cache_dir = (dir / "cache").string();
        std::vector<progskin::net::PendingAsset> pending;
        ASSERT_TRUE(progskin::net::check_server_assets({asset("Fox.glb")}, o, pending).empty());
        progskin::net::build_server_asset(pending.at(0), o);
        for (const auto& e : fs::directory_iterator(o.cache_dir)) written.push_back({e.path().string(), asset("Fox.glb")});
    }
#endif
    std::vector<std::string> files;
    for (const auto& [out, in] : written) files.push_back(out), files.push_back(in);
    const auto reports = validate(files);
    for (const auto& [out, in] : written) {
        ASSERT_TRUE(reports.count(out)) << out;
        ASSERT_TRUE(reports.count(in)) << in;
        const nlohmann::json& r = reports.at(out);
        std::printf("%s: %d errors, %d warnings, %d UNUSED_OBJECT (input %d)\n", fs::path(out).filename().c_str(),
                    r["errors"].get<int>(), r["warnings"].get<int>(), code_count(r, "UNUSED_OBJECT"),
                    code_count(reports.at(in), "UNUSED_OBJECT"));
        EXPECT_EQ(r["errors"].get<int>(), 0) << out << ": " << r["messages"].dump(1);
        EXPECT_LE(code_count(r, "UNUSED_OBJECT"), code_count(reports.at(in), "UNUSED_OBJECT")) << out;
    }
    fs::remove_all(dir);
}

namespace {

// The JSON chunk of a .glb.
nlohmann::json glb_json(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    if (bytes.size() < 20) return {};
    uint32_t n = 0;
    std::memcpy(&n, bytes.data() + 12, 4);
    return nlohmann::json::parse(bytes.substr(20, n));
}

}  // namespace

TEST(GltfOutputs, FromVerticesKeepsTheSourceMeshes) {
    if (!std::ifstream(progskin_bin()).good()) GTEST_SKIP() << progskin_bin() << " not built";
    const std::string out = (fs::temp_directory_path() / ("progskin_scratch_keep_" + std::to_string(::getpid()) + ".glb")).string();
    const CmdResult r = run(progskin_bin() + " build --from-vertices " + asset("CesiumMan.glb") + " -o " + out +
                            " --bones 3 --quiet");
    ASSERT_EQ(r.code, 0) << r.out;
    const nlohmann::json j = glb_json(out);
    const nlohmann::json in = glb_json(asset("CesiumMan.glb"));
    fs::remove(out);
    ASSERT_EQ(j["meshes"].size(), 1u);
    EXPECT_EQ(j["meshes"][0]["name"], in["meshes"][0]["name"]);
    const auto& prim = j["meshes"][0]["primitives"][0];
    EXPECT_TRUE(prim["attributes"].contains("TEXCOORD_0"));
    EXPECT_EQ(prim["material"], in["meshes"][0]["primitives"][0]["material"]);
    ASSERT_EQ(j["materials"].size(), in["materials"].size());  // tinygltf leaves out default values (emissiveFactor 0)
    EXPECT_EQ(j["materials"][0]["name"], in["materials"][0]["name"]);
    EXPECT_EQ(j["materials"][0]["pbrMetallicRoughness"], in["materials"][0]["pbrMetallicRoughness"]);
    ASSERT_EQ(j["images"].size(), in["images"].size());
    const auto& ext = j["skins"][0]["extensions"]["PROGSKIN_progressive_skin"];
    EXPECT_EQ(ext["source"], "CesiumMan.glb");  // the file name, never the build machine's path
    EXPECT_TRUE(ext["source_meshes_kept"].get<bool>());
}

TEST(GltfOutputs, FromVerticesKeepsTheSourceClips) {
    if (!std::ifstream(progskin_bin()).good()) GTEST_SKIP() << progskin_bin() << " not built";
    const std::string out = (fs::temp_directory_path() / ("progskin_scratch_clips_" + std::to_string(::getpid()) + ".glb")).string();
    const CmdResult r = run(progskin_bin() + " build --from-vertices " + asset("Fox.glb") + " -o " + out +
                            " --bones 4 --quiet");
    ASSERT_EQ(r.code, 0) << r.out;
    const nlohmann::json j = glb_json(out);
    fs::remove(out);
    // The Fox's three clips, trained one after another, come back as three animations.
    ASSERT_EQ(j["animations"].size(), 3u);
    EXPECT_EQ(j["animations"][0]["name"], "Survey");
    EXPECT_EQ(j["animations"][1]["name"], "Walk");
    EXPECT_EQ(j["animations"][2]["name"], "Run");
    const auto& ext = j["skins"][0]["extensions"]["PROGSKIN_progressive_skin"];
    EXPECT_EQ(ext["clips_kept"].size(), 3u);
}
