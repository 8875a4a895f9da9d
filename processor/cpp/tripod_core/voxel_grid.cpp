// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/voxel_grid.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <stdexcept>

#include "tripod_core/phase_timer.hpp"

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

PointsXYZ voxel_downsample(const Eigen::Ref<const PointsXYZ>& points, double voxel_size,
                           int num_threads, VoxelAlign align) {
    if (!(voxel_size > 0.0) || !std::isfinite(voxel_size))
        throw std::invalid_argument("voxel_size must be a finite number > 0");
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    TRIPOD_PHASE("voxel: total");
    const int64_t n = points.rows();
    const float* xyz = points.data();  // row-major
    const int64_t stride = points.outerStride();
    // Every pass below splits [0, n) into one contiguous block per thread (all work is O(n),
    // evenly spread); per-block results are combined in block order, so the output is the
    // same whatever the thread count.
    const int nt = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(num_threads, n / 4096)));

    // 0. lattice origin: either 0 (index offset by kOffset) or Open3D's min_bound - size / 2
    std::vector<double> bounds(6 * nt);  // per thread: lo xyz, hi xyz
#pragma omp parallel num_threads(nt)
    {
        const int T = omp_get_num_threads(), t = omp_get_thread_num();
        double lo[3], hi[3];
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::numeric_limits<double>::infinity();
            hi[k] = -lo[k];
        }
        for (int64_t i = n * t / T; i < n * (t + 1) / T; ++i) {
            const float* p = xyz + stride * i;
            if (!finite3(p)) continue;
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::min(lo[k], static_cast<double>(p[k]));
                hi[k] = std::max(hi[k], static_cast<double>(p[k]));
            }
        }
        for (int k = 0; k < 3; ++k) {
            bounds[6 * t + k] = lo[k];
            bounds[6 * t + 3 + k] = hi[k];
        }
        if (t == 0)  // a team smaller than asked for: blank the rest
            for (int u = T; u < nt; ++u)
                for (int k = 0; k < 3; ++k) {
                    bounds[6 * u + k] = std::numeric_limits<double>::infinity();
                    bounds[6 * u + 3 + k] = -std::numeric_limits<double>::infinity();
                }
    }
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (int u = 0; u < nt; ++u)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], bounds[6 * u + k]);
            hi[k] = std::max(hi[k], bounds[6 * u + 3 + k]);
        }
    if (!(lo[0] <= hi[0])) return PointsXYZ(0, 3);  // no finite point
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    int64_t offset = kOffset;
    if (align == VoxelAlign::kMinBound) {
        origin = lo - Eigen::Vector3d::Constant(0.5 * voxel_size);
        offset = 0;
    }
    // dense voxel key over the occupied box: ((ix - ix0) * ny + (iy - iy0)) * nz + (iz - iz0),
    // lexicographic in (x, y, z) like the index itself, but only as many bits as needed; a
    // non-finite point gets the key one past the last voxel (sorted last, dropped)
    int64_t i0[3], extent[3];
    for (int k = 0; k < 3; ++k) {
        const double a = std::floor((lo[k] - origin[k]) / voxel_size) + offset;
        const double b = std::floor((hi[k] - origin[k]) / voxel_size) + offset;
        if (a < 0 || b > static_cast<double>(kMask))
            throw std::invalid_argument("cloud spans too many voxels (more than 2^21 per axis)");
        i0[k] = static_cast<int64_t>(a);
        extent[k] = static_cast<int64_t>(b) - i0[k] + 1;
    }
    const uint64_t kInvalid = static_cast<uint64_t>(extent[0] * extent[1] * extent[2]);

    // 1. key every point; 2. stable LSD radix sort by key, 11-bit digits, skipping digits no
    // key differs in (the order inside a voxel stays the point order, which keeps the sums
    // deterministic); 3. run boundaries. One parallel region, blocks per thread.
    struct Keyed {
        uint64_t key;
        int64_t row;
    };
    constexpr int kDigitBits = 11, kDigits = 1 << kDigitBits;
    std::unique_ptr<Keyed[]> keyed(new Keyed[n]), tmp(new Keyed[n]);  // no zero-fill
    std::vector<uint64_t> key_or(nt, 0), key_and(nt, ~uint64_t{0});
    std::vector<int64_t> hist(static_cast<size_t>(nt) * kDigits);
    std::vector<int64_t> run_count(nt + 1, 0);
    std::vector<int64_t> starts;
    Keyed* sorted = nullptr;
    int64_t valid = 0;
