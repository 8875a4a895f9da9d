// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/local_shape.hpp"

#include <omp.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <iterator>
#include <numeric>
#include <stdexcept>
#include <vector>

namespace tripod {
namespace {

constexpr int64_t kBias = int64_t(1) << 20;  // voxel indices in [-2^20, 2^20)
constexpr int64_t kMask = (int64_t(1) << 21) - 1;

inline int64_t pack(int64_t ix, int64_t iy, int64_t iz) {
    return ((ix + kBias) << 42) | ((iy + kBias) << 21) | (iz + kBias);
}

int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

/// Sorted unique keys and, for each point, the index of its key (-1 for non-finite points).
struct Grid {
    std::vector<int64_t> keys;      // sorted unique
    std::vector<int32_t> point_cell;  // per point
    int64_t find(int64_t key) const {
        auto it = std::lower_bound(keys.begin(), keys.end(), key);
        return (it != keys.end() && *it == key) ? int64_t(it - keys.begin()) : -1;
    }
};

template <class KeyFn>
Grid build_grid(Eigen::Index n, KeyFn key_of, int nt) {
    std::vector<int64_t> pk(n);
#pragma omp parallel for num_threads(nt) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i) pk[i] = key_of(i);
    // sorted unique keys: each thread sorts and dedups its share of the points, then the short
    // runs (voxels, not points) are merged; the same keys as one sort of all of them
    const int nc = int(std::max<Eigen::Index>(1, std::min<Eigen::Index>(nt, n / 65536)));
    std::vector<std::vector<int64_t>> part(nc);
#pragma omp parallel for num_threads(nc) schedule(static, 1)
    for (int c = 0; c < nc; ++c) {
        const Eigen::Index b = n * c / nc, e = n * (c + 1) / nc;
        auto& v = part[c];
        v.reserve(size_t(e - b));
        for (Eigen::Index i = b; i < e; ++i)
            if (pk[i] >= 0) v.push_back(pk[i]);
        std::sort(v.begin(), v.end());
        v.erase(std::unique(v.begin(), v.end()), v.end());
    }
    Grid g;
    g.keys = std::move(part[0]);
    for (int c = 1; c < nc; ++c) {
        std::vector<int64_t> merged;
        merged.reserve(g.keys.size() + part[c].size());
        std::merge(g.keys.begin(), g.keys.end(), part[c].begin(), part[c].end(),
                   std::back_inserter(merged));
        merged.erase(std::unique(merged.begin(), merged.end()), merged.end());
        g.keys = std::move(merged);
    }
    g.point_cell.assign(n, -1);
#pragma omp parallel for num_threads(nt) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i)
        if (pk[i] >= 0) g.point_cell[i] = static_cast<int32_t>(g.find(pk[i]));
    return g;
}

/// The cubic voxels (edge voxel_size [m], lattice floor(p / size)) of a cloud.
Grid voxel_grid(const PointsXYZ& points, double voxel_size, int nt) {
    const double inv = 1.0 / voxel_size;
    auto key_of = [&](Eigen::Index i) -> int64_t {
        const auto p = points.row(i);
        if (!p.allFinite()) return -1;
        return pack(int64_t(std::floor(p.x() * inv)), int64_t(std::floor(p.y() * inv)),
                    int64_t(std::floor(p.z() * inv)));
    };
    return build_grid(points.rows(), key_of, nt);
}

}  // namespace

FeaturesF voxel_local_shape(const PointsXYZ& points, double voxel_size, int radius_voxels,
                            int num_threads) {
    if (!(voxel_size > 0)) throw std::invalid_argument("voxel_size must be > 0");
    if (radius_voxels < 0) throw std::invalid_argument("radius_voxels must be >= 0");
    const int nt = threads(num_threads);
    const Eigen::Index n = points.rows();
    const Grid g = voxel_grid(points, voxel_size, nt);
    const size_t nv = g.keys.size();

    // 1. moments per voxel, relative to the voxel's corner for numerical stability
    //    (count, sum x, sum xx upper triangle): 10 doubles
    std::vector<double> mom(nv * 10, 0.0);
    for (Eigen::Index i = 0; i < n; ++i) {
        const int32_t c = g.point_cell[i];
        if (c < 0) continue;
        double* m = &mom[size_t(c) * 10];
        const double x = points(i, 0), y = points(i, 1), z = points(i, 2);
        m[0] += 1;
        m[1] += x; m[2] += y; m[3] += z;
        m[4] += x * x; m[5] += x * y; m[6] += x * z;
        m[7] += y * y; m[8] += y * z; m[9] += z * z;
    }

    // 2. per voxel: sum the neighbourhood's moments, eigen-decompose the covariance
    FeaturesF vox(static_cast<Eigen::Index>(nv), 7);
    const int r = radius_voxels;
#pragma omp parallel for num_threads(nt) schedule(dynamic, 256)
    for (int64_t v = 0; v < int64_t(nv); ++v) {
        const int64_t k = g.keys[v];
        const int64_t ix = (k >> 42) & kMask, iy = (k >> 21) & kMask, iz = k & kMask;
        double s[10] = {0};
        // a fixed reference point keeps the sums of squares small (centre of this voxel)
        // keys are sorted with z in the lowest bits: the voxels of one (dx, dy) column of the
        // neighbourhood are one run of keys, found with one search (same order as dz = -r..r)
        for (int dx = -r; dx <= r; ++dx)
            for (int dy = -r; dy <= r; ++dy) {
                const int64_t col = ((ix + dx) << 42) | ((iy + dy) << 21);
                const int64_t k_lo = col | (iz - r), k_hi = col | (iz + r);
                for (auto it = std::lower_bound(g.keys.begin(), g.keys.end(), k_lo);
                     it != g.keys.end() && *it <= k_hi; ++it) {
                    const double* m = &mom[size_t(it - g.keys.begin()) * 10];
                    for (int j = 0; j < 10; ++j) s[j] += m[j];
                }
            }
        const double cnt = s[0];
        const Eigen::Vector3d mean(s[1] / cnt, s[2] / cnt, s[3] / cnt);
        Eigen::Matrix3d cov;
        cov(0, 0) = s[4] / cnt - mean.x() * mean.x();
        cov(0, 1) = cov(1, 0) = s[5] / cnt - mean.x() * mean.y();
        cov(0, 2) = cov(2, 0) = s[6] / cnt - mean.x() * mean.z();
        cov(1, 1) = s[7] / cnt - mean.y() * mean.y();
        cov(1, 2) = cov(2, 1) = s[8] / cnt - mean.y() * mean.z();
        cov(2, 2) = s[9] / cnt - mean.z() * mean.z();
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
        es.compute(cov);  // iterative solver: accurate also for nearly flat neighbourhoods
        Eigen::Vector3d nrm = es.eigenvectors().col(0);
        if (nrm.z() < 0) nrm = -nrm;
        const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);
        vox(v, 0) = float(nrm.x());
        vox(v, 1) = float(nrm.y());
        vox(v, 2) = float(nrm.z());
        vox(v, 3) = float(ev(0));
        vox(v, 4) = float(ev(1));
        vox(v, 5) = float(ev(2));
        vox(v, 6) = float(cnt);
    }

