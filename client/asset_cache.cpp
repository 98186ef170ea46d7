// asset_cache.cpp — see asset_cache.h.
#include "asset_cache.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "client_palette.h"
#include "errors.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "wire.h"

namespace progskin::net {

namespace fs = std::filesystem;

std::vector<uint8_t> read_file(const std::string& p) {
    std::ifstream f(p, std::ios::binary);
    if (!f) return {};
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

std::string cached_asset_path(const std::string& dir, uint64_t id, bool glb) {
    return (fs::path(dir) / (hex64(id) + (glb ? ".glb" : ".gltf"))).string();
}

bool is_glb(std::span<const uint8_t> bytes) {
    return bytes.size() >= 4 && bytes[0] == 'g' && bytes[1] == 'l' && bytes[2] == 'T' && bytes[3] == 'F';
}

std::string write_cached_asset(const std::string& path, std::span<const uint8_t> bytes, const void* writer) {
    fs::path tmp = path;
    tmp += ".part" + std::to_string(::getpid()) + "-" + std::to_string(reinterpret_cast<uintptr_t>(writer));
    {
        std::ofstream f(tmp, std::ios::binary);
        f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
        if (!f) return "cannot write " + tmp.string();
    }
    std::error_code ec;
    fs::rename(tmp, path, ec);
    if (ec) return "cannot write " + path + ": " + ec.message();
    return {};
}

std::string default_cache_dir() {
    if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/progskin";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/progskin";
    return "/tmp/progskin-cache";
}
void check_external_uris(const std::string& path) {
    const std::vector<uint8_t> bytes = read_file(path);
    std::string_view json(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    if (bytes.size() >= 20 && std::memcmp(bytes.data(), "glTF", 4) == 0) {  // GLB: the JSON chunk
        const uint32_t n = uint32_t(bytes[12]) | uint32_t(bytes[13]) << 8 | uint32_t(bytes[14]) << 16 | uint32_t(bytes[15]) << 24;
        if (n > bytes.size() - 20) return;  // the importer reports the truncation
        json = json.substr(20, n);
    }
    const nlohmann::json j = nlohmann::json::parse(json, nullptr, false);
    if (j.is_discarded() || !j.is_object()) return;  // the importer reports it
    const fs::path dir = fs::weakly_canonical(fs::absolute(fs::path(path)).parent_path());
    for (const char* key : {"buffers", "images"}) {
        auto it = j.find(key);
        if (it == j.end() || !it->is_array()) continue;
        for (const auto& e : *it) {
            if (!e.is_object() || !e.contains("uri") || !e["uri"].is_string()) continue;
            const std::string uri = e["uri"].get<std::string>();
            if (uri.rfind("data:", 0) == 0) continue;  // embedded
            auto refuse = [&](const std::string& why) {
                throw Error(path + ": " + key + " uri \"" + uri.substr(0, 80) + "\" refused: " + why);
            };
            // Plain relative names only: nothing to decode (%, +), no scheme
            // or drive (:), no backslash, no absolute path, no "..".
            if (uri.empty()) refuse("empty");
            for (char c : uri)
                if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-' || c == '/'))
                    refuse("only letters, digits, '.', '_', '-' and '/' are allowed");
            if (uri[0] == '/') refuse("absolute path, outside the cache folder");
            for (const auto& part : fs::path(uri))
                if (part == "..") refuse("\"..\" leads outside the cache folder");
            // It must exist inside the cache folder (symbolic links resolved),
            // so the loader finds it there and never searches the working directory.
            std::error_code ec;
            const fs::path real = fs::canonical(dir / uri, ec);
            if (ec || !fs::is_regular_file(real, ec)) refuse("no such file in the cache folder " + dir.string());
            const std::string d = dir.string() + "/";
            if (real.string().compare(0, d.size(), d) != 0) refuse("resolves outside the cache folder " + dir.string());
        }
    }
}

std::string read_asset_format(const wire::Asset& a, RecordFormat& out) {
    if (a.t_min()) out.t_min = {a.t_min()->x(), a.t_min()->y(), a.t_min()->z()};
    if (a.t_max()) out.t_max = {a.t_max()->x(), a.t_max()->y(), a.t_max()->z()};
    out.scaled = a.scaled();
    out.scale = a.scale();
    if (!(out.scale >= kMinReferenceScale && out.scale <= kMaxReferenceScale)) return "a bad reference scale";
    out.t_step = a.t_step();
    if (!translation_step_fits(out.t_min, out.t_max, out.t_step)) return "a bad translation step";
    return {};
}

std::shared_ptr<ClientAsset> load_client_asset(const wire::Asset* a, const std::string& path) {
    check_external_uris(path);
    auto ca = std::make_shared<ClientAsset>();
    ca->id = a->asset_id();
    ca->name = a->name() ? a->name()->str() : "";
    ca->path = path;
    ca->character = import_character(path);
    const int B = a->bone_count();
    if (!a->order() || !a->parents() || int(a->order()->size()) != B || int(a->parents()->size()) != B || B < 1 ||
        B > MAX_BONES || (a->corrections() && a->corrections()->size() != size_t(B) * 12))
        throw Error("server sent an inconsistent skin for " + ca->name);
    ProgressiveSkin& s = ca->skin;
    s.order.assign(a->order()->begin(), a->order()->end());
    s.parents.assign(a->parents()->begin(), a->parents()->end());
    if (s.parents[0] != -1) throw Error("bad progressive parents for " + ca->name);
    for (int b = 1; b < B; ++b)
        if (s.parents[b] < 0 || s.parents[b] >= b) throw Error("bad progressive parents for " + ca->name);
    s.corrections.assign(B, Mat34::identity());
    if (a->corrections())
        for (int b = 0; b < B; ++b)
            for (int i = 0; i < 12; ++i) s.corrections[b].m[i] = a->corrections()->Get(size_t(b) * 12 + i);
    if (a->error())
        for (size_t k = 0; k < a->error()->size(); ++k) {
            LodError e;
            e.bones = int(k) + 1;
            e.rms = a->error()->Get(k)->rms();
            e.max = a->error()->Get(k)->max();
            s.error.push_back(e);
        }
    remap_skin_vertices(*ca);
    s.diagonal = a->diagonal();
    ca->diagonal = rest_diagonal(ca->character);
    if (!(ca->diagonal > 0)) ca->diagonal = a->diagonal() > 0 ? a->diagonal() : 1.0;
    if (const std::string why = read_asset_format(*a, ca->format); !why.empty())
        throw Error("server sent " + why + " for " + ca->name);
    return ca;
}

}  // namespace progskin::net
