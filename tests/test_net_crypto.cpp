// test_net_crypto.cpp — proto/crypto.h: sealed datagrams (tampering, wrong
// key or associated data, replays, the replay window against a reference
// model) and connect tokens (valid, expired, forged, for another server,
// replayed).
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cstdio>
#include <random>
#include <set>

#include "crypto.h"
#include "errors.h"

using namespace progskin::net::crypto;

namespace {
std::vector<uint8_t> bytes(size_t n, uint8_t seed) {
    std::vector<uint8_t> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = uint8_t(seed + 31 * i);
    return v;
}
}  // namespace

TEST(NetCrypto, SealedDatagramsOpenOnceAndOnlyIntact) {
    const Key key = random_key();
    Sealer sealer(key);
    Opener opener(key);
    const std::vector<uint8_t> ad = {4, 0, 1, 2, 3, 4, 5, 6, 7, 8};
    std::vector<uint8_t> sealed, plain;
    uint64_t seq = 0;
    for (size_t n : {size_t(0), size_t(1), size_t(100), size_t(1176)}) {
        const auto msg = bytes(n, uint8_t(n));
        sealer.seal(msg, ad, sealed);
        ASSERT_EQ(sealed.size(), n + SEAL_OVERHEAD);
        // Every single-byte change is caught.
        for (size_t i = 0; i < sealed.size(); ++i) {
            auto bad = sealed;
            bad[i] ^= 0x40;
            Opener fresh(key);
            EXPECT_NE(fresh.open(bad, ad, plain, seq), OpenResult::ok) << "byte " << i;
        }
        auto other_ad = ad;
        other_ad[1] ^= 1;
        EXPECT_EQ(Opener(key).open(sealed, other_ad, plain, seq), OpenResult::forged);
        EXPECT_EQ(Opener(random_key()).open(sealed, ad, plain, seq), OpenResult::forged);
        ASSERT_EQ(opener.open(sealed, ad, plain, seq), OpenResult::ok);
        EXPECT_EQ(plain, msg);
        EXPECT_EQ(opener.open(sealed, ad, plain, seq), OpenResult::replayed);  // the same datagram again
    }
    EXPECT_EQ(opener.open(std::vector<uint8_t>(SEAL_OVERHEAD - 1), ad, plain, seq), OpenResult::too_short);
}

// Stale::authenticate (the client's): a stale sequence is replayed only when
// its tag holds; a forged datagram under a stale sequence is forged. Neither
// is ever opened twice, and the window is left as it was.
TEST(NetCrypto, StaleSequencesAreAuthenticatedWhenAsked) {
    const Key key = random_key();
    Sealer sealer(key);
    Opener opener(key);
    const std::vector<uint8_t> ad = {1, 2, 3}, msg = {9, 8, 7, 6};
    std::vector<uint8_t> first, second, plain;
    sealer.seal(msg, ad, first);
    sealer.seal(msg, ad, second);
    uint64_t seq = 0;
    ASSERT_EQ(opener.open(first, ad, plain, seq, Stale::authenticate), OpenResult::ok);
    EXPECT_EQ(opener.open(first, ad, plain, seq, Stale::authenticate), OpenResult::replayed);  // a duplicate
    EXPECT_TRUE(plain.empty());
    std::vector<uint8_t> forged = first;
    forged[forged.size() / 2] ^= 1;
    EXPECT_EQ(opener.open(forged, ad, plain, seq, Stale::authenticate), OpenResult::forged);
    EXPECT_EQ(opener.open(forged, ad, plain, seq), OpenResult::replayed);  // drop: the tag is not looked at
    EXPECT_EQ(Opener(random_key()).open(first, ad, plain, seq, Stale::authenticate), OpenResult::forged);
    ASSERT_EQ(opener.open(second, ad, plain, seq, Stale::authenticate), OpenResult::ok);  // the window goes on
    EXPECT_EQ(plain, msg);
}

TEST(NetCrypto, ReplayWindowMatchesAReferenceModel) {
    std::mt19937_64 rng(5);
    ReplayWindow w;
    std::set<uint64_t> seen;
    uint64_t newest = 0;
    bool any = false;
    for (int i = 0; i < 200000; ++i) {
        // Mostly near the front, sometimes far back or far ahead.
        uint64_t base = any ? newest : 1000;
        uint64_t seq = base + 8 - rng() % 300;
        if (rng() % 50 == 0) seq = base + rng() % 1000;
        const bool expect = !seen.count(seq) && (!any || seq > newest || newest - seq < REPLAY_WINDOW);
        ASSERT_EQ(w.fresh(seq), expect) << "i=" << i << " seq=" << seq << " newest=" << newest;
        if (expect) {
            w.accept(seq);
            seen.insert(seq);
            if (!any || seq > newest) newest = seq;
            any = true;
        }
    }
}

TEST(NetCrypto, ReorderedDatagramsWithinTheWindowOpen) {
    const Key key = random_key();
    Sealer sealer(key);
    std::vector<std::vector<uint8_t>> sealed(300);
    for (auto& s : sealed) sealer.seal(bytes(50, 1), {}, s);
    Opener opener(key);
    std::vector<uint8_t> plain;
    uint64_t seq = 0;
    EXPECT_EQ(opener.open(sealed[299], {}, plain, seq), OpenResult::ok);
    EXPECT_EQ(seq, 299u);
    EXPECT_EQ(opener.open(sealed[299 - 255], {}, plain, seq), OpenResult::ok);      // inside the window
    EXPECT_EQ(opener.open(sealed[299 - 256], {}, plain, seq), OpenResult::replayed);  // just outside
    EXPECT_EQ(opener.open(sealed[10], {}, plain, seq), OpenResult::replayed);
}

