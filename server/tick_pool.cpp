// tick_pool.cpp — see tick_pool.h.
#include "tick_pool.h"

#include <pthread.h>

#include <string>
#include <utility>

#include "errors.h"

namespace progskin::net {

TickPool::TickPool(int threads) {
    if (threads < 1 || threads > kMaxThreads)
        throw Error("tick threads must be in [1, " + std::to_string(kMaxThreads) + "], not " + std::to_string(threads));
    workers_.reserve(size_t(threads - 1));
    for (int w = 1; w < threads; ++w) workers_.emplace_back([this, w] { work(w); });
}

TickPool::~TickPool() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    start_.notify_all();
    for (auto& t : workers_) t.join();
}

void TickPool::finish_one(std::exception_ptr e) {
    std::lock_guard lock(mutex_);
    if (e && !error_) error_ = e;
    if (--running_ == 0) done_.notify_one();
}

void TickPool::work(int w) {
#if defined(__GLIBC__)
    ::pthread_setname_np(::pthread_self(), "progskin-work");
#endif
    uint64_t seen = 0;
    for (;;) {
        void (*fn)(void*, int) = nullptr;
        void* job = nullptr;
        {
            std::unique_lock lock(mutex_);
            start_.wait(lock, [&] { return stopping_ || generation_ != seen; });
            if (stopping_) return;
            seen = generation_;
            fn = fn_;
            job = job_;
        }
        std::exception_ptr e;
        try {
            fn(job, w);
        } catch (...) {
            e = std::current_exception();
        }
        finish_one(e);
    }
}

void TickPool::run_erased(void (*fn)(void*, int), void* job) {
    if (workers_.empty()) {
        fn(job, 0);
        return;
    }
    {
        std::lock_guard lock(mutex_);
        fn_ = fn;
        job_ = job;
        running_ = int(workers_.size()) + 1;
        error_ = nullptr;
        ++generation_;
    }
    start_.notify_all();
    std::exception_ptr e;
    try {
        fn(job, 0);
    } catch (...) {
        e = std::current_exception();
    }
    finish_one(e);
    std::unique_lock lock(mutex_);
    done_.wait(lock, [&] { return running_ == 0; });
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
}

}  // namespace progskin::net
