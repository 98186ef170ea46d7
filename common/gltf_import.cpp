// gltf_import.cpp — glTF 2.0 to Characters (see gltf_import.h for the contract).
//
// tinygltf parses the JSON and loads the buffers; everything else (accessor
// decoding, validation, grouping skins into skeletons, merging primitives) is
// done here so that every defect gets a message naming the file and the item.
#include "gltf_import.h"

#include "gltf_accessor.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <sstream>

#ifndef GLM_ENABLE_EXPERIMENTAL
#define GLM_ENABLE_EXPERIMENTAL  // glm/gtx/matrix_decompose.hpp
#endif
#include <glm/gtc/matrix_inverse.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtx/matrix_decompose.hpp>

#include "errors.h"

namespace progskin {
namespace {

// ---------------------------------------------------------------------------
// File loading

// Everything the import steps share: the parsed model and the file name for messages.
struct Ctx {
    const tinygltf::Model& model;
    std::string path;

    [[noreturn]] void fail(const std::string& what) const { throw Error(path + ": " + what); }
};

// Whole file as bytes; throws when it cannot be read.
std::vector<unsigned char> read_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(path + ": cannot open file");
    std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw Error(path + ": read error");
    return bytes;
}

// Directory part of a path ("" for a bare file name), for external buffer URIs.
std::string directory_of(const std::string& path) {
    const size_t slash = path.find_last_of("/\\");
    return slash == std::string::npos ? std::string() : path.substr(0, slash);
}

// Image callback that accepts every image without decoding it (we never need pixels).
bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int,
                void*) {
    return true;
}

// Little-endian u32 at p (GLB header fields).
uint32_t read_u32le(const unsigned char* p) {
    return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

// Strips trailing newlines and joins tinygltf's multi-line messages with "; ".
std::string tidy_message(std::string s) {
    for (char& ch : s)
        if (ch == '\n' || ch == '\r') ch = ';';
    while (!s.empty() && (s.back() == ';' || s.back() == ' ')) s.pop_back();
    std::string out;
    for (size_t i = 0; i < s.size(); ++i) {
        out += s[i];
        if (s[i] == ';' && i + 1 < s.size() && s[i + 1] != ' ') out += ' ';
    }
    return out;
}

// Parses a .glb or .gltf (detected from the content, not the extension) into `model`.
void load_model(const std::string& path, tinygltf::Model& model) {
    const std::vector<unsigned char> bytes = read_file(path);
    if (bytes.size() > std::numeric_limits<unsigned int>::max()) throw Error(path + ": file too large (over 4 GiB)");
    tinygltf::TinyGLTF loader;
    loader.SetImageLoader(&skip_image, nullptr);
    std::string err, warn;
    bool ok = false;
    if (bytes.size() >= 4 && std::memcmp(bytes.data(), "glTF", 4) == 0) {
        if (bytes.size() < 20)
            throw Error(path + ": truncated GLB (" + std::to_string(bytes.size()) + " bytes, header needs 20)");
        const uint32_t version = read_u32le(bytes.data() + 4);
        const uint32_t length = read_u32le(bytes.data() + 8);
        const uint32_t json_length = read_u32le(bytes.data() + 12);
        if (version != 2) throw Error(path + ": GLB container version " + std::to_string(version) + ", only 2 is supported");
        if (length > bytes.size())
            throw Error(path + ": truncated GLB (header says " + std::to_string(length) + " bytes, file has " +
                        std::to_string(bytes.size()) + ")");
        if (uint64_t(json_length) + 20 > length) throw Error(path + ": truncated GLB (JSON chunk runs past the end of the file)");
        ok = loader.LoadBinaryFromMemory(&model, &err, &warn, bytes.data(), static_cast<unsigned int>(bytes.size()),
                                         directory_of(path));
    } else {
        size_t i = 0;
        if (bytes.size() >= 3 && bytes[0] == 0xEF && bytes[1] == 0xBB && bytes[2] == 0xBF) i = 3;  // UTF-8 BOM
        while (i < bytes.size() && std::isspace(bytes[i])) ++i;
        if (i == bytes.size() || bytes[i] != '{')
            throw Error(path + ": not a glTF file (neither a GLB container nor a JSON object)");
        ok = loader.LoadASCIIFromString(&model, &err, &warn, reinterpret_cast<const char*>(bytes.data()),
                                        static_cast<unsigned int>(bytes.size()), directory_of(path));
    }
    if (!ok) {
        std::string msg = tidy_message(err.empty() ? warn : err);
        if (msg.empty()) msg = "tinygltf could not load it";
        // With images skipped, the only external files tinygltf must find are buffers.
        if (msg.find("File not found") != std::string::npos || msg.find("File read error") != std::string::npos ||
            msg.find("File is empty") != std::string::npos)
            throw Error(path + ": missing buffer (" + msg + ")");
        throw Error(path + ": invalid glTF: " + msg);
    }
    if (model.asset.version.empty() || model.asset.version[0] != '2')
        throw Error(path + ": not a glTF 2.0 file (asset.version \"" + model.asset.version + "\")");
    for (const std::string& ext : model.extensionsRequired)
        if (ext == "KHR_draco_mesh_compression" || ext == "EXT_meshopt_compression" ||
            ext == "KHR_meshopt_compression")
            throw Error(path + ": required extension " + ext + " is not supported (decompress the file first)");
}

// ---------------------------------------------------------------------------
// Accessors

// One decoded accessor: count elements of `components` doubles each.
struct AccessorData {
    size_t count = 0;
    int components = 0;
    std::vector<double> values;  // count * components, column-major for matrices
    double at(size_t i, int c) const { return values[i * size_t(components) + size_t(c)]; }
};

// Components per element of an accessor type (0 for unknown types).
int component_count(int type) {
    switch (type) {
        case TINYGLTF_TYPE_SCALAR: return 1;
        case TINYGLTF_TYPE_VEC2: return 2;
        case TINYGLTF_TYPE_VEC3: return 3;
        case TINYGLTF_TYPE_VEC4: return 4;
        case TINYGLTF_TYPE_MAT2: return 4;
        case TINYGLTF_TYPE_MAT3: return 9;
        case TINYGLTF_TYPE_MAT4: return 16;
        default: return 0;
    }
}

// glTF spelling of an accessor type, for messages.
const char* type_name(int type) {
    switch (type) {
        case TINYGLTF_TYPE_SCALAR: return "SCALAR";
        case TINYGLTF_TYPE_VEC2: return "VEC2";
        case TINYGLTF_TYPE_VEC3: return "VEC3";
        case TINYGLTF_TYPE_VEC4: return "VEC4";
        case TINYGLTF_TYPE_MAT2: return "MAT2";
        case TINYGLTF_TYPE_MAT3: return "MAT3";
        case TINYGLTF_TYPE_MAT4: return "MAT4";
        default: return "unknown type";
    }
}

// Byte size of one component, 0 for types the glTF spec does not allow in accessors.
size_t component_size(int component_type) {
    switch (component_type) {
        case TINYGLTF_COMPONENT_TYPE_BYTE:
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return 1;
        case TINYGLTF_COMPONENT_TYPE_SHORT:
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return 2;
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
        case TINYGLTF_COMPONENT_TYPE_FLOAT: return 4;
        default: return 0;
    }
}

// Byte layout of one element: matrix columns start on 4-byte boundaries (spec 3.6.2.4).
struct ElementLayout {
    int columns = 1;          // 1 for scalars and vectors
    int rows = 1;             // components per column
    size_t column_stride = 0; // bytes between columns
    size_t size = 0;          // bytes of one tightly packed element
};

// Layout of one element of `type` with components of `csize` bytes.
ElementLayout element_layout(int type, size_t csize) {
    ElementLayout l;
    const int n = component_count(type);
    if (type == TINYGLTF_TYPE_MAT2 || type == TINYGLTF_TYPE_MAT3 || type == TINYGLTF_TYPE_MAT4) {
        l.columns = l.rows = (type == TINYGLTF_TYPE_MAT2 ? 2 : type == TINYGLTF_TYPE_MAT3 ? 3 : 4);
        l.column_stride = (size_t(l.rows) * csize + 3) & ~size_t(3);
        l.size = l.column_stride * size_t(l.columns);
    } else {
        l.rows = n;
        l.column_stride = size_t(n) * csize;
        l.size = l.column_stride;
    }
    return l;
}

// One component at p decoded to double; normalized integers map to [0,1] / [-1,1] per spec.
double decode_component(const unsigned char* p, int component_type, bool normalized) {
    switch (component_type) {
        case TINYGLTF_COMPONENT_TYPE_BYTE: {
            int8_t v;
            std::memcpy(&v, p, 1);
            return normalized ? std::max(double(v) / 127.0, -1.0) : double(v);
        }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return normalized ? double(p[0]) / 255.0 : double(p[0]);
        case TINYGLTF_COMPONENT_TYPE_SHORT: {
            int16_t v;
            std::memcpy(&v, p, 2);
            return normalized ? std::max(double(v) / 32767.0, -1.0) : double(v);
        }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
            uint16_t v;
            std::memcpy(&v, p, 2);
            return normalized ? double(v) / 65535.0 : double(v);
        }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
            uint32_t v;
            std::memcpy(&v, p, 4);
            return double(v);
        }
        default: {
            float v;
            std::memcpy(&v, p, 4);
            return double(v);
        }
    }
}

