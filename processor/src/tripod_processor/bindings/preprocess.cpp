// SPDX-License-Identifier: BSD-3-Clause
// Bindings: preprocessing (voxel grid, ...). Conversions and docstrings only.
#include "common.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

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
}
