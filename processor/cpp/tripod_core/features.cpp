// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/features.hpp"

#include <omp.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "tripod_core/kdtree.hpp"

namespace tripod {

namespace {
int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

/// Neighbours of row i by k-NN and/or radius (always includes i itself).
void neighbours(const KdTree<3>& tree, const float* q, const Neighborhood& nb, std::vector<int>& idx,
                std::vector<float>& dist) {
    if (nb.radius > 0) {
        tree.radius(q, static_cast<float>(nb.radius), idx, dist);
        if (nb.k_neighbors > 0 && static_cast<int>(idx.size()) > nb.k_neighbors) {
            // keep the k closest
            std::vector<int> order(idx.size());
            for (size_t j = 0; j < order.size(); ++j) order[j] = static_cast<int>(j);
            std::nth_element(order.begin(), order.begin() + nb.k_neighbors, order.end(),
                             [&](int a, int b) { return dist[a] < dist[b]; });
            std::vector<int> keep(nb.k_neighbors);
            for (int j = 0; j < nb.k_neighbors; ++j) keep[j] = idx[order[j]];
            idx.swap(keep);
        }
    } else {
        const int k = std::max(1, nb.k_neighbors);
        idx.resize(k);
        dist.resize(k);
        idx.resize(tree.knn(q, k, idx.data(), dist.data()));
    }
}
}  // namespace

std::vector<int64_t> finite_rows(const PointsXYZ& points) {
    std::vector<int64_t> rows;
    rows.reserve(points.rows());
    for (int64_t i = 0; i < points.rows(); ++i)
        if (points.row(i).allFinite()) rows.push_back(i);
    return rows;
}

LocalGeometry estimate_local_geometry(const PointsXYZ& points, const Neighborhood& nb,
                                      const Eigen::Vector3d& viewpoint, int num_threads) {
    const KdTree<3> tree(points.data(), points.rows(), 20, num_threads);
    return estimate_local_geometry(points, tree, nb, viewpoint, num_threads, false);
}

LocalGeometry estimate_local_geometry(const PointsXYZ& points, const KdTree<3>& tree,
                                      const Neighborhood& nb, const Eigen::Vector3d& viewpoint,
                                      int num_threads, bool keep_frames) {
    if (nb.k_neighbors <= 0 && nb.radius <= 0)
        throw std::invalid_argument("neighbourhood needs k_neighbors > 0 or radius > 0");
    const int64_t n = points.rows();
    LocalGeometry g;
    g.normals.setZero(n, 3);
    g.covariances.setZero(n, 9);
    g.curvature.setZero(n);
    g.valid.assign(n, 0);
    if (keep_frames) g.frames.assign(n, Eigen::Matrix3d::Identity());
    if (n == 0) return g;
    const std::vector<int64_t>& order = tree.order();
#pragma omp parallel num_threads(threads(num_threads))
    {
        std::vector<int> idx;
        std::vector<float> dist;
#pragma omp for schedule(dynamic, 256)
        for (int64_t k = 0; k < n; ++k) {
            const int64_t i = order[k];  // tree order: neighbouring queries share cache lines
            neighbours(tree, points.row(i).data(), nb, idx, dist);
            const int m = static_cast<int>(idx.size());
            if (m < 3) continue;
            // mean and scatter about the first point (numerically safe far from the origin)
            const Eigen::Vector3d o = points.row(i).transpose().cast<double>();
            Eigen::Vector3d mean = Eigen::Vector3d::Zero();
            Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
            for (int j = 0; j < m; ++j) {
                const Eigen::Vector3d p = points.row(idx[j]).transpose().cast<double>() - o;
                mean += p;
                sum.noalias() += p * p.transpose();
            }
            mean /= m;
            const Eigen::Matrix3d cov = sum / m - mean * mean.transpose();
            Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
            es.computeDirect(cov);
            const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);  // ascending
            if (!(ev[1] > 1e-12 * std::max(ev[2], 1e-30)) || !(ev[2] > 0)) continue;  // collinear
            Eigen::Vector3d normal = es.eigenvectors().col(0);
            if (normal.dot(viewpoint - o) < 0) normal = -normal;
            g.normals.row(i) = normal.transpose();
            Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(g.covariances.row(i).data()) =
                cov;
            g.curvature[i] = ev[0] / ev.sum();
            g.valid[i] = 1;
            if (keep_frames) g.frames[i] = es.eigenvectors();
        }
    }
    return g;
}

