// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/octree_codec.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "tripod_core/range_coder.hpp"

namespace tripod {

namespace {

// ---- Morton codes (x in bit 3k+2, y in 3k+1, z in 3k) -----------------------------------------
constexpr uint64_t kMaskZ = 0x1249249249249249ull;  // bits 0, 3, ..., 60
constexpr uint64_t kMaskY = kMaskZ << 1;
constexpr uint64_t kMaskX = kMaskZ << 2;

inline uint64_t spread3(uint64_t v) {
    v &= 0x1fffffull;
    v = (v | v << 32) & 0x1f00000000ffffull;
    v = (v | v << 16) & 0x1f0000ff0000ffull;
    v = (v | v << 8) & 0x100f00f00f00f00full;
    v = (v | v << 4) & 0x10c30c30c30c30c3ull;
    v = (v | v << 2) & 0x1249249249249249ull;
    return v;
}

inline uint32_t compact3(uint64_t v) {
    v &= 0x1249249249249249ull;
    v = (v ^ (v >> 2)) & 0x10c30c30c30c30c3ull;
    v = (v ^ (v >> 4)) & 0x100f00f00f00f00full;
    v = (v ^ (v >> 8)) & 0x1f0000ff0000ffull;
    v = (v ^ (v >> 16)) & 0x1f00000000ffffull;
    v = (v ^ (v >> 32)) & 0x1fffffull;
    return static_cast<uint32_t>(v);
}

inline uint64_t morton(uint64_t x, uint64_t y, uint64_t z) {
    return (spread3(x) << 2) | (spread3(y) << 1) | spread3(z);
}

// ---- neighbours by propagation: the 27-neighbourhood of a child comes from its parent's -------
// Node slots: (dx+1)*9 + (dy+1)*3 + (dz+1) for (dx, dy, dz) in {-1,0,1}^3; slot 13 is the node.
// The neighbour of child o (octant) of node P at offset d lies in parent P + floor((o+d)/2) at
// child bit (o+d) mod 2, so one level's neighbour indices follow from the level above without
// any search (and neighbours outside the grid never exist, since the root has none).
struct ChildSlotTable {
    uint8_t parent_slot[8][27];
    uint8_t child_bit[8][27];
};

ChildSlotTable make_child_slot_table() {
    ChildSlotTable t{};
    for (int c = 0; c < 8; ++c) {
        const int o[3] = {(c >> 2) & 1, (c >> 1) & 1, c & 1};
        int s = 0;
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz, ++s) {
                    const int d[3] = {dx, dy, dz};
                    int ps = 0, bit = 0;
                    for (int a = 0; a < 3; ++a) {
                        const int tt = o[a] + d[a];                      // -1 .. 2
                        const int pa = tt < 0 ? -1 : (tt > 1 ? 1 : 0);  // floor(tt / 2)
                        ps = ps * 3 + (pa + 1);
                        bit = (bit << 1) | (tt - 2 * pa);
                    }
                    t.parent_slot[c][s] = static_cast<uint8_t>(ps);
                    t.child_bit[c][s] = static_cast<uint8_t>(bit);
                }
    }
    return t;
}

const ChildSlotTable kChildSlots = make_child_slot_table();

/// first_child[i]: index in the next level of the first child of node i (prefix popcounts).
void first_children(const std::vector<uint8_t>& cb, std::vector<uint32_t>& first_child) {
    first_child.resize(cb.size());
    uint32_t acc = 0;
    for (size_t i = 0; i < cb.size(); ++i) {
        first_child[i] = acc;
        acc += static_cast<uint32_t>(__builtin_popcount(cb[i]));
    }
}

/// Neighbour slots (27 per node) of every node of the next level.
void next_level_neighbours(const std::vector<int32_t>& nb, const std::vector<uint8_t>& cb,
                           const std::vector<uint32_t>& first_child, size_t n_next,
                           std::vector<int32_t>& nb_next, int num_threads) {
    nb_next.resize(27 * n_next);
    const int64_t n = static_cast<int64_t>(cb.size());
#pragma omp parallel for num_threads(num_threads) schedule(static) if (n > 4096)
    for (int64_t i = 0; i < n; ++i) {
        const int32_t* np = &nb[27 * i];
        int32_t* out = &nb_next[27 * static_cast<size_t>(first_child[i])];
        const uint32_t byte = cb[i];
        for (int c = 0; c < 8; ++c) {
            if (!((byte >> c) & 1u)) continue;
            for (int s = 0; s < 27; ++s) {
                const int32_t g = np[kChildSlots.parent_slot[c][s]];
                if (g < 0) {
                    out[s] = -1;
                    continue;
                }
                const uint32_t b = cb[g];
                const uint32_t bit = kChildSlots.child_bit[c][s];
                out[s] = ((b >> bit) & 1u)
                             ? static_cast<int32_t>(first_child[g] +
                                                    __builtin_popcount(b & ((1u << bit) - 1u)))
                             : -1;
            }
            out += 27;
        }
    }
}

std::vector<int32_t> root_neighbours() {
    std::vector<int32_t> nb(27, -1);
    nb[13] = 0;
    return nb;
}

// ---- context layout (see the header) ----------------------------------------------------------
struct ContextTables {
    uint8_t causal_slot[8][7];  // neighbour slot holding child-level neighbour k of child c
    uint8_t causal_bit[8][7];   // ... and the child bit of that neighbour
    uint8_t parent_slot[8][7];  // parent-level neighbour k towards the octant of child c
};

ContextTables make_context_tables() {
    ContextTables t{};
    for (int c = 0; c < 8; ++c) {
        const int o[3] = {(c >> 2) & 1, (c >> 1) & 1, c & 1};
        for (int k = 1; k <= 7; ++k) {
            const int sel[3] = {(k >> 2) & 1, (k >> 1) & 1, k & 1};
            int slot = 0, bit = 0, pslot = 0;
            for (int a = 0; a < 3; ++a) {
                const int t_a = o[a] - sel[a];           // child-level coordinate - 2 * parent
                const int p = t_a < 0 ? -1 : 0;          // parent offset
                const int cb = t_a < 0 ? 1 : t_a;        // child bit in that parent
                slot = slot * 3 + (p + 1);
                bit = (bit << 1) | cb;
                const int s = sel[a] ? (o[a] ? 1 : -1) : 0;  // towards the octant
                pslot = pslot * 3 + (s + 1);
            }
            t.causal_slot[c][k - 1] = static_cast<uint8_t>(slot);
            t.causal_bit[c][k - 1] = static_cast<uint8_t>(bit);
            t.parent_slot[c][k - 1] = static_cast<uint8_t>(pslot);
        }
    }
    return t;
}

const ContextTables kTables = make_context_tables();

/// The per-node part of the contexts, gathered once per node; a child's context is then a few
/// bit operations (see the header for the layout).
struct NodeContext {
    uint32_t base[8];       // per child: level, density, octant and parent-level bits
    uint32_t slot_byte[27]; // child bytes of the neighbours coded before this node, else 0
};

inline void make_node_context(const int32_t nb[27], int32_t self, const uint8_t* child_bytes,
                              uint32_t level_field, NodeContext& nc) {
    uint32_t occ = 0, sum = 0, m = 0;
    for (int s = 0; s < 27; ++s) {
        const int32_t j = nb[s];
        uint32_t byte = 0;
        if (j >= 0) {
            occ |= 1u << s;
            if (j < self) {
                byte = child_bytes[j];
                sum += static_cast<uint32_t>(__builtin_popcount(byte));
                ++m;
            }
        }
        nc.slot_byte[s] = byte;
    }
    // density of the coded neighbourhood: occupied children per child cell, bucketed
    const uint32_t density =
        (m == 0 || sum < m) ? 0u : (sum < 2 * m ? 1u : (sum < 4 * m ? 2u : 3u));
    const uint32_t node_bits = level_field | (density << 19);
    for (int c = 0; c < 8; ++c) {
        uint32_t v = node_bits | (static_cast<uint32_t>(c) << 14);
        for (int k = 0; k < 7; ++k) v |= ((occ >> kTables.parent_slot[c][k]) & 1u) << (7 + k);
        nc.base[c] = v;
    }
}

/// Context of child c given the bits of this node decoded so far (`partial`).
inline uint32_t child_context(NodeContext& nc, int c, uint32_t partial) {
    nc.slot_byte[13] = partial;  // the node itself: only its earlier children are known
    // bit 21: has this node an occupied child already? (not all earlier siblings are causal
    // neighbours, e.g. children 1..3 for child 4, so a lone child would otherwise go unseen)
    uint32_t ctx = nc.base[c] | (static_cast<uint32_t>(partial != 0) << 21);
    for (int k = 0; k < 7; ++k)
        ctx |= ((nc.slot_byte[kTables.causal_slot[c][k]] >> kTables.causal_bit[c][k]) & 1u) << k;
    return ctx;
}

inline uint32_t level_bits(int depth, int level) {
    return static_cast<uint32_t>(std::min(depth - 1 - level, 3)) << 17;
}

/// Per-context probabilities: the learned prior, adapted towards the coded bits with integer
/// updates that the decoder repeats exactly. prior == 0: fixed rate 1/2^shift; prior > 0: rate
/// 1/(n + prior) after n updates of the context (a count-based estimate that starts at the
/// learned value, worth `prior` observations), never below 1/2^shift; shift <= 0: static.
class ContextStates {
public:
    ContextStates(const uint16_t* table, int shift, int prior)
        : p0_(table, table + kOctreeContexts), shift_(shift), prior_(prior) {
        if (shift_ > 0 && prior_ > 0) {
            n_.assign(kOctreeContexts, 0);
            for (uint32_t n = 0; n < 256; ++n)
                rate_[n] = std::max<uint32_t>(65536u / (n + static_cast<uint32_t>(prior_)),
                                              65536u >> std::min(shift_, 16));
        }
    }

