// SPDX-License-Identifier: BSD-3-Clause
// parallel_chunks runs every chunk exactly once on any thread count, and a thread held up at
// the start has its share taken over by the others.
#include <gtest/gtest.h>
#include <omp.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include "tripod_core/parallel_chunks.hpp"

namespace tripod {
namespace {

TEST(ParallelChunks, EveryChunkOnceOnAnyThreadCount) {
    for (int threads : {0, 1, 2, 3, 4, 8})
        for (int64_t chunks : {0, 1, 2, 3, 7, 1000}) {
            std::vector<std::atomic<int>> runs(static_cast<size_t>(chunks));
            for (auto& r : runs) r.store(0);
            detail::parallel_chunks(threads, chunks, [&](int64_t c) { runs[c].fetch_add(1); });
            for (int64_t c = 0; c < chunks; ++c)
                EXPECT_EQ(runs[c].load(), 1) << "threads " << threads << " chunk " << c;
        }
}

TEST(ParallelChunks, AHeldUpThreadsShareIsTakenOver) {
    constexpr int64_t kChunks = 64;
    std::vector<int> by(kChunks, -1);
    std::atomic<bool> held{false};
    int team = 0;
    detail::parallel_chunks(2, kChunks, [&](int64_t c) {
        const int t = omp_get_thread_num();
        if (t == 0) {
#pragma omp atomic write
            team = omp_get_num_threads();
        }
        if (t == 0 && !held.exchange(true))
            std::this_thread::sleep_for(std::chrono::milliseconds(200));
        by[c] = t;
    });
    if (team < 2) GTEST_SKIP() << "OpenMP gave one thread";
    // thread 0 owns chunks [0, 32): it slept in its first one, thread 1 did the rest of them
    int taken = 0;
    for (int64_t c = 0; c < kChunks / 2; ++c) taken += by[c] == 1;
    EXPECT_GE(taken, kChunks / 4);
    for (int64_t c = 0; c < kChunks; ++c) EXPECT_GE(by[c], 0);
}

}  // namespace
}  // namespace tripod
