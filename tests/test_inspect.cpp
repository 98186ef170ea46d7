// test_inspect.cpp — `progskin inspect` lists every character of a file
// (README: "characters" and "character" keys of --json) and picks one with
// --character, with a clear error for an index the file does not have.
#include <gtest/gtest.h>

#include "run_command.h"

#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

namespace {


std::string progskin() { return std::string(PROGSKIN_BIN_DIR) + "/tools/progskin"; }
std::string data(const std::string& name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }

}  // namespace

TEST(Inspect, ListsEveryCharacter) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const CmdResult r = run(progskin() + " inspect " + data("multi_skin.gltf") + " --character 1 --json");
    ASSERT_EQ(r.code, 0) << r.out;
    const nlohmann::json j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
    ASSERT_EQ(j["characters"].size(), 2u);
    EXPECT_EQ(j["character"], 1);
    EXPECT_EQ(j["characters"][0]["joints"], 4);
    EXPECT_EQ(j["characters"][1]["joints"], 1);
    EXPECT_EQ(j["joints"], 1);  // the detailed part is character 1's
    EXPECT_EQ(j["vertices"], j["characters"][1]["vertices"]);
    const CmdResult text = run(progskin() + " inspect " + data("multi_skin.gltf") + " --quiet");
    EXPECT_EQ(text.code, 0);
    EXPECT_NE(text.out.find("2 characters"), std::string::npos) << text.out;
    const CmdResult bad = run(progskin() + " inspect " + data("multi_skin.gltf") + " --character 5");
    EXPECT_EQ(bad.code, 1);
    EXPECT_NE(bad.out.find("no character 5 (the file has 2 characters)"), std::string::npos) << bad.out;
}

// build checks its output path before any work: a folder that does not exist
// is an argument error (exit 2) at once, naming -o and the folder.
TEST(BuildCli, OutputPathCheckedBeforeTheBuild) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const std::string in = std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb";
    for (const std::string extra : {"", " --from-vertices --bones 4"}) {
        const auto start = std::chrono::steady_clock::now();
        const CmdResult r = run(progskin() + " build " + in + extra + " -o /nonexistent/dir/out.glb");
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        EXPECT_EQ(r.code, 2) << extra << ": " << r.out;
        EXPECT_NE(r.out.find("-o /nonexistent/dir/out.glb: the folder /nonexistent/dir does not exist"), std::string::npos)
            << r.out;
        EXPECT_EQ(r.out.find("collapses"), std::string::npos) << "worked before checking: " << r.out;
        EXPECT_LT(seconds, 1.0) << r.out;
    }
    const CmdResult folder = run(progskin() + " build " + in + " -o /tmp");
    EXPECT_EQ(folder.code, 2) << folder.out;
    EXPECT_NE(folder.out.find("-o /tmp: is a folder"), std::string::npos) << folder.out;
}

