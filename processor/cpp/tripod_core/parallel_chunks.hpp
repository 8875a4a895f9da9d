// SPDX-License-Identifier: BSD-3-Clause
// Fixed chunks of work spread over an OpenMP team: each thread first takes the chunks of its
// own contiguous share (the same share at every call, so the data it writes stay in its
// cache from one call to the next), then helps the others with what is left of theirs. A
// thread that starts late (woken from sleep: OpenMP threads wait passively, see
// tripod_processor/__init__.py) or meets costlier points no longer holds the others up at the
// closing barrier: the team ends within about one chunk of each other. Which thread runs a
// chunk never changes what the chunk computes, so callers that keep one result per chunk and
// combine them in chunk order get the same bits on any thread count.
#pragma once

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>

#include "tripod_core/phase_timer.hpp"

namespace tripod::detail {

/// Calls body(chunk) once for every chunk in [0, num_chunks) on up to `num_threads` threads
/// (<= 0: all), or on the calling thread alone when there is one chunk or one thread.
template <class Body>
void parallel_chunks(int num_threads, int64_t num_chunks, Body&& body,
                     const char* team_name = "parallel_chunks") {
    const int nt = static_cast<int>(std::min<int64_t>(
        num_threads > 0 ? num_threads : omp_get_max_threads(), num_chunks));
    if (nt <= 1) {
        for (int64_t c = 0; c < num_chunks; ++c) body(c);
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
    TRIPOD_TEAM(team_name);
#pragma omp parallel num_threads(nt)
    {
        TRIPOD_TEAM_ENTER();
        // a team smaller than asked for leaves shares without owner: the stealing loop runs them
        const int t = omp_get_thread_num();
        for (int k = 0; k < nt; ++k) {
            Cursor& s = share[(t + k) % nt];
            for (;;) {
                if (s.next.load(std::memory_order_relaxed) >= s.end) break;
                const int64_t c = s.next.fetch_add(1, std::memory_order_relaxed);
                if (c >= s.end) break;
                body(c);
            }
        }
        TRIPOD_TEAM_LEAVE();
    }
}

}  // namespace tripod::detail
