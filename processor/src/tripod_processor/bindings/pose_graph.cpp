// SPDX-License-Identifier: BSD-3-Clause
// Bindings: pose-graph optimisation (tripod_core/pose_graph.hpp). Conversions and docstrings
// only. Python owner: tripod_processor.registration.pose_graph.
#include <nanobind/stl/string.h>

#include "common.hpp"
#include "tripod_core/pose_graph.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {
using PosesIn = nb::ndarray<const double, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu>;
using InfoIn = nb::ndarray<const double, nb::shape<-1, 6, 6>, nb::c_contig, nb::device::cpu>;
using PairsIn = nb::ndarray<const int64_t, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using FlagsIn = nb::ndarray<const bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using IdxIn = nb::ndarray<const int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Vec3In = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
using VecIn = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

tripod::Pose3d pose_from(const double* m) {
    Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(m);
    tripod::Pose3d out;
    out.p = T.block<3, 1>(0, 3);
    out.q = Eigen::Quaterniond(Eigen::Matrix3d(T.block<3, 3>(0, 0))).normalized();
    return out;
}

std::vector<tripod::PoseGraphEdge> edges_from(PairsIn edge_nodes, PosesIn T_from_to,
                                              InfoIn information, FlagsIn is_loop) {
    const size_t m = edge_nodes.shape(0);
    if (T_from_to.shape(0) != m || information.shape(0) != m || is_loop.shape(0) != m)
        throw std::invalid_argument("edge arrays differ in length");
    std::vector<tripod::PoseGraphEdge> edges(m);
    for (size_t k = 0; k < m; ++k) {
        edges[k].from = static_cast<int>(edge_nodes.data()[2 * k]);
        edges[k].to = static_cast<int>(edge_nodes.data()[2 * k + 1]);
        edges[k].T_from_to = pose_from(T_from_to.data() + 16 * k);
        edges[k].information = Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(
            information.data() + 36 * k);
        edges[k].is_loop = is_loop.data()[k];
    }
    return edges;
}

std::vector<tripod::GravityPrior> gravity_from(IdxIn nodes, Vec3In up, VecIn sigma) {
    if (up.shape(0) != nodes.shape(0) || sigma.shape(0) != nodes.shape(0))
        throw std::invalid_argument("gravity arrays differ in length");
    std::vector<tripod::GravityPrior> gravity(nodes.shape(0));
    for (size_t k = 0; k < gravity.size(); ++k) {
        gravity[k].node = static_cast<int>(nodes.data()[k]);
        gravity[k].up_in_node = Eigen::Map<const Eigen::Vector3d>(up.data() + 3 * k);
        gravity[k].sigma_rad = sigma.data()[k];
    }
    return gravity;
}

/// (n, 4, 4) float64 T_world_node of the result.
nb::ndarray<nb::numpy, double, nb::shape<-1, 4, 4>> poses_array(
    const tripod::PoseGraphResult& r) {
    const size_t n = r.poses.size();
    std::vector<double> out(16 * n);
    for (size_t i = 0; i < n; ++i) {
        Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(out.data() + 16 * i);
        T.setIdentity();
        T.block<3, 3>(0, 0) = r.poses[i].q.toRotationMatrix();
        T.block<3, 1>(0, 3) = r.poses[i].p;
    }
    return owned_array<nb::shape<-1, 4, 4>>(std::move(out), {n, 4, 4});
}
}  // namespace

TRIPOD_BINDING(pose_graph) {
    using Opt = tripod::PoseGraphOptions;
    nb::class_<Opt>(m, "_PoseGraphOptions", "Settings of optimize_pose_graph")
        .def(nb::init<>())
        .def_rw("loss", &Opt::loss, "none, huber, cauchy or soft_l1 (loop edges)")
        .def_rw("loss_scale", &Opt::loss_scale, "robust kernel scale [sigmas]")
        .def_rw("robust_odometry", &Opt::robust_odometry, "odometry edges robust too")
        .def_rw("max_iterations", &Opt::max_iterations)
        .def_rw("num_threads", &Opt::num_threads, "0 = all cores")
        .def_rw("fixed_node", &Opt::fixed_node, "node held constant (-1: none)")
        .def_rw("outlier_chi2", &Opt::outlier_chi2, "reject loop edges above this chi2")
        .def_rw("max_rejection_rounds", &Opt::max_rejection_rounds)
        .def_rw("reject_odometry", &Opt::reject_odometry,
                "odometry edges rejectable when the graph stays connected");

    using Res = tripod::PoseGraphResult;
    nb::class_<Res>(m, "_PoseGraphResult", "What optimize_pose_graph found")
        .def_prop_ro("T_world_node", &poses_array, "(n, 4, 4) float64 optimised poses", nb::rv_policy::reference)
        .def_prop_ro(
            "edge_chi2",
            [](const Res& r) { return owned_array(std::vector<double>(r.edge_chi2)); },
            "(m,) float64 whitened squared error of each edge", nb::rv_policy::reference)
        .def_prop_ro(
            "edge_inlier",
            [](const Res& r) {
                return owned_array(
                    std::vector<uint8_t>(r.edge_inlier.begin(), r.edge_inlier.end()));
            },
            "(m,) uint8: 0 for rejected edges", nb::rv_policy::reference)
        .def_ro("initial_cost", &Res::initial_cost)
        .def_ro("final_cost", &Res::final_cost)
        .def_ro("iterations", &Res::iterations, "summed over all solves")
        .def_ro("rejected", &Res::rejected, "rejected edges")
        .def_ro("converged", &Res::converged)
        .def_ro("message", &Res::message, "Ceres' termination message of the last solve");

    m.def(
        "optimize_pose_graph",
        [](PosesIn T_world_node, PairsIn edge_nodes, PosesIn T_from_to, InfoIn information,
           FlagsIn is_loop, IdxIn gravity_nodes, Vec3In gravity_up, VecIn gravity_sigma,
           const Opt& options) {
            std::vector<tripod::Pose3d> initial(T_world_node.shape(0));
            for (size_t i = 0; i < initial.size(); ++i)
                initial[i] = pose_from(T_world_node.data() + 16 * i);
            const auto edges = edges_from(edge_nodes, T_from_to, information, is_loop);
            const auto gravity = gravity_from(gravity_nodes, gravity_up, gravity_sigma);
            nb::gil_scoped_release release;
            return tripod::optimize_pose_graph(initial, edges, gravity, options);
        },
        nb::arg("T_world_node"), nb::arg("edge_nodes"), nb::arg("T_from_to"),
        nb::arg("information"), nb::arg("is_loop"), nb::arg("gravity_nodes"),
        nb::arg("gravity_up"), nb::arg("gravity_sigma"), nb::arg("options"),
        "Pose-graph optimisation in Ceres (private: use "
        "tripod_processor.registration.pose_graph).");
}
