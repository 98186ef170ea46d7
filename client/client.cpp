// client.cpp — see client.h. Session: TCP connect -> Hello -> Welcome (or
// Refuse) -> InstanceAdded/Removed at any time -> AssetRequest/AssetChunk for
// uncached assets -> View -> UDP Bind until BindAck or a Frame -> frames +
// Acks (+ Stats each second), Spawn/Spawned/Despawn and Pose datagrams for
// the player's own characters -> Goodbye. Everything is driven by update():
// one io_context polled, non-blocking sockets, no thread.
//
// With ClientConfig::tls the control channel is TLS from the first byte
// (asio::ssl::stream over the TCP socket, async handshake in the same
// io_context); the certificate is checked against ca_file (chain + host
// name) and/or pin_sha256 (SHA-256 of its DER) before Hello is sent. When the
// Welcome carries datagram keys (64 bytes: server->client, client->server),
// every datagram sent is sealed and every one received must open
// (proto/crypto.h); anything else is dropped and counted as malformed.
#include "client.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <asio.hpp>
#include <asio/ssl.hpp>
#include <cctype>
#include <cmath>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include <openssl/evp.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <openssl/x509_vfy.h>

#include "asset_cache.h"
#include "crypto.h"
#include "errors.h"
#include "frame_reader.h"
#include "error_metric.h"
#include "gltf_import.h"
#include "wire.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;
namespace fs = std::filesystem;

std::string read_instance(const wire::Instance& in, size_t catalogue_size, RemoteCharacter& rc) {
    if (in.asset() >= catalogue_size) return "asset " + std::to_string(in.asset()) + " is not in the catalogue";
    rc = RemoteCharacter{};
    rc.instance = in.id();
    if (in.clips())
        for (int c : *in.clips()) {
            if (c < 0) return "negative clip index";
            rc.clip.selection.clips.push_back(c);
        }
    rc.clip.selection.start = in.clip_start();
    rc.clip.selection.end = in.clip_end();
    rc.clip.time_offset = in.time_offset();
    rc.clip.speed = in.speed();
    rc.clip.once = rc.once = in.once();
    auto finite = [](double v) { return std::isfinite(v); };
    if (!finite(in.clip_start()) || !finite(in.clip_end()) || in.clip_end() < in.clip_start() || !finite(in.time_offset()) ||
        !finite(in.speed()))
        return "clip times not finite or reversed";
    if (in.position()) {
        rc.root.position = glm::dvec3(in.position()->x(), in.position()->y(), in.position()->z());
        if (!finite(rc.root.position.x) || !finite(rc.root.position.y) || !finite(rc.root.position.z)) return "position not finite";
    }
    if (in.rotation()) {
        const glm::quat q(in.rotation()->w(), in.rotation()->x(), in.rotation()->y(), in.rotation()->z());
        const float len = glm::length(q);
        if (!std::isfinite(len) || std::fabs(len - 1.0f) > 1e-3f) return "rotation is not a unit quaternion";
        rc.root.rotation = q / len;
    }
    rc.publisher.published = in.published();
    rc.publisher.start_us = in.publisher_start_us();
    if (in.walk_center()) rc.publisher.walk_center = {in.walk_center()->x(), in.walk_center()->y(), in.walk_center()->z()};
    rc.publisher.walk_radius = in.walk_radius();
    rc.publisher.walk_speed = in.walk_speed();
    if (!finite(rc.publisher.walk_center.x) || !finite(rc.publisher.walk_center.y) || !finite(rc.publisher.walk_center.z) ||
        !finite(rc.publisher.walk_radius) || !finite(rc.publisher.walk_speed))
        return "walk not finite";
    return {};
}

RootPose walk_root(const glm::dvec3& center, double radius, double speed, double t) {
    RootPose r;
    r.position = center;
    if (!(radius > 0) || !(speed > 0)) return r;
    const double a = speed * t / radius;  // radians around the circle
    r.position += glm::dvec3(radius * std::cos(a), 0.0, radius * std::sin(a));
    // Facing along the circle: +Z turned to the tangent (-sin a, 0, cos a).
    r.rotation = glm::angleAxis(float(-a), glm::vec3(0.0f, 1.0f, 0.0f));
    return r;
}

namespace {

// Receives one datagram with the kernel's arrival time (SO_TIMESTAMPNS), so
// the per-second rate bins reflect the wire even when the game loop is late.
// Returns -1 when nothing is pending; t is on the now_seconds() clock.
ssize_t receive_stamped(udp::socket& s, uint8_t* buf, size_t cap, udp::endpoint& from, double& t) {
    sockaddr_storage addr{};
    iovec iov{buf, cap};
    alignas(cmsghdr) char control[128];
    msghdr msg{};
    msg.msg_name = &addr;
    msg.msg_namelen = sizeof addr;
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    ssize_t n = ::recvmsg(s.native_handle(), &msg, MSG_DONTWAIT);
    if (n < 0) return -1;
    t = now_seconds();
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            timespec ts;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            timespec rt;
            ::clock_gettime(CLOCK_REALTIME, &rt);
            double age = double(rt.tv_sec - ts.tv_sec) + 1e-9 * double(rt.tv_nsec - ts.tv_nsec);
            if (age > 0 && age < 5.0) t -= age;
        }
    }
    if (addr.ss_family == AF_INET) {
        const auto* in = reinterpret_cast<const sockaddr_in*>(&addr);
        from = udp::endpoint(asio::ip::address_v4(ntohl(in->sin_addr.s_addr)), ntohs(in->sin_port));
    }
    if (msg.msg_flags & MSG_TRUNC) return ssize_t(cap);  // cap > MAX_DATAGRAM: dropped as malformed
    return n;
}

}  // namespace

struct Client::Impl {
    ClientConfig cfg;
    asio::io_context io;
    tcp::socket tcp_sock{io};
    // TLS (cfg.tls): the context outlives the stream, the stream runs over tcp_sock.
    std::unique_ptr<asio::ssl::context> ssl_ctx;
    std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;
    bool tls_started = false;      // TCP connected, handshake under way
    std::string tls_verify_error;  // the first reason the chain or host name was refused
    std::string pin;               // cfg.pin_sha256 normalised: 64 lower-case hex digits, or empty
    // Sealed datagrams (Welcome.datagram_keys): set once keys arrive over TLS.
    std::unique_ptr<crypto::Sealer> sealer;
    std::unique_ptr<crypto::Opener> opener;
    std::vector<uint8_t> sealed_buf, opened_buf;
    udp::socket udp_sock{io};
    udp::endpoint server_udp;
    std::string host;
    uint16_t port = 0;
    ClientState state = ClientState::Idle;
    std::string error;
    std::vector<ClientEvent> events;
    double started = 0;   // connect() time
    bool tcp_connected = false, welcomed = false, bound = false;

