// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/pose_graph.hpp"

#include <ceres/ceres.h>
#include <omp.h>

#include <cmath>
#include <functional>
#include <memory>
#include <stdexcept>

namespace tripod {

namespace {

// Relative-pose error between two nodes a (`from`) and b (`to`) with a measurement
// T̂_ab = (p̂_ab, q̂_ab), in the style of Ceres' examples/slam/pose_graph_3d.
//
// Each node is a position p and a unit quaternion q (Eigen order x, y, z, w in memory), as
// T_world_node. The relative pose the current estimate predicts is
//
//     p_ab = R(q_a)^T (p_b - p_a)          (b's origin in a's frame)
//     q_ab = q_a^{-1} q_b
//
// and the error, a 6-vector, compares it with the measurement:
//
//     e = [ p_ab - p̂_ab                  ]   translation error [m], in a's frame
//         [ 2 vec(q̂_ab^{-1} q_ab)        ]   rotation error [rad], small-angle, in b's frame
//
// For small errors 2 vec(δq) equals the rotation vector of δq, so e lives in the tangent space
// of SE(3) at the measurement. The residual is whitened with the square root of the edge's
// information Ω (upper Cholesky factor L^T with Ω = L L^T), so r^T r = e^T Ω e is the edge's
// chi-squared error with 6 degrees of freedom when the information is the true inverse
// covariance. The quaternions live on Ceres' EigenQuaternionManifold (3-dof updates), so no
// normalisation residual is needed.
struct RelativePoseError {
    RelativePoseError(const Pose3d& T_ab_measured, const Eigen::Matrix<double, 6, 6>& sqrt_info)
        : T_ab_measured_(T_ab_measured), sqrt_info_(sqrt_info) {}

    template <typename T>
    bool operator()(const T* const p_a_ptr, const T* const q_a_ptr, const T* const p_b_ptr,
                    const T* const q_b_ptr, T* residuals_ptr) const {
        Eigen::Map<const Eigen::Matrix<T, 3, 1>> p_a(p_a_ptr);
        Eigen::Map<const Eigen::Quaternion<T>> q_a(q_a_ptr);
        Eigen::Map<const Eigen::Matrix<T, 3, 1>> p_b(p_b_ptr);
        Eigen::Map<const Eigen::Quaternion<T>> q_b(q_b_ptr);

        const Eigen::Quaternion<T> q_a_inverse = q_a.conjugate();
        const Eigen::Quaternion<T> q_ab_estimated = q_a_inverse * q_b;
        const Eigen::Matrix<T, 3, 1> p_ab_estimated = q_a_inverse * (p_b - p_a);

        const Eigen::Quaternion<T> delta_q =
            T_ab_measured_.q.template cast<T>().conjugate() * q_ab_estimated;

        Eigen::Map<Eigen::Matrix<T, 6, 1>> residuals(residuals_ptr);
        residuals.template block<3, 1>(0, 0) = p_ab_estimated - T_ab_measured_.p.template cast<T>();
        residuals.template block<3, 1>(3, 0) = T(2.0) * delta_q.vec();
        residuals.applyOnTheLeft(sqrt_info_.template cast<T>());
        return true;
    }

    static ceres::CostFunction* Create(const Pose3d& T_ab_measured,
                                       const Eigen::Matrix<double, 6, 6>& sqrt_info) {
        return new ceres::AutoDiffCostFunction<RelativePoseError, 6, 3, 4, 3, 4>(
            new RelativePoseError(T_ab_measured, sqrt_info));
    }

    EIGEN_MAKE_ALIGNED_OPERATOR_NEW

   private:
    const Pose3d T_ab_measured_;
    const Eigen::Matrix<double, 6, 6> sqrt_info_;
};

// Gravity (tilt) prior on one node from the IMU's roll and pitch.
//
// The IMU measures the world's up axis ẑ = (0, 0, 1) in the node's frame as a unit vector û.
// With the node's attitude q (T_world_node), the estimate maps û back into the world:
//
//     e = R(q) û - ẑ                       3-vector, |e| = 2 sin(θ/2) for a tilt error θ
//
// which vanishes exactly when the estimated attitude agrees with the measured gravity, and is
// blind to rotation about ẑ (yaw), which the IMU without magnetometer does not observe. For
// small θ, |e| ≈ θ, so dividing by the tilt sigma [rad] whitens it; the component along ẑ is
// second order (1 - cos θ) and contributes nothing at the optimum, so the three residuals carry
// two degrees of freedom, as they should.
struct GravityError {
    GravityError(const Eigen::Vector3d& up_in_node, double sigma_rad)
        : up_in_node_(up_in_node.normalized()), inv_sigma_(1.0 / sigma_rad) {}

