// SPDX-License-Identifier: BSD-3-Clause
// A static k-d tree over float points of fixed dimension (3 for clouds, 33 for FPFH features).
// Points are copied in tree order so a leaf scan reads contiguous memory; indices returned are
// the caller's row indices. Header-only so the compiler specialises the search on Dim.
// Each node keeps the tight bounding box of its points (searches prune on it: scans sample
// surfaces, and a node's cell is mostly empty space) and its cell (the box its splits bound):
// a warm-started nearest-neighbour query climbs from the hint's leaf only to the first cell that
// holds its ball (ICP's later iterations, where points barely move, scan a leaf or two).
// With hint lists (each point's nearest others, set_hints(), from prepare_cloud()'s k-NN) most
// warm-started queries are answered from the hint's list alone, with the search's answer.
#pragma once

#include <omp.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <numeric>
#include <stdexcept>
#include <vector>

#include "tripod_core/parallel_chunks.hpp"
#include "tripod_core/phase_timer.hpp"

namespace tripod {

/// Static k-d tree (median split on the widest axis, leaves of up to `leaf_size` points).
template <int Dim>
class KdTree {
public:
    using Row = Eigen::Matrix<float, Dim, 1>;

    /// Build over `n` rows of `Dim` floats at `data` (row-major), all finite.
    /// @param data        n x Dim row-major floats (copied)
    /// @param n           number of rows
    /// @param leaf_size   points per leaf (>= 1)
    /// @param num_threads build threads (parallel_chunks; <= 0: all). The tree is the
    ///                    same whatever the count: a subtree's node numbers follow from its size.
    KdTree(const float* data, int64_t n, int leaf_size = 20, int num_threads = 1)
        : leaf_size_(std::max(1, leaf_size)) {
        const int nt = num_threads > 0 ? num_threads : omp_get_max_threads();
        const bool parallel = nt > 1 && n >= 2 * kTaskPoints;
        order_.resize(n);
        pts_.resize(static_cast<size_t>(n) * Dim);
        src_ = data;
        leaf_node_.resize(n);
        pos_.resize(n);
        if (n > 0) {
            count_nodes(static_cast<int>(n));
            const size_t total = static_cast<size_t>(subtree_nodes(static_cast<int>(n)));
            nodes_.resize(total);
            boxes_.resize(total * 2 * Dim);
            cells_.resize(total * 2 * Dim);
            parent_.resize(total);
            const Row lo = Row::Constant(-std::numeric_limits<float>::infinity()), hi = -lo;
            std::iota(order_.begin(), order_.end(), 0);
            // each leaf copies its rows when made: no pass after the build
            if (parallel) {
                // level by level: the nodes of a level split in parallel, then the subtrees
                // below 2 * kTaskPoints points built whole in parallel (parallel_chunks: a
                // thread that comes late holds no one up); node numbers follow from sizes
                std::vector<Pending> level{{0, 0, static_cast<int>(n), -1, lo, hi}}, next, rest;
                while (!level.empty()) {
                    next.assign(2 * level.size(), Pending{});
                    detail::parallel_chunks(
                        nt, static_cast<int64_t>(level.size()),
                        [&](int64_t k) { make_node(level[k], &next[2 * k]); },
                        "kdtree build: level");
                    level.clear();
                    for (const Pending& c : next) {
                        if (c.id < 0) continue;
                        (c.end - c.begin >= 2 * kTaskPoints ? level : rest).push_back(c);
                    }
                }
                detail::parallel_chunks(
                    nt, static_cast<int64_t>(rest.size()),
                    [&](int64_t k) {
                        const Pending& p = rest[k];
                        build(p.id, p.begin, p.end, p.lo, p.hi, p.parent);
                    },
                    "kdtree build: subtrees");
            } else {
                build(0, 0, static_cast<int>(n), lo, hi, -1);
            }
        }
        src_ = nullptr;
        subtree_nodes_m_.clear();
    }

    int64_t size() const { return static_cast<int64_t>(order_.size()); }

    /// Row indices in tree order: querying in this order is spatially coherent (cache friendly).
    const std::vector<int64_t>& order() const { return order_; }