// Bytes [offset, offset+length) of buffer view `view_index`, bounds-checked against its buffer.
const unsigned char* view_bytes(const Ctx& ctx, int view_index, size_t& length, const std::string& who) {
    const auto& m = ctx.model;
    if (view_index < 0 || size_t(view_index) >= m.bufferViews.size())
        ctx.fail(who + " refers to buffer view " + std::to_string(view_index) + ", which does not exist");
    const tinygltf::BufferView& view = m.bufferViews[size_t(view_index)];
    if (view.buffer < 0 || size_t(view.buffer) >= m.buffers.size())
        ctx.fail("buffer view " + std::to_string(view_index) + " refers to buffer " + std::to_string(view.buffer) +
                 ", which does not exist");
    const size_t buffer_size = m.buffers[size_t(view.buffer)].data.size();
    if (view.byteOffset > buffer_size || view.byteLength > buffer_size - view.byteOffset)
        ctx.fail("buffer view " + std::to_string(view_index) + " out of range of buffer " + std::to_string(view.buffer) +
                 " (bytes " + std::to_string(view.byteOffset) + ".." + std::to_string(view.byteOffset + view.byteLength) +
                 " of " + std::to_string(buffer_size) + ")");
    length = view.byteLength;
    return m.buffers[size_t(view.buffer)].data.data() + view.byteOffset;
}

// Decodes `count` elements of `layout` from `base` with `stride` bytes between elements.
void decode_elements(const unsigned char* base, size_t count, size_t stride, const ElementLayout& layout,
                     int component_type, bool normalized, double* out) {
    const size_t csize = component_size(component_type);
    for (size_t i = 0; i < count; ++i) {
        const unsigned char* e = base + i * stride;
        for (int c = 0; c < layout.columns; ++c)
            for (int r = 0; r < layout.rows; ++r)
                *out++ = decode_component(e + size_t(c) * layout.column_stride + size_t(r) * csize, component_type,
                                          normalized);
    }
}

