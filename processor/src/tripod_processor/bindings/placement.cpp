// SPDX-License-Identifier: BSD-3-Clause
// Bindings: IMU placement of lidar points, "de-skew" (tripod_core/placement.hpp). Conversions
// and docstrings only. Python owner: tripod_processor.reconstruction.placement.
#include "common.hpp"
#include "tripod_core/placement.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

TRIPOD_BINDING(placement) {
    m.def(
        "place_points",
        [](CloudIn points, nb::ndarray<const int64_t, nb::shape<-1>, nb::c_contig> t_ns,
           nb::ndarray<const int64_t, nb::shape<-1>, nb::c_contig> imu_t_ns,
           nb::ndarray<const double, nb::shape<-1, 4>, nb::c_contig> imu_q_wxyz,
           nb::ndarray<const double, nb::shape<3, 3>, nb::c_contig> R_imu_lidar,
           nb::ndarray<const double, nb::shape<3>, nb::c_contig> lever_arm, int64_t anchor_ns,
           int num_threads) {
            if (t_ns.shape(0) != points.shape(0))
                throw std::invalid_argument("points and times differ in length");
            if (imu_q_wxyz.shape(0) != imu_t_ns.shape(0))
                throw std::invalid_argument("IMU times and quaternions differ in length");
            tripod::PointsXYZ in = to_eigen(points);
            std::vector<int64_t> t(t_ns.data(), t_ns.data() + t_ns.shape(0));
            tripod::OrientationTrack track;
            track.t_ns.assign(imu_t_ns.data(), imu_t_ns.data() + imu_t_ns.shape(0));
            track.q_world_imu.reserve(track.t_ns.size());
            for (size_t k = 0; k < track.t_ns.size(); ++k) {
                const double* q = imu_q_wxyz.data() + 4 * k;
                track.q_world_imu.emplace_back(q[0], q[1], q[2], q[3]);
                track.q_world_imu.back().normalize();
            }
            Eigen::Matrix3d R = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(
                R_imu_lidar.data());
            Eigen::Vector3d l(lever_arm.data()[0], lever_arm.data()[1], lever_arm.data()[2]);
            tripod::PointsXYZ out;
            {
                nb::gil_scoped_release release;
                out = tripod::place_points(in, t, track, R, l, anchor_ns, num_threads);
            }
            return to_numpy(std::move(out));
        },
        nb::arg("points"), nb::arg("t_ns"), nb::arg("imu_t_ns"), nb::arg("imu_q_wxyz"),
        nb::arg("R_imu_lidar"), nb::arg("lever_arm"), nb::arg("anchor_ns"),
        nb::arg("num_threads") = 0,
        "De-skew points into the lidar frame at anchor_ns (private: see "
        "tripod_processor.reconstruction.placement.place_points).");
}
