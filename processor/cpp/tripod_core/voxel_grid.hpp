// SPDX-License-Identifier: BSD-3-Clause
// Voxel-grid downsampling with the centroid of each voxel.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace tripod {

/// Row-major N x 3 float cloud (x, y, z) [m].
using PointsXYZ = Eigen::Matrix<float, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// Where the voxel lattice starts.
enum class VoxelAlign {
    kOrigin,    ///< voxel index = floor(p / size): the same lattice for every cloud (PCL-like)
    kMinBound,  ///< index = floor((p - (min_bound - size/2)) / size), exactly as Open3D does
};

/// Replace all points falling in one cubic voxel by their centroid.
///
/// Non-finite points are dropped. The output is ordered by voxel index (lexicographic in x, y, z),
/// so the result is deterministic whatever the thread count. Centroids are summed in double in
/// point order (as Open3D does), then rounded to float.
/// @param points      N x 3 input [m] (a PointsXYZ, or a Map of one: no copy)
/// @param voxel_size  edge length [m], > 0
/// @param num_threads 0 = all available
/// @param align       lattice alignment (see VoxelAlign)
/// @return M x 3 centroids, M <= N
/// @throws std::invalid_argument if voxel_size <= 0 or the cloud spans more than 2^21 voxels
PointsXYZ voxel_downsample(const Eigen::Ref<const PointsXYZ>& points, double voxel_size,
                           int num_threads = 0, VoxelAlign align = VoxelAlign::kOrigin);

}  // namespace tripod