// Applies accessor.sparse (indices + replacement values) to the decoded data.
void apply_sparse(const Ctx& ctx, int index, const tinygltf::Accessor& acc, const ElementLayout& layout,
                  AccessorData& data) {
    const std::string who = "accessor " + std::to_string(index);
    const int n = acc.sparse.count;
    if (n < 0 || size_t(n) > acc.count)
        ctx.fail(who + ": sparse count " + std::to_string(n) + " exceeds the accessor count " + std::to_string(acc.count));
    if (n == 0) return;
    const int itype = acc.sparse.indices.componentType;
    if (itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
        itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
        ctx.fail(who + ": sparse indices must be unsigned byte, short or int (component type " + std::to_string(itype) + ")");
    if (acc.sparse.indices.byteOffset < 0 || acc.sparse.values.byteOffset < 0)
        ctx.fail(who + ": negative sparse byteOffset");

    size_t ilen = 0, vlen = 0;
    const unsigned char* ibytes = view_bytes(ctx, acc.sparse.indices.bufferView, ilen, who + " (sparse indices)");
    const unsigned char* vbytes = view_bytes(ctx, acc.sparse.values.bufferView, vlen, who + " (sparse values)");
    const size_t isize = component_size(itype);
    const size_t ioff = size_t(acc.sparse.indices.byteOffset), voff = size_t(acc.sparse.values.byteOffset);
    if (ioff > ilen || size_t(n) * isize > ilen - ioff)
        ctx.fail(who + ": sparse indices out of range of buffer view " + std::to_string(acc.sparse.indices.bufferView));
    if (voff > vlen || size_t(n) * layout.size > vlen - voff)
        ctx.fail(who + ": sparse values out of range of buffer view " + std::to_string(acc.sparse.values.bufferView));

    std::vector<double> values(size_t(n) * size_t(data.components));
    decode_elements(vbytes + voff, size_t(n), layout.size, layout, acc.componentType, acc.normalized, values.data());
    double previous = -1.0;
    for (int k = 0; k < n; ++k) {
        const double target = decode_component(ibytes + ioff + size_t(k) * isize, itype, false);
        if (target >= double(acc.count))
            ctx.fail(who + ": sparse index " + std::to_string(size_t(target)) + " out of range (count " +
                     std::to_string(acc.count) + ")");
        if (target <= previous) ctx.fail(who + ": sparse indices are not strictly increasing");
        previous = target;
        std::copy_n(values.begin() + std::ptrdiff_t(k) * data.components, data.components,
                    data.values.begin() + std::ptrdiff_t(target) * data.components);
    }
}

// Decodes accessor `index` (any allowed component type, strides, sparse) to doubles, bounds-checked.
AccessorData read_accessor(const Ctx& ctx, int index, const std::string& what) {
    const auto& m = ctx.model;
    if (index < 0 || size_t(index) >= m.accessors.size())
        ctx.fail(what + " refers to accessor " + std::to_string(index) + ", which does not exist");
    const tinygltf::Accessor& acc = m.accessors[size_t(index)];
    const std::string who = "accessor " + std::to_string(index);
    const size_t csize = component_size(acc.componentType);
    if (csize == 0)
        ctx.fail(who + " (" + what + "): component type " + std::to_string(acc.componentType) +
                 " is not allowed in glTF 2.0 accessors");
    if (acc.normalized && (acc.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT ||
                           acc.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT))
        ctx.fail(who + " (" + what + "): normalized is only allowed for 8- and 16-bit integers");
    AccessorData data;
    data.components = component_count(acc.type);
    if (data.components == 0) ctx.fail(who + " (" + what + "): unknown type");
    data.count = acc.count;
    const ElementLayout layout = element_layout(acc.type, csize);

    if (acc.bufferView >= 0) {
        size_t view_length = 0;
        const unsigned char* bytes = view_bytes(ctx, acc.bufferView, view_length, who);
        const size_t view_stride = m.bufferViews[size_t(acc.bufferView)].byteStride;
        const size_t stride = view_stride == 0 ? layout.size : view_stride;
        if (stride < layout.size)
            ctx.fail(who + ": byteStride " + std::to_string(stride) + " of buffer view " + std::to_string(acc.bufferView) +
                     " is smaller than the element size " + std::to_string(layout.size));
        if (acc.count > 0) {
            const bool fits = acc.byteOffset <= view_length &&
                              (acc.count - 1) <= (view_length - acc.byteOffset) / stride &&
                              (acc.count - 1) * stride + layout.size <= view_length - acc.byteOffset;
            if (!fits)
                ctx.fail(who + " out of range of buffer view " + std::to_string(acc.bufferView) + " (" +
                         std::to_string(acc.count) + " x " + std::to_string(layout.size) + " bytes, stride " +
                         std::to_string(stride) + ", offset " + std::to_string(acc.byteOffset) + ", view is " +
                         std::to_string(view_length) + " bytes)");
        }
        data.values.resize(acc.count * size_t(data.components));
        decode_elements(bytes + acc.byteOffset, acc.count, stride, layout, acc.componentType, acc.normalized,
                        data.values.data());
    } else {
        constexpr size_t kMaxZeroElements = size_t(1) << 26;  // refuse absurd counts without data
        if (acc.count > kMaxZeroElements)
            ctx.fail(who + ": count " + std::to_string(acc.count) + " without a buffer view is implausibly large");
        data.values.assign(acc.count * size_t(data.components), 0.0);
    }
    if (acc.sparse.isSparse) apply_sparse(ctx, index, acc, layout, data);
    return data;
}

// read_accessor plus a check of the element type; `types` lists the accepted ones.
AccessorData read_typed(const Ctx& ctx, int index, const std::string& what, std::initializer_list<int> types) {
    AccessorData d = read_accessor(ctx, index, what);
    const int type = ctx.model.accessors[size_t(index)].type;
    if (std::find(types.begin(), types.end(), type) == types.end()) {
        std::string expected;
        for (int t : types) expected += std::string(expected.empty() ? "" : " or ") + type_name(t);
        ctx.fail(what + ": accessor " + std::to_string(index) + " is " + type_name(type) + ", expected " + expected);
    }
    return d;
}

// Throws when any value of `d` is NaN or infinite.
void require_finite(const Ctx& ctx, const AccessorData& d, const std::string& what) {
    for (size_t i = 0; i < d.values.size(); ++i)
        if (!std::isfinite(d.values[i]))
            ctx.fail(what + " has a NaN or infinite value (element " + std::to_string(i / size_t(d.components)) + ")");
}

// ---------------------------------------------------------------------------
// Nodes

// Parent of every node (-1 for roots); throws on bad child indices, shared children and cycles.
std::vector<int> node_parents(const Ctx& ctx) {
    const auto& nodes = ctx.model.nodes;
    std::vector<int> parent(nodes.size(), -1);
    for (size_t n = 0; n < nodes.size(); ++n) {
        for (int child : nodes[n].children) {
            if (child < 0 || size_t(child) >= nodes.size())
                ctx.fail("node " + std::to_string(n) + " has child " + std::to_string(child) + ", which does not exist");
            if (size_t(child) == n) ctx.fail("cyclic node hierarchy: node " + std::to_string(n) + " is its own child");
            if (parent[size_t(child)] != -1)
                ctx.fail("cyclic node hierarchy or shared node: node " + std::to_string(child) +
                         " is a child of both node " + std::to_string(parent[size_t(child)]) + " and node " +
                         std::to_string(n));
            parent[size_t(child)] = int(n);
        }
    }
    // With one parent per node, a cycle is a parent chain that comes back to a node of the walk.
    std::vector<char> state(nodes.size(), 0);  // 0 unseen, 1 on the current walk, 2 reaches a root
    std::vector<size_t> walk;
    for (size_t n = 0; n < nodes.size(); ++n) {
        walk.clear();
        for (int p = int(n); p != -1 && state[size_t(p)] != 2; p = parent[size_t(p)]) {
            if (state[size_t(p)] == 1)
                ctx.fail("cyclic node hierarchy: node " + std::to_string(p) + " is its own ancestor");
            state[size_t(p)] = 1;
            walk.push_back(size_t(p));
        }
        for (size_t w : walk) state[w] = 2;
    }
    return parent;
}

// A node's rest transform, checked for NaN/Inf and with the rotation normalised.
Node convert_node(const Ctx& ctx, int index) {
    const tinygltf::Node& src = ctx.model.nodes[size_t(index)];
    const std::string who = "node " + std::to_string(index) + (src.name.empty() ? "" : " (\"" + src.name + "\")");
    auto check = [&](const std::vector<double>& v, size_t size, const char* field) {
        if (!v.empty() && v.size() != size)
            ctx.fail(who + ": " + field + " has " + std::to_string(v.size()) + " numbers, expected " + std::to_string(size));
        for (double x : v)
            if (!std::isfinite(x)) ctx.fail(who + ": " + field + " has a NaN or infinite value");
    };
    check(src.translation, 3, "translation");
    check(src.rotation, 4, "rotation");
    check(src.scale, 3, "scale");
    check(src.matrix, 16, "matrix");
    Node n;
    n.name = src.name;
    n.gltf_index = index;
    if (src.translation.size() == 3) n.translation = {src.translation[0], src.translation[1], src.translation[2]};
    if (src.scale.size() == 3) n.scale = {src.scale[0], src.scale[1], src.scale[2]};
    if (src.rotation.size() == 4) {
        glm::dquat q(src.rotation[3], src.rotation[0], src.rotation[1], src.rotation[2]);
        const double len = glm::length(q);
        if (!(len > 1e-12)) ctx.fail(who + ": rotation is a zero quaternion");
        n.rotation = q / len;
    }
    if (src.matrix.size() == 16) {
        n.has_matrix = true;
        for (int c = 0; c < 4; ++c)
            for (int r = 0; r < 4; ++r) n.matrix[c][r] = src.matrix[size_t(c * 4 + r)];
    }
    return n;
}

// Local rest matrix of a node: matrix, or T * R * S.
glm::dmat4 local_matrix(const Node& n) {
    if (n.has_matrix) return n.matrix;
    return glm::translate(glm::dmat4(1.0), n.translation) * glm::mat4_cast(n.rotation) *
           glm::scale(glm::dmat4(1.0), n.scale);
}

// Replaces an animated node's matrix by its TRS decomposition (glTF forbids matrix on animated nodes).
void decompose_matrix_node(const Ctx& ctx, Node& n, std::vector<std::string>& notes) {
    glm::dvec3 scale, translation, skew;
    glm::dvec4 perspective;
    glm::dquat rotation;
    if (!glm::decompose(n.matrix, scale, rotation, translation, skew, perspective))
        ctx.fail("node " + std::to_string(n.gltf_index) + " is animated but its matrix cannot be decomposed into TRS");
    const glm::dmat4 rebuilt = glm::translate(glm::dmat4(1.0), translation) * glm::mat4_cast(rotation) *
                               glm::scale(glm::dmat4(1.0), scale);
    double err = 0.0, mag = 1.0;
    for (int c = 0; c < 4; ++c)
        for (int r = 0; r < 4; ++r) {
            err = std::max(err, std::abs(rebuilt[c][r] - n.matrix[c][r]));
            mag = std::max(mag, std::abs(n.matrix[c][r]));
        }
    if (err > 1e-6 * mag)
        ctx.fail("node " + std::to_string(n.gltf_index) + " is animated but its matrix has shear (not a TRS)");
    n.translation = translation;
    n.rotation = glm::normalize(rotation);
    n.scale = scale;
    n.has_matrix = false;
    n.matrix = glm::dmat4(1.0);
    notes.push_back("node " + std::to_string(n.gltf_index) +
                    " is animated but had a matrix; decomposed into translation/rotation/scale");
}

// ---------------------------------------------------------------------------
// Skins and skeletons

struct SkinInfo {
    std::vector<int> joints;             // glTF node per skin joint
    std::vector<glm::dmat4> inverse_bind;
};

// Joints and inverse bind matrices of skin `s`, validated.
SkinInfo read_skin(const Ctx& ctx, int s) {
    const tinygltf::Skin& skin = ctx.model.skins[size_t(s)];
    const std::string who = "skin " + std::to_string(s);
    SkinInfo info;
    if (skin.joints.empty()) ctx.fail(who + " has no joints");
    for (int j : skin.joints)
        if (j < 0 || size_t(j) >= ctx.model.nodes.size())
            ctx.fail(who + " lists joint node " + std::to_string(j) + ", which does not exist");
    info.joints = skin.joints;
    info.inverse_bind.assign(skin.joints.size(), glm::dmat4(1.0));
    if (skin.inverseBindMatrices >= 0) {
        const std::string what = who + " inverseBindMatrices";
        AccessorData d = read_typed(ctx, skin.inverseBindMatrices, what, {TINYGLTF_TYPE_MAT4});
        if (d.count != skin.joints.size())
            ctx.fail(what + ": " + std::to_string(d.count) + " matrices for " + std::to_string(skin.joints.size()) +
                     " joints");
        require_finite(ctx, d, what);
        for (size_t j = 0; j < d.count; ++j)
            for (int c = 0; c < 4; ++c)
                for (int r = 0; r < 4; ++r) info.inverse_bind[j][c][r] = d.at(j, c * 4 + r);
    }
    return info;
}

// True when two inverse bind matrices are equal up to float rounding (same joint in two skins).
bool same_matrix(const glm::dmat4& a, const glm::dmat4& b) {
    double diff = 0.0, mag = 1.0;
    for (int c = 0; c < 4; ++c)
        for (int r = 0; r < 4; ++r) {
            diff = std::max(diff, std::abs(a[c][r] - b[c][r]));
            mag = std::max(mag, std::abs(a[c][r]));
        }
    return diff <= 1e-6 * mag;
}

// Minimal union-find over skin indices.
struct DisjointSets {
    std::vector<int> up;
    explicit DisjointSets(size_t n) : up(n) { std::iota(up.begin(), up.end(), 0); }
    int find(int x) { return up[size_t(x)] == x ? x : up[size_t(x)] = find(up[size_t(x)]); }
    void join(int a, int b) {
        a = find(a), b = find(b);
        if (a != b) up[size_t(std::max(a, b))] = std::min(a, b);
    }
};

// Groups of used skins (ascending), one per skeleton: skins sharing a joint or a top-most joint ancestor.
std::vector<std::vector<int>> group_skins(const Ctx& ctx, const std::vector<int>& used_skins,
                                          const std::vector<int>& parent) {
    std::vector<char> is_joint(ctx.model.nodes.size(), 0);
    for (int s : used_skins)
        for (int j : ctx.model.skins[size_t(s)].joints) {
            if (j < 0 || size_t(j) >= is_joint.size())
                ctx.fail("skin " + std::to_string(s) + " lists joint node " + std::to_string(j) +
                         ", which does not exist");
            is_joint[size_t(j)] = 1;
        }
    auto top_joint = [&](int n) {
        int top = n;
        for (int p = parent[size_t(n)]; p != -1; p = parent[size_t(p)])
            if (is_joint[size_t(p)]) top = p;
        return top;
    };
    DisjointSets sets(used_skins.size());
    std::map<int, int> owner;  // top-most joint node -> position in used_skins
    for (size_t i = 0; i < used_skins.size(); ++i)
        for (int j : ctx.model.skins[size_t(used_skins[i])].joints) {
            auto [it, inserted] = owner.emplace(top_joint(j), int(i));
            if (!inserted) sets.join(it->second, int(i));
        }
    std::map<int, std::vector<int>> groups;
    for (size_t i = 0; i < used_skins.size(); ++i) groups[sets.find(int(i))].push_back(used_skins[i]);
    std::vector<std::vector<int>> out;
    for (auto& [root, skins] : groups) out.push_back(std::move(skins));
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.front() < b.front(); });
    return out;
}