#pragma omp parallel num_threads(nt)
    {
        const int T = omp_get_num_threads(), t = omp_get_thread_num();
        const int64_t b0 = n * t / T, b1 = n * (t + 1) / T;
        // Same arithmetic as Open3D: (p - origin) / size in double, floored, so the two agree
        // bit for bit in kMinBound mode.
        uint64_t kor = 0, kand = ~uint64_t{0};
        for (int64_t i = b0; i < b1; ++i) {
            const float* p = xyz + stride * i;
            uint64_t key = kInvalid;
            if (finite3(p)) {
                int64_t dense = 0;
                for (int k = 0; k < 3; ++k) {
                    int64_t idx = static_cast<int64_t>(std::floor((p[k] - origin[k]) / voxel_size)) +
                                  offset - i0[k];
                    idx = std::clamp<int64_t>(idx, 0, extent[k] - 1);  // rounding at the bounds
                    dense = dense * extent[k] + idx;
                }
                key = static_cast<uint64_t>(dense);
            }
            keyed[i] = {key, i};
            kor |= key;
            kand &= key;
        }
        key_or[t] = kor;
        key_and[t] = kand;
#pragma omp barrier
        uint64_t all_or = 0, all_and = ~uint64_t{0};
        for (int u = 0; u < T; ++u) all_or |= key_or[u], all_and &= key_and[u];
        const uint64_t diff = all_or & ~all_and;  // the bits some keys differ in
        Keyed *src = keyed.get(), *dst = tmp.get();
        int64_t* h = hist.data() + static_cast<size_t>(t) * kDigits;
        for (int shift = 0; shift < 64; shift += kDigitBits) {
            if (((diff >> shift) & (kDigits - 1)) == 0) continue;
            std::fill(h, h + kDigits, 0);
            for (int64_t i = b0; i < b1; ++i) ++h[(src[i].key >> shift) & (kDigits - 1)];
#pragma omp barrier
#pragma omp single
            {
                int64_t sum = 0;  // offsets: digit-major, then block order (stable)
                for (int d = 0; d < kDigits; ++d)
                    for (int u = 0; u < T; ++u) {
                        int64_t& c = hist[static_cast<size_t>(u) * kDigits + d];
                        const int64_t k = c;
                        c = sum;
                        sum += k;
                    }
            }  // implicit barrier
            for (int64_t i = b0; i < b1; ++i) dst[h[(src[i].key >> shift) & (kDigits - 1)]++] = src[i];
            std::swap(src, dst);
#pragma omp barrier
        }
        // the finite points: those before the first invalid key
#pragma omp single
        {
            sorted = src;
            int64_t lo_i = 0, hi_i = n;  // first index with key == kInvalid
            while (lo_i < hi_i) {
                const int64_t mid = lo_i + (hi_i - lo_i) / 2;
                if (src[mid].key == kInvalid) hi_i = mid; else lo_i = mid + 1;
            }
            valid = lo_i;
        }
        // run boundaries: counted per block, then written at the block's offset
        const int64_t v0 = valid * t / T, v1 = valid * (t + 1) / T;
        int64_t c = 0;
        for (int64_t i = v0; i < v1; ++i) c += i == 0 || src[i].key != src[i - 1].key;
        run_count[t + 1] = c;
#pragma omp barrier
#pragma omp single
        {
            for (int u = 0; u < T; ++u) run_count[u + 1] += run_count[u];
            starts.resize(run_count[T] + 1);
            starts[run_count[T]] = valid;
        }
        int64_t w = run_count[t];
        for (int64_t i = v0; i < v1; ++i)
            if (i == 0 || src[i].key != src[i - 1].key) starts[w++] = i;
    }

    // 4. centroids (parallel over voxels)
    const int64_t m = static_cast<int64_t>(starts.size()) - 1;
    PointsXYZ out(std::max<int64_t>(m, 0), 3);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 256)
    for (int64_t v = 0; v < m; ++v) {
        double sx = 0, sy = 0, sz = 0;
        for (int64_t k = starts[v]; k < starts[v + 1]; ++k) {
            const float* p = xyz + stride * sorted[k].row;
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