    inline uint32_t p0(uint32_t ctx) const { return p0_[ctx]; }

    inline void update(uint32_t ctx, int bit) {
        if (shift_ <= 0) return;
        int p = p0_[ctx];
        if (prior_ > 0) {
            uint8_t& n = n_[ctx];
            const int64_t step = static_cast<int64_t>((bit ? 0 : 65536) - p) * rate_[n];
            p += static_cast<int>(step >= 0 ? step >> 16 : -((-step) >> 16));
            if (n < 255) ++n;
        } else if (bit) {
            p -= p >> shift_;
        } else {
            p += (65536 - p) >> shift_;
        }
        p0_[ctx] = static_cast<uint16_t>(std::clamp(p, 32, 65504));
    }

private:
    std::vector<uint16_t> p0_;
    std::vector<uint8_t> n_;
    uint32_t rate_[256] = {};
    int shift_;
    int prior_;
};

void check_depth(int depth) {
    if (depth < 1 || depth > kOctreeMaxDepth)
        throw std::invalid_argument("octree depth must be in 1.." + std::to_string(kOctreeMaxDepth));
}

/// Walk the octree of `codes` in coding order and call sink(context, bit) for every coded bit.
/// Contexts of a level are computed in parallel (the encoder knows every bit), then replayed.
template <class Sink>
void walk_encoder(const std::vector<uint64_t>& codes, int depth, Sink&& sink) {
    check_depth(depth);
    if (codes.empty()) return;
    const int num_threads = omp_get_max_threads();
    // levels bottom-up: child-occupancy bytes of every node
    std::vector<std::vector<uint8_t>> bytes(depth);
    {
        std::vector<uint64_t> below = codes, nodes;
        for (int l = depth - 1; l >= 0; --l) {
            nodes.clear();
            auto& b = bytes[l];
            b.reserve(below.size() / 2 + 1);
            for (uint64_t code : below) {
                const uint64_t parent = code >> 3;
                if (nodes.empty() || nodes.back() != parent) {
                    nodes.push_back(parent);
                    b.push_back(0);
                }
                b.back() |= static_cast<uint8_t>(1u << (code & 7));
            }
            below.swap(nodes);
        }
    }
    constexpr uint32_t kSkip = ~0u;
    std::vector<int32_t> nb = root_neighbours(), nb_next;
    std::vector<uint32_t> first_child, ctx;
    for (int l = 0; l < depth; ++l) {
        const auto& cbv = bytes[l];
        const uint8_t* cb = cbv.data();
        const int64_t n = static_cast<int64_t>(cbv.size());
        const uint32_t lb = level_bits(depth, l);
        ctx.resize(8 * cbv.size());
#pragma omp parallel for num_threads(num_threads) schedule(static) if (n > 4096)
        for (int64_t i = 0; i < n; ++i) {
            const int32_t self = static_cast<int32_t>(i);
            const int32_t* nbi = &nb[27 * i];
            const uint32_t byte = cb[i];
            NodeContext nc;
            make_node_context(nbi, self, cb, lb, nc);
            uint32_t partial = 0;
            for (int c = 0; c < 8; ++c) {
                if (c == 7 && partial == 0) {  // implied: a node is never empty
                    ctx[8 * i + c] = kSkip;
                    break;
                }
                ctx[8 * i + c] = child_context(nc, c, partial);
                partial |= ((byte >> c) & 1u) << c;
            }
        }
        for (int64_t i = 0; i < n; ++i) {
            const uint32_t byte = cb[i];
            for (int c = 0; c < 8; ++c) {
                const uint32_t x = ctx[8 * i + c];
                if (x == kSkip) break;
                sink(x, static_cast<int>((byte >> c) & 1u));
            }
        }
        if (l + 1 < depth) {
            first_children(cbv, first_child);
            next_level_neighbours(nb, cbv, first_child, bytes[l + 1].size(), nb_next, num_threads);
            nb.swap(nb_next);
        }
    }
}

}  // namespace