    /// k nearest neighbours of q, ascending distance.
    /// @param q       query, Dim floats
    /// @param k       wanted neighbours
    /// @param idx     out: k row indices (first `return` valid)
    /// @param sq_dist out: k squared distances [m^2 for points]
    /// @return number found (min(k, size()))
    int knn(const float* q, int k, int* idx, float* sq_dist) const {
        if (nodes_.empty() || k <= 0) return 0;
        int found = 0;
        float worst = std::numeric_limits<float>::infinity();
        float off[Dim] = {};
        knn_rec(0, q, k, idx, sq_dist, found, worst, 0.f, off);
        return found;
    }

    /// Nearest neighbour within sqrt(max_sq_dist); returns its row index or -1.
    int nearest(const float* q, float max_sq_dist, float* sq_dist) const {
        int idx = -1;
        float best = max_sq_dist;
        if (!nodes_.empty() && box_dist(0, q) < best) nn_box(0, q, idx, best);
        if (sq_dist) *sq_dist = best;
        return idx;
    }

    /// Nearest neighbour within sqrt(max_sq_dist), warm-started from a row `hint` (e.g. the
    /// previous ICP iteration's match; -1 for none). The search starts at the hint's leaf and
    /// climbs to the first node whose cell holds the whole ball about q through the hint (no
    /// point outside that cell can be nearer), then searches that subtree only: in ICP's later
    /// iterations, where points barely move, a leaf or two. Same answer as nearest() up to
    /// ties.
    int nearest_from(const float* q, float max_sq_dist, int hint, float* sq_dist) const {
        int idx = -1;
        float best = max_sq_dist;
        int node = 0;
        if (!nodes_.empty() && hint >= 0) {
            const int pos = pos_[hint];
            const float d = sq(q, point_at(pos));
            if (d < best) {
                best = d;
                idx = hint;
                // the hint's neighbour list, when the query is close enough to the hint for
                // the nearest to be on it (the search's answer, bit for bit; see set_hints)
                if (!hint_reach_sq_.empty()) {
                    const int found = nearest_on_list(q, pos, d, idx, best);
                    if (found != kUndecided) {
                        if (sq_dist) *sq_dist = best;
                        return found;
                    }
                }
            }
            node = leaf_node_[pos];
            while (node != 0 && !ball_inside(node, q, best)) node = parent_[node];
        }
        if (!nodes_.empty() && box_dist(node, q) < best) nn_box(node, q, idx, best);
        if (sq_dist) *sq_dist = best;
        return idx;
    }

    /// Others on a stored point's hint list (set_hints()).
    static constexpr int kHintList = 11;

    /// Give the tree each stored point's nearest other stored points, by tree position, e.g.
    /// from a k-NN pass the caller makes anyway: `list` holds kHintList tree positions per
    /// position (ascending distance, -1 after the last when there are fewer), `first_sq` per
    /// position a squared distance no other point is nearer than (the first listed one's),
    /// `reach_sq` one no unlisted point is nearer than (+inf when every other point is
    /// listed; 0 for either: unknown). nearest_from() then answers without the tree when the
    /// query lies closer to its hint than half the reach: the nearest is then the hint or on
    /// its list (triangle inequality), and the list's strictly nearest, or the hint when none
    /// is nearer, is the search's answer bit for bit; an exact tie on the list goes to the
    /// search, which breaks it as before. Empty vectors: no lists.
    void set_hints(std::vector<int> list, std::vector<float> first_sq,
                   std::vector<float> reach_sq) {
        if (!(list.empty() && first_sq.empty() && reach_sq.empty()) &&
            (reach_sq.size() != order_.size() || first_sq.size() != order_.size() ||
             list.size() != order_.size() * kHintList))
            throw std::invalid_argument("set_hints: kHintList positions and two values per point");
        hint_list_ = std::move(list);
        hint_first_sq_ = std::move(first_sq);
        hint_reach_sq_ = std::move(reach_sq);
    }
    bool has_hints() const { return !hint_reach_sq_.empty(); }

    /// Whether every point farther than sqrt(`reach`) from a stored point p is farther from q
    /// than p is, when q lies at squared distance `d` from p (both as sq() computes them):
    /// 2 sqrt(d) < sqrt(reach), with a relative margin of 1e-4 on the squares, far above the
    /// float rounding of the sq() values (a few 1e-7): those points' sq() to q then exceeds d.
    static bool within_half(float d, float reach) {
        return 4.0 * (1.0 + 1e-4) * static_cast<double>(d) < static_cast<double>(reach);
    }

