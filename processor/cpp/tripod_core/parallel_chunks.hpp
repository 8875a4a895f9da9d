// SPDX-License-Identifier: BSD-3-Clause
// Fixed chunks of work spread over the registration path's threads (thread_pool.hpp): each
// thread first takes the chunks of its own contiguous share (the same share at every call, so
// the data it writes stay in its cache from one call to the next), then helps the others with
// what is left of theirs. A thread that starts late (woken from sleep, its CPU taken by another
// process or by the host) no longer holds the others up: the caller takes over its share, and
// the call returns once every chunk is done, without waiting for a worker that never came (the
// pool's jobs close; an OpenMP region would wait for every thread at its closing barrier).
// Which thread runs a chunk never changes what the chunk computes, so callers that keep one
// result per chunk and combine them in chunk order get the same bits on any thread count.
#pragma once

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>
#include <type_traits>

#include "tripod_core/phase_timer.hpp"
#include "tripod_core/thread_pool.hpp"

namespace tripod::detail {

/// The thread count a `num_threads` argument stands for (<= 0: all, as OpenMP counts them).
inline int resolve_threads(int num_threads) {
    return num_threads > 0 ? num_threads : omp_get_max_threads();
}

/// Calls body(chunk) -- or body(chunk, t) with t the running thread's index in [0, threads),
/// for per-thread scratch -- once for every chunk in [0, num_chunks) on up to `num_threads`
/// threads (<= 0: all), or on the calling thread alone when there is one chunk or one thread,
/// when called from inside a parallel_chunks body or an OpenMP parallel region, or when the
/// pool is busy with another caller's job.
template <class Body>
void parallel_chunks(int num_threads, int64_t num_chunks, Body&& body,
                     const char* team_name = "parallel_chunks") {
    constexpr bool kWithThread = std::is_invocable_v<Body&, int64_t, int>;
    auto call = [&](int64_t c, int t) {
        if constexpr (kWithThread) body(c, t); else body(c);
    };
    const int nt = static_cast<int>(
        std::min<int64_t>({resolve_threads(num_threads), num_chunks, int64_t{64}}));
    // nested in a pool job or an OpenMP region (another module's): on the calling thread, as
    // a nested OpenMP region would run
    if (nt <= 1 || in_pool_worker() || omp_in_parallel()) {
        for (int64_t c = 0; c < num_chunks; ++c) call(c, 0);
        return;
    }
    struct alignas(64) Cursor {  // one cache line per share: owners never share a line
        std::atomic<int64_t> next;
        int64_t end;
    };
    std::unique_ptr<Cursor[]> share(new Cursor[nt]);
    for (int u = 0; u < nt; ++u) {
        share[u].next.store(num_chunks * u / nt, std::memory_order_relaxed);
        share[u].end = num_chunks * (u + 1) / nt;
    }
    struct Ctx {
        Cursor* share;
        int nt;
        decltype(call)* body;
        prof::Team* team;
    };
    TRIPOD_TEAM(team_name);
    Ctx ctx{share.get(), nt, &call, &tripod_team};
    auto run = [](void* p, int t) {
        Ctx& x = *static_cast<Ctx*>(p);
        x.team->enter(t);
        // a share without owner (a worker that has not come) is taken over by the loop
        for (int k = 0; k < x.nt; ++k) {
            Cursor& s = x.share[(t + k) % x.nt];
            for (;;) {
                if (s.next.load(std::memory_order_relaxed) >= s.end) break;
                const int64_t c = s.next.fetch_add(1, std::memory_order_relaxed);
                if (c >= s.end) break;
                (*x.body)(c, t);
            }
        }
        x.team->leave(t);
    };
    if (!pool_run(nt, run, &ctx)) run(&ctx, 0);
}

}  // namespace tripod::detail
