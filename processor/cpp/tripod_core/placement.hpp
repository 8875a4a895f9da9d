// SPDX-License-Identifier: BSD-3-Clause
// IMU placement of lidar points: slerp of the IMU orientation at each point's firing time, the
// lidar-IMU extrinsic with the head's lever arm, into the lidar frame at an anchor time.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// Orientation samples q_world_imu on the lidar time line, for slerp.
struct OrientationTrack {
    std::vector<int64_t> t_ns;                 ///< strictly increasing [ns]
    std::vector<Eigen::Quaterniond> q_world_imu;  ///< same length, unit (Hamilton)
};

/// Slerp of q_world_imu at t_ns (clamped to the track's ends).
Eigen::Quaterniond orientation_at(const OrientationTrack& track, int64_t t_ns);

/// Place points in the lidar frame at `anchor_ns` (de-skew with the head turning about a pivot):
///
///     x_out = R_wl(a)^T ( R_wi(t)(R_il x + l) - R_wi(a) l ),   R_wl(a) = R_wi(a) R_il
///
/// @param points       N x 3 in the lidar frame at each point's firing time [m]
/// @param t_ns         N firing times on the lidar time line [ns]
/// @param track        IMU orientation track
/// @param R_imu_lidar  mount rotation
/// @param lever_arm    pivot -> lidar origin in the IMU frame [m]
/// @param anchor_ns    time whose lidar frame the output is in [ns]
/// @param num_threads  0 = all available
/// @return N x 3 [m]
PointsXYZ place_points(const PointsXYZ& points, const std::vector<int64_t>& t_ns,
                       const OrientationTrack& track, const Eigen::Matrix3d& R_imu_lidar,
                       const Eigen::Vector3d& lever_arm, int64_t anchor_ns, int num_threads = 0);

}  // namespace tripod
