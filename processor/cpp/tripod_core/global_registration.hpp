// SPDX-License-Identifier: BSD-3-Clause
// Global registration: FPFH correspondences + RANSAC, optionally constrained by gravity so that
// only yaw and translation are searched (a symmetric room cannot come out upside down).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "tripod_core/features.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// Options of register_global().
struct GlobalOptions {
    double normal_radius = 0.2;       ///< [m] (about 2 voxels)
    double feature_radius = 0.5;      ///< FPFH radius [m] (about 5 voxels)
    int max_neighbors = 100;          ///< cap per neighbourhood
    double inlier_distance = 0.15;    ///< RANSAC inlier threshold [m] (about 1.5 voxels)
    double edge_length_ratio = 0.9;   ///< pairwise-distance similarity check (Open3D's 0.9)
    bool mutual_filter = false;       ///< keep only mutual nearest features
    int64_t max_iterations = 100000;  ///< RANSAC hypotheses at most
    double confidence = 0.999;        ///< early stop when this confidence is reached
    /// Gravity: "up" unit vectors in the source and target frames (from the IMU); when both are
    /// set (non-zero) the rotation is searched about up only.
    Eigen::Vector3d up_source = Eigen::Vector3d::Zero();
    Eigen::Vector3d up_target = Eigen::Vector3d::Zero();
    /// Optional rotation prior (e.g. the IMU's relative orientation, yaw included): hypotheses
    /// whose rotation differs from R_prior by more than rotation_tolerance are rejected. It
    /// resolves what geometry cannot: the 180 deg twin of a symmetric room.
    bool has_rotation_prior = false;
    Eigen::Matrix3d R_prior = Eigen::Matrix3d::Identity();  ///< prior R_target_source
    double rotation_tolerance = 0.5;                         ///< [rad]
    Eigen::Vector3d viewpoint_source = Eigen::Vector3d::Zero();  ///< normals face it [m]
    Eigen::Vector3d viewpoint_target = Eigen::Vector3d::Zero();
    /// With gravity: the turns about up [rad] (e.g. pi for a rectangle's 180 deg twin) at
    /// which the best other hypothesis is reported too (GlobalResult::twins), each searched
    /// within twin_tolerance of the best hypothesis' yaw turned by it. Empty: none.
    std::vector<double> twin_turns;
    double twin_tolerance = 0.35;     ///< [rad] (20 deg)
    uint64_t seed = 0;                ///< same seed, same result, whatever num_threads
    int num_threads = 0;
};

/// A hypothesis at a turn of the best one about up (its twin in a symmetric room).
struct GlobalTwin {
    double turn = 0;  ///< the requested turn [rad]
    Eigen::Matrix4d T_target_source = Eigen::Matrix4d::Identity();
    int64_t num_inlier_correspondences = 0;
    int64_t geometric_score = 0;  ///< probe points (at most 2000) with a target point near
    double fitness = 0;
    double inlier_rmse = 0;       ///< [m]
};

/// Result of register_global().
struct GlobalResult {
    Eigen::Matrix4d T_target_source = Eigen::Matrix4d::Identity();
    bool success = false;  ///< a hypothesis agreeing with more matches than its own sample was found
    std::string status;            ///< "success", "no_correspondences", "no_consensus"
    int64_t num_correspondences = 0;        ///< feature matches
    int64_t num_inlier_correspondences = 0; ///< of the best hypothesis
    int64_t iterations = 0;        ///< hypotheses drawn
    double fitness = 0;            ///< source points with a target point within inlier_distance
    double inlier_rmse = 0;        ///< [m]
    int64_t geometric_score = 0;   ///< RANSAC's score of the pose (probe points near the target)
    /// With gravity and twin_turns: the best hypothesis at each turn that RANSAC drew (a turn
    /// without one is left out), refitted and scored like the pose.
    std::vector<GlobalTwin> twins;
};

/// Find T_target_source from scratch (no initial guess). Clouds should be voxel-downsampled.
/// @throws std::invalid_argument on bad options or fewer than 3 finite points
GlobalResult register_global(const PointsXYZ& source, const PointsXYZ& target,
                             const GlobalOptions& opt);

}  // namespace tripod
