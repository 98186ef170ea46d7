// test_net_cli.cpp — the executables' contract: --help, exit codes, errors on
// stderr, and the JSON summary keys scripts read (progskin-client --report json).
#include <gtest/gtest.h>

#include <array>
#include <utility>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>

namespace {

std::string bin(const std::string& name) {
    return std::string(PROGSKIN_BIN_DIR) + (name == "progskin-client" ? "/client/" : "/server/") + name;
}

struct CmdResult {
    int code = -1;
    std::string out;
};

CmdResult run(const std::string& cmd) {
    CmdResult r;
    FILE* p = ::popen((cmd + " 2>&1").c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf;
    size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
    int st = ::pclose(p);
    r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    return r;
}

bool built(const std::string& name) { return std::ifstream(bin(name)).good(); }

}  // namespace

TEST(NetCli, HelpAndExitCodes) {
    for (const char* name : {"progskin-server", "progskin-client", "progskin-netem"}) {
        if (!built(name)) GTEST_SKIP() << name << " not built";
        CmdResult h = run(bin(name) + " --help");
        EXPECT_EQ(h.code, 0) << name;
        EXPECT_NE(h.out.find("usage:"), std::string::npos) << name;
        CmdResult bad = run(bin(name) + " --no-such-flag");
        EXPECT_EQ(bad.code, 2) << name;
    }
    // Numbers are parsed whole and the error names the option (exit 2, nothing started).
    const std::pair<const char*, const char*> bad_values[] = {
        {"progskin-server --crowd 3x", "--crowd"},
        {"progskin-server --port 70000", "--port"},
        {"progskin-client --duration 1s", "--duration"},
        {"progskin-netem --to 127.0.0.1:7777 --loss 2", "--loss"},
        {"progskin-netem --to 127.0.0.1:7777 --seed 1.5", "--seed"},
    };
    for (const auto& [cmd, option] : bad_values) {
        const std::string c = cmd;
        const std::string name = c.substr(0, c.find(' '));
        CmdResult r = run(bin(name) + c.substr(c.find(' ')));
        EXPECT_EQ(r.code, 2) << cmd;
        EXPECT_NE(r.out.find(option), std::string::npos) << cmd << ": " << r.out;
    }
    if (!built("progskin-client")) GTEST_SKIP();
    CmdResult refused = run(bin("progskin-client") + " --server 127.0.0.1:1 --duration 1");
    EXPECT_EQ(refused.code, 1);
    EXPECT_NE(refused.out.find("cannot connect"), std::string::npos) << refused.out;
}

TEST(NetCli, ClientJsonSummaryHasTheDocumentedKeys) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    const std::string out = ::testing::TempDir() + "progskin-cli-server.out";
    std::string cmd = bin("progskin-server") + " --port 0 --duration 15 --asset " + PROGSKIN_ASSETS +
                      "/Fox.glb > " + out + " 2>/dev/null & echo $! > " + out + ".pid";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    std::string port;
    for (int i = 0; i < 200 && port.empty(); ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        std::ifstream f(out);
        std::string line;
        while (std::getline(f, line)) {
            auto p = line.find("TCP ");
            if (p != std::string::npos) port = line.substr(p + 4, line.find(',', p) - p - 4);
        }
    }
    ASSERT_FALSE(port.empty());
    CmdResult r = run(bin("progskin-client") + " --server 127.0.0.1:" + port + " --max-kbps 64 --duration 2 --verify --report json --cache " +
                ::testing::TempDir() + "progskin-cli-cache");
    {  // stop the server (it would stop by itself after 15 s)
        std::ifstream pf(out + ".pid");
        long pid = 0;
        if (pf >> pid && pid > 0) std::system(("kill " + std::to_string(pid)).c_str());
    }
    ASSERT_EQ(r.code, 0) << r.out;
    for (const char* key : {"\"seconds\"", "\"rate_kbps\"", "\"datagrams\"", "\"loss\"", "\"characters\"", "\"bones_mean\"",
                            "\"bones_min\"", "\"bones_max\"", "\"rms_pct\"", "\"max_pct\""})
        EXPECT_NE(r.out.find(key), std::string::npos) << key << " missing in " << r.out;
    EXPECT_NE(r.out.find("\"characters\": 3"), std::string::npos) << r.out;  // Fox: Survey, Walk, CmdResult
}
