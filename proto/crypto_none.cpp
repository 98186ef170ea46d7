// crypto_none.cpp — crypto.h without libsodium: the build option
// PROGSKIN_CRYPTO=OFF (the WebAssembly client, web/CMakeLists.txt) links this
// file instead of crypto.cpp. available() is false and every function that
// would need libsodium throws Error(UNAVAILABLE); ClientSession checks
// available() before it makes a Sealer or Opener, so a keyed (sealed)
// Welcome fails with that reason (FailReason::Config) rather than here.
// The helpers of crypto.h that need no libsodium (ReplayWindow, hex, token
// cache) are not part of such a build.
#include "crypto.h"

#include "errors.h"

namespace progskin::net::crypto {

bool available() { return false; }

namespace {
[[noreturn]] void unavailable() { throw Error(UNAVAILABLE); }
}  // namespace

void init() { unavailable(); }
void random_bytes(std::span<uint8_t>) { unavailable(); }
Key random_key() { unavailable(); }
void Sealer::seal(std::span<const uint8_t>, std::span<const uint8_t>, std::vector<uint8_t>&) { unavailable(); }
void Sealer::seal_to(std::span<const uint8_t>, std::span<const uint8_t>, uint8_t*) { unavailable(); }
OpenResult Opener::open(std::span<const uint8_t>, std::span<const uint8_t>, std::vector<uint8_t>&, uint64_t&, Stale) {
    unavailable();
}
void seal_datagram(Sealer&, uint64_t, uint16_t, std::span<const uint8_t>, std::vector<uint8_t>&) { unavailable(); }
OpenResult open_datagram(Opener&, uint64_t, uint16_t, std::span<const uint8_t>, std::vector<uint8_t>&, uint64_t&, Stale) {
    unavailable();
}
void signing_keypair(PublicKey&, SecretKey&) { unavailable(); }
std::string issue_connect_token(const SecretKey&, uint64_t, uint64_t, uint64_t, const std::string&) { unavailable(); }
std::string verify_connect_token(const std::string&, const PublicKey&, uint64_t, const std::string&, ConnectToken&) {
    unavailable();
}

}  // namespace progskin::net::crypto
