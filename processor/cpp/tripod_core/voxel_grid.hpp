// SPDX-License-Identifier: BSD-3-Clause
// Voxel-grid downsampling with the centroid of each voxel.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace tripod {

/// Row-major N x 3 float cloud (x, y, z) [m].
using PointsXYZ = Eigen::Matrix<float, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// Replace all points falling in one cubic voxel by their centroid.
///
/// Voxels are aligned to the origin: voxel index = floor(p / voxel_size). Non-finite points are
/// dropped. The output is ordered by voxel index (lexicographic in x, y, z), so the result is
/// deterministic whatever the thread count.
/// @param points      N x 3 input [m]
/// @param voxel_size  edge length [m], > 0
/// @param num_threads 0 = all available
/// @return M x 3 centroids, M <= N
PointsXYZ voxel_downsample(const PointsXYZ& points, double voxel_size, int num_threads = 0);

}  // namespace tripod
