// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/placement.hpp"

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

    // R_wl(a)^T R_wi(t) is evaluated exactly on a grid of kStepNs and interpolated linearly in
    // between. Inside one IMU interval the slerp turns at a constant rate about a fixed axis, so
    // the blend's error is (omega kStepNs)^2 / 8 (1e-9 rad at 1 rad/s); a grid cell that holds
    // an IMU sample (a kink of the path) is evaluated exactly at each point's time.
    constexpr int64_t kStepNs = 100'000;
    const auto& ts = track.t_ns;
    const auto rotation_at = [&](int64_t t) -> Eigen::Matrix3d {
        return R_wl_a_T * orientation_at(track, t).toRotationMatrix();
    };
    const auto grid_index = [&](int64_t t) -> int64_t {  // floor((t - anchor) / step)
        const int64_t d = t - anchor_ns;
        return d >= 0 ? d / kStepNs : -((-d + kStepNs - 1) / kStepNs);
    };
    const Eigen::Vector3d shift = R_wl_a_T * p_a;

    PointsXYZ out(n, 3);
#pragma omp parallel num_threads(num_threads)
    {
        // points come in firing order: the grid cell changes every few dozen points
        int64_t cell = INT64_MIN;
        bool smooth = false;
        Eigen::Matrix3d M0, dM;
        int64_t last_t = INT64_MIN;
        Eigen::Matrix3d M;
#pragma omp for schedule(static)
        for (int64_t k = 0; k < n; ++k) {
            const int64_t t = t_ns[k];
            const int64_t g = grid_index(t);
            if (g != cell) {
                cell = g;
                const int64_t t0 = anchor_ns + g * kStepNs, t1 = t0 + kStepNs;
                const size_t i0 = segment(ts, t0);
                smooth = ts[i0] <= t0 && t1 <= ts[i0 + 1];
                if (smooth) {
                    M0 = rotation_at(t0);
                    dM = rotation_at(t1) - M0;
                }
                last_t = INT64_MIN;
            }
            if (smooth) {
                M = M0 + (static_cast<double>(t - anchor_ns - g * kStepNs) /
                          static_cast<double>(kStepNs)) * dM;
            } else if (t != last_t) {
                M = rotation_at(t);
                last_t = t;
            }
            const Eigen::Vector3d x = points.row(k).cast<double>().transpose();
            const Eigen::Vector3d y = M * (R_imu_lidar * x + lever_arm) - shift;
            out.row(k) = y.cast<float>().transpose();
        }
    }
    return out;
}

}  // namespace tripod
