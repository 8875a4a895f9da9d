// SPDX-License-Identifier: BSD-3-Clause
// Bindings: scene understanding features (local shape, column context). Conversions and docs only.
#include "common.hpp"
#include "tripod_core/local_shape.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {
using FeatOut = nb::ndarray<nb::numpy, float, nb::ndim<2>>;
FeatOut features_to_numpy(tripod::FeaturesF&& m) {
    auto* heap = new tripod::FeaturesF(std::move(m));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<tripod::FeaturesF*>(p); });
    return FeatOut(heap->data(), {static_cast<size_t>(heap->rows()), static_cast<size_t>(heap->cols())},
                   owner);
}
}  // namespace

TRIPOD_BINDING(scene) {
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
    m.def(
        "voxel_assign",
        [](CloudIn points, double voxel_size, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            tripod::PointsXYZ cen;
            auto* idx = new std::vector<int32_t>();
            auto* cnt = new std::vector<int32_t>();
            {
                nb::gil_scoped_release release;
                tripod::voxel_assign(in, voxel_size, cen, *idx, *cnt, num_threads);
            }
            nb::capsule own_idx(idx, [](void* p) noexcept { delete static_cast<std::vector<int32_t>*>(p); });
            nb::capsule own_cnt(cnt, [](void* p) noexcept { delete static_cast<std::vector<int32_t>*>(p); });
            using IntOut = nb::ndarray<nb::numpy, int32_t, nb::ndim<1>>;
            return nb::make_tuple(to_numpy(std::move(cen)), IntOut(idx->data(), {idx->size()}, own_idx),
                                  IntOut(cnt->data(), {cnt->size()}, own_cnt));
        },
        nb::arg("points"), nb::arg("voxel_size"), nb::arg("num_threads") = 0,
        "Group points by voxel. points: (N,3) float32 [m]; returns (centroids (M,3) float32,\n"
        "point_voxel (N,) int32 (-1 for non-finite points), counts (M,) int32).");
    m.def(
        "column_context",
        [](CloudIn points, nb::ndarray<const uint8_t, nb::ndim<1>, nb::c_contig, nb::device::cpu> upright,
           double cell_size, double z_low, double z_high, int num_directions,
           double skip, double max_range, int num_threads) {
            if (upright.shape(0) != points.shape(0))
                throw std::invalid_argument("upright must have one flag per point");
            tripod::PointsXYZ in = to_eigen(points);
            std::vector<uint8_t> up(upright.data(), upright.data() + upright.shape(0));
            tripod::FeaturesF out;
            {
                nb::gil_scoped_release release;
                out = tripod::column_context(in, up.data(), cell_size, z_low, z_high, num_directions, skip,
                                             max_range, num_threads);
            }
            return features_to_numpy(std::move(out));
        },
        nb::arg("points"), nb::arg("upright"), nb::arg("cell_size"), nb::arg("z_low"), nb::arg("z_high"),
        nb::arg("num_directions") = 16, nb::arg("skip") = 0.25, nb::arg("max_range") = 8.0,
        nb::arg("num_threads") = 0,
        "Horizontal context per point of a z-up scan. points: (N,3) float32 [m]; upright: (N,)\n"
        "uint8 flags of the points that count for column heights; returns (N,5) float32: open\n"
        "fraction, mean free distance [m], column z-min [m], column z-max [m], log1p(count).");
}