std::vector<uint64_t> voxelize_morton(const PointsXYZ& points, const double origin[3],
                                      double voxel_size, int depth, int num_threads) {
    check_depth(depth);
    if (!(voxel_size > 0.0)) throw std::invalid_argument("voxel_size must be > 0");
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    const int64_t n = points.rows();
    const double inv = 1.0 / voxel_size;
    const double top = static_cast<double>((int64_t{1} << depth) - 1);
    std::vector<uint64_t> codes(n);
    std::vector<char> ok(n);
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const float* p = points.row(i).data();
        ok[i] = std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
        if (!ok[i]) continue;
        uint64_t q[3];
        for (int a = 0; a < 3; ++a) {
            const double v = std::floor((static_cast<double>(p[a]) - origin[a]) * inv);
            q[a] = static_cast<uint64_t>(std::clamp(v, 0.0, top));
        }
        codes[i] = morton(q[0], q[1], q[2]);
    }
    size_t m = 0;
    for (int64_t i = 0; i < n; ++i)
        if (ok[i]) codes[m++] = codes[i];
    codes.resize(m);
    // sort the two halves in parallel, then merge
    const auto mid = codes.begin() + static_cast<std::ptrdiff_t>(m / 2);
    if (num_threads > 1 && m > 100000) {
#pragma omp parallel sections num_threads(2)
        {
#pragma omp section
            std::sort(codes.begin(), mid);
#pragma omp section
            std::sort(mid, codes.end());
        }
        std::inplace_merge(codes.begin(), mid, codes.end());
    } else {
        std::sort(codes.begin(), codes.end());
    }
    codes.erase(std::unique(codes.begin(), codes.end()), codes.end());
    return codes;
}

