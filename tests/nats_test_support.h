// nats_test_support.h — a real nats-server on loopback for the world tests
// (tests/test_net_world.cpp, tests/test_net_loadgen.cpp): started on a free
// port by the test and killed by it; the tests skip without nats-server.
#pragma once
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

namespace progskin::net::testing {

inline bool have_nats_server() { return std::system("command -v nats-server >/dev/null 2>&1") == 0; }

// A loopback TCP port free now (the kernel's choice; another process may take it before use).
inline uint16_t free_port() {
    const int s = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t n = sizeof a;
    ::bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a);
    ::getsockname(s, reinterpret_cast<sockaddr*>(&a), &n);
    ::close(s);
    return ntohs(a.sin_port);
}

// Whether something accepts TCP connections on the loopback port.
inline bool accepts(uint16_t port) {
    const int s = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(port);
    const bool ok = ::connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    ::close(s);
    return ok;
}

// A real nats-server on 127.0.0.1:port, started (waiting up to 2 s until it
// accepts) and killed by the test; stop() and start() again on the same port
// make a restart.
class NatsServer {
public:
    // args: more nats-server options (e.g. --tls --tlscert FILE --tlskey FILE).
    explicit NatsServer(uint16_t port, std::vector<std::string> args = {}) : port_(port), args_(std::move(args)) { start(); }
    ~NatsServer() { stop(); }
    NatsServer(const NatsServer&) = delete;
    NatsServer& operator=(const NatsServer&) = delete;
    void start() {
        pid_ = ::fork();
        if (pid_ == 0) {
            const std::string p = std::to_string(port_);
            std::vector<const char*> argv{"nats-server", "-a", "127.0.0.1", "-p", p.c_str()};
            for (const std::string& a : args_) argv.push_back(a.c_str());
            argv.push_back(nullptr);
            ::execvp("nats-server", const_cast<char* const*>(argv.data()));
            ::_exit(127);
        }
        for (int i = 0; i < 200 && !accepts(port_); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    void stop() {
        if (pid_ <= 0) return;
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
        pid_ = 0;
    }
    uint16_t port() const { return port_; }
    std::string url() const { return "nats://127.0.0.1:" + std::to_string(port_); }

private:
    uint16_t port_;
    std::vector<std::string> args_;
    pid_t pid_ = 0;
};

}  // namespace progskin::net::testing
