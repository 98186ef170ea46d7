// test_net_websocket.cpp — the WebSocket transport (server/web_endpoint.h,
// docs/protocol.md "WebSocket transport") over real loopback sockets: a
// native WebSocket client (a small RFC 6455 shell here, blocking Asio)
// drives a real ClientSession against a real Server with a web port; and a
// peer sending malformed or oversized messages is dropped and counted while
// a UDP client keeps streaming.
#include <gtest/gtest.h>
#include <poll.h>

#include <asio.hpp>
#include <deque>
#include <filesystem>
#include <fstream>

#include "errors.h"
#include "net_test_support.h"
#include "session.h"
#include "web_endpoint.h"
#include "web_files.h"
#include "wire.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;
using asio::ip::tcp;

namespace {

ServerConfig web_config() {
    ServerConfig c;
    c.web_port = 0;
    return c;
}

// A WebSocket client: the upgrade, masked binary messages out, whole messages in.
class WsClient {
public:
    explicit WsClient(uint16_t port, const std::string& path = "/ws") : sock_(io_) {
        sock_.connect({asio::ip::make_address("127.0.0.1"), port});
        const std::string req = "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                                "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";
        asio::write(sock_, asio::buffer(req));
        asio::streambuf b;
        const size_t n = asio::read_until(sock_, b, "\r\n\r\n");
        response_.assign(asio::buffers_begin(b.data()), asio::buffers_begin(b.data()) + std::ptrdiff_t(n));
        b.consume(n);
        rx_.assign(asio::buffers_begin(b.data()), asio::buffers_end(b.data()));
    }
    const std::string& response() const { return response_; }
    void send(uint8_t kind, std::span<const uint8_t> payload) {
        const uint8_t mask[4] = {0x12, 0x34, 0x56, 0x78};
        std::vector<uint8_t> f;
        websocket_frame(payload, kind, mask, f);
        send_raw(f);
    }
    void send_raw(std::span<const uint8_t> bytes) {
        asio::error_code ec;
        asio::write(sock_, asio::buffer(bytes.data(), bytes.size()), ec);
    }
    // The next whole message (kind byte first) within `ms`; false on timeout or close.
    bool receive(std::vector<uint8_t>& msg, int ms) {
        for (;;) {
            if (take(msg)) return true;
            pollfd p{sock_.native_handle(), POLLIN, 0};
            if (::poll(&p, 1, ms) <= 0) return false;
            uint8_t buf[65536];
            asio::error_code ec;
            const size_t n = sock_.read_some(asio::buffer(buf), ec);
            if (ec) {
                closed_ = true;
                return false;
            }
            rx_.insert(rx_.end(), buf, buf + n);
        }
    }
    bool closed() const { return closed_; }

private:
    bool take(std::vector<uint8_t>& msg) {
        if (rx_.size() < 2) return false;
        size_t n = rx_[1] & 0x7f, at = 2;
        if (n == 126) {
            if (rx_.size() < 4) return false;
            n = size_t(rx_[2]) << 8 | rx_[3];
            at = 4;
        } else if (n == 127) {
            if (rx_.size() < 10) return false;
            n = 0;
            for (int i = 0; i < 8; ++i) n = n << 8 | rx_[2 + size_t(i)];
            at = 10;
        }
        if (rx_.size() < at + n) return false;
        msg.assign(rx_.begin() + std::ptrdiff_t(at), rx_.begin() + std::ptrdiff_t(at + n));
        rx_.erase(rx_.begin(), rx_.begin() + std::ptrdiff_t(at + n));
        return true;
    }
    asio::io_context io_;
    tcp::socket sock_;
    std::string response_;
    std::vector<uint8_t> rx_;
    bool closed_ = false;
};

// The datagrams the WebSocket carried since the last update.
class Queue final : public DatagramSource {
public:
    bool next(std::span<const uint8_t>& bytes, bool& from_server, double& arrival) override {
        if (q_.empty()) return false;
        cur_ = std::move(q_.front().first);
        arrival = q_.front().second;
        q_.pop_front();
        bytes = cur_;
        from_server = true;
        return true;
    }
    void push(std::vector<uint8_t> d, double t) { q_.emplace_back(std::move(d), t); }

private:
    std::deque<std::pair<std::vector<uint8_t>, double>> q_;
    std::vector<uint8_t> cur_;
};

// The session's output onto the WebSocket: one kind-1 message per framed
// control message, one kind-2 message per datagram.
void send_outbox(WsClient& ws, Outbox& out) {
    size_t at = 0;
    while (out.control.size() - at >= 4) {
        uint32_t n = 0;
        read_length({out.control.data() + at, 4}, n);
        if (out.control.size() - at < 4 + size_t(n)) break;
        ws.send(1, {out.control.data() + at, 4 + size_t(n)});
        at += 4 + n;
    }
    out.control.erase(out.control.begin(), out.control.begin() + std::ptrdiff_t(at));
    for (size_t i = 0; i < out.datagrams(); ++i) ws.send(2, out.datagram(i));
    out.clear_datagrams();
}

}  // namespace

