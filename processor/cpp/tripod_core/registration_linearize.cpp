// SPDX-License-Identifier: BSD-3-Clause
// The hot loop of the Gauss-Newton methods: association and linearisation fused in one pass
// over the source points, one instantiation per residual model (no per-point branching on the
// method, no per-point allocation), sums per fixed chunk of points added in chunk order (the
// result is bit-identical whatever the thread count).
//
// Jacobians of e = q - (R p + t) under the left update (exp(w) R, t + v), with S = [R p]x:
//   d e / d(w, v) = J = [S, -I]
// and the normal-equation blocks written out from that structure rather than as generic
// 6x3 products (a third of the flops):
//   GICP, weight M:   J^T M J = [[-S M S, S M], [-M S, M]],   J^T M e = [M e x R p; -M e]
//   point-to-plane:   n^T J = [n x R p; -n]
//   point-to-point:   J^T J = [[-S S, S], [-S, I]],            J^T e = [e x R p; -e]
// Only the lower triangle is summed; the upper one is filled once at the end.
#include <omp.h>

#include "tripod_core/parallel_chunks.hpp"
#include "tripod_core/phase_timer.hpp"
#include "tripod_core/registration_internal.hpp"
#include "tripod_core/registration_voxels.hpp"

namespace tripod::detail {

namespace {
int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

bool is_plane_family(Method m) {
    return m == Method::kPointToPlane || m == Method::kSymmetric || m == Method::kLM;
}

/// Inverse of C = a I - aq u u^T - ap v v^T (C_q + R C_p R^T of two plane-form covariances,
/// u = n_q, v = R n_p; either may be 0) by the Woodbury identity, with U = [u v],
/// D = diag(aq, ap), G = U^T U:
///   C^-1 = (I + U K U^T) / a,   K = (a I - D G)^-1 D   (2x2, symmetric)
/// about a third of the flops of R C_p R^T and a general 3x3 inverse.
inline Eigen::Matrix3d plane_information(const Eigen::Vector3d& u, const Eigen::Vector3d& v,
                                         double aq, double ap, double a) {
    const double uu = u.squaredNorm(), vv = v.squaredNorm(), g = u.dot(v);
    const double d11 = a - aq * uu, d22 = a - ap * vv;
    // det >= a (a - aq - ap) > 0: both covariances are positive definite
    const double inv_det = 1.0 / (d11 * d22 - aq * ap * g * g);
    const double k11 = aq * d22 * inv_det, k12 = aq * ap * g * inv_det,
                 k22 = ap * d11 * inv_det;
    // U K U^T = u p^T + v q^T
    const Eigen::Vector3d p = k11 * u + k12 * v, q = k12 * u + k22 * v;
    const double ia = 1.0 / a;
    Eigen::Matrix3d W;
    W(0, 0) = (1 + u.x() * p.x() + v.x() * q.x()) * ia;
    W(1, 1) = (1 + u.y() * p.y() + v.y() * q.y()) * ia;
    W(2, 2) = (1 + u.z() * p.z() + v.z() * q.z()) * ia;
    W(1, 0) = W(0, 1) = (u.y() * p.x() + v.y() * q.x()) * ia;
    W(2, 0) = W(0, 2) = (u.z() * p.x() + v.z() * q.x()) * ia;
    W(2, 1) = W(1, 2) = (u.z() * p.y() + v.z() * q.y()) * ia;
    return W;
}

/// GICP normal equations of one chunk, lower triangle only, written out from the skew
/// structure of S = [R p]x (A = W S: 18 products; S^T A, lower half: 12):
///   H_rr += w S^T W S,   H_tr += -w W S,   H_tt += w W,   b_r += w (W e) x R p,   b_t -= w W e
struct GicpSums {
    double rr[6] = {}, tr[9] = {}, tt[6] = {}, br[3] = {}, bt[3] = {};
    void add(double w, const Eigen::Matrix3d& W, const Eigen::Vector3d& We,
             const Eigen::Vector3d& r) {
        const double x = r.x(), y = r.y(), z = r.z();
        double A[3][3];
        for (int i = 0; i < 3; ++i) {
            A[i][0] = W(i, 1) * z - W(i, 2) * y;
            A[i][1] = W(i, 2) * x - W(i, 0) * z;
            A[i][2] = W(i, 0) * y - W(i, 1) * x;
        }
        rr[0] += w * (z * A[1][0] - y * A[2][0]);
        rr[1] += w * (x * A[2][0] - z * A[0][0]);
        rr[2] += w * (x * A[2][1] - z * A[0][1]);
        rr[3] += w * (y * A[0][0] - x * A[1][0]);
        rr[4] += w * (y * A[0][1] - x * A[1][1]);
        rr[5] += w * (y * A[0][2] - x * A[1][2]);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) tr[3 * i + j] -= w * A[i][j];
        tt[0] += w * W(0, 0);
        tt[1] += w * W(1, 0);
        tt[2] += w * W(1, 1);
        tt[3] += w * W(2, 0);
        tt[4] += w * W(2, 1);
        tt[5] += w * W(2, 2);
        const Eigen::Vector3d c = We.cross(r);
        for (int k = 0; k < 3; ++k) {
            br[k] += w * c[k];
            bt[k] -= w * We[k];
        }
    }
    /// Into the lower triangle of acc.H and into acc.b.
    void store(Normal& acc) const {
        static constexpr int kI[6] = {0, 1, 1, 2, 2, 2}, kJ[6] = {0, 0, 1, 0, 1, 2};
        for (int k = 0; k < 6; ++k) {
            acc.H(kI[k], kJ[k]) += rr[k];
            acc.H(3 + kI[k], 3 + kJ[k]) += tt[k];
        }
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) acc.H(3 + i, j) += tr[3 * i + j];
        for (int k = 0; k < 3; ++k) {
            acc.b[k] += br[k];
            acc.b[3 + k] += bt[k];
        }
    }
};

