// SPDX-License-Identifier: BSD-3-Clause
// Bindings: local and global registration, their option and result structs as classes.
// Conversions and docstrings only; the public API with full documentation is
// tripod_processor.registration.
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <optional>

#include "common.hpp"
#include "tripod_core/global_registration.hpp"
#include "tripod_core/registration.hpp"

namespace nb = nanobind;
using namespace tripod_bind;
using nb::literals::operator""_a;

namespace {
tripod::Method parse_method(const std::string& s) {
    if (s == "icp" || s == "point_to_point") return tripod::Method::kPointToPoint;
    if (s == "plane" || s == "point_to_plane") return tripod::Method::kPointToPlane;
    if (s == "gicp") return tripod::Method::kGICP;
    if (s == "symmetric") return tripod::Method::kSymmetric;
    if (s == "lm") return tripod::Method::kLM;
    if (s == "vgicp") return tripod::Method::kVGICP;
    throw std::invalid_argument("unknown method '" + s +
                                "' (icp, plane, gicp, vgicp, symmetric, lm)");
}
std::string method_name(tripod::Method m) {
    switch (m) {
        case tripod::Method::kPointToPoint: return "icp";
        case tripod::Method::kPointToPlane: return "plane";
        case tripod::Method::kGICP: return "gicp";
        case tripod::Method::kVGICP: return "vgicp";
        case tripod::Method::kSymmetric: return "symmetric";
        case tripod::Method::kLM: return "lm";
    }
    return "?";
}
std::string loss_name(tripod::Loss l) {
    switch (l) {
        case tripod::Loss::kNone: return "none";
        case tripod::Loss::kHuber: return "huber";
        case tripod::Loss::kCauchy: return "cauchy";
        case tripod::Loss::kTukey: return "tukey";
    }
    return "?";
}
tripod::Loss parse_loss(const std::string& s) {
    if (s == "none") return tripod::Loss::kNone;
    if (s == "huber") return tripod::Loss::kHuber;
    if (s == "cauchy") return tripod::Loss::kCauchy;
    if (s == "tukey") return tripod::Loss::kTukey;
    throw std::invalid_argument("unknown loss '" + s + "' (none, huber, cauchy, tukey)");
}
}  // namespace

