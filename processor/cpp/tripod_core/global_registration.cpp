// SPDX-License-Identifier: BSD-3-Clause
// FPFH + RANSAC. Steps: 1. normals and FPFH per cloud, 2. (mutual) nearest features,
// 3. hypotheses from minimal samples filtered by edge lengths, scored by inlier correspondences,
// 4. least-squares refit on the best inliers, 5. fitness on the full clouds.
// With gravity both clouds are first levelled (up -> +z): a minimal sample is then 2 matches,
// the model is yaw + 3D translation, and the vertical components must agree.
#include "tripod_core/global_registration.hpp"

#include <omp.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "tripod_core/kdtree.hpp"

namespace tripod {

namespace {
int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

uint64_t splitmix(uint64_t x) {
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

/// Rotation taking unit vector `up` onto +z (minimal rotation).
Eigen::Matrix3d level(const Eigen::Vector3d& up) {
    return Eigen::Quaterniond::FromTwoVectors(up.normalized(), Eigen::Vector3d::UnitZ())
        .toRotationMatrix();
}

struct Match {
    Eigen::Vector3d p, q;  // source, target (levelled when gravity is used)
};

/// Least-squares rigid fit on matches (Kabsch), or yaw + translation when `yaw_only`.
Eigen::Isometry3d fit(const std::vector<Match>& m, const std::vector<int>& sel, bool yaw_only) {
    Eigen::Vector3d mp = Eigen::Vector3d::Zero(), mq = Eigen::Vector3d::Zero();
    for (int i : sel) {
        mp += m[i].p;
        mq += m[i].q;
    }
    mp /= sel.size();
    mq /= sel.size();
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    if (yaw_only) {
        double c = 0, s = 0;
        for (int i : sel) {
            const Eigen::Vector2d a = (m[i].p - mp).head<2>(), b = (m[i].q - mq).head<2>();
            c += a.dot(b);
            s += a.x() * b.y() - a.y() * b.x();
        }
        T.linear() = Eigen::AngleAxisd(std::atan2(s, c), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    } else {
        Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
        for (int i : sel) S += (m[i].q - mq) * (m[i].p - mp).transpose();
        Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
        Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
        if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;
        T.linear() = svd.matrixU() * D * svd.matrixV().transpose();
    }
    T.translation() = mq - T.linear() * mp;
    return T;
}

void validate(const GlobalOptions& opt) {
    if (!(opt.normal_radius > 0) || !(opt.feature_radius > 0) || !(opt.inlier_distance > 0))
        throw std::invalid_argument("normal_radius, feature_radius and inlier_distance must be > 0");
    if (opt.max_iterations < 1) throw std::invalid_argument("max_iterations must be >= 1");
    if (!(opt.confidence > 0 && opt.confidence < 1))
        throw std::invalid_argument("confidence must be in (0, 1)");
    if ((opt.up_source.norm() > 0) != (opt.up_target.norm() > 0))
        throw std::invalid_argument("give the up vector of both clouds or of neither");
    if (!opt.up_source.allFinite() || !opt.up_target.allFinite())
        throw std::invalid_argument("up vectors must be finite");
    if (opt.has_rotation_prior) {
        const Eigen::Matrix3d& P = opt.R_prior;
        if (!P.allFinite() || (P.transpose() * P - Eigen::Matrix3d::Identity()).norm() > 1e-4 ||
            P.determinant() < 0)
            throw std::invalid_argument("rotation prior is not a rotation matrix");
        if (!(opt.rotation_tolerance > 0))
            throw std::invalid_argument("rotation_tolerance must be > 0");
    }
    if (!(opt.twin_tolerance > 0) || !std::isfinite(opt.twin_tolerance))
        throw std::invalid_argument("twin_tolerance must be > 0");
    for (const double t : opt.twin_turns)
        if (!std::isfinite(t)) throw std::invalid_argument("twin turns must be finite");
}

/// The finite rows of `in` (at least 3, else std::invalid_argument naming the cloud).
PointsXYZ finite_points(const PointsXYZ& in, const char* name) {
    const std::vector<int64_t> rows = finite_rows(in);
    if (rows.size() < 3)
        throw std::invalid_argument(std::string(name) + " has " + std::to_string(rows.size()) +
                                    " finite points; global registration needs at least 3");
    PointsXYZ out(static_cast<Eigen::Index>(rows.size()), 3);
    for (size_t i = 0; i < rows.size(); ++i) out.row(i) = in.row(rows[i]);
    return out;
}

/// A cloud's normals and FPFH features.
struct Described {
    LocalGeometry geometry;
    MatrixX33f fpfh;
    bool has_feature(int64_t i) const { return geometry.valid[i] && fpfh.row(i).sum() > 0; }
};

Described describe(const PointsXYZ& pts, const Eigen::Vector3d& viewpoint, const GlobalOptions& opt,
                   int nt) {
    const Neighborhood nb{opt.max_neighbors > 0 ? std::min(opt.max_neighbors, 30) : 30,
                          opt.normal_radius};
    Described d;
    d.geometry = estimate_local_geometry(pts, nb, viewpoint, nt);
    d.fpfh = compute_fpfh(pts, d.geometry.normals, opt.feature_radius, opt.max_neighbors, nt);
    return d;
}

/// Nearest feature of each source point among the target's (and back for the mutual filter),
/// as point pairs in the levelled frames (Ls, Lt). Points without a feature (no normal or an
/// empty histogram) are not matched. Too few mutual matches: the one-way ones (as Open3D).
std::vector<Match> match_features(const PointsXYZ& src, const PointsXYZ& tgt,
                                  const Described& ds, const Described& dt,
                                  const Eigen::Matrix3d& Ls, const Eigen::Matrix3d& Lt,
                                  bool mutual_filter, int nt) {
    std::vector<int> tmap, smap;  // rows with a feature
    for (int64_t j = 0; j < tgt.rows(); ++j)
        if (dt.has_feature(j)) tmap.push_back(static_cast<int>(j));
    for (int64_t i = 0; i < src.rows(); ++i)
        if (ds.has_feature(i)) smap.push_back(static_cast<int>(i));
    if (tmap.size() < 3 || smap.size() < 3) return {};
    MatrixX33f ftc(tmap.size(), 33), fsc(smap.size(), 33);
    for (size_t j = 0; j < tmap.size(); ++j) ftc.row(j) = dt.fpfh.row(tmap[j]);
    for (size_t i = 0; i < smap.size(); ++i) fsc.row(i) = ds.fpfh.row(smap[i]);
    const KdTree<33> ttree(ftc.data(), ftc.rows());
    std::vector<int> s2t(smap.size(), -1);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 256)
    for (int64_t i = 0; i < static_cast<int64_t>(smap.size()); ++i) {
        float d;
        s2t[i] = ttree.nearest(fsc.row(i).data(), std::numeric_limits<float>::infinity(), &d);
    }
    std::vector<int> t2s;
    if (mutual_filter) {
        const KdTree<33> stree(fsc.data(), fsc.rows());
        t2s.assign(tmap.size(), -1);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 256)
        for (int64_t j = 0; j < static_cast<int64_t>(tmap.size()); ++j) {
            float d;
            t2s[j] = stree.nearest(ftc.row(j).data(), std::numeric_limits<float>::infinity(), &d);
        }
    }
    auto pair = [&](size_t i, int j) {
        return Match{Ls * src.row(smap[i]).transpose().cast<double>(),
                     Lt * tgt.row(tmap[j]).transpose().cast<double>()};
    };
    std::vector<Match> matches;
    for (size_t i = 0; i < smap.size(); ++i) {
        const int j = s2t[i];
        if (j < 0) continue;
        if (mutual_filter && t2s[j] != static_cast<int>(i)) continue;
        matches.push_back(pair(i, j));
    }
    if (mutual_filter && matches.size() < 10) {
        matches.clear();
        for (size_t i = 0; i < smap.size(); ++i)
            if (s2t[i] >= 0) matches.push_back(pair(i, s2t[i]));
    }
    return matches;
}

/// RANSAC over feature matches in the levelled frames. Hypothesis k draws from its own stream
/// (seed, k), so the result does not depend on the thread count. Hypotheses that agree with
/// more than their minimal sample are scored on the clouds themselves (source points, at most
/// 2000, with a target point within the inlier distance), as Open3D does: sparse or repetitive
/// scenes give few feature inliers, but the right pose explains the geometry.
class Ransac {
public:
    Ransac(const std::vector<Match>& matches, const PointsXYZ& src, const PointsXYZ& tgt,
           const Eigen::Matrix3d& Ls, const Eigen::Matrix3d& Lt, bool gravity,
           const GlobalOptions& opt)
        : m_(matches), opt_(opt), Ls_(Ls), Lt_(Lt), gravity_(gravity),
          sample_(gravity ? 2 : 3), thr2_(opt.inlier_distance * opt.inlier_distance),
          cos_tol_(std::cos(std::min(opt.rotation_tolerance, M_PI))),
          tgt_tree_(tgt.data(), tgt.rows()) {
        const int64_t step = std::max<int64_t>(1, src.rows() / 2000);
        for (int64_t i = 0; i < src.rows(); i += step)
            probe_.push_back(Ls * src.row(i).transpose().cast<double>());
    }

