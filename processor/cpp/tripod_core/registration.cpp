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
#include <limits>
#include <stdexcept>

#include "tripod_core/registration_internal.hpp"

namespace tripod {

using detail::Mat6;
using detail::Normal;
using detail::Vec6;
using detail::skew;

namespace {
int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

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
    const bool needs_normals = opt.method != Method::kPointToPoint;
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
}  // namespace

namespace detail {

/// Point-to-plane family: pairs whose normals differ by more than 60 deg are ignored.
constexpr double kMinNormalCos = 0.5;

void associate(const PreparedCloud& src, const PreparedCloud& tgt, const Eigen::Isometry3d& T,
               double max_sq_dist, std::vector<int>& corr, int num_threads) {
    const int64_t n = src.points.rows();
    if (corr.size() != static_cast<size_t>(n)) corr.assign(n, -1);  // else: warm-start hints
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Eigen::Vector3f t = T.translation().cast<float>();
#pragma omp parallel for num_threads(threads(num_threads)) schedule(dynamic, 512)
    for (int64_t i = 0; i < n; ++i) {
        const Eigen::Vector3f p = R * src.points.row(i).transpose() + t;
        float d;
        corr[i] = tgt.tree->nearest_from(p.data(), static_cast<float>(max_sq_dist), corr[i], &d);
    }
}

Normal linearize(Method method, const PreparedCloud& src, const PreparedCloud& tgt,
                 const Eigen::Isometry3d& T, std::vector<int>& corr,
                 const RegistrationOptions& opt, bool with_jacobian, int num_threads,
                 double associate_sq_dist, std::vector<Eigen::Matrix3d>* mahalanobis) {
    const bool find = associate_sq_dist > 0;
    // the previous iteration's matches (if any) warm-start the nearest-neighbour searches
    if (find && corr.size() != static_cast<size_t>(src.points.rows()))
        corr.assign(src.points.rows(), -1);
    const bool store_M = mahalanobis && with_jacobian && method == Method::kGICP;
    const bool reuse_M = mahalanobis && !with_jacobian && method == Method::kGICP &&
                         mahalanobis->size() == static_cast<size_t>(src.points.rows());
    if (store_M) mahalanobis->resize(src.points.rows());
    const Eigen::Matrix3f Rf = T.linear().cast<float>();
    const Eigen::Vector3f tf = T.translation().cast<float>();
    const int nt = threads(num_threads);
    const double inv_s2 = 1.0 / (opt.point_sigma * opt.point_sigma);
    const Kernel kernel{opt.loss, std::pow(opt.loss_scale / opt.point_sigma, 2)};
    const Eigen::Matrix3d R = T.linear();
    const Eigen::Vector3d t = T.translation();
    const int64_t n = src.points.rows();
    // Fixed chunks handed out dynamically (a descheduled thread on a busy machine does not hold
    // the others up), each with its own partial sum, added in chunk order afterwards: the result
    // is bit-identical whatever the thread count.
    constexpr int64_t kChunk = 512;
    const int64_t num_chunks = (n + kChunk - 1) / kChunk;
    std::vector<Normal> parts(num_chunks);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 1)
    for (int64_t chunk = 0; chunk < num_chunks; ++chunk) {
        Normal acc;
        const int64_t end = std::min(n, (chunk + 1) * kChunk);
        for (int64_t i = chunk * kChunk; i < end; ++i) {
            if (find) {
                const Eigen::Vector3f pf = Rf * src.points.row(i).transpose() + tf;
                float d2;
                corr[i] = tgt.tree->nearest_from(pf.data(), static_cast<float>(associate_sq_dist),
                                                 corr[i], &d2);
            }
            const int j = corr[i];
            if (j < 0) continue;
            const Eigen::Vector3d Rp = R * src.points.row(i).transpose().cast<double>();
            const Eigen::Vector3d q = tgt.points.row(j).transpose().cast<double>();
            const Eigen::Vector3d e = q - (Rp + t);
            Eigen::Matrix<double, 3, 6> J;
            if (with_jacobian) {
                J.leftCols<3>() = skew(Rp);
                J.rightCols<3>() = -Eigen::Matrix3d::Identity();
            }
            double w = 0, rho = 0;
            switch (method) {
                case Method::kGICP: {
                    Eigen::Matrix3d M;
                    if (reuse_M) {
                        M = (*mahalanobis)[i];
                    } else {
                        const Eigen::Matrix3d C =
                            tgt.covariances[j] + R * src.covariances[i] * R.transpose();
                        M = C.inverse();
                        if (store_M) (*mahalanobis)[i] = M;
                    }
                    const Eigen::Vector3d Me = M * e;
                    kernel(e.dot(Me), w, rho);
                    if (with_jacobian) {
                        const Eigen::Matrix<double, 6, 3> JtM = J.transpose() * M;
                        acc.H.noalias() += w * JtM * J;
                        acc.b.noalias() += w * J.transpose() * Me;
                    }
                    break;
                }
                case Method::kPointToPoint: {
                    kernel(e.squaredNorm() * inv_s2, w, rho);
                    if (with_jacobian) {
                        acc.H.noalias() += (w * inv_s2) * J.transpose() * J;
                        acc.b.noalias() += (w * inv_s2) * J.transpose() * e;
                    }
                    break;
                }
                default: {  // point-to-plane family (plane, symmetric, Ceres' model)
                    if (!tgt.normal_valid[j]) continue;
                    Eigen::Vector3d nrm = tgt.normals.row(j).transpose();
                    if (src.normal_valid[i]) {
                        Eigen::Vector3d ns = R * src.normals.row(i).transpose();
                        if (ns.dot(nrm) < 0) ns = -ns;  // seen from the other side
                        // normal compatibility: a pair on different surfaces (a wall point
                        // matched to the floor near a corner) pulls the wrong way: drop it
                        if (ns.dot(nrm) < kMinNormalCos) continue;
                        if (method == Method::kSymmetric) nrm = (nrm + ns).normalized();
                    } else if (method == Method::kSymmetric) {
                        continue;
                    }
                    const double s = nrm.dot(e);
                    kernel(s * s * inv_s2, w, rho);
                    if (with_jacobian) {
                        const Eigen::Matrix<double, 1, 6> Jn = nrm.transpose() * J;
                        acc.H.noalias() += (w * inv_s2) * Jn.transpose() * Jn;
                        acc.b.noalias() += (w * inv_s2 * s) * Jn.transpose();
                    }
                    break;
                }
            }
            acc.error += rho;
            acc.count += 1;
            acc.sq_dist += e.squaredNorm();
        }
        parts[chunk] = acc;
    }
    Normal out;
    for (const Normal& p : parts) {
        out.H += p.H;
        out.b += p.b;
        out.error += p.error;
        out.count += p.count;
        out.sq_dist += p.sq_dist;
    }
    return out;
}

void finish_result(const PreparedCloud& src, const PreparedCloud& tgt, Method residual_model,
                   const RegistrationOptions& opt, RegistrationResult& res, int num_threads,
                   std::vector<int> corr) {
    const Eigen::Isometry3d T(res.T_target_source);
    const double d = opt.max_correspondence_distances.back();
    Normal nl = linearize(residual_model, src, tgt, T, corr, opt, true, num_threads, d * d);
    res.final_error = nl.error + add_prior(opt, T.linear(), &nl.H, &nl.b);
    // Fitness and RMSE as Open3D defines them (all correspondences within the distance).
    int64_t inl = 0;
    double sq = 0;
    for (size_t i = 0; i < corr.size(); ++i) {
        if (corr[i] < 0) continue;
        const Eigen::Vector3d e = tgt.points.row(corr[i]).transpose().cast<double>() -
                                  T * src.points.row(i).transpose().cast<double>();
        sq += e.squaredNorm();
        ++inl;
    }
    res.num_inliers = inl;
    res.fitness = src.points.rows() ? static_cast<double>(inl) / src.points.rows() : 0;
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
    Normal geo = linearize(Method::kPointToPlane, src, tgt, T, corr, opt, true, num_threads);
    if (geo.count > 0) nl.H = geo.H;
    double extent = 0;
    const Eigen::Vector3d c = src.points.cast<double>().colwise().mean().transpose();
    for (int64_t i = 0; i < src.points.rows(); ++i)
        extent += (src.points.row(i).transpose().cast<double>() - c).squaredNorm();
    extent = std::sqrt(extent / std::max<int64_t>(1, src.points.rows()));
    std::vector<int> freeidx;
    for (int k = 0; k < 6; ++k)
        if (!lock[k]) freeidx.push_back(k);
    Eigen::MatrixXd Hs(freeidx.size(), freeidx.size());
    for (size_t a = 0; a < freeidx.size(); ++a)
        for (size_t b = 0; b < freeidx.size(); ++b) {
            const double sa = freeidx[a] < 3 ? 1.0 / std::max(extent, 1e-9) : 1.0;
            const double sb = freeidx[b] < 3 ? 1.0 / std::max(extent, 1e-9) : 1.0;
            Hs(a, b) = nl.H(freeidx[a], freeidx[b]) * sa * sb;
        }
    if (Hs.size() == 0) {
        res.condition = 1;
    } else {
        Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Hs, Eigen::EigenvaluesOnly);
        const double hi = es.eigenvalues().maxCoeff(), lo = es.eigenvalues().minCoeff();
        res.condition = hi > 0 ? std::max(lo, 0.0) / hi : 0;
    }
}

}  // namespace detail