    // control channel
    std::vector<uint8_t> rx, rx_chunk = std::vector<uint8_t>(65536);
    bool reading = false;
    // Control output: messages queued while one batch is being written. Both
    // buffers keep their capacity, so steady sending allocates nothing.
    std::vector<uint8_t> tx_pending, tx_inflight;
    std::vector<uint8_t> rx_body;             // one received control message body
    flatbuffers::FlatBufferBuilder ctl_fbb{256};  // Stats, the one periodic control message
    bool writing = false;

    // session
    uint64_t session = 0, udp_token = 0;
    double tick_rate = 30;
    uint16_t udp_port = 0;
    std::string cache;
    struct CatalogueEntry {
        std::string name;
        uint64_t id = 0, size = 0;
        std::vector<uint8_t> welcome;  // the Asset table's bytes (a copy of Welcome, kept to load the skin)
        std::vector<uint8_t> bytes;    // downloaded so far (grows with what arrives)
        uint64_t requested = 0;
        int in_flight = 0;
        bool ready = false;
    };
    std::vector<uint8_t> welcome_body;  // kept: catalogue entries point into it
    const wire::Welcome* welcome = nullptr;
    std::vector<CatalogueEntry> catalogue;
    std::vector<std::shared_ptr<ClientAsset>> assets;
    std::vector<std::string> asset_names;
    size_t downloading = 0;  // index of the asset being downloaded
    double last_progress = 0;  // last asset chunk (or the start of the download)

    // remote characters, by instance id
    struct Remote {
        RemoteCharacter rc;
        std::unique_ptr<InstanceView> view;
        int asset = -1;
        bool active = false, announced = false;  // announced: CharacterAdded raised (asset ready)
    };
    std::vector<Remote> remotes;          // indexed by instance id
    // characters(): one entry per character with a view, in instance order;
    // rebuilt when characters come or go, updated in place every update
    // (no allocation per frame).
    std::vector<RemoteCharacter> shown;
    std::vector<int> shown_ids;
    bool shown_dirty = true;

    // frame stream
    alignas(16) uint8_t buf[2048];
    bool any_frame = false;
    uint32_t ack = 0, ack_bits = 0, min_seq = 0, max_seq = 0, ack_echo = 0;
    double ack_arrival = 0, last_ack_sent = 0, next_bind = 0, next_stats = 0, last_datagram = 0;
    uint64_t unique = 0, since_ack = 0;
    double t_first = 0, tick_offset = -1e300;
    ClientStats st;
    // display clock (see update)
    double base_delay = 3, max_delay = 18, delay_ticks = 3, needed_delay = 0, last_display_time = 0;
    double display_tick = 0;

    // view and cap
    ViewSpec view;
    bool view_set = false, view_dirty = false;
    double cap = 0;

    // own characters
    struct Own {
        int handle = 0;
        int instance = -1;
        int asset = 0;
        uint32_t request = 0, pose_seq = 0;
        uint8_t epoch = 0;
        bool refused = false, gone = false;
    };
    std::vector<Own> own;
    uint32_t next_request = 1;
    std::vector<uint8_t> pose_records;
    std::vector<int16_t> pose_morphs;
    flatbuffers::FlatBufferBuilder fbb{1400};

    explicit Impl(ClientConfig c) : cfg(std::move(c)) {
        base_delay = max_delay = delay_ticks = 0;
        cap = cfg.max_kbps;
    }

    void raise(ClientEvent::Type t, int instance = -1, int asset = -1, int handle = -1, std::string text = {}) {
        events.push_back({t, instance, asset, handle, std::move(text)});
    }

    void fail(const std::string& why) {
        if (state == ClientState::Failed || state == ClientState::Closed) return;
        state = ClientState::Failed;
        error = why;
        raise(ClientEvent::Type::Failed, -1, -1, -1, why);
        asio::error_code ig;
        tcp_sock.close(ig);
        udp_sock.close(ig);
    }

    // ------------------------------------------------------------ control --
    void send(const flatbuffers::FlatBufferBuilder& b) {
        if (!tcp_connected || state == ClientState::Failed || state == ClientState::Closed) return;
        frame_control(b, tx_pending);  // appends
        write_next();
    }
    void write_next() {
        if (writing || tx_pending.empty()) return;
        writing = true;
        std::swap(tx_pending, tx_inflight);
        auto done = [this](asio::error_code ec, size_t) {
            writing = false;
            if (ec) return fail("control channel: " + ec.message());
            tx_inflight.clear();
            write_next();
        };
        if (tls) asio::async_write(*tls, asio::buffer(tx_inflight), done);
        else asio::async_write(tcp_sock, asio::buffer(tx_inflight), done);
    }
    void read_more() {
        if (reading) return;
        reading = true;
        auto done = [this](asio::error_code ec, size_t n) {
            reading = false;
            if (ec) {
                if (state == ClientState::Closed || state == ClientState::Failed) return;
                if (ec == asio::error::eof || ec == asio::ssl::error::stream_truncated)
                    return fail(welcomed || tls ? "the server closed the control connection"
                                                : "the server closed the control connection before its Welcome "
                                                  "(does it expect TLS?)");
                return fail("control channel: " + ec.message());
            }
            rx.insert(rx.end(), rx_chunk.begin(), rx_chunk.begin() + long(n));
            drain_control();
            if (state != ClientState::Failed && state != ClientState::Closed) read_more();
        };
        if (tls) tls->async_read_some(asio::buffer(rx_chunk), done);
        else tcp_sock.async_read_some(asio::buffer(rx_chunk), done);
    }