    int sample() const { return sample_; }

    int64_t count_inliers(const Eigen::Isometry3d& T) const {
        int64_t c = 0;
        for (const Match& m : m_) c += (T * m.p - m.q).squaredNorm() < thr2_;
        return c;
    }

    /// Rotation prior, compared in the original frames: R = Lt^T R_levelled Ls.
    bool agrees_with_prior(const Eigen::Isometry3d& T) const {
        if (!opt_.has_rotation_prior) return true;
        const Eigen::Matrix3d R = Lt_.transpose() * T.linear() * Ls_;
        return ((R * opt_.R_prior.transpose()).trace() - 1) / 2 >= cos_tol_;
    }

    int64_t geometric_score(const Eigen::Isometry3d& T) const {
        const Eigen::Matrix3d LtT = Lt_.transpose();
        int64_t c = 0;
        for (const Eigen::Vector3d& p : probe_) {
            const Eigen::Vector3f x = (LtT * (T * p)).cast<float>();
            float d;
            c += tgt_tree_.nearest(x.data(), static_cast<float>(thr2_), &d) >= 0;
        }
        return c;
    }

    /// Hypothesis k: a sample passing the edge-length (and, with gravity, height) checks,
    /// fitted, within the rotation prior.
    bool hypothesis(int64_t k, Eigen::Isometry3d& T) const {
        const int64_t M = static_cast<int64_t>(m_.size());
        uint64_t state = splitmix(opt_.seed * 0x100000001b3ULL + static_cast<uint64_t>(k));
        int idx[3];
        for (int s = 0; s < sample_; ++s) {
            bool fresh;
            int tries = 0;
            do {
                state = splitmix(state);
                idx[s] = static_cast<int>(state % static_cast<uint64_t>(M));
                fresh = true;
                for (int u = 0; u < s; ++u) fresh &= idx[u] != idx[s];
            } while (!fresh && ++tries < 16);
            if (!fresh) return false;
        }
        for (int a = 0; a < sample_; ++a)
            for (int b = a + 1; b < sample_; ++b)
                if (!compatible(m_[idx[a]], m_[idx[b]])) return false;
        std::vector<int> sel(idx, idx + sample_);
        T = fit(m_, sel, gravity_);
        return agrees_with_prior(T);
    }