    /// nearest_from(q, max_sq_dist, -1, sq_dist), the search without a hint, bit for bit, tried
    /// first on the hint list of `guess` (a row likely near q, e.g. a neighbouring query's
    /// answer; -1: none): when q is close enough to the guess for the nearest to be the guess
    /// or on its list (set_hints()) and that nearest is unique, it is the search's answer
    /// whatever order the search visits; a tie (the guess included) goes to the search.
    int nearest_guessed(const float* q, float max_sq_dist, int guess, float* sq_dist) const {
        if (guess >= 0 && !hint_reach_sq_.empty()) {
            const int pos = pos_[guess];
            const float d = sq(q, point_at(pos));
            int arg = -1;
            float m = d;
            if (within_half(d, hint_first_sq_[pos])) {
                arg = pos;  // nearer than any other point
            } else if (within_half(d, hint_reach_sq_[pos])) {
                const int* list = hint_list_.data() + static_cast<size_t>(pos) * kHintList;
                int ties = 0;
                arg = pos;
                for (int j = 0; j < kHintList && list[j] >= 0; ++j) {
                    const float dj = sq(q, point_at(list[j]));
                    if (dj < m) {
                        m = dj;
                        arg = list[j];
                        ties = 0;
                    } else if (dj == m) {
                        ++ties;
                    }
                }
                if (ties > 0) arg = -1;
            }
            if (arg >= 0) {  // the unique nearest: the answer when within the bound, else none
                const bool in = m < max_sq_dist;
                if (sq_dist) *sq_dist = in ? m : max_sq_dist;
                return in ? static_cast<int>(order_[arg]) : -1;
            }
        }
        return nearest_from(q, max_sq_dist, -1, sq_dist);
    }

    /// The caller's row stored at tree position `pos`, and its coordinates (Dim floats).
    int64_t row_at(int64_t pos) const { return order_[pos]; }
    const float* point_at(int64_t pos) const { return pts_.data() + pos * Dim; }

    /// Groups of consecutive tree positions that are spatially compact (the subtrees of at most
    /// `max_points` points): boundaries g[0] = 0 < g[1] < ... < g.back() = size().
    std::vector<int> groups(int max_points) const {
        std::vector<int> g{0};
        if (nodes_.empty()) return g;
        int stack[128], sp = 0;
        stack[sp++] = 0;
        while (sp > 0) {
            const Node& nd = nodes_[stack[--sp]];
            if (nd.axis < 0 || nd.end - nd.begin <= max_points) {
                g.push_back(nd.end);
                continue;
            }
            stack[sp++] = nd.right;  // the left one is popped first: groups in position order
            stack[sp++] = nd.left;
        }
        return g;
    }

    /// Scratch buffers of knn_range (one per thread; reused, so queries allocate nothing).
    struct KnnScratch {
        std::vector<int> cand, idx;
        std::vector<uint64_t> key;
        std::vector<float> cx, cy, cz, d, dist;
    };

