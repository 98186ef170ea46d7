// test_net_assets.cpp — what progskin-server does with its --asset arguments
// (server/scene.h): every file checked before anything is built, every problem
// listed, files without a skin pointed at `progskin build --from-vertices` or
// built with --from-vertices, every character of a file served (FILE#N one).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "run_command.h"
#include "temp_dir.h"

#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <fstream>
#include <string>

#include "animation.h"
#include "frame_encoder.h"
#include "gltf_import.h"
#include "progressive_skin.h"
#include "range_of_motion.h"
#include "scene.h"
#include "vertex_animation.h"

using namespace progskin;
using namespace progskin::net;
namespace fs = std::filesystem;

namespace {

std::string asset(const std::string& name) { return std::string(PROGSKIN_ASSETS) + "/" + name; }
std::string data(const std::string& name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }

// A fresh cache directory per test.
std::string temp_cache(const std::string& name) {
    return progskin::testing::process_temp_dir("progskin_test_assets_" + name + "_").string();
}


// CesiumMan built in a fresh cache as `o` says, then again with `change`
// applied to o (o keeps it); nulls when the file was refused.
std::pair<std::shared_ptr<ServerAsset>, std::shared_ptr<ServerAsset>> built_twice(
    const std::string& name, AssetOptions& o, const std::function<void(AssetOptions&)>& change,
    std::vector<PendingAsset>& pending) {
    o.cache_dir = temp_cache(name);
    if (!check_server_assets({asset("CesiumMan.glb")}, o, pending).empty()) return {};
    auto first = build_server_asset(pending[0], o);
    change(o);
    return {first, build_server_asset(pending[0], o)};
}

// The builds (.glb files) in a cache directory.
size_t cached_builds(const std::string& dir) {
    size_t n = 0;
    for (const auto& e : fs::directory_iterator(dir)) n += e.path().extension() == ".glb";
    return n;
}

bool contains(const std::vector<std::string>& lines, const std::string& a, const std::string& b) {
    for (const std::string& l : lines)
        if (l.find(a) != std::string::npos && l.find(b) != std::string::npos) return true;
    return false;
}

void expect_same_tables(const ServerAsset& a, const ServerAsset& b);

}  // namespace

TEST(ServerAssets, EveryProblemListedBeforeAnyBuild) {
    AssetOptions o;
    o.cache_dir = temp_cache("problems");
    std::vector<PendingAsset> pending;
    const auto problems = check_server_assets({asset("Fox.glb"), asset("AnimatedMorphSphere.gltf"),
                                               data("broken/nan_position.gltf"), data("no_such_file.glb"),
                                               data("multi_skin.gltf#7")},
                                              o, pending);
    ASSERT_EQ(problems.size(), 4u);
    EXPECT_TRUE(contains(problems, "AnimatedMorphSphere.gltf", "progskin build --from-vertices"));
    EXPECT_TRUE(contains(problems, "nan_position.gltf", "NaN"));
    EXPECT_TRUE(contains(problems, "no_such_file.glb", "no such file"));
    EXPECT_TRUE(contains(problems, "multi_skin.gltf", "no character 7 (the file has 2 characters)"));
    ASSERT_EQ(pending.size(), 1u);  // the Fox, checked but not built
    EXPECT_FALSE(pending[0].progressive);
    EXPECT_FALSE(fs::exists(o.cache_dir));  // nothing derived was written
}