TRIPOD_BINDING(registration) {
    nb::class_<tripod::PreparedCloud>(m, "_PreparedCloud")
        .def_prop_ro("points", [](const tripod::PreparedCloud& c) {
            return Eigen::Matrix<float, Eigen::Dynamic, 3, Eigen::RowMajor>(c.points); })
        .def_prop_ro("normals", [](const tripod::PreparedCloud& c) { return tripod::MatrixX3d(c.normals); })
        .def_prop_ro("normal_valid", [](const tripod::PreparedCloud& c) {
            Eigen::Matrix<bool, Eigen::Dynamic, 1> v(c.normal_valid.size());
            for (size_t i = 0; i < c.normal_valid.size(); ++i) v[i] = c.normal_valid[i] != 0;
            return v; })
        .def_prop_ro("covariances", [](const tripod::PreparedCloud& c) {
            tripod::MatrixX9d out(c.covariances.size(), 9);
            for (size_t i = 0; i < c.covariances.size(); ++i)
                Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(out.row(i).data()) =
                    c.covariances[i];
            return out; })
        .def_prop_ro("num_dropped", [](const tripod::PreparedCloud& c) { return c.num_dropped; })
        .def("__len__", [](const tripod::PreparedCloud& c) { return c.points.rows(); });

    m.def(
        "prepare_cloud",
        [](CloudIn points, int k_neighbors, double radius, const Eigen::Vector3d& viewpoint,
           double point_sigma, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            nb::gil_scoped_release release;
            return tripod::prepare_cloud(in, tripod::Neighborhood{k_neighbors, radius}, viewpoint,
                                         point_sigma, num_threads);
        },
        "points"_a, "k_neighbors"_a, "radius"_a, "viewpoint"_a, "point_sigma"_a, "num_threads"_a,
        "Finite points + k-d tree + normals + GICP covariances (see registration.prepare).");

    nb::class_<tripod::RegistrationOptions>(m, "_RegistrationOptions")
        .def(nb::init<>())
        .def_prop_rw(
            "method", [](const tripod::RegistrationOptions& o) { return method_name(o.method); },
            [](tripod::RegistrationOptions& o, const std::string& s) { o.method = parse_method(s); })
        .def_rw("max_correspondence_distances",
                &tripod::RegistrationOptions::max_correspondence_distances)
        .def_rw("max_iterations", &tripod::RegistrationOptions::max_iterations)
        .def_rw("rotation_eps", &tripod::RegistrationOptions::rotation_eps)
        .def_rw("translation_eps", &tripod::RegistrationOptions::translation_eps)
        .def_rw("point_sigma", &tripod::RegistrationOptions::point_sigma)
        .def_prop_rw(
            "loss", [](const tripod::RegistrationOptions& o) { return loss_name(o.loss); },
            [](tripod::RegistrationOptions& o, const std::string& s) { o.loss = parse_loss(s); })
        .def_rw("loss_scale", &tripod::RegistrationOptions::loss_scale)
        .def_prop_rw(
            "R_prior",
            [](const tripod::RegistrationOptions& o) {
                return o.has_rotation_prior ? std::optional<Eigen::Matrix3d>(o.R_prior)
                                            : std::nullopt;
            },
            [](tripod::RegistrationOptions& o, std::optional<Eigen::Matrix3d> R) {
                o.has_rotation_prior = R.has_value();
                o.R_prior = R.value_or(Eigen::Matrix3d::Identity());
            },
            nb::arg("R").none())
        .def_rw("rotation_prior_sigma", &tripod::RegistrationOptions::rotation_prior_sigma)
        .def_rw("lock_z", &tripod::RegistrationOptions::lock_z)
        .def_rw("oriented", &tripod::RegistrationOptions::oriented)
        .def_rw("min_normal_cos", &tripod::RegistrationOptions::min_normal_cos)
        .def_rw("max_source", &tripod::RegistrationOptions::max_source)
        .def_rw("min_correspondences", &tripod::RegistrationOptions::min_correspondences)
        .def_rw("num_threads", &tripod::RegistrationOptions::num_threads);

    nb::class_<tripod::RegistrationResult>(m, "_RegistrationResult")
        .def_ro("T_target_source", &tripod::RegistrationResult::T_target_source)
        .def_ro("converged", &tripod::RegistrationResult::converged)
        .def_ro("status", &tripod::RegistrationResult::status)
        .def_ro("iterations", &tripod::RegistrationResult::iterations)
        .def_ro("num_inliers", &tripod::RegistrationResult::num_inliers)
        .def_ro("fitness", &tripod::RegistrationResult::fitness)
        .def_ro("inlier_rmse", &tripod::RegistrationResult::inlier_rmse)
        .def_ro("residual_rmse", &tripod::RegistrationResult::residual_rmse)
        .def_ro("final_error", &tripod::RegistrationResult::final_error)
        .def_ro("information", &tripod::RegistrationResult::information)
        .def_ro("condition", &tripod::RegistrationResult::condition);

    m.def(
        "register_local",
        [](const tripod::PreparedCloud& source, const tripod::PreparedCloud& target,
           const Eigen::Matrix4d& T_init, const tripod::RegistrationOptions& opt) {
            nb::gil_scoped_release release;
            return tripod::register_local(source, target, T_init, opt);
        },
        "source"_a, "target"_a, "T_init"_a, "options"_a,
        "Local registration of prepared clouds (see registration.register).");

    nb::class_<tripod::GlobalOptions>(m, "_GlobalOptions")
        .def(nb::init<>())
        .def_rw("normal_radius", &tripod::GlobalOptions::normal_radius)
        .def_rw("feature_radius", &tripod::GlobalOptions::feature_radius)
        .def_rw("max_neighbors", &tripod::GlobalOptions::max_neighbors)
        .def_rw("inlier_distance", &tripod::GlobalOptions::inlier_distance)
        .def_rw("edge_length_ratio", &tripod::GlobalOptions::edge_length_ratio)
        .def_rw("mutual_filter", &tripod::GlobalOptions::mutual_filter)
        .def_rw("max_iterations", &tripod::GlobalOptions::max_iterations)
        .def_rw("confidence", &tripod::GlobalOptions::confidence)
        .def_rw("up_source", &tripod::GlobalOptions::up_source)
        .def_rw("up_target", &tripod::GlobalOptions::up_target)
        .def_prop_rw(
            "R_prior",
            [](const tripod::GlobalOptions& o) {
                return o.has_rotation_prior ? std::optional<Eigen::Matrix3d>(o.R_prior)
                                            : std::nullopt;
            },
            [](tripod::GlobalOptions& o, std::optional<Eigen::Matrix3d> R) {
                o.has_rotation_prior = R.has_value();
                o.R_prior = R.value_or(Eigen::Matrix3d::Identity());
            },
            nb::arg("R").none())
        .def_rw("rotation_tolerance", &tripod::GlobalOptions::rotation_tolerance)
        .def_rw("viewpoint_source", &tripod::GlobalOptions::viewpoint_source)
        .def_rw("viewpoint_target", &tripod::GlobalOptions::viewpoint_target)
        .def_rw("twin_turns", &tripod::GlobalOptions::twin_turns)
        .def_rw("twin_tolerance", &tripod::GlobalOptions::twin_tolerance)
        .def_rw("seed", &tripod::GlobalOptions::seed)
        .def_rw("num_threads", &tripod::GlobalOptions::num_threads);

    nb::class_<tripod::GlobalTwin>(m, "_GlobalTwin")
        .def_ro("turn", &tripod::GlobalTwin::turn)
        .def_ro("T_target_source", &tripod::GlobalTwin::T_target_source)
        .def_ro("num_inlier_correspondences", &tripod::GlobalTwin::num_inlier_correspondences)
        .def_ro("geometric_score", &tripod::GlobalTwin::geometric_score)
        .def_ro("fitness", &tripod::GlobalTwin::fitness)
        .def_ro("inlier_rmse", &tripod::GlobalTwin::inlier_rmse);

    nb::class_<tripod::GlobalResult>(m, "_GlobalResult")
        .def_ro("T_target_source", &tripod::GlobalResult::T_target_source)
        .def_ro("success", &tripod::GlobalResult::success)
        .def_ro("status", &tripod::GlobalResult::status)
        .def_ro("num_correspondences", &tripod::GlobalResult::num_correspondences)
        .def_ro("num_inlier_correspondences", &tripod::GlobalResult::num_inlier_correspondences)
        .def_ro("iterations", &tripod::GlobalResult::iterations)
        .def_ro("fitness", &tripod::GlobalResult::fitness)
        .def_ro("inlier_rmse", &tripod::GlobalResult::inlier_rmse)
        .def_ro("geometric_score", &tripod::GlobalResult::geometric_score)
        .def_ro("twins", &tripod::GlobalResult::twins);

    m.def(
        "register_global",
        [](CloudIn source, CloudIn target, const tripod::GlobalOptions& opt) {
            tripod::PointsXYZ s = to_eigen(source), t = to_eigen(target);
            nb::gil_scoped_release release;
            return tripod::register_global(s, t, opt);
        },
        "source"_a, "target"_a, "options"_a,
        "FPFH + RANSAC global registration (see registration.register_global).");
}
