// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/thread_pool.hpp"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif
#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <thread>
#include <vector>

namespace tripod::detail {

namespace {

thread_local bool tl_worker = false;

/// A spin-wait hint to the CPU (x86 PAUSE, Arm YIELD; nothing elsewhere).
inline void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
    _mm_pause();
#elif defined(__aarch64__) || defined(__arm__)
    __asm__ __volatile__("yield");
#endif
}

static_assert(sizeof(std::atomic<uint32_t>) == sizeof(uint32_t), "futex word");

void futex_wait(std::atomic<uint32_t>* word, uint32_t expected) {
    syscall(SYS_futex, reinterpret_cast<uint32_t*>(word), FUTEX_WAIT_PRIVATE, expected, nullptr,
            nullptr, 0);
}

void futex_wake_all(std::atomic<uint32_t>* word) {
    syscall(SYS_futex, reinterpret_cast<uint32_t*>(word), FUTEX_WAKE_PRIVATE, INT32_MAX, nullptr,
            nullptr, 0);
}

/// How long [ns] a worker polls for the next job before it sleeps (see thread_pool.hpp).
int64_t poll_ns_from_env() {
    const char* count = std::getenv("GOMP_SPINCOUNT");
    if (count && count[0]) {
        char* end = nullptr;
        const double c = std::strtod(count, &end);
        if (end != count && c >= 0) return static_cast<int64_t>(std::min(c * 30.0, 1e9));
    }
    const char* policy = std::getenv("OMP_WAIT_POLICY");
    if (policy && (policy[0] == 'p' || policy[0] == 'P')) return 0;
    if (policy && (policy[0] == 'a' || policy[0] == 'A')) return 100'000'000;
    return 9'000'000;
}

class Pool {
public:
    bool run(int nt, void (*fn)(void*, int), void* ctx) {
        // a forked child has none of the workers (and may hold a copy of a locked mutex)
        if (tl_worker || nt <= 1 || getpid() != pid_) return false;
        std::unique_lock<std::mutex> busy(busy_, std::try_to_lock);
        if (!busy.owns_lock()) return false;
        const int want = std::min(nt, kMaxThreads) - 1;  // workers
        while (static_cast<int>(workers_.size()) < want) {
            const int index = static_cast<int>(workers_.size()) + 1;
            workers_.emplace_back([this, index] { work(index); });
            workers_.back().detach();
        }
        // the job's fields are written while it is closed (a worker reads them only when it
        // finds its generation open), then published, then opened
        fn_ = fn;
        ctx_ = ctx;
        team_ = std::min(nt, kMaxThreads);
        gen_.fetch_add(1, std::memory_order_seq_cst);
        open_.store(true, std::memory_order_seq_cst);
        // no mutex on this path (a worker on its way to sleep would hold the caller up)
        if (sleepers_.load(std::memory_order_seq_cst) > 0) futex_wake_all(&gen_);
        fn(ctx, 0);
        // every chunk is taken: close the job, wait for the workers inside it (running a chunk)
        open_.store(false, std::memory_order_seq_cst);
        for (uint32_t i = 1; active_.load(std::memory_order_seq_cst) != 0; ++i) {
            cpu_relax();
            if ((i & 16383) == 0) std::this_thread::yield();  // a worker descheduled here
        }
        return true;
    }

private:
    static constexpr int kMaxThreads = 64;

    void work(int index) {
        tl_worker = true;
        uint32_t seen = gen_.load(std::memory_order_acquire);
        for (;;) {
            wait_for_job(seen);
            seen = gen_.load(std::memory_order_seq_cst);
            // join: registered before looking, so the caller cannot close and move on unseen
            active_.fetch_add(1, std::memory_order_seq_cst);
            if (open_.load(std::memory_order_seq_cst) &&
                gen_.load(std::memory_order_seq_cst) == seen && index < team_)
                fn_(ctx_, index);
            active_.fetch_sub(1, std::memory_order_seq_cst);
        }
    }

    void wait_for_job(uint32_t seen) {
        if (poll_ns_ > 0) {
            const auto t0 = std::chrono::steady_clock::now();
            for (uint32_t i = 1;; ++i) {
                if (gen_.load(std::memory_order_acquire) != seen) return;
                if ((i & 63) == 0) {
                    cpu_relax();
                    if (std::chrono::duration_cast<std::chrono::nanoseconds>(
                            std::chrono::steady_clock::now() - t0)
                            .count() > poll_ns_)
                        break;
                }
            }
        }
        // the caller moves gen_ on, then looks for sleepers; a sleeper counts itself, then
        // sleeps only while gen_ is unchanged (the kernel compares): no wake-up is lost
        sleepers_.fetch_add(1, std::memory_order_seq_cst);
        while (gen_.load(std::memory_order_seq_cst) == seen) futex_wait(&gen_, seen);
        sleepers_.fetch_sub(1, std::memory_order_seq_cst);
    }

    const int64_t poll_ns_ = poll_ns_from_env();
    const pid_t pid_ = getpid();
    std::mutex busy_;  // one job at a time
    std::vector<std::thread> workers_;
    // the job (written by the caller before gen_ moves on, read by workers after)
    void (*fn_)(void*, int) = nullptr;
    void* ctx_ = nullptr;
    int team_ = 1;
    alignas(64) std::atomic<uint32_t> gen_{0};  // the job's generation (a futex word)
    alignas(64) std::atomic<bool> open_{false};
    alignas(64) std::atomic<int> active_{0};
    alignas(64) std::atomic<int> sleepers_{0};
};

Pool& pool() {
    // never destroyed: detached workers may still be waiting on it when the process exits
    static Pool* p = new Pool;
    return *p;
}

}  // namespace

bool pool_run(int num_threads, void (*fn)(void*, int), void* ctx) {
    return pool().run(num_threads, fn, ctx);
}

bool in_pool_worker() { return tl_worker; }

}  // namespace tripod::detail
