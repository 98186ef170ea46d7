// world_message.cpp — see world_message.h.
#include "world_message.h"

#include <cstring>

namespace progskin::net {

namespace {

template <class T>
void put(std::vector<uint8_t>& out, T v) {
    uint8_t b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));  // little-endian hosts (x86-64, arm64): the wire order
    out.insert(out.end(), b, b + sizeof(T));
}

// A bounded reader: every take checks the bytes left.
struct Reader {
    std::span<const uint8_t> in;
    size_t at = 0;
    bool ok = true;
    template <class T>
    T get() {
        T v{};
        if (!ok || in.size() - at < sizeof(T)) {
            ok = false;
            return v;
        }
        std::memcpy(&v, in.data() + at, sizeof(T));
        at += sizeof(T);
        return v;
    }
    std::span<const uint8_t> take(size_t n) {
        if (!ok || in.size() - at < n) {
            ok = false;
            return {};
        }
        auto s = in.subspan(at, n);
        at += n;
        return s;
    }
};

constexpr uint8_t kMagic[4] = {'P', 'S', 'K', 'W'};
constexpr uint8_t kVersion = 3;  // 2: world_id; 3: parent-relative records

// One character after the header; "" or what is wrong.
std::string read_character(Reader& r, const ServerAssets& assets, WorldCharacter& c) {
    c.id = r.get<uint16_t>();
    c.world_id = r.get<uint64_t>();
    c.asset = r.get<uint16_t>();
    c.epoch = r.get<uint8_t>();
    const uint8_t flags = r.get<uint8_t>();
    if (flags > 1) return "character flags " + std::to_string(flags);
    c.published = flags == 1;
    c.sample = r.get<uint8_t>();
    const int bones = r.get<uint8_t>();
    const size_t record_bytes = r.get<uint16_t>();
    if (!r.ok) return "truncated character";
    if (c.world_id == 0) return "character without a world id";
    if (c.asset >= assets.size()) return "asset " + std::to_string(c.asset) + " not in the catalogue";
    const ServerAsset& a = *assets[c.asset];
    if (bones != a.bone_count())
        return "character " + std::to_string(c.id) + ": " + std::to_string(bones) + " bones, the asset has " +
               std::to_string(a.bone_count());
    if (record_bytes > (size_t(bones) * size_t(kMaxRecordBits) + 7) / 8)
        return "character " + std::to_string(c.id) + ": " + std::to_string(record_bytes) + " bytes of records for " +
               std::to_string(bones) + " bones";
    const auto root = r.take(ROOT_BYTES);
    if (r.ok) std::memcpy(c.root.data(), root.data(), ROOT_BYTES);
    c.records = r.take(record_bytes);
    c.ints.resize(size_t(bones));
    if (r.ok && !read_pose_records(c.records, a.relative.scaled, {}, c.ints))
        return "character " + std::to_string(c.id) + ": records out of bounds or not " + std::to_string(bones) + " records";
    c.record_bits = c.records.size() * 8;
    const size_t morphs = r.get<uint8_t>();
    const size_t expect = std::min<size_t>(a.character.morphs.size(), MAX_MORPHS);
    if (r.ok && morphs != 0 && morphs != expect) return "character " + std::to_string(c.id) + ": " + std::to_string(morphs) + " morph weights";
    c.morphs.resize(morphs);
    for (auto& w : c.morphs) w = r.get<int16_t>();
    const size_t clips = r.get<uint8_t>();
    if (clips > MAX_INSTANCE_CLIPS) return "more than " + std::to_string(MAX_INSTANCE_CLIPS) + " clips";
    c.clips.resize(clips);
    for (auto& k : c.clips) {
        k = r.get<int32_t>();
        if (r.ok && (k < 0 || size_t(k) >= a.character.clips.size())) return "clip " + std::to_string(k) + " not in the asset";
    }
    c.publisher_start_us = r.get<uint64_t>();
    for (double& v : c.walk_center) v = r.get<double>();
    c.walk_radius = r.get<double>();
    c.walk_speed = r.get<double>();
    if (!r.ok) return "truncated character";
    return {};
}

}  // namespace

