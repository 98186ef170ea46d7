// test_net_cli.cpp — the executables' contract: --help, exit codes, errors on
// stderr, and the JSON summary keys scripts read (progskin-client --report json);
// TLS by default: the server's fingerprint line, the pair it reuses, the
// client's --pin / --no-tls / --insecure.
#include <gtest/gtest.h>

#include "run_command.h"
#include "temp_dir.h"

#include <array>
#include <utility>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <iterator>

#include <unistd.h>

namespace {

std::string bin(const std::string& name) {
    const char* dir = name == "progskin-client" ? "/client/" : name == "progskin-attack" ? "/tests/" : "/server/";
    return std::string(PROGSKIN_BIN_DIR) + dir + name;
}

bool built(const std::string& name) { return std::ifstream(bin(name)).good(); }

// A progskin-server in the background (stdout to `out`); waits for its
// listening line and reads its TCP port and certificate fingerprint.
struct BackgroundServer {
    std::string out, port, pin;
    long pid = 0;
    BackgroundServer(const std::string& name, const std::string& args) {
        out = ::testing::TempDir() + name + ".out";
        std::remove(out.c_str());
        const std::string cmd = bin("progskin-server") + " " + args + " > " + out + " 2>" + out + ".err & echo $! > " + out + ".pid";
        if (std::system(cmd.c_str()) != 0) return;
        for (int i = 0; i < 1200 && port.empty(); ++i) {  // up to 60 s: plain files are built first
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            std::ifstream f(out);
            std::string line;
            while (std::getline(f, line)) {
                if (auto p = line.find("TCP "); p != std::string::npos) port = line.substr(p + 4, line.find(',', p) - p - 4);
                if (auto p = line.find("TLS certificate sha256 "); p != std::string::npos) pin = line.substr(p + 23);
            }
        }
        std::ifstream pf(out + ".pid");
        pf >> pid;
    }
    ~BackgroundServer() {  // it would stop by itself after its --duration
        if (pid > 0) std::system(("kill " + std::to_string(pid) + " 2>/dev/null").c_str());
    }
    std::string text() const {
        std::ifstream f(out);
        return std::string(std::istreambuf_iterator<char>(f), {});
    }
    std::string err() const {
        std::ifstream f(out + ".err");
        return std::string(std::istreambuf_iterator<char>(f), {});
    }
};

}  // namespace

TEST(NetCli, HelpAndExitCodes) {
    for (const char* name : {"progskin-server", "progskin-client", "progskin-netem", "progskin-attack"}) {
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
        {"progskin-server --build-strategy fastest", "--build-strategy"},
        {"progskin-server --build-training everything", "--build-training"},
        {"progskin-server --port 70000", "--port"},
        {"progskin-client --duration 1s", "--duration"},
        {"progskin-server --no-tls --seal-datagrams", "--no-tls"},
        {"progskin-server --tls-cert only.pem", "--tls-key"},
        {"progskin-client --no-tls --pin 00", "--pin"},
        {"progskin-client --pin abc --server 127.0.0.1:1", "--pin"},          // malformed: an argument error
        {"progskin-client --insecure --max-kbps -5 --server 127.0.0.1:1", "--max-kbps"},
        {"progskin-client --insecure --max-kbps 0.5 --server 127.0.0.1:1", "--max-kbps"},  // not silently unlimited
        {"progskin-netem --to 127.0.0.1:7777 --loss 2", "--loss"},
        {"progskin-netem --to 127.0.0.1:7777 --seed 1.5", "--seed"},
        {"progskin-attack --server 10.0.0.1:7777", "--server"},
        {"progskin-server --owner-share-kbps -5", "--owner-share-kbps"},
        {"progskin-server --threads 0", "--threads"},
        {"progskin-server --threads 257", "--threads"},
        {"progskin-server --threads 2x", "--threads"},
        {"progskin-server --fair-floor 1.5", "--fair-floor"},
        {"progskin-server --tick-rate 0", "--tick-rate"},
        {"progskin-server --max-clients 0", "--max-clients"},
        {"progskin-server --nats-queue 0", "--nats-queue"},
        {"progskin-server --nats-queue 2000000", "--nats-queue"},
        {"progskin-server --nats tls://127.0.0.1:1 --nats-cert only.pem", "--nats-key"},
        {"progskin-server --nats tls://127.0.0.1:1 --nats-ca /nonexistent/ca.pem", "--nats-ca /nonexistent/ca.pem: no such file"},
        {"progskin-server --nats-ca ca.pem", "need --nats"},
        {"progskin-attack --server 127.0.0.1:7777 --posers -1", "--posers"},
    };
    for (const auto& [cmd, option] : bad_values) {
        const std::string c = cmd;
        const std::string name = c.substr(0, c.find(' '));
        CmdResult r = run(bin(name) + c.substr(c.find(' ')));
        EXPECT_EQ(r.code, 2) << cmd;
        EXPECT_NE(r.out.find(option), std::string::npos) << cmd << ": " << r.out;
    }
    if (!built("progskin-client")) GTEST_SKIP();
    CmdResult refused = run(bin("progskin-client") + " --no-tls --server 127.0.0.1:1 --duration 1");
    EXPECT_EQ(refused.code, 1);
    EXPECT_NE(refused.out.find("cannot connect"), std::string::npos) << refused.out;
    // TLS is the default and trusts nothing silently: no --pin/--ca/--insecure is an argument error.
    CmdResult untrusted = run(bin("progskin-client") + " --server 127.0.0.1:1 --duration 1");
    EXPECT_EQ(untrusted.code, 2);
    EXPECT_NE(untrusted.out.find("--pin"), std::string::npos) << untrusted.out;
    CmdResult insecure = run(bin("progskin-client") + " --insecure --server 127.0.0.1:1 --duration 1");
    EXPECT_EQ(insecure.code, 1);
    EXPECT_NE(insecure.out.find("--insecure: the server's certificate is not verified"), std::string::npos) << insecure.out;
}