std::shared_ptr<PreparedCloud> prepare_cloud(const PointsXYZ& points, const Neighborhood& nb,
                                             const Eigen::Vector3d& viewpoint, double point_sigma,
                                             int num_threads) {
    if (!(point_sigma > 0)) throw std::invalid_argument("point_sigma must be > 0");
    auto pc = std::make_shared<PreparedCloud>();
    const std::vector<int64_t> rows = finite_rows(points);
    pc->num_dropped = points.rows() - static_cast<int64_t>(rows.size());
    pc->points.resize(static_cast<Eigen::Index>(rows.size()), 3);
    for (size_t i = 0; i < rows.size(); ++i) pc->points.row(i) = points.row(rows[i]);
    pc->tree = std::make_unique<KdTree<3>>(pc->points.data(), pc->points.rows());
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
    return pc;
}

RegistrationResult register_local(const PreparedCloud& src, const PreparedCloud& tgt,
                                  const Eigen::Matrix4d& T_init, const RegistrationOptions& opt) {
    validate(src, tgt, T_init, opt);
    const int nt = threads(opt.num_threads);
    RegistrationResult res;
    Eigen::Isometry3d T(T_init);
    if (opt.has_rotation_prior && !(opt.rotation_prior_sigma > 0)) T.linear() = opt.R_prior;
    const auto lock = locked(opt);
    const double inv_s2 = 1.0 / (opt.point_sigma * opt.point_sigma);
    const Kernel kernel{opt.loss, std::pow(opt.loss_scale / opt.point_sigma, 2)};
    const bool closed_form = opt.method == Method::kPointToPoint && !opt.has_rotation_prior &&
                             !opt.lock_z;
    const int need = min_points(opt.method);

    std::vector<int> corr;
    if (opt.method == Method::kCeresLM) {
        detail::register_ceres(src, tgt, T, opt, res, nt);
    } else {
        std::vector<Eigen::Matrix3d> mahalanobis;  // GICP weights of the current pairs
        bool ok = true;
        res.status = "max_iterations";
        for (size_t stage = 0; stage < opt.max_correspondence_distances.size() && ok; ++stage) {
            const double d = opt.max_correspondence_distances[stage];
            double lambda = 1e-4;
            bool stage_converged = false;
            for (int it = 0; it < opt.max_iterations; ++it) {
                ++res.iterations;
                Eigen::Isometry3d T_new;
                Normal nl;
                int64_t m = 0;
                if (closed_form) {
                    detail::associate(src, tgt, T, d * d, corr, nt);
                    for (int c : corr) m += c >= 0;
                } else {
                    nl = detail::linearize(opt.method, src, tgt, T, corr, opt, true, nt, d * d,
                                           &mahalanobis);
                    m = nl.count;
                }
                if (m < need) {
                    res.status = "too_few_correspondences";
                    ok = false;
                    break;
                }
                if (closed_form) {
                    T_new = kabsch(src, tgt, T, corr, kernel, inv_s2);
                } else {
                    const double err = nl.error + add_prior(opt, T.linear(), &nl.H, &nl.b);
                    for (int k = 0; k < 6; ++k)
                        if (lock[k]) {
                            nl.H.row(k).setZero();
                            nl.H.col(k).setZero();
                            nl.H(k, k) = 1;
                            nl.b[k] = 0;
                        }
                    // Marquardt damping, accepted only when the cost (same pairs) decreases
                    T_new = T;
                    for (int inner = 0; inner < 10; ++inner) {
                        Mat6 Hd = nl.H;
                        // Marquardt scaling, plus a floor so that directions the geometry
                        // does not constrain (a plane, a corridor) stay put instead of drifting
                        Hd.diagonal() += lambda * nl.H.diagonal() +
                                         Vec6::Constant(1e-9 * nl.H.diagonal().maxCoeff() + 1e-12);
                        const Vec6 delta = Hd.ldlt().solve(-nl.b);
                        if (!delta.allFinite()) {
                            lambda *= 10;
                            continue;
                        }
                        const Eigen::Isometry3d cand = apply(T, delta);
                        const Normal ev = detail::linearize(opt.method, src, tgt, cand, corr,
                                                            opt, false, nt, -1, &mahalanobis);
                        const double e_new = ev.error + add_prior(opt, cand.linear(), nullptr, nullptr);
                        if (e_new <= err) {
                            T_new = cand;
                            lambda = std::max(lambda / 10, 1e-10);
                            break;
                        }
                        lambda *= 10;
                    }
                }
                if (detail::step_and_check(T, T_new, opt)) {
                    stage_converged = true;
                    break;
                }
            }
            if (ok && stage + 1 == opt.max_correspondence_distances.size())
                res.status = stage_converged ? "converged" : "max_iterations";
        }
        res.converged = res.status == "converged";
    }
    res.T_target_source = T.matrix();
    // quality and information with the method's own residual model (Ceres: point-to-plane)
    const Method model = opt.method == Method::kCeresLM ? Method::kPointToPlane : opt.method;
    detail::finish_result(src, tgt, model, opt, res, nt, std::move(corr));
    if (res.status != "too_few_correspondences" && res.condition < 1e-4) {
        res.status = "degenerate";
        res.converged = false;
    }
    return res;
}

}  // namespace tripod