    // 3. scatter back to the points
    FeaturesF out = FeaturesF::Zero(n, 7);
#pragma omp parallel for num_threads(nt) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i)
        if (g.point_cell[i] >= 0) out.row(i) = vox.row(g.point_cell[i]);
    return out;
}

void voxel_assign(const PointsXYZ& points, double voxel_size, PointsXYZ& centroids,
                  std::vector<int32_t>& point_voxel, std::vector<int32_t>& counts,
                  int num_threads) {
    if (!(voxel_size > 0)) throw std::invalid_argument("voxel_size must be > 0");
    const int nt = threads(num_threads);
    const Eigen::Index n = points.rows();
    const Grid g = voxel_grid(points, voxel_size, nt);
    const size_t nv = g.keys.size();
    std::vector<double> sum(nv * 3, 0.0);
    counts.assign(nv, 0);
    for (Eigen::Index i = 0; i < n; ++i) {
        const int32_t c = g.point_cell[i];
        if (c < 0) continue;
        sum[size_t(c) * 3 + 0] += points(i, 0);
        sum[size_t(c) * 3 + 1] += points(i, 1);
        sum[size_t(c) * 3 + 2] += points(i, 2);
        counts[c] += 1;
    }
    centroids.resize(static_cast<Eigen::Index>(nv), 3);
    for (size_t v = 0; v < nv; ++v)
        for (int k = 0; k < 3; ++k) centroids(Eigen::Index(v), k) = float(sum[v * 3 + k] / counts[v]);
    point_voxel = std::move(g.point_cell);
}