// Welcome, assets, Bind (its Challenge answered), and every scene character
// shown within 2 s of binding, everything over one WebSocket.
TEST(NetWebSocket, SessionStreamsOverWebSocket) {
    RunningServer s({}, web_config());
    ASSERT_GT(s.server->web_port(), 0);
    WsClient ws(s.server->web_port());
    ASSERT_NE(ws.response().find("101 Switching Protocols"), std::string::npos) << ws.response();
    ASSERT_NE(ws.response().find("Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo="), std::string::npos);  // RFC 6455 1.3

    ClientConfig cfg;
    cfg.cache_dir = RunningServer::cache_dir() + "/ws";
    Outbox out;
    ClientSession session(cfg, out);
    Queue q;
    session.start(now_seconds(), "127.0.0.1:" + std::to_string(s.server->web_port()));
    session.on_channel_ready();
    double bound_at = -1, all_at = -1;
    size_t messages = 0;
    const double end = now_seconds() + 15;
    std::vector<uint8_t> msg;
    while (now_seconds() < end && all_at < 0) {
        send_outbox(ws, out);
        while (ws.receive(msg, 5)) {
            ASSERT_FALSE(msg.empty());
            ++messages;
            if (msg[0] == 1) session.on_control_bytes({msg.data() + 1, msg.size() - 1}, now_seconds());
            else if (msg[0] == 2) q.push({msg.begin() + 1, msg.end()}, now_seconds());
            else FAIL() << "unknown kind " << int(msg[0]);
        }
        ASSERT_FALSE(ws.closed());
        const double now = now_seconds();
        session.update(now, &q);
        ASSERT_NE(session.phase(), SessionPhase::Failed) << session.error();
        if (bound_at < 0 && session.phase() == SessionPhase::Streaming) bound_at = now;
        // Shown: a pose at the display time, which only datagrams give (the
        // Spawn messages alone list the characters before any frame).
        size_t shown = 0;
        for (const RemoteCharacter& rc : session.characters()) shown += rc.shown ? 1 : 0;
        if (bound_at >= 0 && shown == 4) all_at = now;
        session.clear_events();
    }
    ASSERT_GE(bound_at, 0) << "never bound";
    ASSERT_GE(all_at, 0) << "characters listed: " << session.characters().size();
    EXPECT_LE(all_at - bound_at, 2.0);
    const ServerStats st = s.server->stats();
    EXPECT_EQ(st.web_sessions, 1u);
    EXPECT_EQ(st.web_malformed, 0u);
    EXPECT_EQ(st.rejected_datagrams, 0u);
    EXPECT_GT(st.datagrams_sent, 0u);
    std::printf("WebSocket: bound, 4 characters %.3f s later, %zu messages received, %llu datagrams sent\n",
                all_at - bound_at, messages, (unsigned long long)st.datagrams_sent);
}

// Malformed and oversized messages (and a request that is not an upgrade for
// /ws) each close their connection and are counted; a UDP client streaming
// meanwhile is not disturbed.
TEST(NetWebSocket, BadPeersAreDroppedWhileUdpStreams) {
    RunningServer s({}, web_config());
    ClientReport report;
    std::thread udp([&] { report = run_client(s.client(3.0)); });
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    std::vector<uint8_t> msg;
    const auto dropped = [&](WsClient& ws) {
        while (ws.receive(msg, 2000)) {
        }
        return ws.closed();
    };
    {  // an unknown kind
        WsClient ws(s.server->web_port());
        const uint8_t b[3] = {7, 7, 7};
        ws.send(9, b);
        EXPECT_TRUE(dropped(ws));
    }
    {  // a control message whose length disagrees with the message
        WsClient ws(s.server->web_port());
        const uint8_t b[6] = {0, 0, 0, 9, 1, 2};
        ws.send(1, b);
        EXPECT_TRUE(dropped(ws));
    }
    {  // a datagram over MAX_DATAGRAM
        WsClient ws(s.server->web_port());
        std::vector<uint8_t> b(MAX_DATAGRAM + 1, 0);
        ws.send(2, b);
        EXPECT_TRUE(dropped(ws));
    }
    {  // a header announcing 2^40 bytes: refused before anything is allocated
        WsClient ws(s.server->web_port());
        const uint8_t h[14] = {0x82, 0xff, 0, 0, 1, 0, 0, 0, 0, 0, 1, 2, 3, 4};
        ws.send_raw(h);
        EXPECT_TRUE(dropped(ws));
    }
    {  // an unmasked frame
        WsClient ws(s.server->web_port());
        const uint8_t f[4] = {0x82, 0x02, 2, 0};
        ws.send_raw(f);
        EXPECT_TRUE(dropped(ws));
    }
    {  // not /ws: 404 and closed
        WsClient ws(s.server->web_port(), "/other");
        EXPECT_NE(ws.response().find("404"), std::string::npos) << ws.response();
    }
    udp.join();
    const ServerStats st = s.server->stats();
    EXPECT_EQ(st.web_malformed, 6u);
    EXPECT_EQ(st.refusals.count("web_message_too_large") ? st.refusals.at("web_message_too_large") : 0u, 1u);
    EXPECT_EQ(report.characters, 4);
    EXPECT_GE(report.datagrams, 60u);
    EXPECT_EQ(report.malformed, 0u);
}

