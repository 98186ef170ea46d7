// server.cpp — see server.h. Session state machine (docs/protocol.md):
//   AwaitHello --Hello ok--> Welcomed --Bind, Challenge, ChallengeResponse
//       from the same address--> Streaming
//   Streaming --Bind from a new address, Challenge, ChallengeResponse--> Streaming (moved)
//   any --Goodbye / TCP close / error / output backlog--> Closed
//   AwaitHello --no Hello in hello_timeout--> Closed
//   Welcomed --not bound client_timeout after Welcome (TCP traffic or not)--> Goodbye, Closing
//   Streaming --no Ack from the bound address in client_timeout--> Goodbye, Closing
//   AwaitHello --bad version or token, server full, Welcome too large--> Refuse, Closing
//   Closing --queued output written, or 1 s--> Closed
// With tls_cert_file set, the control channel is TLS (asio::ssl) from the
// first byte (handshake within hello_timeout); with seal_datagrams too, every
// datagram both ways is sealed with keys sent in the Welcome. Nothing blocks:
// every TCP write is asynchronous, each session's queued output is capped
// (max_queued_bytes), a failed accept backs off 100 ms, and an exception in
// one session's handler closes that session only.
#include "server.h"

#include <asio.hpp>
#include <asio/ssl.hpp>
#include <chrono>
#include <cstdio>
#include <deque>
#include <map>
#include <mutex>
#include <algorithm>
#include <random>

#include <sodium.h>

#include "crypto.h"
#include "datagram_packer.h"
#include "errors.h"
#include "frame_encoder.h"
#include "rate_controller.h"
#include "scheduler.h"
#include "wire.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;

namespace {
enum class State { AwaitHello, Welcomed, Streaming, Closing, Closed };

// 64 bits from the operating system's cryptographic generator (libsodium).
uint64_t random_u64() {
    uint64_t v = 0;
    while (v == 0) randombytes_buf(&v, sizeof v);
    return v;
}

bool equal_u64(uint64_t a, uint64_t b) { return sodium_memcmp(&a, &b, sizeof a) == 0; }

// Constant-time comparison of two strings of any lengths: compares their
// BLAKE2b digests, so neither the content nor the length leaks through timing.
bool equal_secret(const std::string& a, const std::string& b) {
    unsigned char ha[32], hb[32];
    crypto_generichash(ha, sizeof ha, reinterpret_cast<const unsigned char*>(a.data()), a.size(), nullptr, 0);
    crypto_generichash(hb, sizeof hb, reinterpret_cast<const unsigned char*>(b.data()), b.size(), nullptr, 0);
    return sodium_memcmp(ha, hb, sizeof ha) == 0;
}

constexpr double LINGER_SECONDS = 1.0;     // Closing: time to write the last message
constexpr double CHALLENGE_SECONDS = 5.0;  // a Challenge's nonce is valid this long

}

struct Server::Impl {
    struct Session : std::enable_shared_from_this<Session> {
        Impl* server;
        uint64_t id = 0, token = 0;
        tcp::socket sock;
        std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;  // over `sock` when TLS is on
        State state = State::AwaitHello;
        std::string name;
        uint8_t len_buf[4];
        std::vector<uint8_t> body;
        std::deque<std::vector<uint8_t>> writes;
        size_t queued = 0;
        udp::endpoint peer;
        bool bound = false;
        double opened = 0, welcomed = 0, last_heard = 0;  // last_heard: newest Ack from the bound address
        asio::ip::address remote;                          // TCP peer (per-address limit)
        // Return routability: the address a Bind came from and the nonce sent there.
        udp::endpoint challenge_peer;
        std::array<uint8_t, CHALLENGE_NONCE> challenge_nonce{};
        double challenge_sent = -1e300;
        std::string close_reason;
        double close_deadline = 0;
        // seal_datagrams: server -> client and client -> server keys (sent in the Welcome).
        crypto::Key tx_key{}, rx_key{};
        std::unique_ptr<crypto::Sealer> sealer;
        std::unique_ptr<crypto::Opener> opener;
        RateController rate;
        Scheduler scheduler;
        ViewSpec view;
        std::vector<float> importance;
        std::vector<uint32_t> known;   // per instance slot: generation announced to this client (0: none)
        uint64_t instances_seen = ~0ull;  // Impl::instances_version last synced
        struct Owned {
            int instance = 0;
            double tokens = 0, refilled = 0;  // pose rate limit (token bucket)
        };
        std::vector<Owned> owned;      // characters this session spawned
        uint32_t seq = 0;
        double asset_bytes = 0;
        explicit Session(Impl* s, tcp::socket so) : server(s), sock(std::move(so)) {}
    };

    ServerConfig cfg;
    std::vector<std::shared_ptr<ServerAsset>> assets;
    FrameEncoder encoder;
    asio::io_context io;
    tcp::acceptor acceptor{io};
    udp::socket udp_sock{io};
    asio::steady_timer timer{io};
    asio::steady_timer accept_timer{io};
    std::unique_ptr<asio::ssl::context> tls_ctx;  // set when ServerConfig::tls_cert_file is
    std::chrono::steady_clock::time_point next_tick;
    std::map<uint64_t, std::shared_ptr<Session>> sessions;
    DatagramPacker packer;
    std::vector<Pick> picks;
    std::vector<std::vector<uint8_t>> out_dgrams;
    alignas(16) std::array<uint8_t, 2048> udp_buf;
    udp::endpoint udp_from;
    std::vector<uint8_t> sealed_buf, opened_buf;  // seal_datagrams scratch
    uint32_t tick = 0;
    double last_tick_time = 0;
    std::atomic<uint64_t> instances_version{1};  // bumped by every add / remove
    std::vector<uint32_t> generations;           // scratch: per slot, 0 when inactive
    double total_asset_bytes = 0;
    mutable std::mutex stats_mutex;
    ServerStats st;
    bool connect_tokens = false;
    crypto::PublicKey token_key{};
    crypto::TokenReplayCache token_replays;

