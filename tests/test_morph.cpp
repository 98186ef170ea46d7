// test_morph.cpp — morph targets on skinned characters (glTF order: morphs, then
// skinning): import of tests/data/skinned_morph.gltf (make_gltf_fixtures.py),
// weight sampling (CUBICSPLINE, STEP, defaults), the importance figure, the
// progressive skin's error table measured on the morphed mesh, `progskin pose`
// and `inspect --json`, and the broken-file messages.
#include <gtest/gtest.h>

#include "run_command.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include <glm/gtc/quaternion.hpp>

#include "animation.h"
#include "errors.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "collapse.h"
#include "progressive_skin.h"
#include "thresholds.h"

using namespace progskin;
using namespace progskin::thresholds;

namespace {

std::string data(const std::string& name) { return std::string(PROGSKIN_TEST_DATA) + "/" + name; }

const Character& fixture() {
    static const Character c = import_character(data("skinned_morph.gltf"));
    return c;
}

int morph_named(const Character& c, const std::string& name) {
    for (size_t m = 0; m < c.morphs.size(); ++m)
        if (c.morphs[m].name == name) return int(m);
    return -1;
}

std::string import_error(const std::string& path) {
    try {
        import_gltf(path);
    } catch (const Error& e) {
        return e.what();
    }
    return {};
}


std::string progskin_bin() { return std::string(PROGSKIN_BIN_DIR) + "/tools/progskin"; }

}  // namespace

TEST(Morph, ImportsTargetsNamesAndDefaults) {
    const Character& c = fixture();
    ASSERT_EQ(c.morphs.size(), 4u);  // face: smile, blink, puff; hat: one unnamed target
    EXPECT_TRUE(c.has_morph_targets);
    const int smile = morph_named(c, "smile"), blink = morph_named(c, "blink"), puff = morph_named(c, "puff");
    const int hat = morph_named(c, "hat target 0");
    ASSERT_GE(smile, 0);
    ASSERT_GE(blink, 0);
    ASSERT_GE(puff, 0);
    ASSERT_GE(hat, 0);
    // mesh.weights for the face, node.weights (0.6) overriding mesh.weights (0.2) for the hat.
    EXPECT_EQ(c.morphs[size_t(smile)].default_weight, 0.0f);
    EXPECT_EQ(c.morphs[size_t(puff)].default_weight, 0.25f);
    EXPECT_FLOAT_EQ(c.morphs[size_t(hat)].default_weight, 0.6f);
    // Sparse target: only the 6 vertices above y = 2.4 of the upper primitive move.
    const MorphTarget& b = c.morphs[size_t(blink)];
    ASSERT_EQ(b.vertices.size(), 6u);
    for (size_t i = 0; i < b.vertices.size(); ++i) {
        EXPECT_GT(c.positions[b.vertices[i]].y, 2.4f);
        EXPECT_NEAR(b.position_deltas[i].y, -0.15f, 1e-6f);
        EXPECT_NEAR(b.position_deltas[i].z, 0.05f, 1e-6f);
    }
    EXPECT_TRUE(b.normal_deltas.empty());
    EXPECT_EQ(c.morphs[size_t(puff)].normal_deltas.size(), c.morphs[size_t(puff)].vertices.size());
    // The rigid hat's delta is rotated like its positions (30 degrees about z under the head).
    const MorphTarget& h = c.morphs[size_t(hat)];
    ASSERT_EQ(h.vertices.size(), 1u);
    const glm::dvec3 want = glm::angleAxis(glm::radians(30.0), glm::dvec3(0, 0, 1)) * glm::dvec3(0.1, 0.5, 0.0);
    EXPECT_NEAR(h.position_deltas[0].x, want.x, 1e-6);
    EXPECT_NEAR(h.position_deltas[0].y, want.y, 1e-6);
    // Weight channels are kept, not dropped.
    for (const std::string& note : c.notes) EXPECT_EQ(note.find("ignored"), std::string::npos) << note;
    ASSERT_EQ(c.clips.size(), 2u);
    EXPECT_EQ(c.clips[1].channels.size(), 1u);
    EXPECT_EQ(c.clips[1].channels[0].path, ChannelPath::Weights);
    EXPECT_FLOAT_EQ(c.clips[1].end, 1.0f);
}

