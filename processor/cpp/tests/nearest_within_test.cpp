// SPDX-License-Identifier: BSD-3-Clause
// nearest_within against a brute-force scan (the same rounding: ((dx² + dy²) + dz²) < r²),
// on unit vectors in rings (the station splitter's case) with duplicated directions (ties),
// and on a spread cloud with queries outside the references' box.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "tripod_core/nearest_within.hpp"

namespace tripod {
namespace {

struct Brute {
    std::vector<double> dist;
    std::vector<int64_t> index;
    int64_t ties = 0;
};

Brute brute(const std::vector<double>& ref, const std::vector<double>& q, double radius) {
    const int64_t n = static_cast<int64_t>(ref.size() / 3), m = static_cast<int64_t>(q.size() / 3);
    Brute b;
    b.dist.assign(m, std::numeric_limits<double>::infinity());
    b.index.assign(m, n);
    for (int64_t j = 0; j < m; ++j) {
        double best = radius * radius;
        int64_t bi = n;
        bool tie = false;
        for (int64_t i = 0; i < n; ++i) {
            volatile double d0 = ref[3 * i] - q[3 * j], d1 = ref[3 * i + 1] - q[3 * j + 1],
                            d2 = ref[3 * i + 2] - q[3 * j + 2];
            volatile double s0 = d0 * d0, s1 = d1 * d1, s2 = d2 * d2;
            volatile double s01 = s0 + s1;
            const double d = s01 + s2;
            if (d < best) {
                best = d, bi = i, tie = false;
            } else if (d == best && bi != n) {
                tie = true;  // bi stays the lowest index: rows are scanned in order
            }
        }
        if (bi != n) b.dist[j] = std::sqrt(best), b.index[j] = bi, b.ties += tie;
    }
    return b;
}

/// Unit vectors on 16 cones about an axis turned by `pan` (a VLP-16 sweep), every `dup`-th
/// point given twice (a dual return of the same direction).
std::vector<double> rings(int n, double pan, int dup, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 2 * M_PI);
    std::vector<double> p;
    for (int i = 0; i < n; ++i) {
        const double el = (-15.0 + 2.0 * (i % 16)) * M_PI / 180.0, az = u(rng);
        const double x = std::cos(el) * std::cos(az), y = std::cos(el) * std::sin(az),
                     z = std::sin(el);
        // the head's pan: the lidar on its side, turned about the world z axis
        const double xs = z, ys = y, zs = -x;
        const double v[3] = {std::cos(pan) * xs - std::sin(pan) * ys,
                             std::sin(pan) * xs + std::cos(pan) * ys, zs};
        const double r = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int k = 0; k < (dup > 0 && i % dup == 0 ? 2 : 1); ++k)
            for (double c : v) p.push_back(c / r);
    }
    return p;
}

void expect_same(const NearestWithin& got, const Brute& want) {
    ASSERT_EQ(got.dist.size(), want.dist.size());
    for (size_t j = 0; j < want.dist.size(); ++j) {
        EXPECT_EQ(got.index[j], want.index[j]) << j;
        if (std::isinf(want.dist[j]))
            EXPECT_TRUE(std::isinf(got.dist[j])) << j;
        else
            EXPECT_EQ(got.dist[j], want.dist[j]) << j;  // bit for bit
    }
    EXPECT_EQ(got.ties, want.ties);
}

TEST(NearestWithin, RingsOfUnitVectorsWithTiesMatchBruteForce) {
    const double radius = 0.3 * M_PI / 180.0;
    const std::vector<double> ref = rings(6000, 0.0, 7, 1);
    std::vector<double> q = rings(2000, 0.31, 0, 2);
    // queries that sit exactly on a duplicated reference: a tie at distance 0
    for (int k = 0; k < 5; ++k)
        q.insert(q.end(), ref.begin() + 3 * 7 * k, ref.begin() + 3 * 7 * k + 3);
    const NearestWithin got = nearest_within(ref.data(), ref.size() / 3, q.data(), q.size() / 3,
                                             radius);
    const Brute want = brute(ref, q, radius);
    int hits = 0;
    for (double d : want.dist) hits += std::isfinite(d);
    EXPECT_GT(hits, 100);
    EXPECT_GE(want.ties, 5);
    expect_same(got, want);
}

TEST(NearestWithin, SpreadCloudAndFarQueriesMatchBruteForce) {
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-2.0, 2.0), far(-50.0, 50.0);
    std::vector<double> ref, q;
    for (int i = 0; i < 3000; ++i) ref.push_back(u(rng));
    for (int i = 0; i < 3000; ++i) q.push_back(i % 2 ? u(rng) : far(rng));
    for (double radius : {0.05, 0.2, 1.0}) {
        const NearestWithin got = nearest_within(ref.data(), ref.size() / 3, q.data(),
                                                 q.size() / 3, radius);
        expect_same(got, brute(ref, q, radius));
    }
}

TEST(NearestWithin, EmptyInputsAndBadArguments) {
    const std::vector<double> one{0.0, 0.0, 1.0};
    const NearestWithin none = nearest_within(one.data(), 0, one.data(), 1, 0.1);
    EXPECT_EQ(none.index[0], 0);
    EXPECT_TRUE(std::isinf(none.dist[0]));
    EXPECT_EQ(nearest_within(one.data(), 1, one.data(), 0, 0.1).dist.size(), 0u);
    EXPECT_THROW(nearest_within(one.data(), 1, one.data(), 1, 0.0), std::invalid_argument);
    const std::vector<double> bad{0.0, std::nan(""), 1.0};
    EXPECT_THROW(nearest_within(bad.data(), 1, one.data(), 1, 0.1), std::invalid_argument);
    const std::vector<double> wide{-1e300, 0.0, 0.0, 1e300, 0.0, 0.0};
    EXPECT_THROW(nearest_within(wide.data(), 2, one.data(), 1, 1e-9), std::invalid_argument);
}

}  // namespace
}  // namespace tripod