TEST(NetCrypto, ConnectTokens) {
    PublicKey pk;
    SecretKey sk;
    signing_keypair(pk, sk);
    const uint64_t now = 1'800'000'000;
    const std::string addr = "203.0.113.7:7777";
    const std::string text = issue_connect_token(sk, 42, now, 30, addr);
    EXPECT_LE(text.size(), 216u);
    ConnectToken t;
    EXPECT_EQ(verify_connect_token(text, pk, now, addr, t), "");
    EXPECT_EQ(t.client_id, 42u);
    EXPECT_EQ(t.expires, now + 30);
    EXPECT_EQ(t.server_address, addr);
    EXPECT_EQ(verify_connect_token(text, pk, now, "", t), "");  // any server
    EXPECT_EQ(verify_connect_token(text, pk, now + 30, addr, t), "connect token expired");
    EXPECT_NE(verify_connect_token(text, pk, now, "198.51.100.1:7777", t).find("another server"), std::string::npos);
    PublicKey other_pk;
    SecretKey other_sk;
    signing_keypair(other_pk, other_sk);
    EXPECT_EQ(verify_connect_token(text, other_pk, now, addr, t), "connect token signature invalid");
    EXPECT_EQ(verify_connect_token(issue_connect_token(other_sk, 42, now, 30, addr), pk, now, addr, t),
              "connect token signature invalid");
    // Any changed character is refused (signature or format).
    for (size_t i = 0; i < text.size(); ++i) {
        std::string bad = text;
        bad[i] = bad[i] == 'A' ? 'B' : 'A';
        EXPECT_NE(verify_connect_token(bad, pk, now, addr, t), "") << i;
    }
    EXPECT_EQ(verify_connect_token("", pk, now, addr, t), "malformed connect token");
    EXPECT_EQ(verify_connect_token("not base64!", pk, now, addr, t), "malformed connect token");
    EXPECT_EQ(verify_connect_token(text.substr(0, 40), pk, now, addr, t), "malformed connect token");
    EXPECT_THROW(issue_connect_token(sk, 1, now, 30, std::string(65, 'x')), progskin::Error);
    // Replay: a token is accepted once until it expires.
    TokenReplayCache cache;
    ASSERT_EQ(verify_connect_token(text, pk, now, addr, t), "");
    EXPECT_TRUE(cache.first_use(t, now));
    EXPECT_FALSE(cache.first_use(t, now + 1));
    ConnectToken t2;
    ASSERT_EQ(verify_connect_token(issue_connect_token(sk, 42, now, 30, addr), pk, now, addr, t2), "");
    EXPECT_TRUE(cache.first_use(t2, now + 1));  // a new token for the same client is fine
    EXPECT_TRUE(cache.first_use(t, now + 31));  // expired nonces are forgotten (the token itself is refused as expired)
    EXPECT_EQ(cache.size(), 1u);
}

TEST(NetCrypto, HexRoundTrip) {
    PublicKey pk;
    SecretKey sk;
    signing_keypair(pk, sk);
    const std::string h = to_hex(pk);
    EXPECT_EQ(h.size(), 64u);
    PublicKey back{};
    EXPECT_TRUE(from_hex(h, back));
    EXPECT_EQ(back, pk);
    EXPECT_FALSE(from_hex(h.substr(2), back));
    EXPECT_FALSE(from_hex(h + "00", back));
    EXPECT_FALSE(from_hex(std::string(64, 'g'), back));
}

// `progskin token keygen` / `issue` print a key pair and a token the library verifies.
TEST(NetCrypto, TokenCommand) {
    auto run = [](const std::string& args) {
        std::string out;
        FILE* p = ::popen((std::string(PROGSKIN_BIN_DIR) + "/tools/progskin token " + args + " 2>&1").c_str(), "r");
        if (!p) return std::make_pair(-1, out);
        char buf[512];
        while (std::fgets(buf, sizeof buf, p)) out += buf;
        const int rc = ::pclose(p);
        return std::make_pair(WEXITSTATUS(rc), out);
    };
    auto [rc, keys] = run("keygen");
    ASSERT_EQ(rc, 0) << keys;
    const auto pub_at = keys.find("public "), sec_at = keys.find("secret ");
    ASSERT_NE(pub_at, std::string::npos);
    ASSERT_NE(sec_at, std::string::npos);
    PublicKey pk;
    ASSERT_TRUE(from_hex(keys.substr(pub_at + 7, 64), pk));
    const std::string sk_hex = keys.substr(sec_at + 7, 128);
    auto [rc2, token] = run("issue --secret-key " + sk_hex + " --client-id 99 --server 127.0.0.1:7777 --seconds 60");
    ASSERT_EQ(rc2, 0) << token;
    while (!token.empty() && token.back() == '\n') token.pop_back();
    ConnectToken t;
    EXPECT_EQ(verify_connect_token(token, pk, unix_now(), "127.0.0.1:7777", t), "");
    EXPECT_EQ(t.client_id, 99u);
    EXPECT_EQ(run("issue --client-id 1 --server x:1").first, 2);  // no key: usage error
    EXPECT_EQ(run("issue --secret-key 00 --client-id 1 --server x:1").first, 2);
}