// --strategy auto says which strategy it kept and why, writes it in the
// file, and logs progress one line at a time when stderr is not a terminal
// (run() captures it through a pipe): no carriage returns piling up.
TEST(BuildCli, AutoStrategyChosenAndSaidProgressOneLineAtATime) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const std::string out = ::testing::TempDir() + "progskin_build_auto.glb";
    const CmdResult r = run(progskin() + " build " + std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb --strategy auto -o " + out);
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_EQ(r.out.find('\r'), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("collapses"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("computing the server's tables"), std::string::npos) << r.out;
    const size_t at = r.out.find(": strategy ");
    ASSERT_NE(at, std::string::npos) << r.out;
    EXPECT_NE(r.out.find("(reorder ", at), std::string::npos) << r.out;
    const CmdResult j = run(progskin() + " inspect " + out + " --json");
    ASSERT_EQ(j.code, 0) << j.out;
    const nlohmann::json doc = nlohmann::json::parse(j.out.substr(j.out.find('{')));
    EXPECT_TRUE(doc.is_object());
    const std::string said = r.out.substr(at + 11, r.out.find(':', at + 11) - at - 11);
    EXPECT_TRUE(said == "reorder" || said == "flatten") << said;
    EXPECT_NE(j.out.find("\"" + said + "\""), std::string::npos) << "the file does not say " << said << ": " << j.out.substr(0, 400);
}

// --strategy rate builds reorder, flatten and hierarchy and keeps the one of
// lowest rate-distortion area against the stream's record bits, saying the
// bits and areas; the file records the choice and its figures.
TEST(BuildCli, RateStrategyWeighsTheStreamsRecordBits) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const std::string out = ::testing::TempDir() + "progskin_build_rate.glb";
    const CmdResult r = run(progskin() + " build " + std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb --strategy rate -o " + out);
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_NE(r.out.find("chosen by rate-distortion"), std::string::npos) << r.out;
    // The default is the server's: rate.
    const CmdResult d = run(progskin() + " build " + std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb -o " + out + "-default.glb");
    ASSERT_EQ(d.code, 0) << d.out;
    EXPECT_NE(d.out.find("chosen by rate-distortion"), std::string::npos) << d.out;
    const size_t at = r.out.find(": strategy ");
    ASSERT_NE(at, std::string::npos) << r.out;
    const std::string said = r.out.substr(at + 11, r.out.find(':', at + 11) - at - 11);
    EXPECT_TRUE(said == "reorder" || said == "flatten" || said == "hierarchy") << said;
    const CmdResult j = run(progskin() + " inspect " + out + " --json");
    ASSERT_EQ(j.code, 0) << j.out;
    EXPECT_NE(j.out.find("\"" + said + "\""), std::string::npos) << j.out.substr(0, 400);
    const CmdResult bad = run(progskin() + " build " + std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb --strategy fastest -o " + out);
    EXPECT_EQ(bad.code, 2) << bad.out;
    EXPECT_NE(bad.out.find("--strategy"), std::string::npos) << bad.out;
}

// A file without a skin: inspect lists what it has (vertices, frames, clips,
// morph targets) and points to --from-vertices; build says the same.
TEST(Inspect, FileWithoutASkinListsClipsAndMorphTargetsAndPointsToFromVertices) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const std::string sphere = std::string(PROGSKIN_ASSETS) + "/AnimatedMorphSphere.gltf";
    const CmdResult text = run(progskin() + " inspect " + sphere);
    ASSERT_EQ(text.code, 0) << text.out;
    EXPECT_NE(text.out.find("no skin"), std::string::npos) << text.out;
    EXPECT_NE(text.out.find("morph targets: 2"), std::string::npos) << text.out;
    EXPECT_NE(text.out.find("progskin build --from-vertices " + sphere), std::string::npos) << text.out;
    const CmdResult js = run(progskin() + " inspect " + sphere + " --json");
    ASSERT_EQ(js.code, 0) << js.out;
    const nlohmann::json j = nlohmann::json::parse(js.out.substr(js.out.find('{')));
    EXPECT_EQ(j["skinned"], false);
    EXPECT_GT(j["vertices"].get<int>(), 0);
    EXPECT_GT(j["frames"].get<int>(), 1);
    ASSERT_GE(j["clips"].size(), 1u);
    EXPECT_GT(j["clips"][0]["end"].get<double>(), 0.0);
    EXPECT_GE(j["clips"][0]["weights_channels"].get<int>(), 1);
    ASSERT_EQ(j["morph_targets"].size(), 2u);
    const CmdResult build = run(progskin() + " build " + sphere + " -o /tmp/progskin-no-skin-out.glb");
    EXPECT_EQ(build.code, 1) << build.out;
    EXPECT_NE(build.out.find("no skin"), std::string::npos) << build.out;
    EXPECT_NE(build.out.find("progskin build --from-vertices " + sphere), std::string::npos) << build.out;
}

// A file without animation is built on range-of-motion poses, and says so
// (stderr and the extension's "training"); inspect --clip measures a
// progressive file's stored skin on the clips asked for, not its stored table.
TEST(BuildCli, AFileWithoutAnimationTrainsOnARangeOfMotion) {
    if (!std::ifstream(progskin()).good()) GTEST_SKIP() << progskin() << " not built";
    const std::string out = ::testing::TempDir() + "progskin_build_still.glb";
    // armature_m.gltf without its animation: the same file, "animations" dropped.
    std::ifstream in(data("armature_m.gltf"));
    nlohmann::json doc = nlohmann::json::parse(in);
    ASSERT_TRUE(doc.contains("animations"));
    doc.erase("animations");
    const std::string still = ::testing::TempDir() + "progskin_armature_still.gltf";
    std::ofstream(still) << doc.dump();
    const CmdResult r = run(progskin() + " build " + still + " -o " + out);
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_NE(r.out.find("no clip moves the skeleton"), std::string::npos) << r.out;
    const CmdResult j = run(progskin() + " inspect " + out + " --json");
    ASSERT_EQ(j.code, 0) << j.out;
    const nlohmann::json built = nlohmann::json::parse(j.out.substr(j.out.find('{')));
    EXPECT_EQ(built.value("table_training", nlohmann::json()), "range of motion") << j.out.substr(0, 600);
    // Its stored table is over the range of motion: it has error below the full skin.
    const auto& strategies = built.at("strategies");
    ASSERT_EQ(strategies.size(), 1u);
    const auto& table = strategies.begin().value();
    EXPECT_GT(table.at(0).at("rms").get<double>(), 0.0);

    // --clip range-of-motion: the same training whatever the clips (the
    // animated original builds the skin its still copy gets).
    const std::string forced = ::testing::TempDir() + "progskin_armature_rom.glb";
    const CmdResult rf = run(progskin() + " build " + data("armature_m.gltf") + " --clip range-of-motion -o " + forced);
    ASSERT_EQ(rf.code, 0) << rf.out;
    EXPECT_NE(rf.out.find("--clip range-of-motion: trained on"), std::string::npos) << rf.out;
    const CmdResult jf = run(progskin() + " inspect " + forced + " --json");
    const nlohmann::json fb = nlohmann::json::parse(jf.out.substr(jf.out.find('{')));
    EXPECT_EQ(fb.value("table_training", nlohmann::json()), "range of motion");
    EXPECT_EQ(fb.at("strategies").begin().value().dump(), strategies.begin().value().dump()) << "not the still file's skin";

    // The built file of the animated original, measured on its clip.
    const std::string animated = ::testing::TempDir() + "progskin_armature_built.glb";
    ASSERT_EQ(run(progskin() + " build " + data("armature_m.gltf") + " -o " + animated + " --quiet").code, 0);
    const CmdResult stored = run(progskin() + " inspect " + animated + " --json");
    const CmdResult measured = run(progskin() + " inspect " + animated + " --json --clip 0");
    ASSERT_EQ(measured.code, 0) << measured.out;
    const nlohmann::json a = nlohmann::json::parse(stored.out.substr(stored.out.find('{')));
    const nlohmann::json b = nlohmann::json::parse(measured.out.substr(measured.out.find('{')));
    EXPECT_EQ(b.value("table_measured_on", ""), "0");
    EXPECT_GT(b.value("frames", 0), 1);
    // The clip is the training set: the same table, measured again.
    const auto& ta = a.at("strategies").begin().value();
    const auto& tb = b.at("strategies").begin().value();
    ASSERT_EQ(ta.size(), tb.size());
    for (size_t k = 0; k < ta.size(); ++k)
        EXPECT_NEAR(ta[k].at("rms").get<double>(), tb[k].at("rms").get<double>(), 1e-6 + 1e-3 * ta[k].at("rms").get<double>()) << k;
}
