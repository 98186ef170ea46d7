// web_endpoint.h — the WebSocket transport for browser clients (issue 28;
// docs/protocol.md "WebSocket transport", docs/browser.md): a listener on
// ServerConfig::web_port serving RFC 6455 at the path /ws: plain ws://, or
// wss:// when the server has TLS (the control channel's certificate; every
// connection's TLS handshake first, within kRequestSeconds). One
// WebSocket connection is one server session (the same ServerCore /
// ClientStream as a TCP client). Binary messages only, the first byte the
// kind: 1 = one control message framed as on TCP (4-byte length, body),
// 2 = one datagram as on UDP. The session's datagram "address" is a
// synthetic IPv6 address (fd70:736b:7773::/48 + a connection number, port 0)
// whose datagrams are never sealed (ClientStream::never_seal),
// that the UDP socket (IPv4 only) can never see; the shell's sink hands
// datagrams to such addresses to send_datagram instead of sendto.
//
// Any other GET (or HEAD) is answered from the read-only static files of
// ServerConfig::web_root (web_files.h: the browser client's page), one
// response and the connection closed; such a connection opens no session.
//
// Bounds: at most kMaxPending connections waiting for their request (more
// are closed at once), each for at most kRequestSeconds; an incoming message at most 1 + 4 + MAX_CONTROL_MESSAGE bytes
// (a control message) or 1 + MAX_DATAGRAM (a datagram), else the connection
// is closed and counted (web_malformed); the HTTP upgrade request at most
// kMaxRequestBytes. Outgoing: datagrams waiting for one connection at most
// kMaxQueuedDatagramBytes (more are dropped like UDP loss, web_datagrams_dropped);
// control messages are never dropped: more than ServerConfig::max_queued_bytes
// of them waiting closes the session (backlog_closes), as on TCP.
//
// Threads: everything on the control io_context, under the core's mutex,
// except send_datagram, which the tick's threads call (it only appends to a
// per-connection queue under that connection's own lock and posts a flush).
#pragma once
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <span>

#include <asio.hpp>
#include <asio/ssl.hpp>

#include "server_core.h"
#include "web_files.h"

namespace progskin::net {

class WebEndpoint {
public:
    static constexpr size_t kMaxRequestBytes = 8192;
    static constexpr size_t kMaxQueuedDatagramBytes = 256 * 1024;
    static constexpr size_t kMaxPending = 64;        // connections before their request is handled
    static constexpr double kRequestSeconds = 10.0;  // to send the request (and receive a file)
    // Binds bind_address:port (0: ephemeral); throws Error.
    // web_root: the static files' folder (web_files.h), or empty. tls: the
    // control channel's TLS context (wss:// and https://), or nullptr (ws://).
    WebEndpoint(asio::io_context& io, ServerCore& core, DatagramSink& sink, const std::string& bind_address, uint16_t port,
                const std::string& web_root = {}, asio::ssl::context* tls = nullptr);
    ~WebEndpoint();
    uint16_t port() const { return port_; }
    void start();  // accepting
    // Control thread, core held: every connection's control output written, Closed sessions closed.
    void pump_all();
    // Control thread, core held: every session told Goodbye (stop()).
    void goodbye_all(const char* reason, double now);
    bool writing() const;  // control thread, core held: output still waiting
    void close_all();      // control thread
    // A synthetic address of this endpoint?
    static bool is_web(const PeerAddress& a);
    // Any thread (the tick's), the core held by the tick thread: queues one datagram for the
    // connection of `to` (kind 2), or drops and counts it when that queue is full.
    void send_datagram(std::span<const uint8_t> d, const PeerAddress& to);

    struct Conn;

private:
    void accept();
    void handshake(const std::shared_ptr<Conn>& c);
    // Before the upgrade (no session yet): the connection closed, counted when malformed.
    void drop_pending(const std::shared_ptr<Conn>& c, bool malformed);
    void read_frame(const std::shared_ptr<Conn>& c);
    void on_message(const std::shared_ptr<Conn>& c);
    void pump(const std::shared_ptr<Conn>& c);
    void write_next(const std::shared_ptr<Conn>& c);
    void flush(const std::shared_ptr<Conn>& c);
    // Closes c's session; malformed: counted (web_malformed); dead: the transport failed, nothing more is written.
    void fail(const std::shared_ptr<Conn>& c, const std::string& why, bool malformed, bool dead = false);

    asio::io_context& io_;
    ServerCore& core_;
    DatagramSink& sink_;
    asio::ip::tcp::acceptor acceptor_;
    uint16_t port_ = 0;
    uint64_t next_number_ = 1;
    std::map<uint64_t, std::shared_ptr<Conn>> by_number_;  // by address number; changed only with the core held
    std::map<uint64_t, std::shared_ptr<Conn>> conns_;          // by session id
    std::map<Conn*, std::shared_ptr<Conn>> pending_;           // before the request is handled (no session)
    asio::ssl::context* tls_ = nullptr;
    WebFiles files_;
};

// RFC 6455 pieces, shared with the tests' client: Sec-WebSocket-Accept for a
// key, and one unfragmented binary frame (masked with `mask` when non-null: a
// client's).
std::string websocket_accept(const std::string& key);
void websocket_frame(std::span<const uint8_t> payload, uint8_t kind, const uint8_t* mask, std::vector<uint8_t>& out);

}  // namespace progskin::net