// The server's development default: a self-signed pair generated once in
// --tls-dir, its fingerprint on stdout, the same pair on the next start; a
// client pinning another fingerprint fails with a clear message.
TEST(NetCli, ServerPrintsItsFingerprintAndReusesItsPair) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    const std::string dir = ::testing::TempDir() + "progskin-cli-tls-" + std::to_string(::getpid());
    std::system(("rm -rf " + dir).c_str());
    const std::string args = "--port 0 --duration 10 --tls-dir " + dir + " --asset " + PROGSKIN_ASSETS + "/Fox.glb";
    std::string first_pin;
    {
        BackgroundServer s("progskin-cli-tls1", args);
        ASSERT_FALSE(s.port.empty()) << s.text();
        ASSERT_EQ(s.pin.size(), 64u) << s.text();
        EXPECT_NE(s.text().find("(generated)"), std::string::npos) << s.text();
        EXPECT_NE(s.text().find(dir + "/server-cert.pem"), std::string::npos) << s.text();
        first_pin = s.pin;
        std::string wrong = s.pin;
        wrong[0] = wrong[0] == '0' ? '1' : '0';
        CmdResult r = run(bin("progskin-client") + " --server 127.0.0.1:" + s.port + " --pin " + wrong + " --duration 1");
        EXPECT_EQ(r.code, 1);
        EXPECT_NE(r.out.find("does not match the pinned"), std::string::npos) << r.out;
    }
    BackgroundServer s("progskin-cli-tls2", args);
    ASSERT_FALSE(s.port.empty()) << s.text();
    EXPECT_EQ(s.pin, first_pin);
    EXPECT_NE(s.text().find("(reused)"), std::string::npos) << s.text();
    std::system(("rm -rf " + dir).c_str());
}

TEST(NetCli, ClientJsonSummaryHasTheDocumentedKeys) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    // TLS and sealed datagrams (the defaults), the pair in a temporary
    // directory; two tick threads and the control thread (--threads 2).
    BackgroundServer s("progskin-cli-server", "--port 0 --threads 2 --duration 15 --tls-dir " + ::testing::TempDir() +
                                                  "progskin-cli-tls --asset " + PROGSKIN_ASSETS + "/Fox.glb");
    ASSERT_FALSE(s.port.empty()) << s.text();
    ASSERT_EQ(s.pin.size(), 64u) << s.text();
    EXPECT_NE(s.text().find("TLS, sealed datagrams"), std::string::npos) << s.text();
    EXPECT_NE(s.text().find("2 tick threads + 1 for connections"), std::string::npos) << s.text();
    CmdResult r = run(bin("progskin-client") + " --server 127.0.0.1:" + s.port + " --pin " + s.pin +
                      " --max-kbps 64 --duration 2 --verify --report json --cache " + ::testing::TempDir() + "progskin-cli-cache");
    ASSERT_EQ(r.code, 0) << r.out;
    for (const char* key : {"\"seconds\"", "\"rate_kbps\"", "\"datagrams\"", "\"loss\"", "\"characters\"", "\"bones_mean\"",
                            "\"bones_min\"", "\"bones_max\"", "\"rms_pct\"", "\"max_pct\""})
        EXPECT_NE(r.out.find(key), std::string::npos) << key << " missing in " << r.out;
    EXPECT_NE(r.out.find("\"characters\": 3"), std::string::npos) << r.out;  // Fox: Survey, Walk, CmdResult
}

