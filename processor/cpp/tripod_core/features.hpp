// SPDX-License-Identifier: BSD-3-Clause
// Per-point geometry: normals and covariances, outlier removal, MLS smoothing, normal-space
// sampling and FPFH descriptors. All multi-threaded with OpenMP; input clouds must be finite
// (see finite_rows()).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// Row-major N x 3 double matrix (normals, ...).
using MatrixX3d = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// Row-major N x 9 double matrix: one 3x3 covariance per row [m^2].
using MatrixX9d = Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor>;
/// Row-major N x 33 float FPFH descriptors.
using MatrixX33f = Eigen::Matrix<float, Eigen::Dynamic, 33, Eigen::RowMajor>;

/// Indices of the rows whose three coordinates are finite.
std::vector<int64_t> finite_rows(const PointsXYZ& points);

/// Neighbourhood for per-point estimates: k nearest (k_neighbors > 0) and/or a radius.
struct Neighborhood {
    int k_neighbors = 20;  ///< k nearest; with radius > 0 it caps the count
    double radius = 0.0;   ///< [m]; 0 = pure k-NN
};

/// Normals and covariances of each point from its neighbourhood.
struct LocalGeometry {
    MatrixX3d normals;      ///< N x 3 unit normals, oriented towards `viewpoint`
    MatrixX9d covariances;  ///< N x 9 row-major 3x3 sample covariances [m^2]
    Eigen::VectorXd curvature;  ///< N: lambda_min / (sum lambda) (0 = flat)
    std::vector<uint8_t> valid;  ///< N: 1 if the neighbourhood had >= 3 non-collinear points
    std::vector<Eigen::Matrix3d> frames;  ///< N eigenvector bases (ascending), if asked for
};

template <int Dim>
class KdTree;

/// Estimate normals and covariances (PCA of each neighbourhood).
/// @param points      N x 3 finite points [m]
/// @param nb          neighbourhood (k-NN or radius)
/// @param viewpoint   normals are flipped to face it (the sensor origin) [m]
/// @param num_threads 0 = all
LocalGeometry estimate_local_geometry(const PointsXYZ& points, const Neighborhood& nb,
                                      const Eigen::Vector3d& viewpoint, int num_threads);

/// Same, over an existing k-d tree of `points`; `keep_frames` fills LocalGeometry::frames.
LocalGeometry estimate_local_geometry(const PointsXYZ& points, const KdTree<3>& tree,
                                      const Neighborhood& nb, const Eigen::Vector3d& viewpoint,
                                      int num_threads, bool keep_frames = false);

/// Remove points whose mean distance to their k neighbours exceeds mean + std_ratio * std
/// over the cloud (PCL's StatisticalOutlierRemoval). @return indices of the kept rows.
std::vector<int64_t> statistical_outlier_removal(const PointsXYZ& points, int k_neighbors,
                                                 double std_ratio, int num_threads);

/// Moving-least-squares smoothing: each point is projected onto a weighted second-order
/// polynomial surface fitted to its neighbours within `radius` (Gaussian weights, sigma =
/// radius / 2). Points with fewer than 6 neighbours are left unchanged.
/// @param fit_voxel 0: one surface per point, fitted around it (exact MLS). > 0 [m]: one
///                  surface per voxel centroid of this size, each point projected onto the
///                  surface of its nearest centroid (the same neighbourhoods, far fewer fits;
///                  use a fraction of `radius`).
PointsXYZ mls_smooth(const PointsXYZ& points, double radius, int num_threads,
                     double fit_voxel = 0.0);

/// Normal-space sampling (Rusinkiewicz & Levoy 2001): bucket the normals on a sphere grid and
/// draw uniformly across buckets, so thin constraining structures survive subsampling.
/// @return up to `num_samples` row indices, deterministic for a given seed.
std::vector<int64_t> normal_space_sampling(const MatrixX3d& normals, int64_t num_samples,
                                           int bins_per_axis, uint64_t seed);

/// Fast Point Feature Histograms (Rusu 2009; binning as PCL's FPFHEstimation: 3 x 11 bins, each
/// third sums to 200: own SPFH + normalised neighbours'). Points with fewer than 2 neighbours within `radius` get zeros.
/// @param points  N x 3 finite points [m]; @param normals N x 3 unit normals
MatrixX33f compute_fpfh(const PointsXYZ& points, const MatrixX3d& normals, double radius,
                        int max_neighbors, int num_threads);

}  // namespace tripod
