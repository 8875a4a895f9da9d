// SPDX-License-Identifier: BSD-3-Clause
// Debug phase timers for the registration path: with TRIPOD_PHASE_TIMERS=1 in the environment,
// every TRIPOD_PHASE("name") scope adds its wall time (steady clock) and the calling thread's
// CPU time (CLOCK_THREAD_CPUTIME_ID) to a per-name total, printed to stderr at exit. Scopes
// opened outside a parallel region time what the calling thread does: a serial phase's CPU
// time is its whole work, a parallel region's is the calling thread's share. Off (one cached
// flag test per scope) unless the variable is set.
#pragma once

#include <time.h>

#include <cstdio>
#include <cstdlib>
#include <map>
#include <mutex>
#include <string>

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
    };
    std::mutex mu;
    std::map<std::string, Entry> by_name;
    ~Totals() {
        if (by_name.empty()) return;
        std::fprintf(stderr, "%-28s %8s %10s %10s\n", "phase", "calls", "wall ms", "cpu ms");
        for (const auto& [k, e] : by_name)
            std::fprintf(stderr, "%-28s %8ld %10.3f %10.3f\n", k.c_str(), e.calls, e.wall_ms,
                         e.cpu_ms);
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
    }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

private:
    const char* name_;
    double wall0_ = 0, cpu0_ = 0;
};

}  // namespace tripod::prof

#define TRIPOD_PHASE_CAT2(a, b) a##b
#define TRIPOD_PHASE_CAT(a, b) TRIPOD_PHASE_CAT2(a, b)
#define TRIPOD_PHASE(name) ::tripod::prof::Scope TRIPOD_PHASE_CAT(tripod_phase_, __LINE__)(name)
