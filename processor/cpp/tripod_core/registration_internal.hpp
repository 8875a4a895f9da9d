// SPDX-License-Identifier: BSD-3-Clause
// Internals shared by registration.cpp (Gauss-Newton methods) and registration_lm.cpp (Ceres).
#pragma once

#include <vector>

#include "tripod_core/registration.hpp"

namespace tripod::detail {

using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

/// Normal equations of one linearisation (or just the cost, for evaluate()).
struct Normal {
    Mat6 H = Mat6::Zero();
    Vec6 b = Vec6::Zero();
    double error = 0;     ///< robust chi-square cost
    int64_t count = 0;    ///< correspondences used
    double sq_dist = 0;   ///< sum of squared point distances of the correspondences [m^2]
};

/// Nearest target point of each transformed source point within sqrt(max_sq_dist) (-1: none).
void associate(const PreparedCloud& src, const PreparedCloud& tgt, const Eigen::Isometry3d& T,
               double max_sq_dist, std::vector<int>& corr, int num_threads);

/// Linearise the residuals of `method` at T over the correspondences `corr` (left perturbation
/// (exp(w) R, t + v)); with `with_jacobian` false only the cost is summed. Adds no prior.
/// With `associate_sq_dist` > 0 the correspondences are found first, in the same pass
/// (one parallel region per iteration), and written to `corr`. GICP only: with `mahalanobis`,
/// a linearisation stores each pair's (C_q + R C_p R^T)^-1 there and a cost-only evaluation
/// reuses it (the LM acceptance test then compares costs under the same weights).
Normal linearize(Method method, const PreparedCloud& src, const PreparedCloud& tgt,
                 const Eigen::Isometry3d& T, std::vector<int>& corr,
                 const RegistrationOptions& opt, bool with_jacobian, int num_threads,
                 double associate_sq_dist = -1,
                 std::vector<Eigen::Matrix3d>* mahalanobis = nullptr);

/// Fill fitness, RMSE, information and condition of `res` at its pose (`corr`: the last
/// matches, as hints for the final association, or empty).
void finish_result(const PreparedCloud& src, const PreparedCloud& tgt, Method residual_model,
                   const RegistrationOptions& opt, RegistrationResult& res, int num_threads,
                   std::vector<int> corr = {});

/// Non-linear ICP in Ceres (Method::kCeresLM); fills T, iterations, status.
void register_ceres(const PreparedCloud& src, const PreparedCloud& tgt, Eigen::Isometry3d& T,
                    const RegistrationOptions& opt, RegistrationResult& res, int num_threads);

/// Accept the step T -> T_new (T := T_new) and tell whether it was below both convergence
/// thresholds (rotation [rad], translation [m]).
inline bool step_and_check(Eigen::Isometry3d& T, const Eigen::Isometry3d& T_new,
                           const RegistrationOptions& opt) {
    const double drot = Eigen::AngleAxisd(T_new.linear() * T.linear().transpose()).angle();
    const double dtr = (T_new.translation() - T.translation()).norm();
    T = T_new;
    return drot < opt.rotation_eps && dtr < opt.translation_eps;
}

/// Eigen 3x3 skew-symmetric matrix [v]x.
inline Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
    Eigen::Matrix3d m;
    m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return m;
}

/// Rotation vector (axis * angle) of R [rad].
inline Eigen::Vector3d log_so3(const Eigen::Matrix3d& R) {
    const Eigen::AngleAxisd aa(R);
    return aa.angle() * aa.axis();
}

/// Rotation of a rotation vector [rad].
inline Eigen::Matrix3d exp_so3(const Eigen::Vector3d& w) {
    const double a = w.norm();
    if (a < 1e-12) return Eigen::Matrix3d::Identity() + skew(w);
    return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

}  // namespace tripod::detail