    // ---------------------------------------------------------------- TLS --
    // Sets up the TLS context before connecting; false (and Failed) when the
    // configuration trusts nothing or the CA file cannot be read.
    bool setup_tls() {
        if (!cfg.pin_sha256.empty()) {
            for (char ch : cfg.pin_sha256)
                if (ch != ':') pin.push_back(char(std::tolower(static_cast<unsigned char>(ch))));
            if (pin.size() != 64 || pin.find_first_not_of("0123456789abcdef") != std::string::npos) {
                fail("the pinned certificate fingerprint must be 64 hex digits (SHA-256), not \"" + cfg.pin_sha256 + "\"");
                return false;
            }
        }
        if (cfg.ca_file.empty() && pin.empty() && !cfg.insecure) {
            fail("TLS needs a way to trust the server's certificate: a CA file, a pinned SHA-256 fingerprint, "
                 "or insecure mode (development only)");
            return false;
        }
        ssl_ctx = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_client);
        ssl_ctx->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 |
                             asio::ssl::context::no_sslv3 | asio::ssl::context::no_tlsv1 | asio::ssl::context::no_tlsv1_1);
        asio::error_code ec;
        if (!cfg.ca_file.empty()) {
            ssl_ctx->load_verify_file(cfg.ca_file, ec);
            if (ec) {
                fail("cannot read the CA file " + cfg.ca_file + ": " + ec.message());
                return false;
            }
            ssl_ctx->set_verify_mode(asio::ssl::verify_peer);
        } else {
            ssl_ctx->set_verify_mode(asio::ssl::verify_none);  // pinned or insecure: checked after the handshake
        }
        tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(tcp_sock, *ssl_ctx);
        if (!cfg.ca_file.empty()) {
            asio::ssl::host_name_verification by_name(host);
            tls->set_verify_callback([this, by_name](bool preverified, asio::ssl::verify_context& vc) {
                X509_STORE_CTX* x = vc.native_handle();
                if (!preverified) {
                    if (tls_verify_error.empty()) tls_verify_error = X509_verify_cert_error_string(X509_STORE_CTX_get_error(x));
                    return false;
                }
                if (!by_name(preverified, vc)) {
                    if (tls_verify_error.empty()) tls_verify_error = "the certificate is not for " + host;
                    return false;
                }
                return true;
            });
        }
        // SNI for servers hosting several names (not for a numeric address).
        asio::error_code not_ip;
        asio::ip::make_address(host, not_ip);
        if (not_ip) SSL_set_tlsext_host_name(tls->native_handle(), host.c_str());
        return true;
    }

    // After the handshake: the pinned fingerprint, when there is one.
    bool check_pin() {
        if (pin.empty()) return true;
        X509* cert = SSL_get1_peer_certificate(tls->native_handle());
        if (!cert) {
            fail("the server sent no certificate");
            return false;
        }
        unsigned char md[EVP_MAX_MD_SIZE];
        unsigned int len = 0;
        const int ok = X509_digest(cert, EVP_sha256(), md, &len);
        X509_free(cert);
        if (!ok) {
            fail("cannot compute the server certificate's fingerprint");
            return false;
        }
        const std::string got = crypto::to_hex({md, len});
        if (got != pin) {
            fail("server certificate fingerprint " + got + " does not match the pinned " + pin);
            return false;
        }
        return true;
    }
    void drain_control() {
        size_t at = 0;
        std::vector<uint8_t>& body = rx_body;
        while (state != ClientState::Failed && state != ClientState::Closed) {
            uint32_t n = 0;
            if (!read_length({rx.data() + at, rx.size() - at}, n)) break;
            if (n < 8 || n > MAX_CONTROL_MESSAGE) return fail("server sent a control message of " + std::to_string(n) + " bytes");
            if (rx.size() - at < 4 + size_t(n)) break;
            body.assign(rx.begin() + long(at) + 4, rx.begin() + long(at) + 4 + n);
            at += 4 + size_t(n);
            handle_control(body);
        }
        rx.erase(rx.begin(), rx.begin() + long(std::min(at, rx.size())));
    }

    void handle_control(std::vector<uint8_t>& body) {
        const wire::Control* c = verify_control(body);
        if (!c) return fail("server sent a malformed control message");
        switch (c->body_type()) {
            case wire::ControlBody::Refuse: {
                const wire::Refuse* r = c->body_as_Refuse();
                return fail("server refused the connection: " + (r->reason() ? r->reason()->str() : std::string("no reason")));
            }
            case wire::ControlBody::Welcome:
                if (welcomed) return fail("server sent a second Welcome");
                welcome_body = std::move(body);
                return on_welcome(verify_control(welcome_body)->body_as_Welcome());
            case wire::ControlBody::AssetChunk: return on_asset_chunk(*c->body_as_AssetChunk());
            case wire::ControlBody::InstanceAdded:
                if (!welcomed) return fail("server sent instances before Welcome");
                if (c->body_as_InstanceAdded()->instances())
                    for (const wire::Instance* in : *c->body_as_InstanceAdded()->instances())
                        if (!on_instance_added(*in)) return;
                return;
            case wire::ControlBody::InstanceRemoved:
                if (c->body_as_InstanceRemoved()->ids())
                    for (uint16_t id : *c->body_as_InstanceRemoved()->ids()) remove_remote(id);
                return;
            case wire::ControlBody::Spawned: return on_spawned(*c->body_as_Spawned());
            case wire::ControlBody::Stats:
                st.rtt_ms = c->body_as_Stats()->rtt_ms();
                st.estimate_kbps = c->body_as_Stats()->estimate_kbps();
                return;
            case wire::ControlBody::Goodbye: {
                const auto* g = c->body_as_Goodbye();
                const std::string why = g->reason() ? g->reason()->str() : std::string();
                // The server ends a session it timed out or refused: the stream is lost.
                return fail("the server ended the session" + (why.empty() ? std::string() : ": " + why));
            }
            default: return fail("server sent an unexpected control message");
        }
    }

    void on_welcome(const wire::Welcome* w) {
        if (w->version() != PROTOCOL_VERSION) return fail("server speaks protocol version " + std::to_string(w->version()));
        tick_rate = w->tick_rate();
        if (!(tick_rate > 0 && tick_rate <= 1000)) return fail("server sent a bad tick rate");
        if (const auto* keys = w->datagram_keys(); keys && keys->size() > 0) {
            if (!tls) return fail("server sent datagram keys over an unencrypted channel");
            if (keys->size() != 2 * crypto::KEY_BYTES) return fail("server sent datagram keys of the wrong size");
            crypto::Key down{}, up{};
            std::copy(keys->begin(), keys->begin() + crypto::KEY_BYTES, down.begin());
            std::copy(keys->begin() + crypto::KEY_BYTES, keys->end(), up.begin());
            opener = std::make_unique<crypto::Opener>(down);
            sealer = std::make_unique<crypto::Sealer>(up);
        }
        welcomed = true;
        welcome = w;
        session = w->session_id();
        udp_token = w->udp_token();
        udp_port = w->udp_port();
        base_delay = cfg.delay_ms / 1000.0 * tick_rate;
        max_delay = std::max(base_delay, cfg.max_delay_ms / 1000.0 * tick_rate);
        delay_ticks = base_delay;
        if (w->assets())
            for (const wire::Asset* a : *w->assets()) {
                CatalogueEntry e;
                e.name = a->name() ? a->name()->str() : "asset.glb";
                e.id = a->asset_id();
                e.size = a->size();
                catalogue.push_back(std::move(e));
                asset_names.push_back(catalogue.back().name);
            }
        assets.assign(catalogue.size(), nullptr);
        raise(ClientEvent::Type::Connected);
        if (view_set) view_dirty = true;
        start_downloads();
    }

    void asset_loaded(size_t i, const std::string& path) {
        try {
            assets[i] = load_client_asset(welcome->assets()->Get(flatbuffers::uoffset_t(i)), path);
        } catch (const std::exception& e) {
            return fail(std::string("asset ") + catalogue[i].name + ": " + e.what());
        }
        catalogue[i].ready = true;
        catalogue[i].bytes = {};
        if (all_assets_ready()) st.download_seconds = now_seconds() - started;
        raise(ClientEvent::Type::AssetReady, -1, int(i));
        for (auto& r : remotes)
            if (r.active && r.asset == int(i)) make_view(r);
    }

    // Finds cached assets, then downloads the others one after another.
    void start_downloads() {
        cache = cfg.cache_dir.empty() ? default_cache_dir() : cfg.cache_dir;
        std::error_code ec;
        fs::create_directories(cache, ec);
        for (size_t i = 0; i < catalogue.size(); ++i) {
            CatalogueEntry& e = catalogue[i];
            std::string ext = fs::path(e.name).extension().string();
            if (ext != ".glb" && ext != ".gltf") ext = ".glb";
            const fs::path path = fs::path(cache) / (hex64(e.id) + ext);
            if (fs::exists(path) && content_hash(read_file(path.string())) == e.id) {
                ++st.assets_cached;
                asset_loaded(i, path.string());
                if (state == ClientState::Failed) return;
            } else if (e.size == 0 || e.size > MAX_ASSET_BYTES) {
                return fail("server announced asset " + e.name + " of " + std::to_string(e.size) + " bytes (the limit is " +
                            std::to_string(MAX_ASSET_BYTES) + ")");
            }
        }
        downloading = 0;
        last_progress = now_seconds();
        request_chunks();
    }

    void request_chunks() {
        while (downloading < catalogue.size() && catalogue[downloading].ready) ++downloading;
        if (downloading >= catalogue.size()) return;
        CatalogueEntry& e = catalogue[downloading];
        while (e.in_flight < 4 && e.requested < e.size) {
            flatbuffers::FlatBufferBuilder b;
            const uint32_t len = uint32_t(std::min<uint64_t>(MAX_ASSET_CHUNK, e.size - e.requested));
            auto r = wire::CreateAssetRequest(b, e.id, e.requested, len);
            b.Finish(wire::CreateControl(b, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
            send(b);
            e.requested += len;
            ++e.in_flight;
        }
    }

    void on_asset_chunk(const wire::AssetChunk& ch) {
        if (downloading >= catalogue.size()) return fail("server sent an asset chunk nobody asked for");
        CatalogueEntry& e = catalogue[downloading];
        // Chunks come in request order: each must continue the bytes so far,
        // so memory grows with what arrives, never with the declared size.
        if (ch.asset_id() != e.id || !ch.data() || ch.offset() != e.bytes.size() || ch.data()->size() == 0 ||
            ch.offset() + ch.data()->size() > e.size)
            return fail("server sent a bad asset chunk for " + e.name);
        e.bytes.insert(e.bytes.end(), ch.data()->begin(), ch.data()->end());
        st.asset_bytes_downloaded += ch.data()->size();
        --e.in_flight;
        last_progress = now_seconds();
        if (cfg.on_download) cfg.on_download(e.name, e.bytes.size(), e.size);
        if (e.bytes.size() < e.size) return request_chunks();
        if (content_hash(e.bytes) != e.id) return fail("downloaded " + e.name + " does not match its content hash");
        std::string ext = fs::path(e.name).extension().string();
        if (ext != ".glb" && ext != ".gltf") ext = ".glb";
        const fs::path path = fs::path(cache) / (hex64(e.id) + ext);
        // A temporary name unique to this process and client: several clients
        // may fill the same cache at once, and the rename makes the file appear whole.
        fs::path tmp = path;
        tmp += ".part" + std::to_string(::getpid()) + "-" + std::to_string(reinterpret_cast<uintptr_t>(this));
        {
            std::ofstream f(tmp, std::ios::binary);
            f.write(reinterpret_cast<const char*>(e.bytes.data()), std::streamsize(e.bytes.size()));
            if (!f) return fail("cannot write " + tmp.string());
        }
        std::error_code ec;
        fs::rename(tmp, path, ec);
        if (ec) return fail("cannot write " + path.string() + ": " + ec.message());
        asset_loaded(downloading, path.string());
        request_chunks();
    }

    bool all_assets_ready() const {
        for (const auto& e : catalogue)
            if (!e.ready) return false;
        return welcomed;
    }

    // ---------------------------------------------------------- instances --
    bool on_instance_added(const wire::Instance& in) {
        RemoteCharacter rc;
        const std::string why = read_instance(in, catalogue.size(), rc);
        if (!why.empty()) {
            fail("server sent a bad instance: " + why);
            return false;
        }
        if (remotes.size() <= in.id()) remotes.resize(size_t(in.id()) + 1);
        Remote& r = remotes[in.id()];
        if (r.active) remove_remote(in.id());  // announced again: a new character in that slot
        r = Remote{};
        r.active = true;
        r.asset = in.asset();
        r.rc = std::move(rc);
        if (catalogue[size_t(r.asset)].ready) make_view(r);
        return true;
    }

    void make_view(Remote& r) {
        if (r.view) return;
        const auto& a = assets[size_t(r.asset)];
        for (int c : r.rc.clip.selection.clips)
            if (size_t(c) >= a->character.clips.size()) return fail("server sent an unknown clip index");
        r.view = std::make_unique<InstanceView>(a, r.rc.clip, cfg.blend_frames, tick_rate);
        r.rc.asset = a.get();
        r.announced = true;
        shown_dirty = true;
        raise(ClientEvent::Type::CharacterAdded, r.rc.instance, r.asset);
    }

    void remove_remote(int id) {
        if (id < 0 || size_t(id) >= remotes.size() || !remotes[size_t(id)].active) return;
        Remote& r = remotes[size_t(id)];
        if (r.announced) raise(ClientEvent::Type::CharacterRemoved, id, r.asset);
        r = Remote{};
        shown_dirty = true;
    }

    void on_spawned(const wire::Spawned& m) {
        auto it = std::find_if(own.begin(), own.end(), [&](const Own& o) { return o.request == m.request(); });
        if (it == own.end()) return fail("server answered a spawn request that was never made");
        if (m.ok() && it->gone) {  // despawned before the answer came
            flatbuffers::FlatBufferBuilder b;
            auto d = wire::CreateDespawn(b, m.instance());
            b.Finish(wire::CreateControl(b, wire::ControlBody::Despawn, d.Union()), wire::ControlIdentifier());
            send(b);
            return;
        }
        if (m.ok()) {
            it->instance = m.instance();
            raise(ClientEvent::Type::Spawned, it->instance, it->asset, it->handle);
        } else {
            it->refused = true;
            raise(ClientEvent::Type::SpawnRefused, -1, it->asset, it->handle, m.reason() ? m.reason()->str() : "");
        }
    }

    // ---------------------------------------------------------------- UDP --
    void send_datagram(const flatbuffers::FlatBufferBuilder& b) {
        asio::error_code ig;
        if (sealer) {
            crypto::seal_datagram(*sealer, session, PROTOCOL_VERSION, {b.GetBufferPointer(), b.GetSize()}, sealed_buf);
            udp_sock.send_to(asio::buffer(sealed_buf), server_udp, 0, ig);
            return;
        }
        udp_sock.send_to(asio::buffer(b.GetBufferPointer(), b.GetSize()), server_udp, 0, ig);
    }

    void open_udp() {
        udp_sock.open(udp::v4());
        udp_sock.bind(udp::endpoint(udp::v4(), 0));
        udp_sock.non_blocking(true);
        asio::error_code ig;
        udp_sock.set_option(asio::socket_base::receive_buffer_size(4 << 20), ig);
        int on = 1;
        ::setsockopt(udp_sock.native_handle(), SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
        udp::resolver r(io);
        asio::error_code ec;
        const std::string h = cfg.udp_via_host.empty() ? host : cfg.udp_via_host;
        const uint16_t p = cfg.udp_via_host.empty() ? udp_port : cfg.udp_via_port;
        auto res = r.resolve(udp::v4(), h, std::to_string(p), ec);
        if (ec || res.empty()) return fail("cannot resolve " + h + ": " + ec.message());
        server_udp = *res.begin();
    }

    void send_bind() {
        fbb.Clear();
        build_bind(fbb, session, udp_token);  // padded: always larger than its BindAck or Challenge
        send_datagram(fbb);
    }

    void receive_udp() {
        for (;;) {
            udp::endpoint from;
            double t = 0;
            const ssize_t got = receive_stamped(udp_sock, buf, sizeof buf, from, t);
            if (got < 0) break;
            const size_t n = size_t(got);  // on the wire (sealed: 32 bytes more than the datagram)
            const wire::Datagram* d = nullptr;
            if (opener) {  // sealed session: unsealed, forged and replayed datagrams are dropped
                uint64_t seq = 0;
                if (from == server_udp &&
                    crypto::open_datagram(*opener, session, PROTOCOL_VERSION, {buf, n}, opened_buf, seq) == crypto::OpenResult::ok)
                    d = verify_datagram(opened_buf);
            } else {
                d = verify_datagram({buf, n});
            }
            if (!d || from != server_udp) {
                ++st.malformed;
                continue;
            }
            last_datagram = t;
            if (d->body_type() == wire::DatagramBody::BindAck) {
                bound = true;
                continue;
            }
            if (d->body_type() == wire::DatagramBody::Challenge) {  // return routability: echo the nonce
                const wire::Challenge* ch = d->body_as_Challenge();
                if (ch->session_id() == session && ch->nonce() && ch->nonce()->size() == CHALLENGE_NONCE) {
                    fbb.Clear();
                    build_challenge_response(fbb, session, udp_token, {ch->nonce()->data(), ch->nonce()->size()});
                    send_datagram(fbb);
                } else {
                    ++st.malformed;
                }
                continue;
            }
            if (d->body_type() != wire::DatagramBody::Frame) {
                ++st.malformed;
                continue;
            }
            handle_frame(d, n, t);
        }
    }

    void handle_frame(const wire::Datagram* d, size_t n, double t) {
        const wire::Frame* f = d->body_as_Frame();
        const uint32_t seq = d->seq();
        if (any_frame) {
            const int32_t diff = int32_t(seq - ack);
            if (diff == 0 || (diff < 0 && diff >= -32 && (ack_bits & (1u << (-diff - 1))))) {
                ++st.duplicates;
                return;
            }
        }
        // Every chunk is checked before any is applied (proto/frame_reader.h).
        auto record_size = [&](uint16_t instance) -> int {
            if (instance >= remotes.size() || !remotes[instance].view) return 0;
            return remotes[instance].view->asset().format.size();
        };
        uint8_t epoch = 0;
        const uint8_t* root = nullptr;
        auto on_chunk = [&](const wire::Chunk& c, const uint8_t* r, const uint8_t* morph) {
            epoch = c.epoch();
            root = r;
            // Morph weights (sparse: the others keep their values), PoseBuffer::add_morphs.
            if (morph && !remotes[c.instance()].view->buffer().add_morphs(f->tick(), c.show(), c.show(), c.epoch(), morph))
                ++st.malformed;
        };
        auto apply = [&](uint16_t instance, int first, int count, int show, const uint8_t* rec) {
            InstanceView& v = *remotes[instance].view;
            const bool had = !v.buffer().empty();
            const uint32_t prev = v.buffer().newest_tick();
            if (!v.buffer().add_chunk(f->tick(), first, count, show, rec, show, epoch, root)) {
                ++st.malformed;
            } else if (had && tick_offset > -1e299) {
                // Cover the gap since the instance's newest frame and the gap
                // since these bones' previous frames (deep bones are refreshed
                // less often, scheduler.h).
                double since = int32_t(f->tick() - prev) > 0 ? double(prev) : double(f->tick());
                if (v.buffer().last_gap() > 0) since = std::min(since, double(f->tick()) - v.buffer().last_gap());
                if (since < double(f->tick())) needed_delay = std::max(needed_delay, t * tick_rate + tick_offset - since);
            }
        };
        if (!read_frame(*f, record_size, apply, on_chunk)) {
            ++st.malformed;
            return;
        }
        if (f->chunks())
            for (const wire::Chunk* c : *f->chunks())
                if (record_size(c->instance()) == 0) ++st.unknown_chunks;
        if (!any_frame) {
            ack = seq;
            ack_bits = 0;
            min_seq = max_seq = seq;
            t_first = t;
        } else if (int32_t(seq - ack) > 0) {
            const uint32_t shift = seq - ack;
            uint32_t nb = shift >= 32 ? 0 : (ack_bits << shift);
            if (shift <= 32) nb |= 1u << (shift - 1);
            ack_bits = nb;
            ack = seq;
        } else {
            const uint32_t back = ack - seq - 1;
            if (back < 32) ack_bits |= 1u << back;
        }
        if (int32_t(seq - max_seq) > 0) max_seq = seq;
        if (int32_t(min_seq - seq) > 0) min_seq = seq;
        if (seq == ack) {
            ack_echo = d->send_time_us();
            ack_arrival = t;
        }
        any_frame = bound = true;
        ++unique;
        ++since_ack;
        ++st.datagrams;
        st.wire_bytes += n + UDP_IP_OVERHEAD;
        const size_t bin = size_t(t - t_first);
        if (st.per_second_bytes.size() <= bin) st.per_second_bytes.resize(bin + 1, 0.0);
        st.per_second_bytes[bin] += double(n + UDP_IP_OVERHEAD);
        tick_offset = std::max(tick_offset, double(f->tick()) - t * tick_rate);
    }

    void send_view_now() {
        flatbuffers::FlatBufferBuilder b;
        std::vector<wire::InstanceWeight> ws;
        for (const auto& [i, wt] : view.weights) ws.emplace_back(uint16_t(i), wt);
        auto vw = b.CreateVectorOfStructs(ws);
        wire::Vec3 cam(view.camera.x, view.camera.y, view.camera.z);
        wire::ViewBuilder vb(b);
        if (view.has_camera) vb.add_camera(&cam);
        vb.add_fov_y(view.fov_y);
        vb.add_viewport_height(view.viewport_height);
        vb.add_weights(vw);
        vb.add_max_kbps(uint32_t(std::max(0.0, cap)));
        auto v = vb.Finish();
        b.Finish(wire::CreateControl(b, wire::ControlBody::View, v.Union()), wire::ControlIdentifier());
        send(b);
        view_dirty = false;
    }

    // ------------------------------------------------------------- update --
    void update(double now) {
        events.clear();
        if (state == ClientState::Idle || state == ClientState::Closed || state == ClientState::Failed) {
            shown.clear();
            shown_ids.clear();
            return;
        }
        io.poll();
        io.restart();
        if (state == ClientState::Failed || state == ClientState::Closed) {
            shown.clear();
            shown_ids.clear();
            return;
        }
        if (!tcp_connected) {
            if (now - started > cfg.connect_timeout)
                fail((tls_started ? "TLS handshake with " : "cannot connect to ") + host + ":" + std::to_string(port) + ": timed out");
            return;
        }
        if (!welcomed) {
            if (now - started > cfg.connect_timeout) fail("no answer from the server");
            return;
        }
        if (view_dirty) send_view_now();
        // UDP right after Welcome: the server drops a session that is not
        // bound 10 s after its Welcome, and a download may take longer
        // (frames of characters whose asset is not ready are skipped).
        if (!udp_sock.is_open()) {
            st.per_second_bytes.reserve(3600);  // an hour of per-second rate bins without reallocating
            open_udp();
            if (state == ClientState::Failed) return;
            next_stats = now + 1.0;
        }
        // Bind until bound; bind again after 1 s without a datagram (the
        // address may have changed: NAT rebinding), every 0.2 s.
        if (((!any_frame && !bound) || (bound && has_characters() && now - last_datagram > 1.0)) && now >= next_bind) {
            send_bind();
            next_bind = now + 0.2;
        }
        receive_udp();
        if ((any_frame || bound) && state == ClientState::Connecting) state = ClientState::Streaming;
        if (!all_assets_ready()) {
            if (now - last_progress > cfg.connect_timeout)
                return fail("timed out downloading " + catalogue[downloading].name + " (" +
                            std::to_string(catalogue[downloading].bytes.size()) + " of " +
                            std::to_string(catalogue[downloading].size) + " bytes)");
        } else if (!any_frame && !bound && now - started > cfg.connect_timeout) {
            return fail("no answer from the server's UDP port");
        }
        if (any_frame && now - last_datagram > cfg.stream_timeout && has_characters())
            return fail("lost the stream: no datagram for " + std::to_string(int(now - last_datagram)) + " s");
        // Acks
        if (any_frame && since_ack > 0 && (since_ack >= 8 || now - last_ack_sent > 0.033)) {
            fbb.Clear();
            const uint32_t hold = uint32_t(std::max(0.0, (now - ack_arrival) * 1e6));
            auto a = wire::CreateAck(fbb, session, udp_token, ack, ack_bits, ack_echo, hold);
            fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
            send_datagram(fbb);
            since_ack = 0;
            last_ack_sent = now;
        }
        if (now >= next_stats) {
            flatbuffers::FlatBufferBuilder& b = ctl_fbb;
            b.Clear();
            wire::StatsBuilder sb(b);
            const auto& bins = st.per_second_bytes;
            sb.add_rate_kbps(float(bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : 0));
            auto s = sb.Finish();
            b.Finish(wire::CreateControl(b, wire::ControlBody::Stats, s.Union()), wire::ControlIdentifier());
            send(b);
            next_stats = now + 1.0;
        }
        display(now);
    }

    bool has_characters() const {
        for (const auto& r : remotes)
            if (r.active) return true;
        return false;
    }

    // The display clock: at least delay_ms behind the newest frame, raised
    // to cover the gaps between an instance's frames (plus their lateness)
    // so the display interpolates rather than holds; it changes by at most
    // 25% of the elapsed time (the clock runs at 0.75x..1.25x while it
    // adapts), up to max_delay_ms.
    void display(double now) {
        if (shown_dirty) {
            shown.clear();
            shown_ids.clear();
            for (const auto& r : remotes)
                if (r.active && r.view) {
                    shown.push_back(r.rc);
                    shown_ids.push_back(r.rc.instance);
                }
            shown_dirty = false;
        }
        if (!any_frame) return;
        const double elapsed = last_display_time > 0 ? (now - last_display_time) * tick_rate : 0;
        last_display_time = now;
        const double target = std::clamp(needed_delay + 0.5, base_delay, max_delay);
        const double step = 0.25 * elapsed;
        delay_ticks += std::clamp(target - delay_ticks, -step, step);
        needed_delay *= std::pow(0.7, elapsed / tick_rate);  // forget over a few seconds
        st.delay_ms = std::max(st.delay_ms, delay_ticks / tick_rate * 1000.0);
        double d = now * tick_rate + tick_offset - delay_ticks;
        if (cfg.snap_to_ticks) d = std::floor(d);
        display_tick = d;
        for (size_t k = 0; k < shown.size(); ++k) {
            Remote& r = remotes[size_t(shown_ids[k])];
            InstanceView& v = *r.view;
            RemoteCharacter& rc = shown[k];
            rc.shown = v.buffer().covers(d) && v.display(d);
            rc.display_tick = d;
            if (rc.shown) {
                rc.palette = v.palette();
                rc.morph_weights = v.morph_weights();
                rc.bones = v.target_bones();
                RootPose root;
                if (v.buffer().root(d, root)) rc.root = root;
            } else {
                rc.palette = {};
                rc.morph_weights = {};
                rc.bones = 0;
            }
        }
    }

    // -------------------------------------------------------------- own ---
    Own* find_own(int handle) {
        for (auto& o : own)
            if (o.handle == handle && !o.gone) return &o;
        return nullptr;
    }

    // TCP connected (and the TLS handshake and pin checked): Hello, then read.
    void on_channel_ready();

    bool publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport,
                 std::span<const float> morph_weights) {
        Own* o = find_own(handle);
        if (!o || o->instance < 0 || !bound || state != ClientState::Streaming) return false;
        const auto& a = assets[size_t(o->asset)];
        if (!a || skinning.size() != a->character.joint_count()) return false;
        std::array<uint8_t, ROOT_BYTES> rb;
        const RecordFormat& fmt = a->format;
        const int B = a->skin.bone_count();
        const size_t rs = size_t(fmt.size());
        pose_records.resize(size_t(B) * rs);
        bool ok = encode_root(root, rb.data());
        for (int b = 0; ok && b < B; ++b) {
            const BonePose p = decompose(skinning[size_t(a->skin.order[size_t(b)])]);
            if (!bone_in_range(p, fmt)) ok = false;
            else encode_bone(p, fmt, pose_records.data() + size_t(b) * rs);
        }
        if (!morph_weights.empty()) {
            if (morph_weights.size() != std::min<size_t>(a->character.morphs.size(), MAX_MORPHS)) return false;
            pose_morphs.resize(morph_weights.size());
            for (size_t m = 0; ok && m < morph_weights.size(); ++m) ok = encode_morph_weight(morph_weights[m], pose_morphs[m]);
        }
        if (!ok) {
            ++st.poses_refused;
            return false;
        }
        if (teleport) ++o->epoch;
        ++o->pose_seq;
        // As many bones per datagram as fit (a 67-bone character takes one).
        const size_t per = std::max<size_t>(1, (MAX_DATAGRAM - 120 - ROOT_BYTES) / rs);
        for (int first = 0; first < B; first += int(per)) {
            const int count = std::min(B - first, int(per));
            fbb.Clear();
            auto rv = fbb.CreateVector(rb.data(), rb.size());
            auto rec = fbb.CreateVector(pose_records.data() + size_t(first) * rs, size_t(count) * rs);
            flatbuffers::Offset<flatbuffers::Vector<int16_t>> mv;  // the weights go with the first bones
            if (first == 0 && !morph_weights.empty()) mv = fbb.CreateVector(pose_morphs.data(), pose_morphs.size());
            auto p = wire::CreatePose(fbb, session, udp_token, uint16_t(o->instance), o->pose_seq, o->epoch, uint8_t(first), rv, rec, mv);
            fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Pose, p.Union()), wire::DatagramIdentifier());
            send_datagram(fbb);
        }
        ++st.poses_sent;
        return true;
    }
};

