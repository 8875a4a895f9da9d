// SPDX-License-Identifier: BSD-3-Clause
// Per-point local shape (normal, covariance eigenvalues) from voxel moments, and the 2-D
// "column" context of a gravity-aligned indoor scan. Both are O(N) after one sort, so they keep
// up with inference at > 1 M points/s.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// Row-major N x C float matrix (per-point features).
using FeaturesF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Local shape of every point from the second moments of the points in the cube of
/// (2 radius_voxels + 1)^3 voxels around the point's voxel.
///
/// All points of one voxel share the result (that is what makes it fast: one 3x3 eigen
/// problem per occupied voxel, not per point).
/// @param points        N x 3 [m]; non-finite points get zeros
/// @param voxel_size    voxel edge [m], > 0
/// @param radius_voxels neighbourhood half-width in voxels, >= 0
/// @param num_threads   0 = all available
/// @return N x 7: normal (nx, ny, nz; unit, oriented nz >= 0, the eigenvector of the smallest
///         eigenvalue), eigenvalues l0 <= l1 <= l2 of the covariance [m^2], neighbour count
FeaturesF voxel_local_shape(const PointsXYZ& points, double voxel_size, int radius_voxels,
                            int num_threads = 0);

/// Points grouped by cubic voxel: the centroid of each occupied voxel, and each point's voxel.
/// Voxels are numbered in sorted key order (deterministic). Non-finite points get index -1.
/// @param points      N x 3 [m]
/// @param voxel_size  edge [m], > 0
/// @param centroids   out: M x 3 centroids [m]
/// @param point_voxel out: N voxel indices
/// @param counts      out: M point counts
void voxel_assign(const PointsXYZ& points, double voxel_size, PointsXYZ& centroids,
                  std::vector<int32_t>& point_voxel, std::vector<int32_t>& counts,
                  int num_threads = 0);

/// Settings of column_context.
struct ColumnContextOptions {
    double cell_size = 0.1;   ///< side of a grid cell [m]
    double z_low = 0.2;       ///< occupancy band: points between z_low and z_high [m]
    double z_high = 2.0;
    int num_directions = 16;  ///< horizontal rays per occupied cell
    double skip = 0.25;       ///< rays start this far from their cell [m]
    double max_range = 8.0;   ///< a ray that leaves this far without a hit is open [m]
    int num_threads = 0;      ///< 0 = all available
};

/// Context of every point in the horizontal plane of a z-up scan.
///
/// The x-y plane is cut into square cells; a cell is "occupied" when it holds points between
/// z_low and z_high (the band between floor and ceiling where walls and furniture live).
/// For every occupied cell, rays are cast in num_directions horizontal directions through the
/// occupancy grid, starting skip [m] away; a ray that leaves max_range [m] without meeting an
/// occupied cell is "open". Walls bound the scanned space, so about half of their rays are open;
/// furniture and pillars stand inside it, so few of theirs are.
/// Column heights come from the "upright" points only (e.g. |n_z| < 0.7), so that the ceiling
/// above a cabinet does not make the cabinet's front look as tall as a wall.
/// @param upright       N flags (non-zero: the point counts for column heights), or nullptr = all
/// @return N x 5: open fraction of the point's cell (0 outside the band), mean free distance of
///         its rays [m] (capped at max_range), column z-min and z-max of the upright points of
///         the 3x3 cells around the point's cell [m] (the point's own z when there are none),
///         number of points of that column neighbourhood (log1p)
FeaturesF column_context(const PointsXYZ& points, const uint8_t* upright,
                         const ColumnContextOptions& options);

}  // namespace tripod
