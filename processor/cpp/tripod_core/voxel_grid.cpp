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

/// static_cast<int64_t>(std::floor(x)) for |x| < 2^63, without a libm call.
inline int64_t floor_i64(double x) {
    const int64_t i = static_cast<int64_t>(x);
    return i - (x < static_cast<double>(i));
}

struct Keyed {
    uint64_t key;
    int64_t row;
};
constexpr int kDigitBits = 11, kDigits = 1 << kDigitBits;
constexpr int kMaxTeam = 64;  // threads at most

// Sort buffers kept by the calling thread between calls (up to kKeepKeyed entries each): fresh
// pages cost a page fault each on first touch, serialised in the kernel, whatever the threads.
constexpr int64_t kKeepKeyed = int64_t{1} << 21;
thread_local std::vector<Keyed> tl_keyed_a, tl_keyed_b;

Keyed* scratch(std::vector<Keyed>& buf, int64_t n) {
    if (static_cast<int64_t>(buf.size()) < n) {
        std::vector<Keyed>().swap(buf);
        buf.resize(n);
    }
    return buf.data();
}

/// Gives back a buffer above kKeepKeyed entries (a one-off huge cloud).
void trim(std::vector<Keyed>& buf) {
    if (static_cast<int64_t>(buf.size()) > kKeepKeyed) std::vector<Keyed>().swap(buf);
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
    const int nt = static_cast<int>(
        std::max<int64_t>(1, std::min<int64_t>({num_threads, n / 4096, kMaxTeam})));

    // 0. lattice origin: either 0 (index offset by kOffset) or Open3D's min_bound - size / 2,
    // from the bounds of the finite points (each block's, combined in the same parallel region
    // as the rest: every fork, join and barrier may have to wake a sleeping thread, see
    // tripod_processor/__init__.py)
    std::vector<double> bounds(6 * nt);  // per thread: lo xyz, hi xyz
    for (int u = 0; u < nt; ++u)
        for (int k = 0; k < 3; ++k) {
            bounds[6 * u + k] = std::numeric_limits<double>::infinity();
            bounds[6 * u + 3 + k] = -std::numeric_limits<double>::infinity();
        }
    // dense voxel key over the occupied box: ((ix - ix0) * ny + (iy - iy0)) * nz + (iz - iz0),
    // lexicographic in (x, y, z) like the index itself, but only as many bits as needed; a
    // non-finite point gets the key one past the last voxel (sorted last, dropped)
    struct Lattice {
        Eigen::Vector3d origin = Eigen::Vector3d::Zero();
        int64_t offset = kOffset, i0[3] = {}, extent[3] = {};
        uint64_t invalid = 0;
        bool empty = false, too_big = false;
    };
    auto lattice = [&](int T) {
        Lattice L;
        Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
        Eigen::Vector3d hi = -lo;
        for (int u = 0; u < T; ++u)
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::min(lo[k], bounds[6 * u + k]);
                hi[k] = std::max(hi[k], bounds[6 * u + 3 + k]);
            }
        if (!(lo[0] <= hi[0])) {  // no finite point
            L.empty = true;
            return L;
        }
        if (align == VoxelAlign::kMinBound) {
            L.origin = lo - Eigen::Vector3d::Constant(0.5 * voxel_size);
            L.offset = 0;
        }
        for (int k = 0; k < 3; ++k) {
            const double a = std::floor((lo[k] - L.origin[k]) / voxel_size) + L.offset;
            const double b = std::floor((hi[k] - L.origin[k]) / voxel_size) + L.offset;
            if (a < 0 || b > static_cast<double>(kMask)) {
                L.too_big = true;
                return L;
            }
            L.i0[k] = static_cast<int64_t>(a);
            L.extent[k] = static_cast<int64_t>(b) - L.i0[k] + 1;
        }
        L.invalid = static_cast<uint64_t>(L.extent[0] * L.extent[1] * L.extent[2]);
        return L;
    };

    // 1. key the points of each thread's block (a contiguous range of rows); 2. each thread
    // sorts its own block by key (stable LSD radix sort, 11-bit digits, skipping digits no key
    // differs in), in its own part of the buffers: the data stay with the thread (cache lines
    // moving between cores cost more than the sort itself); 3. each block's runs of equal keys;
    // 4. the runs merged by key into voxels and 5. each voxel's centroid, summed over its runs
    // in block order, i.e. in point order: the same sums, bit for bit, on any thread count.
    Keyed* A = scratch(tl_keyed_a, n);
    Keyed* B = scratch(tl_keyed_b, n);
    std::vector<uint64_t> key_or(nt, 0), key_and(nt, ~uint64_t{0});
    std::vector<int64_t> hist(static_cast<size_t>(nt) * kDigits);
    std::vector<std::vector<int64_t>> runs(nt);  // per block: run starts, then the block's end
    std::vector<std::vector<float>> centroids(nt);  // per thread: x, y, z of its voxels
    int team = 1;
    Lattice lat;