PointsXYZ morton_to_points(const std::vector<uint64_t>& codes, const double origin[3],
                           double voxel_size, int num_threads) {
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    const int64_t m = static_cast<int64_t>(codes.size());
    PointsXYZ out(m, 3);
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int64_t i = 0; i < m; ++i) {
        const uint64_t c = codes[i];
        for (int a = 0; a < 3; ++a) {
            const double q = compact3(c >> (2 - a));
            out(i, a) = static_cast<float>(origin[a] + (q + 0.5) * voxel_size);
        }
    }
    return out;
}

void octree_contexts(const std::vector<uint64_t>& codes, int depth,
                     std::vector<uint32_t>& contexts, std::vector<uint8_t>& bits) {
    contexts.clear();
    bits.clear();
    walk_encoder(codes, depth, [&](uint32_t ctx, int bit) {
        contexts.push_back(ctx);
        bits.push_back(static_cast<uint8_t>(bit));
    });
}

std::vector<uint8_t> octree_encode(const std::vector<uint64_t>& codes, int depth,
                                   const uint16_t* p0_table, int adapt_shift, int adapt_prior) {
    std::vector<uint8_t> out;
    out.reserve(codes.size() / 2 + 16);
    ContextStates states(p0_table, adapt_shift, adapt_prior);
    RangeEncoder enc(out);
    walk_encoder(codes, depth, [&](uint32_t ctx, int bit) {
        enc.encode(states.p0(ctx), bit);
        states.update(ctx, bit);
    });
    enc.finish();
    return out;
}

