// SPDX-License-Identifier: BSD-3-Clause
// Internals shared by registration.cpp (the solver) and registration_linearize.cpp (the
// per-point hot loop).
#pragma once

#include <algorithm>
#include <cmath>
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
    double sq_res = 0;    ///< sum of squared unweighted residuals (plane family: n . e) [m^2]
};

/// Robust kernel: weight rho'(s) and cost rho(s) of a whitened squared residual s.
struct Kernel {
    Loss loss;
    double c2;  // squared scale, whitened
    void operator()(double s, double& w, double& rho) const {
        switch (loss) {
            case Loss::kNone:
                w = 1;
                rho = s;
                return;
            case Loss::kHuber:
                if (s <= c2) {
                    w = 1;
                    rho = s;
                } else {
                    const double r = std::sqrt(s), c = std::sqrt(c2);
                    w = c / r;
                    rho = 2 * c * r - c2;
                }
                return;
            case Loss::kCauchy:
                w = 1 / (1 + s / c2);
                rho = c2 * std::log1p(s / c2);
                return;
            case Loss::kTukey:
                if (s < c2) {
                    const double u = 1 - s / c2;
                    w = u * u;
                    rho = c2 / 3 * (1 - u * u * u);
                } else {
                    w = 0;
                    rho = c2 / 3;
                }
                return;
        }
    }
};

class GaussianVoxels;

/// What one linearisation pass works on: the clouds, the options, the residual model and the
/// active source rows (in the source tree's order, so that consecutive queries touch the same
/// part of the target tree; oriented: only rows with a normal; at most max_source of them).
struct Problem {
    const PreparedCloud& src;
    const PreparedCloud& tgt;
    const RegistrationOptions& opt;
    Method method;
    int num_threads;
    std::vector<int64_t> rows;              ///< active source rows
    const GaussianVoxels* voxels = nullptr;  ///< VGICP: the current stage's target voxels

    Problem(const PreparedCloud& s, const PreparedCloud& t, const RegistrationOptions& o,
            Method m, int nt);
};

/// Nearest target point of each active transformed source point within sqrt(max_sq_dist)
/// (-1: none; `corr` is indexed by source row, its previous content warm-starts the search).
void associate(const Problem& P, const Eigen::Isometry3d& T, double max_sq_dist,
               std::vector<int>& corr);

/// Linearise the residuals of P.method at T over the correspondences `corr` (left perturbation
/// (exp(w) R, t + v)); with `with_jacobian` false only the cost is summed. Adds no prior.
/// With `associate_sq_dist` > 0 the correspondences are found first, in the same pass
/// (one parallel region per iteration), and written to `corr`. GICP/VGICP: with `mahalanobis`,
/// a linearisation stores each pair's (C_q + R C_p R^T)^-1 there and a cost-only evaluation
/// reuses it (the LM acceptance test then compares costs under the same weights).
Normal linearize(const Problem& P, const Eigen::Isometry3d& T, std::vector<int>& corr,
                 bool with_jacobian, double associate_sq_dist = -1,
                 std::vector<Eigen::Matrix3d>* mahalanobis = nullptr);

/// linearize(P, T, corr, true, associate_sq_dist, mahalanobis) and, in the same pass (one
/// parallel region instead of two), the cost at T of the previous pairs `prev_corr` (GICP:
/// weighted by `prev_mahalanobis`), bit for bit what linearize(P, T, prev_corr, false, -1,
/// prev_mahalanobis).error gives, into `prev_error`. The previous pairs are the searches' hints.
/// `corr` and `mahalanobis` must not be `prev_corr` and `prev_mahalanobis`.
Normal linearize_fused(const Problem& P, const Eigen::Isometry3d& T,
                       const std::vector<int>& prev_corr,
                       const std::vector<Eigen::Matrix3d>* prev_mahalanobis, double& prev_error,
                       std::vector<int>& corr, double associate_sq_dist,
                       std::vector<Eigen::Matrix3d>* mahalanobis);

/// Fill fitness, RMSE, information and condition of `res` at its pose (`corr`: the last
/// matches, as hints for the final association, or empty). P.method: the residual model of the
/// information.
/// `last`: the linearisation at that pose with association at the last distance, when the
/// solver already has it (P.method's model, `corr` its pairs), else computed here.
void finish_result(const Problem& P, RegistrationResult& res, std::vector<int> corr = {},
                   const Normal* last = nullptr);

/// Convergence test of one stage. Steps are measured against the thresholds (s = max(rotation
/// / rotation_eps, translation / translation_eps)); a step below them (s < 1) is converged only
/// when the steps shrink fast enough that the rest of the way, extrapolated as a geometric
/// series s r / (1 - r) with r the ratio of the last two steps, is below them too. Point-to-
/// point ICP converges linearly (r near 1 on partial overlap): a plain small-step test stops
/// it degrees away from the minimum and calls that converged.
class StepTest {
public:
    explicit StepTest(const RegistrationOptions& opt) : opt_(opt) {}
    /// Accept T -> T_new (T := T_new) and tell whether the stage has converged.
    bool step(Eigen::Isometry3d& T, const Eigen::Isometry3d& T_new) {
        const double drot = Eigen::AngleAxisd(T_new.linear() * T.linear().transpose()).angle();
        const double dtr = (T_new.translation() - T.translation()).norm();
        T = T_new;
        const double s = std::max(drot / opt_.rotation_eps, dtr / opt_.translation_eps);
        const double prev = prev_;
        prev_ = s;
        if (!(s < 1)) return false;
        if (!(prev > 0)) return true;  // first step of the stage, or a step that was 0
        const double r = s / prev;
        return r < 1 && s * r / (1 - r) < 1;
    }

private:
    const RegistrationOptions& opt_;
    double prev_ = -1;
};

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