    /// The best hypothesis of a yaw sector (gravity only): its score, index, pose, inliers.
    struct Best {
        int64_t score = -1, k = -1, inl = 0;
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        bool beats(const Best& o) const {
            return score > o.score || (score == o.score && score >= 0 && k < o.k);
        }
    };
    static constexpr int kSectors = 72;  // 5 deg

    static double yaw_of(const Eigen::Isometry3d& T) {
        return std::atan2(T.linear()(1, 0), T.linear()(0, 0));
    }
    static int sector_of(const Eigen::Isometry3d& T) {
        const int s = static_cast<int>(std::floor((yaw_of(T) + M_PI) / (2 * M_PI) * kSectors));
        return std::clamp(s, 0, kSectors - 1);
    }

    /// Draw hypotheses in batches until `confidence` (or max_iterations); the best by
    /// geometric score (ties: the lowest k). Returns false when none agreed with more than its
    /// sample. With `sectors` (gravity), the best of each 5 deg yaw sector too.
    bool run(Eigen::Isometry3d& best_T, int64_t& iterations, int64_t& best_score, int nt,
             std::vector<Best>* sectors = nullptr) const {
        int64_t best = -1, best_k = -1, best_inl = 0;
        int64_t needed = opt_.max_iterations, done = 0;
        const int64_t M = static_cast<int64_t>(m_.size());
        constexpr int64_t kBatch = 1024;
        if (sectors) sectors->assign(kSectors, Best{});
        while (done < std::min(needed, opt_.max_iterations)) {
            const int64_t end = std::min(done + kBatch, opt_.max_iterations);
#pragma omp parallel num_threads(nt)
            {
                int64_t lb = -1, lk = -1, linl = 0;
                Eigen::Isometry3d lT = Eigen::Isometry3d::Identity();
                std::vector<Best> ls(sectors ? kSectors : 0);
#pragma omp for schedule(dynamic, 64)
                for (int64_t k = done; k < end; ++k) {
                    Eigen::Isometry3d T;
                    if (!hypothesis(k, T)) continue;
                    const int64_t inl = count_inliers(T);
                    if (inl <= sample_) continue;
                    const int64_t c = geometric_score(T);
                    if (c > lb || (c == lb && k < lk)) {
                        lb = c;
                        lk = k;
                        lT = T;
                        linl = inl;
                    }
                    if (sectors) {
                        Best h;
                        h.score = c;
                        h.k = k;
                        h.inl = inl;
                        h.T = T;
                        Best& b = ls[sector_of(T)];
                        if (h.beats(b)) b = h;
                    }
                }
#pragma omp critical
                {
                    if (lb > best || (lb == best && lb >= 0 && lk < best_k)) {
                        best = lb;
                        best_k = lk;
                        best_T = lT;
                        best_inl = linl;
                    }
                    if (sectors)
                        for (int s = 0; s < kSectors; ++s)
                            if (ls[s].beats((*sectors)[s])) (*sectors)[s] = ls[s];
                }
            }
            done = end;
            if (best_inl > sample_) {
                const double w = static_cast<double>(best_inl) / M;
                const double denom = std::log(1 - std::pow(w, sample_));
                if (denom < 0)
                    needed = static_cast<int64_t>(std::ceil(std::log(1 - opt_.confidence) / denom));
                if (w >= 1) needed = done;
            }
        }
        iterations = done;
        best_score = best;
        return best >= 0;
    }

