// SPDX-License-Identifier: BSD-3-Clause
// Exact nearest neighbour within a radius, in double, on a hashed grid (cells as wide as the
// radius, sorted by cell key; each query sweeps the 3 x 3 columns around its cell). Made for
// many small queries with a short radius (the station splitter's direction matches: ~12000
// unit vectors, ~4000 queries, 0.3 degrees), where building a k-d tree costs more than the
// whole search. The squared distance is summed as scipy's cKDTree sums it, ((dx² + dy²) + dz²),
// and a match is kept when it is strictly below radius² — so distances and indices are those of
// cKDTree.query(k=1, distance_upper_bound=radius) bit for bit, except where two references lie
// at exactly the same distance from a query (cKDTree keeps whichever its traversal meets first;
// this returns the lowest index and counts the query in `ties`).
#pragma once

#include <cstdint>
#include <vector>

namespace tripod {

/// Result of nearest_within: one entry per query.
struct NearestWithin {
    std::vector<double> dist;    ///< distance to the nearest reference; +inf when none is near
    std::vector<int64_t> index;  ///< its row in the references; n_ref when none is near
    int64_t ties = 0;            ///< queries whose nearest distance two or more references share
};

/// For each query row, the nearest reference row closer than `radius` (strictly).
/// @param ref     n_ref x 3 row-major doubles, all finite
/// @param n_ref   number of reference rows
/// @param query   n_query x 3 row-major doubles, all finite
/// @param n_query number of query rows
/// @param radius  search radius (same unit as the points), finite and > 0
/// @throws std::invalid_argument on a non-finite point or radius <= 0, or when the references
///         span more than 2^60 cells of the radius
NearestWithin nearest_within(const double* ref, int64_t n_ref, const double* query,
                             int64_t n_query, double radius);

}  // namespace tripod
