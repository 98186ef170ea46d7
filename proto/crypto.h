// crypto.h — the cryptographic pieces of the streaming protocol, all from
// libsodium (no hand-written primitives): sealed datagrams with a replay
// window, and connect tokens signed by a backend (docs/protocol.md
// "Security"). Nothing here touches sockets.
//
// Sealed datagram (XChaCha20-Poly1305-IETF, one key per direction):
//     [sequence: uint64 LE][ciphertext of the plain datagram][tag: 16 bytes]
//   nonce = sequence (8 bytes LE) followed by 16 zero bytes; associated data
//   chosen by the caller (e.g. protocol version + session id), authenticated
//   but not sent. SEAL_OVERHEAD = 24 bytes per datagram. A sender never
//   reuses a sequence under one key; the receiver drops what fails the tag,
//   what it has already accepted and what is older than the replay window
//   (REPLAY_WINDOW sequences behind the newest accepted), as netcode does.
//
// Connect token (Ed25519, crypto_sign_detached), base64url without padding:
//     [version: uint8 = 1][client_id: uint64 LE][expires: uint64 LE, Unix seconds]
//     [nonce: 16 bytes][address length: uint8 <= 64][server address: "host:port"]
//     [signature: 64 bytes over everything before it]
//   A backend holding the secret key issues one per client and server; a
//   server holding only the public key verifies signature, version, expiry,
//   server address, and refuses a nonce it has already accepted.
#pragma once
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