/// The previous pairs, evaluated (cost only) in the same pass as a linearisation at the same
/// pose: see linearize_fused().
struct PrevPairs {
    const std::vector<int>& corr;
    const std::vector<Eigen::Matrix3d>* mahalanobis;
    double error = 0;
};

/// One pair's residual under a model: what both the linearisation and the cost-only evaluation
/// of the previous pairs need (fields a model does not use are never written).
struct PairResidual {
    Eigen::Vector3d e;    ///< q - T p [m]
    Eigen::Matrix3d W;    ///< GICP/VGICP: (C_q + R C_p R^T)^-1 [1/m^2]
    Eigen::Vector3d We;   ///< GICP/VGICP: W e
    Eigen::Vector3d nrm;  ///< plane family: the residual's normal
    double s = 0;         ///< plane family: n . e [m]
    double w = 0, rho = 0;  ///< robust weight and cost
};

/// The residual model of method M (lm: point-to-plane) over one problem at one pose: the
/// per-method kernel of the hot loop, shared by the linearisation and by the fused cost of the
/// previous pairs (the same code, so the same bits).
template <Method M>
struct Model {
    static constexpr bool kVoxels = M == Method::kVGICP;
    static constexpr bool kGicp = M == Method::kGICP || kVoxels;
    static constexpr bool kPlane =
        M == Method::kPointToPlane || M == Method::kSymmetric || M == Method::kLM;

    const PreparedCloud& src;
    const PreparedCloud& tgt;
    const GaussianVoxels* vox;
    Eigen::Matrix3d R;
    double inv_s2;
    Kernel kernel;
    bool oriented;
    double min_cos;
    // GICP over plane-form covariances: C = a I - aq n_q n_q^T - ap (R n_p)(R n_p)^T
    bool plane_form;
    double aq, ap, a;

    Model(const Problem& P, const Eigen::Isometry3d& T)
        : src(P.src),
          tgt(P.tgt),
          vox(P.voxels),
          R(T.linear()),
          inv_s2(1.0 / (P.opt.point_sigma * P.opt.point_sigma)),
          kernel{P.opt.loss, std::pow(P.opt.loss_scale / P.opt.point_sigma, 2)},
          oriented(P.opt.oriented),
          min_cos(P.opt.min_normal_cos),
          plane_form(P.tgt.cov_scale > 0 && P.src.cov_scale > 0),
          aq(P.tgt.cov_scale * P.tgt.cov_plane),
          ap(P.src.cov_scale * P.src.cov_plane),
          a(P.tgt.cov_scale + P.src.cov_scale) {}

