// SPDX-License-Identifier: BSD-3-Clause
// Bindings: pose-graph optimisation. Conversions and docstrings only.
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

template <typename T>
nb::ndarray<nb::numpy, T> owned(std::vector<T>&& v, std::initializer_list<size_t> shape) {
    auto* heap = new std::vector<T>(std::move(v));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(heap->data(), shape, owner);
}
}  // namespace

TRIPOD_BINDING(pose_graph) {
    m.def(
        "optimize_pose_graph",
        [](PosesIn T_world_node, PairsIn edge_nodes, PosesIn T_from_to, InfoIn information,
           FlagsIn is_loop, IdxIn gravity_nodes, Vec3In gravity_up, VecIn gravity_sigma,
           const std::string& loss, double loss_scale, bool robust_odometry, int max_iterations,
           int num_threads, int fixed_node, double outlier_chi2, int max_rejection_rounds,
           bool reject_odometry) {
            const size_t n = T_world_node.shape(0), m_edges = edge_nodes.shape(0);
            if (T_from_to.shape(0) != m_edges || information.shape(0) != m_edges ||
                is_loop.shape(0) != m_edges)
                throw std::invalid_argument("edge arrays differ in length");
            if (gravity_up.shape(0) != gravity_nodes.shape(0) ||
                gravity_sigma.shape(0) != gravity_nodes.shape(0))
                throw std::invalid_argument("gravity arrays differ in length");
            std::vector<tripod::Pose3d> initial(n);
            for (size_t i = 0; i < n; ++i) initial[i] = pose_from(T_world_node.data() + 16 * i);
            std::vector<tripod::PoseGraphEdge> edges(m_edges);
            for (size_t k = 0; k < m_edges; ++k) {
                edges[k].from = static_cast<int>(edge_nodes.data()[2 * k]);
                edges[k].to = static_cast<int>(edge_nodes.data()[2 * k + 1]);
                edges[k].T_from_to = pose_from(T_from_to.data() + 16 * k);
                edges[k].information =
                    Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(
                        information.data() + 36 * k);
                edges[k].is_loop = is_loop.data()[k];
            }
            std::vector<tripod::GravityPrior> gravity(gravity_nodes.shape(0));
            for (size_t k = 0; k < gravity.size(); ++k) {
                gravity[k].node = static_cast<int>(gravity_nodes.data()[k]);
                gravity[k].up_in_node = Eigen::Map<const Eigen::Vector3d>(gravity_up.data() + 3 * k);
                gravity[k].sigma_rad = gravity_sigma.data()[k];
            }
            tripod::PoseGraphOptions opt;
            opt.loss = loss;
            opt.loss_scale = loss_scale;
            opt.robust_odometry = robust_odometry;
            opt.max_iterations = max_iterations;
            opt.num_threads = num_threads;
            opt.fixed_node = fixed_node;
            opt.outlier_chi2 = outlier_chi2;
            opt.max_rejection_rounds = max_rejection_rounds;
            opt.reject_odometry = reject_odometry;

            tripod::PoseGraphResult res;
            {
                nb::gil_scoped_release release;
                res = tripod::optimize_pose_graph(initial, edges, gravity, opt);
            }
            std::vector<double> poses(16 * n);
            for (size_t i = 0; i < n; ++i) {
                Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(poses.data() + 16 * i);
                T.setIdentity();
                T.block<3, 3>(0, 0) = res.poses[i].q.toRotationMatrix();
                T.block<3, 1>(0, 3) = res.poses[i].p;
            }
            std::vector<uint8_t> inlier(res.edge_inlier.begin(), res.edge_inlier.end());
            nb::dict out;
            out["T_world_node"] = owned(std::move(poses), {n, 4, 4});
            out["edge_chi2"] = owned(std::move(res.edge_chi2), {m_edges});
            out["edge_inlier"] = owned(std::move(inlier), {m_edges});
            out["initial_cost"] = res.initial_cost;
            out["final_cost"] = res.final_cost;
            out["iterations"] = res.iterations;
            out["rejected"] = res.rejected;
            out["converged"] = res.converged;
            out["message"] = res.message;
            return out;
        },
        nb::arg("T_world_node"), nb::arg("edge_nodes"), nb::arg("T_from_to"),
        nb::arg("information"), nb::arg("is_loop"), nb::arg("gravity_nodes"),
        nb::arg("gravity_up"), nb::arg("gravity_sigma"), nb::arg("loss"), nb::arg("loss_scale"),
        nb::arg("robust_odometry"), nb::arg("max_iterations"), nb::arg("num_threads"),
        nb::arg("fixed_node"), nb::arg("outlier_chi2"), nb::arg("max_rejection_rounds"),
        nb::arg("reject_odometry"),
        "Pose-graph optimisation in Ceres (private: use tripod_processor.pose_graph).");
}