TEST(Morph, SamplesWeightsCubicStepAndDefaults) {
    const Character& c = fixture();
    const int smile = morph_named(c, "smile"), blink = morph_named(c, "blink"), puff = morph_named(c, "puff");
    const int hat = morph_named(c, "hat target 0");
    std::vector<float> w(c.morphs.size());
    // CUBICSPLINE at a key: the key's value.
    sample_morph_weights(c, select_clips(c, "talk"), 0.8, w);
    EXPECT_NEAR(w[size_t(smile)], 0.8f, 1e-6f);
    EXPECT_NEAR(w[size_t(blink)], 0.5f, 1e-6f);
    EXPECT_NEAR(w[size_t(puff)], 0.6f, 1e-6f);
    EXPECT_FLOAT_EQ(w[size_t(hat)], 0.6f);  // not animated: its default
    // Between keys: the Hermite spline with tangents scaled by the interval.
    const double u = 0.5, d = 0.8, h00 = 2 * u * u * u - 3 * u * u + 1, h10 = u * u * u - 2 * u * u + u,
                 h01 = -2 * u * u * u + 3 * u * u, h11 = u * u * u - u * u;
    sample_morph_weights(c, select_clips(c, "talk"), 0.4, w);
    EXPECT_NEAR(w[size_t(smile)], h00 * 0.0 + h10 * d * 1.5 + h01 * 0.8 + h11 * d * -0.5, 1e-6);
    // STEP holds the previous key.
    sample_morph_weights(c, select_clips(c, "blink"), 0.49, w);
    EXPECT_EQ(w[size_t(blink)], 0.0f);
    sample_morph_weights(c, select_clips(c, "blink"), 0.7, w);
    EXPECT_EQ(w[size_t(blink)], 1.0f);
    // Rest pose: the defaults.
    sample_morph_weights(c, ClipSelection{}, 0.0, w);
    EXPECT_EQ(w[size_t(puff)], 0.25f);
    std::vector<float> wrong(1);
    EXPECT_THROW(sample_morph_weights(c, ClipSelection{}, 0.0, wrong), Error);
    // sample_frames carries the weights of every frame.
    const FrameSet fs = sample_frames(c, {select_clips(c, "blink")}, 10.0);
    ASSERT_EQ(fs.morph_count, 4);
    ASSERT_EQ(fs.frame_count(), 11u);
    EXPECT_EQ(fs.weights(4)[size_t(blink)], 0.0f);
    EXPECT_EQ(fs.weights(6)[size_t(blink)], 1.0f);
}

TEST(Morph, ImportanceIsRmsDisplacementPerUnitWeight) {
    const Character& c = fixture();
    const std::vector<double> imp = morph_importance(c);
    ASSERT_EQ(imp.size(), c.morphs.size());
    const int blink = morph_named(c, "blink");
    const double expected = std::sqrt(6 * (0.15 * 0.15 + 0.05 * 0.05) / double(c.vertex_count()));
    EXPECT_NEAR(imp[size_t(blink)], expected, 1e-7);
    // Moving the weight by 1 moves the mesh by exactly that RMS.
    std::vector<float> w0(c.morphs.size(), 0.0f), w1 = w0;
    w1[size_t(blink)] = 1.0f;
    std::vector<glm::vec3> a(c.vertex_count()), b(c.vertex_count());
    morph_positions(c, w0, a);
    morph_positions(c, w1, b);
    ErrorAccumulator acc(1.0);
    acc.add(a, b);
    EXPECT_NEAR(acc.stats().rms, imp[size_t(blink)], 1e-6);
}

