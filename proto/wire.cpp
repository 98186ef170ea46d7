// wire.cpp — see wire.h.
#include "wire.h"

#include <chrono>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>

#include "hash.h"

namespace progskin::net {

namespace {
// Little-endian uint32 (the control length prefix, the Frame datagram's header).
uint32_t get32(const uint8_t* p) { return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24; }
void put32(uint8_t* p, uint32_t v) {
    p[0] = uint8_t(v);
    p[1] = uint8_t(v >> 8);
    p[2] = uint8_t(v >> 16);
    p[3] = uint8_t(v >> 24);
}
}  // namespace

uint64_t content_hash(std::span<const uint8_t> bytes) { return fnv1a64(bytes); }

std::string hex64(uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

const wire::Control* verify_control(std::span<const uint8_t> body) {
    if (body.size() < 8 || body.size() > MAX_CONTROL_MESSAGE) return nullptr;
    flatbuffers::Verifier::Options opt;
    opt.max_depth = 16;
    opt.max_tables = 4096;
    flatbuffers::Verifier v(body.data(), body.size(), opt);
    if (!wire::VerifyControlBuffer(v)) return nullptr;
    const wire::Control* c = wire::GetControl(body.data());
    // The verifier accepts a union whose type is set but whose table is
    // absent, and types it does not know (forward compatibility): neither
    // is a message this version can read.
    if (c->body_type() == wire::ControlBody::NONE || c->body_type() > wire::ControlBody::MAX || !c->body()) return nullptr;
    return c;
}

const wire::Datagram* verify_datagram(std::span<const uint8_t> d) {
    if (d.size() < 8 || d.size() > MAX_DATAGRAM || is_frame_datagram(d)) return nullptr;
    flatbuffers::Verifier::Options opt;
    opt.max_depth = 8;
    opt.max_tables = 64;
    flatbuffers::Verifier v(d.data(), d.size(), opt);
    if (!wire::VerifyDatagramBuffer(v)) return nullptr;
    const wire::Datagram* g = wire::GetDatagram(d.data());
    // A Frame table is no longer a datagram (version 13: FrameDatagram).
    if (g->body_type() == wire::DatagramBody::NONE || g->body_type() == wire::DatagramBody::Frame ||
        g->body_type() > wire::DatagramBody::MAX || !g->body())
        return nullptr;
    return g;
}

wire::PoseAck FrameDatagram::pose_ack(size_t i) const {
    const uint8_t* p = acks.data() + i * POSE_ACK_BYTES;
    return wire::PoseAck(uint16_t(p[0] | p[1] << 8), get32(p + 2));
}

bool read_frame_datagram(std::span<const uint8_t> d, FrameDatagram& out) {
    if (d.size() < FRAME_HEADER_BYTES || d.size() > MAX_DATAGRAM) return false;
    const uint8_t flags = d[0];
    if (!(flags & FRAME_KIND) || (flags & ~(FRAME_KIND | FRAME_SAMPLED | FRAME_ACKS))) return false;
    out.seq = get32(&d[1]);
    out.send_time_us = get32(&d[5]);
    out.tick = get32(&d[9]);
    out.sampled = (flags & FRAME_SAMPLED) != 0;
    size_t at = FRAME_HEADER_BYTES;
    out.acks = {};
    if (flags & FRAME_ACKS) {
        if (at >= d.size()) return false;
        const size_t n = d[at++];
        if (n == 0 || n > size_t(MAX_SPAWNED) || (d.size() - at) / POSE_ACK_BYTES < n) return false;
        out.acks = d.subspan(at, n * POSE_ACK_BYTES);
        at += n * POSE_ACK_BYTES;
    }
    out.payload = d.subspan(at);
    return true;
}

void write_frame_datagram(uint32_t seq, uint32_t send_time_us, uint32_t tick, bool sampled,
                          std::span<const wire::PoseAck> acks, std::span<const uint8_t> payload, std::vector<uint8_t>& out) {
    if (acks.size() > size_t(MAX_SPAWNED))
        throw std::invalid_argument("write_frame_datagram: " + std::to_string(acks.size()) + " pose acks, at most " +
                                    std::to_string(MAX_SPAWNED));
    out.resize(FRAME_HEADER_BYTES + (acks.empty() ? 0 : 1 + acks.size() * POSE_ACK_BYTES) + payload.size());
    uint8_t* p = out.data();
    p[0] = uint8_t(FRAME_KIND | (sampled ? FRAME_SAMPLED : 0) | (acks.empty() ? 0 : FRAME_ACKS));
    put32(p + 1, seq);
    put32(p + 5, send_time_us);
    put32(p + 9, tick);
    p += FRAME_HEADER_BYTES;
    if (!acks.empty()) {
        *p++ = uint8_t(acks.size());
        for (const wire::PoseAck& a : acks) {
            p[0] = uint8_t(a.instance());
            p[1] = uint8_t(a.instance() >> 8);
            put32(p + 2, a.pose_seq());
            p += POSE_ACK_BYTES;
        }
    }
    if (!payload.empty()) std::memcpy(p, payload.data(), payload.size());
}

void frame_control(const flatbuffers::FlatBufferBuilder& fbb, std::vector<uint8_t>& out) {
    uint8_t len[4];
    put32(len, fbb.GetSize());
    out.insert(out.end(), len, len + 4);
    out.insert(out.end(), fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
}

bool read_length(std::span<const uint8_t> in, uint32_t& length) {
    if (in.size() < 4) return false;
    length = get32(in.data());
    return true;
}

double now_seconds() {
    using namespace std::chrono;
    return duration<double>(steady_clock::now().time_since_epoch()).count();
}

uint32_t now_us32() {
    using namespace std::chrono;
    return static_cast<uint32_t>(
        duration_cast<microseconds>(steady_clock::now().time_since_epoch()).count());
}

void build_goodbye(flatbuffers::FlatBufferBuilder& fbb, const std::string& reason) {
    auto r = fbb.CreateString(reason);
    auto g = wire::CreateGoodbye(fbb, r);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Goodbye, g.Union()), wire::ControlIdentifier());
}

void build_refuse(flatbuffers::FlatBufferBuilder& fbb, const std::string& reason) {
    auto r = fbb.CreateString(reason);
    auto g = wire::CreateRefuse(fbb, PROTOCOL_VERSION, r);
    fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Refuse, g.Union()), wire::ControlIdentifier());
}

void build_bind(flatbuffers::FlatBufferBuilder& fbb, uint64_t session_id, uint64_t token) {
    const std::vector<uint8_t> pad(64, 0);  // a Bind is always larger than its Challenge or BindAck
    auto p = fbb.CreateVector(pad);
    auto b = wire::CreateBind(fbb, session_id, token, p);
    fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Bind, b.Union()), wire::DatagramIdentifier());
}

void build_challenge_response(flatbuffers::FlatBufferBuilder& fbb, uint64_t session_id, uint64_t token,
                              std::span<const uint8_t> nonce) {
    const std::vector<uint8_t> pad(32, 0);
    auto n = fbb.CreateVector(nonce.data(), nonce.size());
    auto p = fbb.CreateVector(pad);
    auto r = wire::CreateChallengeResponse(fbb, session_id, token, n, p);
    fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::ChallengeResponse, r.Union()),
               wire::DatagramIdentifier());
}

}  // namespace progskin::net
