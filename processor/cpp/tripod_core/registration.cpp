// SPDX-License-Identifier: BSD-3-Clause
// Gauss-Newton ICP family. Every method minimises a sum of robust chi-squares over nearest-
// neighbour correspondences, re-associated at each iteration, with Marquardt damping accepted
// only when the cost (same correspondences) decreases, as small_gicp's LM optimiser does.
//
// Pose update (left, decoupled): R <- exp(w) R, t <- t + v, so that locking t_z is v_z = 0
// and an IMU rotation prior acts on w directly. For a residual e = q - (R p + t):
//   d e / d w = [R p]x ,   d e / d v = -I.
#include "tripod_core/registration.hpp"

#include <omp.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>

#include "tripod_core/parallel_chunks.hpp"
#include "tripod_core/phase_timer.hpp"
#include "tripod_core/registration_internal.hpp"
#include "tripod_core/registration_voxels.hpp"

namespace tripod {

using detail::Mat6;
using detail::Normal;
using detail::Vec6;
using detail::Kernel;
using detail::Problem;
using detail::skew;

namespace {
/// Locked components of (wx, wy, wz, vx, vy, vz).
std::array<bool, 6> locked(const RegistrationOptions& opt) {
    std::array<bool, 6> l{};
    if (opt.has_rotation_prior && !(opt.rotation_prior_sigma > 0)) l[0] = l[1] = l[2] = true;
    if (opt.lock_z) l[5] = true;
    return l;
}

/// Cost of the rotation prior and its contribution to H, b.
double add_prior(const RegistrationOptions& opt, const Eigen::Matrix3d& R, Mat6* H, Vec6* b) {
    if (!opt.has_rotation_prior || !(opt.rotation_prior_sigma > 0)) return 0;
    const double inv_s2 = 1.0 / (opt.rotation_prior_sigma * opt.rotation_prior_sigma);
    const Eigen::Vector3d r = detail::log_so3(R * opt.R_prior.transpose());
    if (H) H->topLeftCorner<3, 3>() += inv_s2 * Eigen::Matrix3d::Identity();
    if (b) b->head<3>() += inv_s2 * r;
    return inv_s2 * r.squaredNorm();
}

Eigen::Isometry3d apply(const Eigen::Isometry3d& T, const Vec6& d) {
    Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
    out.linear() = detail::exp_so3(d.head<3>()) * T.linear();
    // re-orthonormalise to keep R in SO(3) over many small updates
    const Eigen::Quaterniond q(out.linear());
    out.linear() = q.normalized().toRotationMatrix();
    out.translation() = T.translation() + d.tail<3>();
    return out;
}

int min_points(Method m) { return m == Method::kPointToPoint ? 3 : 6; }

void validate(const PreparedCloud& src, const PreparedCloud& tgt, const Eigen::Matrix4d& T,
              const RegistrationOptions& opt) {
    const int need = min_points(opt.method);
    if (src.points.rows() < need)
        throw std::invalid_argument("source has " + std::to_string(src.points.rows()) +
                                    " finite points; the method needs at least " +
                                    std::to_string(need));
    if (tgt.points.rows() < need)
        throw std::invalid_argument("target has " + std::to_string(tgt.points.rows()) +
                                    " finite points; the method needs at least " +
                                    std::to_string(need));
    if (opt.max_correspondence_distances.empty())
        throw std::invalid_argument("max_correspondence_distances must not be empty");
    for (double d : opt.max_correspondence_distances)
        if (!(d > 0) || !std::isfinite(d))
            throw std::invalid_argument("max_correspondence_distance must be finite and > 0");
    if (opt.max_iterations < 1) throw std::invalid_argument("max_iterations must be >= 1");
    if (!(opt.point_sigma > 0)) throw std::invalid_argument("point_sigma must be > 0");
    if (opt.loss != Loss::kNone && !(opt.loss_scale > 0))
        throw std::invalid_argument("loss_scale must be > 0");
    if (!T.allFinite()) throw std::invalid_argument("initial guess is not finite");
    const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-4 || R.determinant() < 0 ||
        (T.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).norm() > 1e-9)
        throw std::invalid_argument("initial guess is not a rigid transform");
    if (opt.has_rotation_prior) {
        const Eigen::Matrix3d& P = opt.R_prior;
        if (!P.allFinite() || (P.transpose() * P - Eigen::Matrix3d::Identity()).norm() > 1e-4 ||
            P.determinant() < 0)
            throw std::invalid_argument("rotation prior is not a rotation matrix");
        if (opt.rotation_prior_sigma < 0)
            throw std::invalid_argument("rotation_prior_sigma must be >= 0 (0 = fixed)");
    }
    if (opt.max_source < 0) throw std::invalid_argument("max_source must be >= 0 (0 = all)");
    if (opt.min_correspondences < 0)
        throw std::invalid_argument("min_correspondences must be >= 0");
    if (!(opt.min_normal_cos >= -1 && opt.min_normal_cos <= 1))
        throw std::invalid_argument("min_normal_cos must be in [-1, 1]");
    const bool needs_normals = opt.method == Method::kPointToPlane ||
                               opt.method == Method::kSymmetric || opt.method == Method::kLM;
    if (needs_normals) {
        int64_t ok = 0;
        for (uint8_t v : tgt.normal_valid) ok += v;
        if (ok < need)
            throw std::invalid_argument(
                "target has no surface normals (too few neighbours or all points collinear)");
    }
}

/// Point-to-point step in closed form (weighted Kabsch / Umeyama without scale).
Eigen::Isometry3d kabsch(const PreparedCloud& src, const PreparedCloud& tgt,
                         const Eigen::Isometry3d& T, const std::vector<int>& corr,
                         const Kernel& kernel, double inv_s2) {
    // corr is -1 for every source row outside the problem's active rows
    double wsum = 0;
    Eigen::Vector3d mp = Eigen::Vector3d::Zero(), mq = Eigen::Vector3d::Zero();
    std::vector<double> w(corr.size(), 0.0);
    for (size_t i = 0; i < corr.size(); ++i) {
        if (corr[i] < 0) continue;
        const Eigen::Vector3d p = T * src.points.row(i).transpose().cast<double>();
        const Eigen::Vector3d q = tgt.points.row(corr[i]).transpose().cast<double>();
        double rho = 0;
        kernel((q - p).squaredNorm() * inv_s2, w[i], rho);
        wsum += w[i];
        mp += w[i] * p;
        mq += w[i] * q;
    }
    if (!(wsum > 0)) return T;
    mp /= wsum;
    mq /= wsum;
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < corr.size(); ++i) {
        if (corr[i] < 0 || w[i] == 0) continue;
        const Eigen::Vector3d p = T * src.points.row(i).transpose().cast<double>();
        const Eigen::Vector3d q = tgt.points.row(corr[i]).transpose().cast<double>();
        S += w[i] * (q - mq) * (p - mp).transpose();
    }
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;
    Eigen::Isometry3d dT = Eigen::Isometry3d::Identity();
    dT.linear() = svd.matrixU() * D * svd.matrixV().transpose();
    dT.translation() = mq - dT.linear() * mp;
    return dT * T;
}
/// Smallest / largest eigenvalue of the free block of H, rotations scaled by the RMS extent of
/// the source about its centroid (so that both are in metres).
double condition_number(const PreparedCloud& src, const Mat6& H, const std::array<bool, 6>& lock) {
    double extent = 0;
    const Eigen::Vector3d c = src.points.cast<double>().colwise().mean().transpose();
    for (int64_t i = 0; i < src.points.rows(); ++i)
        extent += (src.points.row(i).transpose().cast<double>() - c).squaredNorm();
    extent = std::sqrt(extent / std::max<int64_t>(1, src.points.rows()));
    std::vector<int> freeidx;
    for (int k = 0; k < 6; ++k)
        if (!lock[k]) freeidx.push_back(k);
    if (freeidx.empty()) return 1;
    Eigen::MatrixXd Hs(freeidx.size(), freeidx.size());
    for (size_t a = 0; a < freeidx.size(); ++a)
        for (size_t b = 0; b < freeidx.size(); ++b) {
            const double sa = freeidx[a] < 3 ? 1.0 / std::max(extent, 1e-9) : 1.0;
            const double sb = freeidx[b] < 3 ? 1.0 / std::max(extent, 1e-9) : 1.0;
            Hs(a, b) = H(freeidx[a], freeidx[b]) * sa * sb;
        }
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Hs, Eigen::EigenvaluesOnly);
    const double hi = es.eigenvalues().maxCoeff(), lo = es.eigenvalues().minCoeff();
    return hi > 0 ? std::max(lo, 0.0) / hi : 0;
}

