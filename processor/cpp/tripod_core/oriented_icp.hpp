// SPDX-License-Identifier: BSD-3-Clause
// Point-to-plane ICP that pairs only surfaces seen from the same side (oriented normals).
#pragma once

#include <Eigen/Core>
#include <cstdint>

#include "tripod_core/registration.hpp"

namespace tripod {

/// Options of oriented_point_to_plane().
struct OrientedIcpOptions {
    double max_distance = 0.15;  ///< max correspondence distance [m]
    int iterations = 10;         ///< at most
    double point_sigma = 0.03;   ///< range noise [m]; Huber weights at 2 sigma
    double min_normal_dot = 0.5; ///< a pair whose normals (both facing their sensor) agree less
                                 ///< is no correspondence
    int64_t max_source = 40000;  ///< source points used at most (an even stride through them)
    int num_threads = 0;         ///< 0 = all
};

/// Result of oriented_point_to_plane().
struct OrientedIcpResult {
    Eigen::Matrix4d T_target_source = Eigen::Matrix4d::Identity();
    /// Huber-weighted Gauss-Newton matrix J^T W J of the last linearisation, order (δt, δω) of
    /// a left perturbation T <- exp(δ) T in the target frame (not scaled by any sigma)
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    double fitness = 0;   ///< share of the used source points with a correspondence
    double rmse = 0;      ///< RMS point-to-plane residual of the correspondences [m]
    int iterations = 0;
    bool linearized = false;  ///< at least one iteration had >= 100 correspondences
};

/// Refine T_target_source by point-to-plane Gauss-Newton (Huber weights) over the prepared
/// clouds' oriented normals: a source point pairs with its nearest target point only when
/// both normals agree (dot >= min_normal_dot after rotation). Points without a valid normal
/// take no part. Stops when an update moves < 1e-5 m and rotates < 1e-6 rad, or when fewer
/// than 100 pairs are left. Deterministic for a given thread count.
OrientedIcpResult oriented_point_to_plane(const PreparedCloud& source, const PreparedCloud& target,
                                          const Eigen::Matrix4d& T_init,
                                          const OrientedIcpOptions& opt);

}  // namespace tripod