    /// Residual of source row i (transformed: Tp) against target j (VGICP: voxel j) into r;
    /// false for a pair the model drops (plane family: no normal, incompatible normals).
    /// GICP: `W_known`, when given, is the pair's weight (else computed here).
    [[gnu::always_inline]] bool residual(int64_t i, int j, const Eigen::Vector3d& Tp,
                                         const Eigen::Matrix3d* W_known,
                                         PairResidual& r) const {
        if constexpr (kVoxels)
            r.e = vox->mean(j) - Tp;
        else
            r.e = tgt.points.row(j).transpose().cast<double>() - Tp;
        if constexpr (kGicp) {
            if (W_known) {
                r.W = *W_known;
            } else if (!kVoxels && plane_form) {
                r.W = plane_information(tgt.normals.row(j).transpose(),
                                        R * src.normals.row(i).transpose(), aq, ap, a);
            } else {
                const Eigen::Matrix3d& Cq = kVoxels ? vox->covariance(j) : tgt.covariances[j];
                const Eigen::Matrix3d C = Cq + R * src.covariances[i] * R.transpose();
                r.W = C.inverse();
            }
            r.We = r.W * r.e;
            kernel(r.e.dot(r.We), r.w, r.rho);
        } else if constexpr (kPlane) {
            if (!tgt.normal_valid[j]) return false;
            r.nrm = tgt.normals.row(j).transpose();
            if (src.normal_valid[i]) {
                Eigen::Vector3d ns = R * src.normals.row(i).transpose();
                // sign-free: a normal seen from the other side is the same surface
                if (!oriented && ns.dot(r.nrm) < 0) ns = -ns;
                // normal compatibility: a pair on different surfaces (a wall point matched to
                // the floor near a corner) pulls the wrong way: drop it
                if (!(ns.dot(r.nrm) >= min_cos)) return false;
                if constexpr (M == Method::kSymmetric) r.nrm = (r.nrm + ns).normalized();
            } else if (oriented || M == Method::kSymmetric) {
                return false;
            }
            r.s = r.nrm.dot(r.e);
            kernel(r.s * r.s * inv_s2, r.w, r.rho);
        } else {  // point-to-point
            kernel(r.e.squaredNorm() * inv_s2, r.w, r.rho);
        }
        return true;
    }
};