std::vector<int64_t> statistical_outlier_removal(const PointsXYZ& points, int k_neighbors,
                                                 double std_ratio, int num_threads) {
    if (k_neighbors < 1) throw std::invalid_argument("k_neighbors must be >= 1");
    const int64_t n = points.rows();
    std::vector<int64_t> kept;
    if (n == 0) return kept;
    const KdTree<3> tree(points.data(), n, 20, num_threads);
    std::vector<double> mean_dist(n, 0.0);
#pragma omp parallel num_threads(threads(num_threads))
    {
        std::vector<int> idx(k_neighbors + 1);
        std::vector<float> dist(k_neighbors + 1);
#pragma omp for schedule(static)
        for (int64_t i = 0; i < n; ++i) {
            const int m = tree.knn(points.row(i).data(), k_neighbors + 1, idx.data(), dist.data());
            double s = 0;
            int c = 0;
            for (int j = 0; j < m; ++j) {
                if (idx[j] == i) continue;  // skip the point itself
                s += std::sqrt(static_cast<double>(dist[j]));
                ++c;
            }
            mean_dist[i] = c ? s / c : 0.0;
        }
    }
    double mu = 0, var = 0;
    for (double d : mean_dist) mu += d;
    mu /= n;
    for (double d : mean_dist) var += (d - mu) * (d - mu);
    const double sd = n > 1 ? std::sqrt(var / (n - 1)) : 0.0;
    const double limit = mu + std_ratio * sd;
    for (int64_t i = 0; i < n; ++i)
        if (mean_dist[i] <= limit) kept.push_back(i);
    return kept;
}

namespace {
/// A local MLS surface: origin `o` on the weighted plane, in-plane axes `u`, `v`, normal `n`,
/// height h(x, y) = c0 + c1 x + c2 y + c3 x^2 + c4 xy + c5 y^2 along `n`.
struct MlsSurface {
    Eigen::Vector3d o, u, v, n;
    Eigen::Matrix<double, 6, 1> c = Eigen::Matrix<double, 6, 1>::Zero();
    bool ok = false;

    /// The point `p` projected onto the surface.
    Eigen::Vector3d project(const Eigen::Vector3d& p) const {
        const Eigen::Vector3d d = p - o;
        const double x = u.dot(d), y = v.dot(d);
        const double h = c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y;
        return o + x * u + y * v + h * n;
    }
};

/// Fit the MLS surface around `p` to the points of `tree` within `radius` (Gaussian weights,
/// sigma = radius / 2), its origin the projection of `p` on the weighted plane. Not ok with
/// fewer than 6 neighbours or a singular fit.
MlsSurface fit_mls(const PointsXYZ& points, const KdTree<3>& tree, const Eigen::Vector3d& p,
                   double radius, std::vector<int>& idx, std::vector<float>& dist,
                   std::vector<double>& w) {
    MlsSurface s;
    const float q[3] = {static_cast<float>(p[0]), static_cast<float>(p[1]),
                        static_cast<float>(p[2])};
    tree.radius(q, static_cast<float>(radius), idx, dist);
    const int m = static_cast<int>(idx.size());
    if (m < 6) return s;
    const double inv2s2 = 1.0 / (2.0 * (radius / 2) * (radius / 2));
    // 1. weighted plane (PCA) through the neighbourhood
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    double wsum = 0;
    w.resize(m);
    for (int j = 0; j < m; ++j) {
        w[j] = std::exp(-dist[j] * inv2s2);
        mean += w[j] * points.row(idx[j]).transpose().cast<double>();
        wsum += w[j];
    }
    mean /= wsum;
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (int j = 0; j < m; ++j) {
        const Eigen::Vector3d d = points.row(idx[j]).transpose().cast<double>() - mean;
        cov += w[j] * d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(cov);
    s.n = es.eigenvectors().col(0);
    s.u = es.eigenvectors().col(2);
    s.v = es.eigenvectors().col(1);
    // 2. weighted least-squares height in the plane's frame centred on p's projection
    s.o = p - s.n.dot(p - mean) * s.n;
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    for (int j = 0; j < m; ++j) {
        const Eigen::Vector3d d = points.row(idx[j]).transpose().cast<double>() - s.o;
        const double x = s.u.dot(d), y = s.v.dot(d), h = s.n.dot(d);
        Eigen::Matrix<double, 6, 1> f;
        f << 1, x, y, x * x, x * y, y * y;
        A.selfadjointView<Eigen::Lower>().rankUpdate(f, w[j]);
        b += w[j] * h * f;
    }
    Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(A.selfadjointView<Eigen::Lower>());
    if (ldlt.info() == Eigen::Success && ldlt.isPositive()) {
        const Eigen::Matrix<double, 6, 1> c = ldlt.solve(b);
        if (c.allFinite()) s.c = c;
    }
    s.ok = true;
    return s;
}
}  // namespace

PointsXYZ mls_smooth(const PointsXYZ& points, double radius, int num_threads,
                     double fit_voxel) {
    if (!(radius > 0)) throw std::invalid_argument("radius must be > 0");
    if (!(fit_voxel >= 0) || !std::isfinite(fit_voxel))
        throw std::invalid_argument("fit_voxel must be a finite number >= 0");
    const int64_t n = points.rows();
    PointsXYZ out = points;
    if (n == 0) return out;
    const KdTree<3> tree(points.data(), n, 20, num_threads);
    if (fit_voxel == 0) {
        // a surface per point, evaluated at the point's own projection
#pragma omp parallel num_threads(threads(num_threads))
        {
            std::vector<int> idx;
            std::vector<float> dist;
            std::vector<double> w;
#pragma omp for schedule(guided, 32)
            for (int64_t i = 0; i < n; ++i) {
                const Eigen::Vector3d p = points.row(i).transpose().cast<double>();
                const MlsSurface s = fit_mls(points, tree, p, radius, idx, dist, w);
                if (s.ok) out.row(i) = (s.o + s.c[0] * s.n).cast<float>().transpose();
            }
        }
        return out;
    }
    // a surface per voxel centroid of `fit_voxel`; each point projected onto its nearest one's
    const PointsXYZ anchors = voxel_downsample(points, fit_voxel, num_threads);
    const int64_t na = anchors.rows();
    std::vector<MlsSurface> surf(static_cast<size_t>(na));
#pragma omp parallel num_threads(threads(num_threads))
    {
        std::vector<int> idx;
        std::vector<float> dist;
        std::vector<double> w;
#pragma omp for schedule(guided, 32)
        for (int64_t a = 0; a < na; ++a)
            surf[a] = fit_mls(points, tree, anchors.row(a).transpose().cast<double>(), radius,
                              idx, dist, w);
    }
    const KdTree<3> anchor_tree(anchors.data(), na, 20, num_threads);
#pragma omp parallel for num_threads(threads(num_threads)) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        int j = -1;
        float d2 = 0;
        if (anchor_tree.knn(points.row(i).data(), 1, &j, &d2) < 1 || j < 0) continue;
        if (!surf[j].ok) continue;
        out.row(i) = surf[j].project(points.row(i).transpose().cast<double>()).cast<float>()
                         .transpose();
    }
    return out;
}

