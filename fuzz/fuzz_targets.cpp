#include "fuzz_targets.h"

#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include "animation.h"
#include "errors.h"
#include "gltf_import.h"

namespace progskin::fuzz {

int gltf_import(const uint8_t* data, size_t size) {
    const bool glb = size >= 4 && std::memcmp(data, "glTF", 4) == 0;
    const std::string path = (std::filesystem::temp_directory_path() /
                              ("progskin-fuzz-" + std::to_string(getpid()) + (glb ? ".glb" : ".gltf")))
                                 .string();
    if (FILE* f = std::fopen(path.c_str(), "wb")) {
        if (size) std::fwrite(data, 1, size, f);
        std::fclose(f);
    } else {
        return 0;
    }
    int accepted = 0;
    try {
        ImportOptions opt;
        opt.require_skin = false;
        for (const Character& c : import_gltf(path, opt)) {
            // A few poses over the whole clip range, never a full sampling.
            for (const ClipSelection& sel : default_training_set(c)) {
                std::vector<glm::dmat4> m(c.joint_count());
                for (int i = 0; i < 4; ++i) sample_skinning_matrices(c, sel, sel.start + sel.duration() * i / 3.0, m);
            }
        }
        accepted = 1;
    } catch (const Error&) {
    }
    std::remove(path.c_str());
    return accepted;
}

}  // namespace progskin::fuzz