bool world_character(const EncodedFrame& frame, int i, const RootPose& placed, WorldCharacter& c) {
    const EncodedInstance& e = frame.instances[size_t(i)];
    c.id = uint16_t(i);
    c.asset = uint16_t(e.asset);
    c.epoch = e.epoch;
    c.sample = e.sample;
    if (e.flags & CHUNK_ROOT) c.root = e.root;
    else if (!encode_root(placed, c.root.data())) return false;
    c.record_bits = frame.record_bits(i, 0, e.bone_count);
    c.records = {frame.relative(i), (c.record_bits + 7) / 8};
    c.morphs.clear();
    bool weights = e.morph_count > 0;
    for (int32_t w : frame.morphs(i)) weights = weights && w != kNoWeight;
    if (weights)
        for (int32_t w : frame.morphs(i)) c.morphs.push_back(int16_t(w));
    return true;
}

uint64_t catalogue_hash(const ServerAssets& assets) {
    uint64_t h = 1469598103934665603ull;  // FNV-1a over the ids' bytes
    for (const auto& a : assets)
        for (int i = 0; i < 8; ++i) h = (h ^ ((a->id >> (8 * i)) & 0xff)) * 1099511628211ull;
    return h;
}

void write_world_message(const WorldHeader& h, std::span<const WorldCharacter> chars, const ServerAssets& assets,
                         std::vector<uint8_t>& out) {
    out.clear();
    out.insert(out.end(), kMagic, kMagic + 4);
    put<uint8_t>(out, kVersion);
    put<uint8_t>(out, 0);
    put<uint16_t>(out, h.node);
    put<uint64_t>(out, h.catalogue);
    put<uint32_t>(out, h.tick);
    put<uint16_t>(out, uint16_t(chars.size()));
    for (const WorldCharacter& c : chars) {
        const ServerAsset& a = *assets[c.asset];
        put<uint16_t>(out, c.id);
        put<uint64_t>(out, c.world_id);
        put<uint16_t>(out, c.asset);
        put<uint8_t>(out, c.epoch);
        put<uint8_t>(out, c.published ? 1 : 0);
        put<uint8_t>(out, c.sample);
        const size_t n = std::min((c.record_bits + 7) / 8, c.records.size());
        put<uint8_t>(out, uint8_t(a.bone_count()));
        put<uint16_t>(out, uint16_t(n));
        out.insert(out.end(), c.root.begin(), c.root.end());
        out.insert(out.end(), c.records.begin(), c.records.begin() + long(n));
        if (n > 0 && c.record_bits % 8 != 0 && n * 8 > c.record_bits)  // zero bits past the last record
            out.back() &= uint8_t((1u << (c.record_bits % 8)) - 1);
        put<uint8_t>(out, uint8_t(c.morphs.size()));
        for (int16_t w : c.morphs) put<int16_t>(out, w);
        put<uint8_t>(out, uint8_t(c.clips.size()));
        for (int k : c.clips) put<int32_t>(out, k);
        put<uint64_t>(out, c.publisher_start_us);
        for (double v : c.walk_center) put<double>(out, v);
        put<double>(out, c.walk_radius);
        put<double>(out, c.walk_speed);
    }
}

std::string read_world_message(std::span<const uint8_t> bytes, const ServerAssets& assets, WorldHeader& h,
                               std::vector<WorldCharacter>& chars) {
    return read_world_message(bytes, assets, catalogue_hash(assets), h, chars);
}

std::string read_world_message(std::span<const uint8_t> bytes, const ServerAssets& assets, uint64_t catalogue,
                               WorldHeader& h, std::vector<WorldCharacter>& chars) {
    chars.clear();
    if (bytes.size() > kWorldMaxMessage) return "message of " + std::to_string(bytes.size()) + " bytes";
    Reader r{bytes};
    const auto magic = r.take(4);
    if (!r.ok || std::memcmp(magic.data(), kMagic, 4) != 0) return "not a world message";
    const uint8_t version = r.get<uint8_t>();
    r.get<uint8_t>();
    if (version != kVersion) return "world message version " + std::to_string(version);
    h.node = r.get<uint16_t>();
    h.catalogue = r.get<uint64_t>();
    h.tick = r.get<uint32_t>();
    const size_t n = r.get<uint16_t>();
    if (!r.ok) return "truncated header";
    if (n > kWorldMaxCharacters) return std::to_string(n) + " characters";
    if (h.catalogue != catalogue) return "another catalogue";
    chars.resize(n);
    for (WorldCharacter& c : chars)
        if (std::string why = read_character(r, assets, c); !why.empty()) return why;
    if (r.at != bytes.size()) return std::to_string(bytes.size() - r.at) + " bytes after the last character";
    return {};
}

}  // namespace progskin::net
