// SPDX-License-Identifier: BSD-3-Clause
// Bindings: the geometry codecs, octree (tripod_core/octree_codec.hpp) and predictive scan
// coding (tripod_core/predictive_codec.hpp). Conversions and docstrings only. Python owners:
// tripod_processor.compression.codec (octree) and .predictive.
#include <nanobind/stl/array.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <array>
#include <stdexcept>
#include <string>
#include <tuple>

#include "common.hpp"
#include "tripod_core/octree_codec.hpp"
#include "tripod_core/predictive_codec.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {
using CodesIn = nb::ndarray<const uint64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using TableIn = nb::ndarray<const uint16_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using OriginIn = nb::ndarray<const double, nb::shape<3>, nb::c_contig, nb::device::cpu>;

std::vector<uint64_t> to_codes(const CodesIn& a) {
    return std::vector<uint64_t>(a.data(), a.data() + a.shape(0));
}

const uint16_t* check_table(const TableIn& t) {
    if (t.shape(0) != tripod::kOctreeContexts)
        throw std::invalid_argument("probability table must have 2^" +
                                    std::to_string(tripod::kOctreeContextBits) + " entries");
    return t.data();
}

nb::bytes as_bytes(const std::vector<uint8_t>& v) {
    return nb::bytes(reinterpret_cast<const char*>(v.data()), v.size());
}

void bind_octree(nb::module_& m) {
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
            return owned_array(std::move(codes));
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
            return nb::make_tuple(owned_array(std::move(ctx)), owned_array(std::move(bits)));
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
            return as_bytes(out);
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
            return owned_array(std::move(codes));
        },
        nb::arg("data"), nb::arg("depth"), nb::arg("n_voxels"), nb::arg("p0_table"),
        nb::arg("adapt_shift"), nb::arg("adapt_prior") = 0,
        "Decode an octree stream to sorted Morton codes (uint64); RuntimeError if corrupt.");
}

void bind_predictive(nb::module_& m) {
    using Grid = tripod::SphericalGrid;
    nb::class_<Grid>(m, "_SphericalGrid", "The quantisation grid of a predictive stream")
        .def(nb::init<>())
        .def_prop_rw(
            "origin", [](const Grid& g) { return std::array<double, 3>{g.origin[0], g.origin[1],
                                                                        g.origin[2]}; },
            [](Grid& g, const std::array<double, 3>& o) { std::copy(o.begin(), o.end(), g.origin); },
            "sensor origin [m]")
        .def_rw("range_step", &Grid::range_step, "[m]")
        .def_rw("az_count", &Grid::az_count, "azimuth steps per turn")
        .def_rw("el_step", &Grid::el_step, "[rad] (used when el_table is empty)")
        .def_rw("el_table", &Grid::el_table, "sorted elevations [rad], or empty")
        .def_rw("row_shift", &Grid::row_shift,
                "without a table: scan row of elevation index e is e >> row_shift")
        .def_rw("z_table", &Grid::z_table, "per-laser heights [m] (size of el_table), or empty")
        .def_rw("az_predictor", &Grid::az_predictor,
                "0: previous azimuth (predictive-sph1); 1: adaptive with the row predictor");

    using Stats = tripod::PredictiveStats;
    nb::class_<Stats>(m, "_PredictiveStats", "What predictive_encode measured")
        .def_ro("max_error_m", &Stats::max_error_m,
                "largest distance of a decoded point from its input point [m]")
        .def_ro("checksum", &Stats::checksum, "FNV-1a of the quantised points (for the decoder)")
        .def_prop_ro(
            "part_bits",
            [](const Stats& s) { return std::make_tuple(s.part_bits[0], s.part_bits[1],
                                                        s.part_bits[2]); },
            "estimated bits spent on (elevation, azimuth, range)");

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
            return owned_array<nb::shape<-1, 3>>(std::move(sph), {n, 3});
        },
        nb::arg("points"), nb::arg("origin"), nb::arg("num_threads") = 0,
        "(N,3) float64 (range [m], azimuth [rad], elevation [rad]) of points about origin.");

    m.def(
        "predictive_encode",
        [](CloudIn points, const Grid& grid, int num_threads) {
            tripod::PointsXYZ in = to_eigen(points);
            Stats stats;
            std::vector<uint8_t> out;
            {
                nb::gil_scoped_release release;
                out = tripod::predictive_encode(in, grid, &stats, num_threads);
            }
            return std::make_tuple(as_bytes(out), stats);
        },
        nb::arg("points"), nb::arg("grid"), nb::arg("num_threads") = 0,
        "Code points (N,3) float32 [m] in order on the grid; returns (stream, stats).");

    m.def(
        "predictive_decode",
        [](nb::bytes data, uint64_t n_points, const Grid& grid, uint32_t checksum,
           int num_threads) {
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
        nb::arg("data"), nb::arg("n_points"), nb::arg("grid"), nb::arg("checksum"),
        nb::arg("num_threads") = 0,
        "Decode n_points (N,3) float32 [m] of a predictive stream; RuntimeError if corrupt.");
}
}  // namespace

TRIPOD_BINDING(compression) {
    bind_octree(m);
    bind_predictive(m);
}