/// lm: Levenberg-Marquardt iterations per set of correspondences at most (Ceres' 10 before).
constexpr int kLmInner = 10;

/// The next iteration's linearisation, made in the same pass as a step's acceptance test
/// (linearize_fused: one parallel region per iteration instead of two). The buffers are the
/// solver's spares, swapped with its pairs and weights when the step is accepted.
struct Ahead {
    double sq_dist = 0;  ///< the stage's association distance^2 [m^2]
    std::vector<int> corr;
    std::vector<Eigen::Matrix3d> mahalanobis;
    Normal next;        ///< at the accepted pose, with its new pairs (now the solver's)
    bool have = false;  ///< `next` is that of the last accepted step
};

/// One damped Gauss-Newton step from T on the normal equations `nl` (prior and locks added
/// here): Marquardt damping, accepted only when the cost (same pairs) decreases, as small_gicp's
/// LM optimiser does; T itself when no damping up to 1e6 decreases it. With `ahead`, the first
/// try also linearises at its pose (pairs found anew): if it is accepted, that is the next
/// iteration's (ahead->have); a rejected try wastes it (rare: the later tries only evaluate).
Eigen::Isometry3d damped_step(const Problem& P, const Eigen::Isometry3d& T, Normal nl,
                              std::vector<int>& corr, std::vector<Eigen::Matrix3d>& mahalanobis,
                              double& lambda, Ahead* ahead = nullptr) {
    if (ahead) ahead->have = false;
    const RegistrationOptions& opt = P.opt;
    const double err = nl.error + add_prior(opt, T.linear(), &nl.H, &nl.b);
    const auto lock = locked(opt);
    for (int k = 0; k < 6; ++k)
        if (lock[k]) {
            nl.H.row(k).setZero();
            nl.H.col(k).setZero();
            nl.H(k, k) = 1;
            nl.b[k] = 0;
        }
    for (int inner = 0; inner < 10; ++inner) {
        Mat6 Hd = nl.H;
        // Marquardt scaling, plus a floor so that directions the geometry does not constrain
        // (a plane, a corridor) stay put instead of drifting
        Hd.diagonal() += lambda * nl.H.diagonal() +
                         Vec6::Constant(1e-9 * nl.H.diagonal().maxCoeff() + 1e-12);
        const Vec6 delta = Hd.ldlt().solve(-nl.b);
        if (!delta.allFinite()) {
            lambda *= 10;
            continue;
        }
        const Eigen::Isometry3d cand = apply(T, delta);
        double e_pairs = 0;
        const bool fused = ahead && inner == 0;
        Normal next;
        if (fused)
            next = detail::linearize_fused(P, cand, corr, &mahalanobis, e_pairs, ahead->corr,
                                           ahead->sq_dist, &ahead->mahalanobis);
        else
            e_pairs = detail::linearize(P, cand, corr, false, -1, &mahalanobis).error;
        const double e_new = e_pairs + add_prior(opt, cand.linear(), nullptr, nullptr);
        if (e_new <= err) {
            lambda = std::max(lambda / 10, 1e-10);
            if (fused) {
                corr.swap(ahead->corr);
                mahalanobis.swap(ahead->mahalanobis);
                ahead->next = next;
                ahead->have = true;
            }
            return cand;
        }
        lambda *= 10;
    }
    return T;
}

