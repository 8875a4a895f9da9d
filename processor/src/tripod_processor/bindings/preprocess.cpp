// SPDX-License-Identifier: BSD-3-Clause
// Bindings: preprocessing (voxel grid, ...). Conversions and docstrings only.
#include <nanobind/eigen/dense.h>

#include "common.hpp"
#include "tripod_core/features.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace nb = nanobind;
using namespace tripod_bind;
using nb::literals::operator""_a;

namespace {
Eigen::Matrix<int64_t, Eigen::Dynamic, 1> as_index(const std::vector<int64_t>& v) {
    return Eigen::Map<const Eigen::Matrix<int64_t, Eigen::Dynamic, 1>>(v.data(), v.size());
}
}  // namespace

TRIPOD_BINDING(preprocess) {
    m.def(
        "voxel_downsample",
        [](CloudIn points, double voxel_size, int num_threads, bool align_min_bound) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::PointsXYZ out;
            {
                nb::gil_scoped_release release;
                out = tripod::voxel_downsample(
                    in, voxel_size, num_threads,
                    align_min_bound ? tripod::VoxelAlign::kMinBound : tripod::VoxelAlign::kOrigin);
            }
            return to_numpy(std::move(out));
        },
        nb::arg("points"), nb::arg("voxel_size"), nb::arg("num_threads") = 0,
        nb::arg("align_min_bound") = false,
        "Voxel-grid downsampling with centroids. points: (N,3) float32 [m]; returns (M,3).");

    m.def(
        "estimate_normals",
        [](CloudIn points, int k_neighbors, double radius, const Eigen::Vector3d& viewpoint,
           int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::LocalGeometry g;
            {
                nb::gil_scoped_release release;
                g = tripod::estimate_local_geometry(in, tripod::Neighborhood{k_neighbors, radius},
                                                    viewpoint, num_threads);
            }
            Eigen::Matrix<bool, Eigen::Dynamic, 1> valid(g.valid.size());
            for (size_t i = 0; i < g.valid.size(); ++i) valid[i] = g.valid[i] != 0;
            return nb::make_tuple(g.normals, g.covariances, g.curvature, valid);
        },
        "points"_a, "k_neighbors"_a, "radius"_a, "viewpoint"_a, "num_threads"_a,
        "PCA normals: (normals (N,3), covariances (N,9), curvature (N,), valid (N,)).");
    m.def(
        "statistical_outlier_removal",
        [](CloudIn points, int k_neighbors, double std_ratio, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            std::vector<int64_t> kept;
            {
                nb::gil_scoped_release release;
                kept = tripod::statistical_outlier_removal(in, k_neighbors, std_ratio, num_threads);
            }
            return as_index(kept);
        },
        "points"_a, "k_neighbors"_a, "std_ratio"_a, "num_threads"_a, "Indices of the kept rows.");
    m.def(
        "mls_smooth",
        [](CloudIn points, double radius, int num_threads, double fit_voxel) {
            tripod::PointsXYZ in = to_eigen(points), out;
            {
                nb::gil_scoped_release release;
                out = tripod::mls_smooth(in, radius, num_threads, fit_voxel);
            }
            return to_numpy(std::move(out));
        },
        "points"_a, "radius"_a, "num_threads"_a, "fit_voxel"_a = 0.0,
        "MLS-smoothed points (N,3).");
    m.def(
        "normal_space_sampling",
        [](const tripod::MatrixX3d& normals, int64_t num_samples, int bins, uint64_t seed) {
            return as_index(tripod::normal_space_sampling(normals, num_samples, bins, seed));
        },
        "normals"_a, "num_samples"_a, "bins_per_axis"_a, "seed"_a, "Sorted sample indices.");
    m.def(
        "compute_fpfh",
        [](CloudIn points, const tripod::MatrixX3d& normals, double radius, int max_neighbors,
           int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::MatrixX33f f;
            {
                nb::gil_scoped_release release;
                f = tripod::compute_fpfh(in, normals, radius, max_neighbors, num_threads);
            }
            return f;
        },
        "points"_a, "normals"_a, "radius"_a, "max_neighbors"_a, "num_threads"_a,
        "FPFH descriptors (N,33) float32.");
}