    /// k nearest neighbours of each stored point at the tree positions [begin, end) (best a
    /// group from groups(): the search is shared by the whole range). Calls
    /// fn(pos, nbr, sq_dist, m) per position, in order, with its m = min(k, size()) nearest
    /// neighbours as tree positions (point_at(), row_at()), itself included, in no particular
    /// order. Exact, ties at the k-th distance broken by tree position; each point's answer
    /// depends only on the tree and k, not on the range it is asked in.
    ///
    /// How: one k-NN search from the point nearest the range's centre gives a radius r0; the
    /// points within R = 1.5 r0 of the range's bounding box are gathered once (in SoA); each
    /// query takes its k nearest among those within R of it. With k of them there, no point
    /// outside can be nearer (the query lies in the box), so that is exact; with fewer (a query
    /// at the sparse edge of the range) the query searches the tree instead.
    template <class Fn>
    void knn_range(int k, int begin, int end, KnnScratch& s, Fn&& fn) const {
        static_assert(Dim == 3, "knn_range is for 3-D points");
        k = static_cast<int>(std::min<int64_t>(k, size()));
        if (k <= 0 || begin >= end) return;
        s.idx.resize(k);
        s.dist.resize(k);
        // 1. the range's box, and the point nearest its centre
        Row lo = Row::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
        for (int i = begin; i < end; ++i) {
            Eigen::Map<const Row> p(point_at(i));
            lo = lo.cwiseMin(p);
            hi = hi.cwiseMax(p);
        }
        const Row centre = 0.5f * (lo + hi);
        int q0 = begin;
        float best = std::numeric_limits<float>::infinity();
        for (int i = begin; i < end; ++i) {
            const float d = sq(centre.data(), point_at(i));
            if (d < best) best = d, q0 = i;
        }
        const int m0 = knn(point_at(q0), k, s.idx.data(), s.dist.data());
        const float r = 1.5f * std::sqrt(s.dist[m0 - 1]);
        const float R2 = r * r;
        // 2. candidates: the points within R of the box, in position order, as SoA
        s.cand.clear();
        box_range(0, lo.data(), hi.data(), R2, s.cand);
        const int nc = static_cast<int>(s.cand.size());
        s.cx.resize(nc);
        s.cy.resize(nc);
        s.cz.resize(nc);
        s.d.resize(nc);
        s.key.resize(nc);
        for (int j = 0; j < nc; ++j) {
            const float* p = point_at(s.cand[j]);
            s.cx[j] = p[0];
            s.cy[j] = p[1];
            s.cz[j] = p[2];
        }
        constexpr float kGuess = 1.25f;  // squared margin on the previous k-th distance
        float guess = kGuess * s.dist[m0 - 1];
        // 3. per query: distances to all candidates (vectorised), those within R, their k nearest
        for (int pos = begin; pos < end; ++pos) {
            const float* q = point_at(pos);
            const float qx = q[0], qy = q[1], qz = q[2];
            float* d = s.d.data();
            const float *cx = s.cx.data(), *cy = s.cy.data(), *cz = s.cz.data();
            for (int j = 0; j < nc; ++j) {
                const float ex = qx - cx[j], ey = qy - cy[j], ez = qz - cz[j];
                d[j] = ex * ex + ey * ey + ez * ez;  // the sum sq() forms
            }
            // keys (distance bits, candidate): a non-negative float's bits order as it does, and
            // the candidate (in position order) breaks ties as the position does. Only those
            // within a guess T of the k-th distance (the previous query's, a neighbour, with a
            // margin) are kept, to select from few; too few: again with R.
            uint64_t* key = s.key.data();
            int m = 0;
            for (float T = std::min(R2, guess);; T = R2) {
                m = 0;
                for (int j = 0; j < nc; ++j) {
                    uint32_t bits;
                    std::memcpy(&bits, &d[j], sizeof bits);
                    key[m] = (uint64_t(bits) << 32) | uint32_t(j);
                    m += d[j] <= T;
                }
                if (m >= k || T == R2) break;
            }
            if (m < k) {  // the k-th nearest may lie outside: search the tree
                const int f = knn(q, k, s.idx.data(), s.dist.data());
                for (int j = 0; j < f; ++j) s.idx[j] = pos_[s.idx[j]];
                guess = kGuess * s.dist[f - 1];
                fn(pos, static_cast<const int*>(s.idx.data()),
                   static_cast<const float*>(s.dist.data()), f);
                continue;
            }
            if (m > k) std::nth_element(key, key + (k - 1), key + m);
            for (int j = 0; j < k; ++j) {
                const int c = static_cast<int>(key[j] & 0xffffffffu);
                s.idx[j] = s.cand[c];
                s.dist[j] = d[c];
            }
            guess = kGuess * d[key[k - 1] & 0xffffffffu];
            fn(pos, static_cast<const int*>(s.idx.data()),
               static_cast<const float*>(s.dist.data()), k);
        }
    }

    /// All rows within `radius` of q (unordered), at most `max_nn` if > 0 (the first found).
    void radius(const float* q, float radius, std::vector<int>& idx, std::vector<float>& sq_dist,
                int max_nn = 0) const {
        idx.clear();
        sq_dist.clear();
        if (!nodes_.empty()) radius_rec(0, q, radius * radius, idx, sq_dist, max_nn);
    }

private:
    struct Node {
        int begin, end;  // range in tree order (leaf)
        int axis;        // -1 for a leaf
        float split;
        int left, right;
    };

    /// Nodes of at least 2 x this many points are split level by level in parallel; smaller
    /// subtrees are built whole, in parallel.
    static constexpr int kTaskPoints = 512;