std::vector<int64_t> normal_space_sampling(const MatrixX3d& normals, int64_t num_samples,
                                           int bins_per_axis, uint64_t seed) {
    if (bins_per_axis < 1) throw std::invalid_argument("bins_per_axis must be >= 1");
    const int64_t n = normals.rows();
    std::vector<int64_t> out;
    if (n == 0 || num_samples <= 0) return out;
    if (num_samples >= n) {
        out.resize(n);
        for (int64_t i = 0; i < n; ++i) out[i] = i;
        return out;
    }
    // bucket each normal by its (x, y, z) components on a bins^3 grid over [-1, 1]^3
    const int b = bins_per_axis;
    std::vector<std::vector<int64_t>> buckets(static_cast<size_t>(b) * b * b);
    for (int64_t i = 0; i < n; ++i) {
        int key = 0;
        for (int d = 0; d < 3; ++d) {
            const double c = std::isfinite(normals(i, d)) ? normals(i, d) : 0.0;
            const int k = std::clamp(static_cast<int>((c + 1.0) * 0.5 * b), 0, b - 1);
            key = key * b + k;
        }
        buckets[key].push_back(i);
    }
    std::mt19937_64 rng(seed);
    std::vector<std::vector<int64_t>*> live;
    for (auto& bk : buckets)
        if (!bk.empty()) {
            std::shuffle(bk.begin(), bk.end(), rng);
            live.push_back(&bk);
        }
    // round-robin over the non-empty buckets, drawing without replacement
    std::vector<size_t> pos(live.size(), 0);
    while (static_cast<int64_t>(out.size()) < num_samples) {
        for (size_t j = 0; j < live.size() && static_cast<int64_t>(out.size()) < num_samples; ++j)
            if (pos[j] < live[j]->size()) out.push_back((*live[j])[pos[j]++]);
    }
    std::sort(out.begin(), out.end());
    return out;
}

