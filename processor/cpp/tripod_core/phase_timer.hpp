// SPDX-License-Identifier: BSD-3-Clause
// Debug phase timers for the registration path: with TRIPOD_PHASE_TIMERS=1 in the environment,
// every TRIPOD_PHASE("name") scope adds its wall time (steady clock) and the calling thread's
// CPU time (CLOCK_THREAD_CPUTIME_ID) to a per-name total, printed to stderr at exit. Scopes
// opened outside a parallel region time what the calling thread does: a serial phase's CPU
// time is its whole work, a parallel region's is the calling thread's share. Off (one cached
// flag test per scope) unless the variable is set.
// TRIPOD_TEAM("name") / TRIPOD_TEAM_ENTER / TRIPOD_TEAM_LEAVE time a parallel region's team: how
// long after the fork each thread started and how long each waited at the join for the last
// one (summed over threads and calls, printed with the phases as "team: name"), and the CPU time
// the threads spent in it (work: compare 1 and n threads for the work a team adds; a thread's
// spin at an inner barrier counts as work).
#pragma once

#include <omp.h>
#include <time.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace tripod::prof {

inline bool enabled() {
    static const bool on = [] {
        const char* v = std::getenv("TRIPOD_PHASE_TIMERS");
        return v && v[0] && v[0] != '0';
    }();
    return on;
}

struct Totals {
    struct Entry {
        double wall_ms = 0, cpu_ms = 0;
        long calls = 0;
        std::vector<float> walls;  // per call [ms], for the median
        double median() {
            if (walls.empty()) return 0;
            std::nth_element(walls.begin(), walls.begin() + walls.size() / 2, walls.end());
            return walls[walls.size() / 2];
        }
    };
    std::mutex mu;
    std::map<std::string, Entry> by_name;
    struct TeamEntry {
        double late_ms = 0, idle_ms = 0, busy_ms = 0;  // summed over threads other than none
        double work_ms = 0;                             // CPU time, summed over threads
        long calls = 0, threads = 0;
    };
    std::map<std::string, TeamEntry> teams;
    ~Totals() {
        if (by_name.empty() && teams.empty()) return;
        std::fprintf(stderr, "%-28s %8s %10s %10s %10s\n", "phase", "calls", "wall ms", "cpu ms",
                     "median ms");
        for (auto& [k, e] : by_name)
            std::fprintf(stderr, "%-28s %8ld %10.3f %10.3f %10.4f\n", k.c_str(), e.calls,
                         e.wall_ms, e.cpu_ms, e.median());
        if (teams.empty()) return;
        std::fprintf(stderr, "%-28s %8s %10s %10s %10s %10s %8s\n", "team", "calls", "late ms",
                     "idle ms", "busy ms", "work ms", "threads");
        for (const auto& [k, e] : teams)
            std::fprintf(stderr, "team: %-22s %8ld %10.3f %10.3f %10.3f %10.3f %8ld\n",
                         k.c_str(), e.calls, e.late_ms, e.idle_ms, e.busy_ms, e.work_ms,
                         e.threads);
    }
};

inline Totals& totals() {
    static Totals t;
    return t;
}

inline double now_ms(clockid_t c) {
    timespec ts;
    clock_gettime(c, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

class Scope {
public:
    explicit Scope(const char* name) : name_(enabled() ? name : nullptr) {
        if (!name_) return;
        wall0_ = now_ms(CLOCK_MONOTONIC);
        cpu0_ = now_ms(CLOCK_THREAD_CPUTIME_ID);
    }
    ~Scope() {
        if (!name_) return;
        const double w = now_ms(CLOCK_MONOTONIC) - wall0_;
        const double c = now_ms(CLOCK_THREAD_CPUTIME_ID) - cpu0_;
        Totals& t = totals();
        std::lock_guard<std::mutex> lock(t.mu);
        auto& e = t.by_name[name_];
        e.wall_ms += w;
        e.cpu_ms += c;
        ++e.calls;
        e.walls.push_back(static_cast<float>(w));
    }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

private:
    const char* name_;
    double wall0_ = 0, cpu0_ = 0;
};

/// One parallel region's team: made before the fork (records the fork time), enter()/leave()
/// called by each thread first and last thing in the region, totals added when it goes.
/// late: from the fork to a thread's start; idle: from a thread's end to the last one's end.
class Team {
public:
    static constexpr int kMax = 64;
    explicit Team(const char* name) : name_(enabled() ? name : nullptr) {
        if (name_) fork_ = now_ms(CLOCK_MONOTONIC);
    }
    void enter(int t) {
        if (!name_ || t >= kMax) return;
        enter_[t] = now_ms(CLOCK_MONOTONIC);
        cpu_[t] = now_ms(CLOCK_THREAD_CPUTIME_ID);
    }
    void leave(int t) {
        if (!name_ || t >= kMax) return;
        leave_[t] = now_ms(CLOCK_MONOTONIC);
        cpu_[t] = now_ms(CLOCK_THREAD_CPUTIME_ID) - cpu_[t];
    }
    ~Team() {
        if (!name_) return;
        double last = 0;
        int nt = 0;
        for (int t = 0; t < kMax && enter_[t] > 0; ++t, ++nt) last = std::max(last, leave_[t]);
        Totals& tot = totals();
        std::lock_guard<std::mutex> lock(tot.mu);
        auto& e = tot.teams[name_];
        ++e.calls;
        e.threads += nt;
        for (int t = 0; t < nt; ++t) {
            e.late_ms += enter_[t] - fork_;
            e.idle_ms += last - leave_[t];
            e.busy_ms += leave_[t] - enter_[t];
            e.work_ms += cpu_[t];
        }
    }
    Team(const Team&) = delete;
    Team& operator=(const Team&) = delete;

private:
    const char* name_;
    double fork_ = 0, enter_[kMax] = {}, leave_[kMax] = {}, cpu_[kMax] = {};
};

}  // namespace tripod::prof

#define TRIPOD_PHASE_CAT2(a, b) a##b
#define TRIPOD_PHASE_CAT(a, b) TRIPOD_PHASE_CAT2(a, b)
#define TRIPOD_PHASE(name) ::tripod::prof::Scope TRIPOD_PHASE_CAT(tripod_phase_, __LINE__)(name)
#define TRIPOD_TEAM(name) ::tripod::prof::Team tripod_team(name)
#define TRIPOD_TEAM_ENTER() tripod_team.enter(omp_get_thread_num())
#define TRIPOD_TEAM_LEAVE() tripod_team.leave(omp_get_thread_num())
