// net_attacker.h — a hostile player for the hardening tests and the soak
// (tests/test_net_hardening.cpp, tests/attack_main.cpp): an ordinary TLS
// client that verifies nothing, connecting from a chosen loopback address
// (127.0.0.N: "many addresses" on one machine), speaking the protocol by
// hand and sealing its own datagrams with the keys its Welcome gave it. It
// does what an honest client never does: Spawns of thousands of clips,
// characters posed from many sessions, Views of thousands of weights,
// asset pulls, handshakes it never finishes, reconnects whenever dropped.
// Synchronous, one thread drives any number of them (poll with timeouts).
#pragma once
#include <poll.h>
#include <sys/socket.h>

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "bone_codec.h"
#include "cli_args.h"
#include "crypto.h"
#include "bone_record.h"
#include "root_block.h"
#include "wire.h"

namespace progskin::net::testing {

// The port of a --server 127.0.0.1:PORT value: the load tools (progskin-attack,
// progskin-flood) only ever aim at this machine. `why` ends the message.
inline uint16_t loopback_port(const std::string& key, const std::string& v, const char* why) {
    const auto colon = v.rfind(':');
    if (colon == std::string::npos || v.substr(0, colon) != "127.0.0.1")
        throw std::invalid_argument(key + " must be 127.0.0.1:PORT (" + why + ")");
    return cli::to_port(key, v.substr(colon + 1));
}

class Attacker {
public:
    // A catalogue entry as the Welcome announced it (what a Pose needs).
    struct AssetInfo {
        uint64_t id = 0, size = 0;
        int bones = 0;
        RecordFormat format;
    };

    Attacker(std::string source_ip, uint16_t tcp_port, uint16_t udp_port, bool tls = true)
        : ip_(std::move(source_ip)), tcp_port_(tcp_port), udp_port_(udp_port), tls_on_(tls), ctx_(asio::ssl::context::tls_client) {
        ctx_.set_verify_mode(asio::ssl::verify_none);  // an ordinary client that trusts anything
    }
    ~Attacker() { disconnect(); }
    Attacker(const Attacker&) = delete;
    Attacker& operator=(const Attacker&) = delete;

    // Connects from source_ip, TLS handshake, Hello; true once the Welcome
    // came (keys, ids, catalogue), false when refused, closed or timed out.
    bool join(int timeout_ms = 3000, const std::string& name = "attacker") {
        disconnect();
        try {
            connect_tcp();
            if (tls_on_) {
                tls_ = std::make_unique<asio::ssl::stream<asio::ip::tcp::socket&>>(*sock_, ctx_);
                set_timeouts(timeout_ms);
                tls_->handshake(asio::ssl::stream_base::client);
            }
            flatbuffers::FlatBufferBuilder fbb;
            auto n = fbb.CreateString(name);
            auto h = wire::CreateHello(fbb, PROTOCOL_VERSION, n, 0, 0);
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
            send_control(fbb);
            std::vector<uint8_t> body;
            const auto end = clock::now() + std::chrono::milliseconds(timeout_ms);
            while (clock::now() < end) {
                if (!read_control(body, 50)) {
                    if (closed_) return false;
                    continue;
                }
                const wire::Control* c = verify_control(body);
                if (!c) return false;
                if (c->body_type() == wire::ControlBody::Welcome) return on_welcome(*c->body_as_Welcome());
                if (c->body_type() == wire::ControlBody::Refuse) {
                    refused_ = c->body_as_Refuse()->reason() ? c->body_as_Refuse()->reason()->str() : "";
                    return false;
                }
            }
        } catch (const std::exception& e) {
            error_ = e.what();
        }
        return false;
    }

    // Connects and sends `bytes` raw (a TLS ClientHello never finished, or
    // nothing at all), leaving the connection open: a handshake in progress.
    bool open_idle(const std::vector<uint8_t>& bytes = {}) {
        disconnect();
        try {
            connect_tcp();
            if (!bytes.empty()) asio::write(*sock_, asio::buffer(bytes));
            return true;
        } catch (const std::exception& e) {
            error_ = e.what();
            return false;
        }
    }