    Impl(ServerConfig c, std::vector<std::shared_ptr<ServerAsset>> a, std::vector<InstanceSpec> inst)
        : cfg(std::move(c)), assets(a), encoder(a, std::move(inst), cfg.tick_rate) {
        if (!(cfg.tick_rate > 0 && cfg.tick_rate <= 240)) throw Error("tick rate must be in (0, 240]");
        if (assets.empty()) throw Error("server: no assets");
        if (sodium_init() < 0) throw Error("server: libsodium could not be initialised");
        if (!cfg.tls_cert_file.empty() || !cfg.tls_key_file.empty()) {
            if (cfg.tls_cert_file.empty() || cfg.tls_key_file.empty())
                throw Error("server: TLS needs both a certificate and a private key file");
            tls_ctx = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_server);
            tls_ctx->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 |
                                 asio::ssl::context::no_sslv3 | asio::ssl::context::no_tlsv1 | asio::ssl::context::no_tlsv1_1 |
                                 asio::ssl::context::single_dh_use);
            asio::error_code ec;
            tls_ctx->use_certificate_chain_file(cfg.tls_cert_file, ec);
            if (ec) throw Error("server: TLS certificate " + cfg.tls_cert_file + ": " + ec.message());
            tls_ctx->use_private_key_file(cfg.tls_key_file, asio::ssl::context::pem, ec);
            if (ec) throw Error("server: TLS private key " + cfg.tls_key_file + ": " + ec.message());
        }
        if (cfg.seal_datagrams && !tls_ctx)
            throw Error("server: sealed datagrams need TLS (their keys travel in the Welcome)");
        if (!cfg.token_public_key.empty() && !cfg.token.empty())
            throw Error("server: an access token and connect tokens both travel in Hello.token; configure one");
        if (!cfg.token_public_key.empty()) {
            if (!crypto::from_hex(cfg.token_public_key, token_key))
                throw Error("server: the connect token public key must be 64 hex digits");
            connect_tokens = true;
        }
        for (const auto& x : assets) total_asset_bytes += double(x->bytes.size());
        auto addr = asio::ip::make_address(cfg.bind_address);
        // Bind TCP, then UDP on the same number when possible.
        for (int attempt = 0;; ++attempt) {
            tcp::endpoint ep(addr, cfg.port);
            acceptor = tcp::acceptor(io);
            acceptor.open(ep.protocol());
            acceptor.set_option(tcp::acceptor::reuse_address(true));
            asio::error_code ec;
            acceptor.bind(ep, ec);
            if (ec) throw Error("cannot listen on " + cfg.bind_address + ":" + std::to_string(cfg.port) + ": " + ec.message());
            acceptor.listen(asio::socket_base::max_listen_connections);
            uint16_t want = cfg.udp_port ? cfg.udp_port : acceptor.local_endpoint().port();
            udp_sock = udp::socket(io);
            udp_sock.open(udp::v4());
            udp_sock.bind(udp::endpoint(addr, want), ec);
            if (!ec) break;
            if (cfg.udp_port) throw Error("cannot bind UDP port " + std::to_string(cfg.udp_port) + ": " + ec.message());
            if (cfg.port != 0 || attempt > 20) {
                udp_sock.bind(udp::endpoint(addr, 0), ec);  // any free port; announced in Welcome
                if (ec) throw Error("cannot bind UDP: " + ec.message());
                break;
            }
        }
        udp_sock.non_blocking(true);
        udp_sock.set_option(asio::socket_base::send_buffer_size(4 << 20));
        udp_sock.set_option(asio::socket_base::receive_buffer_size(4 << 20));
    }

    template <class F>
    void with_stats(F f) {
        std::lock_guard lock(stats_mutex);
        f(st);
    }

    void log(const std::string& s) {
        if (cfg.verbose) std::fprintf(stderr, "progskin-server: %s\n", s.c_str());
    }

    // ---------------------------------------------------------------- TCP --
    void accept() {
        acceptor.async_accept([this](asio::error_code ec, tcp::socket s) {
            if (ec == asio::error::operation_aborted) return;
            if (ec) {
                // Out of descriptors (EMFILE, ENFILE) or memory: the pending
                // connection stays queued and accept() would fail again at
                // once; wait before trying again instead of spinning.
                with_stats([](ServerStats& st) { ++st.accept_errors; });
                if (ec == asio::error::connection_aborted) {
                    accept();
                    return;
                }
                log("accept: " + ec.message() + "; retrying in 100 ms");
                accept_timer.expires_after(std::chrono::milliseconds(100));
                accept_timer.async_wait([this](asio::error_code e) {
                    if (!e) accept();
                });
                return;
            }
            try {
                admit(std::move(s));
            } catch (const std::exception& e) {
                with_stats([](ServerStats& st) { ++st.handler_errors; });
                log(std::string("accept: ") + e.what());
            }
            accept();
        });
    }

    void admit(tcp::socket s) {
        asio::error_code ig;
        s.set_option(tcp::no_delay(true), ig);
        auto sess = std::make_shared<Session>(this, std::move(s));
        sess->remote = sess->sock.remote_endpoint(ig).address();
        if (ig) return;  // already gone
        do sess->id = random_u64();
        while (sessions.count(sess->id));
        sess->token = random_u64();
        sess->opened = sess->last_heard = now_seconds();
        sess->rate = RateController(cfg.max_kbps, std::min(cfg.initial_kbps, cfg.max_kbps));
        int same = 0;
        for (auto& [id, x] : sessions)
            if (x->state != State::Closed && x->state != State::Closing && x->remote == sess->remote) ++same;
        sessions[sess->id] = sess;
        with_stats([](ServerStats& st) { ++st.sessions_total; });
        if (cfg.max_per_address > 0 && same >= cfg.max_per_address) {
            if (tls_ctx) {  // no handshake spent on it: closed without a message
                with_stats([](ServerStats& st) { ++st.refused; });
                close(sess, "too many connections from " + sess->remote.to_string());
                return;
            }
            refuse(sess, "too many connections from " + sess->remote.to_string() + " (" + std::to_string(cfg.max_per_address) +
                             ")");
            return;
        }
        if (tls_ctx) {  // the handshake runs under hello_timeout like the rest of AwaitHello
            sess->tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(sess->sock, *tls_ctx);
            sess->tls->async_handshake(asio::ssl::stream_base::server, [this, sess](asio::error_code ec) {
                if (sess->state == State::Closed) return;
                if (ec) {
                    with_stats([](ServerStats& st) { ++st.tls_failures; });
                    close(sess, "TLS handshake: " + ec.message());
                    return;
                }
                read_header(sess);
            });
            return;
        }
        read_header(sess);
    }

    // The session's byte stream: TLS over the socket when configured, else the socket.
    template <class Buffers, class Handler>
    void read_exactly(const std::shared_ptr<Session>& s, const Buffers& b, Handler&& h) {
        if (s->tls) asio::async_read(*s->tls, b, std::forward<Handler>(h));
        else asio::async_read(s->sock, b, std::forward<Handler>(h));
    }
    template <class Buffers, class Handler>
    void write_all(const std::shared_ptr<Session>& s, const Buffers& b, Handler&& h) {
        if (s->tls) asio::async_write(*s->tls, b, std::forward<Handler>(h));
        else asio::async_write(s->sock, b, std::forward<Handler>(h));
    }

    void close(const std::shared_ptr<Session>& s, const std::string& why) {
        if (s->state == State::Closed) return;
        s->state = State::Closed;
        despawn_all(*s);
        log("session " + hex64(s->id) + " (" + s->name + ") closed: " + why);
        asio::error_code ig;
        s->sock.shutdown(tcp::socket::shutdown_both, ig);
        s->sock.close(ig);
        asio::post(io, [this, id = s->id] { sessions.erase(id); });
    }

    // Queues one control message; never blocks. A peer that does not read
    // what it asked for is closed once max_queued_bytes are waiting.
    void send(const std::shared_ptr<Session>& s, const flatbuffers::FlatBufferBuilder& fbb) {
        if (s->state == State::Closed || s->state == State::Closing) return;
        std::vector<uint8_t> msg;
        frame_control(fbb, msg);
        if (s->queued + msg.size() > cfg.max_queued_bytes) {  // slow reader
            with_stats([](ServerStats& st) { ++st.backlog_closes; });
            close(s, "control backlog over " + std::to_string(cfg.max_queued_bytes) + " bytes");
            return;
        }
        s->queued += msg.size();
        s->writes.push_back(std::move(msg));
        if (s->writes.size() == 1) write_next(s);
    }

    // Sends a last message (Refuse or Goodbye) and closes once it is written,
    // or after LINGER_SECONDS if the peer does not read it.
    void finish(const std::shared_ptr<Session>& s, const flatbuffers::FlatBufferBuilder& last, const std::string& why) {
        if (s->state == State::Closed || s->state == State::Closing) return;
        send(s, last);
        if (s->state == State::Closed) return;
        s->state = State::Closing;
        despawn_all(*s);  // its characters leave with it
        s->close_reason = why;
        s->close_deadline = now_seconds() + LINGER_SECONDS;
        if (s->writes.empty()) close(s, why);
    }

    void write_next(const std::shared_ptr<Session>& s) {
        if (s->writes.empty()) return;
        write_all(s, asio::buffer(s->writes.front()), [this, s](asio::error_code ec, size_t) {
            if (s->state == State::Closed) return;
            if (ec) {
                close(s, "write: " + ec.message());
                return;
            }
            s->queued -= s->writes.front().size();
            s->writes.pop_front();
            if (!s->writes.empty()) write_next(s);
            else if (s->state == State::Closing) close(s, s->close_reason);
        });
    }

    void read_header(const std::shared_ptr<Session>& s) {
        read_exactly(s, asio::buffer(s->len_buf, 4), [this, s](asio::error_code ec, size_t) {
            if (s->state == State::Closing) return;  // nothing more is read once the last message is queued
            if (ec || s->state == State::Closed) {
                close(s, ec ? ec.message() : "closed");
                return;
            }
            uint32_t n = 0;
            read_length({s->len_buf, 4}, n);
            if (n < 8 || n > MAX_CONTROL_MESSAGE) {
                with_stats([](ServerStats& st) { ++st.malformed_control; });
                close(s, "bad control length " + std::to_string(n));
                return;
            }
            s->body.resize(n);
            read_exactly(s, asio::buffer(s->body), [this, s](asio::error_code ec2, size_t) {
                if (s->state == State::Closing) return;
                if (ec2 || s->state == State::Closed) {
                    close(s, ec2 ? ec2.message() : "closed");
                    return;
                }
                bool more = false;
                try {
                    more = handle_control(s);
                } catch (const std::exception& e) {  // one session's failure never reaches io.run()
                    with_stats([](ServerStats& st) { ++st.handler_errors; });
                    close(s, std::string("error: ") + e.what());
                    return;
                }
                if (!more || s->state == State::Closing || s->state == State::Closed) return;
                read_header(s);
            });
        });
    }

    void refuse(const std::shared_ptr<Session>& s, const std::string& reason) {
        with_stats([](ServerStats& st) { ++st.refused; });
        flatbuffers::FlatBufferBuilder fbb;
        build_refuse(fbb, reason);
        log("refused: " + reason);
        finish(s, fbb, "refused: " + reason);
    }

    bool handle_control(const std::shared_ptr<Session>& s) {
        const wire::Control* c = verify_control(s->body);
        if (!c) {
            with_stats([](ServerStats& st) { ++st.malformed_control; });
            close(s, "malformed control message");
            return false;
        }
        // Control messages never extend a session's life: only Acks from the
        // bound address do (handle_datagram), so a TCP-only peer cannot hold a slot.
        switch (c->body_type()) {
            case wire::ControlBody::Hello: {
                if (s->state != State::AwaitHello) break;
                const wire::Hello* h = c->body_as_Hello();
                if (h->version() != PROTOCOL_VERSION) {
                    refuse(s, "protocol version " + std::to_string(h->version()) + " not supported; this server speaks version " +
                                  std::to_string(PROTOCOL_VERSION));
                    return false;
                }
                if ((h->client_name() && h->client_name()->size() > MAX_NAME) || (h->token() && h->token()->size() > MAX_TOKEN)) {
                    refuse(s, "client name or token too long");
                    return false;
                }
                if (!cfg.token.empty() && (!h->token() || !equal_secret(h->token()->str(), cfg.token))) {
                    refuse(s, "bad or missing access token");
                    return false;
                }
                if (connect_tokens) {
                    crypto::ConnectToken ct;
                    const uint64_t now_unix = crypto::unix_now();
                    std::string why = h->token() ? crypto::verify_connect_token(h->token()->str(), token_key, now_unix,
                                                                                cfg.public_address, ct)
                                                 : std::string("missing connect token");
                    if (why.empty() && !token_replays.first_use(ct, now_unix)) why = "connect token already used";
                    if (!why.empty()) {
                        with_stats([](ServerStats& st) { ++st.tokens_refused; });
                        refuse(s, why);
                        return false;
                    }
                    s->name += "client " + std::to_string(ct.client_id) + " ";
                }
                int active = 0;
                for (auto& [id, x] : sessions)
                    if (x->state == State::Welcomed || x->state == State::Streaming) ++active;
                if (active >= cfg.max_clients) {
                    refuse(s, "server full (" + std::to_string(cfg.max_clients) + " clients)");
                    return false;
                }
                s->name += h->client_name() ? h->client_name()->str() : "";
                double cap = h->max_kbps() ? std::min(double(h->max_kbps()), cfg.max_kbps) : cfg.max_kbps;
                s->rate = RateController(cap, std::min(cap, cfg.initial_kbps));
                s->scheduler.reset(0);
                if (cfg.seal_datagrams) {
                    s->tx_key = crypto::random_key();
                    s->rx_key = crypto::random_key();
                    s->sealer = std::make_unique<crypto::Sealer>(s->tx_key);
                    s->opener = std::make_unique<crypto::Opener>(s->rx_key);
                }
                if (!send_welcome(s, cap)) return false;
                if (s->state == State::Closed) return false;
                s->state = State::Welcomed;
                s->welcomed = s->last_heard = now_seconds();
                log("session " + hex64(s->id) + " (" + s->name + ") welcomed, cap " + std::to_string(int(cap)) + " kbit/s");
                return true;
            }
            case wire::ControlBody::AssetRequest: {
                if (s->state == State::AwaitHello) break;
                const wire::AssetRequest* r = c->body_as_AssetRequest();
                const ServerAsset* a = nullptr;
                for (const auto& x : assets)
                    if (x->id == r->asset_id()) a = x.get();
                if (!a || r->offset() >= a->bytes.size() || r->length() == 0 || r->length() > MAX_ASSET_CHUNK) {
                    with_stats([](ServerStats& st) { ++st.malformed_control; });
                    close(s, "bad asset request");
                    return false;
                }
                size_t n = std::min<size_t>(r->length(), a->bytes.size() - r->offset());
                s->asset_bytes += double(n);
                if (s->asset_bytes > cfg.asset_bytes_factor * total_asset_bytes + MAX_ASSET_CHUNK) {
                    close(s, "asset download limit");
                    return false;
                }
                flatbuffers::FlatBufferBuilder fbb(n + 128);
                auto data = fbb.CreateVector(a->bytes.data() + r->offset(), n);
                auto ch = wire::CreateAssetChunk(fbb, a->id, r->offset(), a->bytes.size(), data);
                fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetChunk, ch.Union()), wire::ControlIdentifier());
                with_stats([n](ServerStats& st) { st.asset_bytes_sent += n; });
                send(s, fbb);
                return true;
            }
            case wire::ControlBody::View: {
                if (s->state == State::AwaitHello) break;
                const wire::View* v = c->body_as_View();
                ViewSpec vs;
                if (v->camera()) {
                    vs.camera = {v->camera()->x(), v->camera()->y(), v->camera()->z()};
                    vs.has_camera = true;
                }
                if (v->fov_y() > 0) vs.fov_y = v->fov_y();
                if (v->viewport_height() > 0) vs.viewport_height = v->viewport_height();
                if (v->weights())
                    for (const auto* w : *v->weights())
                        if (std::isfinite(w->weight())) vs.weights.emplace_back(w->instance(), w->weight());
                s->view = std::move(vs);
                if (v->max_kbps()) s->rate.set_cap(std::min(double(v->max_kbps()), cfg.max_kbps));
                return true;
            }
            case wire::ControlBody::Stats: {
                if (s->state == State::AwaitHello) break;
                flatbuffers::FlatBufferBuilder fbb;
                wire::StatsBuilder sb(fbb);
                sb.add_estimate_kbps(float(s->rate.target_kbps()));
                sb.add_loss(float(s->rate.loss()));
                sb.add_rtt_ms(float(s->rate.rtt_ms()));
                sb.add_sent_datagrams(s->seq);
                auto so = sb.Finish();
                fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Stats, so.Union()), wire::ControlIdentifier());
                send(s, fbb);
                return true;
            }
            case wire::ControlBody::Spawn: {
                if (s->state == State::AwaitHello) break;
                handle_spawn(s, *c->body_as_Spawn());
                return true;
            }
            case wire::ControlBody::Despawn: {
                if (s->state == State::AwaitHello) break;
                const int id = c->body_as_Despawn()->instance();
                auto it = std::find_if(s->owned.begin(), s->owned.end(), [&](const Session::Owned& o) { return o.instance == id; });
                if (it == s->owned.end()) {
                    with_stats([](ServerStats& st) { ++st.malformed_control; });
                    close(s, "despawn of an instance this session does not own");
                    return false;
                }
                remove_instance(id);
                s->owned.erase(it);
                log("session " + hex64(s->id) + " despawned instance " + std::to_string(id));
                return true;
            }
            case wire::ControlBody::Goodbye:
                close(s, "goodbye");
                return false;
            default:
                break;
        }
        with_stats([](ServerStats& st) { ++st.malformed_control; });
        close(s, "unexpected control message in this state");
        return false;
    }

    void spawned(const std::shared_ptr<Session>& s, uint32_t request, bool ok, int instance, const std::string& reason) {
        flatbuffers::FlatBufferBuilder fbb;
        auto r = fbb.CreateString(reason);
        auto m = wire::CreateSpawned(fbb, request, ok, uint16_t(ok ? instance : 0), r);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Spawned, m.Union()), wire::ControlIdentifier());
        send(s, fbb);
        if (!ok) log("session " + hex64(s->id) + " spawn refused: " + reason);
    }

    void handle_spawn(const std::shared_ptr<Session>& s, const wire::Spawn& m) {
        if (s->owned.size() >= size_t(MAX_SPAWNED))
            return spawned(s, m.request(), false, 0, "this session owns " + std::to_string(MAX_SPAWNED) + " characters already");
        InstanceSpec sp;
        const std::string why = read_spawn(m, assets, s->id, sp);
        if (!why.empty()) return spawned(s, m.request(), false, 0, why);
        int id;
        try {
            id = add_instance(sp);
        } catch (const Error& e) {
            return spawned(s, m.request(), false, 0, e.what());
        }
        s->owned.push_back({id, 0.0, now_seconds()});
        log("session " + hex64(s->id) + " spawned " + assets[size_t(sp.asset)]->name + " as instance " + std::to_string(id));
        spawned(s, m.request(), true, id, "");
    }

    bool send_welcome(const std::shared_ptr<Session>& s, double cap) {
        flatbuffers::FlatBufferBuilder fbb(16384);
        std::vector<flatbuffers::Offset<wire::Asset>> as;
        for (const auto& a : assets) {
            const ProgressiveSkin& sk = a->skin;
            std::vector<int16_t> order(sk.order.begin(), sk.order.end());
            std::vector<float> corr;
            corr.reserve(sk.corrections.size() * 12);
            for (const Mat34& m : sk.corrections) corr.insert(corr.end(), m.m, m.m + 12);
            std::vector<wire::ErrorPoint> err;
            for (const auto& e : sk.error) err.emplace_back(float(e.rms), float(e.max));
            auto name = fbb.CreateString(a->name);
            auto vo = fbb.CreateVector(order);
            auto vp = fbb.CreateVector(sk.parents);
            auto vc = fbb.CreateVector(corr);
            auto ve = fbb.CreateVectorOfStructs(err);
            wire::Vec3 lo(a->format.t_min.x, a->format.t_min.y, a->format.t_min.z);
            wire::Vec3 hi(a->format.t_max.x, a->format.t_max.y, a->format.t_max.z);
            as.push_back(wire::CreateAsset(fbb, a->id, name, a->bytes.size(), uint16_t(a->bone_count()), a->format.scaled, vo, vp,
                                           vc, ve, float(a->diagonal), &lo, &hi, float(a->motion)));
        }
        auto va = fbb.CreateVector(as);
        auto sn = fbb.CreateString("progskin-server");
        flatbuffers::Offset<flatbuffers::Vector<uint8_t>> keys;
        if (s->sealer) {
            std::array<uint8_t, 2 * crypto::KEY_BYTES> k;
            std::copy(s->tx_key.begin(), s->tx_key.end(), k.begin());
            std::copy(s->rx_key.begin(), s->rx_key.end(), k.begin() + crypto::KEY_BYTES);
            keys = fbb.CreateVector(k.data(), k.size());
            sodium_memzero(k.data(), k.size());
        }
        auto w = wire::CreateWelcome(fbb, PROTOCOL_VERSION, s->id, s->token, udp_sock.local_endpoint().port(), cfg.tick_rate,
                                     uint32_t(cap), va, sn, keys);
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Welcome, w.Union()), wire::ControlIdentifier());
        if (fbb.GetSize() > MAX_CONTROL_MESSAGE) {  // the catalogue alone (instances travel apart)
            refuse(s, "Welcome would be " + std::to_string(fbb.GetSize()) + " bytes, over the " +
                          std::to_string(MAX_CONTROL_MESSAGE) + "-byte control message limit (too many assets)");
            return false;
        }
        send(s, fbb);
        sync_instances(s);
        return true;
    }

    // One Instance table (control.fbs) for an active instance.
    flatbuffers::Offset<wire::Instance> instance_table(flatbuffers::FlatBufferBuilder& fbb, int id, const InstanceSpec& sp) {
        const ServerAsset& a = *assets[size_t(sp.asset)];
        std::vector<int32_t> clips;
        float start = 0, end = 0;
        if (sp.selection >= 0) {
            const ClipSelection& sel = a.selections[size_t(sp.selection)];
            clips.assign(sel.clips.begin(), sel.clips.end());
            start = sel.start;
            end = sel.end;
        } else {
            clips.assign(sp.announced_clips.begin(), sp.announced_clips.end());
            if (!clips.empty()) {
                const ClipSelection sel = make_selection(a.character, sp.announced_clips);
                start = sel.start;
                end = sel.end;
            }
        }
        wire::Vec3 pos(sp.position.x, sp.position.y, sp.position.z);
        wire::Quat rot(sp.rotation.x, sp.rotation.y, sp.rotation.z, sp.rotation.w);
        wire::DVec3 wc(sp.walk_center.x, sp.walk_center.y, sp.walk_center.z);
        auto vcl = fbb.CreateVector(clips);
        return wire::CreateInstance(fbb, uint16_t(id), uint16_t(sp.asset), &pos, vcl, start, end, sp.time_offset, sp.speed, sp.once,
                                    &rot, sp.owner != 0, sp.publisher_start_us, &wc, sp.walk_radius, sp.walk_speed);
    }

    // Tells a client about instances added and removed since it last heard
    // (never its own), in messages that fit the control limit.
    void sync_instances(const std::shared_ptr<Session>& s) {
        const uint64_t version = instances_version.load();
        if (s->instances_seen == version || s->state == State::Closed) return;
        s->instances_seen = version;
        encoder.generations(generations);
        if (s->known.size() < generations.size()) s->known.resize(generations.size(), 0);
        std::vector<uint16_t> removed;
        std::vector<std::pair<int, InstanceSpec>> added;  // id and spec, read once
        for (size_t i = 0; i < s->known.size(); ++i) {
            const uint32_t g = i < generations.size() ? generations[i] : 0;
            if (s->known[i] == g) continue;
            if (s->known[i] != 0) removed.push_back(uint16_t(i));
            s->known[i] = 0;
            InstanceSpec sp;
            if (g == 0 || !encoder.spec_if_active(int(i), sp) || sp.owner == s->id) continue;
            s->known[i] = g;
            added.emplace_back(int(i), std::move(sp));
        }
        for (size_t at = 0; at < removed.size(); at += 16000) {
            flatbuffers::FlatBufferBuilder fbb;
            auto ids = fbb.CreateVector(removed.data() + at, std::min<size_t>(16000, removed.size() - at));
            auto r = wire::CreateInstanceRemoved(fbb, ids);
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::InstanceRemoved, r.Union()), wire::ControlIdentifier());
            send(s, fbb);
        }
        constexpr size_t kBatch = 128;  // an Instance table is under 200 bytes
        for (size_t at = 0; at < added.size(); at += kBatch) {
            flatbuffers::FlatBufferBuilder fbb(32768);
            std::vector<flatbuffers::Offset<wire::Instance>> is;
            for (size_t k = at; k < std::min(added.size(), at + kBatch); ++k)
                is.push_back(instance_table(fbb, added[k].first, added[k].second));
            auto v = fbb.CreateVector(is);
            auto m = wire::CreateInstanceAdded(fbb, v);
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::InstanceAdded, m.Union()), wire::ControlIdentifier());
            send(s, fbb);
        }
    }

    // ------------------------------------------------------ run-time scene --
    int add_instance(const InstanceSpec& spec) {
        const int id = encoder.add_instance(spec);
        ++instances_version;
        return id;
    }
    void remove_instance(int id) {
        encoder.remove_instance(id);
        ++instances_version;
    }

    void despawn_all(Session& s) {
        for (const auto& o : s.owned) remove_instance(o.instance);
        s.owned.clear();
    }

    // ---------------------------------------------------------------- UDP --
    void receive() {
        udp_sock.async_receive_from(asio::buffer(udp_buf), udp_from, [this](asio::error_code ec, size_t n) {
            if (ec == asio::error::operation_aborted) return;
            if (!ec) {
                try {
                    handle_datagram(n);
                } catch (const std::exception& e) {
                    with_stats([](ServerStats& st) { ++st.handler_errors; });
                    log(std::string("datagram: ") + e.what());
                }
            }
            receive();
        });
    }

    // Sends one datagram to `to`, sealed when the session seals; returns the bytes sent.
    size_t send_datagram(Session& s, std::span<const uint8_t> plain, const udp::endpoint& to) {
        asio::error_code ig;
        if (!s.sealer) {
            udp_sock.send_to(asio::buffer(plain.data(), plain.size()), to, 0, ig);
            return plain.size();
        }
        crypto::seal_datagram(*s.sealer, s.id, PROTOCOL_VERSION, plain, sealed_buf);
        udp_sock.send_to(asio::buffer(sealed_buf), to, 0, ig);
        return sealed_buf.size();
    }

    void handle_datagram(size_t n) {
        with_stats([](ServerStats& st) { ++st.datagrams_received; });
        auto reject = [&](bool malformed) {
            with_stats([&](ServerStats& st) {
                if (malformed) ++st.malformed_datagrams;
                else ++st.rejected_datagrams;
                st.unverified_bytes_in += n;
            });
        };
        std::span<const uint8_t> bytes(udp_buf.data(), n);
        Session* sealed_by = nullptr;  // seal_datagrams: the session whose key opened it
        if (cfg.seal_datagrams) {
            auto it = sessions.find(crypto::sealed_session_id(bytes));
            if (it == sessions.end() || !it->second->opener) return reject(false);
            uint64_t seq = 0;
            if (crypto::open_datagram(*it->second->opener, it->first, PROTOCOL_VERSION, bytes, opened_buf, seq) !=
                crypto::OpenResult::ok)
                return reject(false);  // forged, replayed, or unsealed
            sealed_by = it->second.get();
            bytes = opened_buf;
        }
        const wire::Datagram* d = verify_datagram(bytes);
        if (!d) return reject(true);
        // Sends `fbb` to the datagram's source only if it is smaller than what
        // came from there (never amplifies toward an unproven address; sealing
        // adds the same 32 bytes to both).
        auto answer = [&](Session& s, const flatbuffers::FlatBufferBuilder& fbb, bool unverified) {
            if (fbb.GetSize() >= bytes.size()) return;
            const size_t sent = send_datagram(s, {fbb.GetBufferPointer(), fbb.GetSize()}, udp_from);
            if (unverified) with_stats([&](ServerStats& st) { st.unverified_bytes_out += sent; });
        };
        auto find = [&](uint64_t id, uint64_t token) -> Session* {
            auto it = sessions.find(id);
            if (it == sessions.end() || !equal_u64(it->second->token, token)) return nullptr;
            Session* s = it->second.get();
            if (sealed_by && s != sealed_by) return nullptr;  // sealed under another session's key
            return s->state == State::Welcomed || s->state == State::Streaming ? s : nullptr;
        };
        auto bind_ack = [&](Session& s) {
            flatbuffers::FlatBufferBuilder fbb(64);
            auto ba = wire::CreateBindAck(fbb, s.id);
            fbb.Finish(wire::CreateDatagram(fbb, s.seq, now_us32(), wire::DatagramBody::BindAck, ba.Union()),
                       wire::DatagramIdentifier());
            answer(s, fbb, false);
        };
        const double now = now_seconds();
        if (d->body_type() == wire::DatagramBody::Bind) {
            const wire::Bind* b = d->body_as_Bind();
            Session* s = find(b->session_id(), b->token());
            if (!s) return reject(false);
            if (s->bound && s->peer == udp_from) return bind_ack(*s);  // already proven
            // A new address: only a Challenge goes there until its nonce comes
            // back from it. The same nonce is repeated for repeated Binds.
            if (s->challenge_peer != udp_from || now - s->challenge_sent > CHALLENGE_SECONDS) {
                randombytes_buf(s->challenge_nonce.data(), s->challenge_nonce.size());
                s->challenge_peer = udp_from;
                s->challenge_sent = now;
            }
            flatbuffers::FlatBufferBuilder fbb(96);
            auto nv = fbb.CreateVector(s->challenge_nonce.data(), s->challenge_nonce.size());
            auto ch = wire::CreateChallenge(fbb, s->id, nv);
            fbb.Finish(wire::CreateDatagram(fbb, s->seq, now_us32(), wire::DatagramBody::Challenge, ch.Union()),
                       wire::DatagramIdentifier());
            with_stats([](ServerStats& st) { ++st.challenges_sent; });
            return answer(*s, fbb, true);
        }
        if (d->body_type() == wire::DatagramBody::ChallengeResponse) {
            const wire::ChallengeResponse* r = d->body_as_ChallengeResponse();
            Session* s = find(r->session_id(), r->token());
            if (!s || !r->nonce() || r->nonce()->size() != CHALLENGE_NONCE || s->challenge_peer != udp_from ||
                now - s->challenge_sent > CHALLENGE_SECONDS ||
                sodium_memcmp(r->nonce()->data(), s->challenge_nonce.data(), CHALLENGE_NONCE) != 0)
                return reject(false);
            const bool moved = s->bound && s->peer != udp_from;
            s->peer = udp_from;
            s->bound = true;
            s->last_heard = now;
            s->challenge_sent = -1e300;  // one use
            if (s->state == State::Welcomed) s->state = State::Streaming;
            log("session " + hex64(s->id) + (moved ? " moved to " : " bound to ") + udp_from.address().to_string() + ":" +
                std::to_string(udp_from.port()));
            return bind_ack(*s);
        }
        if (d->body_type() == wire::DatagramBody::Ack) {
            const wire::Ack* a = d->body_as_Ack();
            Session* s = find(a->session_id(), a->token());
            if (!s || !s->bound || s->peer != udp_from) return reject(false);  // counts only from the bound address
            s->last_heard = now;
            s->rate.on_ack(a->ack(), a->ack_bits(), a->echo_time_us(), a->hold_us(), now_us32());
            return;
        }
        if (d->body_type() == wire::DatagramBody::Pose) {
            const wire::Pose* p = d->body_as_Pose();
            Session* s = find(p->session_id(), p->token());
            if (!s || !s->bound || s->peer != udp_from || s->state != State::Streaming) return reject(false);
            auto o = std::find_if(s->owned.begin(), s->owned.end(), [&](const Session::Owned& x) { return x.instance == p->instance(); });
            if (o == s->owned.end()) return reject(false);  // not this session's character (or despawned)
            const ServerAsset& a = *assets[size_t(encoder.spec(o->instance).asset)];
            const size_t rs = size_t(a.format.size());
            if (!p->root() || p->root()->size() != ROOT_BYTES || !p->records() || p->records()->size() == 0 ||
                p->records()->size() % rs != 0 || p->first() + p->records()->size() / rs > size_t(a.bone_count()))
                return reject(true);
            // Every record must decode to a finite unit rotation (smallest-three
            // components whose squares sum to at most 1) and a finite scale.
            for (size_t r = 0; r < p->records()->size() / rs; ++r)
                if (!record_valid(p->records()->data() + r * rs, a.format)) return reject(true);
            // Morph weights, when present: one per target (every int16 is a weight in [-2, 2)).
            const size_t morphs = std::min<size_t>(a.character.morphs.size(), MAX_MORPHS);
            if (p->morphs() && p->morphs()->size() != morphs) return reject(true);
            // Rate limit: a bucket of 2 s at twice the tick rate (poses beyond
            // it are dropped and counted, the newest wins anyway).
            const double now = now_seconds(), rate = 2.0 * cfg.tick_rate;
            o->tokens = std::min(2.0 * rate, o->tokens + (now - o->refilled) * rate);
            o->refilled = now;
            if (o->tokens < 1.0) {
                with_stats([](ServerStats& st) { ++st.poses_rate_limited; });
                return;
            }
            o->tokens -= 1.0;
            std::span<const uint8_t, ROOT_BYTES> root(p->root()->data(), ROOT_BYTES);
            std::span<const int16_t> weights;
            if (p->morphs()) weights = {p->morphs()->data(), p->morphs()->size()};
            if (encoder.push_records(o->instance, p->pose_seq(), p->epoch(), p->first(),
                                     {p->records()->data(), p->records()->size()}, root, weights))
                with_stats([](ServerStats& st) { ++st.poses_received; });
            else
                with_stats([](ServerStats& st) { ++st.poses_stale; });
            return;
        }
        reject(false);  // Frame / BindAck / Challenge are server -> client only
    }

    // --------------------------------------------------------------- tick --
    void schedule_tick() {
        next_tick += std::chrono::microseconds(int64_t(1e6 / cfg.tick_rate));
        auto now = std::chrono::steady_clock::now();
        if (next_tick < now - std::chrono::milliseconds(200)) next_tick = now;  // fell far behind: skip
        timer.expires_at(next_tick);
        timer.async_wait([this](asio::error_code ec) {
            if (ec) return;
            on_tick();
            schedule_tick();
        });
    }

    void on_tick() {
        const double t0 = now_seconds();
        const double dt = last_tick_time > 0 ? std::min(0.25, t0 - last_tick_time) : 1.0 / cfg.tick_rate;
        last_tick_time = t0;
        ++tick;
        bool any = false;
        for (auto& [id, s] : sessions) {
            if (s->state == State::Streaming) any = true;
            if (s->state == State::Welcomed || s->state == State::Streaming) sync_instances(s);
        }
        const EncodedFrame* frame = any ? &encoder.encode(tick) : nullptr;
        uint64_t dg = 0, bytes = 0, timeouts = 0;
        std::vector<std::shared_ptr<Session>> drop;
        for (auto& [id, s] : sessions) {
            if (s->state == State::Closing) {
                if (t0 > s->close_deadline) drop.push_back(s);
                continue;
            }
            if (s->state == State::AwaitHello && t0 - s->opened > cfg.hello_timeout) {
                drop.push_back(s);
                continue;
            }
            // Unbound: client_timeout after Welcome, whatever arrives over TCP.
            // Streaming: client_timeout after the newest Ack from the bound address.
            if ((s->state == State::Welcomed && t0 - s->welcomed > cfg.client_timeout) ||
                (s->state == State::Streaming && t0 - s->last_heard > cfg.client_timeout)) {
                drop.push_back(s);
                continue;
            }
            if (s->state != State::Streaming || !frame) continue;
            s->rate.refill(dt);
            s->rate.update(t0);
            size_t budget = s->rate.budget();
            if (!budget) continue;
            // Importance at every instance's current world position; none for
            // instances this client was not told about (yet) or owns.
            compute_importance(s->view, *frame, assets, s->id, s->importance);
            for (size_t i = 0; i < s->importance.size(); ++i)
                if (i >= s->known.size() || s->known[i] != frame->instances[i].generation) s->importance[i] = 0.0f;
            s->scheduler.select(*frame, assets, s->importance, budget, cfg.tick_rate, picks);
            if (s->scheduler.limited()) s->rate.mark_limited();
            if (picks.empty()) continue;
            out_dgrams.clear();
            uint32_t first_seq = s->seq;
            size_t wire = packer.pack(*frame, picks, s->seq, out_dgrams);
            for (size_t i = 0; i < out_dgrams.size(); ++i) {
                const size_t sent = send_datagram(*s, out_dgrams[i], s->peer);
                s->rate.on_sent(first_seq + uint32_t(i), now_us32(), sent + UDP_IP_OVERHEAD);
                wire += sent - out_dgrams[i].size();  // the seal's 32 bytes count against the rate
            }
            s->rate.spend(wire);
            s->scheduler.sent(picks, tick);
            dg += out_dgrams.size();
            bytes += wire;
        }
        for (auto& s : drop) {
            if (s->state == State::Closing) {  // the peer did not read its last message in time
                close(s, s->close_reason + " (not read)");
                continue;
            }
            ++timeouts;
            if (s->state == State::AwaitHello) {
                close(s, "timeout");
                continue;
            }
            flatbuffers::FlatBufferBuilder fbb;  // queued like any message: a peer that does not read cannot stall the tick
            build_goodbye(fbb, s->state == State::Welcomed ? "timeout: UDP address not bound" : "timeout: no acks");
            finish(s, fbb, "timeout");
        }
        const double t1 = now_seconds();
        with_stats([&](ServerStats& st) {
            ++st.ticks;
            st.datagrams_sent += dg;
            st.wire_bytes_sent += bytes;
            st.timeouts += timeouts;
            st.tick_seconds += t1 - t0;
            uint64_t active = 0;
            for (auto& [id, s] : sessions)
                if (s->state != State::Closed && s->state != State::Closing) ++active;
            st.sessions_active = active;
        });
    }
};