    /// Node count of a subtree of m points: every node of more than leaf_size_ points splits at
    /// its median (a leaf of equal points leaves its subtree's other numbers unused), so a
    /// subtree's size, and so each node's number in depth-first order, follows from m alone.
    /// Only two sizes occur per level: memoised for those from the root's.
    void count_nodes(int m) {
        if (subtree_nodes_m_.count(m)) return;
        if (m <= leaf_size_) {
            subtree_nodes_m_[m] = 1;
            return;
        }
        count_nodes(m / 2);
        count_nodes(m - m / 2);
        subtree_nodes_m_[m] = 1 + subtree_nodes_m_[m / 2] + subtree_nodes_m_[m - m / 2];
    }
    int subtree_nodes(int m) const { return subtree_nodes_m_.find(m)->second; }

    void copy_row(int64_t i) {
        std::copy(src_ + order_[i] * Dim, src_ + order_[i] * Dim + Dim, pts_.data() + i * Dim);
        pos_[order_[i]] = static_cast<int>(i);
    }

    /// Node `id` is a leaf over tree positions [begin, end): their order is final, so their
    /// rows are copied here.
    void make_leaf(int id, int begin, int end) {
        for (int i = begin; i < end; ++i) {
            leaf_node_[i] = id;
            copy_row(i);
        }
    }

    /// A node still to be made: id, tree positions [begin, end), parent, cell.
    struct Pending {
        int id = -1, begin = 0, end = 0, parent = -1;
        Row lo, hi;
    };

    /// Makes node p.id over tree positions [p.begin, p.end): its cell and box, and either a
    /// leaf or the split of its positions. A split's children go to child[0] and child[1] (left,
    /// right); a leaf leaves them with id -1.
    void make_node(const Pending& p, Pending* child) {
        const int id = p.id, begin = p.begin, end = p.end;
        nodes_[id] = {begin, end, -1, 0.f, -1, -1};
        parent_[id] = p.parent;
        float* cell = cells_.data() + static_cast<size_t>(id) * 2 * Dim;
        std::copy(p.lo.data(), p.lo.data() + Dim, cell);
        std::copy(p.hi.data(), p.hi.data() + Dim, cell + Dim);
        Row lo = Row::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
        for (int i = begin; i < end; ++i) {
            Eigen::Map<const Row> q(src_ + order_[i] * Dim);
            lo = lo.cwiseMin(q);
            hi = hi.cwiseMax(q);
        }
        float* box = boxes_.data() + static_cast<size_t>(id) * 2 * Dim;
        std::copy(lo.data(), lo.data() + Dim, box);
        std::copy(hi.data(), hi.data() + Dim, box + Dim);
        if (end - begin <= leaf_size_) return make_leaf(id, begin, end);
        int axis;
        const float extent = (hi - lo).maxCoeff(&axis);
        if (!(extent > 0.f)) return make_leaf(id, begin, end);  // all equal
        const int mid = begin + (end - begin) / 2;
        std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                         [&](int64_t a, int64_t b) {
                             return src_[a * Dim + axis] < src_[b * Dim + axis];
                         });
        const float split = src_[order_[mid] * Dim + axis];
        // left cell: coordinate <= split, right cell: >= split (ties may sit on either side)
        const int l = id + 1, r = id + 1 + subtree_nodes(mid - begin);
        nodes_[id].axis = axis;
        nodes_[id].split = split;
        nodes_[id].left = l;
        nodes_[id].right = r;
        child[0] = {l, begin, mid, id, p.lo, p.hi};
        child[0].hi[axis] = split;
        child[1] = {r, mid, end, id, p.lo, p.hi};
        child[1].lo[axis] = split;
    }

    /// Build node `id` over tree positions [begin, end) and its subtree (nodes id, id + 1, ...).
    void build(int id, int begin, int end, const Row& cell_lo, const Row& cell_hi, int parent) {
        Pending child[2];
        make_node({id, begin, end, parent, cell_lo, cell_hi}, child);
        if (child[0].id < 0) return;
        build(child[0].id, child[0].begin, child[0].end, child[0].lo, child[0].hi, id);
        build(child[1].id, child[1].begin, child[1].end, child[1].lo, child[1].hi, id);
    }

    /// Squared distance from q to node `id`'s bounding box (0 inside). Never above the
    /// distance sq() gives to a point in the box (float rounding is monotonic), so pruning on
    /// it is exact.
    float box_dist(int id, const float* q) const {
        const float* lo = boxes_.data() + static_cast<size_t>(id) * 2 * Dim;
        const float* hi = lo + Dim;
        float s = 0.f;
        for (int d = 0; d < Dim; ++d) {
            const float e = std::max(std::max(lo[d] - q[d], q[d] - hi[d]), 0.f);
            s += e * e;
        }
        return s;
    }

