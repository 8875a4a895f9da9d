// SPDX-License-Identifier: BSD-3-Clause
// The registration path's worker threads (parallel_chunks runs on them): a fork never waits
// for a worker that has not started. An OpenMP parallel region ends at a barrier every thread
// of the team must reach, so a worker whose CPU is slow to come back (woken from sleep, or its
// virtual CPU descheduled by the host) holds the caller even when the caller did all the work
// itself. Here the caller publishes a job, takes part in it, closes it when every chunk is
// taken, and waits only for the workers that joined it in time (they are running a chunk); a
// worker that comes later sees the job closed and does nothing. Results never depend on which
// thread ran what (parallel_chunks' chunks are fixed).
//
// Waiting between jobs follows the process's OpenMP policy (set by tripod_processor at import
// unless the user chose): a worker polls for the next job for GOMP_SPINCOUNT x 30 ns (about
// what libgomp's spin of that count lasts on the 2-core VM: 30000 -> ~0.9 ms), then sleeps;
// OMP_WAIT_POLICY=PASSIVE alone: sleeps at once; ACTIVE: polls for 100 ms; neither set: 9 ms
// (libgomp's default count). The poll does not execute a PAUSE per iteration (a KVM guest
// spinning on PAUSE is exited to the host by its pause filter and may lose its CPU there).
// One job at a time: a call from a second thread while a job runs runs on its caller alone, as
// does a call in a forked child process (it has none of the parent's workers).
#pragma once

#include <cstdint>

namespace tripod::detail {

/// Calls fn(ctx, t) on the calling thread (t = 0) and on up to `num_threads` - 1 workers
/// (t = 1, 2, ...; each worker that joins in time, once), returns when all of them returned.
/// fn must do nothing wrong when some t never come (the work goes to whoever asks for it).
/// Returns false without calling fn when the pool is busy with another caller's job or the
/// caller is itself a worker (the caller then does the work alone).
bool pool_run(int num_threads, void (*fn)(void* ctx, int t), void* ctx);

/// Whether the calling thread is one of the pool's workers.
bool in_pool_worker();

}  // namespace tripod::detail