std::string read_spawn(const wire::Spawn& m, const std::vector<std::shared_ptr<ServerAsset>>& assets, uint64_t owner,
                       InstanceSpec& sp) {
    if (m.asset() >= assets.size()) return "no asset " + std::to_string(m.asset());
    const ServerAsset& a = *assets[m.asset()];
    sp = InstanceSpec{};
    sp.asset = m.asset();
    sp.selection = -1;
    sp.owner = owner;
    sp.once = m.once();
    sp.speed = m.speed();
    if (m.clips())
        for (int c : *m.clips()) {
            if (c < 0 || size_t(c) >= a.character.clips.size()) return "no clip " + std::to_string(c) + " in " + a.name;
            sp.announced_clips.push_back(c);
        }
    sp.publisher_start_us = m.publisher_start_us();
    if (m.walk_center()) sp.walk_center = {m.walk_center()->x(), m.walk_center()->y(), m.walk_center()->z()};
    sp.walk_radius = m.walk_radius();
    sp.walk_speed = m.walk_speed();
    if (m.position()) sp.position = {m.position()->x(), m.position()->y(), m.position()->z()};
    if (!std::isfinite(sp.speed) || !std::isfinite(sp.walk_radius) || !std::isfinite(sp.walk_speed) ||
        !std::isfinite(sp.walk_center.x) || !std::isfinite(sp.walk_center.y) || !std::isfinite(sp.walk_center.z) ||
        !std::isfinite(sp.position.x) || !std::isfinite(sp.position.y) || !std::isfinite(sp.position.z))
        return "spawn values must be finite";
    if (!(std::fabs(sp.position.x) < 2e6f && std::fabs(sp.position.y) < 2e6f && std::fabs(sp.position.z) < 2e6f))
        return "spawn position outside the world (+-2,000 km)";
    return {};
}