template <Method M>
Normal linearize_model(const Problem& P, const Eigen::Isometry3d& T, std::vector<int>& corr,
                       bool with_jacobian, double associate_sq_dist,
                       std::vector<Eigen::Matrix3d>* mahalanobis, PrevPairs* prev) {
    using Mo = Model<M>;
    const Mo model(P, T);
    const PreparedCloud& src = P.src;
    const PreparedCloud& tgt = P.tgt;
    const GaussianVoxels* vox = P.voxels;
    const int64_t n = src.points.rows();
    const bool find = associate_sq_dist > 0;
    TRIPOD_PHASE(prev ? "linearize: P eval+assoc+lin"
                      : (find ? "linearize: P assoc+lin"
                              : (with_jacobian ? "linearize: P lin" : "linearize: P eval")));
    // the previous iteration's matches (if any) warm-start the nearest-neighbour searches
    if (corr.size() != static_cast<size_t>(n)) corr.assign(n, -1);
    const bool store_M = Mo::kGicp && mahalanobis && with_jacobian;
    const bool reuse_M = Mo::kGicp && mahalanobis && !with_jacobian &&
                         mahalanobis->size() == static_cast<size_t>(n);
    // the previous pairs' weights, as a cost-only pass given them would reuse them
    const bool prev_M = Mo::kGicp && prev && prev->mahalanobis &&
                        prev->mahalanobis->size() == static_cast<size_t>(n);
    if (store_M) mahalanobis->resize(n);
    const Eigen::Matrix3d& R = model.R;
    const Eigen::Vector3d t = T.translation();
    const float max_sq = static_cast<float>(associate_sq_dist);
    const double inv_s2 = model.inv_s2;
    const int64_t m = static_cast<int64_t>(P.rows.size());
    // Fixed chunks, each with its own partial sum, added in chunk order afterwards (the same
    // sums on any thread count). Each thread takes the same contiguous run of chunks at every
    // call first (the correspondences and weights it writes stay in its own cache from one
    // iteration to the next: lines moving between cores cost more than the work), then helps
    // with what the others have left (parallel_chunks).
    constexpr int64_t kChunk = 128;
    const int64_t num_chunks = (m + kChunk - 1) / kChunk;
    std::vector<Normal> parts(num_chunks);
    std::vector<double> prev_parts(prev ? num_chunks : 0);
    parallel_chunks(P.num_threads, num_chunks, [&](int64_t chunk) {
        Normal acc;
        GicpSums gicp;
        double prev_error = 0;
        PairResidual r;
        const int64_t end = std::min(m, (chunk + 1) * kChunk);
        for (int64_t k = chunk * kChunk; k < end; ++k) {
            const int64_t i = P.rows[k];
            const Eigen::Vector3d Rp = R * src.points.row(i).transpose().cast<double>();
            const Eigen::Vector3d Tp = Rp + t;
            int j = corr[i];
            if (prev) {
                j = prev->corr[i];  // the previous match: evaluated here, and the search's hint
                // the cost-only pass's terms exactly (a pair it skips adds nothing)
                if (j >= 0 &&
                    model.residual(i, j, Tp, prev_M ? &(*prev->mahalanobis)[i] : nullptr, r))
                    prev_error += r.rho;
            }
            if (find) {
                if constexpr (Mo::kVoxels) {
                    j = vox->find(Tp);
                    if (j >= 0 && (vox->mean(j) - Tp).squaredNorm() > associate_sq_dist) j = -1;
                } else {
                    const Eigen::Vector3f pf = Tp.cast<float>();
                    float d2;
                    j = tgt.tree->nearest_from(pf.data(), max_sq, j, &d2);
                }
                corr[i] = j;
            }
            if (j < 0) continue;
            if (!model.residual(i, j, Tp, reuse_M ? &(*mahalanobis)[i] : nullptr, r)) continue;
            const Eigen::Vector3d& e = r.e;
            if constexpr (Mo::kGicp) {
                if (store_M) (*mahalanobis)[i] = r.W;
                if (with_jacobian) gicp.add(r.w, r.W, r.We, Rp);
            } else if constexpr (Mo::kPlane) {
                acc.sq_res += r.s * r.s;
                if (with_jacobian) {
                    Vec6 Jn;
                    Jn.head<3>() = r.nrm.cross(Rp);
                    Jn.tail<3>() = -r.nrm;
                    const double c = r.w * inv_s2;
                    acc.H.noalias() += (c * Jn) * Jn.transpose();
                    acc.b.noalias() += (c * r.s) * Jn;
                }
            } else {  // point-to-point
                if (with_jacobian) {
                    const double c = r.w * inv_s2;
                    const Eigen::Matrix3d S = skew(Rp);
                    acc.H.topLeftCorner<3, 3>().noalias() -= c * (S * S);
                    acc.H.bottomLeftCorner<3, 3>() -= c * S;
                    acc.H.bottomRightCorner<3, 3>().diagonal().array() += c;
                    acc.b.head<3>() += c * e.cross(Rp);
                    acc.b.tail<3>() -= c * e;
                }
            }
            acc.error += r.rho;
            acc.count += 1;
            acc.sq_dist += e.squaredNorm();
            if constexpr (!Mo::kPlane) acc.sq_res += e.squaredNorm();
        }
        if constexpr (Mo::kGicp) gicp.store(acc);
        parts[chunk] = acc;
        if (prev) prev_parts[chunk] = prev_error;
    }, find ? "assoc+lin" : (with_jacobian ? "lin" : "eval"));
    Normal out;
    for (const Normal& p : parts) {
        out.H += p.H;
        out.b += p.b;
        out.error += p.error;
        out.count += p.count;
        out.sq_dist += p.sq_dist;
        out.sq_res += p.sq_res;
    }
    out.H = out.H.selfadjointView<Eigen::Lower>();
    if (prev) {
        prev->error = 0;
        for (double e : prev_parts) prev->error += e;  // chunk order, as `out.error`
    }
    return out;
}

