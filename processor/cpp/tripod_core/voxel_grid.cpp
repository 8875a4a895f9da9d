// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/voxel_grid.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

namespace tripod {

namespace {
// 21 bits per axis: 2,097,152 voxels per axis, i.e. +-10 km at 1 cm around the origin.
constexpr int64_t kBits = 21;
constexpr int64_t kOffset = int64_t{1} << (kBits - 1);
constexpr int64_t kMask = (int64_t{1} << kBits) - 1;

inline bool finite3(const float* p) {
    return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}
}  // namespace

PointsXYZ voxel_downsample(const PointsXYZ& points, double voxel_size, int num_threads,
                           VoxelAlign align) {
    if (!(voxel_size > 0.0) || !std::isfinite(voxel_size))
        throw std::invalid_argument("voxel_size must be a finite number > 0");
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    const int64_t n = points.rows();

    // 0. lattice origin: either 0 (index offset by kOffset) or Open3D's min_bound - size / 2
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (int64_t i = 0; i < n; ++i) {
        const float* p = points.row(i).data();
        if (!finite3(p)) continue;
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], static_cast<double>(p[k]));
            hi[k] = std::max(hi[k], static_cast<double>(p[k]));
        }
    }
    if (!(lo[0] <= hi[0])) return PointsXYZ(0, 3);  // no finite point
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    int64_t offset = kOffset;
    if (align == VoxelAlign::kMinBound) {
        origin = lo - Eigen::Vector3d::Constant(0.5 * voxel_size);
        offset = 0;
    }
    // dense voxel key over the occupied box: ((ix - ix0) * ny + (iy - iy0)) * nz + (iz - iz0),
    // lexicographic in (x, y, z) like the index itself, but only as many bits as needed
    int64_t i0[3], extent[3];
    for (int k = 0; k < 3; ++k) {
        const double a = std::floor((lo[k] - origin[k]) / voxel_size) + offset;
        const double b = std::floor((hi[k] - origin[k]) / voxel_size) + offset;
        if (a < 0 || b > static_cast<double>(kMask))
            throw std::invalid_argument("cloud spans too many voxels (more than 2^21 per axis)");
        i0[k] = static_cast<int64_t>(a);
        extent[k] = static_cast<int64_t>(b) - i0[k] + 1;
    }

    // 1. key every finite point (parallel). Same arithmetic as Open3D: (p - origin) / size in
    // double, floored, so the two agree bit for bit in kMinBound mode.
    std::vector<std::pair<uint64_t, int64_t>> keyed(n);
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const float* p = points.row(i).data();
        uint64_t key = ~uint64_t{0};
        if (finite3(p)) {
            int64_t dense = 0;
            for (int k = 0; k < 3; ++k) {
                int64_t idx =
                    static_cast<int64_t>(std::floor((p[k] - origin[k]) / voxel_size)) + offset - i0[k];
                idx = std::clamp<int64_t>(idx, 0, extent[k] - 1);  // guards rounding at the bounds
                dense = dense * extent[k] + idx;
            }
            key = static_cast<uint64_t>(dense);
        }
        keyed[i] = {key, i};
    }
    // 2. stable LSD radix sort by key, 11-bit digits, skipping digits no key differs in; the
    //    order inside a voxel stays the point order, which keeps the sums deterministic
    {
        uint64_t diff = 0;
        for (const auto& e : keyed) diff |= e.first ^ keyed[0].first;
        std::vector<std::pair<uint64_t, int64_t>> tmp(n);
        std::vector<int64_t> count(2049);
        for (int shift = 0; shift < 64; shift += 11) {
            if (((diff >> shift) & 0x7FF) == 0) continue;
            std::fill(count.begin(), count.end(), 0);
            for (const auto& e : keyed) ++count[((e.first >> shift) & 0x7FF) + 1];
            for (int d = 0; d < 2048; ++d) count[d + 1] += count[d];
            for (const auto& e : keyed) tmp[count[(e.first >> shift) & 0x7FF]++] = e;
            keyed.swap(tmp);
        }
    }
    int64_t valid = n;
    while (valid > 0 && keyed[valid - 1].first == ~uint64_t{0}) --valid;

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
