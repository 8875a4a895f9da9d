// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/deskew.hpp"

#include <omp.h>

#include <algorithm>
#include <stdexcept>

namespace tripod {

namespace {
// Index i with t[i] <= t < t[i+1], clamped to [0, n-2].
inline size_t segment(const std::vector<int64_t>& t, int64_t x) {
    auto it = std::upper_bound(t.begin(), t.end(), x);
    size_t i = it == t.begin() ? 0 : static_cast<size_t>(it - t.begin()) - 1;
    return std::min(i, t.size() - 2);
}
}  // namespace

Eigen::Quaterniond orientation_at(const OrientationTrack& track, int64_t t_ns) {
    const auto& t = track.t_ns;
    if (t.size() < 2) throw std::invalid_argument("orientation track needs at least 2 samples");
    const size_t i = segment(t, t_ns);
    const double dt = static_cast<double>(t[i + 1] - t[i]);
    double u = static_cast<double>(t_ns - t[i]) / std::max(dt, 1.0);
    u = std::clamp(u, 0.0, 1.0);
    // Eigen's slerp takes the short way (it flips the sign of a negative dot product)
    return track.q_world_imu[i].slerp(u, track.q_world_imu[i + 1]).normalized();
}

PointsXYZ place_points(const PointsXYZ& points, const std::vector<int64_t>& t_ns,
                       const OrientationTrack& track, const Eigen::Matrix3d& R_imu_lidar,
                       const Eigen::Vector3d& lever_arm, int64_t anchor_ns, int num_threads) {
    const int64_t n = points.rows();
    if (static_cast<int64_t>(t_ns.size()) != n)
        throw std::invalid_argument("points and times differ in length");
    if (track.t_ns.size() < 2 || track.t_ns.size() != track.q_world_imu.size())
        throw std::invalid_argument("orientation track needs at least 2 samples");
    if (num_threads <= 0) num_threads = omp_get_max_threads();

    const Eigen::Matrix3d R_wi_a = orientation_at(track, anchor_ns).toRotationMatrix();
    const Eigen::Matrix3d R_wl_a_T = (R_wi_a * R_imu_lidar).transpose();
    const Eigen::Vector3d p_a = R_wi_a * lever_arm;

    PointsXYZ out(n, 3);
#pragma omp parallel num_threads(num_threads)
    {
        // points come in firing order: reuse the rotation while the time does not change
        int64_t last_t = INT64_MIN;
        Eigen::Matrix3d M;  // R_wl(a)^T R_wi(t)
#pragma omp for schedule(static)
        for (int64_t k = 0; k < n; ++k) {
            if (t_ns[k] != last_t) {
                M = R_wl_a_T * orientation_at(track, t_ns[k]).toRotationMatrix();
                last_t = t_ns[k];
            }
            const Eigen::Vector3d x = points.row(k).cast<double>().transpose();
            const Eigen::Vector3d y = M * (R_imu_lidar * x + lever_arm) - R_wl_a_T * p_a;
            out.row(k) = y.cast<float>().transpose();
        }
    }
    return out;
}

}  // namespace tripod
