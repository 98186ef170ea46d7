// scene.h — what a server hosts: assets (a character, its progressive skin,
// the file bytes the clients download) and instances (an asset played with a
// clip, a time offset and a position, or driven by live poses).
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "bone_record.h"
#include "character.h"
#include "cost_model.h"
#include "progressive_skin.h"

namespace progskin::net {

struct ServerAsset : AssetTables {
    std::string path, name;          // file and its base name
    std::vector<uint8_t> bytes;      // the file as clients download it
    uint64_t id = 0;                 // content_hash(bytes)
    bool progressive_file = false;   // the skin came from the file's PROGSKIN_progressive_skin extension
    Character character;
    ProgressiveSkin skin;
    std::vector<ClipSelection> selections;  // independently played clip groups
    RecordFormat format;             // the wire record of its bones (from the tables' translation box)
    RelativeFormat relative;         // the frame stream's parent-relative records (bone_record.h)
    // diagonal, motion, bind_radius, max_scale, the translation box and the
    // scheduler's cost model (segments, per clip selection and one for live
    // poses): AssetTables (cost_model.h), computed by finish_server_asset or
    // read from the file's stored tables.
    // Per morph target: RMS vertex displacement per unit weight (error_metric.h
    // morph_importance), the scheduler's value of sending a weight.
    std::vector<double> morph_importance;
    // What the stream does not carry that the file has (e.g. morph targets past MAX_MORPHS),
    // one line each, for the server to print on stderr.
    std::vector<std::string> warnings;
    int bone_count() const { return skin.bone_count(); }
};

// Loads character 0 of a glTF (progressive or plain: a plain file's skin is
// built here with build_progressive_skin on its default training set at 30
// fps). Throws Error.
std::shared_ptr<ServerAsset> load_server_asset(const std::string& path);

// How progskin-server turns its --asset arguments into assets: first
// check_server_assets (import and size checks of every file, nothing built),
// then build_server_asset per character (the expensive part).
struct AssetOptions {
    bool from_vertices = false;  // files without a skin: build one from their vertex animation
    int scratch_bones = 16;      // bones of such a build (progskin build --from-vertices --bones)
    std::string cache_dir;       // derived files (server_cache_dir() when empty)
    // Plain files: build as progskin build --strategy rate (reorder, flatten
    // and hierarchy, the most error removed per bit of the stream's records)
    // instead of --strategy auto (the lower mean error of reorder and flatten).
    bool build_by_rate = false;
    // Plain files: train the build on range-of-motion poses whatever the
    // clips (progskin build --clip range-of-motion), for avatars a game
    // animates whose clips say little of it. Files whose clips do not move
    // the skeleton train on them anyway (offline/range_of_motion.h).
    bool range_of_motion = false;
};
// $XDG_CACHE_HOME/progskin, else $HOME/.cache/progskin, else ./progskin-cache.
std::string server_cache_dir();

// One character to serve, checked but not built.
struct PendingAsset {
    std::string path;             // the file
    std::string label;            // "file.glb", or "file.glb#N" when the file holds several characters
    int character = 0;            // index in the file (import_gltf order)
    int characters_in_file = 1;
    bool from_vertices = false;   // no skin: a skin is built from the vertex animation
    Character imported;           // the imported character (empty when from_vertices)
    ProgressiveSkin skin;         // read from the file's extension when progressive
    bool progressive = false;
    std::string extension_json;   // the file's extension object as stored (its "server" tables, if any)
};

// Checks every --asset argument (FILE: every character of the file; FILE#N:
// character N) before anything expensive is built: the file imports, it has a
// skin (else the message names `progskin build --from-vertices`, unless
// options.from_vertices), the index exists, bones fit the wire (MAX_BONES),
// the character has vertices, its clips fit the sampling limit, a progressive
// extension decodes. Returns every problem found, one line each naming the
// file (empty: all fine); `out` gets one PendingAsset per character to serve.
std::vector<std::string> check_server_assets(const std::vector<std::string>& args, const AssetOptions& options,
                                             std::vector<PendingAsset>& out);
// Builds what a checked character needs to be served. A progressive file's
// skin and stored server tables are used as they are (tables missing or of
// another version are recomputed, with a warning). A plain file is built once:
// its progressive skin and tables are cached as <cache>/<content hash>-c<N>-t<version>-b2[r][m].glb
// (r: options.build_by_rate, m: options.range_of_motion)
// and read from there on later starts. Characters other than the file's first
// are served as a copy of the file with their skins first (cached too), since
// a client plays character 0 of the file it downloads. A file without a skin
// (options.from_vertices) is built into <cache>/<content hash>-scratch<bones>.glb
// once, its tables kept beside it. Throws Error.
std::shared_ptr<ServerAsset> build_server_asset(const PendingAsset& p, const AssetOptions& options);
// Sets the derived fields of an asset whose character and skin are set: its
// clip selections when none (default_training_set), its tables
// (offline/cost_tables.h compute_asset_tables) and record format. Throws
// Error when the bone count cannot be streamed. Used by load_server_asset,
// build_server_asset and tests.
void finish_server_asset(ServerAsset& a);

struct InstanceSpec {
    int asset = 0;              // index into the server's asset list
    int selection = 0;          // index into ServerAsset::selections (-1: live poses only)
    float time_offset = 0;      // seconds
    float speed = 1;
    bool once = false;          // the clip plays once and holds its last frame (else it loops)
    glm::vec3 position{0.0f};   // world placement (clip instances; live poses carry their own root)
    glm::quat rotation{1, 0, 0, 0};
    // A player's character (control Spawn): owned by one session, which
    // alone publishes its poses and never receives it back.
    uint64_t owner = 0;         // session id, 0: the server's own
    // What the publisher announced for observers' references (control.fbs Instance).
    std::vector<int> announced_clips;
    uint64_t publisher_start_us = 0;
    glm::dvec3 walk_center{0.0};
    double walk_radius = 0, walk_speed = 0;
    // The character's id across a world (control.fbs Instance.world_id): 0
    // asks the encoder for one (FrameEncoder::add_instance); a foreign
    // character keeps the one its own node gave it.
    uint64_t world_id = 0;
};

// Lays out n instances cycling over assets and their clip selections, on a
// grid spaced by the largest asset diagonal, with varied time offsets.
std::vector<InstanceSpec> crowd_layout(const std::vector<std::shared_ptr<ServerAsset>>& assets, int n);
// One instance per asset and clip group, side by side along x (what
// progskin-server serves without --crowd).
std::vector<InstanceSpec> default_instances(const std::vector<std::shared_ptr<ServerAsset>>& assets);

// The bundled default character set (assets/Fox.glb, assets/CesiumMan.glb),
// searched relative to `hint_dir` (a directory), then its parents, then PROGSKIN_ASSETS.
std::vector<std::string> default_asset_paths(const std::string& hint_dir);

}  // namespace progskin::net
