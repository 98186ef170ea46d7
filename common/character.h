// character.h — one skinned character as imported from glTF (docs/metrics.md §1).
//
// A Character is plain data: the node hierarchy (every node of the file that is
// an ancestor of a joint, a joint, or a skinned/rigid mesh node), the joints
// with their inverse bind matrices, the merged vertex stream and the animation
// clips. It knows nothing of progressive order; see progressive_skin.h.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "mat34.h"

namespace progskin {

// A glTF node's rest transform. Local matrix = matrix if has_matrix, else T*R*S.
struct Node {
    std::string name;
    int gltf_index = -1;  // node index in the source file
    int parent = -1;      // index into Character::nodes, -1 for a scene root
    glm::dvec3 translation{0.0};
    glm::dquat rotation{1.0, 0.0, 0.0, 0.0};  // glm order (w, x, y, z)
    glm::dvec3 scale{1.0};
    bool has_matrix = false;
    glm::dmat4 matrix{1.0};
};

enum class Interpolation : uint8_t { Step, Linear, CubicSpline };
enum class ChannelPath : uint8_t { Translation, Rotation, Scale, Weights };

// One animation channel. values: components per key = 3 (T, S), 4 (R, x y z w
// as glTF stores quaternions) or morph_count (Weights); CubicSpline keys hold
// in-tangent, value, out-tangent (3 * components floats per key), as the glTF
// spec lays them out.
struct Channel {
    int node = -1;  // index into Character::nodes (for Weights: the mesh node)
    ChannelPath path = ChannelPath::Translation;
    int morph_first = 0;  // Weights only: the channel's values are Character::morphs
    int morph_count = 0;  //   [morph_first, morph_first + morph_count), in target order
    Interpolation interpolation = Interpolation::Linear;
    std::vector<float> times;   // strictly increasing (checked on import)
    std::vector<float> values;  // decoded to float (normalized ints converted)
};

struct Clip {
    std::string name;
    int gltf_index = -1;
    std::vector<Channel> channels;
    float start = 0.0f;  // min key time over channels
    float end = 0.0f;    // max key time over channels
};

// Where a run of the merged vertex stream came from (export and `pose` order).
struct PrimitiveRange {
    int node = -1;       // glTF node index of the mesh node
    int mesh = -1;       // glTF mesh index
    int primitive = -1;  // primitive index in the mesh
    uint32_t first = 0;  // first vertex in Character::positions
    uint32_t count = 0;
    bool rigid = false;  // mesh rigidly parented to a joint (weight 1 on rigid_joint)
    int skin = -1;       // glTF skin index for skinned primitives
};

// One morph target of the merged vertex stream: target `target` of the mesh of
// glTF node `gltf_node`, over all primitives of that mesh (glTF requires the
// same number of targets in every primitive). Sparse: only vertices whose
// position or normal delta is non-zero are listed. Deltas are in the space of
// Character::positions (rigid meshes: transformed like their positions).
// glTF order of evaluation: morphed = positions + sum_m w_m * delta_m, then
// skinning (common/error_metric.h, morph_positions).
struct MorphTarget {
    std::string name;          // mesh.extras.targetNames[target] when present, else "<node name> target i"
    int node = -1;             // index into Character::nodes of the mesh node
    int gltf_node = -1;        // its node index in the file
    int target = -1;           // index of the target in the mesh
    float default_weight = 0;  // node.weights, else mesh.weights, else 0 (the rest pose's weight)
    std::vector<uint32_t> vertices;          // ascending indices into Character::positions
    std::vector<glm::vec3> position_deltas;  // per listed vertex
    std::vector<glm::vec3> normal_deltas;    // per listed vertex, or empty (no NORMAL target)
};

struct Character {
    std::string name;
    std::string source;  // file it came from

    std::vector<Node> nodes;

    // Joints, in the order of the (first) glTF skin, then joints of further skins
    // of the same skeleton that were not yet present.
    std::vector<int> joint_node;           // joint -> index into nodes
    std::vector<int> joint_parent;         // nearest ancestor that is a joint, -1 if none
    std::vector<glm::dmat4> inverse_bind;  // per joint (identity when absent in the file)

    // Merged vertex stream, `influences` slots per vertex (4 or 8); unused slots
    // have weight 0 and joint 0. Weights sum to 1 (renormalised on import).
    std::vector<glm::vec3> positions;  // bind-space positions, as in the file
    std::vector<glm::vec3> normals;    // same count as positions, or empty
    std::vector<uint32_t> triangles;   // 3 indices per triangle into positions (may be empty)
    int influences = 4;
    std::vector<uint16_t> joints;  // positions.size() * influences, indices into joint_node
    std::vector<float> weights;    // positions.size() * influences
    std::vector<PrimitiveRange> primitives;

    std::vector<MorphTarget> morphs;  // evaluated before skinning; weights animated by Weights channels
    std::vector<Clip> clips;

    // Import diagnostics for `inspect`.
    uint32_t renormalised_vertices = 0;  // vertices whose weights did not sum to 1
    bool has_morph_targets = false;      // morphs is not empty (kept for callers of the old flag)
    std::vector<std::string> notes;      // human-readable notes of the above and similar

    size_t joint_count() const { return joint_node.size(); }
    size_t vertex_count() const { return positions.size(); }
};

}  // namespace progskin