Client::Client(ClientConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}
Client::~Client() {
    if (impl_ && (impl_->state == ClientState::Connecting || impl_->state == ClientState::Streaming)) close();
}

void Client::connect(const std::string& host, uint16_t port) {
    Impl& m = *impl_;
    if (m.state != ClientState::Idle) throw Error("connect: the client is already connected");
    m.host = host;
    m.port = port;
    m.started = now_seconds();
    tcp::resolver r(m.io);
    asio::error_code ec;
    auto res = r.resolve(host, std::to_string(port), ec);
    if (ec) throw Error("cannot resolve " + host + ": " + ec.message());
    m.state = ClientState::Connecting;
    if (m.cfg.tls && !m.setup_tls()) return;  // Failed: see error()
    asio::async_connect(m.tcp_sock, res, [&m](asio::error_code e, const tcp::endpoint&) {
        if (e) return m.fail("cannot connect to " + m.host + ":" + std::to_string(m.port) + ": " + e.message());
        asio::error_code ig;
        m.tcp_sock.set_option(tcp::no_delay(true), ig);
        if (!m.tls) return m.on_channel_ready();
        m.tls_started = true;
        m.tls->async_handshake(asio::ssl::stream_base::client, [&m](asio::error_code he) {
            if (m.state == ClientState::Failed || m.state == ClientState::Closed) return;
            if (he) {
                if (!m.tls_verify_error.empty()) return m.fail("server certificate not trusted: " + m.tls_verify_error);
                return m.fail("TLS handshake with " + m.host + ":" + std::to_string(m.port) + " failed: " + he.message());
            }
            if (m.check_pin()) m.on_channel_ready();
        });
    });
}