/// Iterate one stage (correspondence distance d) from T. Returns false when too few pairs
/// were left; `converged` tells whether the stage's step test passed. `last` (if given) gets
/// the linearisation at the final T with association at d when the last step made it (then
/// `corr` holds its pairs), else is left empty.
bool run_stage(Problem& P, double d, Eigen::Isometry3d& T, std::vector<int>& corr,
               RegistrationResult& res, bool& converged, std::optional<Normal>* last = nullptr) {
    const RegistrationOptions& opt = P.opt;
    const bool closed_form = opt.method == Method::kPointToPoint && !opt.has_rotation_prior &&
                             !opt.lock_z;
    const int64_t need = std::max<int64_t>(min_points(opt.method), opt.min_correspondences);
    const double inv_s2 = 1.0 / (opt.point_sigma * opt.point_sigma);
    const Kernel kernel{opt.loss, std::pow(opt.loss_scale / opt.point_sigma, 2)};
    // VGICP: the target's Gaussian voxels at this stage's scale
    std::unique_ptr<detail::GaussianVoxels> voxels;
    if (opt.method == Method::kVGICP) {
        voxels = std::make_unique<detail::GaussianVoxels>(P.tgt, d);
        P.voxels = voxels.get();
        corr.clear();  // voxel indices of another stage are no hints
    }
    std::vector<Eigen::Matrix3d> mahalanobis;  // GICP weights of the current pairs
    double lambda = 1e-4;
    // one damped step per association: its acceptance test and the next linearisation in one
    // pass (lm solves each association's problem with cost-only tests: not fused)
    const bool fuse = !closed_form && opt.method != Method::kLM;
    Ahead ahead;
    ahead.sq_dist = d * d;
    detail::StepTest test(opt);
    converged = false;
    for (int it = 0; it < opt.max_iterations; ++it) {
        ++res.iterations;
        Eigen::Isometry3d T_new;
        if (closed_form) {
            detail::associate(P, T, d * d, corr);
            int64_t m = 0;
            for (int c : corr) m += c >= 0;
            if (m < need) return false;
            T_new = kabsch(P.src, P.tgt, T, corr, kernel, inv_s2);
        } else {
            Normal nl = ahead.have ? ahead.next
                                   : detail::linearize(P, T, corr, true, d * d, &mahalanobis);
            ahead.have = false;
            if (nl.count < need) return false;
            T_new = damped_step(P, T, std::move(nl), corr, mahalanobis, lambda,
                                fuse ? &ahead : nullptr);
            // lm: the non-linear problem of these pairs solved to convergence before the
            // next association (one damped step per association for the others)
            for (int inner = 1; opt.method == Method::kLM && inner < kLmInner; ++inner) {
                Eigen::Isometry3d T_prev = T_new;
                T_new = damped_step(P, T_prev, detail::linearize(P, T_prev, corr, true), corr,
                                    mahalanobis, lambda);
                detail::StepTest inner_test(opt);
                if (inner_test.step(T_prev, T_new)) break;
            }
        }
        if (test.step(T, T_new)) {
            converged = true;
            break;
        }
    }
    if (last && ahead.have) *last = ahead.next;
    P.voxels = nullptr;
    if (opt.method == Method::kVGICP) corr.clear();
    return true;
}

}  // namespace

