// crypto.cpp — see crypto.h.
#include "crypto.h"

#include <sodium.h>

#include <chrono>
#include <cstring>

#include "errors.h"

namespace progskin::net::crypto {

namespace {

void put_u64(std::vector<uint8_t>& out, uint64_t v) {
    for (int i = 0; i < 8; ++i) out.push_back(uint8_t(v >> (8 * i)));
}

uint64_t get_u64(const uint8_t* p) {
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= uint64_t(p[i]) << (8 * i);
    return v;
}

void make_nonce(uint64_t seq, uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES]) {
    std::memset(nonce, 0, crypto_aead_xchacha20poly1305_ietf_NPUBBYTES);
    for (int i = 0; i < 8; ++i) nonce[i] = uint8_t(seq >> (8 * i));
}

constexpr size_t TOKEN_FIXED = 1 + 8 + 8 + TOKEN_NONCE_BYTES + 1;  // before the address
static_assert(crypto_aead_xchacha20poly1305_ietf_KEYBYTES == KEY_BYTES);
static_assert(crypto_aead_xchacha20poly1305_ietf_ABYTES == 16);
static_assert(crypto_sign_PUBLICKEYBYTES == PUBLIC_KEY_BYTES && crypto_sign_SECRETKEYBYTES == SECRET_KEY_BYTES);
static_assert(crypto_sign_BYTES == SIGNATURE_BYTES);

}  // namespace

bool available() { return true; }

void init() {
    if (sodium_init() < 0) throw Error("libsodium could not be initialised");
}

void random_bytes(std::span<uint8_t> out) {
    init();
    randombytes_buf(out.data(), out.size());
}

Key random_key() {
    Key k;
    init();
    crypto_aead_xchacha20poly1305_ietf_keygen(k.data());
    return k;
}

bool ReplayWindow::fresh(uint64_t seq) const {
    if (!any_ || seq > newest_) return true;
    if (newest_ - seq >= REPLAY_WINDOW) return false;  // too old to tell
    return !(bits_[(seq % REPLAY_WINDOW) / 64] >> (seq % 64) & 1);
}

void ReplayWindow::accept(uint64_t seq) {
    if (!any_ || seq > newest_) {
        // Clear the bits of the sequences that enter the window unseen.
        const uint64_t from = any_ ? newest_ + 1 : seq;
        if (!any_ || seq - from >= REPLAY_WINDOW) bits_.fill(0);
        else
            for (uint64_t s = from; s < seq; ++s) bits_[(s % REPLAY_WINDOW) / 64] &= ~(uint64_t(1) << (s % 64));
        newest_ = seq;
        any_ = true;
    }
    bits_[(seq % REPLAY_WINDOW) / 64] |= uint64_t(1) << (seq % 64);
}

void Sealer::seal(std::span<const uint8_t> plain, std::span<const uint8_t> ad, std::vector<uint8_t>& out) {
    out.resize(plain.size() + SEAL_OVERHEAD);
    seal_to(plain, ad, out.data());
}

void Sealer::seal_to(std::span<const uint8_t> plain, std::span<const uint8_t> ad, uint8_t* out) {
    const uint64_t seq = seq_++;
    for (int i = 0; i < 8; ++i) out[i] = uint8_t(seq >> (8 * i));
    uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
    make_nonce(seq, nonce);
    unsigned long long n = 0;
    crypto_aead_xchacha20poly1305_ietf_encrypt(out + 8, &n, plain.data(), plain.size(), ad.data(), ad.size(), nullptr, nonce,
                                               key_.data());
}

const char* to_string(OpenResult r) {
    switch (r) {
        case OpenResult::ok: return "ok";
        case OpenResult::too_short: return "too short";
        case OpenResult::replayed: return "replayed or too old";
        case OpenResult::forged: return "authentication failed";
    }
    return "?";
}

OpenResult Opener::open(std::span<const uint8_t> sealed, std::span<const uint8_t> ad, std::vector<uint8_t>& plain,
                        uint64_t& seq, Stale stale) {
    if (sealed.size() < SEAL_OVERHEAD) return OpenResult::too_short;
    seq = get_u64(sealed.data());
    const bool fresh = window_.fresh(seq);
    if (!fresh && stale == Stale::drop) return OpenResult::replayed;  // before spending time on the tag
    uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
    make_nonce(seq, nonce);
    plain.resize(sealed.size() - SEAL_OVERHEAD);
    unsigned long long n = 0;
    if (crypto_aead_xchacha20poly1305_ietf_decrypt(plain.data(), &n, nullptr, sealed.data() + 8, sealed.size() - 8, ad.data(),
                                                   ad.size(), nonce, key_.data()) != 0) {
        plain.clear();
        return OpenResult::forged;
    }
    if (!fresh) {  // authentic, but opened before (or too old): never opened twice
        plain.clear();
        return OpenResult::replayed;
    }
    plain.resize(size_t(n));
    window_.accept(seq);
    return OpenResult::ok;
}

namespace {
std::array<uint8_t, 10> datagram_ad(uint64_t session_id, uint16_t version) {
    std::array<uint8_t, 10> ad{};
    for (int i = 0; i < 8; ++i) ad[size_t(i)] = uint8_t(session_id >> (8 * i));
    ad[8] = uint8_t(version);
    ad[9] = uint8_t(version >> 8);
    return ad;
}
}  // namespace

