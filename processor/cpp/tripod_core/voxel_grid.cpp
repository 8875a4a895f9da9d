// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/voxel_grid.hpp"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <stdexcept>

#include "tripod_core/parallel_chunks.hpp"
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

/// Parts (key ranges) per thread of the merge. The key/sort pass has one chunk per thread: each
/// voxel's merge looks at every chunk (two key loads per chunk and voxel), and with 4 chunks of
/// 16384 rows per thread, sorted in cache, the merge cost more than the sort saved (a scan of
/// 86,400 rows to 4,400 voxels: 2 threads did 1.3x the CPU work of one; one chunk each: 1.15x).
constexpr int kPartsPerThread = 4;
/// Keys sampled per chunk to cut the voxels into parts of about equal point counts.
constexpr int kSamplesPerChunk = 32;

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
    // The rows are cut into chunks (contiguous, in row order), each keyed and sorted by one
    // thread; the voxels are cut into parts (key ranges, in key order) merged and summed by one
    // thread each; chunks and parts are shared out by parallel_chunks. Each voxel's centroid
    // is summed over its points in chunk order and, within a chunk, in row order (a stable
    // sort): in row order, whatever the cut, so the output is the same bit for bit on any
    // thread count and any number of chunks.
    const int nt = static_cast<int>(
        std::max<int64_t>(1, std::min<int64_t>({num_threads, n / 4096, kMaxTeam})));
    const int64_t num_chunks = nt;
    const int64_t num_parts = nt == 1 ? 1 : kPartsPerThread * nt;
    auto chunk_begin = [&](int64_t c) { return n * c / num_chunks; };

    // 0. lattice origin: either 0 (index offset by kOffset) or Open3D's min_bound - size / 2,
    // from the bounds of the finite points (each chunk's, combined by the caller)
    std::vector<double> bounds(6 * num_chunks);  // per chunk: lo xyz, hi xyz
    // dense voxel key over the occupied box: ((ix - ix0) * ny + (iy - iy0)) * nz + (iz - iz0),
    // lexicographic in (x, y, z) like the index itself, but only as many bits as needed; a
    // non-finite point gets the key one past the last voxel (sorted last, dropped)
    struct Lattice {
        Eigen::Vector3d origin = Eigen::Vector3d::Zero();
        int64_t offset = kOffset, i0[3] = {}, extent[3] = {};
        uint64_t invalid = 0;
        bool empty = false, too_big = false;
    };
    auto lattice = [&]() {
        Lattice L;
        Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
        Eigen::Vector3d hi = -lo;
        for (int64_t c = 0; c < num_chunks; ++c)
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::min(lo[k], bounds[6 * c + k]);
                hi[k] = std::max(hi[k], bounds[6 * c + 3 + k]);
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

    // 1. bounds of each chunk; 2. per chunk: the keys of its points, sorted (stable LSD radix
    // sort, 11-bit digits, skipping digits none of its keys differ in) in its own part of the
    // buffers, and its runs of equal keys; 3. per part (a range of keys holding about as many
    // points as the others, whatever the chunks cover: chunks of a scan's rows each cover a
    // part of the room): the chunks' runs merged by key into voxels, and each voxel's centroid
    // summed over its runs in chunk order, i.e. in row order.
    Keyed* A = scratch(tl_keyed_a, n);
    Keyed* B = scratch(tl_keyed_b, n);
    std::vector<uint8_t> in_b(num_chunks, 0);  // a chunk's sorted keys ended up in B
    std::vector<int64_t> hist(static_cast<size_t>(nt) * kDigits);
    std::vector<std::vector<int64_t>> runs(num_chunks);  // per chunk: run starts, then its end
    std::vector<std::vector<float>> centroids(num_parts);  // per part: x, y, z of its voxels
    // three passes over fixed chunks / parts (parallel_chunks: a thread that comes late holds
    // no one up), the lattice and the part bounds computed between them by the caller
    detail::parallel_chunks(nt, num_chunks, [&](int64_t c) {
            double lo[3], hi[3];
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::numeric_limits<double>::infinity();
                hi[k] = -lo[k];
            }
            for (int64_t i = chunk_begin(c), e = chunk_begin(c + 1); i < e; ++i) {
                const float* p = xyz + stride * i;
                if (!finite3(p)) continue;
                for (int k = 0; k < 3; ++k) {
                    lo[k] = std::min(lo[k], static_cast<double>(p[k]));
                    hi[k] = std::max(hi[k], static_cast<double>(p[k]));
                }
            }
            for (int k = 0; k < 3; ++k) {
                bounds[6 * c + k] = lo[k];
                bounds[6 * c + 3 + k] = hi[k];
            }
        }, "voxel grid: bounds");
    const Lattice lat = lattice();
    {
        const Lattice& L = lat;
        const Eigen::Vector3d origin = L.origin;
        const int64_t offset = L.offset, *i0 = L.i0, *extent = L.extent;
        const uint64_t kInvalid = L.invalid;
        if (!L.empty && !L.too_big) {
            detail::parallel_chunks(nt, num_chunks, [&](int64_t c, int t) {
                int64_t* h = hist.data() + static_cast<size_t>(t) * kDigits;
                const int64_t b0 = chunk_begin(c), b1 = chunk_begin(c + 1);
                // Same arithmetic as Open3D: (p - origin) / size in double, floored, so the two
                // agree bit for bit in kMinBound mode.
                uint64_t kor = 0, kand = ~uint64_t{0};
                for (int64_t i = b0; i < b1; ++i) {
                    const float* p = xyz + stride * i;
                    uint64_t key = kInvalid;
                    if (finite3(p)) {
                        int64_t dense = 0;
                        for (int k = 0; k < 3; ++k) {
                            int64_t idx =
                                floor_i64((p[k] - origin[k]) / voxel_size) + offset - i0[k];
                            // rounding at the bounds
                            idx = std::clamp<int64_t>(idx, 0, extent[k] - 1);
                            dense = dense * extent[k] + idx;
                        }
                        key = static_cast<uint64_t>(dense);
                    }
                    A[i] = {key, i};
                    kor |= key;
                    kand &= key;
                }
                const uint64_t diff = kor & ~kand;  // the bits some keys differ in
                Keyed *src = A, *dst = B;
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
                in_b[c] = src == B;
                std::vector<int64_t>& r = runs[c];
                r.clear();
                r.reserve((b1 - b0) / 4 + 2);
                for (int64_t i = b0; i < b1 && src[i].key != kInvalid; ++i)
                    if (i == b0 || src[i].key != src[i - 1].key) r.push_back(i);
                int64_t e = b0;  // the chunk's end of finite points
                while (e < b1 && src[e].key != kInvalid) ++e;
                r.push_back(e);
            }, "voxel grid: keys");
            auto sorted = [&](int64_t c) -> const Keyed* { return in_b[c] ? B : A; };
            auto run_key = [&](int64_t c, size_t j) { return sorted(c)[runs[c][j]].key; };
            // Part bounds: keys at equal steps through a sample of every chunk's sorted finite
            // keys (kSamplesPerChunk each, weighted by the chunk's count), so the parts hold
            // about as many points each. Any increasing bounds give the same output (a voxel is
            // merged whole in one part); computed by the caller between the passes from a few
            // hundred keys (an exact count of the points below a key, searched for by bisection
            // over the key range, cost as much as a tenth of the merge).
            std::vector<std::pair<uint64_t, int64_t>> sample;  // (key, points it stands for)
            sample.reserve(num_chunks * kSamplesPerChunk);
            int64_t finite = 0;
            for (int64_t c = 0; c < num_chunks; ++c) {
                const int64_t b0 = chunk_begin(c), len = runs[c].back() - b0;
                finite += len;
                for (int q = 0; q < kSamplesPerChunk && len > 0; ++q) {
                    const int64_t lo = len * q / kSamplesPerChunk,
                                  hi = len * (q + 1) / kSamplesPerChunk;
                    if (hi > lo) sample.emplace_back(sorted(c)[b0 + lo].key, hi - lo);
                }
            }
            std::sort(sample.begin(), sample.end());
            std::vector<uint64_t> bound(num_parts + 1, kInvalid);  // part p: [bound[p], bound[p+1])
            bound[0] = 0;
            {
                int64_t below = 0;
                size_t j = 0;
                for (int64_t s = 1; s < num_parts; ++s) {
                    const int64_t want = finite * s / num_parts;
                    while (j < sample.size() && below + sample[j].second <= want)
                        below += sample[j++].second;
                    bound[s] = j < sample.size() ? std::max(bound[s - 1], sample[j].first)
                                                 : kInvalid;
                }
            }
            std::vector<size_t> at_stop(2 * static_cast<size_t>(nt) * num_chunks);
            detail::parallel_chunks(nt, num_parts, [&](int64_t part, int t) {
                size_t* at = at_stop.data() + 2 * static_cast<size_t>(t) * num_chunks;
                size_t* stop = at + num_chunks;
                const uint64_t k_lo = bound[part], k_hi = bound[part + 1];
                for (int64_t c = 0; c < num_chunks; ++c) {
                    const size_t nc = runs[c].size() - 1;
                    size_t lo = 0, hi = nc;  // first run with key >= k_lo
                    while (lo < hi) {
                        const size_t mid = (lo + hi) / 2;
                        if (run_key(c, mid) < k_lo) lo = mid + 1; else hi = mid;
                    }
                    at[c] = lo;
                    hi = nc;  // first run with key >= k_hi
                    while (lo < hi) {
                        const size_t mid = (lo + hi) / 2;
                        if (run_key(c, mid) < k_hi) lo = mid + 1; else hi = mid;
                    }
                    stop[c] = lo;
                }
                std::vector<float>& c_out = centroids[part];
                c_out.clear();
                for (;;) {
                    uint64_t k = kInvalid;
                    for (int64_t c = 0; c < num_chunks; ++c)
                        if (at[c] < stop[c]) k = std::min(k, run_key(c, at[c]));
                    if (k == kInvalid) break;
                    double sx = 0, sy = 0, sz = 0;
                    int64_t cnt = 0;
                    for (int64_t c = 0; c < num_chunks; ++c) {
                        if (at[c] == stop[c] || run_key(c, at[c]) != k) continue;
                        const Keyed* srt = sorted(c);
                        const int64_t k0 = runs[c][at[c]], k1 = runs[c][at[c] + 1];
                        ++at[c];
                        for (int64_t q = k0; q < k1; ++q) {
                            const float* p = xyz + stride * srt[q].row;
                            sx += p[0];
                            sy += p[1];
                            sz += p[2];
                        }
                        cnt += k1 - k0;
                    }
                    const double dc = static_cast<double>(cnt);
                    c_out.push_back(static_cast<float>(sx / dc));
                    c_out.push_back(static_cast<float>(sy / dc));
                    c_out.push_back(static_cast<float>(sz / dc));
                }
            }, "voxel grid: merge");
        }  // a lattice
    }
    if (lat.too_big)
        throw std::invalid_argument("cloud spans too many voxels (more than 2^21 per axis)");
    if (lat.empty) return PointsXYZ(0, 3);  // no finite point

    // the parts one after the other
    int64_t m = 0;
    for (const auto& c : centroids) m += static_cast<int64_t>(c.size()) / 3;
    PointsXYZ out(m, 3);
    float* o = out.data();
    for (const auto& c : centroids) o = std::copy(c.begin(), c.end(), o);
    trim(tl_keyed_a);
    trim(tl_keyed_b);
    return out;
}

}  // namespace tripod
