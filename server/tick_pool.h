// tick_pool.h — a small fixed pool of threads for the tick's per-client work
// (ServerCore::tick: importance, selection, packing, sealing, sending of each
// Streaming session). Built once with the server (ServerConfig::threads); a
// tick wakes its workers, the calling thread works too, and run() returns
// once every worker is done: no thread is created and nothing is allocated
// per tick.
//
// Ownership during run(): the job decides which data each worker touches
// (ServerCore::tick gives each ClientStream to exactly one worker per tick);
// everything the caller wrote before run() is visible to the workers, and
// everything the workers wrote is visible to the caller after it (the pool's
// mutex orders them).
#pragma once
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace progskin::net {

class TickPool {
public:
    // threads >= 1 threads in all: threads - 1 workers are started here, the
    // caller of run() is the first. Throws Error for threads < 1 or > kMaxThreads.
    explicit TickPool(int threads);
    ~TickPool();  // stops and joins the workers
    TickPool(const TickPool&) = delete;
    TickPool& operator=(const TickPool&) = delete;

    static constexpr int kMaxThreads = 256;
    int threads() const { return int(workers_.size()) + 1; }

    // Calls job(w) once for every w in [0, threads()), w = 0 on the calling
    // thread, the others on the workers, at the same time; returns when all
    // returned. An exception from a job is rethrown here (the first one) once
    // all are done. Not reentrant: one run() at a time.
    template <class F>
    void run(F& job) {
        run_erased(&call<F>, &job);
    }

private:
    template <class F>
    static void call(void* job, int w) {
        (*static_cast<F*>(job))(w);
    }
    void run_erased(void (*fn)(void*, int), void* job);
    void work(int w);  // a worker's loop
    void finish_one(std::exception_ptr e);

    std::vector<std::thread> workers_;
    std::mutex mutex_;
    std::condition_variable start_, done_;
    uint64_t generation_ = 0;  // bumped by every run()
    int running_ = 0;          // workers still in this run's job
    bool stopping_ = false;
    void (*fn_)(void*, int) = nullptr;
    void* job_ = nullptr;
    std::exception_ptr error_;
};

}  // namespace progskin::net