MatrixX33f compute_fpfh(const PointsXYZ& points, const MatrixX3d& normals, double radius,
                        int max_neighbors, int num_threads) {
    if (!(radius > 0)) throw std::invalid_argument("feature radius must be > 0");
    if (normals.rows() != points.rows()) throw std::invalid_argument("one normal per point");
    const int64_t n = points.rows();
    constexpr int kBins = 11;
    MatrixX33f spfh = MatrixX33f::Zero(n, 33), fpfh = MatrixX33f::Zero(n, 33);
    if (n == 0) return fpfh;
    const KdTree<3> tree(points.data(), n, 20, num_threads);
    std::vector<std::vector<int>> nbrs(n);
    std::vector<std::vector<float>> nbr_dist(n);
    const int nt = threads(num_threads);
    // 1. simplified point feature histograms (pairs of the point with each neighbour)
#pragma omp parallel for num_threads(nt) schedule(guided, 32)
    for (int64_t i = 0; i < n; ++i) {
        tree.radius(points.row(i).data(), static_cast<float>(radius), nbrs[i], nbr_dist[i]);
        if (max_neighbors > 0 && static_cast<int>(nbrs[i].size()) > max_neighbors) {
            std::vector<int> order(nbrs[i].size());
            for (size_t j = 0; j < order.size(); ++j) order[j] = static_cast<int>(j);
            std::nth_element(order.begin(), order.begin() + max_neighbors, order.end(),
                             [&](int a, int b) { return nbr_dist[i][a] < nbr_dist[i][b]; });
            std::vector<int> ki(max_neighbors);
            std::vector<float> kd(max_neighbors);
            for (int j = 0; j < max_neighbors; ++j) {
                ki[j] = nbrs[i][order[j]];
                kd[j] = nbr_dist[i][order[j]];
            }
            nbrs[i].swap(ki);
            nbr_dist[i].swap(kd);
        }
        const int m = static_cast<int>(nbrs[i].size());
        if (m < 2) continue;
        const float incr = 100.f / static_cast<float>(m - 1);
        const Eigen::Vector3d p1 = points.row(i).transpose().cast<double>();
        const Eigen::Vector3d n1 = normals.row(i).transpose();
        for (int j : nbrs[i]) {
            if (j == i) continue;
            const Eigen::Vector3d p2 = points.row(j).transpose().cast<double>();
            const Eigen::Vector3d n2 = normals.row(j).transpose();
            // pair feature (PCL computePairFeatures): Darboux frame on the "source" point
            Eigen::Vector3d dp = p2 - p1;
            const double f4 = dp.norm();
            if (f4 == 0) continue;
            Eigen::Vector3d a = n1, b = n2;
            const double ang1 = n1.dot(dp) / f4, ang2 = n2.dot(dp) / f4;
            double f3;
            if (std::acos(std::fabs(ang1)) > std::acos(std::fabs(ang2))) {
                a = n2;
                b = n1;
                dp = -dp;
                f3 = -ang2;
            } else {
                f3 = ang1;
            }
            Eigen::Vector3d v = dp.cross(a);
            const double vn = v.norm();
            double f1 = 0, f2 = 0;
            if (vn > 0) {
                v /= vn;
                const Eigen::Vector3d w = a.cross(v);
                f2 = v.dot(b);
                f1 = std::atan2(w.dot(b), a.dot(b));
            } else {
                f3 = 0;
            }
            const int h1 = std::clamp(static_cast<int>(std::floor(kBins * ((f1 + M_PI) / (2 * M_PI)))), 0, kBins - 1);
            const int h2 = std::clamp(static_cast<int>(std::floor(kBins * ((f2 + 1.0) * 0.5))), 0, kBins - 1);
            const int h3 = std::clamp(static_cast<int>(std::floor(kBins * ((f3 + 1.0) * 0.5))), 0, kBins - 1);
            spfh(i, h1) += incr;
            spfh(i, kBins + h2) += incr;
            spfh(i, 2 * kBins + h3) += incr;
        }
    }
    // 2. FPFH = SPFH(p) + weighted SPFH of the neighbours (weight 1 / distance^2), each of the
    //    three sub-histograms of the weighted sum renormalised to 100
#pragma omp parallel for num_threads(nt) schedule(guided, 32)
    for (int64_t i = 0; i < n; ++i) {
        Eigen::Matrix<double, 33, 1> acc = Eigen::Matrix<double, 33, 1>::Zero();
        for (size_t jj = 0; jj < nbrs[i].size(); ++jj) {
            const int j = nbrs[i][jj];
            if (j == i || nbr_dist[i][jj] <= 0) continue;
            // 1 / squared distance, as PCL (its radiusSearch distances are squared) and Open3D
            const double w = 1.0 / static_cast<double>(nbr_dist[i][jj]);
            acc += w * spfh.row(j).transpose().cast<double>();
        }
        for (int s = 0; s < 3; ++s) {
            const double sum = acc.segment<kBins>(s * kBins).sum();
            if (sum > 0) acc.segment<kBins>(s * kBins) *= 100.0 / sum;
        }
        acc += spfh.row(i).transpose().cast<double>();
        fpfh.row(i) = acc.cast<float>().transpose();
    }
    return fpfh;
}

}  // namespace tripod