TEST(Morph, ErrorTableMeasuredOnTheMorphedMesh) {
    const Character& c = fixture();
    const FrameSet frames = sample_frames(c, {select_clips(c, "talk")}, 30.0);
    const ProgressiveSkin s = build_progressive_skin(c, frames);
    ASSERT_EQ(s.bone_count(), 3);
    const std::vector<LodError> t = evaluate_error_table(c, s, frames);
    ASSERT_EQ(t.size(), s.error.size());
    for (size_t k = 0; k < t.size(); ++k) EXPECT_DOUBLE_EQ(s.error[k].rms, t[k].rms) << k;
    // All bones: the LOD is the reference (morphs included), to float rounding.
    EXPECT_LT(s.error.back().max_pct, kLosslessMorphFixturePct);
    EXPECT_GT(s.error.front().rms_pct, kOneBoneMinRmsPct);  // one bone: the nod is lost
    // The LOD keeps the morph weights: at full detail it moves with the morphs.
    std::vector<glm::vec3> ref(c.vertex_count()), lod(c.vertex_count()), bare(c.vertex_count());
    const size_t f = 12;
    reference_positions(c, frames, f, ref);
    lod_positions(c, s, frames, f, s.bone_count(), lod);
    skinned_bind_positions(c, frames, f, bare);
    ErrorAccumulator with(1.0), without(1.0);
    with.add(ref, lod);
    without.add(ref, bare);
    EXPECT_LT(with.stats().max, 1e-5);
    EXPECT_GT(without.stats().max, 0.05);
}

TEST(Morph, PoseAndInspectIncludeMorphs) {
    if (!std::ifstream(progskin_bin()).good()) GTEST_SKIP() << progskin_bin() << " not built";
    const Character& c = fixture();
    const CmdResult pose = run(progskin_bin() + " pose " + data("skinned_morph.gltf") + " --clip talk --time 0.37 --json");
    ASSERT_EQ(pose.code, 0) << pose.out;
    const nlohmann::json p = nlohmann::json::parse(pose.out);
    const FrameSet fs = sample_pose(c, select_clips(c, "talk"), 0.37);
    std::vector<glm::vec3> ref(c.vertex_count());
    reference_positions(c, fs, 0, ref);
    ASSERT_EQ(p["positions"].size(), ref.size());
    for (size_t v = 0; v < ref.size(); ++v)
        EXPECT_NEAR(p["positions"][v][2].get<double>(), ref[v].z, 1e-5) << v;
    const CmdResult ins = run(progskin_bin() + " inspect " + data("skinned_morph.gltf") + " --json");
    ASSERT_EQ(ins.code, 0) << ins.out;
    const nlohmann::json j = nlohmann::json::parse(ins.out.substr(ins.out.find('{')));
    EXPECT_EQ(j["morph_targets"].size(), 4u);
    EXPECT_EQ(j["morph_targets"][0]["name"], "smile");
    EXPECT_TRUE(j["morph_targets_streamed"].get<bool>());  // the morph block carries their weights (issue 24)
}

TEST(Morph, BrokenFilesNameTheDefect) {
    const std::pair<const char*, const char*> cases[] = {
        {"morph_weights_count.gltf", "node 4 weights has 2 values for 1 morph targets"},
        {"morph_target_count.gltf", "primitive 1 has 2 morph targets, primitive 0 has 3"},
        {"morph_channel_count.gltf", "output values for 3 keys of 3 morph weights"},
    };
    for (const auto& [file, phrase] : cases) {
        const std::string what = import_error(data(std::string("broken/") + file));
        ASSERT_FALSE(what.empty()) << file << " was accepted";
        EXPECT_NE(what.find(file), std::string::npos) << what;
        EXPECT_NE(what.find(phrase), std::string::npos) << what;
    }
}