namespace detail {

void finish_result(const Problem& P, RegistrationResult& res, std::vector<int> corr,
                   const Normal* last) {
    const PreparedCloud& src = P.src;
    const PreparedCloud& tgt = P.tgt;
    const RegistrationOptions& opt = P.opt;
    const Eigen::Isometry3d T(res.T_target_source);
    const double d = opt.max_correspondence_distances.back();
    Normal nl = last ? *last : linearize(P, T, corr, true, d * d);
    res.final_error = nl.error + add_prior(opt, T.linear(), &nl.H, &nl.b);
    res.residual_rmse = nl.count ? std::sqrt(nl.sq_res / nl.count) : 0;
    // Fitness and RMSE as Open3D defines them (all correspondences within the distance), over
    // the source points taking part.
    int64_t inl = 0;
    double sq = 0;
    for (int64_t i : P.rows) {
        if (corr[i] < 0) continue;
        const Eigen::Vector3d e = tgt.points.row(corr[i]).transpose().cast<double>() -
                                  T * src.points.row(i).transpose().cast<double>();
        sq += e.squaredNorm();
        ++inl;
    }
    res.num_inliers = inl;
    res.fitness = P.rows.empty() ? 0 : static_cast<double>(inl) / P.rows.size();
    res.inlier_rmse = inl ? std::sqrt(sq / inl) : 0;
    // Information in the right-perturbation tangent T exp(xi), xi = (w, v) in the source frame:
    // the left update (w_L, v_L) = (R w, R v) to first order, so H_R = A^T H_L A.
    const auto lock = locked(opt);
    for (int k = 0; k < 6; ++k)
        if (lock[k]) {
            nl.H.row(k).setZero();
            nl.H.col(k).setZero();
        }
    Mat6 A = Mat6::Zero();
    A.topLeftCorner<3, 3>() = T.linear();
    A.bottomRightCorner<3, 3>() = T.linear();
    res.information = A.transpose() * nl.H * A;
    res.information = 0.5 * (res.information + res.information.transpose()).eval();
    // Conditioning of the free components, rotations scaled by the source's extent to metres.
    // Judged on the surfaces (point-to-plane information) whatever the method: point-to-point
    // and GICP also "see" in-plane sample positions, which do not constrain a real surface.
    TRIPOD_PHASE("finish: plane info+condition");
    Problem plane(src, tgt, opt, Method::kPointToPlane, P.num_threads);
    Normal geo = linearize(plane, T, corr, true);
    if (geo.count > 0) nl.H = geo.H;
    res.condition = condition_number(src, nl.H, lock);
}

}  // namespace detail