namespace {
// One raw HTTP request on a fresh connection; the whole response (the server closes).
std::string http(uint16_t port, const std::string& request) {
    asio::io_context io;
    tcp::socket s(io);
    s.connect({asio::ip::make_address("127.0.0.1"), port});
    asio::write(s, asio::buffer(request));
    std::string out;
    asio::error_code ec;
    char buf[65536];
    for (;;) {
        const size_t n = s.read_some(asio::buffer(buf), ec);
        if (ec) break;
        out.append(buf, n);
    }
    return out;
}
std::string get(uint16_t port, const std::string& target) {
    return http(port, "GET " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n");
}
}  // namespace

// The web port also serves the page's static files (web_files.h): index.html
// for "/", the wasm as application/wasm, HEAD without a body; "..", escapes,
// hidden files, symbolic links out of the root and other methods refused;
// no session is opened for a file request; the WebSocket still works beside.
TEST(NetWebSocket, StaticFilesServedReadOnlyAndBounded) {
    namespace fs = std::filesystem;
    const fs::path root = fs::path(RunningServer::cache_dir()) / "web-root";
    fs::remove_all(root);
    fs::create_directories(root / "sub");
    std::ofstream(root / "index.html") << "<!doctype html><title>t</title>";
    std::ofstream(root / "client.wasm") << std::string("\0asm\1\0\0\0", 8);
    std::ofstream(root / "sub" / "x.js") << "export {};";
    std::ofstream(root / ".hidden") << "secret";
    std::ofstream(root.parent_path() / "outside.txt") << "outside";
    std::error_code ec;
    fs::create_symlink(root.parent_path() / "outside.txt", root / "escape.txt", ec);
    ASSERT_FALSE(ec) << ec.message();

    ServerConfig cfg = web_config();
    cfg.web_root = root.string();
    RunningServer s({}, cfg);
    const uint16_t port = s.server->web_port();
    std::string r = get(port, "/");
    EXPECT_EQ(r.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << r;
    EXPECT_NE(r.find("Content-Type: text/html; charset=utf-8\r\n"), std::string::npos) << r;
    EXPECT_NE(r.find("<!doctype html>"), std::string::npos);
    r = get(port, "/client.wasm?v=1");
    EXPECT_EQ(r.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << r;
    EXPECT_NE(r.find("Content-Type: application/wasm\r\n"), std::string::npos) << r;
    EXPECT_NE(r.find("Content-Length: 8\r\n"), std::string::npos) << r;
    r = get(port, "/sub/x.js");
    EXPECT_NE(r.find("Content-Type: text/javascript; charset=utf-8\r\n"), std::string::npos) << r;
    r = http(port, "HEAD /index.html HTTP/1.1\r\n\r\n");
    EXPECT_EQ(r.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << r;
    EXPECT_EQ(r.find("<!doctype"), std::string::npos) << "HEAD has no body";
    for (const char* bad : {"/../outside.txt", "/sub/../index.html", "/%2e%2e/outside.txt", "/.hidden", "//index.html",
                            "/a\\b", "index.html"})
        EXPECT_EQ(get(port, bad).rfind("HTTP/1.1 400 ", 0), 0u) << bad;
    EXPECT_EQ(get(port, "/escape.txt").rfind("HTTP/1.1 404 ", 0), 0u) << "a link out of the root";
    EXPECT_EQ(get(port, "/missing.js").rfind("HTTP/1.1 404 ", 0), 0u);
    EXPECT_EQ(get(port, "/" + std::string(300, 'a')).rfind("HTTP/1.1 400 ", 0), 0u) << "target over kMaxTarget";
    EXPECT_EQ(http(port, "POST /index.html HTTP/1.1\r\nContent-Length: 0\r\n\r\n").rfind("HTTP/1.1 405 ", 0), 0u);
    // A request over kMaxRequestBytes: closed, counted.
    EXPECT_EQ(http(port, "GET /" + std::string(WebEndpoint::kMaxRequestBytes, 'a')), "");

    WsClient ws(port);  // the WebSocket beside the files
    EXPECT_NE(ws.response().find("101 Switching Protocols"), std::string::npos) << ws.response();
    const ServerStats st = s.server->stats();
    EXPECT_EQ(st.web_files_served, 4u);  // /, wasm, x.js, HEAD (none of the refusals)
    EXPECT_EQ(st.web_sessions, 1u);      // only the WebSocket opened a session
    EXPECT_EQ(st.web_malformed, 1u);     // the oversized request

    // Without a root every file is 404 saying how to build the page.
    int status = 0;
    const auto none = WebFiles("").respond("GET", "/index.html", status);
    EXPECT_EQ(status, 404);
    EXPECT_NE(std::string(none.begin(), none.end()).find("scripts/build_web.sh"), std::string::npos);
    EXPECT_THROW(WebFiles((root / "index.html").string()), Error);
}
