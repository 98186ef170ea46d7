// walk_root.cpp — walk_root (client.h): the circle a published character's
// root walks. A file of its own so that the WebAssembly client (web/), which
// has no client.cpp (sockets), publishes the same walk.
#include <cmath>

#include <glm/gtc/quaternion.hpp>

#include "client.h"

namespace progskin::net {

RootPose walk_root(const glm::dvec3& center, double radius, double speed, double t) {
    RootPose r;
    r.position = center;
    if (!(radius > 0) || !(speed > 0)) return r;
    const double a = speed * t / radius;  // radians around the circle
    r.position += glm::dvec3(radius * std::cos(a), 0.0, radius * std::sin(a));
    // Facing along the circle: +Z turned to the tangent (-sin a, 0, cos a).
    r.rotation = glm::angleAxis(float(-a), glm::vec3(0.0f, 1.0f, 0.0f));
    return r;
}

}  // namespace progskin::net