namespace {
/// Normals and plane-regularised GICP covariances of every point from its k nearest
/// neighbours (PCA), fused: one k-NN per group of nearby points (KdTree::knn_range), the 3x3
/// scatter and its eigenvectors, and the covariance written straight away; nothing allocated
/// per point. Each point's result depends only on the tree, so it is the same bit for bit on
/// any number of threads.
void estimate_gicp_geometry(PreparedCloud& pc, int k, const Eigen::Vector3d& viewpoint,
                            double point_sigma, int num_threads) {
    const KdTree<3>& tree = *pc.tree;
    const int64_t n = pc.points.rows();
    pc.normals.setZero(n, 3);
    pc.normal_valid.assign(n, 0);
    pc.covariances.resize(n);
    constexpr double kEps = 1e-3;
    const double s2 = point_sigma * point_sigma / kEps;
    // U diag(eps, 1, 1) U^T s2 = s2 (I - (1 - eps) n n^T): only the normal is needed
    const Eigen::Matrix3d iso = s2 * Eigen::Matrix3d::Identity();
    const std::vector<int> groups = tree.groups(32);
    const int64_t num_groups = static_cast<int64_t>(groups.size()) - 1;
    // Chunks of kGroupsPerChunk groups, each thread taking its own contiguous share of the
    // tree's positions first (parallel_chunks): the rows a thread writes are then mostly those
    // of its own half of the tree, not interleaved with the other's at fine grain (cache lines
    // of the outputs written from two cores cost more than the work).
    constexpr int64_t kGroupsPerChunk = 4;
    const int64_t num_chunks = (num_groups + kGroupsPerChunk - 1) / kGroupsPerChunk;
    const int nt = detail::resolve_threads(num_threads);
    std::vector<KdTree<3>::KnnScratch> scratches(std::clamp(nt, 1, 64));
    // each point's nearest others, by tree position, from the same k-NN (KdTree::set_hints:
    // warm-started correspondence searches mostly skip the tree)
    constexpr int kList = KdTree<3>::kHintList;
    std::vector<int> hint_list(static_cast<size_t>(n) * kList, -1);
    std::vector<float> hint_reach(n, 0.f), hint_first(n, 0.f);  // 0: no shortcut
    auto body = [&](int64_t chunk, int t) {
        KdTree<3>::KnnScratch& scratch = scratches[t];
        for (int64_t g = chunk * kGroupsPerChunk,
                     g_end = std::min(num_groups, (chunk + 1) * kGroupsPerChunk);
             g < g_end; ++g) {
            tree.knn_range(k, groups[g], groups[g + 1], scratch,
                           [&](int64_t pos, const int* nbr, const float* sq_dist, int m) {
                {
                    // the kList nearest others, ascending (insertion into a short sorted list;
                    // ties keep the k-NN's order, itself deterministic)
                    float ld[kList];
                    int lp[kList];
                    int take = 0, others = 0;
                    for (int j = 0; j < m; ++j) {
                        if (nbr[j] == pos) continue;
                        ++others;
                        const float dj = sq_dist[j];
                        if (take == kList && !(dj < ld[kList - 1])) continue;
                        int at = take < kList ? take++ : kList - 1;
                        while (at > 0 && dj < ld[at - 1]) {
                            ld[at] = ld[at - 1];
                            lp[at] = lp[at - 1];
                            --at;
                        }
                        ld[at] = dj;
                        lp[at] = nbr[j];
                    }
                    int* out = hint_list.data() + static_cast<size_t>(pos) * kList;
                    std::copy(lp, lp + take, out);
                    // unlisted points lie no nearer than the last listed one: the k-NN is
                    // exact (KdTree::knn_range); when it holds the whole cloud, none is unlisted
                    const bool all = take == others && m == tree.size();
                    hint_reach[pos] = all ? std::numeric_limits<float>::infinity()
                                          : (take > 0 ? ld[take - 1] : 0.f);
                    hint_first[pos] = take > 0 ? ld[0] : hint_reach[pos];
                }
                const int64_t i = tree.row_at(pos);
                pc.covariances[i] = iso;  // isotropic unless a plane is found
                if (m < 3) return;
                // mean and scatter about the query (numerically safe far from the origin)
                const float* o = tree.point_at(pos);
                double sx = 0, sy = 0, sz = 0, sxx = 0, sxy = 0, sxz = 0, syy = 0, syz = 0,
                       szz = 0;
                for (int j = 0; j < m; ++j) {
                    const float* p = tree.point_at(nbr[j]);
                    const double x = double(p[0]) - o[0], y = double(p[1]) - o[1],
                                 z = double(p[2]) - o[2];
                    sx += x, sy += y, sz += z;
                    sxx += x * x, sxy += x * y, sxz += x * z;
                    syy += y * y, syz += y * z, szz += z * z;
                }
                const double inv = 1.0 / m, mx = sx * inv, my = sy * inv, mz = sz * inv;
                Eigen::Matrix3d cov;
                cov(0, 0) = sxx * inv - mx * mx;
                cov(1, 0) = cov(0, 1) = sxy * inv - mx * my;
                cov(2, 0) = cov(0, 2) = sxz * inv - mx * mz;
                cov(1, 1) = syy * inv - my * my;
                cov(2, 1) = cov(1, 2) = syz * inv - my * mz;
                cov(2, 2) = szz * inv - mz * mz;
                Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
                es.computeDirect(cov);
                const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);  // ascending
                if (!(ev[1] > 1e-12 * std::max(ev[2], 1e-30)) || !(ev[2] > 0)) return;  // collinear
                Eigen::Vector3d nrm = es.eigenvectors().col(0);
                const Eigen::Vector3d po(o[0], o[1], o[2]);
                if (nrm.dot(viewpoint - po) < 0) nrm = -nrm;
                pc.normals.row(i) = nrm.transpose();
                pc.normal_valid[i] = 1;
                pc.covariances[i].noalias() = iso - (s2 * (1 - kEps)) * nrm * nrm.transpose();
            });
        }
    };
    detail::parallel_chunks(nt, num_chunks, body, "geometry");
    pc.tree->set_hints(std::move(hint_list), std::move(hint_first), std::move(hint_reach));
    pc.cov_scale = s2;
    pc.cov_plane = 1 - kEps;
}
}  // namespace

