// SPDX-License-Identifier: BSD-3-Clause
// Pose-graph optimisation (SLAM back end) in Ceres: relative-pose edges with 6x6 information,
// gravity priors from the IMU, a robust loss, gauge fixing and outlier-edge rejection.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace tripod {

/// A rigid pose: position p [m] and unit quaternion q (Hamilton). As T_world_node it maps a
/// point from the node's frame into the world: x_world = q * x_node + p.
struct Pose3d {
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
};

/// A relative-pose measurement between two nodes: T_from_to (the pose of node `to` in the frame
/// of node `from`), with its information matrix.
struct PoseGraphEdge {
    int from = 0;
    int to = 0;
    Pose3d T_from_to;
    /// 6x6 information, ordered (tx, ty, tz, rx, ry, rz): the translation error [m] in the
    /// frame of `from` first, then the rotation error as a small-angle vector [rad] in the frame
    /// of `to` (right perturbation). Must be symmetric positive semi-definite.
    Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Identity();
    /// Loop-closure edges may be rejected as outliers; odometry edges (false) never are.
    bool is_loop = false;
};

/// An absolute attitude measurement: the world's up axis (+z, against gravity) seen in the
/// node's frame, as the IMU gives it (roll and pitch; yaw is unobserved).
struct GravityPrior {
    int node = 0;
    Eigen::Vector3d up_in_node = Eigen::Vector3d::UnitZ();  ///< unit vector
    double sigma_rad = 0.01;                                 ///< 1-sigma tilt error [rad]
};

struct PoseGraphOptions {
    /// "none", "huber", "cauchy" or "soft_l1"; applied to loop edges (odometry edges use it
    /// too when robust_odometry is set). Residuals are whitened, so the scale is in sigmas.
    std::string loss = "cauchy";
    double loss_scale = 4.74;  // ~ sqrt(outlier_chi2): full weight inside the gate
    bool robust_odometry = false;
    int max_iterations = 200;
    int num_threads = 0;  ///< 0 = all available
    /// Node whose pose is held constant (gauge). -1 holds none (only valid with priors that fix
    /// every degree of freedom, which gravity alone does not).
    int fixed_node = 0;
    /// A loop edge whose whitened squared error (chi2, 6 dof) exceeds this after a solve is
    /// rejected and the graph solved again. 22.46 is the 99.9 % quantile of chi2(6).
    double outlier_chi2 = 22.46;
    int max_rejection_rounds = 5;
    /// Odometry edges may be rejected too, but only when the graph stays connected without
    /// them (a wrong odometry edge is outvoted by the loops around it).
    bool reject_odometry = false;
};

struct PoseGraphResult {
    std::vector<Pose3d> poses;           ///< optimised T_world_node, one per node
    std::vector<double> edge_chi2;       ///< whitened squared error of each edge after the solve
    std::vector<unsigned char> edge_inlier;  ///< 0 for rejected loop edges
    double initial_cost = 0.0;           ///< Ceres cost before the first solve
    double final_cost = 0.0;             ///< Ceres cost after the last solve
    int iterations = 0;                  ///< summed over all solves
    int rejected = 0;                    ///< number of rejected loop edges
    bool converged = false;
    std::string message;                 ///< Ceres' termination message of the last solve
};

/// Optimise T_world_node for every node given relative-pose edges and gravity priors.
///
/// @param initial  initial T_world_node of every node (e.g. chained odometry)
/// @param edges    relative measurements; node indices must be in [0, initial.size())
/// @param gravity  absolute tilt priors (may be empty)
/// @param options  loss, gauge, rejection and solver settings
/// @throws std::invalid_argument on an empty graph, bad indices or non-finite input
PoseGraphResult optimize_pose_graph(const std::vector<Pose3d>& initial,
                                    const std::vector<PoseGraphEdge>& edges,
                                    const std::vector<GravityPrior>& gravity,
                                    const PoseGraphOptions& options);

/// Whitened squared error r^T r (no robust loss) of one edge at the given node poses.
double edge_chi2(const Pose3d& T_world_from, const Pose3d& T_world_to, const PoseGraphEdge& edge);

}  // namespace tripod
