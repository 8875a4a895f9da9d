// SPDX-License-Identifier: BSD-3-Clause
// Non-linear ICP in Ceres: point-to-plane residuals under a robust loss, solved with
// Levenberg-Marquardt, correspondences re-found between solves.
#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <omp.h>

#include <algorithm>
#include <cmath>

#include "tripod_core/registration_internal.hpp"

namespace tripod::detail {

namespace {

// Point-to-plane residual, whitened by the range noise sigma.
//
//   r(q, t) = n^T (R(q) p + t - x) / sigma
//
// p: source point, x: its nearest target point, n: the target normal at x, R(q): the rotation
// of the unit quaternion q (Eigen order x, y, z, w, kept unit by EigenQuaternionManifold),
// t: translation [m]. The robust loss of the problem acts on r^2.
struct PointToPlaneError {
    PointToPlaneError(const Eigen::Vector3d& p, const Eigen::Vector3d& x, const Eigen::Vector3d& n,
                      double inv_sigma)
        : p_(p), x_(x), n_(n), inv_sigma_(inv_sigma) {}

    template <typename T>
    bool operator()(const T* q_ptr, const T* t_ptr, T* r) const {
        const Eigen::Map<const Eigen::Quaternion<T>> q(q_ptr);
        const Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(t_ptr);
        const Eigen::Matrix<T, 3, 1> y = q * p_.cast<T>() + t - x_.cast<T>();
        r[0] = n_.cast<T>().dot(y) * T(inv_sigma_);
        return true;
    }

    Eigen::Vector3d p_, x_, n_;
    double inv_sigma_;
};

// Rotation prior from the IMU, whitened by its angular sigma.
//
//   r(q) = 2 vec(q_prior^-1 q) / sigma_R   (~ the rotation vector of R_prior^T R for small angles)
//
// The sign of the error quaternion is chosen with w >= 0 so that r is the short way round.
struct RotationPriorError {
    RotationPriorError(const Eigen::Quaterniond& q_prior, double inv_sigma)
        : q_prior_inv_(q_prior.conjugate()), inv_sigma_(inv_sigma) {}

    template <typename T>
    bool operator()(const T* q_ptr, T* r) const {
        const Eigen::Map<const Eigen::Quaternion<T>> q(q_ptr);
        const Eigen::Quaternion<T> e = q_prior_inv_.cast<T>() * q;
        const T s = e.w() < T(0) ? T(-2.0 * inv_sigma_) : T(2.0 * inv_sigma_);
        r[0] = s * e.x();
        r[1] = s * e.y();
        r[2] = s * e.z();
        return true;
    }

    Eigen::Quaterniond q_prior_inv_;
    double inv_sigma_;
};

ceres::LossFunction* make_loss(const RegistrationOptions& opt) {
    const double c = opt.loss_scale / opt.point_sigma;  // whitened scale
    switch (opt.loss) {
        case Loss::kHuber: return new ceres::HuberLoss(c);
        case Loss::kCauchy: return new ceres::CauchyLoss(c);
        case Loss::kTukey: return new ceres::TukeyLoss(c);
        case Loss::kNone: return nullptr;
    }
    return nullptr;
}

}  // namespace

void register_ceres(const Problem& P, Eigen::Isometry3d& T, RegistrationResult& res) {
    const PreparedCloud& src = P.src;
    const PreparedCloud& tgt = P.tgt;
    const RegistrationOptions& opt = P.opt;
    const int64_t need = std::max<int64_t>(6, opt.min_correspondences);
    const bool fixed_rotation = opt.has_rotation_prior && !(opt.rotation_prior_sigma > 0);
    const double inv_sigma = 1.0 / opt.point_sigma;
    std::vector<int> corr;
    res.status = "max_iterations";
    bool ok = true;
    for (size_t stage = 0; stage < opt.max_correspondence_distances.size() && ok; ++stage) {
        const double d = opt.max_correspondence_distances[stage];
        bool stage_converged = false;
        StepTest test(opt);
        for (int it = 0; it < opt.max_iterations; ++it) {
            ++res.iterations;
            associate(P, T, d * d, corr);
            Eigen::Quaterniond q(T.linear());
            q.normalize();
            Eigen::Vector3d t = T.translation();
            ceres::Problem::Options popt;
            popt.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
            ceres::Problem problem(popt);
            std::unique_ptr<ceres::LossFunction> loss(make_loss(opt));
            int64_t m = 0;
            for (int64_t i : P.rows) {
                const int j = corr[i];
                if (j < 0 || !tgt.normal_valid[j]) continue;
                if (src.normal_valid[i]) {  // normal compatibility, as the Gauss-Newton methods
                    const Eigen::Vector3d ns = T.linear() * src.normals.row(i).transpose();
                    const double c = ns.dot(tgt.normals.row(j).transpose());
                    if (!((opt.oriented ? c : std::fabs(c)) >= opt.min_normal_cos)) continue;
                } else if (opt.oriented) {
                    continue;
                }
                auto* cost = new ceres::AutoDiffCostFunction<PointToPlaneError, 1, 4, 3>(
                    new PointToPlaneError(src.points.row(i).transpose().cast<double>(),
                                          tgt.points.row(j).transpose().cast<double>(),
                                          tgt.normals.row(j).transpose(), inv_sigma));
                problem.AddResidualBlock(cost, loss.get(), q.coeffs().data(), t.data());
                ++m;
            }
            if (m < need) {
                res.status = "too_few_correspondences";
                ok = false;
                break;
            }
            problem.SetManifold(q.coeffs().data(), new ceres::EigenQuaternionManifold);
            if (opt.lock_z) problem.SetManifold(t.data(), new ceres::SubsetManifold(3, {2}));
            if (fixed_rotation) {
                problem.SetParameterBlockConstant(q.coeffs().data());
            } else if (opt.has_rotation_prior) {
                problem.AddResidualBlock(
                    new ceres::AutoDiffCostFunction<RotationPriorError, 3, 4>(new RotationPriorError(
                        Eigen::Quaterniond(opt.R_prior), 1.0 / opt.rotation_prior_sigma)),
                    nullptr, q.coeffs().data());
            }
            ceres::Solver::Options sopt;
            sopt.linear_solver_type = ceres::DENSE_QR;
            sopt.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
            sopt.max_num_iterations = 10;
            sopt.num_threads = P.num_threads;
            sopt.logging_type = ceres::SILENT;
            sopt.minimizer_progress_to_stdout = false;
            ceres::Solver::Summary summary;
            ceres::Solve(sopt, &problem, &summary);
            Eigen::Isometry3d T_new = Eigen::Isometry3d::Identity();
            T_new.linear() = q.normalized().toRotationMatrix();
            T_new.translation() = t;
            if (test.step(T, T_new)) {
                stage_converged = true;
                break;
            }
        }
        if (ok && stage + 1 == opt.max_correspondence_distances.size())
            res.status = stage_converged ? "converged" : "max_iterations";
    }
    res.converged = res.status == "converged";
}

}  // namespace tripod::detail
