// stream_assets.h — the server-side assets shared by the unit tests of the
// streaming modules (test_scheduler, test_packer, test_frame_encoder,
// test_pose_buffer), each loaded once per test binary: the bundled Fox and
// CesiumMan, and tests/data/skinned_morph.gltf (3 bones, 4 morph targets).
// Only scene.h: no server or client session.
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "scene.h"

namespace progskin::net::testing {

inline const std::vector<std::shared_ptr<ServerAsset>>& fox_and_cesium() {
    static const std::vector<std::shared_ptr<ServerAsset>> a = {
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/Fox.glb"),
        load_server_asset(std::string(PROGSKIN_ASSETS) + "/CesiumMan.glb")};
    return a;
}

inline const std::shared_ptr<ServerAsset>& skinned_morph_asset() {
    static const std::shared_ptr<ServerAsset> a = load_server_asset(std::string(PROGSKIN_TEST_DATA) + "/skinned_morph.gltf");
    return a;
}

// The selection playing exactly the clip `name`, or -1.
inline int selection_of_clip(const ServerAsset& a, const std::string& name) {
    for (size_t s = 0; s < a.selections.size(); ++s)
        if (a.selections[s].clips.size() == 1 && a.character.clips[size_t(a.selections[s].clips[0])].name == name)
            return int(s);
    return -1;
}

}  // namespace progskin::net::testing
