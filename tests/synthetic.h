// synthetic.h — small made-up skinned characters for tests and benchmarks.
#pragma once
#include <cmath>
#include <glm/gtc/matrix_transform.hpp>

#include "character.h"

namespace progskin::synth {

// A branching "tree" creature: `chains` limbs of `bones_per_chain` bones each
// hanging from one root, every bone 1 unit long along its limb direction;
// `rings` rings of 8 vertices per bone, weights blended smoothly between a bone
// and its parent near the joint. One clip of `frames` keys (LINEAR) in which
// every bone rotates about its own z axis with its own phase and amplitude.
inline Character make_tree(int chains, int bones_per_chain, int rings = 4, int frames = 31, float amplitude = 0.6f) {
    Character c;
    c.name = "synthetic tree";
    c.source = "synthetic";
    c.influences = 4;
    auto add_node = [&](int parent, glm::dvec3 t) {
        Node n;
        n.name = "bone" + std::to_string(c.nodes.size());
        n.gltf_index = int(c.nodes.size());
        n.parent = parent;
        n.translation = t;
        c.nodes.push_back(n);
        const int j = int(c.joint_node.size());
        c.joint_node.push_back(int(c.nodes.size()) - 1);
        c.joint_parent.push_back(parent);  // node index == joint index here
        return j;
    };
    add_node(-1, {0, 0, 0});
    std::vector<glm::dvec3> dir_of(1, glm::dvec3(0, 1, 0));
    for (int ch = 0; ch < chains; ++ch) {
        const double ang = 2.0 * M_PI * ch / chains;
        const glm::dvec3 dir(std::cos(ang), 0.3, std::sin(ang));
        int parent = 0;
        for (int b = 0; b < bones_per_chain; ++b) {
            parent = add_node(parent, b == 0 ? glm::dvec3(0, 0.5, 0) : dir);
            dir_of.push_back(dir);
        }
    }
    const int B = int(c.joint_node.size());
    // Rest globals -> inverse bind.
    std::vector<glm::dmat4> G(size_t(B), glm::dmat4(1.0));
    for (int j = 0; j < B; ++j) {
        const glm::dmat4 L = glm::translate(glm::dmat4(1.0), c.nodes[j].translation);
        G[j] = c.joint_parent[j] >= 0 ? G[c.joint_parent[j]] * L : L;
        c.inverse_bind.push_back(glm::inverse(G[j]));
    }
    // Vertices: rings along each bone (from its origin along the direction of its child).
    for (int j = 1; j < B; ++j) {
        const glm::dvec3 o = glm::dvec3(G[j][3]);
        const glm::dvec3 d = glm::normalize(dir_of[j]);
        const glm::dvec3 u = glm::normalize(glm::cross(d, glm::dvec3(0, 0, 1)) + glm::dvec3(1e-3));
        const glm::dvec3 w = glm::normalize(glm::cross(d, u));
        for (int r = 0; r < rings; ++r) {
            const double s = (r + 0.5) / rings;
            for (int k = 0; k < 8; ++k) {
                const double a = 2.0 * M_PI * k / 8;
                const glm::dvec3 p = o + d * s + 0.15 * (std::cos(a) * u + std::sin(a) * w);
                c.positions.push_back(glm::vec3(p));
                c.normals.push_back(glm::vec3(std::cos(a) * u + std::sin(a) * w));
                const float wp = float(std::max(0.0, 0.5 - s));  // share with parent near the joint
                c.joints.insert(c.joints.end(), {uint16_t(j), uint16_t(c.joint_parent[j]), 0, 0});
                c.weights.insert(c.weights.end(), {1.0f - wp, wp, 0.0f, 0.0f});
            }
        }
    }
    PrimitiveRange pr;
    pr.node = -1;
    pr.count = uint32_t(c.positions.size());
    c.primitives.push_back(pr);
    Clip clip;
    clip.name = "wiggle";
    clip.gltf_index = 0;
    for (int j = 0; j < B; ++j) {
        Channel ch;
        ch.node = j;
        ch.path = ChannelPath::Rotation;
        ch.interpolation = Interpolation::Linear;
        const double amp = amplitude * (0.3 + 0.7 * ((j * 7) % 5) / 4.0) / (1.0 + 0.15 * j);
        for (int f = 0; f < frames; ++f) {
            const double t = f / 30.0;
            ch.times.push_back(float(t));
            const double ang = amp * std::sin(2.0 * M_PI * (t + 0.13 * j));
            const glm::dquat q = glm::angleAxis(ang, glm::normalize(glm::dvec3(0.2, 0.1 * j, 1.0)));
            ch.values.insert(ch.values.end(), {float(q.x), float(q.y), float(q.z), float(q.w)});
        }
        clip.channels.push_back(ch);
    }
    clip.start = 0.0f;
    clip.end = float((frames - 1) / 30.0);
    c.clips.push_back(clip);
    return c;
}

}  // namespace progskin::synth
