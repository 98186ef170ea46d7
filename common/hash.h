// hash.h — FNV-1a 64 over bytes (not cryptographic): the wire's asset id
// (proto/wire.h content_hash) and the trajectory buckets of join_coincident.
// Feed a long input in pieces by passing the previous result as `h`.
#pragma once
#include <cstdint>
#include <span>

namespace progskin {

inline constexpr uint64_t FNV1A64_BASIS = 14695981039346656037ull;

inline uint64_t fnv1a64(std::span<const uint8_t> bytes, uint64_t h = FNV1A64_BASIS) {
    for (uint8_t b : bytes) {
        h ^= b;
        h *= 1099511628211ull;
    }
    return h;
}

}  // namespace progskin