std::shared_ptr<PreparedCloud> prepare_cloud(const PointsXYZ& points, const Neighborhood& nb,
                                             const Eigen::Vector3d& viewpoint, double point_sigma,
                                             int num_threads) {
    if (!(point_sigma > 0)) throw std::invalid_argument("point_sigma must be > 0");
    TRIPOD_PHASE("prepare: total");
    auto pc = std::make_shared<PreparedCloud>();
    std::optional<prof::Scope> sc;
    sc.emplace("prepare: S finite+copy");
    const std::vector<int64_t> rows = finite_rows(points);
    pc->num_dropped = points.rows() - static_cast<int64_t>(rows.size());
    if (static_cast<int64_t>(rows.size()) == points.rows()) {
        pc->points = points;
    } else {
        pc->points.resize(static_cast<Eigen::Index>(rows.size()), 3);
        for (size_t i = 0; i < rows.size(); ++i) pc->points.row(i) = points.row(rows[i]);
    }
    sc.reset();
    sc.emplace("prepare: S kdtree");
    pc->tree = std::make_unique<KdTree<3>>(pc->points.data(), pc->points.rows(), 20, num_threads);
    sc.reset();
    sc.emplace("prepare: P geometry");
    if (!(nb.radius > 0)) {
        if (nb.k_neighbors <= 0)
            throw std::invalid_argument("neighbourhood needs k_neighbors > 0 or radius > 0");
        estimate_gicp_geometry(*pc, nb.k_neighbors, viewpoint, point_sigma, num_threads);
        return pc;
    }
    const LocalGeometry g =
        estimate_local_geometry(pc->points, *pc->tree, nb, viewpoint, num_threads, true);
    pc->normals = g.normals;
    pc->normal_valid = g.valid;
    const int64_t n = pc->points.rows();
    pc->covariances.resize(n);
    constexpr double kEps = 1e-3;
    const double s2 = point_sigma * point_sigma / kEps;
    const Eigen::Vector3d diag(s2 * kEps, s2, s2);
    for (int64_t i = 0; i < n; ++i) {
        if (!g.valid[i]) {  // isotropic: no plane known
            pc->covariances[i] = s2 * Eigen::Matrix3d::Identity();
            continue;
        }
        const Eigen::Matrix3d& U = g.frames[i];
        pc->covariances[i].noalias() = U * diag.asDiagonal() * U.transpose();
    }
    pc->cov_scale = s2;  // U diag(eps, 1, 1) U^T = I - (1 - eps) n n^T
    pc->cov_plane = 1 - kEps;
    return pc;
}