void seal_datagram(Sealer& sealer, uint64_t session_id, uint16_t version, std::span<const uint8_t> plain,
                   std::vector<uint8_t>& out) {
    const auto ad = datagram_ad(session_id, version);
    out.resize(8 + plain.size() + SEAL_OVERHEAD);  // no allocation once `out` has grown to the largest datagram
    for (int i = 0; i < 8; ++i) out[size_t(i)] = uint8_t(session_id >> (8 * i));
    sealer.seal_to(plain, ad, out.data() + 8);
}

uint64_t sealed_session_id(std::span<const uint8_t> wire) {
    return wire.size() < SEALED_DATAGRAM_OVERHEAD ? 0 : get_u64(wire.data());
}

OpenResult open_datagram(Opener& opener, uint64_t session_id, uint16_t version, std::span<const uint8_t> wire,
                         std::vector<uint8_t>& plain, uint64_t& seq, Stale stale) {
    if (wire.size() < SEALED_DATAGRAM_OVERHEAD) return OpenResult::too_short;
    if (get_u64(wire.data()) != session_id) return OpenResult::forged;
    const auto ad = datagram_ad(session_id, version);
    return opener.open(wire.subspan(8), ad, plain, seq, stale);
}

// ------------------------------------------------------------ tokens --

void signing_keypair(PublicKey& pk, SecretKey& sk) {
    init();
    crypto_sign_keypair(pk.data(), sk.data());
}

std::string issue_connect_token(const SecretKey& sk, uint64_t client_id, uint64_t now_unix, uint64_t seconds,
                                const std::string& server_address) {
    init();
    if (server_address.size() > MAX_TOKEN_ADDRESS)
        throw Error("server address over " + std::to_string(MAX_TOKEN_ADDRESS) + " bytes: " + server_address);
    std::vector<uint8_t> t;
    t.push_back(1);
    put_u64(t, client_id);
    put_u64(t, now_unix + seconds);
    uint8_t nonce[TOKEN_NONCE_BYTES];
    randombytes_buf(nonce, sizeof nonce);
    t.insert(t.end(), nonce, nonce + sizeof nonce);
    t.push_back(uint8_t(server_address.size()));
    t.insert(t.end(), server_address.begin(), server_address.end());
    const size_t signed_len = t.size();
    t.resize(signed_len + SIGNATURE_BYTES);
    crypto_sign_detached(t.data() + signed_len, nullptr, t.data(), signed_len, sk.data());
    std::string text(sodium_base64_ENCODED_LEN(t.size(), sodium_base64_VARIANT_URLSAFE_NO_PADDING), '\0');
    sodium_bin2base64(text.data(), text.size(), t.data(), t.size(), sodium_base64_VARIANT_URLSAFE_NO_PADDING);
    text.resize(std::strlen(text.c_str()));
    return text;
}

std::string verify_connect_token(const std::string& text, const PublicKey& pk, uint64_t now_unix,
                                 const std::string& server_address, ConnectToken& out) {
    init();
    std::vector<uint8_t> t(text.size());
    size_t len = 0;
    if (text.empty() || sodium_base642bin(t.data(), t.size(), text.data(), text.size(), nullptr, &len, nullptr,
                                          sodium_base64_VARIANT_URLSAFE_NO_PADDING) != 0)
        return "malformed connect token";
    t.resize(len);
    if (t.size() < TOKEN_FIXED + SIGNATURE_BYTES || t[0] != 1) return "malformed connect token";
    const size_t addr_len = t[TOKEN_FIXED - 1];
    if (addr_len > MAX_TOKEN_ADDRESS || t.size() != TOKEN_FIXED + addr_len + SIGNATURE_BYTES) return "malformed connect token";
    const size_t signed_len = TOKEN_FIXED + addr_len;
    if (crypto_sign_verify_detached(t.data() + signed_len, t.data(), signed_len, pk.data()) != 0)
        return "connect token signature invalid";
    out.client_id = get_u64(t.data() + 1);
    out.expires = get_u64(t.data() + 9);
    std::memcpy(out.nonce.data(), t.data() + 17, TOKEN_NONCE_BYTES);
    out.server_address.assign(reinterpret_cast<const char*>(t.data()) + TOKEN_FIXED, addr_len);
    if (out.expires <= now_unix) return "connect token expired";
    if (!server_address.empty() && out.server_address != server_address)
        return "connect token for another server (" + out.server_address + ")";
    return "";
}

bool TokenReplayCache::first_use(const ConnectToken& t, uint64_t now_unix) {
    if (now_unix >= next_sweep_) {  // forget expired nonces, at most once a second
        std::erase_if(seen_, [&](const auto& e) { return e.second <= now_unix; });
        next_sweep_ = now_unix + 1;
    }
    const std::string key(reinterpret_cast<const char*>(t.nonce.data()), t.nonce.size());
    return seen_.emplace(key, t.expires).second;
}

std::string to_hex(std::span<const uint8_t> bytes) {
    std::string s(bytes.size() * 2 + 1, '\0');
    sodium_bin2hex(s.data(), s.size(), bytes.data(), bytes.size());
    s.pop_back();
    return s;
}

bool from_hex(const std::string& hex, std::span<uint8_t> out) {
    size_t len = 0;
    return sodium_hex2bin(out.data(), out.size(), hex.data(), hex.size(), nullptr, &len, nullptr) == 0 && len == out.size() &&
           hex.size() == out.size() * 2;
}

uint64_t unix_now() {
    using namespace std::chrono;
    return uint64_t(duration_cast<seconds>(system_clock::now().time_since_epoch()).count());
}

}  // namespace progskin::net::crypto
