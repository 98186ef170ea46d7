// progressive_asset.cpp — see progressive_asset.h.
#include "progressive_asset.h"

#include <tiny_gltf.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "errors.h"
#include "gltf_accessor.h"
#include "gltf_import.h"

namespace progskin {

namespace gltf {
nlohmann::json value_json(const tinygltf::Value& v) {
    if (v.IsObject()) {
        nlohmann::json o = nlohmann::json::object();
        for (const auto& key : v.Keys()) o[key] = value_json(v.Get(key));
        return o;
    }
    if (v.IsArray()) {
        nlohmann::json a = nlohmann::json::array();
        for (size_t i = 0; i < v.ArrayLen(); ++i) a.push_back(value_json(v.Get(int(i))));
        return a;
    }
    if (v.IsString()) return v.Get<std::string>();
    if (v.IsBool()) return v.Get<bool>();
    if (v.IsInt()) return v.Get<int>();
    if (v.IsNumber()) return v.GetNumberAsDouble();
    return nullptr;
}

}  // namespace gltf

namespace {
constexpr const char* kExtension = "PROGSKIN_progressive_skin";

tinygltf::Model load_model(const std::string& path) {
    tinygltf::Model model;
    gltf::load_model(path, model);
    return model;
}
}  // namespace

bool read_progressive_extension(const std::string& path, const Character& c, ProgressiveSkin& out,
                                std::string* raw_json) {
    tinygltf::Model m = load_model(path);
    const tinygltf::Skin* skin = nullptr;
    for (const PrimitiveRange& r : c.primitives)
        if (!r.rigid && r.skin >= 0 && size_t(r.skin) < m.skins.size() &&
            m.skins[size_t(r.skin)].extensions.count(kExtension)) {
            skin = &m.skins[size_t(r.skin)];
            break;
        }
    if (!skin) return false;
    const nlohmann::json j = gltf::value_json(skin->extensions.at(kExtension));
    if (raw_json) *raw_json = j.dump();
    const int B = int(c.joint_count());
    auto bad = [&](const std::string& what) { return Error(path + ": " + kExtension + ": " + what); };
    if (!j.is_object() || j.value("version", 0) != 1) throw bad("unsupported version");
    const auto& parents = j.at("parents");
    const auto& corr = j.at("corrections");
    if (!parents.is_array() || int(parents.size()) != B) throw bad("'parents' must list one entry per joint");
    if (!corr.is_array() || corr.size() != size_t(B) * 12) throw bad("'corrections' must hold 12 numbers per joint");
    out = ProgressiveSkin{};
    out.strategy = parse_strategy(j.value("strategy", std::string("reorder")));
    out.order.resize(size_t(B));
    for (int b = 0; b < B; ++b) out.order[b] = b;
    out.parents.resize(size_t(B));
    for (int b = 0; b < B; ++b) {
        const int p = parents[size_t(b)].is_number_integer() ? parents[size_t(b)].get<int>() : -2;
        if ((b == 0 && p != -1) || (b > 0 && (p < 0 || p >= b)))
            throw bad("parent of bone " + std::to_string(b) + " must be " + (b ? "in 0.." + std::to_string(b - 1) : "-1"));
        out.parents[b] = int16_t(p);
    }
    out.corrections.resize(size_t(B));
    for (int b = 0; b < B; ++b)
        for (int i = 0; i < 12; ++i) {
            const auto& x = corr[size_t(b) * 12 + i];
            if (!x.is_number() || !std::isfinite(x.get<double>())) throw bad("correction values must be finite numbers");
            out.corrections[b].m[i] = x.get<float>();
        }
    out.diagonal = j.value("diagonal", 0.0);
    if (j.contains("error") && j["error"].is_array())
        for (const auto& e : j["error"]) {
            if (!e.is_object()) throw bad("'error' entries must be objects");
            out.error.push_back({e.value("bones", 0), e.value("rms", 0.0), e.value("max", 0.0), e.value("rms_pct", 0.0),
                                 e.value("max_pct", 0.0), e.value("influences", 0.0),
                                 e.value("distortion_pct", -1.0)});
        }
    out.influences = c.influences;
    out.joints = c.joints;
    out.weights = c.weights;
    return true;
}

ProgressiveAsset load_progressive(const std::string& path, int character_index) {
    ProgressiveAsset a;
    a.character = import_character(path, character_index);
    a.progressive = read_progressive_extension(path, a.character, a.skin);
    return a;
}

}  // namespace progskin
