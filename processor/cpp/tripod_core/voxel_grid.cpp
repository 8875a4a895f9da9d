// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/voxel_grid.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

namespace tripod {

namespace {
// 21 bits per axis: +-1,048,576 voxels, i.e. +-10 km at 1 cm.
constexpr int64_t kBits = 21;
constexpr int64_t kOffset = int64_t{1} << (kBits - 1);
constexpr int64_t kMask = (int64_t{1} << kBits) - 1;

inline uint64_t voxel_key(const float* p, double inv) {
    const int64_t ix = static_cast<int64_t>(std::floor(p[0] * inv)) + kOffset;
    const int64_t iy = static_cast<int64_t>(std::floor(p[1] * inv)) + kOffset;
    const int64_t iz = static_cast<int64_t>(std::floor(p[2] * inv)) + kOffset;
    return (static_cast<uint64_t>(ix & kMask) << (2 * kBits)) |
           (static_cast<uint64_t>(iy & kMask) << kBits) | static_cast<uint64_t>(iz & kMask);
}
}  // namespace

PointsXYZ voxel_downsample(const PointsXYZ& points, double voxel_size, int num_threads) {
    if (!(voxel_size > 0.0)) throw std::invalid_argument("voxel_size must be > 0");
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    const double inv = 1.0 / voxel_size;
    const int64_t n = points.rows();

    // 1. key every finite point (parallel)
    std::vector<std::pair<uint64_t, int64_t>> keyed(n);
    std::vector<char> ok(n, 0);
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const float* p = points.row(i).data();
        ok[i] = std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
        keyed[i] = {ok[i] ? voxel_key(p, inv) : ~uint64_t{0}, i};
    }
    // 2. sort by key (stable order inside a voxel keeps the sum deterministic)
    std::sort(keyed.begin(), keyed.end());
    int64_t valid = n;
    while (valid > 0 && !ok[keyed[valid - 1].second]) --valid;

    // 3. run boundaries, then centroids (parallel over voxels)
    std::vector<int64_t> starts;
    starts.reserve(valid / 4 + 1);
    for (int64_t i = 0; i < valid; ++i)
        if (i == 0 || keyed[i].first != keyed[i - 1].first) starts.push_back(i);
    starts.push_back(valid);
    const int64_t m = static_cast<int64_t>(starts.size()) - 1;
    PointsXYZ out(std::max<int64_t>(m, 0), 3);
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int64_t v = 0; v < m; ++v) {
        double sx = 0, sy = 0, sz = 0;
        for (int64_t k = starts[v]; k < starts[v + 1]; ++k) {
            const float* p = points.row(keyed[k].second).data();
            sx += p[0];
            sy += p[1];
            sz += p[2];
        }
        const double c = static_cast<double>(starts[v + 1] - starts[v]);
        out(v, 0) = static_cast<float>(sx / c);
        out(v, 1) = static_cast<float>(sy / c);
        out(v, 2) = static_cast<float>(sz / c);
    }
    return out;
}

}  // namespace tripod
