// SPDX-License-Identifier: BSD-3-Clause
// Bindings: octree geometry codec (tripod_processor.compression). Conversions and docstrings only.
#include <stdexcept>
#include <string>

#include "common.hpp"
#include "tripod_core/octree_codec.hpp"
#include "tripod_core/predictive_codec.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {
using CodesIn = nb::ndarray<const uint64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using TableIn = nb::ndarray<const uint16_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using OriginIn = nb::ndarray<const double, nb::shape<3>, nb::c_contig, nb::device::cpu>;

/// Move a std::vector into a 1-D numpy array owned by a capsule (no copy).
template <class T>
nb::ndarray<nb::numpy, T, nb::ndim<1>> vector_to_numpy(std::vector<T>&& v) {
    auto* heap = new std::vector<T>(std::move(v));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T, nb::ndim<1>>(heap->data(), {heap->size()}, owner);
}

std::vector<uint64_t> to_codes(const CodesIn& a) {
    return std::vector<uint64_t>(a.data(), a.data() + a.shape(0));
}

using TableF64In = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

tripod::SphericalGrid make_grid(OriginIn origin, double range_step, int64_t az_count,
                                double el_step, TableF64In el_table, int row_shift,
                                TableF64In z_table, int az_predictor) {
    tripod::SphericalGrid g;
    for (int i = 0; i < 3; ++i) g.origin[i] = origin(i);
    g.range_step = range_step;
    g.az_count = az_count;
    g.el_step = el_step;
    g.el_table.assign(el_table.data(), el_table.data() + el_table.shape(0));
    g.row_shift = row_shift;
    g.z_table.assign(z_table.data(), z_table.data() + z_table.shape(0));
    g.az_predictor = az_predictor;
    return g;
}

const uint16_t* check_table(const TableIn& t) {
    if (t.shape(0) != tripod::kOctreeContexts)
        throw std::invalid_argument("probability table must have 2^" +
                                    std::to_string(tripod::kOctreeContextBits) + " entries");
    return t.data();
}
}  // namespace

