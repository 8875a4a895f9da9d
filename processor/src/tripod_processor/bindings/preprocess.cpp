// SPDX-License-Identifier: BSD-3-Clause
// Bindings: preprocessing (voxel grid: tripod_core/voxel_grid.hpp; normals, outliers, sampling,
// FPFH: tripod_core/features.hpp). Conversions and docstrings only. Python owner:
// tripod_processor.preprocess.
#include <nanobind/eigen/dense.h>

#include "common.hpp"
#include "tripod_core/features.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace nb = nanobind;
using namespace tripod_bind;
using nb::literals::operator""_a;

namespace {
/// Local geometry of every point, as numpy arrays (the result class of estimate_normals).
struct Normals {
    nb::ndarray<nb::numpy, double, nb::shape<-1, 3>> normals;
    nb::ndarray<nb::numpy, double, nb::shape<-1, 9>> covariances;
    nb::ndarray<nb::numpy, double, nb::ndim<1>> curvature;
    nb::ndarray<nb::numpy, bool, nb::ndim<1>> valid;
};

/// (N, 33) float32 FPFH rows, moved to numpy.
nb::ndarray<nb::numpy, float, nb::shape<-1, 33>> fpfh_to_numpy(tripod::MatrixX33f&& f) {
    const size_t n = static_cast<size_t>(f.rows());
    return owned_array<nb::shape<-1, 33>>(std::move(f), {n, 33});
}
}  // namespace

TRIPOD_BINDING(preprocess) {
    nb::class_<Normals>(m, "_Normals", "What estimate_normals found")
        .def_ro("normals", &Normals::normals, "(N, 3) float64 unit normals towards the viewpoint", nb::rv_policy::reference)
        .def_ro("covariances", &Normals::covariances, "(N, 9) float64 row-major 3x3 [m^2]", nb::rv_policy::reference)
        .def_ro("curvature", &Normals::curvature, "(N,) float64 lambda_min / sum (0 = flat)", nb::rv_policy::reference)
        .def_ro("valid", &Normals::valid, "(N,) bool: >= 3 non-collinear neighbours", nb::rv_policy::reference);
    m.def(
        "voxel_downsample",
        [](CloudIn points, double voxel_size, int num_threads, bool align_min_bound) {
            // read in place (the GIL is released, the caller's array is held by `points`)
            const Eigen::Map<const tripod::PointsXYZ> in(points.data(),
                                                         static_cast<Eigen::Index>(points.shape(0)), 3);
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
            const size_t n = static_cast<size_t>(g.normals.rows());
            std::unique_ptr<bool[]> valid(new bool[n ? n : 1]);
            for (size_t i = 0; i < n; ++i) valid[i] = g.valid[i] != 0;
            return Normals{owned_array<nb::shape<-1, 3>>(std::move(g.normals), {n, 3}),
                           owned_array<nb::shape<-1, 9>>(std::move(g.covariances), {n, 9}),
                           owned_array<nb::ndim<1>>(std::move(g.curvature), {n}),
                           owned_array<nb::ndim<1>>(std::move(valid), {n})};
        },
        "points"_a, "k_neighbors"_a, "radius"_a, "viewpoint"_a, "num_threads"_a,
        "PCA normals of points (N,3) float32 [m] over k neighbours within radius [m].");
    m.def(
        "statistical_outlier_removal",
        [](CloudIn points, int k_neighbors, double std_ratio, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            std::vector<int64_t> kept;
            {
                nb::gil_scoped_release release;
                kept = tripod::statistical_outlier_removal(in, k_neighbors, std_ratio, num_threads);
            }
            return owned_array(std::move(kept));
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
            return owned_array(tripod::normal_space_sampling(normals, num_samples, bins, seed));
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
            return fpfh_to_numpy(std::move(f));
        },
        "points"_a, "normals"_a, "radius"_a, "max_neighbors"_a, "num_threads"_a,
        "FPFH descriptors (N,33) float32.");
}