// ---------------------------------------------------------------------------
// Building one character

// Per character joint table: glTF node -> joints with that node, and per skin the remap to character joints.
struct JointTable {
    std::vector<int> node_of_joint;              // glTF node per character joint
    std::vector<glm::dmat4> inverse_bind;
    std::map<int, std::vector<int>> joints_of_node;
    std::map<int, std::vector<int>> skin_remap;  // glTF skin -> character joint per skin joint
};

// Merges the skins of one skeleton; joints are keyed by (node, inverse bind matrix).
JointTable merge_skins(const Ctx& ctx, const std::vector<int>& skins) {
    JointTable t;
    for (int s : skins) {
        const SkinInfo info = read_skin(ctx, s);
        std::vector<int>& remap = t.skin_remap[s];
        for (size_t k = 0; k < info.joints.size(); ++k) {
            const int node = info.joints[k];
            int found = -1;
            for (int j : t.joints_of_node[node])
                if (found < 0 && same_matrix(t.inverse_bind[size_t(j)], info.inverse_bind[k])) found = j;
            if (found < 0) {
                found = int(t.node_of_joint.size());
                t.node_of_joint.push_back(node);
                t.inverse_bind.push_back(info.inverse_bind[k]);
                t.joints_of_node[node].push_back(found);
            }
            remap.push_back(found);
        }
    }
    if (t.node_of_joint.size() > 65536)
        ctx.fail("skeleton with " + std::to_string(t.node_of_joint.size()) + " joints (at most 65536 supported)");
    return t;
}

// A mesh node of the character: skinned by `skin`, or rigidly attached to character joint `rigid_joint`.
struct MeshNode {
    int node = -1;
    int skin = -1;
    int rigid_joint = -1;
};

// Nearest ancestor-or-self of glTF node n that is a joint of the table, as a character joint (-1 if none).
int nearest_joint(const JointTable& t, const std::vector<int>& parent, int n) {
    for (int p = n; p != -1; p = parent[size_t(p)]) {
        auto it = t.joints_of_node.find(p);
        if (it != t.joints_of_node.end()) return it->second.front();
    }
    return -1;
}

// Character::nodes: the given glTF nodes plus all their ancestors, parents before children, else by index.
std::vector<int> collect_nodes(const std::vector<int>& seeds, const std::vector<int>& parent) {
    std::set<int> wanted;
    for (int n : seeds)
        for (int p = n; p != -1; p = parent[size_t(p)]) wanted.insert(p);
    std::vector<int> order;
    std::set<int> placed;
    std::vector<int> chain;
    for (int n : wanted) {
        chain.clear();
        for (int p = n; p != -1 && !placed.count(p); p = parent[size_t(p)]) chain.push_back(p);
        for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
            order.push_back(*it);
            placed.insert(*it);
        }
    }
    return order;
}