    void disconnect() {
        asio::error_code ig;
        if (sock_) sock_->close(ig);
        if (udp_) udp_->close(ig);
        tls_.reset();
        sock_.reset();
        udp_.reset();
        welcomed_ = bound_ = closed_ = false;
        rx_.clear();
        spawned_.clear();
        sealer_.reset();
        opener_.reset();
    }

    // Whether the server closed the control connection (reads and drops what waits).
    bool server_closed() {
        std::vector<uint8_t> body;
        while (!closed_ && read_control(body, 0)) on_message(body);
        return closed_;
    }

    void send_control(const flatbuffers::FlatBufferBuilder& fbb) {
        std::vector<uint8_t> m;
        frame_control(fbb, m);
        asio::error_code ec;
        if (tls_) asio::write(*tls_, asio::buffer(m), ec);
        else asio::write(*sock_, asio::buffer(m), ec);
        if (ec) closed_ = true;
    }

    // Bind, Challenge, ChallengeResponse, BindAck over sealed datagrams.
    bool bind(int timeout_ms = 2000) {
        open_udp();
        const auto end = clock::now() + std::chrono::milliseconds(timeout_ms);
        while (clock::now() < end && !bound_) {
            flatbuffers::FlatBufferBuilder b;
            build_bind(b, session_, token_);
            send_datagram(b);
            const auto until = clock::now() + std::chrono::milliseconds(200);
            while (clock::now() < until && !bound_) {
                const Got got = receive(20);
                if (got.frame) {
                    bound_ = true;
                    continue;
                }
                const wire::Datagram* d = got.other;
                if (!d) continue;
                if (d->body_type() == wire::DatagramBody::Challenge && d->body_as_Challenge()->nonce()) {
                    const auto* n = d->body_as_Challenge()->nonce();
                    const std::vector<uint8_t> nonce(n->begin(), n->end());
                    flatbuffers::FlatBufferBuilder r;
                    build_challenge_response(r, session_, token_, nonce);
                    send_datagram(r);
                } else if (d->body_type() == wire::DatagramBody::BindAck) {
                    bound_ = true;
                }
            }
        }
        return bound_;
    }

    // Reads the datagrams waiting (for up to ms) and acknowledges the newest
    // (all 32 before it too): the server sees a client that receives everything.
    size_t pump_and_ack(int ms = 0) {
        size_t n = 0;
        const auto end = clock::now() + std::chrono::milliseconds(ms);
        do {
            while (receive(0)) ++n;
        } while (clock::now() < end && (std::this_thread::sleep_for(std::chrono::milliseconds(2)), true));
        ack();
        frames_ += n;
        return n;
    }
    // Waits up to ms for a datagram, then reads every one waiting; returns
    // the Frames among them (no Ack sent: ack()).
    size_t read_frames(int ms) {
        size_t n = 0;
        for (Got d = receive(ms); d; d = receive(0))
            if (d.frame) ++n;
        frames_ += n;
        return n;
    }
    // Acknowledges the newest Frame received (and the 32 before it).
    void ack() {
        if (!bound_) return;
        flatbuffers::FlatBufferBuilder a;
        auto ack = wire::CreateAck(a, session_, token_, newest_seq_, 0xffffffffu, newest_send_us_, 0);
        a.Finish(wire::CreateDatagram(a, 0, now_us32(), wire::DatagramBody::Ack, ack.Union()), wire::DatagramIdentifier());
        send_datagram(a);
    }

