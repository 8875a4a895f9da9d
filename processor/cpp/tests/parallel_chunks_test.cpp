// SPDX-License-Identifier: BSD-3-Clause
// parallel_chunks runs every chunk exactly once on any thread count, a thread held up at the
// start has its share taken over by the others, and a worker that never comes holds no one up.
#include <gtest/gtest.h>

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
    detail::parallel_chunks(2, kChunks, [&](int64_t c, int t) {
        if (t == 0 && !held.exchange(true))
            std::this_thread::sleep_for(std::chrono::milliseconds(200));
        by[c] = t;
    });
    // thread 0 owns chunks [0, 32): it slept in its first one, thread 1 did the rest of them
    int taken = 0;
    for (int64_t c = 0; c < kChunks / 2; ++c) taken += by[c] == 1;
    EXPECT_GE(taken, kChunks / 4);
    for (int64_t c = 0; c < kChunks; ++c) EXPECT_GE(by[c], 0);
}

TEST(ParallelChunks, BackToBackSmallJobsRunEveryChunkOnce) {
    // jobs far shorter than a worker's wake-up: most close before the worker comes, which
    // then must find them closed and leave every chunk done exactly once
    for (int rep = 0; rep < 2000; ++rep) {
        std::atomic<int> runs[3] = {0, 0, 0};
        detail::parallel_chunks(2, 3, [&](int64_t c, int t) {
            EXPECT_GE(t, 0);
            EXPECT_LT(t, 2);
            runs[c].fetch_add(1);
        });
        for (auto& r : runs) ASSERT_EQ(r.load(), 1);
    }
}

TEST(ParallelChunks, NestedAndConcurrentCallsRunEveryChunk) {
    std::atomic<int> inner{0};
    detail::parallel_chunks(2, 6, [&](int64_t) {
        detail::parallel_chunks(2, 5, [&](int64_t) { inner.fetch_add(1); });
    });
    EXPECT_EQ(inner.load(), 30);
    std::atomic<int> total{0};
    std::vector<std::thread> callers;
    for (int k = 0; k < 4; ++k)
        callers.emplace_back([&] {
            for (int rep = 0; rep < 100; ++rep)
                detail::parallel_chunks(2, 16, [&](int64_t) { total.fetch_add(1); });
        });
    for (auto& c : callers) c.join();
    EXPECT_EQ(total.load(), 4 * 100 * 16);
}

}  // namespace
}  // namespace tripod