#pragma omp parallel num_threads(nt)
    {
        const int T = omp_get_num_threads(), t = omp_get_thread_num();
        const int64_t b0 = n * t / T, b1 = n * (t + 1) / T;
        {
            double lo[3], hi[3];
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::numeric_limits<double>::infinity();
                hi[k] = -lo[k];
            }
            for (int64_t i = b0; i < b1; ++i) {
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
        }
#pragma omp barrier
        // every thread combines the blocks' bounds alike (the same lattice on every thread)
        const Lattice L = lattice(nt);
        if (t == 0) lat = L;
        const Eigen::Vector3d origin = L.origin;
        const int64_t offset = L.offset, *i0 = L.i0, *extent = L.extent;
        const uint64_t kInvalid = L.invalid;
        if (!L.empty && !L.too_big) {
            // Same arithmetic as Open3D: (p - origin) / size in double, floored, so the two agree
            // bit for bit in kMinBound mode.
            uint64_t kor = 0, kand = ~uint64_t{0};
            for (int64_t i = b0; i < b1; ++i) {
                const float* p = xyz + stride * i;
                uint64_t key = kInvalid;
                if (finite3(p)) {
                    int64_t dense = 0;
                    for (int k = 0; k < 3; ++k) {
                        int64_t idx = floor_i64((p[k] - origin[k]) / voxel_size) + offset - i0[k];
                        idx = std::clamp<int64_t>(idx, 0, extent[k] - 1);  // rounding at the bounds
                        dense = dense * extent[k] + idx;
                    }
                    key = static_cast<uint64_t>(dense);
                }
                A[i] = {key, i};
                kor |= key;
                kand &= key;
            }
            key_or[t] = kor;
            key_and[t] = kand;
#pragma omp barrier
            // the same digits for every block, so that every sorted block ends up in the same
            // buffer
            uint64_t all_or = 0, all_and = ~uint64_t{0};
            for (int u = 0; u < T; ++u) all_or |= key_or[u], all_and &= key_and[u];
            const uint64_t diff = all_or & ~all_and;  // the bits some keys differ in
            Keyed *src = A, *dst = B;
            int64_t* h = hist.data() + static_cast<size_t>(t) * kDigits;
            for (int shift = 0; shift < 64; shift += kDigitBits) {
                if (((diff >> shift) & (kDigits - 1)) == 0) continue;
                std::fill(h, h + kDigits, 0);
                for (int64_t i = b0; i < b1; ++i) ++h[(src[i].key >> shift) & (kDigits - 1)];
                int64_t sum = b0;
                for (int d = 0; d < kDigits; ++d) {
                    const int64_t k = h[d];
                    h[d] = sum;
                    sum += k;
                }
                for (int64_t i = b0; i < b1; ++i)
                    dst[h[(src[i].key >> shift) & (kDigits - 1)]++] = src[i];
                std::swap(src, dst);
            }
            std::vector<int64_t>& r = runs[t];
            r.reserve((b1 - b0) / 4 + 2);
            for (int64_t i = b0; i < b1 && src[i].key != kInvalid; ++i)
                if (i == b0 || src[i].key != src[i - 1].key) r.push_back(i);
            int64_t e = b0;  // the block's end of finite points
            while (e < b1 && src[e].key != kInvalid) ++e;
            r.push_back(e);
            // 4. merge the blocks' runs by key and 5. sum each voxel's centroid, every thread for
            // its own share of the keys (split at block 0's runs): a voxel's runs are summed in
            // block order, i.e. in point order
#pragma omp barrier
            auto run_key = [&](int u, size_t j) { return src[runs[u][j]].key; };
            const size_t n0 = runs[0].size() - 1;  // block 0's voxels
            const uint64_t k_lo = t == 0 ? 0 : (n0 ? run_key(0, n0 * t / T) : kInvalid);
            const uint64_t k_hi =
                t + 1 == T ? kInvalid : (n0 ? run_key(0, n0 * (t + 1) / T) : kInvalid);
            size_t at[kMaxTeam], stop[kMaxTeam];
            for (int u = 0; u < T; ++u) {
                const size_t nu = runs[u].size() - 1;
                size_t lo = 0, hi = nu;  // first run with key >= k_lo
                while (lo < hi) {
                    const size_t mid = (lo + hi) / 2;
                    if (run_key(u, mid) < k_lo) lo = mid + 1; else hi = mid;
                }
                at[u] = lo;
                hi = nu;  // first run with key >= k_hi
                while (lo < hi) {
                    const size_t mid = (lo + hi) / 2;
                    if (run_key(u, mid) < k_hi) lo = mid + 1; else hi = mid;
                }
                stop[u] = lo;
            }
            std::vector<float>& c_out = centroids[t];
            c_out.clear();
            for (;;) {
                uint64_t k = kInvalid;
                for (int u = 0; u < T; ++u)
                    if (at[u] < stop[u]) k = std::min(k, run_key(u, at[u]));
                if (k == kInvalid) break;
                double sx = 0, sy = 0, sz = 0;
                int64_t c = 0;
                for (int u = 0; u < T; ++u) {
                    if (at[u] == stop[u] || run_key(u, at[u]) != k) continue;
                    const int64_t k0 = runs[u][at[u]], k1 = runs[u][at[u] + 1];
                    ++at[u];
                    for (int64_t q = k0; q < k1; ++q) {
                        const float* p = xyz + stride * src[q].row;
                        sx += p[0];
                        sy += p[1];
                        sz += p[2];
                    }
                    c += k1 - k0;
                }
                const double cnt = static_cast<double>(c);
                c_out.push_back(static_cast<float>(sx / cnt));
                c_out.push_back(static_cast<float>(sy / cnt));
                c_out.push_back(static_cast<float>(sz / cnt));
            }
            if (t == 0) team = T;
        }  // a lattice
    }
    if (lat.too_big)
        throw std::invalid_argument("cloud spans too many voxels (more than 2^21 per axis)");
    if (lat.empty) return PointsXYZ(0, 3);  // no finite point

    // the shares one after the other
    int64_t m = 0;
    for (int u = 0; u < team; ++u) m += static_cast<int64_t>(centroids[u].size()) / 3;
    PointsXYZ out(m, 3);
    float* o = out.data();
    for (int u = 0; u < team; ++u) o = std::copy(centroids[u].begin(), centroids[u].end(), o);
    trim(tl_keyed_a);
    trim(tl_keyed_b);
    return out;
}

}  // namespace tripod