void Client::Impl::on_channel_ready() {
    Impl& m = *this;
    {
        m.tcp_connected = true;
        flatbuffers::FlatBufferBuilder b;
        auto name = b.CreateString(m.cfg.name.substr(0, MAX_NAME));
        auto token = b.CreateString(m.cfg.token.substr(0, MAX_TOKEN));
        auto h = wire::CreateHello(b, m.cfg.protocol_version ? m.cfg.protocol_version : PROTOCOL_VERSION, name, token,
                                   uint32_t(std::max(0.0, m.cfg.max_kbps)));
        b.Finish(wire::CreateControl(b, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
        m.send(b);
        m.read_more();
    }
}

void Client::update(double now) { impl_->update(now); }

void Client::close(const std::string& reason) {
    Impl& m = *impl_;
    if (m.state == ClientState::Closed || m.state == ClientState::Failed || m.state == ClientState::Idle) return;
    if (m.tcp_connected) {
        // Best effort, without waiting: Goodbye is small and the socket's
        // buffer takes it unless the server stopped reading.
        flatbuffers::FlatBufferBuilder b;
        build_goodbye(b, reason);
        std::vector<uint8_t> msg;
        frame_control(b, msg);
        asio::error_code ec;
        m.tcp_sock.non_blocking(true, ec);
        if (!m.writing && m.tx_pending.empty()) {
            if (m.tls) m.tls->write_some(asio::buffer(msg), ec);  // one TLS record; would_block: dropped
            else m.tcp_sock.write_some(asio::buffer(msg), ec);
        }
    }
    m.state = ClientState::Closed;
    m.raise(ClientEvent::Type::Closed, -1, -1, -1, reason);
    asio::error_code ig;
    m.tcp_sock.close(ig);
    m.udp_sock.close(ig);
    m.shown.clear();
}

ClientState Client::state() const { return impl_->state; }
const std::string& Client::error() const { return impl_->error; }
std::span<const ClientEvent> Client::events() const { return impl_->events; }
std::span<const RemoteCharacter> Client::characters() const { return impl_->shown; }
const RemoteCharacter* Client::character(int instance) const {
    for (const auto& c : impl_->shown)
        if (c.instance == instance) return &c;
    return nullptr;
}
const std::vector<std::shared_ptr<ClientAsset>>& Client::assets() const { return impl_->assets; }
const std::vector<std::string>& Client::asset_names() const { return impl_->asset_names; }
double Client::tick_rate() const { return impl_->tick_rate; }

ClientStats Client::stats() const {
    const Impl& m = *impl_;
    ClientStats s = m.st;
    s.seconds = m.any_frame ? now_seconds() - m.t_first : 0;
    const uint64_t span = m.any_frame ? uint64_t(m.max_seq - m.min_seq) + 1 : 0;
    s.loss = span ? std::max(0.0, 1.0 - double(m.unique) / double(span)) : 0;
    return s;
}

void Client::set_view(const ViewSpec& view) {
    impl_->view = view;
    impl_->view_set = true;
    impl_->view_dirty = impl_->welcomed;
}

void Client::set_max_kbps(double kbps) {
    impl_->cap = std::max(0.0, kbps);
    impl_->view_set = true;
    impl_->view_dirty = impl_->welcomed;
}

int Client::spawn(const SpawnSpec& spec) {
    Impl& m = *impl_;
    Impl::Own o;
    o.handle = int(m.own.size()) + 1;
    o.asset = spec.asset;
    o.request = m.next_request++;
    m.own.push_back(o);
    if (!m.welcomed || spec.asset < 0 || size_t(spec.asset) >= m.catalogue.size()) {
        m.own.back().refused = true;
        m.raise(ClientEvent::Type::SpawnRefused, -1, spec.asset, o.handle,
                m.welcomed ? "no asset " + std::to_string(spec.asset) + " in the catalogue" : "not connected yet");
        return o.handle;
    }
    flatbuffers::FlatBufferBuilder b;
    std::vector<int32_t> clips(spec.clips.begin(), spec.clips.end());
    auto vc = b.CreateVector(clips);
    wire::DVec3 wc(spec.walk_center.x, spec.walk_center.y, spec.walk_center.z);
    wire::Vec3 pos(spec.position.x, spec.position.y, spec.position.z);
    auto s = wire::CreateSpawn(b, o.request, uint16_t(spec.asset), vc, spec.once, spec.speed, spec.start_us, &wc, spec.walk_radius,
                               spec.walk_speed, &pos);
    b.Finish(wire::CreateControl(b, wire::ControlBody::Spawn, s.Union()), wire::ControlIdentifier());
    m.send(b);
    return o.handle;
}

bool Client::publish(int handle, const RootPose& root, std::span<const Mat34> skinning, bool teleport,
                     std::span<const float> morph_weights) {
    return impl_->publish(handle, root, skinning, teleport, morph_weights);
}

void Client::despawn(int handle) {
    Impl& m = *impl_;
    Impl::Own* o = m.find_own(handle);
    if (!o) return;
    o->gone = true;
    if (o->instance < 0) return;
    flatbuffers::FlatBufferBuilder b;
    auto d = wire::CreateDespawn(b, uint16_t(o->instance));
    b.Finish(wire::CreateControl(b, wire::ControlBody::Despawn, d.Union()), wire::ControlIdentifier());
    m.send(b);
}

int Client::instance_of(int handle) const {
    for (const auto& o : impl_->own)
        if (o.handle == handle && !o.gone && !o.refused) return o.instance;
    return -1;
}

}  // namespace progskin::net
