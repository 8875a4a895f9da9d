// SPDX-License-Identifier: BSD-3-Clause
// Bindings: per-point local shape and column context for scene understanding
// (tripod_core/local_shape.hpp). Conversions and docstrings only. Python owners:
// tripod_processor.preprocess (local_shape, voxel_assign) and
// tripod_processor.scene.segmentation.features (column_context).
#include "common.hpp"
#include "tripod_core/local_shape.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {
using FeatOut = nb::ndarray<nb::numpy, float, nb::ndim<2>>;
using FlagsIn = nb::ndarray<const uint8_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

FeatOut features_to_numpy(tripod::FeaturesF&& m) {
    const size_t rows = static_cast<size_t>(m.rows()), cols = static_cast<size_t>(m.cols());
    return owned_array<nb::ndim<2>>(std::move(m), {rows, cols});
}

/// Voxels of a cloud: their centroids, each point's voxel and each voxel's count.
struct VoxelAssignment {
    CloudOut centroids;                                       // (M, 3) float32 [m]
    nb::ndarray<nb::numpy, int32_t, nb::ndim<1>> point_voxel;  // (N,), -1 for non-finite points
    nb::ndarray<nb::numpy, int32_t, nb::ndim<1>> counts;       // (M,)
};
}  // namespace

TRIPOD_BINDING(local_shape) {
    m.def(
        "voxel_local_shape",
        [](CloudIn points, double voxel_size, int radius_voxels, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::FeaturesF out;
            {
                nb::gil_scoped_release release;
                out = tripod::voxel_local_shape(in, voxel_size, radius_voxels, num_threads);
            }
            return features_to_numpy(std::move(out));
        },
        nb::arg("points"), nb::arg("voxel_size"), nb::arg("radius_voxels") = 1,
        nb::arg("num_threads") = 0,
        "Per-point normal, covariance eigenvalues and neighbour count from voxel moments.\n"
        "points: (N,3) float32 [m]; returns (N,7) float32: nx ny nz l0 l1 l2 count.");

    nb::class_<VoxelAssignment>(m, "_VoxelAssignment", "What voxel_assign found")
        .def_ro("centroids", &VoxelAssignment::centroids, "(M, 3) float32 voxel centroids [m]", nb::rv_policy::reference)
        .def_ro("point_voxel", &VoxelAssignment::point_voxel,
                "(N,) int32 voxel of each point (-1 for non-finite points)", nb::rv_policy::reference)
        .def_ro("counts", &VoxelAssignment::counts, "(M,) int32 points per voxel", nb::rv_policy::reference);
    m.def(
        "voxel_assign",
        [](CloudIn points, double voxel_size, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::PointsXYZ centroids;
            std::vector<int32_t> point_voxel, counts;
            {
                nb::gil_scoped_release release;
                tripod::voxel_assign(in, voxel_size, centroids, point_voxel, counts, num_threads);
            }
            return VoxelAssignment{to_numpy(std::move(centroids)),
                                   owned_array(std::move(point_voxel)),
                                   owned_array(std::move(counts))};
        },
        nb::arg("points"), nb::arg("voxel_size"), nb::arg("num_threads") = 0,
        "Group points (N,3) float32 [m] by voxel.");

    using Opt = tripod::ColumnContextOptions;
    nb::class_<Opt>(m, "_ColumnContextOptions", "Settings of column_context")
        .def(nb::init<>())
        .def_rw("cell_size", &Opt::cell_size, "side of a grid cell [m]")
        .def_rw("z_low", &Opt::z_low, "occupancy band: points between z_low and z_high [m]")
        .def_rw("z_high", &Opt::z_high)
        .def_rw("num_directions", &Opt::num_directions, "horizontal rays per occupied cell")
        .def_rw("skip", &Opt::skip, "rays start this far from their cell [m]")
        .def_rw("max_range", &Opt::max_range,
                "a ray that leaves this far without a hit is open [m]")
        .def_rw("num_threads", &Opt::num_threads, "0 = all cores");
    m.def(
        "column_context",
        [](CloudIn points, FlagsIn upright, const Opt& options) {
            if (upright.shape(0) != points.shape(0))
                throw std::invalid_argument("upright must have one flag per point");
            tripod::PointsXYZ in = to_eigen(points);
            std::vector<uint8_t> up(upright.data(), upright.data() + upright.shape(0));
            tripod::FeaturesF out;
            {
                nb::gil_scoped_release release;
                out = tripod::column_context(in, up.data(), options);
            }
            return features_to_numpy(std::move(out));
        },
        nb::arg("points"), nb::arg("upright"), nb::arg("options"),
        "Horizontal context per point of a z-up scan. points: (N,3) float32 [m]; upright: (N,)\n"
        "uint8 flags of the points that count for column heights; returns (N,5) float32: open\n"
        "fraction, mean free distance [m], column z-min [m], column z-max [m], log1p(count).");
}
