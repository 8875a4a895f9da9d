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
}  // namespace

GlobalResult register_global(const PointsXYZ& source_in, const PointsXYZ& target_in,
                             const GlobalOptions& opt) {
    if (!(opt.normal_radius > 0) || !(opt.feature_radius > 0) || !(opt.inlier_distance > 0))
        throw std::invalid_argument("normal_radius, feature_radius and inlier_distance must be > 0");
    if (opt.max_iterations < 1) throw std::invalid_argument("max_iterations must be >= 1");
    if (!(opt.confidence > 0 && opt.confidence < 1))
        throw std::invalid_argument("confidence must be in (0, 1)");
    const bool gravity = opt.up_source.norm() > 0 && opt.up_target.norm() > 0;
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
    const int nt = threads(opt.num_threads);

    // 0. finite points only
    auto finite = [](const PointsXYZ& in, const char* name) {
        const std::vector<int64_t> rows = finite_rows(in);
        if (rows.size() < 3)
            throw std::invalid_argument(std::string(name) + " has " + std::to_string(rows.size()) +
                                        " finite points; global registration needs at least 3");
        PointsXYZ out(static_cast<Eigen::Index>(rows.size()), 3);
        for (size_t i = 0; i < rows.size(); ++i) out.row(i) = in.row(rows[i]);
        return out;
    };
    const PointsXYZ src = finite(source_in, "source"), tgt = finite(target_in, "target");

    // 1. normals and FPFH
    const Neighborhood nb{opt.max_neighbors > 0 ? std::min(opt.max_neighbors, 30) : 30,
                          opt.normal_radius};
    const LocalGeometry gs = estimate_local_geometry(src, nb, opt.viewpoint_source, nt);
    const LocalGeometry gt = estimate_local_geometry(tgt, nb, opt.viewpoint_target, nt);
    const MatrixX33f fs = compute_fpfh(src, gs.normals, opt.feature_radius, opt.max_neighbors, nt);
    const MatrixX33f ft = compute_fpfh(tgt, gt.normals, opt.feature_radius, opt.max_neighbors, nt);

    // 2. nearest features (source -> target, and back for the mutual filter); points without a
    //    feature (no normal or empty histogram) are not matched
    auto has_feature = [](const LocalGeometry& g, const MatrixX33f& f, int64_t i) {
        return g.valid[i] && f.row(i).sum() > 0;
    };
    std::vector<int> tmap;  // rows of tgt with a feature
    for (int64_t j = 0; j < tgt.rows(); ++j)
        if (has_feature(gt, ft, j)) tmap.push_back(static_cast<int>(j));
    std::vector<int> smap;
    for (int64_t i = 0; i < src.rows(); ++i)
        if (has_feature(gs, fs, i)) smap.push_back(static_cast<int>(i));
    GlobalResult res;
    if (tmap.size() < 3 || smap.size() < 3) {
        res.status = "no_correspondences";
        return res;
    }
    MatrixX33f ftc(tmap.size(), 33), fsc(smap.size(), 33);
    for (size_t j = 0; j < tmap.size(); ++j) ftc.row(j) = ft.row(tmap[j]);
    for (size_t i = 0; i < smap.size(); ++i) fsc.row(i) = fs.row(smap[i]);
    const KdTree<33> ttree(ftc.data(), ftc.rows());
    std::vector<int> s2t(smap.size(), -1);
#pragma omp parallel for num_threads(nt) schedule(static)
    for (int64_t i = 0; i < static_cast<int64_t>(smap.size()); ++i) {
        float d;
        s2t[i] = ttree.nearest(fsc.row(i).data(), std::numeric_limits<float>::infinity(), &d);
    }
    std::vector<int> t2s;
    if (opt.mutual_filter) {
        const KdTree<33> stree(fsc.data(), fsc.rows());
        t2s.assign(tmap.size(), -1);
#pragma omp parallel for num_threads(nt) schedule(static)
        for (int64_t j = 0; j < static_cast<int64_t>(tmap.size()); ++j) {
            float d;
            t2s[j] = stree.nearest(ftc.row(j).data(), std::numeric_limits<float>::infinity(), &d);
        }
    }
    const Eigen::Matrix3d Ls = gravity ? level(opt.up_source) : Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d Lt = gravity ? level(opt.up_target) : Eigen::Matrix3d::Identity();
    std::vector<Match> matches;
    for (size_t i = 0; i < smap.size(); ++i) {
        const int j = s2t[i];
        if (j < 0) continue;
        if (opt.mutual_filter && t2s[j] != static_cast<int>(i)) continue;
        matches.push_back({Ls * src.row(smap[i]).transpose().cast<double>(),
                           Lt * tgt.row(tmap[j]).transpose().cast<double>()});
    }
    // too few mutual matches: fall back to one-way matches (Open3D does the same)
    if (opt.mutual_filter && matches.size() < 10) {
        matches.clear();
        for (size_t i = 0; i < smap.size(); ++i)
            if (s2t[i] >= 0)
                matches.push_back({Ls * src.row(smap[i]).transpose().cast<double>(),
                                   Lt * tgt.row(tmap[s2t[i]]).transpose().cast<double>()});
    }
    res.num_correspondences = static_cast<int64_t>(matches.size());
    const int sample = gravity ? 2 : 3;
    if (static_cast<int>(matches.size()) < sample) {
        res.status = "no_correspondences";
        return res;
    }

    // 3. RANSAC; hypothesis k draws from its own stream (seed, k): thread-count independent
    const int64_t M = static_cast<int64_t>(matches.size());
    const double thr2 = opt.inlier_distance * opt.inlier_distance;
    auto count_inliers = [&](const Eigen::Isometry3d& T) {
        int64_t c = 0;
        for (const Match& m : matches) c += (T * m.p - m.q).squaredNorm() < thr2;
        return c;
    };
    // rotation prior, compared in the original frames: R = Lt^T R_levelled Ls
    const double cos_tol = std::cos(std::min(opt.rotation_tolerance, M_PI));
    auto agrees_with_prior = [&](const Eigen::Isometry3d& T) {
        if (!opt.has_rotation_prior) return true;
        const Eigen::Matrix3d R = Lt.transpose() * T.linear() * Ls;
        return ((R * opt.R_prior.transpose()).trace() - 1) / 2 >= cos_tol;
    };
    auto hypothesis = [&](int64_t k, Eigen::Isometry3d& T) -> bool {
        uint64_t state = splitmix(opt.seed * 0x100000001b3ULL + static_cast<uint64_t>(k));
        int idx[3];
        for (int s = 0; s < sample; ++s) {
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
        // edge-length check on every pair of the sample
        for (int a = 0; a < sample; ++a)
            for (int b = a + 1; b < sample; ++b) {
                const double ds = (matches[idx[a]].p - matches[idx[b]].p).norm();
                const double dt = (matches[idx[a]].q - matches[idx[b]].q).norm();
                if (ds < opt.edge_length_ratio * dt || dt < opt.edge_length_ratio * ds) return false;
                if (gravity) {
                    // heights must agree, and the pair must span some horizontal distance
                    const double dzs = matches[idx[a]].p.z() - matches[idx[b]].p.z();
                    const double dzt = matches[idx[a]].q.z() - matches[idx[b]].q.z();
                    if (std::fabs(dzs - dzt) > 2 * opt.inlier_distance) return false;
                    if ((matches[idx[a]].p - matches[idx[b]].p).head<2>().norm() <
                        2 * opt.inlier_distance)
                        return false;
                }
            }
        std::vector<int> sel(idx, idx + sample);
        T = fit(matches, sel, gravity);
        return agrees_with_prior(T);
    };
    // Hypotheses that agree with more than the minimal sample are scored on the clouds
    // themselves (source points, at most 2000, with a target point within the inlier distance),
    // as Open3D does: sparse or repetitive scenes give few feature inliers, but the right pose
    // explains the geometry.
    const KdTree<3> tgt_tree(tgt.data(), tgt.rows());
    std::vector<Eigen::Vector3d> probe;
    {
        const int64_t step = std::max<int64_t>(1, src.rows() / 2000);
        for (int64_t i = 0; i < src.rows(); i += step)
            probe.push_back(Ls * src.row(i).transpose().cast<double>());
    }
    const Eigen::Matrix3d LtT = Lt.transpose();
    auto geometric_score = [&](const Eigen::Isometry3d& T) {
        int64_t c = 0;
        for (const Eigen::Vector3d& p : probe) {
            const Eigen::Vector3f x = (LtT * (T * p)).cast<float>();
            float d;
            c += tgt_tree.nearest(x.data(), static_cast<float>(thr2), &d) >= 0;
        }
        return c;
    };
    int64_t best = -1, best_k = -1, best_inl = 0;
    Eigen::Isometry3d best_T = Eigen::Isometry3d::Identity();
    int64_t needed = opt.max_iterations;
    int64_t done = 0;
    const int64_t batch = 1024;
    while (done < std::min(needed, opt.max_iterations)) {
        const int64_t end = std::min({done + batch, opt.max_iterations});
#pragma omp parallel num_threads(nt)
        {
            int64_t lb = -1, lk = -1, linl = 0;
            Eigen::Isometry3d lT = Eigen::Isometry3d::Identity();
#pragma omp for schedule(static)
            for (int64_t k = done; k < end; ++k) {
                Eigen::Isometry3d T;
                if (!hypothesis(k, T)) continue;
                const int64_t inl = count_inliers(T);
                if (inl <= sample) continue;
                const int64_t c = geometric_score(T);
                if (c > lb || (c == lb && k < lk)) {
                    lb = c;
                    lk = k;
                    lT = T;
                    linl = inl;
                }
            }
#pragma omp critical
            if (lb > best || (lb == best && lb >= 0 && lk < best_k)) {
                best = lb;
                best_k = lk;
                best_T = lT;
                best_inl = linl;
            }
        }
        done = end;
        if (best_inl > sample) {
            const double w = static_cast<double>(best_inl) / M;
            const double denom = std::log(1 - std::pow(w, sample));
            if (denom < 0)
                needed = static_cast<int64_t>(std::ceil(std::log(1 - opt.confidence) / denom));
            if (w >= 1) needed = done;
        }
    }
    res.iterations = done;
    if (best < 0) {
        res.status = "no_consensus";
        return res;
    }
    // 4. refit on the inliers (twice: the refit can gain inliers), kept if it explains the
    //    geometry at least as well
    Eigen::Isometry3d T = best_T;
    for (int r = 0; r < 2; ++r) {
        std::vector<int> sel;
        for (int64_t i = 0; i < M; ++i)
            if ((T * matches[i].p - matches[i].q).squaredNorm() < thr2) sel.push_back(static_cast<int>(i));
        if (static_cast<int>(sel.size()) < sample) break;
        const Eigen::Isometry3d T2 = fit(matches, sel, gravity);
        if (agrees_with_prior(T2) && geometric_score(T2) >= geometric_score(T)) T = T2;
    }
    res.num_inlier_correspondences = count_inliers(T);
    // back from the levelled frames: T_target_source = Lt^T T Ls
    Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
    out.linear() = Lt.transpose() * T.linear() * Ls;
    out.translation() = Lt.transpose() * T.translation();
    res.T_target_source = out.matrix();
    // 5. fitness on the full clouds
    const KdTree<3> tt(tgt.data(), tgt.rows());
    int64_t inl = 0;
    double sq = 0;
    const Eigen::Matrix3f R = out.linear().cast<float>();
    const Eigen::Vector3f t = out.translation().cast<float>();
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
    res.success = true;
    res.status = "success";
    return res;
}

}  // namespace tripod