namespace progskin::net::crypto {

// Initialises libsodium (idempotent, thread-safe); throws Error if it cannot.
void init();

// Whether this build has libsodium (crypto.cpp: true). A build with the CMake
// option PROGSKIN_CRYPTO=OFF (the WebAssembly client, web/) links
// crypto_none.cpp instead: false, and every function below that needs
// libsodium throws Error("sealed datagrams need libsodium, not built into
// this client"); a client then fails a keyed Welcome with that reason.
bool available();
inline constexpr const char* UNAVAILABLE = "sealed datagrams need libsodium, not built into this client";

inline constexpr size_t KEY_BYTES = 32;         // AEAD key
inline constexpr size_t SEAL_OVERHEAD = 8 + 16; // sequence + tag
inline constexpr uint64_t REPLAY_WINDOW = 256;
using Key = std::array<uint8_t, KEY_BYTES>;

Key random_key();
void random_bytes(std::span<uint8_t> out);

// Which sequences a receiver has accepted: the newest and a bitmap of the
// REPLAY_WINDOW before it. O(1), no allocation.
class ReplayWindow {
public:
    // Whether `seq` is new and recent enough (does not record it).
    bool fresh(uint64_t seq) const;
    // Records `seq` as accepted (call only after the tag verified).
    void accept(uint64_t seq);

private:
    uint64_t newest_ = 0;
    bool any_ = false;
    std::array<uint64_t, REPLAY_WINDOW / 64> bits_{};  // bit (s % WINDOW): sequence s accepted
};

// Seals with increasing sequence numbers from 0 under one key.
class Sealer {
public:
    explicit Sealer(const Key& key) : key_(key) {}
    // Writes the sealed datagram to `out` (resized to plain.size() + SEAL_OVERHEAD).
    void seal(std::span<const uint8_t> plain, std::span<const uint8_t> ad, std::vector<uint8_t>& out);
    // The same into out[0 .. plain.size() + SEAL_OVERHEAD) (no allocation).
    void seal_to(std::span<const uint8_t> plain, std::span<const uint8_t> ad, uint8_t* out);
    uint64_t next_sequence() const { return seq_; }

private:
    Key key_;
    uint64_t seq_ = 0;
};

enum class OpenResult { ok, too_short, replayed, forged };
const char* to_string(OpenResult r);

// What open() does with a sequence already accepted or older than the
// window: drop it before the tag (replayed, whatever its bytes: a server
// spends nothing on a flood of stale sequences), or check its tag first
// (replayed only when authentic, a duplicate of the network; else forged),
// for a receiver that counts the two apart (the client).
enum class Stale { drop, authenticate };

// Opens sealed datagrams of one Sealer's key, dropping replays.
class Opener {
public:
    explicit Opener(const Key& key) : key_(key) {}
    // On ok, `plain` holds the datagram and `seq` its sequence.
    OpenResult open(std::span<const uint8_t> sealed, std::span<const uint8_t> ad, std::vector<uint8_t>& plain, uint64_t& seq,
                    Stale stale = Stale::drop);

private:
    Key key_;
    ReplayWindow window_;
};

// A sealed datagram on the wire (docs/protocol.md "Sealed datagrams"):
//     [session_id: uint64 LE][Sealer output: sequence, ciphertext, tag]
// associated data = session_id (8 bytes LE) + protocol version (2 bytes LE).
// SEALED_DATAGRAM_OVERHEAD = 32 bytes.
inline constexpr size_t SEALED_DATAGRAM_OVERHEAD = 8 + SEAL_OVERHEAD;
void seal_datagram(Sealer& sealer, uint64_t session_id, uint16_t version, std::span<const uint8_t> plain,
                   std::vector<uint8_t>& out);
// The session id a sealed datagram names (0 when it is too short to be one).
uint64_t sealed_session_id(std::span<const uint8_t> wire);
OpenResult open_datagram(Opener& opener, uint64_t session_id, uint16_t version, std::span<const uint8_t> wire,
                         std::vector<uint8_t>& plain, uint64_t& seq, Stale stale = Stale::drop);

// ------------------------------------------------------------ tokens --

inline constexpr size_t PUBLIC_KEY_BYTES = 32, SECRET_KEY_BYTES = 64, SIGNATURE_BYTES = 64;
inline constexpr size_t TOKEN_NONCE_BYTES = 16, MAX_TOKEN_ADDRESS = 64;
using PublicKey = std::array<uint8_t, PUBLIC_KEY_BYTES>;
using SecretKey = std::array<uint8_t, SECRET_KEY_BYTES>;

void signing_keypair(PublicKey& pk, SecretKey& sk);

struct ConnectToken {
    uint64_t client_id = 0;
    uint64_t expires = 0;  // Unix seconds
    std::array<uint8_t, TOKEN_NONCE_BYTES> nonce{};
    std::string server_address;  // "host:port" the token is valid for
};

// Issues a token (fresh random nonce) for `client_id`, valid `seconds` from
// `now_unix`, for `server_address`; returns its base64url text (at most 216
// characters, fits Hello.token). Throws Error for an address over 64 bytes.
std::string issue_connect_token(const SecretKey& sk, uint64_t client_id, uint64_t now_unix, uint64_t seconds,
                                const std::string& server_address);

// Checks a token's text against the public key, the clock and the server's
// own address (empty: any). Returns "" and fills `out` if valid, else the
// reason ("malformed connect token", "connect token signature invalid",
// "connect token expired", "connect token for another server").
std::string verify_connect_token(const std::string& text, const PublicKey& pk, uint64_t now_unix,
                                 const std::string& server_address, ConnectToken& out);

// Nonces of accepted tokens until they expire: a token is accepted once.
class TokenReplayCache {
public:
    // False if this nonce was already accepted (and has not expired).
    bool first_use(const ConnectToken& t, uint64_t now_unix);
    size_t size() const { return seen_.size(); }

private:
    std::unordered_map<std::string, uint64_t> seen_;  // nonce -> expiry
    uint64_t next_sweep_ = 0;
};

// Hex text of bytes, and back (false on bad length or characters).
std::string to_hex(std::span<const uint8_t> bytes);
bool from_hex(const std::string& hex, std::span<uint8_t> out);

uint64_t unix_now();

}  // namespace progskin::net::crypto