std::vector<uint64_t> octree_decode(const uint8_t* data, size_t size, int depth,
                                    uint64_t n_voxels, const uint16_t* p0_table,
                                    int adapt_shift, int adapt_prior) {
    check_depth(depth);
    std::vector<uint64_t> cur;
    if (n_voxels == 0) return cur;
    const int num_threads = omp_get_max_threads();
    ContextStates states(p0_table, adapt_shift, adapt_prior);
    RangeDecoder dec(data, size);
    std::vector<uint64_t> next;
    std::vector<uint8_t> cb;
    std::vector<uint32_t> first_child;
    std::vector<int32_t> nb = root_neighbours(), nb_next;
    cur.push_back(0);
    for (int l = 0; l < depth; ++l) {
        cb.assign(cur.size(), 0);
        const uint32_t lb = level_bits(depth, l);
        uint64_t n_children = 0;
        for (size_t i = 0; i < cur.size(); ++i) {
            const int32_t self = static_cast<int32_t>(i);
            const int32_t* nbi = &nb[27 * i];
            NodeContext nc;
            make_node_context(nbi, self, cb.data(), lb, nc);
            uint32_t partial = 0;
            for (int c = 0; c < 8; ++c) {
                int bit;
                if (c == 7 && partial == 0) {
                    bit = 1;
                } else {
                    const uint32_t ctx = child_context(nc, c, partial);
                    bit = dec.decode(states.p0(ctx));
                    states.update(ctx, bit);
                }
                partial |= static_cast<uint32_t>(bit) << c;
            }
            cb[i] = static_cast<uint8_t>(partial);
            n_children += static_cast<uint64_t>(__builtin_popcount(partial));
            if (n_children > n_voxels)
                throw std::runtime_error("corrupt octree stream: more nodes than voxels");
        }
        if (dec.overrun()) throw std::runtime_error("corrupt octree stream: ran past its end");
        next.resize(n_children);
        size_t k = 0;
        for (size_t i = 0; i < cur.size(); ++i) {
            const uint64_t base = cur[i] << 3;
            for (int c = 0; c < 8; ++c)
                if ((cb[i] >> c) & 1u) next[k++] = base | static_cast<uint64_t>(c);
        }
        if (l + 1 < depth) {
            first_children(cb, first_child);
            next_level_neighbours(nb, cb, first_child, n_children, nb_next, num_threads);
            nb.swap(nb_next);
        }
        cur.swap(next);
    }
    if (cur.size() != n_voxels)
        throw std::runtime_error("corrupt octree stream: decoded " + std::to_string(cur.size()) +
                                 " voxels, header says " + std::to_string(n_voxels));
    return cur;
}

}  // namespace tripod