    /// Whether the ball of squared radius r2 about q lies inside node `id`'s cell.
    bool ball_inside(int id, const float* q, float r2) const {
        const float* lo = cells_.data() + static_cast<size_t>(id) * 2 * Dim;
        const float* hi = lo + Dim;
        for (int a = 0; a < Dim; ++a) {
            const float dl = q[a] - lo[a], dh = hi[a] - q[a];
            if (!(dl >= 0 && dh >= 0 && dl * dl >= r2 && dh * dh >= r2)) return false;
        }
        return true;
    }

    /// Tree positions of the points within sqrt(r2) of the box [lo, hi], in position order.
    void box_range(int id, const float* lo, const float* hi, float r2, std::vector<int>& out) const {
        const float* nlo = boxes_.data() + static_cast<size_t>(id) * 2 * Dim;
        const float* nhi = nlo + Dim;
        float s = 0.f;
        for (int d = 0; d < Dim; ++d) {
            const float e = std::max(std::max(lo[d] - nhi[d], nlo[d] - hi[d]), 0.f);
            s += e * e;
        }
        if (s > r2) return;
        const Node& nd = nodes_[id];
        if (nd.axis >= 0) {
            box_range(nd.left, lo, hi, r2, out);
            box_range(nd.right, lo, hi, r2, out);
            return;
        }
        for (int i = nd.begin; i < nd.end; ++i) {
            const float* p = point_at(i);
            float t = 0.f;
            for (int d = 0; d < Dim; ++d) {
                const float e = std::max(std::max(lo[d] - p[d], p[d] - hi[d]), 0.f);
                t += e * e;
            }
            if (t <= r2) out.push_back(i);
        }
    }

    static float sq(const float* a, const float* b) {
        float s = 0.f;
        for (int d = 0; d < Dim; ++d) {
            const float e = a[d] - b[d];
            s += e * e;
        }
        return s;
    }

    /// sq(a, b), or any value > bound once the partial sum exceeds it (checked every 8
    /// dimensions: FPFH's 33-D matching rejects most leaf points after 8 or 16). Same sum order
    /// as sq(): a candidate that is kept has bit-identical distance.
    static float sq_bounded(const float* a, const float* b, float bound) {
        if constexpr (Dim <= 8) {
            return sq(a, b);
        } else {
            float s = 0.f;
            int d = 0;
            for (; d + 8 <= Dim; d += 8) {
                for (int j = d; j < d + 8; ++j) {
                    const float e = a[j] - b[j];
                    s += e * e;
                }
                if (s > bound) return s;
            }
            for (; d < Dim; ++d) {
                const float e = a[d] - b[d];
                s += e * e;
            }
            return s;
        }
    }

    // Searches descend to the near child first; the far child is visited only if its cell can
    // hold a closer point. The cell distance is tracked incrementally per axis (Arya & Mount):
    // `off[d]` is the query's offset from the cell along d, `mindist` their squared sum.
    void knn_rec(int id, const float* q, int k, int* idx, float* dist, int& found, float& worst,
                 float mindist, float* off) const {
        const Node& nd = nodes_[id];
        if (nd.axis < 0) {
            for (int i = nd.begin; i < nd.end; ++i) {
                const float d = sq_bounded(q, pts_.data() + static_cast<size_t>(i) * Dim, worst);
                if (found == k && d >= worst) continue;
                int j = found < k ? found++ : k - 1;  // insertion into the sorted buffer
                while (j > 0 && dist[j - 1] > d) {
                    dist[j] = dist[j - 1];
                    idx[j] = idx[j - 1];
                    --j;
                }
                dist[j] = d;
                idx[j] = static_cast<int>(order_[i]);
                if (found == k) worst = dist[k - 1];
            }
            return;
        }
        const float diff = q[nd.axis] - nd.split;
        const int near = diff < 0 ? nd.left : nd.right;
        const int far = diff < 0 ? nd.right : nd.left;
        knn_rec(near, q, k, idx, dist, found, worst, mindist, off);
        const float old = off[nd.axis];
        const float far_dist = mindist - old * old + diff * diff;
        if (found < k || far_dist < worst) {
            off[nd.axis] = diff;
            knn_rec(far, q, k, idx, dist, found, worst, far_dist, off);
            off[nd.axis] = old;
        }
    }