// Raw influences of one skinned primitive: per-skin joint indices and weights, `slots` per vertex.
struct Influences {
    std::vector<double> joints;   // raw per-skin joint indices, count * slots
    std::vector<double> weights;  // count * slots
    int slots = 0;
    bool quantized = false;  // any weight set stored as normalized integers
};

// Reads JOINTS_0/WEIGHTS_0 and, when present, JOINTS_1/WEIGHTS_1 of a skinned primitive (raw, not remapped).
Influences read_influences(const Ctx& ctx, const tinygltf::Primitive& prim, size_t count, const std::string& who) {
    Influences inf;
    std::vector<std::pair<AccessorData, AccessorData>> sets;
    for (int set = 0; set < 2; ++set) {
        const std::string js = "JOINTS_" + std::to_string(set), ws = "WEIGHTS_" + std::to_string(set);
        auto ji = prim.attributes.find(js), wi = prim.attributes.find(ws);
        if (ji == prim.attributes.end() && wi == prim.attributes.end()) {
            if (set == 0) ctx.fail(who + " is skinned but has no JOINTS_0/WEIGHTS_0");
            break;
        }
        if (ji == prim.attributes.end() || wi == prim.attributes.end())
            ctx.fail(who + " has " + (ji == prim.attributes.end() ? ws + " without " + js : js + " without " + ws));
        AccessorData jd = read_typed(ctx, ji->second, who + " " + js, {TINYGLTF_TYPE_VEC4});
        AccessorData wd = read_typed(ctx, wi->second, who + " " + ws, {TINYGLTF_TYPE_VEC4});
        const tinygltf::Accessor& ja = ctx.model.accessors[size_t(ji->second)];
        const tinygltf::Accessor& wa = ctx.model.accessors[size_t(wi->second)];
        if (ja.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
            ja.componentType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT)
            ctx.fail(who + " " + js + ": joint indices must be unsigned byte or unsigned short");
        if (wa.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT && !wa.normalized)
            ctx.fail(who + " " + ws + ": integer weights must be normalized");
        if (wa.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT) inf.quantized = true;
        if (jd.count != count || wd.count != count)
            ctx.fail(who + ": " + js + "/" + ws + " have " + std::to_string(jd.count) + "/" + std::to_string(wd.count) +
                     " elements for " + std::to_string(count) + " vertices");
        require_finite(ctx, wd, who + " " + ws);
        sets.push_back({std::move(jd), std::move(wd)});
    }
    inf.slots = 4 * int(sets.size());
    inf.joints.resize(count * size_t(inf.slots));
    inf.weights.resize(count * size_t(inf.slots));
    for (size_t v = 0; v < count; ++v)
        for (size_t set = 0; set < sets.size(); ++set)
            for (int k = 0; k < 4; ++k) {
                const size_t slot = v * size_t(inf.slots) + set * 4 + size_t(k);
                inf.joints[slot] = sets[set].first.at(v, k);
                inf.weights[slot] = sets[set].second.at(v, k);
            }
    return inf;
}

// Everything needed while appending primitives to a character.
struct Builder {
    const Ctx& ctx;
    Character& c;
    const JointTable& table;
    const std::vector<int>& parent;
    const std::vector<int>& animated_nodes;  // 1 for glTF nodes targeted by a T/R/S channel
    bool any_normals = false;
    size_t primitives_without_normals = 0;
    glm::dmat4 rigid{1.0};  // rigid transform of the last appended primitive (identity when skinned)
};

// Appends skinned primitive influences to c.joints/c.weights, remapped and renormalised.
void append_skinned_influences(Builder& b, const Influences& inf, const std::vector<int>& remap, size_t count,
                               const std::string& who) {
    const double tolerance = inf.quantized ? 2e-3 : 1e-3;
    const int slots = b.c.influences;
    for (size_t v = 0; v < count; ++v) {
        double sum = 0.0;
        for (int k = 0; k < inf.slots; ++k) {
            const double w = inf.weights[v * size_t(inf.slots) + size_t(k)];
            if (w < 0.0)
                b.ctx.fail(who + " vertex " + std::to_string(v) + ": negative weight " + std::to_string(w));
            sum += w;
        }
        if (!(sum > 0.0)) b.ctx.fail(who + " vertex " + std::to_string(v) + ": weights sum to 0");
        if (std::abs(sum - 1.0) > tolerance) ++b.c.renormalised_vertices;
        for (int k = 0; k < slots; ++k) {
            uint16_t joint = 0;
            float weight = 0.0f;
            if (k < inf.slots) {
                const double w = inf.weights[v * size_t(inf.slots) + size_t(k)];
                const double j = inf.joints[v * size_t(inf.slots) + size_t(k)];
                if (j < double(remap.size()))
                    joint = static_cast<uint16_t>(remap[size_t(j)]);
                else if (w > 0.0)
                    b.ctx.fail(who + " vertex " + std::to_string(v) + ": joint index " + std::to_string(size_t(j)) +
                               " out of range (skin has " + std::to_string(remap.size()) + " joints)");
                weight = static_cast<float>(w / sum);
            }
            b.c.joints.push_back(joint);
            b.c.weights.push_back(weight);
        }
    }
}

