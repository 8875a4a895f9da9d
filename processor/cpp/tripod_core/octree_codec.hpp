// SPDX-License-Identifier: BSD-3-Clause
// Octree geometry codec: occupancy bits coded by a binary range coder whose probabilities come
// from a learned context table (see tripod_processor/compression/model.py).
//
// The cloud is quantised to a voxel grid of 2^depth cells per axis and stored as sorted, unique
// Morton codes (x in bit 3k+2, y in 3k+1, z in 3k). The octree is coded breadth first, level by
// level, nodes in Morton order; each node codes its 8 child-occupancy bits in child order. The
// context of a child bit packs, in kOctreeContextBits bits:
//   bits  0..6   occupancy of the 7 child-level neighbours C + d, d in {-1,0}^3 \ {0} (all are
//                already coded: they are earlier siblings or children of earlier nodes)
//   bits  7..13  occupancy of the 7 parent-level neighbours towards the child's octant
//   bits 14..16  the child index (octant) 0..7
//   bits 17..18  min(levels left below the parent - 1, 3): 0 = the children are leaves
//   bits 19..20  density of the coded neighbourhood: occupied children per child cell over the
//                parent-level neighbours coded before this node, bucketed <1/8, <1/4, <1/2, more
//   bit  21      whether an earlier child of this node is occupied
// The last child bit of a node whose first seven are empty is implied (a node is never empty).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod {

/// Bits of one occupancy context; the probability table has 1 << kOctreeContextBits entries.
constexpr int kOctreeContextBits = 22;
constexpr size_t kOctreeContexts = size_t{1} << kOctreeContextBits;
/// Deepest supported octree: 21 levels (3 * 21 = 63-bit Morton codes).
constexpr int kOctreeMaxDepth = 21;

/// Quantise points to voxel indices floor((p - origin) / voxel_size), clamp them to
/// [0, 2^depth), and return their sorted unique Morton codes. Non-finite points are dropped.
/// @param points      N x 3 [m]
/// @param origin      grid corner [m]
/// @param voxel_size  voxel edge [m], > 0
/// @param depth       1..kOctreeMaxDepth
/// @param num_threads 0 = all available
std::vector<uint64_t> voxelize_morton(const PointsXYZ& points, const double origin[3],
                                      double voxel_size, int depth, int num_threads = 0);

/// Voxel centres origin + (index + 0.5) * voxel_size of sorted Morton codes, as M x 3 [m].
PointsXYZ morton_to_points(const std::vector<uint64_t>& codes, const double origin[3],
                           double voxel_size, int num_threads = 0);

/// Every coded occupancy decision of the octree of `codes` as (context, bit) pairs, in coding
/// order: the training data of the context model.
/// @param codes  sorted unique Morton codes < 2^(3 depth)
void octree_contexts(const std::vector<uint64_t>& codes, int depth, std::vector<uint32_t>& contexts,
                     std::vector<uint8_t>& bits);

/// Encode the octree of sorted unique Morton codes.
/// @param p0_table    kOctreeContexts probabilities P(bit = 0) * 65536, each in [1, 65535]
/// @param adapt_shift 0: static table; s > 0: each context's probability moves towards every
///                    coded bit (an integer update the decoder repeats exactly) by 1/2^s, or
/// @param adapt_prior if > 0: by 1/(n + adapt_prior) after n updates of that context, at least
///                    1/2^s (the learned probability counts as adapt_prior observations)
/// @return the range-coded stream
std::vector<uint8_t> octree_encode(const std::vector<uint64_t>& codes, int depth,
                                   const uint16_t* p0_table, int adapt_shift, int adapt_prior = 0);

/// Decode a stream of octree_encode back to the sorted Morton codes.
/// @param n_voxels  number of voxels the encoder coded (from the container); a stream that
///                  decodes to another count, or needs bytes it does not have, throws
///                  std::runtime_error
std::vector<uint64_t> octree_decode(const uint8_t* data, size_t size, int depth,
                                    uint64_t n_voxels, const uint16_t* p0_table,
                                    int adapt_shift, int adapt_prior = 0);

}  // namespace tripod