    // Nearest neighbour below `best` in the subtree `id` (whose box is nearer than `best`):
    // the nearer child first, each child only while its tight box can hold a nearer point.
    // (`skip`: a leaf already scanned.)
    void nn_box(int id, const float* q, int& idx, float& best, int skip = -1) const {
        const Node& nd = nodes_[id];
        if (nd.axis < 0) {
            if (id != skip) scan_leaf(nd, q, idx, best);
            return;
        }
        const float dl = box_dist(nd.left, q), dr = box_dist(nd.right, q);
        const bool left_first = dl <= dr;
        const int near = left_first ? nd.left : nd.right, far = left_first ? nd.right : nd.left;
        const float dn = left_first ? dl : dr, df = left_first ? dr : dl;
        if (dn < best) nn_box(near, q, idx, best, skip);
        if (df < best) nn_box(far, q, idx, best, skip);
    }

    void scan_leaf(const Node& nd, const float* q, int& idx, float& best) const {
        for (int i = nd.begin; i < nd.end; ++i) {
            const float d = sq_bounded(q, point_at(i), best);
            if (d < best) {
                best = d;
                idx = static_cast<int>(order_[i]);
            }
        }
    }

    void radius_rec(int id, const float* q, float r2, std::vector<int>& idx,
                    std::vector<float>& dist, int max_nn) const {
        if (max_nn > 0 && static_cast<int>(idx.size()) >= max_nn) return;
        const Node& nd = nodes_[id];
        if (nd.axis < 0) {
            for (int i = nd.begin; i < nd.end; ++i) {
                const float d = sq(q, pts_.data() + static_cast<size_t>(i) * Dim);
                if (d <= r2) {
                    idx.push_back(static_cast<int>(order_[i]));
                    dist.push_back(d);
                    if (max_nn > 0 && static_cast<int>(idx.size()) >= max_nn) return;
                }
            }
            return;
        }
        const float diff = q[nd.axis] - nd.split;
        radius_rec(diff < 0 ? nd.left : nd.right, q, r2, idx, dist, max_nn);
        if (diff * diff <= r2) radius_rec(diff < 0 ? nd.right : nd.left, q, r2, idx, dist, max_nn);
    }

    int leaf_size_;
    const float* src_ = nullptr;  // only during build
    std::map<int, int> subtree_nodes_m_;  // only during build: points -> subtree node count
    std::vector<int64_t> order_;  // tree position -> caller's row
    std::vector<int> pos_;        // caller's row -> tree position
    std::vector<float> pts_;      // rows in tree order
    std::vector<Node> nodes_;
    std::vector<float> boxes_;    // per node: the tight bounding box of its points, lo then hi
    std::vector<float> cells_;    // per node: its cell (the box its splits bound), lo then hi
    std::vector<int> parent_;     // per node (-1: the root)
    std::vector<int> leaf_node_;  // tree position -> its leaf node
    /// nearest_from() by the hint's list (hint at tree position `pos`, sq() `d` from q, below
    /// the search's bound): the answer's row (`best` its sq()), or kUndecided when the list
    /// cannot decide (q too far from the hint for the list to cover, or a tie on the list).
    static constexpr int kUndecided = -2;
    int nearest_on_list(const float* q, int pos, float d, int hint, float& best) const {
        if (within_half(d, hint_first_sq_[pos])) return hint;  // nearer than any other point
        if (!within_half(d, hint_reach_sq_[pos])) return kUndecided;
        const int* list = hint_list_.data() + static_cast<size_t>(pos) * kHintList;
        float m = d;
        int arg = -1, ties = 0;
        for (int j = 0; j < kHintList && list[j] >= 0; ++j) {
            const float dj = sq(q, point_at(list[j]));
            if (dj < m) {
                m = dj;
                arg = list[j];
                ties = 0;
            } else if (dj == m && arg >= 0) {
                ++ties;
            }
        }
        if (arg < 0) return hint;  // none strictly nearer: the hint, as the search keeps it
        if (ties > 0) return kUndecided;
        best = m;
        return static_cast<int>(order_[arg]);
    }

    std::vector<int> hint_list_;        // tree position -> kHintList tree positions (-1: none)
    std::vector<float> hint_reach_sq_;  // tree position -> no unlisted point nearer [sq()]
    std::vector<float> hint_first_sq_;  // tree position -> sq() to the first listed point
};

}  // namespace tripod