// Appends primitive `p` of mesh node `mn` (positions, normals, triangles, influences) to the character.
void append_primitive(Builder& b, const MeshNode& mn, int p) {
    const Ctx& ctx = b.ctx;
    const tinygltf::Node& node = ctx.model.nodes[size_t(mn.node)];
    const tinygltf::Mesh& mesh = ctx.model.meshes[size_t(node.mesh)];
    const tinygltf::Primitive& prim = mesh.primitives[size_t(p)];
    const std::string who = "mesh " + std::to_string(node.mesh) + " primitive " + std::to_string(p);
    auto pos_it = prim.attributes.find("POSITION");
    if (pos_it == prim.attributes.end()) ctx.fail(who + " has no POSITION");
    AccessorData pos = read_typed(ctx, pos_it->second, who + " POSITION", {TINYGLTF_TYPE_VEC3});
    require_finite(ctx, pos, who + " POSITION");
    const size_t count = pos.count;
    Character& c = b.c;
    if (c.positions.size() + count > size_t(std::numeric_limits<uint32_t>::max()))
        ctx.fail("more than 2^32 vertices in one character");

    PrimitiveRange range;
    range.node = mn.node;
    range.mesh = node.mesh;
    range.primitive = p;
    range.first = static_cast<uint32_t>(c.positions.size());
    range.count = static_cast<uint32_t>(count);
    range.rigid = mn.rigid_joint >= 0;
    range.skin = mn.skin;

    // Rigid attachment: v' = inverse(IBM_j) * L * v with L the rest transform from the joint down to the mesh node.
    glm::dmat4 rigid(1.0);
    if (range.rigid) {
        const int joint_node = b.table.node_of_joint[size_t(mn.rigid_joint)];
        glm::dmat4 chain(1.0);
        bool animated_between = false;
        for (int n = mn.node; n != joint_node; n = b.parent[size_t(n)]) {
            chain = local_matrix(convert_node(ctx, n)) * chain;
            animated_between = animated_between || b.animated_nodes[size_t(n)];
        }
        const glm::dmat4& ibm = b.table.inverse_bind[size_t(mn.rigid_joint)];
        if (std::abs(glm::determinant(ibm)) < 1e-300)
            ctx.fail("inverse bind matrix of joint node " + std::to_string(joint_node) + " is singular");
        rigid = glm::inverse(ibm) * chain;
        if (animated_between)
            c.notes.push_back("rigid mesh node " + std::to_string(mn.node) + ": animated nodes between it and joint node " +
                              std::to_string(joint_node) + " are frozen at their rest transform");
    }
    const glm::dmat3 rigid_normal = glm::inverseTranspose(glm::dmat3(rigid));
    b.rigid = rigid;

    for (size_t v = 0; v < count; ++v) {
        glm::dvec3 x(pos.at(v, 0), pos.at(v, 1), pos.at(v, 2));
        if (range.rigid) x = glm::dvec3(rigid * glm::dvec4(x, 1.0));
        c.positions.emplace_back(x);
    }

    auto nrm_it = prim.attributes.find("NORMAL");
    if (nrm_it != prim.attributes.end()) {
        AccessorData nrm = read_typed(ctx, nrm_it->second, who + " NORMAL", {TINYGLTF_TYPE_VEC3});
        require_finite(ctx, nrm, who + " NORMAL");
        if (nrm.count != count)
            ctx.fail(who + ": NORMAL has " + std::to_string(nrm.count) + " elements for " + std::to_string(count) +
                     " vertices");
        c.normals.resize(range.first, glm::vec3(0.0f, 0.0f, 1.0f));  // fill primitives that had none
        for (size_t v = 0; v < count; ++v) {
            glm::dvec3 n(nrm.at(v, 0), nrm.at(v, 1), nrm.at(v, 2));
            if (range.rigid) {
                n = rigid_normal * n;
                const double len = glm::length(n);
                if (len > 0.0) n /= len;
            }
            c.normals.emplace_back(n);
        }
        b.any_normals = true;
    } else {
        ++b.primitives_without_normals;
        if (b.any_normals) c.normals.resize(c.positions.size(), glm::vec3(0.0f, 0.0f, 1.0f));
    }

    const int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
    if (mode == TINYGLTF_MODE_TRIANGLES) {
        if (prim.indices >= 0) {
            AccessorData idx = read_typed(ctx, prim.indices, who + " indices", {TINYGLTF_TYPE_SCALAR});
            const int ct = ctx.model.accessors[size_t(prim.indices)].componentType;
            if (ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
                ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
                ctx.fail(who + " indices must be unsigned integers");
            for (size_t i = 0; i + 2 < idx.count; i += 3)
                for (size_t k = 0; k < 3; ++k) {
                    const double vi = idx.values[i + k];
                    if (vi >= double(count))
                        ctx.fail(who + ": index " + std::to_string(size_t(vi)) + " out of range (" +
                                 std::to_string(count) + " vertices)");
                    c.triangles.push_back(range.first + static_cast<uint32_t>(vi));
                }
        } else {
            for (size_t i = 0; i + 2 < count; i += 3)
                for (size_t k = 0; k < 3; ++k) c.triangles.push_back(range.first + static_cast<uint32_t>(i + k));
        }
    }

    if (range.rigid) {
        for (size_t v = 0; v < count; ++v)
            for (int k = 0; k < c.influences; ++k) {
                c.joints.push_back(k == 0 ? static_cast<uint16_t>(mn.rigid_joint) : 0);
                c.weights.push_back(k == 0 ? 1.0f : 0.0f);
            }
    } else {
        const Influences inf = read_influences(ctx, prim, count, who);
        append_skinned_influences(b, inf, b.table.skin_remap.at(mn.skin), count, who);
    }
    c.primitives.push_back(range);
}

// Names of a mesh's morph targets from mesh.extras.targetNames (the de-facto
// convention of Blender and three.js); empty strings where absent.
std::vector<std::string> target_names(const tinygltf::Mesh& mesh, size_t count) {
    std::vector<std::string> names(count);
    if (!mesh.extras.IsObject() || !mesh.extras.Has("targetNames")) return names;
    const tinygltf::Value& v = mesh.extras.Get("targetNames");
    if (!v.IsArray()) return names;
    for (size_t i = 0; i < count && i < v.ArrayLen(); ++i)
        if (v.Get(int(i)).IsString()) names[i] = v.Get(int(i)).Get<std::string>();
    return names;
}

// Default weights of a mesh node's morph targets: node.weights, else mesh.weights, else 0.
std::vector<float> default_morph_weights(const Ctx& ctx, int gltf_node, size_t count) {
    const tinygltf::Node& node = ctx.model.nodes[size_t(gltf_node)];
    const tinygltf::Mesh& mesh = ctx.model.meshes[size_t(node.mesh)];
    const std::vector<double>& w = !node.weights.empty() ? node.weights : mesh.weights;
    const std::string who = !node.weights.empty() ? "node " + std::to_string(gltf_node) + " weights"
                                                  : "mesh " + std::to_string(node.mesh) + " weights";
    std::vector<float> out(count, 0.0f);
    if (w.empty()) return out;
    if (w.size() != count)
        ctx.fail(who + " has " + std::to_string(w.size()) + " values for " + std::to_string(count) + " morph targets");
    for (size_t i = 0; i < count; ++i) {
        if (!std::isfinite(w[i])) ctx.fail(who + " has a NaN or infinite value");
        out[i] = float(w[i]);
    }
    return out;
}

// One VEC3 morph attribute (POSITION or NORMAL) of a target, transformed by m; empty when absent.
std::vector<glm::dvec3> read_target_attribute(const Ctx& ctx, const std::map<std::string, int>& target,
                                              const char* attribute, size_t count, const glm::dmat3& m,
                                              const std::string& who) {
    auto it = target.find(attribute);
    if (it == target.end()) return {};
    const std::string what = who + " " + attribute;
    AccessorData d = read_typed(ctx, it->second, what, {TINYGLTF_TYPE_VEC3});
    require_finite(ctx, d, what);
    if (d.count != count)
        ctx.fail(what + ": " + std::to_string(d.count) + " elements for " + std::to_string(count) + " vertices");
    std::vector<glm::dvec3> out(count);
    for (size_t v = 0; v < count; ++v) out[v] = m * glm::dvec3(d.at(v, 0), d.at(v, 1), d.at(v, 2));
    return out;
}

// Morph targets of mesh node `mn` (character node `node`), whose primitives are
// c.primitives[first_primitive..]: one MorphTarget per target of the mesh.
void read_morph_targets(Builder& b, const MeshNode& mn, int node, size_t first_primitive) {
    const Ctx& ctx = b.ctx;
    Character& c = b.c;
    const tinygltf::Node& gnode = ctx.model.nodes[size_t(mn.node)];
    const tinygltf::Mesh& mesh = ctx.model.meshes[size_t(gnode.mesh)];
    const size_t count = mesh.primitives.empty() ? 0 : mesh.primitives[0].targets.size();
    for (size_t p = 1; p < mesh.primitives.size(); ++p)
        if (mesh.primitives[p].targets.size() != count)
            ctx.fail("mesh " + std::to_string(gnode.mesh) + ": primitive " + std::to_string(p) + " has " +
                     std::to_string(mesh.primitives[p].targets.size()) + " morph targets, primitive 0 has " +
                     std::to_string(count) + " (glTF requires the same number)");
    if (count == 0) {
        if (!gnode.weights.empty() || !mesh.weights.empty())
            c.notes.push_back("mesh node " + std::to_string(mn.node) + ": weights given without morph targets (ignored)");
        return;
    }
    const std::vector<std::string> names = target_names(mesh, count);
    const std::vector<float> weights = default_morph_weights(ctx, mn.node, count);
    const glm::dmat3 linear(b.rigid);
    const glm::dmat3 normal_m = glm::inverseTranspose(linear);
    const size_t base = c.morphs.size();
    for (size_t t = 0; t < count; ++t) {
        MorphTarget m;
        m.name = !names[t].empty() ? names[t]
                                   : (gnode.name.empty() ? "node " + std::to_string(mn.node) : gnode.name) + " target " +
                                         std::to_string(t);
        m.node = node;
        m.gltf_node = mn.node;
        m.target = int(t);
        m.default_weight = weights[t];
        c.morphs.push_back(std::move(m));
    }
    std::vector<char> has_normal(count, 0);  // per target: NORMAL deltas in any primitive
    for (size_t p = 0; p < mesh.primitives.size(); ++p)
        for (size_t t = 0; t < count; ++t)
            if (mesh.primitives[p].targets[t].count("NORMAL")) has_normal[t] = 1;
    for (size_t p = 0; p < mesh.primitives.size(); ++p) {
        const PrimitiveRange& range = c.primitives[first_primitive + p];
        for (size_t t = 0; t < count; ++t) {
            const std::string who = "mesh " + std::to_string(gnode.mesh) + " primitive " + std::to_string(p) +
                                    " morph target " + std::to_string(t);
            const auto& target = mesh.primitives[p].targets[t];
            const auto dp = read_target_attribute(ctx, target, "POSITION", range.count, linear, who);
            const auto dn = read_target_attribute(ctx, target, "NORMAL", range.count, normal_m, who);
            MorphTarget& m = c.morphs[base + t];
            for (size_t v = 0; v < range.count; ++v) {
                const glm::dvec3 a = dp.empty() ? glm::dvec3(0.0) : dp[v];
                const glm::dvec3 n = dn.empty() ? glm::dvec3(0.0) : dn[v];
                if (a == glm::dvec3(0.0) && n == glm::dvec3(0.0)) continue;
                m.vertices.push_back(range.first + static_cast<uint32_t>(v));
                m.position_deltas.emplace_back(a);
                if (has_normal[t]) m.normal_deltas.emplace_back(n);
            }
        }
    }
    c.has_morph_targets = true;
}

// Decodes one animation sampler's times and values for a T/R/S channel, or a
// weights channel of `weight_count` morph targets.
void read_sampler(const Ctx& ctx, int a, int s, ChannelPath path, Channel& ch, size_t weight_count = 0) {
    const tinygltf::Animation& anim = ctx.model.animations[size_t(a)];
    if (s < 0 || size_t(s) >= anim.samplers.size())
        ctx.fail("animation " + std::to_string(a) + " channel refers to sampler " + std::to_string(s) +
                 ", which does not exist");
    const tinygltf::AnimationSampler& smp = anim.samplers[size_t(s)];
    const std::string who = "animation " + std::to_string(a) + " sampler " + std::to_string(s);
    if (smp.interpolation == "LINEAR")
        ch.interpolation = Interpolation::Linear;
    else if (smp.interpolation == "STEP")
        ch.interpolation = Interpolation::Step;
    else if (smp.interpolation == "CUBICSPLINE")
        ch.interpolation = Interpolation::CubicSpline;
    else
        ctx.fail(who + ": unknown interpolation \"" + smp.interpolation + "\"");

    AccessorData in = read_typed(ctx, smp.input, who + " input", {TINYGLTF_TYPE_SCALAR});
    require_finite(ctx, in, who + " input");
    if (in.count == 0) ctx.fail(who + ": no key times");
    for (size_t k = 1; k < in.count; ++k)
        if (!(float(in.values[k]) > float(in.values[k - 1])))
            ctx.fail(who + ": key times not strictly increasing at key " + std::to_string(k) + " (" +
                     std::to_string(in.values[k - 1]) + " then " + std::to_string(in.values[k]) + ")");
    const int type = path == ChannelPath::Rotation  ? TINYGLTF_TYPE_VEC4
                     : path == ChannelPath::Weights ? TINYGLTF_TYPE_SCALAR
                                                    : TINYGLTF_TYPE_VEC3;
    AccessorData out = read_typed(ctx, smp.output, who + " output", {type});
    require_finite(ctx, out, who + " output");
    const size_t per_key = (ch.interpolation == Interpolation::CubicSpline ? 3 : 1) *
                           (path == ChannelPath::Weights ? weight_count : 1);
    if (out.count != in.count * per_key)
        ctx.fail(who + ": " + std::to_string(out.count) + " output values for " + std::to_string(in.count) + " keys" +
                 (path == ChannelPath::Weights ? " of " + std::to_string(weight_count) + " morph weights" : "") +
                 (ch.interpolation == Interpolation::CubicSpline ? " (CUBICSPLINE needs 3 per key)" : ""));
    ch.times.assign(in.values.begin(), in.values.end());
    ch.values.assign(out.values.begin(), out.values.end());
}

// Clips of the file restricted to the character's nodes (gltf node -> character node via node_index).
void read_clips(const Ctx& ctx, Character& c, const std::vector<int>& node_index) {
    std::set<std::string> unknown_paths;
    for (size_t a = 0; a < ctx.model.animations.size(); ++a) {
        const tinygltf::Animation& anim = ctx.model.animations[a];
        Clip clip;
        clip.name = anim.name.empty() ? "clip " + std::to_string(a) : anim.name;
        clip.gltf_index = int(a);
        bool first = true;
        for (size_t k = 0; k < anim.channels.size(); ++k) {
            const tinygltf::AnimationChannel& src = anim.channels[k];
            ChannelPath path;
            if (src.target_path == "translation")
                path = ChannelPath::Translation;
            else if (src.target_path == "rotation")
                path = ChannelPath::Rotation;
            else if (src.target_path == "scale")
                path = ChannelPath::Scale;
            else if (src.target_path == "weights")
                path = ChannelPath::Weights;
            else {
                unknown_paths.insert(src.target_path);
                continue;
            }
            if (src.target_node < 0) continue;  // e.g. KHR_animation_pointer targets
            if (size_t(src.target_node) >= ctx.model.nodes.size())
                ctx.fail("animation " + std::to_string(a) + " channel " + std::to_string(k) + " targets node " +
                         std::to_string(src.target_node) + ", which does not exist");
            const int node = node_index[size_t(src.target_node)];
            if (node < 0) continue;  // not part of this character
            Channel ch;
            ch.node = node;
            ch.path = path;
            if (path == ChannelPath::Weights) {
                ch.morph_first = -1;
                for (size_t m = 0; m < c.morphs.size(); ++m)
                    if (c.morphs[m].gltf_node == src.target_node) {
                        if (ch.morph_first < 0) ch.morph_first = int(m);
                        ++ch.morph_count;
                    }
                if (ch.morph_first < 0)
                    ctx.fail("animation " + std::to_string(a) + " channel " + std::to_string(k) +
                             " animates the morph weights of node " + std::to_string(src.target_node) +
                             ", which has no morph targets");
            }
            read_sampler(ctx, int(a), src.sampler, path, ch, size_t(ch.morph_count));
            clip.start = first ? ch.times.front() : std::min(clip.start, ch.times.front());
            clip.end = first ? ch.times.back() : std::max(clip.end, ch.times.back());
            first = false;
            clip.channels.push_back(std::move(ch));
        }
        c.clips.push_back(std::move(clip));
    }
    for (const std::string& p : unknown_paths) c.notes.push_back("animation channels with path \"" + p + "\" ignored");
}

// glTF nodes targeted by any translation/rotation/scale channel (validated later when read).
std::vector<int> animated_nodes(const Ctx& ctx) {
    std::vector<int> animated(ctx.model.nodes.size(), 0);
    for (const auto& anim : ctx.model.animations)
        for (const auto& ch : anim.channels)
            if (ch.target_node >= 0 && size_t(ch.target_node) < animated.size() &&
                (ch.target_path == "translation" || ch.target_path == "rotation" || ch.target_path == "scale"))
                animated[size_t(ch.target_node)] = 1;
    return animated;
}

// Builds the character of one skeleton (a group of skins) and the mesh nodes attached to it.
Character build_character(const Ctx& ctx, const std::vector<int>& skins, const std::vector<MeshNode>& mesh_nodes,
                          const JointTable& table, const std::vector<int>& parent, const std::vector<int>& animated,
                          int character_index) {
    Character c;
    c.source = ctx.path;
    const tinygltf::Skin& first_skin = ctx.model.skins[size_t(skins.front())];
    if (!first_skin.name.empty())
        c.name = first_skin.name;
    else if (!mesh_nodes.empty() && !ctx.model.nodes[size_t(mesh_nodes.front().node)].name.empty())
        c.name = ctx.model.nodes[size_t(mesh_nodes.front().node)].name;
    else
        c.name = "character " + std::to_string(character_index);

    // Nodes: joints, mesh nodes and all their ancestors.
    std::vector<int> seeds = table.node_of_joint;
    for (const MeshNode& mn : mesh_nodes) seeds.push_back(mn.node);
    const std::vector<int> order = collect_nodes(seeds, parent);
    std::vector<int> node_index(ctx.model.nodes.size(), -1);
    for (size_t i = 0; i < order.size(); ++i) node_index[size_t(order[i])] = int(i);
    for (int g : order) {
        Node n = convert_node(ctx, g);
        n.parent = parent[size_t(g)] < 0 ? -1 : node_index[size_t(parent[size_t(g)])];
        if (n.has_matrix && animated[size_t(g)]) decompose_matrix_node(ctx, n, c.notes);
        c.nodes.push_back(std::move(n));
    }

    // Joints and their parents in the joint hierarchy.
    for (size_t j = 0; j < table.node_of_joint.size(); ++j) {
        const int g = table.node_of_joint[j];
        c.joint_node.push_back(node_index[size_t(g)]);
        c.inverse_bind.push_back(table.inverse_bind[j]);
        c.joint_parent.push_back(parent[size_t(g)] < 0 ? -1 : nearest_joint(table, parent, parent[size_t(g)]));
    }

    // Influence count: 8 when any skinned primitive has a second set.
    c.influences = 4;
    for (const MeshNode& mn : mesh_nodes) {
        if (mn.skin < 0) continue;
        for (const auto& prim : ctx.model.meshes[size_t(ctx.model.nodes[size_t(mn.node)].mesh)].primitives)
            if (prim.attributes.count("JOINTS_1") || prim.attributes.count("WEIGHTS_1")) c.influences = 8;
    }

    Builder b{ctx, c, table, parent, animated};
    for (const MeshNode& mn : mesh_nodes) {
        const int mesh = ctx.model.nodes[size_t(mn.node)].mesh;
        const size_t first_primitive = c.primitives.size();
        for (size_t p = 0; p < ctx.model.meshes[size_t(mesh)].primitives.size(); ++p) append_primitive(b, mn, int(p));
        read_morph_targets(b, mn, node_index[size_t(mn.node)], first_primitive);
    }
    if (!b.any_normals) c.normals.clear();
    if (b.any_normals && b.primitives_without_normals > 0)
        c.notes.push_back(std::to_string(b.primitives_without_normals) +
                          " primitive(s) without NORMAL: normals set to (0, 0, 1)");
    if (c.renormalised_vertices > 0)
        c.notes.push_back(std::to_string(c.renormalised_vertices) + " vertices had weights not summing to 1 (renormalised)");

    read_clips(ctx, c, node_index);
    return c;
}

}  // namespace