TEST(ServerAssets, ServerExitsAtOnceListingEveryProblem) {
    const std::string server = std::string(PROGSKIN_BIN_DIR) + "/server/progskin-server";
    if (!std::ifstream(server).good()) GTEST_SKIP() << server << " not built";
    const auto start = std::chrono::steady_clock::now();
    // The Fox first: a server that built before checking would spend seconds on it.
    const CmdResult r = run(server + " --no-tls --port 0 --duration 1 --cache " + temp_cache("cli") + " --asset " +
                            asset("Fox.glb") + " " + asset("AnimatedMorphSphere.gltf") + " " +
                            data("broken/nan_position.gltf"));
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_EQ(r.code, 1) << r.out;
    EXPECT_NE(r.out.find("AnimatedMorphSphere.gltf: no skin"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("--from-vertices"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("nan_position.gltf"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("2 problems"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("listening"), std::string::npos) << r.out;
    EXPECT_LT(seconds, 2.0) << "the check must not build the Fox first";
}

TEST(ServerAssets, EveryCharacterOfAFileAndOneByIndex) {
    AssetOptions o;
    o.cache_dir = temp_cache("multi");
    std::vector<PendingAsset> all, one;
    ASSERT_TRUE(check_server_assets({data("multi_skin.gltf")}, o, all).empty());
    ASSERT_EQ(all.size(), 2u);
    EXPECT_EQ(all[0].label, "multi_skin.gltf#0");
    EXPECT_EQ(all[1].label, "multi_skin.gltf#1");
    ASSERT_TRUE(check_server_assets({data("multi_skin.gltf#1")}, o, one).empty());
    ASSERT_EQ(one.size(), 1u);
    EXPECT_EQ(one[0].character, 1);
    // Character 1 is served as a file whose character 0 is that character (what clients play).
    const auto a = build_server_asset(one[0], o);
    const Character reference = import_character(data("multi_skin.gltf"), 1);
    ASSERT_EQ(a->character.vertex_count(), reference.vertex_count());
    const std::string copy = (fs::path(o.cache_dir) / "served.glb").string();
    {
        std::ofstream f(copy, std::ios::binary);
        f.write(reinterpret_cast<const char*>(a->bytes.data()), std::streamsize(a->bytes.size()));
    }
    const Character downloaded = import_character(copy, 0);
    ASSERT_EQ(downloaded.vertex_count(), reference.vertex_count());
    ASSERT_EQ(downloaded.joint_count(), reference.joint_count());
    for (size_t v = 0; v < reference.vertex_count(); ++v) EXPECT_EQ(downloaded.positions[v], reference.positions[v]);
    for (size_t j = 0; j < reference.joint_count(); ++j)
        EXPECT_EQ(downloaded.nodes[size_t(downloaded.joint_node[j])].name,
                  reference.nodes[size_t(reference.joint_node[j])].name);
    const auto first = build_server_asset(all[0], o);
    EXPECT_NE(first->id, a->id);
}

// --build-strategy rate: a plain file's skin is the one of reorder, flatten
// and hierarchy that removes the most error per bit of the stream's records,
// cached apart from the default build (another file name), read back as built.
TEST(ServerAssets, BuildByRateIsCachedApartFromTheDefaultBuild) {
    AssetOptions o;
    std::vector<PendingAsset> pending;
    const auto [plain, rate] = built_twice("by_rate", o, [](AssetOptions& x) { x.build_by_rate = true; }, pending);
    ASSERT_TRUE(plain && rate);
    const Strategy s = rate->skin.strategy;
    EXPECT_TRUE(s == Strategy::Reorder || s == Strategy::Flatten || s == Strategy::Hierarchy) << strategy_name(s);
    EXPECT_TRUE(plain->skin.strategy == Strategy::Reorder || plain->skin.strategy == Strategy::Flatten);
    EXPECT_EQ(cached_builds(o.cache_dir), 2u) << "one cached build each";
    const auto again = build_server_asset(pending[0], o);
    EXPECT_EQ(again->skin.strategy, s);
    EXPECT_EQ(again->skin.order, rate->skin.order);
    // The bits of every bone per frame of each build (what the choice weighs), printed.
    const FrameSet f = sample_frames(plain->character, plain->selections, 30.0);
    double bp = 0, br = 0;
    for (double b : record_bits_per_bone(plain->character, plain->skin, f)) bp += b;
    for (double b : record_bits_per_bone(rate->character, rate->skin, f)) br += b;
    std::printf("CesiumMan: default build %s %.0f bits per frame, by rate %s %.0f\n", strategy_name(plain->skin.strategy), bp,
                strategy_name(s), br);
    EXPECT_GT(br, 0.0);
}

TEST(ServerAssets, FromVerticesBuildsAndCachesASkin) {
    AssetOptions o;
    o.cache_dir = temp_cache("scratch");
    o.from_vertices = true;
    o.scratch_bones = 4;
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({asset("AnimatedMorphSphere.gltf")}, o, pending).empty());
    ASSERT_EQ(pending.size(), 1u);
    EXPECT_TRUE(pending[0].from_vertices);
    const auto a = build_server_asset(pending[0], o);
    EXPECT_TRUE(a->progressive_file);
    EXPECT_LE(a->bone_count(), 4);
    EXPECT_GE(a->bone_count(), 1);
    // The second load reuses the cached build and its tables (same bytes, nothing rebuilt).
    const auto start = std::chrono::steady_clock::now();
    const auto b = build_server_asset(pending[0], o);
    EXPECT_EQ(a->id, b->id);
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 5.0);
    size_t sidecars = 0;
    for (const auto& e : fs::directory_iterator(o.cache_dir)) sidecars += e.path().extension() == ".json";
    EXPECT_EQ(sidecars, 1u);
    expect_same_tables(*a, *b);
}

namespace {

// Two assets' derived tables agree (relative tolerance: float rounding of recomputation).
void expect_same_tables(const ServerAsset& a, const ServerAsset& b) {
    auto near = [](double x, double y) { return std::abs(x - y) <= 1e-4 * std::max({1.0, std::abs(x), std::abs(y)}); };
    EXPECT_TRUE(near(a.diagonal, b.diagonal));
    EXPECT_TRUE(near(a.motion, b.motion)) << a.motion << " " << b.motion;
    EXPECT_TRUE(near(a.bind_radius, b.bind_radius));
    EXPECT_TRUE(near(a.max_scale, b.max_scale));
    EXPECT_EQ(a.format.scaled, b.format.scaled);
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(near(a.format.t_min[i], b.format.t_min[i]));
    ASSERT_EQ(a.segments.size(), b.segments.size());
    for (size_t s = 0; s < a.segments.size(); ++s) {
        EXPECT_EQ(a.segments[s].from, b.segments[s].from);
        EXPECT_EQ(a.segments[s].to, b.segments[s].to);
        ASSERT_EQ(a.segments[s].gap.size(), b.segments[s].gap.size());
        for (size_t m = 0; m < a.segments[s].gap.size(); ++m) {
            EXPECT_TRUE(near(a.segments[s].collapse[m], b.segments[s].collapse[m])) << s << " " << m;
            EXPECT_TRUE(near(a.segments[s].show_value[m], b.segments[s].show_value[m])) << s << " " << m;
            for (int g = 0; g < ServerAsset::kGapTable; ++g) {
                EXPECT_TRUE(near(a.segments[s].gap[m][size_t(g)], b.segments[s].gap[m][size_t(g)])) << s << " " << m << " " << g;
                EXPECT_TRUE(near(a.segments[s].refresh[m][size_t(g)], b.segments[s].refresh[m][size_t(g)]));
            }
        }
    }
}

}  // namespace

TEST(ServerAssets, ProgressiveFileTablesAreReadNotBuilt) {
    const std::string progskin = std::string(PROGSKIN_BIN_DIR) + "/tools/progskin";
    if (!std::ifstream(progskin).good()) GTEST_SKIP() << progskin << " not built";
    AssetOptions o;
    o.cache_dir = temp_cache("progressive");
    fs::create_directories(o.cache_dir);
    const std::string file = o.cache_dir + "/CesiumMan_progressive.glb";
    ASSERT_EQ(run(progskin + " build " + asset("CesiumMan.glb") + " -o " + file + " --quiet").code, 0);
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({file}, o, pending).empty());
    ASSERT_EQ(pending.size(), 1u);
    ASSERT_TRUE(pending[0].progressive);
    ASSERT_TRUE(nlohmann::json::parse(pending[0].extension_json).contains("server"));
    const auto start = std::chrono::steady_clock::now();
    const auto stored = build_server_asset(pending[0], o);
    const double read_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_TRUE(stored->warnings.empty()) << stored->warnings.front();
    // What the server would compute from the same file: the same tables.
    const auto computed = load_server_asset(file);
    const double build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() - read_s;
    std::printf("CesiumMan progressive: tables read in %.3f s, computed in %.3f s\n", read_s, build_s);
    expect_same_tables(*stored, *computed);
    EXPECT_LT(read_s, build_s);
    // Tables of another version are not used: computed, with a warning.
    PendingAsset old = pending[0];
    nlohmann::json ext = nlohmann::json::parse(old.extension_json);
    ext["server"]["version"] = kServerTablesVersion + 1;
    old.extension_json = ext.dump();
    const auto rebuilt = build_server_asset(old, o);
    ASSERT_FALSE(rebuilt->warnings.empty());
    EXPECT_NE(rebuilt->warnings.front().find("version"), std::string::npos) << rebuilt->warnings.front();
    expect_same_tables(*rebuilt, *computed);
}

TEST(ServerAssets, PlainFileBuiltOnceThenReadFromTheCache) {
    AssetOptions o;
    o.cache_dir = temp_cache("plain");
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({asset("Fox.glb")}, o, pending).empty());
    ASSERT_EQ(pending.size(), 1u);
    const auto t0 = std::chrono::steady_clock::now();
    const auto first = build_server_asset(pending[0], o);
    const auto t1 = std::chrono::steady_clock::now();
    const auto second = build_server_asset(pending[0], o);
    const auto t2 = std::chrono::steady_clock::now();
    const double build_s = std::chrono::duration<double>(t1 - t0).count();
    const double cached_s = std::chrono::duration<double>(t2 - t1).count();
    std::printf("Fox plain: built in %.3f s, from the cache in %.3f s\n", build_s, cached_s);
    size_t files = 0;
    for (const auto& e : fs::directory_iterator(o.cache_dir)) files += e.path().extension() == ".glb";
    EXPECT_EQ(files, 1u);
    EXPECT_LT(cached_s, build_s);
    EXPECT_EQ(first->id, second->id);  // clients download the original file either way
    EXPECT_EQ(first->skin.order, second->skin.order);
    EXPECT_EQ(first->skin.parents, second->skin.parents);
    EXPECT_EQ(first->skin.joints, second->skin.joints);
    ASSERT_EQ(first->skin.error.size(), second->skin.error.size());
    for (size_t k = 0; k < first->skin.error.size(); ++k)
        EXPECT_NEAR(first->skin.error[k].rms, second->skin.error[k].rms, 1e-9 + 1e-6 * first->skin.error[k].rms);
    expect_same_tables(*first, *second);
}