/// The one method dispatch of the linearisation: linearize_model of P.method's residual model
/// (lm: point-to-plane's), with or without the previous pairs' cost (`prev`).
Normal linearize_any(const Problem& P, const Eigen::Isometry3d& T, std::vector<int>& corr,
                     bool with_jacobian, double associate_sq_dist,
                     std::vector<Eigen::Matrix3d>* mahalanobis, PrevPairs* prev) {
    switch (P.method) {
        case Method::kPointToPoint:
            return linearize_model<Method::kPointToPoint>(P, T, corr, with_jacobian,
                                                          associate_sq_dist, mahalanobis, prev);
        case Method::kGICP:
            return linearize_model<Method::kGICP>(P, T, corr, with_jacobian, associate_sq_dist,
                                                  mahalanobis, prev);
        case Method::kVGICP:
            return linearize_model<Method::kVGICP>(P, T, corr, with_jacobian, associate_sq_dist,
                                                   mahalanobis, prev);
        case Method::kSymmetric:
            return linearize_model<Method::kSymmetric>(P, T, corr, with_jacobian,
                                                       associate_sq_dist, mahalanobis, prev);
        case Method::kPointToPlane:
        case Method::kLM:
            break;
    }
    return linearize_model<Method::kPointToPlane>(P, T, corr, with_jacobian, associate_sq_dist,
                                                  mahalanobis, prev);
}
}  // namespace

Problem::Problem(const PreparedCloud& s, const PreparedCloud& t, const RegistrationOptions& o,
                 Method m, int nt)
    : src(s), tgt(t), opt(o), method(m), num_threads(threads(nt)) {
    TRIPOD_PHASE("problem: S rows");
    const bool need_normal = o.oriented && is_plane_family(m);
    std::vector<int64_t> all;
    all.reserve(s.points.rows());
    for (int64_t i : s.tree->order())
        if (!need_normal || s.normal_valid[i]) all.push_back(i);
    const int64_t na = static_cast<int64_t>(all.size());
    if (o.max_source > 0 && na > o.max_source) {
        rows.resize(o.max_source);
        for (int64_t k = 0; k < o.max_source; ++k) rows[k] = all[(k * na) / o.max_source];
    } else {
        rows.swap(all);
    }
}

void associate(const Problem& P, const Eigen::Isometry3d& T, double max_sq_dist,
               std::vector<int>& corr) {
    const int64_t n = P.src.points.rows();
    if (corr.size() != static_cast<size_t>(n)) corr.assign(n, -1);  // else: warm-start hints
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Eigen::Vector3f t = T.translation().cast<float>();
    const int64_t m = static_cast<int64_t>(P.rows.size());
    constexpr int64_t kChunk = 128;
    parallel_chunks(P.num_threads, (m + kChunk - 1) / kChunk, [&](int64_t chunk) {
        int guess = -1;  // as in linearize_model: the chunk's previous match
        for (int64_t k = chunk * kChunk, end = std::min(m, k + kChunk); k < end; ++k) {
            const int64_t i = P.rows[k];
            const Eigen::Vector3f p = R * P.src.points.row(i).transpose() + t;
            float d;
            const float max_sq = static_cast<float>(max_sq_dist);
            corr[i] = corr[i] >= 0 ? P.tgt.tree->nearest_from(p.data(), max_sq, corr[i], &d)
                                   : P.tgt.tree->nearest_guessed(p.data(), max_sq, guess, &d);
            if (corr[i] >= 0) guess = corr[i];
        }
    }, "associate");
}

Normal linearize_fused(const Problem& P, const Eigen::Isometry3d& T,
                       const std::vector<int>& prev_corr,
                       const std::vector<Eigen::Matrix3d>* prev_mahalanobis, double& prev_error,
                       std::vector<int>& corr, double associate_sq_dist,
                       std::vector<Eigen::Matrix3d>* mahalanobis) {
    PrevPairs prev{prev_corr, prev_mahalanobis};
    Normal out = linearize_any(P, T, corr, true, associate_sq_dist, mahalanobis, &prev);
    prev_error = prev.error;
    return out;
}

Normal linearize(const Problem& P, const Eigen::Isometry3d& T, std::vector<int>& corr,
                 bool with_jacobian, double associate_sq_dist,
                 std::vector<Eigen::Matrix3d>* mahalanobis) {
    return linearize_any(P, T, corr, with_jacobian, associate_sq_dist, mahalanobis, nullptr);
}

}  // namespace tripod::detail
