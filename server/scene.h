// scene.h — what a server hosts: assets (a character, its progressive skin,
// the file bytes the clients download) and instances (an asset played with a
// clip, a time offset and a position, or driven by live poses).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "character.h"
#include "progressive_skin.h"

namespace progskin::net {

// One step of the lower convex hull of the error table: going from `from`
// bones to `to` bones removes `gain` of RMS error (model units).
struct HullStep {
    int from = 0, to = 0;
    double gain = 0;
};

struct ServerAsset {
    std::string path, name;          // file and its base name
    std::vector<uint8_t> bytes;      // the file as clients download it
    uint64_t id = 0;                 // content_hash(bytes)
    bool progressive_file = false;   // the skin came from the file's PROGSKIN_progressive_skin extension
    Character character;
    ProgressiveSkin skin;
    std::vector<ClipSelection> selections;  // independently played clip groups
    RecordFormat format;
    double diagonal = 1;
    double motion = 0;               // RMS vertex motion per second (model units/s)
    // gap_error[g]: RMS error (model units) of a pose interpolated (slerp per
    // bone) half-way between two frames g/30 s apart, g = 0..kGapTable-1
    // (gap_error[0] = gap_error[1] = 0 by definition: consecutive frames).
    static constexpr int kGapTable = 17;
    std::vector<double> gap_error;
    double bind_radius = 0;          // max |bind-space position|
    double max_scale = 1;            // of the skinning matrices over the training frames
    std::vector<HullStep> hull;      // lower convex hull of e(k), k = 1..B
    double e1 = 0;                   // e(1): RMS error with only bone 0
    int bone_count() const { return skin.bone_count(); }
};

// Loads a glTF (progressive or plain: a plain file's skin is built here with
// build_progressive_skin on its default training set at 30 fps). Throws Error.
std::shared_ptr<ServerAsset> load_server_asset(const std::string& path);
// Builds the derived fields (format, hull, motion...) of an asset whose
// character and skin are set; used by load_server_asset and by tests.
void finish_server_asset(ServerAsset& a);
// The lower convex hull of an error table (used by the scheduler).
std::vector<HullStep> error_hull(const std::vector<LodError>& error);

struct InstanceSpec {
    int asset = 0;              // index into the server's asset list
    int selection = 0;          // index into ServerAsset::selections (-1: live poses only)
    float time_offset = 0;      // seconds
    float speed = 1;
    glm::vec3 position{0.0f};
};

// Lays out n instances cycling over assets and their clip selections, on a
// grid spaced by the largest asset diagonal, with varied time offsets.
std::vector<InstanceSpec> crowd_layout(const std::vector<std::shared_ptr<ServerAsset>>& assets, int n);

// The bundled default character set (assets/Fox.glb, assets/CesiumMan.glb),
// searched relative to `hint_dir` (a directory), then its parents, then PROGSKIN_ASSETS.
std::vector<std::string> default_asset_paths(const std::string& hint_dir);

}  // namespace progskin::net