namespace {

// A progskin-client run in the background: its stdout and stderr in a file,
// then "EXIT <code>". wait() returns the exit code (-1: still running after `seconds`).
struct BackgroundClient {
    std::string out;
    BackgroundClient(const std::string& name, const std::string& args) {
        out = ::testing::TempDir() + name + ".out";
        std::remove(out.c_str());
        std::system(("(" + bin("progskin-client") + " " + args + "; echo \"EXIT $?\") > " + out + " 2>&1 &").c_str());
    }
    std::string text() const {
        std::ifstream f(out);
        return std::string(std::istreambuf_iterator<char>(f), {});
    }
    int wait(double seconds) const {
        for (int i = 0; i < int(seconds * 20); ++i) {
            const std::string t = text();
            if (auto p = t.find("EXIT "); p != std::string::npos) return std::atoi(t.c_str() + p + 5);
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        return -1;
    }
};

}  // namespace

// --report json is written on every exit: a server stopped by SIGTERM says
// Goodbye (the client reports server_goodbye, exit 3); a server killed
// outright closes the connection (an error, exit 1); both reports hold what
// was received until then.
TEST(NetCli, ReportWrittenOnEveryExitServerGoodbyeToldFromACrash) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    const std::string cache = " --cache " + ::testing::TempDir() + "progskin-cli-cache";
    for (const bool clean : {true, false}) {
        const std::string tag = clean ? "term" : "kill";
        BackgroundServer s("progskin-cli-bye-" + tag, "--no-tls --port 0 --duration 60 --asset " +
                                                           std::string(PROGSKIN_ASSETS) + "/Fox.glb");
        ASSERT_FALSE(s.port.empty()) << s.text();
        BackgroundClient c("progskin-cli-bye-client-" + tag,
                           "--no-tls --server 127.0.0.1:" + s.port + " --duration 30 --report json" + cache);
        std::this_thread::sleep_for(std::chrono::seconds(3));
        std::system(("kill " + std::string(clean ? "-TERM " : "-KILL ") + std::to_string(s.pid)).c_str());
        const int code = c.wait(10);
        const std::string out = c.text();
        EXPECT_EQ(code, clean ? 3 : 1) << tag << ": " << out;
        const size_t json_at = out.find("{\"seconds\"");
        ASSERT_NE(json_at, std::string::npos) << tag << ": no report in " << out;
        const std::string json = out.substr(json_at, out.find('\n', json_at) - json_at);
        EXPECT_NE(json.find("\"characters\": 3"), std::string::npos) << tag << ": " << json;  // received before the end
        EXPECT_EQ(json.find("\"datagrams\": 0,"), std::string::npos) << tag << ": " << json;
        EXPECT_NE(json.find(clean ? "\"server_goodbye\": true" : "\"server_goodbye\": false"), std::string::npos)
            << tag << ": " << json;
        if (clean) EXPECT_NE(json.find("\"error\": \"the server ended the session: shutdown: the server is stopping\""),
                             std::string::npos) << json;
        else EXPECT_NE(json.find("closed the control connection"), std::string::npos) << json;
        s.pid = 0;  // already gone
    }
    // No server at all: still a report, with the reason.
    CmdResult r = run(bin("progskin-client") + " --no-tls --server 127.0.0.1:1 --duration 1 --report json" + cache);
    EXPECT_EQ(r.code, 1);
    EXPECT_NE(r.out.find("\"error\": \""), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("cannot connect"), std::string::npos) << r.out;
}

// --server A,B: the first server killed outright (or stopped with its
// Goodbye), the client goes on with the second, spawns its character again
// and exits 0; the report says how many failovers and how long to stream.
TEST(NetCli, ServerListFailsOverToTheNextServer) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    const std::string cache = " --cache " + ::testing::TempDir() + "progskin-cli-cache";
    const std::string asset = " --asset " + std::string(PROGSKIN_ASSETS) + "/Fox.glb";
    for (const bool clean : {true, false}) {
        const std::string tag = clean ? "term" : "kill";
        BackgroundServer a("progskin-cli-failover-a-" + tag, "--no-tls --port 0 --duration 60" + asset);
        BackgroundServer b("progskin-cli-failover-b-" + tag, "--no-tls --port 0 --duration 60" + asset);
        ASSERT_FALSE(a.port.empty() || b.port.empty()) << a.text() << b.text();
        BackgroundClient c("progskin-cli-failover-client-" + tag, "--no-tls --server 127.0.0.1:" + a.port + ",127.0.0.1:" +
                                                                    b.port + " --duration 6 --publish 0 --report json" + cache);
        std::this_thread::sleep_for(std::chrono::seconds(3));
        std::system(("kill " + std::string(clean ? "-TERM " : "-KILL ") + std::to_string(a.pid)).c_str());
        a.pid = 0;
        const int code = c.wait(15);
        const std::string out = c.text();
        EXPECT_EQ(code, 0) << tag << ": " << out;
        const size_t at = out.find("\"failover\": {\"count\": ");
        ASSERT_NE(at, std::string::npos) << tag << ": " << out;
        EXPECT_EQ(std::atoi(out.c_str() + at + 22), 1) << tag << ": " << out;
        const size_t sec = out.find("\"seconds_to_stream\": ", at);
        ASSERT_NE(sec, std::string::npos) << out;
        const double seconds = std::atof(out.c_str() + sec + 21);
        EXPECT_GT(seconds, 0.0) << out;
        EXPECT_LT(seconds, 3.0) << out;
        EXPECT_NE(out.find("\"error\": \"\""), std::string::npos) << tag << ": " << out;
        std::printf("%s: streaming again %.3f s after losing the first server\n", tag.c_str(), seconds);
    }
    // A list that is not HOST:PORT entries: exit 2, naming the entry.
    const CmdResult r = run(bin("progskin-client") + " --no-tls --server 127.0.0.1:7777,nope --duration 1");
    EXPECT_EQ(r.code, 2) << r.out;
    EXPECT_NE(r.out.find("'nope' is not HOST:PORT"), std::string::npos) << r.out;
}