Server::Server(ServerConfig config, std::vector<std::shared_ptr<ServerAsset>> assets, std::vector<InstanceSpec> instances)
    : impl_(std::make_unique<Impl>(std::move(config), std::move(assets), std::move(instances))) {}

Server::~Server() = default;

uint16_t Server::tcp_port() const { return impl_->acceptor.local_endpoint().port(); }
uint16_t Server::udp_port() const { return impl_->udp_sock.local_endpoint().port(); }

void Server::run() {
    impl_->accept();
    impl_->receive();
    impl_->next_tick = std::chrono::steady_clock::now();
    impl_->schedule_tick();
    for (;;) {  // a handler's exception stops run() only: log it and go on serving
        try {
            impl_->io.run();
            return;
        } catch (const std::exception& e) {
            std::fprintf(stderr, "progskin-server: error: %s\n", e.what());
        }
    }
}

void Server::stop() {
    asio::post(impl_->io, [this] {
        asio::error_code ig;
        impl_->acceptor.close(ig);
        impl_->udp_sock.close(ig);
        impl_->timer.cancel();
        impl_->accept_timer.cancel();
        for (auto& [id, s] : impl_->sessions) {
            s->state = State::Closed;
            s->sock.close(ig);
        }
        impl_->io.stop();
    });
}

bool Server::push_pose(int instance, std::span<const Mat34> m) { return impl_->encoder.push_pose(instance, m); }
bool Server::set_root(int instance, const RootPose& root, bool teleport) { return impl_->encoder.set_root(instance, root, teleport); }
int Server::add_instance(const InstanceSpec& spec) { return impl_->add_instance(spec); }
void Server::remove_instance(int instance) { impl_->remove_instance(instance); }

ServerStats Server::stats() const {
    const EncoderStats es = impl_->encoder.stats();
    std::lock_guard lock(impl_->stats_mutex);
    ServerStats s = impl_->st;
    s.poses_out_of_range = es.poses_out_of_range;
    s.morphs_out_of_range = es.morphs_out_of_range;
    return s;
}

}  // namespace progskin::net
