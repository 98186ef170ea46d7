// alloc_counter.h — counts the calling thread's operator new while
// `counting` is set (the no-allocation tests: test_net_client_alloc,
// test_net_capi_alloc). It replaces the global operator new/delete (malloc
// and free), so exactly one source file of an executable includes it; the
// libraries' allocations resolve to it too.
#pragma once

#pragma GCC diagnostic ignored "-Wmismatched-new-delete"  // operator new below is malloc, delete free

#include <cstdlib>
#include <new>

namespace alloc_counter {
inline thread_local bool counting = false, measuring = false;
inline thread_local long allocations = 0;
}  // namespace alloc_counter

void* operator new(std::size_t n) {
    if (alloc_counter::counting) ++alloc_counter::allocations;
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
// NOLINTNEXTLINE: paired with the malloc above
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
