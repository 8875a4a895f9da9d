// SPDX-License-Identifier: BSD-3-Clause
// Predictive geometry codec for ordered sensor scans (in the way of MPEG G-PCC's predictive
// geometry with the angular mode).
//
// Points are coded one after another, in the order given, in spherical coordinates about the
// sensor origin: range r, azimuth az in (-pi, pi], elevation el in [-pi/2, pi/2]. Each is first
// quantised to an integer on its own, with no prediction involved, so the reconstruction error of
// every point is that of the quantiser alone (no drift):
//   range      k = round(r / range_step)                    (range_step: a multiple of a detected
//                                                            range lattice, or free)
//   azimuth    a = round(az / (2 pi / az_count)) mod az_count
//   elevation  e = index of the nearest entry of a table of elevations (a detected lattice: the
//                  lasers of a spinning lidar, the steps of a tilting scanner), or
//              e = round(el / el_step) without a table.
// Per-laser model (G-PCC's angular mode): with a z_table, entry e is a laser whose beam leaves
// the spin axis at height z_table[e] above the origin (a multi-beam lidar's per-laser vertical
// offset) at elevation el_table[e]; a point is then assigned the laser whose beam cone it lies
// nearest, its range is measured from that laser's own centre (0, 0, z_e), and it is
// reconstructed as origin + (r cos el_e cos az, r cos el_e sin az, z_e + r sin el_e).
// The integers are then coded losslessly with prediction from earlier points and a binary range
// coder whose probabilities adapt online (contexts below), so encoder and decoder agree exactly:
//   e: the residual against the index that followed e_{i-1} the last time that row was seen (a
//      scan repeats its row order: a tilting scanner's sweep, a lidar's laser firing order);
//      context = the size of the previous residual;
//   a: with az_predictor 0, the step a_i - a_{i-1} (wrapped); with 1, the better (so far, by a
//      decaying score both sides keep) of that and a_{i-1} + (the row's last azimuth - the one
//      row e_{i-1} had before): a spinning lidar's firing repeats its per-laser azimuth offsets
//      (firing-time interpolation) every firing; context = whether e was predicted exactly and
//      the size of the previous azimuth residual;
//   k: the residual against the median edge detector of LOCO-I (JPEG-LS) over the scan seen as
//      an image whose rows are elevation indices (the lasers of a spinning lidar, the steps of a
//      tilting scanner): from the previous point, the last range in this row (the previous
//      revolution or sweep) and that sweep's range in the previous point's row; context = the
//      local range gradient and the size of the previous residual.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// The quantisation grid of the predictive codec (all of it is stored in the file).
struct SphericalGrid {
    double origin[3] = {0.0, 0.0, 0.0};  ///< sensor origin [m]
    double range_step = 0.001;           ///< [m]
    int64_t az_count = 1 << 16;          ///< azimuth steps per turn (step 2 pi / az_count)
    double el_step = 1e-4;               ///< [rad] (used when el_table is empty)
    std::vector<double> el_table;        ///< sorted elevations [rad], or empty
    int row_shift = 0;  ///< without a table: scan row of index e is e >> row_shift
    std::vector<double> z_table;  ///< per-laser heights [m] (size of el_table), or empty
    int az_predictor = 0;         ///< 0: previous azimuth; 1: adaptive with the row predictor
};

/// Range, azimuth and elevation of points about `origin`, as N x 3 doubles ([m], [rad], [rad]).
std::vector<double> cartesian_to_spherical(const PointsXYZ& points, const double origin[3],
                                           int num_threads = 0);

/// What predictive_encode measured while coding (for the caller's checks and reports).
struct PredictiveStats {
    double max_error_m = 0.0;  ///< largest distance of a decoded point from its input point
    uint32_t checksum = 0;     ///< FNV-1a of the quantised points (store it for the decoder)
    double part_bits[3] = {0, 0, 0};  ///< estimated bits spent on elevation, azimuth, range
};

/// Quantise `points` to `grid` and code them in order.
/// @param points N x 3 [m], all finite
/// @return the range-coded stream (N is not in it: the caller stores it)
std::vector<uint8_t> predictive_encode(const PointsXYZ& points, const SphericalGrid& grid,
                                       PredictiveStats* stats = nullptr, int num_threads = 0);

/// Decode `n_points` points of a predictive_encode stream, in their coding order.
/// Throws std::runtime_error when the stream is corrupt: it needs bytes it does not have,
/// decodes an out-of-range index, or the decoded points do not match `expected_checksum`
/// (PredictiveStats::checksum of the encoder).
PointsXYZ predictive_decode(const uint8_t* data, size_t size, uint64_t n_points,
                            const SphericalGrid& grid, uint32_t expected_checksum,
                            int num_threads = 0);

}  // namespace tripod
