// SPDX-License-Identifier: BSD-3-Clause
// Bindings: exact nearest neighbour within a radius (tripod_core/nearest_within.hpp).
// Conversions and docstrings only. Python owner: tripod_processor.reconstruction.stations.
#include <nanobind/stl/tuple.h>

#include "common.hpp"
#include "tripod_core/nearest_within.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

TRIPOD_BINDING(nearest) {
    using Rows = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
    m.def(
        "nearest_within",
        [](Rows ref, Rows query, double radius) {
            tripod::NearestWithin r;
            {
                nb::gil_scoped_release release;
                r = tripod::nearest_within(ref.data(), static_cast<int64_t>(ref.shape(0)),
                                           query.data(), static_cast<int64_t>(query.shape(0)),
                                           radius);
            }
            const int64_t ties = r.ties;
            return std::make_tuple(owned_array(std::move(r.dist)), owned_array(std::move(r.index)),
                                   ties);
        },
        nb::arg("ref"), nb::arg("query"), nb::arg("radius"),
        "(dist, index, ties): per query row the nearest ref row strictly closer than radius, "
        "as scipy's cKDTree.query(k=1, distance_upper_bound=radius) gives them (inf / len(ref) "
        "where none is); ties counts the queries whose nearest distance two refs share (there "
        "the lowest index, where cKDTree keeps the one its traversal meets first). Private: see "
        "tripod_processor.reconstruction.stations.");
}