FeaturesF column_context(const PointsXYZ& points, const uint8_t* upright,
                         const ColumnContextOptions& options) {
    const double cell_size = options.cell_size, z_low = options.z_low, z_high = options.z_high;
    const int num_directions = options.num_directions, num_threads = options.num_threads;
    const double skip = options.skip, max_range = options.max_range;
    if (!(cell_size > 0)) throw std::invalid_argument("cell_size must be > 0");
    if (num_directions < 1) throw std::invalid_argument("num_directions must be >= 1");
    const int nt = threads(num_threads);
    const Eigen::Index n = points.rows();

    // bounds of the finite points -> a dense 2-D grid (rooms are small: a few 100 x 100 cells)
    double xmin = 1e300, ymin = 1e300, xmax = -1e300, ymax = -1e300;
    for (Eigen::Index i = 0; i < n; ++i) {
        const auto p = points.row(i);
        if (!p.allFinite()) continue;
        xmin = std::min(xmin, double(p.x())); xmax = std::max(xmax, double(p.x()));
        ymin = std::min(ymin, double(p.y())); ymax = std::max(ymax, double(p.y()));
    }
    FeaturesF out = FeaturesF::Zero(n, 5);
    if (xmin > xmax) return out;
    const double inv = 1.0 / cell_size;
    const int64_t W = int64_t((xmax - xmin) * inv) + 1, H = int64_t((ymax - ymin) * inv) + 1;
    if (W * H > int64_t(1) << 28) throw std::invalid_argument("column grid too large: cell_size too small for this extent");
    std::vector<int32_t> cell(n, -1);
    std::vector<float> zlo(W * H, 1e30f), zhi(W * H, -1e30f);
    std::vector<int32_t> count(W * H, 0);
    std::vector<uint8_t> occ(W * H, 0);
    for (Eigen::Index i = 0; i < n; ++i) {
        const auto p = points.row(i);
        if (!p.allFinite()) continue;
        const int64_t cx = int64_t((p.x() - xmin) * inv), cy = int64_t((p.y() - ymin) * inv);
        const int64_t c = cy * W + cx;
        cell[i] = int32_t(c);
        count[c] += 1;
        if (upright && !upright[i]) continue;
        zlo[c] = std::min(zlo[c], p.z());
        zhi[c] = std::max(zhi[c], p.z());
        if (p.z() > z_low && p.z() < z_high) occ[c] = 1;
    }

    // rays from every occupied cell
    std::vector<float> open_frac(W * H, 0.f), free_mean(W * H, 0.f);
    const double step = 0.5;  // [cells] ray marching step
    const int max_steps = int(max_range * inv / step);
    const int skip_steps = int(skip * inv / step);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 64)
    for (int64_t c = 0; c < W * H; ++c) {
        if (!occ[c]) continue;
        const double x0 = double(c % W) + 0.5, y0 = double(c / W) + 0.5;
        int n_open = 0;
        double free_sum = 0;
        for (int d = 0; d < num_directions; ++d) {
            const double a = 2.0 * M_PI * d / num_directions;
            const double dx = std::cos(a) * step, dy = std::sin(a) * step;
            int s = skip_steps;
            bool hit = false;
            for (; s < max_steps; ++s) {
                // floor, not truncation: a ray just past the low edge has left the grid (a
                // truncated -0.5 would still read cell 0 and make walls on that edge look closed)
                const int64_t cx = int64_t(std::floor(x0 + dx * s)), cy = int64_t(std::floor(y0 + dy * s));
                if (cx < 0 || cy < 0 || cx >= W || cy >= H) break;
                if (occ[cy * W + cx]) { hit = true; break; }
            }
            if (!hit) ++n_open;
            free_sum += hit ? s * step * cell_size : max_range;
        }
        open_frac[c] = float(n_open) / num_directions;
        free_mean[c] = float(free_sum / num_directions);
    }

    // 3x3 column neighbourhood
    std::vector<float> nlo(W * H), nhi(W * H), ncnt(W * H);
#pragma omp parallel for num_threads(nt) schedule(static)
    for (int64_t c = 0; c < W * H; ++c) {
        const int64_t cx = c % W, cy = c / W;
        float lo = 1e30f, hi = -1e30f;
        int64_t cnt = 0;
        for (int64_t yy = std::max<int64_t>(0, cy - 1); yy <= std::min(H - 1, cy + 1); ++yy)
            for (int64_t xx = std::max<int64_t>(0, cx - 1); xx <= std::min(W - 1, cx + 1); ++xx) {
                const int64_t u = yy * W + xx;
                cnt += count[u];
                lo = std::min(lo, zlo[u]);
                hi = std::max(hi, zhi[u]);
            }
        nlo[c] = lo; nhi[c] = hi; ncnt[c] = float(std::log1p(double(cnt)));
    }
#pragma omp parallel for num_threads(nt) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i) {
        const int32_t c = cell[i];
        if (c < 0) continue;
        out(i, 0) = open_frac[c];
        out(i, 1) = free_mean[c];
        const float z = points(i, 2);
        out(i, 2) = nlo[c] <= nhi[c] ? nlo[c] : z;
        out(i, 3) = nlo[c] <= nhi[c] ? nhi[c] : z;
        out(i, 4) = ncnt[c];
    }
    return out;
}

}  // namespace tripod