    template <typename T>
    bool operator()(const T* const q_ptr, T* residuals_ptr) const {
        Eigen::Map<const Eigen::Quaternion<T>> q(q_ptr);
        const Eigen::Matrix<T, 3, 1> up_world = q * up_in_node_.template cast<T>();
        Eigen::Map<Eigen::Matrix<T, 3, 1>> residuals(residuals_ptr);
        residuals = (up_world - Eigen::Matrix<T, 3, 1>(T(0), T(0), T(1))) * T(inv_sigma_);
        return true;
    }

    static ceres::CostFunction* Create(const Eigen::Vector3d& up_in_node, double sigma_rad) {
        return new ceres::AutoDiffCostFunction<GravityError, 3, 4>(
            new GravityError(up_in_node, sigma_rad));
    }

   private:
    const Eigen::Vector3d up_in_node_;
    const double inv_sigma_;
};

ceres::LossFunction* make_loss(const std::string& name, double scale) {
    if (name == "none" || name.empty()) return nullptr;
    if (!(scale > 0.0)) throw std::invalid_argument("loss_scale must be > 0");
    if (name == "huber") return new ceres::HuberLoss(scale);
    if (name == "cauchy") return new ceres::CauchyLoss(scale);
    if (name == "soft_l1") return new ceres::SoftLOneLoss(scale);
    throw std::invalid_argument("unknown loss '" + name + "' (none, huber, cauchy, soft_l1)");
}

Eigen::Matrix<double, 6, 6> sqrt_information(const Eigen::Matrix<double, 6, 6>& info) {
    const Eigen::Matrix<double, 6, 6> sym = 0.5 * (info + info.transpose());
    Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(sym);
    if (llt.info() == Eigen::Success) return llt.matrixL().transpose();
    // Semi-definite (e.g. a degenerate direction): symmetric square root via eigen-decomposition.
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(sym);
    const Eigen::Matrix<double, 6, 1> ev = es.eigenvalues().cwiseMax(0.0).cwiseSqrt();
    return es.eigenvectors() * ev.asDiagonal() * es.eigenvectors().transpose();
}

// Whether the nodes used by the inlier edges stay connected when edge `skip` is left out.
bool connected_without(int n, const std::vector<PoseGraphEdge>& edges,
                       const std::vector<unsigned char>& inlier, size_t skip) {
    std::vector<int> parent(n);
    for (int i = 0; i < n; ++i) parent[i] = i;
    std::function<int(int)> find = [&](int x) { return parent[x] == x ? x : parent[x] = find(parent[x]); };
    std::vector<bool> used(n, false);
    for (size_t k = 0; k < edges.size(); ++k) {
        if (!inlier[k]) continue;
        used[edges[k].from] = used[edges[k].to] = true;
        if (k == skip) continue;
        parent[find(edges[k].from)] = find(edges[k].to);
    }
    int root = -1;
    for (int i = 0; i < n; ++i) {
        if (!used[i]) continue;
        if (root < 0) root = find(i);
        else if (find(i) != root) return false;
    }
    return true;
}

bool finite_pose(const Pose3d& T) {
    return T.p.allFinite() && T.q.coeffs().allFinite() && T.q.norm() > 1e-9;
}

}  // namespace

double edge_chi2(const Pose3d& T_world_from, const Pose3d& T_world_to, const PoseGraphEdge& edge) {
    RelativePoseError term(edge.T_from_to, sqrt_information(edge.information));
    Eigen::Quaterniond qa = T_world_from.q.normalized(), qb = T_world_to.q.normalized();
    Eigen::Matrix<double, 6, 1> r;
    term(T_world_from.p.data(), qa.coeffs().data(), T_world_to.p.data(), qb.coeffs().data(),
         r.data());
    return r.squaredNorm();
}

PoseGraphResult optimize_pose_graph(const std::vector<Pose3d>& initial,
                                    const std::vector<PoseGraphEdge>& edges,
                                    const std::vector<GravityPrior>& gravity,
                                    const PoseGraphOptions& options) {
    const int n = static_cast<int>(initial.size());
    if (n == 0) throw std::invalid_argument("pose graph has no nodes");
    for (const auto& T : initial)
        if (!finite_pose(T)) throw std::invalid_argument("non-finite initial pose");
    for (const auto& e : edges) {
        if (e.from < 0 || e.from >= n || e.to < 0 || e.to >= n || e.from == e.to)
            throw std::invalid_argument("edge with a bad node index");
        if (!finite_pose(e.T_from_to) || !e.information.allFinite())
            throw std::invalid_argument("edge with a non-finite measurement or information");
    }
    for (const auto& g : gravity) {
        if (g.node < 0 || g.node >= n) throw std::invalid_argument("gravity prior with a bad node");
        if (!g.up_in_node.allFinite() || g.up_in_node.norm() < 1e-9 || !(g.sigma_rad > 0.0))
            throw std::invalid_argument("gravity prior with a bad direction or sigma");
    }
    if (options.fixed_node >= n) throw std::invalid_argument("fixed_node out of range");
    // validate the loss name once, before building anything
    delete make_loss(options.loss, options.loss_scale);

    PoseGraphResult result;
    result.poses = initial;
    for (auto& T : result.poses) T.q.normalize();
    result.edge_inlier.assign(edges.size(), 1);
    result.edge_chi2.assign(edges.size(), 0.0);

    std::vector<Eigen::Matrix<double, 6, 6>> sqrt_infos;
    sqrt_infos.reserve(edges.size());
    for (const auto& e : edges) sqrt_infos.push_back(sqrt_information(e.information));

    const int threads = options.num_threads > 0 ? options.num_threads : omp_get_max_threads();
    bool first = true;
    for (int round = 0; round <= options.max_rejection_rounds; ++round) {
        // 1. build the problem over the current inlier edges
        ceres::Problem problem;
        auto* manifold = new ceres::EigenQuaternionManifold;  // owned by the problem
        std::vector<bool> used(n, false);
        for (size_t k = 0; k < edges.size(); ++k) {
            if (!result.edge_inlier[k]) continue;
            const auto& e = edges[k];
            ceres::LossFunction* loss = (e.is_loop || options.robust_odometry)
                                            ? make_loss(options.loss, options.loss_scale)
                                            : nullptr;
            auto& a = result.poses[e.from];
            auto& b = result.poses[e.to];
            problem.AddResidualBlock(RelativePoseError::Create(e.T_from_to, sqrt_infos[k]), loss,
                                     a.p.data(), a.q.coeffs().data(), b.p.data(),
                                     b.q.coeffs().data());
            used[e.from] = used[e.to] = true;
        }
        for (const auto& g : gravity) {
            auto& T = result.poses[g.node];
            problem.AddResidualBlock(GravityError::Create(g.up_in_node, g.sigma_rad), nullptr,
                                     T.q.coeffs().data());
            if (!used[g.node]) problem.AddParameterBlock(T.p.data(), 3);
            used[g.node] = true;
        }
        for (int i = 0; i < n; ++i)
            if (used[i]) problem.SetManifold(result.poses[i].q.coeffs().data(), manifold);
        if (!used[0] && n > 0) {
            // keep the manifold owned even when node 0 is isolated
            problem.AddParameterBlock(result.poses[0].q.coeffs().data(), 4, manifold);
            problem.AddParameterBlock(result.poses[0].p.data(), 3);
        }
        // 2. gauge: hold one node constant (position and attitude)
        if (options.fixed_node >= 0 && problem.HasParameterBlock(result.poses[options.fixed_node].p.data())) {
            problem.SetParameterBlockConstant(result.poses[options.fixed_node].p.data());
            problem.SetParameterBlockConstant(result.poses[options.fixed_node].q.coeffs().data());
        }

        // 3. solve
        ceres::Solver::Options so;
        so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
        so.max_num_iterations = options.max_iterations;
        so.num_threads = threads;
        so.minimizer_progress_to_stdout = false;
        so.logging_type = ceres::SILENT;
        ceres::Solver::Summary summary;
        ceres::Solve(so, &problem, &summary);
        if (first) result.initial_cost = summary.initial_cost;
        first = false;
        result.final_cost = summary.final_cost;
        result.iterations += static_cast<int>(summary.iterations.size());
        result.converged = summary.termination_type == ceres::CONVERGENCE;
        result.message = summary.message;
        for (auto& T : result.poses) T.q.normalize();

        // 4. reject loop edges far outside their information; stop when none is
        for (size_t k = 0; k < edges.size(); ++k) {
            result.edge_chi2[k] =
                edge_chi2(result.poses[edges[k].from], result.poses[edges[k].to], edges[k]);
        }
        if (round == options.max_rejection_rounds) break;
        // reject only the worst offender per round: one bad loop can drag good ones over the
        // threshold, and they recover once it is gone
        int worst = -1;
        double worst_chi2 = options.outlier_chi2;
        for (size_t k = 0; k < edges.size(); ++k) {
            if (!result.edge_inlier[k] || result.edge_chi2[k] <= worst_chi2) continue;
            if (!edges[k].is_loop &&
                !(options.reject_odometry && connected_without(n, edges, result.edge_inlier, k)))
                continue;
            worst = static_cast<int>(k);
            worst_chi2 = result.edge_chi2[k];
        }
        if (worst < 0) break;
        result.edge_inlier[worst] = 0;
        ++result.rejected;
        result.poses = initial;  // re-solve from the start, free of the outlier's pull
        for (auto& T : result.poses) T.q.normalize();
    }
    return result;
}

}  // namespace tripod
