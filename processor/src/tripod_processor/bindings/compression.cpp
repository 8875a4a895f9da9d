// SPDX-License-Identifier: BSD-3-Clause
// Bindings: octree geometry codec (tripod_processor.compression). Conversions and docstrings only.
#include <stdexcept>
#include <string>

#include "common.hpp"
#include "tripod_core/octree_codec.hpp"

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
}