namespace gltf {

void load_model(const std::string& path, tinygltf::Model& model) { progskin::load_model(path, model); }

std::vector<double> read_accessor(const std::string& path, const tinygltf::Model& model, int index, int components,
                                  const std::string& what) {
    const Ctx ctx{model, path};
    AccessorData d = progskin::read_accessor(ctx, index, what);
    if (d.components != components)
        ctx.fail(what + ": accessor " + std::to_string(index) + " has " + std::to_string(d.components) +
                 " components per element, expected " + std::to_string(components));
    require_finite(ctx, d, what);
    return std::move(d.values);
}

}  // namespace gltf

std::vector<Character> import_gltf(const std::string& path, const ImportOptions& options) {
    tinygltf::Model model;
    load_model(path, model);
    const Ctx ctx{model, path};
    const std::vector<int> parent = node_parents(ctx);
    const std::vector<int> animated = animated_nodes(ctx);

    // Skins used by a mesh node, and the mesh nodes.
    std::vector<int> used_skins;
    for (size_t n = 0; n < model.nodes.size(); ++n) {
        const tinygltf::Node& node = model.nodes[n];
        if (node.mesh >= 0 && size_t(node.mesh) >= model.meshes.size())
            ctx.fail("node " + std::to_string(n) + " refers to mesh " + std::to_string(node.mesh) + ", which does not exist");
        if (node.skin >= 0 && size_t(node.skin) >= model.skins.size())
            ctx.fail("node " + std::to_string(n) + " refers to skin " + std::to_string(node.skin) + ", which does not exist");
        if (node.mesh >= 0 && node.skin >= 0) used_skins.push_back(node.skin);
    }
    std::sort(used_skins.begin(), used_skins.end());
    used_skins.erase(std::unique(used_skins.begin(), used_skins.end()), used_skins.end());
    if (used_skins.empty()) {
        if (!options.require_skin) return {};
        ctx.fail(model.skins.empty() ? "no skin (the file has no skins; nothing to skin)"
                                     : "no skin (no mesh node uses any of the file's " +
                                           std::to_string(model.skins.size()) + " skins)");
    }

    const std::vector<std::vector<int>> groups = group_skins(ctx, used_skins, parent);
    std::vector<JointTable> tables;
    for (const auto& g : groups) tables.push_back(merge_skins(ctx, g));

    // Assign every mesh node to a character: by its skin, or by the nearest ancestor joint (rigid).
    std::vector<std::vector<MeshNode>> mesh_nodes(groups.size());
    for (size_t n = 0; n < model.nodes.size(); ++n) {
        const tinygltf::Node& node = model.nodes[n];
        if (node.mesh < 0) continue;
        for (size_t g = 0; g < groups.size(); ++g) {
            if (node.skin >= 0) {
                if (std::find(groups[g].begin(), groups[g].end(), node.skin) != groups[g].end())
                    mesh_nodes[g].push_back({int(n), node.skin, -1});
                continue;
            }
            const int joint = nearest_joint(tables[g], parent, int(n));
            if (joint >= 0) {
                mesh_nodes[g].push_back({int(n), -1, joint});
                break;
            }
        }
    }

    std::vector<Character> out;
    for (size_t g = 0; g < groups.size(); ++g)
        out.push_back(build_character(ctx, groups[g], mesh_nodes[g], tables[g], parent, animated, int(g)));
    return out;
}

Character import_character(const std::string& path, int character_index) {
    std::vector<Character> all = import_gltf(path);
    if (character_index < 0 || size_t(character_index) >= all.size())
        throw Error(path + ": no character " + std::to_string(character_index) + " (the file has " +
                    std::to_string(all.size()) + (all.size() == 1 ? " character)" : " characters)"));
    return std::move(all[size_t(character_index)]);
}

}  // namespace progskin