    // A Spawn of `asset` announcing `clips` (any count, repeats included);
    // with wait_ms > 0 waits for Spawned: the instance, or -1 when refused
    // (reason in refused()) or nothing came.
    int spawn(int asset, const std::vector<int32_t>& clips, int wait_ms = 2000) {
        flatbuffers::FlatBufferBuilder fbb(clips.size() * 4 + 256);
        auto vc = fbb.CreateVector(clips);
        wire::Vec3 pos(float(spawned_.size()), 0, 3);
        wire::DVec3 wc(0, 0, 0);
        auto s = wire::CreateSpawn(fbb, ++request_, uint16_t(asset), vc, false, 1.0f, 0, &wc, 0, 0, &pos);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Spawn, s.Union()), wire::ControlIdentifier());
        send_control(fbb);
        if (wait_ms <= 0) return -1;
        const uint32_t want = request_;
        std::vector<uint8_t> body;
        const auto end = clock::now() + std::chrono::milliseconds(wait_ms);
        while (clock::now() < end && !closed_) {
            if (!read_control(body, 20)) continue;
            const wire::Control* c = verify_control(body);
            if (c && c->body_type() == wire::ControlBody::Spawned && c->body_as_Spawned()->request() == want) {
                const wire::Spawned* m = c->body_as_Spawned();
                if (!m->ok()) {
                    refused_ = m->reason() ? m->reason()->str() : "";
                    return -1;
                }
                spawned_.push_back({m->instance(), asset});
                return m->instance();
            }
            on_message(body);
        }
        return -1;
    }

    // One valid Pose (identity bones, a root in front of the camera) of each
    // character this session spawned.
    void pose_all() {
        for (const auto& [instance, asset] : spawned_) pose(instance, asset);
    }
    // One Pose datagram with the given record bits, count, first bone and
    // baseline (hostile ones: tests/test_net_hardening.cpp).
    // root_block: Pose.root as given (default: an absolute root block).
    void pose_raw(int instance, const std::vector<uint8_t>& records, int count, int first = 0, uint32_t base_seq = 0,
                  std::vector<uint8_t> root = {}) {
        if (root.empty()) {
            std::array<uint8_t, ROOT_BYTES> abs{};
            RootPose r;
            r.position = {double(instance % 64), 0.0, 3.0};
            encode_root(r, abs.data());
            write_root(abs.data(), 0, nullptr, nullptr, root);  // an absolute root block (root_block.h)
        }
        flatbuffers::FlatBufferBuilder fbb;
        auto rv = fbb.CreateVector(root.data(), root.size());
        auto rc = fbb.CreateVector(records);
        auto p = wire::CreatePose(fbb, session_, token_, uint16_t(instance), ++pose_seq_, 0, uint8_t(first), rv, rc, 0,
                                  uint16_t(count), base_seq);
        fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Pose, p.Union()), wire::DatagramIdentifier());
        send_datagram(fbb);
    }
    uint32_t pose_seq() const { return pose_seq_; }
    void set_pose_seq(uint32_t s) { pose_seq_ = s; }  // the next Pose goes as s + 1 (reordering)
    int bones(int asset) const { return assets_[size_t(asset)].bones; }

    void pose(int instance, int asset) {
        const AssetInfo& a = assets_[size_t(asset)];
        // Every bone at the middle of the box, unturned: bone 0 translated
        // there from the root, every other bone the identity relative to its
        // parent (all-zero integers: bone_record.h), standalone records.
        const float step = chain_format(1, a.format).t_step;
        const glm::vec3 mid = 0.5f * (a.format.t_min + a.format.t_max);
        RecordInts r0;
        for (int k = 0; k < 3; ++k) r0.trans[k] = int32_t(std::lround(mid[k] / step));
        r0.has_trans = true;
        std::vector<uint8_t> records;
        BitWriter w(records);
        write_record(r0, a.format.scaled, w);
        for (int b = 1; b < a.bones; ++b) write_record(RecordInts{}, a.format.scaled, w);
        std::array<uint8_t, ROOT_BYTES> abs{};
        RootPose r;
        r.position = {double(instance % 64), 0.0, 3.0};
        r.source_us = now_us32();
        encode_root(r, abs.data());
        std::vector<uint8_t> root;  // an absolute root block (root_block.h)
        write_root(abs.data(), 0, nullptr, nullptr, root);
        ++pose_seq_;
        flatbuffers::FlatBufferBuilder fbb;
        auto rv = fbb.CreateVector(root.data(), root.size());
        auto rc = fbb.CreateVector(records);
        auto p = wire::CreatePose(fbb, session_, token_, uint16_t(instance), pose_seq_, 0, 0, rv, rc, 0, uint16_t(a.bones), 0);
        fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Pose, p.Union()), wire::DatagramIdentifier());
        send_datagram(fbb);
    }

    // A View naming `count` instances (ids 0..count-1) with weight 1.
    void view(size_t count) {
        std::vector<wire::InstanceWeight> ws;
        for (size_t i = 0; i < count; ++i) ws.emplace_back(uint16_t(i % 65535), 1.0f);
        flatbuffers::FlatBufferBuilder fbb(count * 8 + 256);
        auto vw = fbb.CreateVectorOfStructs(ws);
        wire::ViewBuilder vb(fbb);
        vb.add_weights(vw);
        auto v = vb.Finish();
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::View, v.Union()), wire::ControlIdentifier());
        send_control(fbb);
    }

    // Asks for a whole asset in chunks and reads the answers; returns the
    // asset bytes received before the server stopped answering or closed.
    uint64_t pull_asset(int asset, int timeout_ms = 3000) {
        const AssetInfo& a = assets_[size_t(asset)];
        uint64_t got = 0;
        for (uint64_t off = 0; off < a.size && !closed_; off += MAX_ASSET_CHUNK) {
            flatbuffers::FlatBufferBuilder fbb;
            auto r = wire::CreateAssetRequest(fbb, a.id, off, uint32_t(MAX_ASSET_CHUNK));
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
            send_control(fbb);
        }
        std::vector<uint8_t> body;
        const auto end = clock::now() + std::chrono::milliseconds(timeout_ms);
        while (clock::now() < end && got < a.size && !closed_) {
            if (!read_control(body, 20)) continue;
            const wire::Control* c = verify_control(body);
            if (c && c->body_type() == wire::ControlBody::AssetChunk && c->body_as_AssetChunk()->data())
                got += c->body_as_AssetChunk()->data()->size();
        }
        return got;
    }

    bool welcomed() const { return welcomed_; }
    bool bound() const { return bound_; }
    const std::string& refused() const { return refused_; }
    const std::string& error() const { return error_; }
    const std::vector<AssetInfo>& assets() const { return assets_; }
    size_t characters() const { return spawned_.size(); }
    uint64_t frames() const { return frames_; }

