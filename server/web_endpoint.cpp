// web_endpoint.cpp — see web_endpoint.h. A small RFC 6455 server over the
// project's standalone Asio (websocketpp 0.8.2 does not compile as C++20:
// see docs/browser.md), the handshake's SHA-1 and base64 from OpenSSL.
#include "web_endpoint.h"

#include <openssl/evp.h>
#include <openssl/sha.h>

#include <algorithm>
#include <cstring>
#include <deque>
#include <mutex>

#include "errors.h"
#include "wire.h"

namespace progskin::net {

using asio::ip::tcp;

namespace {

constexpr uint8_t kPrefix[6] = {0xfd, 0x70, 0x73, 0x6b, 0x77, 0x73};  // fd70:736b:7773::/48 ("psk" "ws")
constexpr uint8_t kKindControl = 1, kKindDatagram = 2;
constexpr size_t kMaxMessage = 1 + 4 + MAX_CONTROL_MESSAGE;
constexpr double kLingerSeconds = 2.0;  // a closed session's last messages

PeerAddress web_address(uint64_t number) {
    PeerAddress a;
    a.v6 = true;
    std::copy(std::begin(kPrefix), std::end(kPrefix), a.ip.begin());
    for (int i = 0; i < 8; ++i) a.ip[8 + i] = uint8_t(number >> (56 - 8 * i));
    return a;
}

uint64_t number_of(const PeerAddress& a) {
    uint64_t n = 0;
    for (int i = 0; i < 8; ++i) n = n << 8 | a.ip[8 + i];
    return n;
}

PeerAddress peer_ip(const asio::ip::address& a) {
    PeerAddress p;
    if (a.is_v4()) {
        const auto b = a.to_v4().to_bytes();
        std::copy(b.begin(), b.end(), p.ip.begin());
    } else {
        const auto b = a.to_v6().to_bytes();
        std::copy(b.begin(), b.end(), p.ip.begin());
        p.scope = uint32_t(a.to_v6().scope_id());
        p.v6 = true;
    }
    return p;
}

// The value of an HTTP header (case-insensitive name), trimmed; empty when absent.
std::string header(const std::string& req, const std::string& name) {
    std::string lower = req;
    std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
    const size_t at = lower.find("\r\n" + name + ":");
    if (at == std::string::npos) return {};
    const size_t from = at + 3 + name.size(), end = req.find("\r\n", from);
    std::string v = req.substr(from, end - from);
    v.erase(0, v.find_first_not_of(" \t"));
    v.erase(v.find_last_not_of(" \t") + 1);
    return v;
}

}  // namespace

std::string websocket_accept(const std::string& key) {
    const std::string in = key + "258EAFA5-E914-47DA-95CA-C5AB0DC85B11";
    unsigned char digest[SHA_DIGEST_LENGTH];
    SHA1(reinterpret_cast<const unsigned char*>(in.data()), in.size(), digest);
    unsigned char b64[64];
    const int n = EVP_EncodeBlock(b64, digest, SHA_DIGEST_LENGTH);
    return std::string(reinterpret_cast<const char*>(b64), size_t(n));
}

void websocket_frame(std::span<const uint8_t> payload, uint8_t kind, const uint8_t* mask, std::vector<uint8_t>& out) {
    const size_t n = payload.size() + 1;  // the kind byte first
    out.push_back(0x82);                  // FIN, binary
    const uint8_t m = mask ? 0x80 : 0;
    if (n < 126) out.push_back(uint8_t(m | n));
    else if (n <= 0xffff) out.insert(out.end(), {uint8_t(m | 126), uint8_t(n >> 8), uint8_t(n)});
    else {
        out.push_back(uint8_t(m | 127));
        for (int i = 7; i >= 0; --i) out.push_back(uint8_t(uint64_t(n) >> (8 * i)));
    }
    if (mask) out.insert(out.end(), mask, mask + 4);
    const size_t start = out.size();
    out.push_back(kind);
    out.insert(out.end(), payload.begin(), payload.end());
    if (mask)
        for (size_t i = 0; i < n; ++i) out[start + i] ^= mask[i % 4];
}

struct WebEndpoint::Conn {
    tcp::socket sock;
    std::unique_ptr<asio::ssl::stream<tcp::socket&>> tls;  // wss:// (the endpoint has a TLS context)
    std::shared_ptr<ClientStream> stream;
    PeerAddress address;
    asio::streambuf request{kMaxRequestBytes};
    uint8_t head[14];
    std::vector<uint8_t> message;
    std::deque<std::vector<uint8_t>> writes;  // encoded frames, the front being written
    size_t control_bytes = 0;                 // of them, control messages
    bool writing = false, closed = false, upgraded = false;
    bool dead = false, lingering = false;  // dead: a transport error (nothing more is written)
    asio::steady_timer linger;
    std::mutex dmutex;                         // the datagram queue (tick threads)
    std::vector<std::vector<uint8_t>> datagrams;
    size_t datagram_bytes = 0;                 // queued + in `writes`
    bool flush_posted = false;
    Conn(tcp::socket s, asio::io_context& io) : sock(std::move(s)), linger(io) {}
};

namespace {
// The connection's byte stream: TLS over the socket for wss://, else the socket.
template <class Buffers, class Handler>
void read_all(WebEndpoint::Conn& c, const Buffers& b, Handler&& h) {
    if (c.tls) asio::async_read(*c.tls, b, std::forward<Handler>(h));
    else asio::async_read(c.sock, b, std::forward<Handler>(h));
}
template <class Buffers, class Handler>
void write_all(WebEndpoint::Conn& c, const Buffers& b, Handler&& h) {
    if (c.tls) asio::async_write(*c.tls, b, std::forward<Handler>(h));
    else asio::async_write(c.sock, b, std::forward<Handler>(h));
}
}  // namespace

WebEndpoint::WebEndpoint(asio::io_context& io, ServerCore& core, DatagramSink& sink, const std::string& bind_address,
                         uint16_t port, const std::string& web_root, asio::ssl::context* tls)
    : io_(io), core_(core), sink_(sink), acceptor_(io), tls_(tls), files_(web_root) {
    asio::error_code ec;
    const tcp::endpoint ep(asio::ip::make_address(bind_address, ec), port);
    if (!ec) acceptor_.open(ep.protocol(), ec);
    if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor_.bind(ep, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) throw Error("cannot listen (web) on " + bind_address + ":" + std::to_string(port) + ": " + ec.message());
    port_ = acceptor_.local_endpoint().port();
}

WebEndpoint::~WebEndpoint() = default;

bool WebEndpoint::is_web(const PeerAddress& a) { return a.v6 && std::equal(std::begin(kPrefix), std::end(kPrefix), a.ip.begin()); }

void WebEndpoint::start() { accept(); }

void WebEndpoint::accept() {
    acceptor_.async_accept([this](asio::error_code ec, tcp::socket s) {
        if (ec == asio::error::operation_aborted || !acceptor_.is_open()) return;
        if (!ec) {
            asio::error_code ig;
            s.set_option(tcp::no_delay(true), ig);
            std::lock_guard lock(core_.mutex());
            if (pending_.size() >= kMaxPending) {  // too many waiting for their request: closed at once
                core_.refused("web_too_many_pending");
                s.close(ig);
            } else {
                auto c = std::make_shared<Conn>(std::move(s), io_);
                pending_[c.get()] = c;
                c->linger.expires_after(std::chrono::milliseconds(int(kRequestSeconds * 1000)));
                c->linger.async_wait([this, c](asio::error_code e) {
                    if (e) return;
                    std::lock_guard l(core_.mutex());
                    if (!c->upgraded && !c->closed) drop_pending(c, false);
                });
                if (!tls_) {
                    handshake(c);
                } else {  // wss:// (and https:// for the files): the TLS handshake first, within kRequestSeconds
                    c->tls = std::make_unique<asio::ssl::stream<tcp::socket&>>(c->sock, *tls_);
                    c->tls->async_handshake(asio::ssl::stream_base::server, [this, c](asio::error_code e) {
                        std::lock_guard l(core_.mutex());
                        if (c->closed) return;
                        if (e) {
                            core_.count([](ServerStats& st) { ++st.tls_failures; });
                            return drop_pending(c, false);
                        }
                        handshake(c);
                    });
                }
            }
        }
        accept();
    });
}

void WebEndpoint::drop_pending(const std::shared_ptr<Conn>& c, bool malformed) {
    if (malformed) core_.count([](ServerStats& st) { ++st.web_malformed; });
    c->closed = true;
    c->linger.cancel();
    asio::error_code ig;
    c->sock.shutdown(tcp::socket::shutdown_both, ig);
    c->sock.close(ig);
    pending_.erase(c.get());
}

// The request: GET /ws with Upgrade: websocket and a key opens a session and
// is answered 101 (then frames); another GET or HEAD is answered from the
// static files and closed; anything else 404 or 405, closed and counted.
void WebEndpoint::handshake(const std::shared_ptr<Conn>& c) {
    auto on_request = [this, c](asio::error_code ec, size_t n) {
        std::lock_guard lock(core_.mutex());
        if (c->closed) return;
        if (ec) return drop_pending(c, ec == asio::error::not_found);  // not_found: over kMaxRequestBytes
        const std::string req(asio::buffers_begin(c->request.data()), asio::buffers_begin(c->request.data()) + std::ptrdiff_t(n));
        c->request.consume(n);
        const std::string key = header(req, "sec-websocket-key");
        std::string upgrade = header(req, "upgrade");
        std::transform(upgrade.begin(), upgrade.end(), upgrade.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
        if (upgrade.empty() && c->request.size() == 0) {  // a plain HTTP request: a static file
            const size_t sp1 = req.find(' '), sp2 = sp1 == std::string::npos ? sp1 : req.find(' ', sp1 + 1);
            const size_t eol = req.find("\r\n");
            if (sp1 == std::string::npos || sp2 == std::string::npos || sp2 > eol) return drop_pending(c, true);
            int status = 0;
            auto bytes = std::make_shared<std::vector<uint8_t>>(
                files_.respond(req.substr(0, sp1), req.substr(sp1 + 1, sp2 - sp1 - 1), status));
            if (status == 200) core_.count([](ServerStats& st) { ++st.web_files_served; });
            write_all(*c, asio::buffer(*bytes), [this, c, bytes](asio::error_code, size_t) {
                std::lock_guard l(core_.mutex());
                if (!c->closed) drop_pending(c, false);
            });
            return;
        }
        if (req.rfind("GET /ws ", 0) != 0 || upgrade != "websocket" || key.empty() || c->request.size() != 0) {
            static const std::string no = "HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n";
            core_.count([](ServerStats& st) { ++st.web_malformed; });
            write_all(*c, asio::buffer(no), [this, c](asio::error_code, size_t) {
                std::lock_guard l(core_.mutex());
                if (!c->closed) drop_pending(c, false);
            });
            return;
        }
        // A WebSocket: one session, as a TCP connection is.
        pending_.erase(c.get());
        c->linger.cancel();
        asio::error_code ig;
        const auto remote = c->sock.remote_endpoint(ig).address();
        if (ig) {
            c->closed = true;
            c->sock.close(ig);
            return;
        }
        c->stream = core_.open(peer_ip(remote), now_seconds());
        c->stream->never_seal();  // its datagrams travel inside this connection
        core_.count([](ServerStats& st) { ++st.web_sessions; });
        if (c->stream->state() != SessionState::AwaitHello) {  // refused: closed without a word
            c->closed = true;
            c->sock.close(ig);
            asio::post(io_, [this, id = c->stream->id()] {
                std::lock_guard l(core_.mutex());
                core_.erase(id, now_seconds());
            });
            return;
        }
        c->address = web_address(next_number_++);
        conns_[c->stream->id()] = c;
        by_number_[number_of(c->address)] = c;
        const std::string ok = "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                               "Sec-WebSocket-Accept: " + websocket_accept(key) + "\r\n\r\n";
        c->writes.emplace_back(ok.begin(), ok.end());
        c->control_bytes += ok.size();
        c->upgraded = true;
        pump(c);
        read_frame(c);
    };
    if (c->tls) asio::async_read_until(*c->tls, c->request, "\r\n\r\n", on_request);
    else asio::async_read_until(c->sock, c->request, "\r\n\r\n", on_request);
}

// One frame: a client's, masked, unfragmented, binary (or ping, pong, close).
void WebEndpoint::read_frame(const std::shared_ptr<Conn>& c) {
    read_all(*c, asio::buffer(c->head, 2), [this, c](asio::error_code ec, size_t) {
        std::lock_guard lock(core_.mutex());
        if (c->closed) return;
        if (ec) return fail(c, "web read: " + ec.message(), false, true);
        const uint8_t op = c->head[0] & 0x0f, len7 = c->head[1] & 0x7f;
        if ((c->head[0] & 0xf0) != 0x80 || !(c->head[1] & 0x80) || (op != 2 && op != 8 && op != 9 && op != 10))
            return fail(c, "web: not a masked unfragmented binary frame", true);
        const size_t extra = (len7 == 126 ? 2 : len7 == 127 ? 8 : 0) + 4;
        read_all(*c, asio::buffer(c->head + 2, extra), [this, c, op, len7, extra](asio::error_code ec2, size_t) {
            std::lock_guard lock2(core_.mutex());
            if (c->closed) return;
            if (ec2) return fail(c, "web read: " + ec2.message(), false, true);
            uint64_t n = len7;
            for (size_t i = 0; i + 4 < extra; ++i) n = (i ? n : 0) << 8 | c->head[2 + i];
            if (n > kMaxMessage || (op != 2 && n > 125)) {
                core_.refused("web_message_too_large");
                return fail(c, "web: message of " + std::to_string(n) + " bytes", true);
            }
            c->message.resize(size_t(n) + 1);
            c->message[0] = op;  // the opcode, then the payload
            read_all(*c, asio::buffer(c->message.data() + 1, size_t(n)), [this, c, extra](asio::error_code ec3, size_t) {
                std::lock_guard lock3(core_.mutex());
                if (c->closed) return;
                if (ec3) return fail(c, "web read: " + ec3.message(), false, true);
                const uint8_t* mask = c->head + 2 + extra - 4;
                for (size_t i = 1; i < c->message.size(); ++i) c->message[i] ^= mask[(i - 1) % 4];
                on_message(c);
            });
        });
    });
}

// A whole message (the opcode first): a control message to the stream, a
// datagram to the core, a ping answered, a close closing.
void WebEndpoint::on_message(const std::shared_ptr<Conn>& c) {
    const uint8_t op = c->message[0];
    const std::span<const uint8_t> payload(c->message.data() + 1, c->message.size() - 1);
    if (op == 8) return fail(c, "web: closed by the peer", false, true);
    if (op == 9) {
        std::vector<uint8_t> pong{0x8a, uint8_t(payload.size())};
        pong.insert(pong.end(), payload.begin(), payload.end());
        c->control_bytes += pong.size();
        c->writes.push_back(std::move(pong));
    } else if (op == 2 && !payload.empty() && payload[0] == kKindDatagram) {
        if (payload.size() - 1 > MAX_DATAGRAM) return fail(c, "web: datagram too large", true);
        try {
            core_.on_datagram(payload.subspan(1), c->address, now_seconds(), sink_);
        } catch (const std::exception& e) {
            core_.count([](ServerStats& st) { ++st.handler_errors; });
        }
    } else if (op == 2 && payload.size() >= 5 && payload[0] == kKindControl) {
        uint32_t n = 0;
        read_length(payload.subspan(1, 4), n);
        if (n != payload.size() - 5) return fail(c, "web: control length " + std::to_string(n) + " does not match", true);
        if (!c->stream->accept_length(n)) return pump(c);
        bool more = false;
        try {
            more = c->stream->on_control(payload.subspan(5), now_seconds());
        } catch (const std::exception& e) {
            core_.count([](ServerStats& st) { ++st.handler_errors; });
            c->stream->close(std::string("error: ") + e.what());
        }
        pump(c);
        if (!more || !c->stream->is_open()) return;
    } else if (op == 2) {
        return fail(c, "web: unknown message kind", true);
    }
    pump(c);
    read_frame(c);
}

// The session closed on a failure of its connection; `malformed`: counted as the peer's fault.
void WebEndpoint::fail(const std::shared_ptr<Conn>& c, const std::string& why, bool malformed, bool dead) {
    if (malformed) core_.count([](ServerStats& st) { ++st.web_malformed; });
    c->dead = c->dead || dead;
    c->stream->close(why);
    pump(c);
}

// Core held, control thread: control output framed (kind 1) and written; a Closed session's connection closed.
void WebEndpoint::pump(const std::shared_ptr<Conn>& c) {
    if (c->closed) return;
    if (c->stream->state() == SessionState::Closed) {
        // Its last messages (a Refuse, a Goodbye) written first, for at most
        // kLingerSeconds; not after a transport error.
        if (!c->dead && (c->writing || !c->writes.empty())) {
            if (!c->writing) write_next(c);
            if (!std::exchange(c->lingering, true)) {
                c->linger.expires_after(std::chrono::milliseconds(int(kLingerSeconds * 1000)));
                c->linger.async_wait([this, c](asio::error_code ec) {
                    if (ec) return;
                    std::lock_guard lock(core_.mutex());
                    c->dead = true;
                    pump(c);
                });
            }
            return;
        }
        c->closed = true;
        c->linger.cancel();
        asio::error_code ig;
        c->sock.shutdown(tcp::socket::shutdown_both, ig);
        c->sock.close(ig);
        by_number_.erase(number_of(c->address));
        asio::post(io_, [this, id = c->stream->id()] {
            std::lock_guard lock(core_.mutex());
            conns_.erase(id);
            core_.erase(id, now_seconds());
        });
        return;
    }
    if (c->upgraded) {
        while (!c->stream->output().empty()) {
            const auto& m = c->stream->output().front();
            std::vector<uint8_t> f;
            websocket_frame(m, kKindControl, nullptr, f);
            c->control_bytes += f.size();
            c->writes.push_back(std::move(f));
            c->stream->on_written();
        }
        if (c->control_bytes > core_.config().max_queued_bytes) {
            core_.count([](ServerStats& st) { ++st.backlog_closes; });
            c->stream->close("web: control backlog over " + std::to_string(core_.config().max_queued_bytes) + " bytes");
            return pump(c);
        }
    }
    if (!c->writing && !c->writes.empty()) write_next(c);
}

void WebEndpoint::write_next(const std::shared_ptr<Conn>& c) {
    c->writing = true;
    write_all(*c, asio::buffer(c->writes.front()), [this, c](asio::error_code ec, size_t) {
        std::lock_guard lock(core_.mutex());
        c->writing = false;
        if (c->closed) return;
        const std::vector<uint8_t>& done = c->writes.front();
        if (!done.empty() && done[0] == 0x82 && done.size() > 2) {
            const size_t at = (done[1] & 0x7f) == 126 ? 4 : (done[1] & 0x7f) == 127 ? 10 : 2;
            if (done[at] == kKindDatagram) {
                std::lock_guard l(c->dmutex);
                c->datagram_bytes -= done.size();
            } else c->control_bytes -= done.size();
        } else c->control_bytes -= std::min(c->control_bytes, done.size());
        c->writes.pop_front();
        if (ec) {
            c->dead = true;
            c->stream->close("web write: " + ec.message());
            return pump(c);
        }
        pump(c);
    });
}

void WebEndpoint::send_datagram(std::span<const uint8_t> d, const PeerAddress& to) {
    const auto it = by_number_.find(number_of(to));
    if (it == by_number_.end()) return;  // gone: lost
    const std::shared_ptr<Conn>& c = it->second;
    std::vector<uint8_t> f;
    websocket_frame(d, kKindDatagram, nullptr, f);
    std::lock_guard lock(c->dmutex);
    if (c->datagram_bytes + f.size() > kMaxQueuedDatagramBytes) {
        core_.count([](ServerStats& st) { ++st.web_datagrams_dropped; });
        return;
    }
    c->datagram_bytes += f.size();
    c->datagrams.push_back(std::move(f));
    if (!std::exchange(c->flush_posted, true)) asio::post(io_, [this, c] { flush(c); });
}

// Control thread: the datagrams the tick queued, behind what is being written.
void WebEndpoint::flush(const std::shared_ptr<Conn>& c) {
    std::lock_guard lock(core_.mutex());
    std::vector<std::vector<uint8_t>> ds;
    {
        std::lock_guard l(c->dmutex);
        c->flush_posted = false;
        ds.swap(c->datagrams);
    }
    if (c->closed) return;
    for (auto& d : ds) c->writes.push_back(std::move(d));
    pump(c);
}

void WebEndpoint::pump_all() {
    for (auto& [id, c] : conns_) pump(c);
}

void WebEndpoint::goodbye_all(const char* reason, double now) {
    asio::error_code ig;
    acceptor_.close(ig);
    for (auto& [id, c] : conns_) {
        c->stream->goodbye(reason, now);
        pump(c);
    }
}

bool WebEndpoint::writing() const {
    for (const auto& [id, c] : conns_)
        if (!c->closed && (c->writing || !c->writes.empty())) return true;
    return false;
}

void WebEndpoint::close_all() {
    asio::error_code ig;
    acceptor_.close(ig);
    for (auto& [p, c] : pending_) {
        c->closed = true;
        c->linger.cancel();
        c->sock.close(ig);
    }
    pending_.clear();
    for (auto& [id, c] : conns_) {
        c->closed = true;
        c->sock.close(ig);
    }
}

}  // namespace progskin::net
