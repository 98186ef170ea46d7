// self_contained.cpp — see self_contained.h.
#include "self_contained.h"

#include <tiny_gltf.h>

#include <cctype>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "errors.h"

namespace progskin {

namespace fs = std::filesystem;

namespace {

uint32_t read_u32le(const uint8_t* p) {
    return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}
void put_u32le(std::vector<uint8_t>& out, uint32_t v) {
    for (int i = 0; i < 4; ++i) out.push_back(uint8_t(v >> (8 * i)));
}

std::vector<uint8_t> read_whole(const fs::path& p, const std::string& what) {
    std::ifstream f(p, std::ios::binary);
    if (!f) throw Error(what + ": cannot open " + p.string());
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// "%20" and the like decoded; false on a malformed escape or a decoded NUL.
bool percent_decode(const std::string& in, std::string& out) {
    out.clear();
    for (size_t i = 0; i < in.size(); ++i) {
        if (in[i] != '%') {
            out += in[i];
            continue;
        }
        if (i + 2 >= in.size() || !std::isxdigit(static_cast<unsigned char>(in[i + 1])) ||
            !std::isxdigit(static_cast<unsigned char>(in[i + 2])))
            return false;
        const char c = char(std::stoi(in.substr(i + 1, 2), nullptr, 16));
        if (c == 0) return false;
        out += c;
        i += 2;
    }
    return true;
}

// A parsed glTF or GLB: its JSON and, for a GLB, its binary chunk.
struct Parsed {
    nlohmann::json json;
    std::vector<uint8_t> bin;
    bool glb = false, has_bin = false;
};

// False when the bytes are not a glTF JSON object or a GLB (the importer reports those).
bool parse_gltf(const std::vector<uint8_t>& bytes, Parsed& p) {
    std::string_view text(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    if (bytes.size() >= 4 && std::memcmp(bytes.data(), "glTF", 4) == 0) {
        if (bytes.size() < 20) return false;
        const uint32_t json_len = read_u32le(bytes.data() + 12);
        if (uint64_t(json_len) + 20 > bytes.size()) return false;
        text = text.substr(20, json_len);
        p.glb = true;
        const size_t bin_at = 20 + size_t(json_len);
        if (bin_at + 8 <= bytes.size() && read_u32le(bytes.data() + bin_at + 4) == 0x004E4942u) {
            const uint32_t bin_len = read_u32le(bytes.data() + bin_at);
            if (bin_at + 8 + uint64_t(bin_len) > bytes.size()) return false;
            p.bin.assign(bytes.begin() + std::ptrdiff_t(bin_at + 8), bytes.begin() + std::ptrdiff_t(bin_at + 8 + bin_len));
            p.has_bin = true;
        }
    }
    p.json = nlohmann::json::parse(text, nullptr, false);
    return !p.json.is_discarded() && p.json.is_object();
}

bool is_external(const nlohmann::json& e) {
    return e.is_object() && e.contains("uri") && e["uri"].is_string() && e["uri"].get<std::string>().rfind("data:", 0) != 0;
}

// The image's MIME type: from the file's extension, else from its first bytes ("" when unknown).
std::string image_mime(const fs::path& p, const std::vector<uint8_t>& d) {
    std::string ext = p.extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (ext == ".png") return "image/png";
    if (ext == ".jpg" || ext == ".jpeg") return "image/jpeg";
    if (ext == ".webp") return "image/webp";
    if (ext == ".ktx2") return "image/ktx2";
    if (d.size() >= 8 && std::memcmp(d.data(), "\x89PNG", 4) == 0) return "image/png";
    if (d.size() >= 3 && d[0] == 0xFF && d[1] == 0xD8 && d[2] == 0xFF) return "image/jpeg";
    if (d.size() >= 12 && std::memcmp(d.data(), "RIFF", 4) == 0 && std::memcmp(d.data() + 8, "WEBP", 4) == 0)
        return "image/webp";
    return {};
}

// Appends `data` to `bin` at a 16-byte boundary; returns its offset.
size_t append_aligned(std::vector<uint8_t>& bin, const uint8_t* data, size_t n) {
    while (bin.size() % 16) bin.push_back(0);
    const size_t at = bin.size();
    bin.insert(bin.end(), data, data + n);
    return at;
}

std::vector<uint8_t> write_glb(const nlohmann::json& j, std::vector<uint8_t> bin) {
    std::string text = j.dump();
    while (text.size() % 4) text.push_back(' ');
    while (bin.size() % 4) bin.push_back(0);
    const uint64_t total = 12 + 8 + uint64_t(text.size()) + (bin.empty() ? 0 : 8 + uint64_t(bin.size()));
    if (total > kMaxSelfContainedBytes)
        throw Error("the self-contained GLB would be " + std::to_string(total) + " bytes, over the limit of " +
                    std::to_string(kMaxSelfContainedBytes));
    std::vector<uint8_t> out;
    out.reserve(size_t(total));
    put_u32le(out, 0x46546C67u);  // "glTF"
    put_u32le(out, 2);
    put_u32le(out, uint32_t(total));
    put_u32le(out, uint32_t(text.size()));
    put_u32le(out, 0x4E4F534Au);  // "JSON"
    out.insert(out.end(), text.begin(), text.end());
    if (!bin.empty()) {
        put_u32le(out, uint32_t(bin.size()));
        put_u32le(out, 0x004E4942u);  // "BIN\0"
        out.insert(out.end(), bin.begin(), bin.end());
    }
    return out;
}

}  // namespace

ExternalFile resolve_external_uri(const std::string& gltf_path, const std::string& kind, size_t index,
                                  const std::string& uri) {
    auto refuse = [&](const std::string& why) -> Error {
        return Error(gltf_path + ": " + kind + "[" + std::to_string(index) + "] uri \"" + uri.substr(0, 120) + "\": " + why);
    };
    if (uri.empty()) throw refuse("empty");
    if (uri.find(':') != std::string::npos)
        throw refuse("not a file beside the glTF (a URL, a drive or a scheme); only relative file names are embedded");
    std::string name;
    if (!percent_decode(uri, name)) throw refuse("malformed percent escape");
    if (name.find('\\') != std::string::npos) throw refuse("backslash in a file name (use '/')");
    if (name[0] == '/') throw refuse("absolute path; only files inside the glTF's folder are embedded");
    for (const auto& part : fs::path(name))
        if (part == "..") throw refuse("\"..\" leads outside the glTF's folder");
    std::error_code ec;
    const fs::path dir = fs::weakly_canonical(fs::absolute(fs::path(gltf_path)).parent_path(), ec);
    const fs::path wanted = dir / name;
    if (!fs::exists(wanted, ec)) throw refuse("missing: no such file " + wanted.string());
    const fs::path real = fs::canonical(wanted, ec);
    if (ec || !fs::is_regular_file(real, ec)) throw refuse("not a regular file: " + wanted.string());
    const std::string d = dir.string() + "/";
    if (real.string().compare(0, d.size(), d) != 0) throw refuse("resolves outside the glTF's folder, to " + real.string());
    const uint64_t size = fs::file_size(real, ec);
    if (ec) throw refuse("cannot read its size: " + ec.message());
    if (size > kMaxEmbeddedFileBytes)
        throw refuse(std::to_string(size) + " bytes, over the limit of " + std::to_string(kMaxEmbeddedFileBytes));
    return {kind, index, uri, real, size};
}

nlohmann::json read_gltf_json(const std::string& path) {
    Parsed p;
    if (!parse_gltf(read_whole(path, path), p)) return nlohmann::json(nlohmann::json::value_t::discarded);
    return p.json;
}

std::vector<ExternalFile> external_files(const std::string& path) {
    Parsed p;
    if (!parse_gltf(read_whole(path, path), p)) return {};
    std::vector<ExternalFile> out;
    uint64_t total = 0;
    for (const char* kind : {"buffers", "images"}) {
        const auto it = p.json.find(kind);
        if (it == p.json.end() || !it->is_array()) continue;
        for (size_t i = 0; i < it->size(); ++i) {
            if (!is_external((*it)[i])) continue;
            out.push_back(resolve_external_uri(path, kind, i, (*it)[i]["uri"].get<std::string>()));
            total += out.back().size;
            if (total > kMaxSelfContainedBytes)
                throw Error(path + ": its external files add up to more than " + std::to_string(kMaxSelfContainedBytes) +
                            " bytes (the largest asset a client accepts)");
        }
    }
    return out;
}

std::vector<uint8_t> self_contained_glb(const std::string& path) {
    std::vector<uint8_t> bytes = read_whole(path, path);
    const std::vector<ExternalFile> files = external_files(path);
    if (files.empty()) return bytes;
    Parsed p;
    parse_gltf(bytes, p);
    nlohmann::json& j = p.json;
    nlohmann::json& buffers = j["buffers"];
    if (!buffers.is_array()) buffers = nlohmann::json::array();
    // The new buffer list: 0 = the binary chunk (a GLB's own, or new), then
    // every data: buffer; external buffers are appended to the chunk.
    std::vector<uint8_t> bin = p.has_bin ? std::move(p.bin) : std::vector<uint8_t>();
    const bool glb_bin = p.glb && p.has_bin && !buffers.empty() && buffers[0].is_object() && !buffers[0].contains("uri");
    std::vector<int> new_index(buffers.size(), -1);
    std::vector<size_t> base(buffers.size(), 0);
    nlohmann::json kept = nlohmann::json::array();
    kept.push_back(nlohmann::json::object());
    for (size_t i = 0; i < buffers.size(); ++i) {
        if (i == 0 && glb_bin) {
            new_index[0] = 0;
            continue;
        }
        if (!is_external(buffers[i])) {
            new_index[i] = int(kept.size());
            kept.push_back(buffers[i]);
        }
    }
    for (const ExternalFile& f : files) {
        if (f.kind != "buffers") continue;
        const std::vector<uint8_t> data = read_whole(f.path, path);
        const nlohmann::json& b = buffers[f.index];
        const uint64_t length = b.contains("byteLength") && b["byteLength"].is_number_unsigned()
                                    ? b["byteLength"].get<uint64_t>()
                                    : uint64_t(data.size());
        if (length > data.size())
            throw Error(path + ": buffers[" + std::to_string(f.index) + "] uri \"" + f.uri + "\": the file has " +
                        std::to_string(data.size()) + " bytes, the buffer's byteLength says " + std::to_string(length));
        new_index[f.index] = 0;
        base[f.index] = append_aligned(bin, data.data(), size_t(length));
    }
    if (j.contains("bufferViews") && j["bufferViews"].is_array())
        for (auto& v : j["bufferViews"]) {
            if (!v.is_object() || !v.contains("buffer") || !v["buffer"].is_number_unsigned()) continue;
            const size_t b = v["buffer"].get<size_t>();
            if (b >= new_index.size() || new_index[b] < 0) continue;  // the importer reports a bad index
            v["buffer"] = new_index[b];
            if (base[b]) v["byteOffset"] = (v.contains("byteOffset") && v["byteOffset"].is_number_unsigned()
                                                ? v["byteOffset"].get<uint64_t>()
                                                : 0) + base[b];
        }
    for (const ExternalFile& f : files) {
        if (f.kind != "images") continue;
        const std::vector<uint8_t> data = read_whole(f.path, path);
        nlohmann::json& img = j["images"][f.index];
        const size_t at = append_aligned(bin, data.data(), data.size());
        if (!j.contains("bufferViews") || !j["bufferViews"].is_array()) j["bufferViews"] = nlohmann::json::array();
        j["bufferViews"].push_back({{"buffer", 0}, {"byteOffset", at}, {"byteLength", data.size()}});
        img.erase("uri");
        img["bufferView"] = j["bufferViews"].size() - 1;
        if (!img.contains("mimeType")) {
            const std::string mime = image_mime(f.path, data);
            if (mime.empty())
                throw Error(path + ": images[" + std::to_string(f.index) + "] uri \"" + f.uri +
                            "\": unknown image type (not PNG, JPEG, WebP or KTX2) and no mimeType");
            img["mimeType"] = mime;
        }
    }
    while (bin.size() % 4) bin.push_back(0);
    kept[0]["byteLength"] = bin.size();
    if (bin.empty()) kept.erase(kept.begin());  // nothing in the chunk (cannot happen with an external file)
    j["buffers"] = kept;
    try {
        return write_glb(j, std::move(bin));
    } catch (const Error& e) {
        throw Error(path + ": " + e.what());
    }
}

size_t embed_external_images(tinygltf::Model& m, const std::string& source_path) {
    if (m.buffers.empty()) m.buffers.emplace_back();
    size_t n = 0;
    for (size_t i = 0; i < m.images.size(); ++i) {
        tinygltf::Image& img = m.images[i];
        if (img.uri.empty() || img.uri.rfind("data:", 0) == 0) continue;
        const ExternalFile f = resolve_external_uri(source_path, "images", i, img.uri);
        const std::vector<uint8_t> data = read_whole(f.path, source_path);
        auto& buf = m.buffers[0].data;
        const size_t at = append_aligned(buf, data.data(), data.size());
        while (buf.size() % 4) buf.push_back(0);
        tinygltf::BufferView bv;
        bv.buffer = 0;
        bv.byteOffset = at;
        bv.byteLength = data.size();
        m.bufferViews.push_back(bv);
        if (img.mimeType.empty()) img.mimeType = image_mime(f.path, data);
        if (img.mimeType.empty())
            throw Error(source_path + ": images[" + std::to_string(i) + "] uri \"" + img.uri +
                        "\": unknown image type (not PNG, JPEG, WebP or KTX2) and no mimeType");
        img.bufferView = int(m.bufferViews.size() - 1);
        img.uri.clear();
        ++n;
    }
    return n;
}

}  // namespace progskin
