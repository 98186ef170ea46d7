// view.h — a client's view of the scene (control.fbs View), decoded: what
// both the client (which sends it) and the server's scheduler (which weighs
// characters by it, docs/metrics.md §4) share.
#pragma once
#include <utility>
#include <vector>

#include "mat34.h"

namespace progskin::net {

struct ViewSpec {
    glm::vec3 camera{0.0f, 0.0f, 0.0f};
    float fov_y = 0.8f;              // radians
    float viewport_height = 1080.0f; // pixels
    std::vector<std::pair<int, float>> weights;  // explicit per-instance weights (instance, weight)
    bool has_camera = false;
};

}  // namespace progskin::net