private:
    using clock = std::chrono::steady_clock;

    void connect_tcp() {
        sock_ = std::make_unique<asio::ip::tcp::socket>(io_);
        sock_->open(asio::ip::tcp::v4());
        sock_->bind({asio::ip::make_address(ip_), 0});
        sock_->connect({asio::ip::make_address("127.0.0.1"), tcp_port_});
    }
    void set_timeouts(int ms) {
        timeval tv{ms / 1000, (ms % 1000) * 1000};
        ::setsockopt(sock_->native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    }
    void open_udp() {
        if (udp_) return;
        udp_ = std::make_unique<asio::ip::udp::socket>(io_);
        udp_->open(asio::ip::udp::v4());
        udp_->bind({asio::ip::make_address(ip_), 0});
        udp_->non_blocking(true);
    }

    bool on_welcome(const wire::Welcome& w) {
        session_ = w.session_id();
        token_ = w.udp_token();
        if (w.udp_port()) udp_port_ = w.udp_port();
        assets_.clear();
        if (w.assets())
            for (const wire::Asset* a : *w.assets()) {
                AssetInfo i;
                i.id = a->asset_id();
                i.size = a->size();
                i.bones = a->bone_count();
                i.format.scaled = a->scaled();
                if (a->t_min()) i.format.t_min = {a->t_min()->x(), a->t_min()->y(), a->t_min()->z()};
                if (a->t_max()) i.format.t_max = {a->t_max()->x(), a->t_max()->y(), a->t_max()->z()};
                assets_.push_back(i);
            }
        if (const auto* k = w.datagram_keys(); k && k->size() == 2 * crypto::KEY_BYTES) {
            crypto::Key down{}, up{};
            std::copy(k->begin(), k->begin() + crypto::KEY_BYTES, down.begin());
            std::copy(k->begin() + crypto::KEY_BYTES, k->end(), up.begin());
            sealer_ = std::make_unique<crypto::Sealer>(up);
            opener_ = std::make_unique<crypto::Opener>(down);
        }
        // No more blocking reads from here on: every read polls first.
        timeval tv{0, 0};
        ::setsockopt(sock_->native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
        welcomed_ = true;
        return true;
    }

    void on_message(const std::vector<uint8_t>&) {}  // InstanceAdded and the like: read, ignored

    // One control message within ms (0: only what is already there).
    bool read_control(std::vector<uint8_t>& body, int ms) {
        if (!sock_ || closed_) return false;
        const auto end = clock::now() + std::chrono::milliseconds(ms);
        for (;;) {
            uint32_t n = 0;
            if (read_length(rx_, n) && rx_.size() >= 4 + size_t(n)) {
                body.assign(rx_.begin() + 4, rx_.begin() + 4 + long(n));
                rx_.erase(rx_.begin(), rx_.begin() + 4 + long(n));
                return true;
            }
            // What is already here first, without blocking: asio's TLS stream
            // may hold whole records it read with an earlier one (neither the
            // socket nor SSL_pending shows them), and a readable socket may
            // carry no application data (a TLS 1.3 session ticket).
            uint8_t buf[16384];
            asio::error_code ec, ig;
            sock_->non_blocking(true, ig);
            const size_t got = tls_ ? tls_->read_some(asio::buffer(buf), ec) : sock_->read_some(asio::buffer(buf), ec);
            sock_->non_blocking(false, ig);
            if (!ec) {
                rx_.insert(rx_.end(), buf, buf + got);
                continue;
            }
            if (ec != asio::error::would_block && ec != asio::error::try_again) {
                closed_ = true;
                return false;
            }
            const int left = int(std::chrono::duration_cast<std::chrono::milliseconds>(end - clock::now()).count());
            pollfd p{sock_->native_handle(), POLLIN, 0};
            if (left <= 0 || ::poll(&p, 1, left) <= 0) return false;
        }
    }

    void send_datagram(const flatbuffers::FlatBufferBuilder& fbb) {
        open_udp();
        const asio::ip::udp::endpoint to(asio::ip::make_address("127.0.0.1"), udp_port_);
        asio::error_code ec;
        if (sealer_) {
            crypto::seal_datagram(*sealer_, session_, PROTOCOL_VERSION, {fbb.GetBufferPointer(), fbb.GetSize()}, sealed_);
            udp_->send_to(asio::buffer(sealed_), to, 0, ec);
        } else {
            udp_->send_to(asio::buffer(fbb.GetBufferPointer(), fbb.GetSize()), to, 0, ec);
        }
    }

    // One datagram received: a Frame datagram (its seq noted) or another,
    // verified; neither when nothing came or it did not open or verify.
    struct Got {
        bool frame = false;
        const wire::Datagram* other = nullptr;
        explicit operator bool() const { return frame || other; }
    };
    // One datagram within ms, opened and read.
    Got receive(int ms) {
        if (!udp_) return {};
        pollfd p{udp_->native_handle(), POLLIN, 0};
        if (::poll(&p, 1, ms) <= 0) return {};
        uint8_t buf[2048];
        const ssize_t r = ::recv(udp_->native_handle(), buf, sizeof buf, MSG_DONTWAIT);
        if (r <= 0) return {};
        std::span<const uint8_t> bytes(buf, size_t(r));
        if (opener_) {
            uint64_t seq = 0;
            if (crypto::open_datagram(*opener_, session_, PROTOCOL_VERSION, bytes, plain_, seq) != crypto::OpenResult::ok) return {};
        } else {
            plain_.assign(bytes.begin(), bytes.end());
        }
        FrameDatagram f;
        if (read_frame_datagram(plain_, f)) {
            bound_ = true;
            newest_seq_ = f.seq;
            newest_send_us_ = f.send_time_us;
            return {true, nullptr};
        }
        return {false, verify_datagram(plain_)};
    }

    std::string ip_;
    uint16_t tcp_port_, udp_port_;
    bool tls_on_;
    asio::io_context io_;
    asio::ssl::context ctx_;
    std::unique_ptr<asio::ip::tcp::socket> sock_;
    std::unique_ptr<asio::ssl::stream<asio::ip::tcp::socket&>> tls_;
    std::unique_ptr<asio::ip::udp::socket> udp_;
    std::unique_ptr<crypto::Sealer> sealer_;
    std::unique_ptr<crypto::Opener> opener_;
    std::vector<uint8_t> rx_, sealed_, plain_;
    uint64_t session_ = 0, token_ = 0;
    bool welcomed_ = false, bound_ = false, closed_ = false;
    std::string refused_, error_;
    std::vector<AssetInfo> assets_;
    std::vector<std::pair<int, int>> spawned_;  // instance, asset
    uint32_t request_ = 0, pose_seq_ = 0, newest_seq_ = 0, newest_send_us_ = 0;
    uint64_t frames_ = 0;
};

}  // namespace progskin::net::testing
