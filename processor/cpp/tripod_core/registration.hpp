// SPDX-License-Identifier: BSD-3-Clause
// Local registration: point-to-point, point-to-plane (optionally over oriented normals), GICP,
// voxelised GICP, symmetric ICP and robust non-linear point-to-plane ICP ("lm"): one damped
// Gauss-Newton solver with OpenMP reductions behind one API.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "tripod_core/features.hpp"
#include "tripod_core/kdtree.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// A cloud prepared once for registration (as source or target, any number of times):
/// finite points, k-d tree, normals and covariances.
struct PreparedCloud {
    PointsXYZ points;                 ///< N x 3 finite points [m]
    MatrixX3d normals;                ///< N x 3 unit normals (zero where invalid)
    std::vector<Eigen::Matrix3d> covariances;  ///< N GICP covariances, plane-regularised [m^2]
    std::vector<uint8_t> normal_valid;          ///< N: 1 where the normal is defined
    std::unique_ptr<KdTree<3>> tree;  ///< over `points`
    int64_t num_dropped = 0;          ///< non-finite input rows dropped
    /// When > 0, every covariance is in the "plane" form prepare_cloud() builds:
    /// covariances[i] = cov_scale (I - cov_plane n_i n_i^T), n_i = normals row i (zero where
    /// invalid). GICP then inverts C_q + R C_p R^T in closed form (a rank-2 update of a
    /// multiple of I) instead of as a general 3x3. 0: general covariances.
    double cov_scale = 0;  ///< [m^2]
    double cov_plane = 0;  ///< in [0, 1)
};

/// Build a PreparedCloud: drop non-finite rows, build the tree, estimate normals (towards
/// `viewpoint`) and covariances. GICP covariances are regularised as in small_gicp's "plane"
/// mode, U diag(eps, 1, 1) U^T with eps = 1e-3, then scaled by point_sigma^2 / eps so that the
/// normal direction has std `point_sigma` [m] and the Mahalanobis cost is a chi-square.
std::shared_ptr<PreparedCloud> prepare_cloud(const PointsXYZ& points, const Neighborhood& nb,
                                             const Eigen::Vector3d& viewpoint, double point_sigma,
                                             int num_threads);

/// Residual model.
enum class Method {
    kPointToPoint,  ///< |q - T p|^2, closed-form SVD (Gauss-Newton when constrained)
    kPointToPlane,  ///< (n_q . (q - T p))^2
    kGICP,          ///< (q - T p)^T (C_q + R C_p R^T)^-1 (q - T p)
    kSymmetric,     ///< ((n_q + R n_p) . (q - T p))^2 (Rusinkiewicz 2019)
    kLM,       ///< point-to-plane, Levenberg-Marquardt to convergence on each set of
                    ///< correspondences (use a robust loss)
    kVGICP,         ///< GICP against Gaussian voxels of the target (voxel edge = the stage's
                    ///< correspondence distance; correspondence = the voxel a point falls in)
};

/// Robust kernel on the whitened residual (residual / point_sigma), scale `loss_scale` [m].
enum class Loss { kNone, kHuber, kCauchy, kTukey };

/// Options of register_local().
struct RegistrationOptions {
    Method method = Method::kGICP;
    /// Max correspondence distance per stage [m], coarse to fine (at least one).
    std::vector<double> max_correspondence_distances{1.0};
    int max_iterations = 64;         ///< per stage
    double rotation_eps = 1e-3;      ///< convergence: rotation update below this [rad] ...
    double translation_eps = 5e-4;   ///< ... and translation update below this [m]
    double point_sigma = 0.02;       ///< range noise assumed for the information matrix [m]
    Loss loss = Loss::kNone;
    double loss_scale = 0.1;         ///< robust kernel scale [m]
    bool has_rotation_prior = false;
    Eigen::Matrix3d R_prior = Eigen::Matrix3d::Identity();  ///< prior R_target_source
    double rotation_prior_sigma = 0; ///< [rad]; 0 = fixed to R_prior
    bool lock_z = false;             ///< keep t_z of the initial guess
    /// Point-to-plane family: normals of both clouds face their own sensor, so a pair counts
    /// only when n_source . n_target >= min_normal_cos as they are (a wall's two faces, seen
    /// from both rooms, never pair). Without it the source normal is flipped first (sign-free).
    /// Points without a valid normal then take no part.
    bool oriented = false;
    double min_normal_cos = 0.5;     ///< point-to-plane family: pairs less aligned are dropped
    int64_t max_source = 0;          ///< source points used at most (an even stride); 0 = all
    int64_t min_correspondences = 0; ///< fewer: "too_few_correspondences" (0: the method's minimum)
    int num_threads = 0;             ///< 0 = all
};

/// Result of register_local(). The one information convention of the registration core.
struct RegistrationResult {
    Eigen::Matrix4d T_target_source = Eigen::Matrix4d::Identity();
    bool converged = false;
    std::string status;       ///< "converged", "max_iterations", "degenerate", "too_few_correspondences"
    int iterations = 0;       ///< total over stages
    int64_t num_inliers = 0;  ///< source points with a target neighbour within the final distance
    double fitness = 0;       ///< num_inliers / source points
    double inlier_rmse = 0;   ///< RMS point distance of the inliers [m]
    /// RMS of the method's own unweighted residual over the pairs it used [m]: the point-to-
    /// plane distance for the plane family, the point distance otherwise
    double residual_rmse = 0;
    double final_error = 0;   ///< cost at the solution (chi-square)
    /// 6x6 information (inverse covariance) of the pose, order (rx, ry, rz, tx, ty, tz), for a
    /// perturbation T = (exp(w) R, t + v) in the target frame [1/rad^2, 1/m^2]; assumes
    /// `point_sigma`. Locked components get zero rows/columns.
    Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
    double condition = 0;  ///< smallest / largest eigenvalue of the surfaces' (point-to-plane) scaled information; < 1e-4: "degenerate"
};

/// Register `source` onto `target`: find T_target_source with target ~ T * source.
/// @throws std::invalid_argument on bad options or clouds too small for the method
RegistrationResult register_local(const PreparedCloud& source, const PreparedCloud& target,
                                  const Eigen::Matrix4d& T_init, const RegistrationOptions& opt);

}  // namespace tripod