RegistrationResult register_local(const PreparedCloud& src, const PreparedCloud& tgt,
                                  const Eigen::Matrix4d& T_init, const RegistrationOptions& opt) {
    TRIPOD_PHASE("register: total");
    std::optional<prof::Scope> sc;
    sc.emplace("register: S validate+problem");
    validate(src, tgt, T_init, opt);
    RegistrationResult res;
    Eigen::Isometry3d T(T_init);
    if (opt.has_rotation_prior && !(opt.rotation_prior_sigma > 0)) T.linear() = opt.R_prior;
    Problem P(src, tgt, opt, opt.method, opt.num_threads);
    std::vector<int> corr;
    sc.reset();
    sc.emplace("register: stages");
    res.status = "max_iterations";
    const size_t stages = opt.max_correspondence_distances.size();
    // the last stage's final linearisation, when its last step made it (finish_result needs it)
    std::optional<Normal> last;
    for (size_t stage = 0; stage < stages; ++stage) {
        bool converged = false;
        if (!run_stage(P, opt.max_correspondence_distances[stage], T, corr, res, converged,
                       stage + 1 == stages ? &last : nullptr)) {
            last.reset();
            res.status = "too_few_correspondences";
            break;
        }
        if (stage + 1 == stages) res.status = converged ? "converged" : "max_iterations";
    }
    res.converged = res.status == "converged";
    res.T_target_source = T.matrix();
    // quality and information with the method's own residual model (lm: point-to-plane;
    // VGICP: GICP on the points, at the final pose)
    Method model = opt.method;
    if (model == Method::kLM) model = Method::kPointToPlane;
    if (model == Method::kVGICP) model = Method::kGICP;
    sc.reset();
    sc.emplace("register: finish");
    Problem F(src, tgt, opt, model, opt.num_threads);
    // the solver's model is the finish's (not lm, not VGICP): its last linearisation is reused
    const bool reuse = last && model == opt.method;
    detail::finish_result(F, res, std::move(corr), reuse ? &*last : nullptr);
    if (res.status != "too_few_correspondences" && res.condition < 1e-4) {
        res.status = "degenerate";
        res.converged = false;
    }
    return res;
}

}  // namespace tripod
