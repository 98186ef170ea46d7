// bench_net_crypto.cpp — cost of sealing and opening a datagram
// (proto/crypto.h, XChaCha20-Poly1305 + replay window) and of checking a
// connect token, per call on one core. Bytes: SEAL_OVERHEAD (24) per datagram.
#include <benchmark/benchmark.h>

#include "crypto.h"

using namespace progskin::net::crypto;

static void BM_Seal(benchmark::State& st) {
    const Key key = random_key();
    Sealer sealer(key);
    std::vector<uint8_t> plain(size_t(st.range(0)), 0x5a), out;
    const uint8_t ad[10] = {4, 0, 1, 2, 3, 4, 5, 6, 7, 8};
    for (auto _ : st) {
        sealer.seal(plain, ad, out);
        benchmark::DoNotOptimize(out.data());
    }
    st.SetBytesProcessed(int64_t(st.iterations()) * st.range(0));
    st.counters["overhead_bytes"] = double(SEAL_OVERHEAD);
}
BENCHMARK(BM_Seal)->Arg(100)->Arg(600)->Arg(1176);

static void BM_Open(benchmark::State& st) {
    const Key key = random_key();
    Sealer sealer(key);
    std::vector<uint8_t> plain(size_t(st.range(0)), 0x5a), out;
    const uint8_t ad[10] = {4, 0, 1, 2, 3, 4, 5, 6, 7, 8};
    // A stream of sealed datagrams, opened in order (each is new to the window).
    std::vector<std::vector<uint8_t>> sealed(4096);
    for (auto& s : sealed) sealer.seal(plain, ad, s);
    Opener opener(key);
    size_t i = 0;
    uint64_t seq = 0;
    for (auto _ : st) {
        if (i == sealed.size()) {
            st.PauseTiming();
            for (auto& s : sealed) sealer.seal(plain, ad, s);
            i = 0;
            st.ResumeTiming();
        }
        benchmark::DoNotOptimize(opener.open(sealed[i++], ad, out, seq));
    }
    st.SetBytesProcessed(int64_t(st.iterations()) * st.range(0));
}
BENCHMARK(BM_Open)->Arg(100)->Arg(600)->Arg(1176);

static void BM_VerifyConnectToken(benchmark::State& st) {
    PublicKey pk;
    SecretKey sk;
    signing_keypair(pk, sk);
    const std::string text = issue_connect_token(sk, 7, unix_now(), 60, "127.0.0.1:7777");
    ConnectToken t;
    for (auto _ : st) benchmark::DoNotOptimize(verify_connect_token(text, pk, unix_now(), "127.0.0.1:7777", t));
}
BENCHMARK(BM_VerifyConnectToken);

BENCHMARK_MAIN();
