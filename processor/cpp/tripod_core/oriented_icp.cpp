// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/oriented_icp.hpp"

#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <vector>

namespace tripod {

namespace {
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

struct Sums {
    Mat6 H = Mat6::Zero();
    Vec6 g = Vec6::Zero();
    double sq = 0;
    int64_t count = 0;
};
}  // namespace

OrientedIcpResult oriented_point_to_plane(const PreparedCloud& source, const PreparedCloud& target,
                                          const Eigen::Matrix4d& T_init,
                                          const OrientedIcpOptions& opt) {
    OrientedIcpResult res;
    res.T_target_source = T_init;
    const int nt = opt.num_threads > 0 ? opt.num_threads : omp_get_max_threads();
    // source points with a valid normal, at most max_source of them (an even stride)
    std::vector<int64_t> valid;
    valid.reserve(source.points.rows());
    for (int64_t i = 0; i < source.points.rows(); ++i)
        if (source.normal_valid[i]) valid.push_back(i);
    std::vector<int64_t> use;
    const int64_t nv = static_cast<int64_t>(valid.size());
    if (opt.max_source > 0 && nv > opt.max_source) {
        use.resize(opt.max_source);
        for (int64_t k = 0; k < opt.max_source; ++k) use[k] = valid[(k * nv) / opt.max_source];
    } else {
        use.swap(valid);
    }
    const int64_t n = static_cast<int64_t>(use.size());
    if (n == 0 || !target.tree) return res;
    const float max_sq = static_cast<float>(opt.max_distance * opt.max_distance);
    const double huber = 2.0 * opt.point_sigma;
    Eigen::Matrix4d T = T_init;
    std::vector<Sums> part(nt);
    for (int it = 0; it < opt.iterations; ++it) {
        const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
        const Eigen::Vector3d t = T.topRightCorner<3, 1>();
        for (auto& p : part) p = Sums();
#pragma omp parallel num_threads(nt)
        {
            Sums& s = part[omp_get_thread_num()];
#pragma omp for schedule(static)
            for (int64_t k = 0; k < n; ++k) {
                const int64_t i = use[k];
                const Eigen::Vector3d p = R * source.points.row(i).transpose().cast<double>() + t;
                const float pf[3] = {static_cast<float>(p[0]), static_cast<float>(p[1]),
                                     static_cast<float>(p[2])};
                float d2 = 0;
                const int j = target.tree->nearest(pf, max_sq, &d2);
                if (j < 0 || !target.normal_valid[j]) continue;
                const Eigen::Vector3d nq = target.normals.row(j).transpose();
                const Eigen::Vector3d ns = R * source.normals.row(i).transpose();
                if (!(ns.dot(nq) > opt.min_normal_dot)) continue;
                const Eigen::Vector3d q = target.points.row(j).transpose().cast<double>();
                const double r = nq.dot(p - q);
                const double w = std::min(1.0, huber / std::max(std::abs(r), 1e-9));
                Vec6 J;
                J.head<3>() = nq;
                J.tail<3>() = p.cross(nq);
                s.H.selfadjointView<Eigen::Lower>().rankUpdate(J, w);
                s.g += w * r * J;
                s.sq += r * r;
                ++s.count;
            }
        }
        Sums tot;  // combined in thread order: deterministic for a given thread count
        for (const auto& p : part) {
            tot.H += p.H;
            tot.g += p.g;
            tot.sq += p.sq;
            tot.count += p.count;
        }
        if (tot.count < 100) break;
        const Mat6 H = tot.H.selfadjointView<Eigen::Lower>();
        const Vec6 delta = -(H + 1e-9 * Mat6::Identity()).ldlt().solve(tot.g);
        if (!delta.allFinite()) break;
        Eigen::Matrix4d D = Eigen::Matrix4d::Identity();
        const double ang = delta.tail<3>().norm();
        if (ang > 0)
            D.topLeftCorner<3, 3>() =
                Eigen::AngleAxisd(ang, delta.tail<3>() / ang).toRotationMatrix();
        D.topRightCorner<3, 1>() = delta.head<3>();
        T = D * T;
        res.H = H;
        res.fitness = static_cast<double>(tot.count) / static_cast<double>(n);
        res.rmse = std::sqrt(tot.sq / static_cast<double>(tot.count));
        res.iterations = it + 1;
        res.linearized = true;
        if (delta.head<3>().norm() < 1e-5 && ang < 1e-6) break;
    }
    res.T_target_source = T;
    return res;
}

}  // namespace tripod
