// scene.h — what a server hosts: assets (a character, its progressive skin,
// the file bytes the clients download) and instances (an asset played with a
// clip, a time offset and a position, or driven by live poses).
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "animation.h"
#include "bone_codec.h"
#include "character.h"
#include "progressive_skin.h"

namespace progskin::net {

// One step of a lower convex hull of an error table: going from `from`
// bones to `to` bones removes `gain` of error.
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
    // The scheduler's cost model (scheduler.h), per segment of the skin:
    // segment 0 is bone 0, segment s >= 1 the bones [from, to) of one step of
    // the lower convex hull of the squared error table e(k)^2. Each table has
    // one entry per clip selection (what an instance plays) and a last one
    // over all of them (live poses).
    // These tables are stored in progressive files and the server's cache
    // (server_tables_json): whoever changes what they hold or how
    // finish_server_asset computes them must bump kServerTablesVersion, so
    // that stale stored tables are recomputed instead of read.
    static constexpr int kGapTable = 17;
    struct Segment {
        int from = 0, to = 1;
        // Squared RMS error (model units^2) the segment removes when shown:
        // e(from)^2 - e(to)^2 over the selection's frames (segment 0:
        // (diagonal + e(1))^2, nothing shown).
        std::vector<double> collapse;
        // gap[m][g]: mean squared vertex error (model units^2) over an
        // interpolation interval of g frames at 30 Hz when only this segment's
        // bones are interpolated between frames g apart as the client does
        // (cubic over the neighbours g before and after, pose_buffer.h) and every
        // other bone is exact; gap[m][0] = gap[m][1] = 0. Beyond the table it
        // grows as g^2 (a linear drift).
        std::vector<std::array<double, kGapTable>> gap;
        double gap_at(int model, double g) const;
        // refresh[m][a] = a (a + 1) (G(a + 1) - G(a)) for a = 1..kGapTable-1,
        // the value of a refresh at age a at 30 Hz (scheduler.h); [0] unused.
        std::vector<std::array<double, kGapTable>> refresh;
        // show_value[m] = max over p < HOLD_TICKS of p (C - G(p)): showing the
        // segment, refreshed every p ticks, saves C - G(p) per tick for the
        // bytes of one refresh every p ticks (scheduler.h).
        std::vector<double> show_value;
    };
    std::vector<Segment> segments;
    double bind_radius = 0;          // max |bind-space position|
    // Per morph target: RMS vertex displacement per unit weight (error_metric.h
    // morph_importance), the scheduler's value of sending a weight.
    std::vector<double> morph_importance;
    // What the stream does not carry that the file has (e.g. morph targets past MAX_MORPHS),
    // one line each, for the server to print on stderr.
    std::vector<std::string> warnings;
    double max_scale = 1;            // of the skinning matrices over the training frames
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
    nlohmann::json extension;     // the file's extension object (its "server" tables, if any)
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
// its progressive skin and tables are cached as <cache>/<content hash>-c<N>-t<version>.glb
// and read from there on later starts. Characters other than the file's first
// are served as a copy of the file with their skins first (cached too), since
// a client plays character 0 of the file it downloads. A file without a skin
// (options.from_vertices) is built into <cache>/<content hash>-scratch<bones>.glb
// once, its tables kept beside it. Throws Error.
std::shared_ptr<ServerAsset> build_server_asset(const PendingAsset& p, const AssetOptions& options);
// Builds the derived fields (format, hull, motion...) of an asset whose
// character and skin are set; used by load_server_asset and by tests.
void finish_server_asset(ServerAsset& a);
// What finish_server_asset derives (diagonal, format, motion, bind_radius,
// max_scale and the segment tables), as JSON: `progskin build` stores it in
// the PROGSKIN_progressive_skin extension under "server", and the server's
// cache of plain files keeps it, so that loading builds nothing. Versioned
// (kServerTablesVersion): tables of another version are not used.
inline constexpr int kServerTablesVersion = 1;
nlohmann::json server_tables_json(const ServerAsset& a);
// Sets those fields of `a` (character, skin and selections already set) from
// server_tables_json output. Returns false, leaving `a` as it was and saying
// why in *why, when the JSON is absent, of another version, or does not fit
// the asset (bone count, selections, segment layout); throws nothing.
bool read_server_tables(const nlohmann::json& j, ServerAsset& a, std::string* why = nullptr);

// The lower convex hull of the points (k, e[k - 1]), k = 1..B, as steps.
std::vector<HullStep> error_hull(const std::vector<double>& e);

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
