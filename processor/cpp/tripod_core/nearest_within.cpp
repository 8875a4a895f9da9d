// SPDX-License-Identifier: BSD-3-Clause
// Exact nearest neighbour within a radius on a hashed grid (see nearest_within.hpp).
// Compiled with -ffp-contract=off (CMakeLists): the squared distance must round as cKDTree's.
#include "tripod_core/nearest_within.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace tripod {
namespace {

/// Stable LSD radix sort of (key, row) pairs by key, keys < 2^bits.
void radix_sort(std::vector<std::pair<uint64_t, int64_t>>& a, int bits) {
    constexpr int kDigit = 11;
    constexpr size_t kBuckets = size_t{1} << kDigit;
    std::vector<std::pair<uint64_t, int64_t>> tmp(a.size());
    std::vector<size_t> count(kBuckets);
    for (int shift = 0; shift < bits; shift += kDigit) {
        std::fill(count.begin(), count.end(), 0);
        for (const auto& e : a) ++count[(e.first >> shift) & (kBuckets - 1)];
        size_t sum = 0;
        for (auto& c : count) sum += std::exchange(c, sum);
        for (const auto& e : a) tmp[count[(e.first >> shift) & (kBuckets - 1)]++] = e;
        a.swap(tmp);
    }
}

void check_finite(const double* p, int64_t n, const char* what) {
    for (int64_t i = 0; i < 3 * n; ++i)
        if (!std::isfinite(p[i]))
            throw std::invalid_argument(std::string(what) + ": non-finite point");
}

}  // namespace

NearestWithin nearest_within(const double* ref, int64_t n_ref, const double* query,
                             int64_t n_query, double radius) {
    if (!(radius > 0) || !std::isfinite(radius))
        throw std::invalid_argument("nearest_within: radius must be finite and > 0");
    check_finite(ref, n_ref, "nearest_within: references");
    check_finite(query, n_query, "nearest_within: queries");
    NearestWithin out;
    out.dist.assign(n_query, std::numeric_limits<double>::infinity());
    out.index.assign(n_query, n_ref);
    if (n_ref == 0 || n_query == 0) return out;

    // cells a hair wider than the radius, so a rounding in the cell index never hides a match:
    // a match differs by less than one cell in every axis
    const double h = radius * (1.0 + 1e-6);
    std::array<double, 3> lo, hi;
    for (int a = 0; a < 3; ++a) lo[a] = hi[a] = ref[a];
    for (int64_t i = 1; i < n_ref; ++i)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], ref[3 * i + a]);
            hi[a] = std::max(hi[a], ref[3 * i + a]);
        }
    // cell c = floor((x - lo) / h) + 1: references in 1..n, queries that can match in 0..n+1
    std::array<int64_t, 3> dims;
    double cells = 1.0;
    for (int a = 0; a < 3; ++a) {
        const double n = std::floor((hi[a] - lo[a]) / h) + 3.0;
        cells *= n;
        if (!(cells < std::ldexp(1.0, 60)))
            throw std::invalid_argument("nearest_within: the references span too many cells");
        dims[a] = static_cast<int64_t>(n);
    }
    const int64_t NY = dims[1], NZ = dims[2];
    int bits = 1;
    while (bits < 64 && (uint64_t{1} << bits) < static_cast<uint64_t>(cells)) ++bits;

    auto cell_key = [&](const double* p, uint64_t* key) {
        int64_t c[3];
        for (int a = 0; a < 3; ++a) {
            const double f = std::floor((p[a] - lo[a]) / h) + 1.0;
            if (!(f >= 0.0 && f <= static_cast<double>(dims[a] - 1))) return false;
            c[a] = static_cast<int64_t>(f);
        }
        *key = static_cast<uint64_t>((c[0] * NY + c[1]) * NZ + c[2]);
        return true;
    };

    std::vector<std::pair<uint64_t, int64_t>> rk(n_ref), qk;
    for (int64_t i = 0; i < n_ref; ++i) {
        rk[i].second = i;
        cell_key(ref + 3 * i, &rk[i].first);  // always inside
    }
    qk.reserve(n_query);
    for (int64_t j = 0; j < n_query; ++j) {
        uint64_t k;
        if (cell_key(query + 3 * j, &k)) qk.emplace_back(k, j);
    }
    radix_sort(rk, bits);
    radix_sort(qk, bits);

    // the 3 x 3 columns around a cell: key offsets; each column's 3 cells are consecutive keys.
    // A neighbour index out of the padded grid wraps into a padding cell, which holds no
    // reference, so no range reaches a wrong reference (and any candidate is checked anyway).
    std::array<int64_t, 9> off;
    for (int dx = -1, m = 0; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy) off[m++] = (dx * NY + dy) * NZ;
    std::array<size_t, 9> ptr{};  // per column offset: first reference not below the range
    const double r2 = radius * radius;
    const size_t nr = rk.size();
    for (const auto& [key, j] : qk) {  // queries in key order: every range start only grows
        const double* q = query + 3 * j;
        double best = r2;
        int64_t best_i = n_ref;
        bool tie = false;
        for (int m = 0; m < 9; ++m) {
            const int64_t first = static_cast<int64_t>(key) + off[m] - 1;
            const int64_t last = first + 2;
            size_t& p = ptr[m];
            while (p < nr && static_cast<int64_t>(rk[p].first) < first) ++p;
            for (size_t s = p; s < nr && static_cast<int64_t>(rk[s].first) <= last; ++s) {
                const int64_t i = rk[s].second;
                const double* r = ref + 3 * i;
                // as cKDTree: (reference - query) per axis, summed x, y, z in order
                const double d0 = r[0] - q[0], d1 = r[1] - q[1], d2 = r[2] - q[2];
                double d = d0 * d0;
                d += d1 * d1;
                d += d2 * d2;
                if (d < best) {
                    best = d;
                    best_i = i;
                    tie = false;
                } else if (d == best && best_i != n_ref) {
                    tie = true;
                    best_i = std::min(best_i, i);
                }
            }
        }
        if (best_i != n_ref) {
            out.dist[j] = std::sqrt(best);
            out.index[j] = best_i;
            out.ties += tie;
        }
    }
    return out;
}

}  // namespace tripod