// The ports are bound before any asset is built: a port in use is an error
// at once (exit 1, naming the port), not after the build.
TEST(NetCli, PortInUseReportedBeforeAnyAssetIsBuilt) {
    if (!built("progskin-server")) GTEST_SKIP() << "progskin-server not built";
    BackgroundServer first("progskin-cli-port-first", "--no-tls --port 0 --duration 20 --asset " +
                                                          std::string(PROGSKIN_ASSETS) + "/Fox.glb");
    ASSERT_FALSE(first.port.empty()) << first.text();
    // An empty cache: this server would build the CesiumMan (seconds) before binding, as it used to.
    const std::string cache = ::testing::TempDir() + "progskin-cli-port-cache-" + std::to_string(::getpid());
    std::system(("rm -rf " + cache).c_str());
    const auto start = std::chrono::steady_clock::now();
    const CmdResult r = run(bin("progskin-server") + " --no-tls --port " + first.port + " --duration 5 --cache " + cache +
                            " --asset " + PROGSKIN_ASSETS + "/CesiumMan.glb");
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_EQ(r.code, 1) << r.out;
    EXPECT_NE(r.out.find("cannot listen on 0.0.0.0:" + first.port), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("in use"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("loading"), std::string::npos) << "built before binding: " << r.out;
    EXPECT_LT(seconds, 1.0) << r.out;
    std::system(("rm -rf " + cache).c_str());
}

// Two files of one name (every Sketchfab download is scene.gltf): the server
// says so with both paths, and a client that names one (--publish NAME) is
// refused with the indices instead of given the first; the index works.
TEST(NetCli, TwoAssetsOfOneNameAreSaidAndNeverPickedSilently) {
    if (!built("progskin-server") || !built("progskin-client")) GTEST_SKIP() << "executables not built";
    const std::filesystem::path dir = progskin::testing::process_temp_dir("progskin-cli-same-name-");
    std::filesystem::create_directories(dir / "a");
    std::filesystem::create_directories(dir / "b");
    // Two small self-contained files (their build is quick), both scene.gltf.
    std::filesystem::copy_file(std::string(PROGSKIN_ASSETS) + "/RiggedSimple.gltf", dir / "a" / "scene.gltf");
    std::filesystem::copy_file(std::string(PROGSKIN_TEST_DATA) + "/armature_m.gltf", dir / "b" / "scene.gltf");
    const std::string cache = " --cache " + (dir / "cache").string();
    BackgroundServer s("progskin-cli-same-name", "--no-tls --port 0 --duration 30 --asset " + (dir / "a" / "scene.gltf").string() +
                                                     " --asset " + (dir / "b" / "scene.gltf").string() + cache);
    ASSERT_FALSE(s.port.empty()) << s.text() << s.err();
    EXPECT_NE(s.err().find("are both named scene.gltf"), std::string::npos) << s.err();
    BackgroundClient by_name("progskin-cli-same-name-client", "--no-tls --server 127.0.0.1:" + s.port +
                                                                   " --duration 3 --publish scene.gltf --report json" + cache + "-c1");
    const int code = by_name.wait(20);
    EXPECT_NE(code, 0) << by_name.text();
    EXPECT_NE(by_name.text().find("2 assets of the catalogue have that name (indices 0, 1)"), std::string::npos) << by_name.text();
    BackgroundClient by_index("progskin-cli-same-name-index", "--no-tls --server 127.0.0.1:" + s.port +
                                                                   " --duration 3 --publish 1 --report json" + cache + "-c2");
    EXPECT_EQ(by_index.wait(20), 0) << by_index.text();
    std::filesystem::remove_all(dir);
}
