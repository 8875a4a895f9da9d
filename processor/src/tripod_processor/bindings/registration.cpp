// SPDX-License-Identifier: BSD-3-Clause
// Bindings: local and global registration. Conversions and docstrings only; the public API with
// full documentation is tripod_processor.registration.
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <optional>

#include "common.hpp"
#include "tripod_core/global_registration.hpp"
#include "tripod_core/oriented_icp.hpp"
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
    if (s == "lm") return tripod::Method::kCeresLM;
    throw std::invalid_argument("unknown method '" + s + "' (icp, plane, gicp, symmetric, lm)");
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

    m.def(
        "register_local",
        [](const tripod::PreparedCloud& source, const tripod::PreparedCloud& target,
           const Eigen::Matrix4d& T_init, const std::string& method,
           const std::vector<double>& max_correspondence_distances, int max_iterations,
           double rotation_eps, double translation_eps, double point_sigma, const std::string& loss,
           double loss_scale, std::optional<Eigen::Matrix3d> R_prior, double rotation_prior_sigma,
           bool lock_z, int num_threads) {
            tripod::RegistrationOptions opt;
            opt.method = parse_method(method);
            opt.max_correspondence_distances = max_correspondence_distances;
            opt.max_iterations = max_iterations;
            opt.rotation_eps = rotation_eps;
            opt.translation_eps = translation_eps;
            opt.point_sigma = point_sigma;
            opt.loss = parse_loss(loss);
            opt.loss_scale = loss_scale;
            opt.has_rotation_prior = R_prior.has_value();
            if (R_prior) opt.R_prior = *R_prior;
            opt.rotation_prior_sigma = rotation_prior_sigma;
            opt.lock_z = lock_z;
            opt.num_threads = num_threads;
            tripod::RegistrationResult r;
            {
                nb::gil_scoped_release release;
                r = tripod::register_local(source, target, T_init, opt);
            }
            nb::dict d;
            d["T_target_source"] = r.T_target_source;
            d["converged"] = r.converged;
            d["status"] = r.status;
            d["iterations"] = r.iterations;
            d["num_inliers"] = r.num_inliers;
            d["fitness"] = r.fitness;
            d["inlier_rmse"] = r.inlier_rmse;
            d["final_error"] = r.final_error;
            d["information"] = r.information;
            d["condition"] = r.condition;
            return d;
        },
        "source"_a, "target"_a, "T_init"_a, "method"_a, "max_correspondence_distances"_a,
        "max_iterations"_a, "rotation_eps"_a, "translation_eps"_a, "point_sigma"_a, "loss"_a,
        "loss_scale"_a, "R_prior"_a.none(), "rotation_prior_sigma"_a, "lock_z"_a, "num_threads"_a,
        "Local registration of prepared clouds; returns a dict (see registration.register).");

    m.def(
        "oriented_point_to_plane",
        [](const tripod::PreparedCloud& source, const tripod::PreparedCloud& target,
           const Eigen::Matrix4d& T_init, double max_distance, int iterations,
           double point_sigma, double min_normal_dot, int64_t max_source, int num_threads) {
            tripod::OrientedIcpOptions opt;
            opt.max_distance = max_distance;
            opt.iterations = iterations;
            opt.point_sigma = point_sigma;
            opt.min_normal_dot = min_normal_dot;
            opt.max_source = max_source;
            opt.num_threads = num_threads;
            tripod::OrientedIcpResult r;
            {
                nb::gil_scoped_release release;
                r = tripod::oriented_point_to_plane(source, target, T_init, opt);
            }
            nb::dict d;
            d["T_target_source"] = r.T_target_source;
            d["H"] = r.H;
            d["fitness"] = r.fitness;
            d["rmse"] = r.rmse;
            d["iterations"] = r.iterations;
            d["linearized"] = r.linearized;
            return d;
        },
        "source"_a, "target"_a, "T_init"_a, "max_distance"_a, "iterations"_a, "point_sigma"_a,
        "min_normal_dot"_a, "max_source"_a, "num_threads"_a,
        "Point-to-plane ICP over oriented normals (see reconstruction.odometry.oriented_refine).");

    m.def(
        "register_global",
        [](CloudIn source, CloudIn target, double normal_radius, double feature_radius,
           int max_neighbors, double inlier_distance, double edge_length_ratio, bool mutual_filter,
           int64_t max_iterations, double confidence, const Eigen::Vector3d& up_source,
           const Eigen::Vector3d& up_target, const Eigen::Vector3d& viewpoint_source,
           const Eigen::Vector3d& viewpoint_target, std::optional<Eigen::Matrix3d> R_prior,
           double rotation_tolerance, uint64_t seed, int num_threads) {
            tripod::PointsXYZ s = to_eigen(source), t = to_eigen(target);
            tripod::GlobalOptions opt;
            opt.normal_radius = normal_radius;
            opt.feature_radius = feature_radius;
            opt.max_neighbors = max_neighbors;
            opt.inlier_distance = inlier_distance;
            opt.edge_length_ratio = edge_length_ratio;
            opt.mutual_filter = mutual_filter;
            opt.max_iterations = max_iterations;
            opt.confidence = confidence;
            opt.up_source = up_source;
            opt.up_target = up_target;
            opt.viewpoint_source = viewpoint_source;
            opt.viewpoint_target = viewpoint_target;
            opt.has_rotation_prior = R_prior.has_value();
            if (R_prior) opt.R_prior = *R_prior;
            opt.rotation_tolerance = rotation_tolerance;
            opt.seed = seed;
            opt.num_threads = num_threads;
            tripod::GlobalResult r;
            {
                nb::gil_scoped_release release;
                r = tripod::register_global(s, t, opt);
            }
            nb::dict d;
            d["T_target_source"] = r.T_target_source;
            d["success"] = r.success;
            d["status"] = r.status;
            d["num_correspondences"] = r.num_correspondences;
            d["num_inlier_correspondences"] = r.num_inlier_correspondences;
            d["iterations"] = r.iterations;
            d["fitness"] = r.fitness;
            d["inlier_rmse"] = r.inlier_rmse;
            return d;
        },
        "source"_a, "target"_a, "normal_radius"_a, "feature_radius"_a, "max_neighbors"_a,
        "inlier_distance"_a, "edge_length_ratio"_a, "mutual_filter"_a, "max_iterations"_a,
        "confidence"_a, "up_source"_a, "up_target"_a, "viewpoint_source"_a, "viewpoint_target"_a,
        "R_prior"_a.none(), "rotation_tolerance"_a, "seed"_a, "num_threads"_a,
        "FPFH + RANSAC global registration; returns a dict (see registration.register_global).");
}