    /// Refit on the inliers (twice: the refit can gain inliers), kept when it explains the
    /// geometry at least as well.
    Eigen::Isometry3d refine(Eigen::Isometry3d T) const {
        for (int r = 0; r < 2; ++r) {
            std::vector<int> sel;
            for (size_t i = 0; i < m_.size(); ++i)
                if ((T * m_[i].p - m_[i].q).squaredNorm() < thr2_) sel.push_back(static_cast<int>(i));
            if (static_cast<int>(sel.size()) < sample_) break;
            const Eigen::Isometry3d T2 = fit(m_, sel, gravity_);
            if (agrees_with_prior(T2) && geometric_score(T2) >= geometric_score(T)) T = T2;
        }
        return T;
    }

private:
    /// Edge-length check on a pair of the sample; with gravity, heights must agree and the
    /// pair must span some horizontal distance.
    bool compatible(const Match& a, const Match& b) const {
        const double ds = (a.p - b.p).norm();
        const double dt = (a.q - b.q).norm();
        if (ds < opt_.edge_length_ratio * dt || dt < opt_.edge_length_ratio * ds) return false;
        if (!gravity_) return true;
        const double dzs = a.p.z() - b.p.z();
        const double dzt = a.q.z() - b.q.z();
        if (std::fabs(dzs - dzt) > 2 * opt_.inlier_distance) return false;
        return (a.p - b.p).head<2>().norm() >= 2 * opt_.inlier_distance;
    }