TEST(ServerAssets, PointCacheNeedsFromVertices) {
    // A PC2 point cache written from the sphere's morph animation.
    AssetOptions o;
    o.cache_dir = temp_cache("pc2");
    fs::create_directories(o.cache_dir);
    const std::string pc2 = o.cache_dir + "/sphere.pc2";
    progskin::save_pc2(progskin::load_vertex_animation(asset("AnimatedMorphSphere.gltf")), pc2);
    std::vector<PendingAsset> pending;
    const auto problems = check_server_assets({pc2}, o, pending);
    ASSERT_EQ(problems.size(), 1u);
    EXPECT_NE(problems[0].find("progskin build --from-vertices"), std::string::npos) << problems[0];
    o.from_vertices = true;
    o.scratch_bones = 3;
    ASSERT_TRUE(check_server_assets({pc2}, o, pending).empty());
    ASSERT_EQ(pending.size(), 1u);
    const auto a = build_server_asset(pending[0], o);
    EXPECT_LE(a->bone_count(), 3);
    EXPECT_EQ(a->character.vertex_count(), progskin::load_pc2(pc2).vertex_count);
}

namespace {

// A copy of a .glb with its animations taken out (an avatar exported for a
// game to drive): the JSON chunk rewritten, the binary chunk kept.
void write_without_animations(const std::string& in, const std::string& out) {
    std::ifstream f(in, std::ios::binary);
    std::vector<char> d{std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
    ASSERT_GE(d.size(), 20u);
    uint32_t json_len = 0;
    std::memcpy(&json_len, d.data() + 12, 4);
    nlohmann::json j = nlohmann::json::parse(d.begin() + 20, d.begin() + 20 + json_len);
    j.erase("animations");
    std::string text = j.dump();
    while (text.size() % 4) text.push_back(' ');
    const std::vector<char> bin(d.begin() + 20 + json_len, d.end());  // the BIN chunk, header included
    const uint32_t total = uint32_t(12 + 8 + text.size() + bin.size()), len = uint32_t(text.size()), type = 0x4E4F534A;
    std::ofstream o(out, std::ios::binary);
    o.write(d.data(), 8);
    o.write(reinterpret_cast<const char*>(&total), 4);
    o.write(reinterpret_cast<const char*>(&len), 4);
    o.write(reinterpret_cast<const char*>(&type), 4);
    o.write(text.data(), std::streamsize(text.size()));
    o.write(bin.data(), std::streamsize(bin.size()));
}

}  // namespace

// A character exported without animation, for a game to drive (the bundled
// CesiumMan with its animations taken out of the file): the server orders its
// bones by range-of-motion poses and says so, and takes the poses a game
// gives it (the original walk, and rigid poses far beyond it) where the rest
// pose's translation box refused them.
TEST(ServerAssets, AClipLessAvatarTakesTheGamesPoses) {
    const std::string dir = temp_cache("clipless");
    fs::create_directories(dir);
    const std::string file = dir + "/CesiumMan_noanim.glb";
    write_without_animations(asset("CesiumMan.glb"), file);
    AssetOptions o;
    o.cache_dir = dir + "/cache";
    o.build_by_rate = true;  // the server's default
    std::vector<PendingAsset> pending;
    ASSERT_TRUE(check_server_assets({file}, o, pending).empty());
    const auto a = build_server_asset(pending[0], o);
    ASSERT_TRUE(a->character.clips.empty());
    EXPECT_TRUE(contains(a->warnings, "no clip moves the skeleton", "range-of-motion")) << "the operator is not told";

    const Character walk = import_gltf(asset("CesiumMan.glb")).at(0);
    const auto sel = default_training_set(walk);
    InstanceSpec live;
    live.selection = -1;
    FrameEncoder enc({a}, {live}, 30.0f);
    std::vector<glm::dmat4> m(walk.joint_count());
    std::vector<Mat34> pose(m.size());
    int taken = 0;
    for (double t = 0; t < sel[0].duration(); t += 0.1) {
        sample_skinning_matrices(walk, sel[0], sel[0].start + t, m);
        for (size_t j = 0; j < m.size(); ++j) pose[j] = Mat34::from_glm(m[j]);
        taken += enc.push_pose(0, pose);
    }
    std::printf("walk: %d poses taken, %llu refused\n", taken, (unsigned long long)enc.stats().poses_out_of_range);
    // Arms and legs thrown about: every joint turned by up to 120 degrees, and
    // the skeleton's root joint moved by up to a fifth of the diagonal (a
    // crouch, a jump). The nodes above the skeleton stay: where the character
    // stands and faces travels in its root block.
    std::vector<char> is_joint(walk.nodes.size(), 0);
    for (int n : walk.joint_node) is_joint[size_t(n)] = 1;
    std::vector<glm::dmat4> locals(walk.nodes.size()), globals(walk.nodes.size());
    const double diagonal = a->diagonal;
    for (int i = 0; i < 50; ++i) {
        for (size_t n = 0; n < walk.nodes.size(); ++n) {
            const Node& nd = walk.nodes[n];
            const double angle = is_joint[n] ? 2.1 * std::sin(1.7 * double(i) + double(n)) : 0.0;
            const glm::dquat turn = glm::angleAxis(angle, glm::normalize(glm::dvec3(std::sin(double(n)), std::cos(double(i)), 0.5)));
            locals[n] = nd.has_matrix ? nd.matrix * glm::mat4_cast(turn)
                                      : glm::translate(glm::dmat4(1.0), nd.translation) * glm::mat4_cast(nd.rotation * turn) *
                                            glm::scale(glm::dmat4(1.0), nd.scale);
        }
        const size_t root = size_t(walk.joint_node[0]);  // CesiumMan's first joint is its root joint
        ASSERT_LT(walk.joint_parent[0], 0);
        const glm::dvec3 move = 0.2 * diagonal * glm::dvec3(std::sin(0.9 * i), std::cos(1.3 * i), std::sin(2.1 * i)) / std::sqrt(3.0);
        compose_node_globals(walk, locals, globals);
        const int up = walk.nodes[root].parent;
        const glm::dmat4 parent = up < 0 ? glm::dmat4(1.0) : globals[size_t(up)];
        locals[root] = glm::inverse(parent) * glm::translate(glm::dmat4(1.0), move) * parent * locals[root];
        compose_node_globals(walk, locals, globals);
        for (size_t j = 0; j < walk.joint_count(); ++j)
            pose[j] = Mat34::from_glm(globals[size_t(walk.joint_node[j])] * walk.inverse_bind[j]);
        taken += enc.push_pose(0, pose);
    }
    EXPECT_EQ(enc.stats().poses_out_of_range, 0u);
    EXPECT_GT(taken, 60);
    fs::remove_all(dir);
}

// --build-training range-of-motion: a plain file's build trains on
// range-of-motion poses whatever its clips (its error table is theirs), and
// is cached apart from the build on the clips.
TEST(ServerAssets, BuildTrainingRangeOfMotionIsCachedApart) {
    AssetOptions o;
    std::vector<PendingAsset> pending;
    const auto [clips, rom] = built_twice("rom_training", o, [](AssetOptions& x) { x.range_of_motion = true; }, pending);
    ASSERT_TRUE(clips && rom);
    EXPECT_FALSE(contains(rom->warnings, "no clip moves the skeleton", "")) << "the clips move it: no warning";
    const FrameSet f = range_of_motion_frames(rom->character, 30.0);
    const std::vector<LodError> on_rom = evaluate_error_table(rom->character, rom->skin, f);
    ASSERT_EQ(on_rom.size(), rom->skin.error.size());
    for (size_t k = 0; k < on_rom.size(); ++k)
        EXPECT_NEAR(rom->skin.error[k].rms, on_rom[k].rms, 1e-6 + 1e-3 * on_rom[k].rms) << "k " << k + 1;
    EXPECT_NE(rom->skin.error[0].rms, clips->skin.error[0].rms);
    EXPECT_EQ(cached_builds(o.cache_dir), 2u) << "one cached build each";
    const auto again = build_server_asset(pending[0], o);
    EXPECT_EQ(again->skin.order, rom->skin.order);
    fs::remove_all(o.cache_dir);
}
