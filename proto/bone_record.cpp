// bone_record.cpp — see bone_record.h.
#include "bone_record.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

#include <glm/gtc/quaternion.hpp>

#include "animation.h"
#include "character.h"
#include "progressive_skin.h"

namespace progskin::net {
namespace {

uint32_t zigzag(int32_t v) { return (uint32_t(v) << 1) ^ uint32_t(v >> 31); }
int64_t unzigzag(uint64_t u) { return int64_t(u >> 1) ^ -int64_t(u & 1); }
int eg_bits(uint32_t u, int k) { return 2 * int(std::bit_width(uint64_t(u) + (uint64_t(1) << k))) - 1 - k; }

// The order (index into orders) that codes three values in the fewest bits.
int best_order(const uint32_t u[3], const int (&orders)[4], int& bits) {
    int best = 0;
    bits = 1 << 30;
    for (int s = 0; s < 4; ++s) {
        const int n = eg_bits(u[0], orders[s]) + eg_bits(u[1], orders[s]) + eg_bits(u[2], orders[s]);
        if (n < bits) bits = n, best = s;
    }
    return best;
}

bool round_to(double v, int32_t bound, int32_t& out) {
    const double r = std::round(v);
    if (!(r >= -double(bound) && r <= double(bound))) return false;  // NaN fails too
    out = int32_t(r);
    return true;
}

struct DPose {
    glm::dquat r{1, 0, 0, 0};
    glm::dvec3 t{0.0};
    double s = 1.0;
};
DPose widen(const BonePose& p) { return {glm::dquat(p.r), glm::dvec3(p.t), double(p.s)}; }

// Rotation of a record's integers (w may be slightly negative past |p| = 1).
glm::dquat rotation_of(const int32_t rot[3]) {
    const glm::dvec3 p(rot[0] * ROT_STEP, rot[1] * ROT_STEP, rot[2] * ROT_STEP);
    const double n2 = glm::dot(p, p);
    const glm::dvec3 v = p * (2.0 / (1.0 + n2));
    return glm::dquat((1.0 - n2) / (1.0 + n2), v.x, v.y, v.z);
}

}  // namespace

RelativeFormat relative_format(std::span<const int16_t> parents, std::span<const Mat34> inverse_binds,
                               const RecordFormat& box) {
    if (parents.size() != inverse_binds.size()) throw std::invalid_argument("relative_format: parents and binds differ in size");
    RelativeFormat f;
    f.parents.assign(parents.begin(), parents.end());
    f.pivots.resize(parents.size());
    for (size_t b = 0; b < parents.size(); ++b) {
        if (parents[b] >= int(b) || parents[b] < -1 || (b == 0 && parents[b] != -1))
            throw std::invalid_argument("relative_format: a progressive parent is not below its bone");
        const glm::dmat4 bind = glm::inverse(glm::dmat4(inverse_binds[b].to_glm()));
        f.pivots[b] = glm::vec3(bind[3]);
    }
    const glm::vec3 ext = box.t_max - box.t_min;
    f.t_step = box.t_step > 0.0f ? box.t_step : std::max({ext.x, ext.y, ext.z, 1e-9f}) / 65535.0f;
    f.scaled = box.scaled;
    if (!(box.scale >= kMinReferenceScale && box.scale <= kMaxReferenceScale))
        throw std::invalid_argument("relative_format: a reference scale outside [2^-16, 2^16]");
    f.s_ref = box.scale;
    return f;
}

RelativeFormat chain_format(int bones, const RecordFormat& box) {
    std::vector<int16_t> parents(size_t(std::max(0, bones)));
    for (size_t b = 0; b < parents.size(); ++b) parents[b] = int16_t(int(b) - 1);
    return relative_format(parents, std::vector<Mat34>(parents.size(), Mat34::identity()), box);
}

RelativeFormat relative_format(const ProgressiveSkin& skin, const Character& c, const RecordFormat& box) {
    std::vector<Mat34> ib(skin.order.size());
    for (size_t b = 0; b < ib.size(); ++b) {
        const size_t j = size_t(skin.order[b]);
        if (j >= c.inverse_bind.size()) throw std::invalid_argument("relative_format: a bone's joint is not in the character");
        ib[b] = Mat34::from_glm(c.inverse_bind[j]);
    }
    return relative_format(skin.parents, ib, box);
}

bool quantise_record(const BonePose& parent_decoded, const BonePose& m, int b, const RelativeFormat& f, RecordInts& out) {
    if (b < 0 || size_t(b) >= f.pivots.size()) return false;
    const glm::vec3& pivot = f.pivots[size_t(b)];
    const double s0 = f.scale_unit(b), step = f.trans_step(b);
    const DPose p = widen(parent_decoded), c = widen(m);
    if (!(p.s > 0) || !(c.s > 0)) return false;
    const glm::dquat ip = glm::conjugate(p.r);
    glm::dquat q = ip * c.r;
    const double len = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    if (!(len > 1e-6) || !std::isfinite(len)) return false;
    q = q / len;
    if (q.w < 0) q = -q;
    RecordInts r;
    const double d = 1.0 + q.w;
    if (!round_to(q.x / d / ROT_STEP, kMaxRotInt, r.rot[0]) || !round_to(q.y / d / ROT_STEP, kMaxRotInt, r.rot[1]) ||
        !round_to(q.z / d / ROT_STEP, kMaxRotInt, r.rot[2]))
        return false;
    const double s_rel = c.s / p.s;
    if (f.scaled) {
        int32_t l = 0;
        if (!round_to(std::log2(s_rel / s0) * 2048.0, kMaxScaleInt, l)) return false;
        r.scale = l;
        r.has_scale = l != 0;
    }
    // The translation R would have if the joint turned rigidly about its pivot.
    const glm::dquat qh = rotation_of(r.rot);
    const double sh = s0 * (r.has_scale ? std::exp2(double(r.scale) / 2048.0) : 1.0);
    const glm::dvec3 j(pivot);
    const glm::dvec3 pred = s0 * j - sh * (qh * j);
    const glm::dvec3 t_rel = (ip * (c.t - p.t)) / p.s;
    bool big = false;
    for (int a = 0; a < 3; ++a) {
        if (!round_to((t_rel[a] - pred[a]) / step, kMaxTransInt, r.trans[a])) return false;
        big = big || std::abs(r.trans[a]) > kTransDeadZone;
    }
    r.has_trans = big;
    if (!big) r.trans[0] = r.trans[1] = r.trans[2] = 0;
    out = r;
    return true;
}

BonePose dequantise_record(const RecordInts& r, int b, const RelativeFormat& f) {
    const glm::dquat q = rotation_of(r.rot);
    const double s0 = f.scale_unit(b), s = s0 * (f.scaled && r.has_scale ? std::exp2(double(r.scale) / 2048.0) : 1.0);
    const glm::dvec3 j(b >= 0 && size_t(b) < f.pivots.size() ? glm::dvec3(f.pivots[size_t(b)]) : glm::dvec3(0.0));
    glm::dvec3 t = s0 * j - s * (q * j);
    if (r.has_trans) t += glm::dvec3(r.trans[0], r.trans[1], r.trans[2]) * f.trans_step(b);
    BonePose out;
    out.r = glm::quat(glm::normalize(q));
    out.t = glm::vec3(t);
    out.s = float(s);
    return out;
}

BonePose compose_relative(const BonePose& parent, const BonePose& rel) {
    const DPose p = widen(parent), r = widen(rel);
    BonePose out;
    out.r = glm::quat(glm::normalize(p.r * r.r));
    out.t = glm::vec3(p.t + p.s * (p.r * r.t));
    out.s = float(p.s * r.s);
    return out;
}

// Bits are written and read through a little-endian 64-bit window: a field
// of at most 57 bits starting anywhere in a byte fits one window.
// The partial last byte first, then whole bytes by push_back (no
// zero-filling resize, no variable-length copy: this is the record coders'
// inner loop).
void BitWriter::put(uint64_t bits, int n) {
    if (n <= 0) return;
    bits &= n >= 64 ? ~uint64_t(0) : (uint64_t(1) << n) - 1;
    if (free_ > 0) {
        out_.back() = uint8_t(out_.back() | uint8_t(bits << (8 - free_)));
        const int used = std::min(free_, n);
        free_ -= used;
        n -= used;
        if (n == 0) return;
        bits >>= used;
    }
    for (; n >= 8; n -= 8, bits >>= 8) out_.push_back(uint8_t(bits));
    if (n > 0) {
        out_.push_back(uint8_t(bits));
        free_ = 8 - n;
    }
}

void BitWriter::put_eg(uint32_t u, int k) {
    const uint64_t x = uint64_t(u) + (uint64_t(1) << k);
    const int n = int(std::bit_width(x));
    const int z = n - 1 - k;
    // z zero bits, a one, then the low n - 1 bits of x: one field when it fits a window.
    if (2 * z + k + 1 <= 57) {
        put((uint64_t(1) << z) | ((x & ((uint64_t(1) << (n - 1)) - 1)) << (z + 1)), 2 * z + k + 1);
        return;
    }
    put(0, z);
    put(1, 1);
    put(x & ((uint64_t(1) << (n - 1)) - 1), n - 1);
}

size_t write_record(const RecordInts& r, bool scaled, BitWriter& w) {
    const size_t start = w.bits();
    uint32_t u[3] = {zigzag(r.rot[0]), zigzag(r.rot[1]), zigzag(r.rot[2])};
    int bits = 0;
    int s = best_order(u, kRotOrders, bits);
    w.put(uint64_t(s), 2);
    for (int a = 0; a < 3; ++a) w.put_eg(u[a], kRotOrders[s]);
    w.put(r.has_trans ? 1 : 0, 1);
    if (r.has_trans) {
        uint32_t t[3] = {zigzag(r.trans[0]), zigzag(r.trans[1]), zigzag(r.trans[2])};
        s = best_order(t, kTransOrders, bits);
        w.put(uint64_t(s), 2);
        for (int a = 0; a < 3; ++a) w.put_eg(t[a], kTransOrders[s]);
    }
    if (scaled) {
        w.put(r.has_scale ? 1 : 0, 1);
        if (r.has_scale) w.put_eg(zigzag(r.scale), kScaleOrder);
    }
    return w.bits() - start;
}

bool read_record(BitReader& in, bool scaled, RecordInts& r) {
    r = RecordInts{};
    uint64_t s = 0, u = 0, flag = 0;
    if (!in.get(2, s)) return false;
    int64_t n2 = 0;
    for (int a = 0; a < 3; ++a) {
        if (!in.get_eg(kRotOrders[s], u)) return false;
        const int64_t v = unzigzag(u);
        if (v < -kMaxRotInt || v > kMaxRotInt) return false;
        r.rot[a] = int32_t(v);
        n2 += v * v;
    }
    if (n2 > int64_t(kMaxRotInt) * kMaxRotInt) return false;
    if (!in.get(1, flag)) return false;
    r.has_trans = flag != 0;
    if (r.has_trans) {
        if (!in.get(2, s)) return false;
        for (int a = 0; a < 3; ++a) {
            if (!in.get_eg(kTransOrders[s], u)) return false;
            const int64_t v = unzigzag(u);
            if (v < -kMaxTransInt || v > kMaxTransInt) return false;
            r.trans[a] = int32_t(v);
        }
    }
    if (scaled) {
        if (!in.get(1, flag)) return false;
        r.has_scale = flag != 0;
        if (r.has_scale) {
            if (!in.get_eg(kScaleOrder, u)) return false;
            const int64_t v = unzigzag(u);
            if (v < -kMaxScaleInt || v > kMaxScaleInt) return false;
            r.scale = int32_t(v);
        }
    }
    return true;
}

RecordInts predict_record(const RecordInts& b1, uint32_t a1, const RecordInts* b2, uint32_t a2) {
    RecordInts p = b1;
    // Evenly spaced samples (a2 = 2 a1, every tick-sampled baseline): the
    // step is x1 - x2 exactly, without the division.
    const bool even = a2 - a1 == a1;
    auto lin = [&](int32_t x1, int32_t x2) -> int32_t {
        const int64_t d = int64_t(x1) - int64_t(x2);
        const int64_t v = int64_t(x1) + (even ? d : d * int64_t(a1) / int64_t(a2 - a1));
        return int32_t(std::clamp<int64_t>(v, -(int64_t(1) << 30), int64_t(1) << 30));
    };
    if (b2 && a2 > a1 && a1 >= 1) {
        for (int a = 0; a < 3; ++a) {
            p.rot[a] = lin(b1.rot[a], b2->rot[a]);
            p.trans[a] = lin(b1.has_trans ? b1.trans[a] : 0, b2->has_trans ? b2->trans[a] : 0);
        }
        p.scale = lin(b1.has_scale ? b1.scale : 0, b2->has_scale ? b2->scale : 0);
    }
    if (!b1.has_trans && !(b2 && b2->has_trans)) p.trans[0] = p.trans[1] = p.trans[2] = 0;
    p.has_trans = p.trans[0] || p.trans[1] || p.trans[2];
    p.has_scale = p.scale != 0;
    return p;
}

static bool same(const RecordInts& a, const RecordInts& b) {
    for (int i = 0; i < 3; ++i)
        if (a.rot[i] != b.rot[i] || a.trans[i] != b.trans[i]) return false;
    return a.scale == b.scale;
}

namespace {
// Counts what a BitWriter would write (predicted_bits).
struct BitCounter {
    size_t n = 0;
    void put(uint64_t, int bits) { n += size_t(std::max(0, bits)); }
    void put_eg(uint32_t u, int k) { n += size_t(eg_bits(u, k)); }
    size_t bits() const { return n; }
};

// write_predicted's syntax to a BitWriter, or to a BitCounter (its length).
template <class Out>
size_t code_predicted(const RecordInts& now, const RecordInts& pred, bool scaled, Out& w) {
    const size_t start = w.bits();
    RecordInts n = now;
    if (!n.has_trans) n.trans[0] = n.trans[1] = n.trans[2] = 0;
    if (!n.has_scale || !scaled) n.scale = 0;
    RecordInts p = pred;
    if (!scaled) p.scale = 0;
    if (same(n, p)) {
        w.put(1, 1);
        return w.bits() - start;
    }
    w.put(0, 1);
    uint32_t u[3];
    int bits = 0;
    for (int a = 0; a < 3; ++a) u[a] = zigzag(n.rot[a] - p.rot[a]);
    int s = best_order(u, kDeltaOrders, bits);
    w.put(uint64_t(s), 2);
    for (int a = 0; a < 3; ++a) w.put_eg(u[a], kDeltaOrders[s]);
    const bool t = n.trans[0] != p.trans[0] || n.trans[1] != p.trans[1] || n.trans[2] != p.trans[2];
    w.put(t ? 1 : 0, 1);
    if (t) {
        for (int a = 0; a < 3; ++a) u[a] = zigzag(n.trans[a] - p.trans[a]);
        s = best_order(u, kDeltaOrders, bits);
        w.put(uint64_t(s), 2);
        for (int a = 0; a < 3; ++a) w.put_eg(u[a], kDeltaOrders[s]);
    }
    if (scaled) {
        w.put(n.scale != p.scale ? 1 : 0, 1);
        if (n.scale != p.scale) w.put_eg(zigzag(n.scale - p.scale), kScaleOrder);
    }
    return w.bits() - start;
}
}  // namespace

size_t write_predicted(const RecordInts& now, const RecordInts& pred, bool scaled, BitWriter& w) {
    return code_predicted(now, pred, scaled, w);
}

size_t predicted_bits(const RecordInts& now, const RecordInts& pred, bool scaled) {
    BitCounter c;
    return code_predicted(now, pred, scaled, c);
}

bool read_predicted(BitReader& in, const RecordInts& pred, bool scaled, RecordInts& out) {
    RecordInts r = pred;
    if (!scaled) r.scale = 0;
    uint64_t flag = 0, s = 0, u = 0;
    if (!in.get(1, flag)) return false;
    if (!flag) {
        if (!in.get(2, s)) return false;
        for (int a = 0; a < 3; ++a) {
            if (!in.get_eg(kDeltaOrders[s], u)) return false;
            r.rot[a] = int32_t(std::clamp<int64_t>(int64_t(r.rot[a]) + unzigzag(u), INT32_MIN, INT32_MAX));
        }
        if (!in.get(1, flag)) return false;
        if (flag) {
            if (!in.get(2, s)) return false;
            for (int a = 0; a < 3; ++a) {
                if (!in.get_eg(kDeltaOrders[s], u)) return false;
                r.trans[a] = int32_t(std::clamp<int64_t>(int64_t(r.trans[a]) + unzigzag(u), INT32_MIN, INT32_MAX));
            }
        }
        if (scaled) {
            if (!in.get(1, flag)) return false;
            if (flag) {
                if (!in.get_eg(kScaleOrder, u)) return false;
                r.scale = int32_t(std::clamp<int64_t>(int64_t(r.scale) + unzigzag(u), INT32_MIN, INT32_MAX));
            }
        }
    }
    int64_t n2 = 0;
    for (int a = 0; a < 3; ++a) {
        if (std::abs(int64_t(r.rot[a])) > kMaxRotInt || std::abs(int64_t(r.trans[a])) > kMaxTransInt) return false;
        n2 += int64_t(r.rot[a]) * r.rot[a];
    }
    if (n2 > int64_t(kMaxRotInt) * kMaxRotInt || std::abs(int64_t(r.scale)) > kMaxScaleInt) return false;
    r.has_trans = r.trans[0] || r.trans[1] || r.trans[2];
    r.has_scale = r.scale != 0;
    out = r;
    return true;
}

bool read_prefix(BitReader& in, RecordPrefix& out) {
    uint64_t d = 0, o = 0, age = 0, linear = 0;
    out = RecordPrefix{};
    if (!in.get(1, d)) return false;
    if (d) {
        out.kind = RecordPrefix::Chunk;
        return true;
    }
    if (!in.get(1, o)) return false;
    if (!o) return true;  // standalone
    if (!in.get(4, age) || !in.get(1, linear) || age == 0) return false;
    out.kind = RecordPrefix::Own;
    out.base = uint8_t(age | (linear ? kBaseLinear : 0));
    return true;
}

void write_prefix(const RecordPrefix& p, BitWriter& w) {
    if (p.kind == RecordPrefix::Chunk) {
        w.put(1, 1);
        return;
    }
    w.put(0, 1);
    w.put(p.kind == RecordPrefix::Own ? 1 : 0, 1);
    if (p.kind == RecordPrefix::Own) {
        w.put(p.base & 0xF, 4);
        w.put((p.base & kBaseLinear) ? 1 : 0, 1);
    }
}

bool skip_record(BitReader& in, bool scaled, bool with_base) {
    uint64_t flag = 0, s = 0, u = 0;
    if (with_base) {
        RecordPrefix prefix;
        if (!read_prefix(in, prefix)) return false;
        if (prefix.kind != RecordPrefix::Standalone) {  // predicted: the residuals' syntax (their sums are checked where the baseline is known)
            if (!in.get(1, flag)) return false;
            if (flag) return true;  // equal to the prediction
            for (int part = 0; part < 2; ++part) {
                if (part == 1) {
                    if (!in.get(1, flag)) return false;
                    if (!flag) break;
                }
                if (!in.get(2, s)) return false;
                for (int a = 0; a < 3; ++a)
                    if (!in.get_eg(kDeltaOrders[s], u)) return false;
            }
            if (scaled) {
                if (!in.get(1, flag)) return false;
                if (flag && !in.get_eg(kScaleOrder, u)) return false;
            }
            return true;
        }
    }
    RecordInts r;
    return read_record(in, scaled, r);
}

bool read_pose_records(std::span<const uint8_t> bytes, bool scaled, std::span<const RecordInts> pred, std::span<RecordInts> out) {
    if (!pred.empty() && pred.size() != out.size()) return false;
    BitReader in(bytes.data(), bytes.size());
    for (size_t i = 0; i < out.size(); ++i)
        if (!(pred.empty() ? read_record(in, scaled, out[i]) : read_predicted(in, pred[i], scaled, out[i]))) return false;
    const size_t rest = in.size() - in.at();
    uint64_t pad = 0;
    return rest < 8 && in.get(int(rest), pad) && pad == 0;
}

bool encode_pose(std::span<const BonePose> model, const RelativeFormat& f, std::vector<uint8_t>& bits,
                 std::span<uint32_t> offsets, std::span<BonePose> decoded, std::span<RecordInts> ints) {
    const size_t B = size_t(f.bone_count());
    if (model.size() < B || offsets.size() < B + 1 || decoded.size() < B || (!ints.empty() && ints.size() < B)) return false;
    const size_t base = bits.size() * 8;
    BitWriter w(bits);
    const BonePose identity;
    for (size_t b = 0; b < B; ++b) {
        const int p = f.parents[b];
        const BonePose& parent = p >= 0 ? decoded[size_t(p)] : identity;
        RecordInts r;
        if (!quantise_record(parent, model[b], int(b), f, r)) return false;
        offsets[b] = uint32_t(w.bits() - base);
        write_record(r, f.scaled, w);
        if (!ints.empty()) ints[b] = r;
        decoded[b] = compose_relative(parent, dequantise_record(r, int(b), f));
    }
    offsets[B] = uint32_t(w.bits() - base);
    return true;
}

void copy_bits(const uint8_t* src, size_t from, size_t count, BitWriter& w) { w.append_bits(src, from, count); }

// The output is grown once; the bits go through a 64-bit accumulator that
// is stored 8 bytes at a time (fewer at the end) and never loaded back: the
// only byte of the output read is the partial one the run starts in. (Loading
// 8 bytes of output that the previous window had just stored stalled on
// store forwarding: most of the packer's time at the full rate.)
void BitWriter::append_bits(const uint8_t* src, size_t from, size_t count) {
    if (count == 0) return;
    const size_t pos = out_.size() * 8 - size_t(free_), end = pos + count;
    const size_t bytes = (end + 7) / 8;
    if (bytes > out_.size()) out_.resize(bytes);
    free_ = int(bytes * 8 - end);
    const size_t src_end = (from + count + 7) / 8;
    uint8_t* dst = out_.data() + pos / 8;
    const size_t dst_len = bytes - pos / 8;  // bytes from dst on that this run writes
    int nacc = int(pos % 8);
    uint64_t acc = nacc ? uint64_t(dst[0]) & ((uint64_t(1) << nacc) - 1) : 0;
    size_t at_dst = 0;
    while (count > 0) {
        const int n = int(std::min<size_t>(56, count));
        const size_t at = from / 8;
        uint64_t v = 0;
        if (std::endian::native == std::endian::little && at + 8 <= src_end) std::memcpy(&v, src + at, 8);
        else  // the last bytes one by one, in registers (a short memcpy into v stalled the load of v)
            for (size_t i = 0; at + i < src_end && i < 8; ++i) v |= uint64_t(src[at + i]) << (8 * i);
        acc |= ((v >> (from % 8)) & ((uint64_t(1) << n) - 1)) << nacc;  // nacc < 8, n <= 56
        nacc += n;
        from += size_t(n);
        count -= size_t(n);
        const size_t whole = size_t(nacc) / 8;  // <= 7
        if constexpr (std::endian::native == std::endian::little) {
            if (at_dst + 8 <= dst_len) std::memcpy(dst + at_dst, &acc, 8);  // the bytes past `whole` are written again next
            else std::memcpy(dst + at_dst, &acc, std::min<size_t>(8, dst_len - at_dst));
        } else {
            for (size_t i = 0; i < 8 && at_dst + i < dst_len; ++i) dst[at_dst + i] = uint8_t(acc >> (8 * i));
        }
        at_dst += whole;
        acc >>= 8 * whole;
        nacc -= int(8 * whole);
    }
}

double relative_bound(const RelativeFormat& f, double bind_radius, double max_scale) {
    double pivot_radius = 0.0;
    for (const glm::vec3& j : f.pivots) pivot_radius = std::max(pivot_radius, double(glm::length(j)));
    const double angle = 2.0 * std::sqrt(3.0) * ROT_STEP * 1.01;  // 4 x half a step per component, |dp| <= sqrt3/2 step
    // A bone past 0 steps in its parent's units, t_step / s_ref: at most
    // t_step max_scale / s_ref in model units.
    const double trans = std::sqrt(3.0) * (kTransDeadZone + 0.5) * double(f.t_step) *
                         std::max(1.0, max_scale / double(f.s_ref));
    return (max_scale * angle * (bind_radius + pivot_radius) + trans) * 1.001 + 1e-6 * bind_radius;
}

std::vector<double> record_bits_per_bone(const Character& c, const ProgressiveSkin& s, const FrameSet& frames) {
    const size_t B = size_t(s.bone_count()), F = frames.frame_count();
    std::vector<double> bits(B, 0.0);
    if (B == 0 || F == 0 || frames.joint_count != int(c.joint_count())) return bits;
    std::vector<BonePose> model(F * B);
    std::vector<float> scales(F * B);
    RecordFormat box;
    box.t_min = glm::vec3(std::numeric_limits<float>::max());
    box.t_max = glm::vec3(-std::numeric_limits<float>::max());
    for (size_t f = 0; f < F; ++f)
        for (size_t b = 0; b < B; ++b) {
            BonePose& p = model[f * B + b];
            p = decompose(frames.frame(f)[size_t(s.order[b])]);
            box.t_min = glm::min(box.t_min, p.t);
            box.t_max = glm::max(box.t_max, p.t);
            scales[f * B + b] = p.s;
        }
    const ReferenceScale rs = reference_scale(scales);
    box.scale = rs.scale;
    box.scaled = rs.scaled;
    box.t_max = glm::max(box.t_max, box.t_min + glm::vec3(1e-3f));  // a box of some size
    const RelativeFormat fmt = relative_format(s, c, box);
    std::vector<uint8_t> scratch;
    std::vector<uint32_t> offsets(B + 1);
    std::vector<BonePose> decoded(B);
    std::vector<RecordInts> now(B), before(B);
    for (size_t f = 0; f < F; ++f) {
        scratch.clear();
        if (!encode_pose(std::span<const BonePose>(model.data() + f * B, B), fmt, scratch, offsets, decoded, now)) continue;
        if (f == 0) {
            for (size_t b = 0; b < B; ++b) bits[b] += double(offsets[b + 1] - offsets[b]);
        } else {
            for (size_t b = 0; b < B; ++b) {
                scratch.clear();
                BitWriter w(scratch);
                bits[b] += double(write_predicted(now[b], before[b], fmt.scaled, w));
            }
        }
        std::swap(now, before);
    }
    for (double& x : bits) x /= double(F);
    return bits;
}

}  // namespace progskin::net