    const std::vector<Match>& m_;
    const GlobalOptions& opt_;
    Eigen::Matrix3d Ls_, Lt_;
    bool gravity_;
    int sample_;
    double thr2_, cos_tol_;
    KdTree<3> tgt_tree_;
    std::vector<Eigen::Vector3d> probe_;
};

/// Fitness and inlier RMSE of T on the full clouds (pairs within sqrt(thr2)).
void score_on_clouds(const PointsXYZ& src, const PointsXYZ& tgt, const Eigen::Isometry3d& T,
                     double thr2, int nt, GlobalResult& res) {
    const KdTree<3> tt(tgt.data(), tgt.rows(), 20, nt);
    int64_t inl = 0;
    double sq = 0;
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Eigen::Vector3f t = T.translation().cast<float>();
#pragma omp parallel for num_threads(nt) reduction(+ : inl, sq)
    for (int64_t i = 0; i < src.rows(); ++i) {
        const Eigen::Vector3f p = R * src.row(i).transpose() + t;
        float d;
        if (tt.nearest(p.data(), static_cast<float>(thr2), &d) >= 0) {
            ++inl;
            sq += d;
        }
    }
    res.fitness = static_cast<double>(inl) / src.rows();
    res.inlier_rmse = inl ? std::sqrt(sq / inl) : 0;
}
double yaw_of_levelled(const Eigen::Isometry3d& T) {
    return std::atan2(T.linear()(1, 0), T.linear()(0, 0));
}
}  // namespace

GlobalResult register_global(const PointsXYZ& source_in, const PointsXYZ& target_in,
                             const GlobalOptions& opt) {
    validate(opt);
    const int nt = threads(opt.num_threads);
    const bool gravity = opt.up_source.norm() > 0 && opt.up_target.norm() > 0;
    // 0. finite points only; 1. normals and FPFH
    const PointsXYZ src = finite_points(source_in, "source");
    const PointsXYZ tgt = finite_points(target_in, "target");
    const Described ds = describe(src, opt.viewpoint_source, opt, nt);
    const Described dt = describe(tgt, opt.viewpoint_target, opt, nt);
    // 2. feature matches, in frames levelled by gravity (if known)
    const Eigen::Matrix3d Ls = gravity ? level(opt.up_source) : Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d Lt = gravity ? level(opt.up_target) : Eigen::Matrix3d::Identity();
    const std::vector<Match> matches =
        match_features(src, tgt, ds, dt, Ls, Lt, opt.mutual_filter, nt);
    GlobalResult res;
    res.num_correspondences = static_cast<int64_t>(matches.size());
    const Ransac ransac(matches, src, tgt, Ls, Lt, gravity, opt);
    if (static_cast<int>(matches.size()) < ransac.sample()) {
        res.status = "no_correspondences";
        return res;
    }
    // 3. RANSAC; 4. refit on the inliers
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    std::vector<Ransac::Best> sectors;
    const bool twins = gravity && !opt.twin_turns.empty();
    int64_t score = 0;
    if (!ransac.run(T, res.iterations, score, nt, twins ? &sectors : nullptr)) {
        res.status = "no_consensus";
        return res;
    }
    T = ransac.refine(T);
    res.num_inlier_correspondences = ransac.count_inliers(T);
    res.geometric_score = ransac.geometric_score(T);
    // back from the levelled frames: T_target_source = Lt^T T Ls
    auto unlevel = [&](const Eigen::Isometry3d& A) {
        Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
        out.linear() = Lt.transpose() * A.linear() * Ls;
        out.translation() = Lt.transpose() * A.translation();
        return out;
    };
    const Eigen::Isometry3d out = unlevel(T);
    res.T_target_source = out.matrix();
    // 5. fitness on the full clouds
    const double thr2 = opt.inlier_distance * opt.inlier_distance;
    score_on_clouds(src, tgt, out, thr2, nt, res);
    // 6. twins: the best hypothesis of the sectors about each turn of the pose's yaw
    const double yaw0 = yaw_of_levelled(T);
    for (const double turn : opt.twin_turns) {
        const Ransac::Best* pick = nullptr;
        for (const Ransac::Best& b : sectors) {
            if (b.score < 0) continue;
            const double d = std::remainder(yaw_of_levelled(b.T) - yaw0 - turn, 2 * M_PI);
            if (std::fabs(d) > opt.twin_tolerance) continue;
            if (!pick || b.beats(*pick)) pick = &b;
        }
        if (!pick) continue;
        const Eigen::Isometry3d T2 = ransac.refine(pick->T);
        GlobalTwin tw;
        tw.turn = turn;
        tw.num_inlier_correspondences = ransac.count_inliers(T2);
        tw.geometric_score = ransac.geometric_score(T2);
        const Eigen::Isometry3d out2 = unlevel(T2);
        tw.T_target_source = out2.matrix();
        GlobalResult tmp;
        score_on_clouds(src, tgt, out2, thr2, nt, tmp);
        tw.fitness = tmp.fitness;
        tw.inlier_rmse = tmp.inlier_rmse;
        res.twins.push_back(tw);
    }
    res.success = true;
    res.status = "success";
    return res;
}

}  // namespace tripod