TRIPOD_BINDING(compression) {
    m.attr("OCTREE_CONTEXT_BITS") = tripod::kOctreeContextBits;
    m.attr("OCTREE_MAX_DEPTH") = tripod::kOctreeMaxDepth;

    m.def(
        "voxelize_morton",
        [](CloudIn points, OriginIn origin, double voxel_size, int depth, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            const double o[3] = {origin(0), origin(1), origin(2)};
            std::vector<uint64_t> codes;
            {
                nb::gil_scoped_release release;
                codes = tripod::voxelize_morton(in, o, voxel_size, depth, num_threads);
            }
            return vector_to_numpy(std::move(codes));
        },
        nb::arg("points"), nb::arg("origin"), nb::arg("voxel_size"), nb::arg("depth"),
        nb::arg("num_threads") = 0,
        "Sorted unique Morton codes (uint64) of floor((points - origin) / voxel_size), clamped "
        "to [0, 2^depth). points: (N,3) float32 [m]; origin: (3,) float64 [m].");

    m.def(
        "morton_to_points",
        [](CodesIn codes, OriginIn origin, double voxel_size, int num_threads) {
            std::vector<uint64_t> c = to_codes(codes);
            const double o[3] = {origin(0), origin(1), origin(2)};
            tripod::PointsXYZ out;
            {
                nb::gil_scoped_release release;
                out = tripod::morton_to_points(c, o, voxel_size, num_threads);
            }
            return to_numpy(std::move(out));
        },
        nb::arg("codes"), nb::arg("origin"), nb::arg("voxel_size"), nb::arg("num_threads") = 0,
        "Voxel centres (M,3) float32 [m] of Morton codes.");

    m.def(
        "octree_contexts",
        [](CodesIn codes, int depth) {
            std::vector<uint64_t> c = to_codes(codes);
            std::vector<uint32_t> ctx;
            std::vector<uint8_t> bits;
            {
                nb::gil_scoped_release release;
                tripod::octree_contexts(c, depth, ctx, bits);
            }
            return nb::make_tuple(vector_to_numpy(std::move(ctx)), vector_to_numpy(std::move(bits)));
        },
        nb::arg("codes"), nb::arg("depth"),
        "(contexts uint32, bits uint8) of every coded occupancy bit, in coding order.");

    m.def(
        "octree_encode",
        [](CodesIn codes, int depth, TableIn p0_table, int adapt_shift, int adapt_prior) {
            std::vector<uint64_t> c = to_codes(codes);
            const uint16_t* table = check_table(p0_table);
            std::vector<uint8_t> out;
            {
                nb::gil_scoped_release release;
                out = tripod::octree_encode(c, depth, table, adapt_shift, adapt_prior);
            }
            return nb::bytes(reinterpret_cast<const char*>(out.data()), out.size());
        },
        nb::arg("codes"), nb::arg("depth"), nb::arg("p0_table"), nb::arg("adapt_shift"),
        nb::arg("adapt_prior") = 0,
        "Range-code the octree of sorted unique Morton codes; returns the stream (bytes).");

    m.def(
        "octree_decode",
        [](nb::bytes data, int depth, uint64_t n_voxels, TableIn p0_table, int adapt_shift,
           int adapt_prior) {
            const uint16_t* table = check_table(p0_table);
            std::vector<uint8_t> in(static_cast<const uint8_t*>(data.data()),
                                    static_cast<const uint8_t*>(data.data()) + data.size());
            std::vector<uint64_t> codes;
            {
                nb::gil_scoped_release release;
                codes = tripod::octree_decode(in.data(), in.size(), depth, n_voxels, table,
                                              adapt_shift, adapt_prior);
            }
            return vector_to_numpy(std::move(codes));
        },
        nb::arg("data"), nb::arg("depth"), nb::arg("n_voxels"), nb::arg("p0_table"),
        nb::arg("adapt_shift"), nb::arg("adapt_prior") = 0,
        "Decode an octree stream to sorted Morton codes (uint64); RuntimeError if corrupt.");

    m.def(
        "spherical_coordinates",
        [](CloudIn points, OriginIn origin, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            const double o[3] = {origin(0), origin(1), origin(2)};
            std::vector<double> sph;
            {
                nb::gil_scoped_release release;
                sph = tripod::cartesian_to_spherical(in, o, num_threads);
            }
            const size_t n = sph.size() / 3;
            auto* heap = new std::vector<double>(std::move(sph));
            nb::capsule owner(heap, [](void* p) noexcept {
                delete static_cast<std::vector<double>*>(p);
            });
            return nb::ndarray<nb::numpy, double, nb::shape<-1, 3>>(heap->data(), {n, 3}, owner);
        },
        nb::arg("points"), nb::arg("origin"), nb::arg("num_threads") = 0,
        "(N,3) float64 (range [m], azimuth [rad], elevation [rad]) of points about origin.");

    m.def(
        "predictive_encode",
        [](CloudIn points, OriginIn origin, double range_step, int64_t az_count, double el_step,
           TableF64In el_table, int row_shift, TableF64In z_table, int az_predictor,
           int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            const tripod::SphericalGrid grid =
                make_grid(origin, range_step, az_count, el_step, el_table, row_shift, z_table,
                          az_predictor);
            tripod::PredictiveStats stats;
            std::vector<uint8_t> out;
            {
                nb::gil_scoped_release release;
                out = tripod::predictive_encode(in, grid, &stats, num_threads);
            }
            return nb::make_tuple(nb::bytes(reinterpret_cast<const char*>(out.data()), out.size()),
                                  stats.max_error_m, stats.checksum,
                                  nb::make_tuple(stats.part_bits[0], stats.part_bits[1],
                                                 stats.part_bits[2]));
        },
        nb::arg("points"), nb::arg("origin"), nb::arg("range_step"), nb::arg("az_count"),
        nb::arg("el_step"), nb::arg("el_table"), nb::arg("row_shift"), nb::arg("z_table"),
        nb::arg("az_predictor"), nb::arg("num_threads") = 0,
        "Code points (N,3) float32 [m] in order on a spherical grid about origin; returns "
        "(stream bytes, max point error [m], checksum of the quantised points, estimated bits "
        "spent on (elevation, azimuth, range)).");

    m.def(
        "predictive_decode",
        [](nb::bytes data, uint64_t n_points, OriginIn origin, double range_step,
           int64_t az_count, double el_step, TableF64In el_table, int row_shift,
           TableF64In z_table, int az_predictor, uint32_t checksum, int num_threads) {
            const tripod::SphericalGrid grid =
                make_grid(origin, range_step, az_count, el_step, el_table, row_shift, z_table,
                          az_predictor);
            std::vector<uint8_t> in(static_cast<const uint8_t*>(data.data()),
                                    static_cast<const uint8_t*>(data.data()) + data.size());
            tripod::PointsXYZ out;
            {
                nb::gil_scoped_release release;
                out = tripod::predictive_decode(in.data(), in.size(), n_points, grid, checksum,
                                                num_threads);
            }
            return to_numpy(std::move(out));
        },
        nb::arg("data"), nb::arg("n_points"), nb::arg("origin"), nb::arg("range_step"),
        nb::arg("az_count"), nb::arg("el_step"), nb::arg("el_table"), nb::arg("row_shift"),
        nb::arg("z_table"), nb::arg("az_predictor"), nb::arg("checksum"),
        nb::arg("num_threads") = 0,
        "Decode n_points (N,3) float32 [m] of a predictive stream; RuntimeError if corrupt.");
}
