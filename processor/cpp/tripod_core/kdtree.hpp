// SPDX-License-Identifier: BSD-3-Clause
// A static k-d tree over float points of fixed dimension (3 for clouds, 33 for FPFH features).
// Points are copied in tree order so a leaf scan reads contiguous memory; indices returned are
// the caller's row indices. Header-only so the compiler specialises the search on Dim.
// Each leaf keeps its cell (the box its splits bound): a warm-started nearest-neighbour query
// whose ball around the query (radius: the distance to the hint) lies inside the hint's cell
// scans that one leaf and skips the tree (ICP's later iterations, where points barely move).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <limits>
#include <numeric>
#include <vector>

namespace tripod {

/// Static k-d tree (median split on the widest axis, leaves of up to `leaf_size` points).
template <int Dim>
class KdTree {
public:
    using Row = Eigen::Matrix<float, Dim, 1>;

    /// Build over `n` rows of `Dim` floats at `data` (row-major), all finite.
    /// @param data      n x Dim row-major floats (copied)
    /// @param n         number of rows
    /// @param leaf_size points per leaf (>= 1)
    KdTree(const float* data, int64_t n, int leaf_size = 20) : leaf_size_(std::max(1, leaf_size)) {
        order_.resize(n);
        std::iota(order_.begin(), order_.end(), 0);
        pts_.resize(static_cast<size_t>(n) * Dim);
        src_ = data;
        nodes_.reserve(2 * (n / leaf_size_ + 1));
        leaf_of_.resize(n);
        if (n > 0) {
            Row lo = Row::Constant(-std::numeric_limits<float>::infinity()), hi = -lo;
            build(0, static_cast<int>(n), lo, hi);
        }
        pos_.resize(n);
        for (int64_t i = 0; i < n; ++i) {
            std::copy(data + order_[i] * Dim, data + order_[i] * Dim + Dim, pts_.data() + i * Dim);
            pos_[order_[i]] = static_cast<int>(i);
        }
        src_ = nullptr;
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
        float off[Dim] = {};
        if (!nodes_.empty()) nn_rec(0, q, idx, best, 0.f, off);
        if (sq_dist) *sq_dist = best;
        return idx;
    }

    /// Nearest neighbour within sqrt(max_sq_dist), warm-started from a row `hint` (e.g. the
    /// previous ICP iteration's match; -1 for none): its distance bounds the search, which
    /// then prunes most of the tree. Same answer as nearest() up to ties.
    int nearest_from(const float* q, float max_sq_dist, int hint, float* sq_dist) const {
        int idx = -1;
        float best = max_sq_dist;
        if (hint >= 0) {
            const int pos = pos_[hint];
            const float d = sq(q, pts_.data() + static_cast<size_t>(pos) * Dim);
            if (d < best) {
                best = d;
                idx = hint;
                // the ball of radius sqrt(d) about q inside the hint's cell: no point outside
                // the cell can be nearer, so the answer is in this leaf
                const Leaf& lf = leaves_[leaf_of_[pos]];
                bool inside = true;
                for (int a = 0; a < Dim && inside; ++a) {
                    const float dl = q[a] - lf.lo[a], dh = lf.hi[a] - q[a];
                    inside = dl >= 0 && dh >= 0 && dl * dl >= d && dh * dh >= d;
                }
                if (inside) {
                    for (int i = lf.begin; i < lf.end; ++i) {
                        const float e = sq(q, pts_.data() + static_cast<size_t>(i) * Dim);
                        if (e < best) {
                            best = e;
                            idx = static_cast<int>(order_[i]);
                        }
                    }
                    if (sq_dist) *sq_dist = best;
                    return idx;
                }
            }
        }
        float off[Dim] = {};
        if (!nodes_.empty()) nn_rec(0, q, idx, best, 0.f, off);
        if (sq_dist) *sq_dist = best;
        return idx;
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

    struct Leaf {
        int begin, end;
        Row lo, hi;  // the cell (infinite towards the outside of the root)
    };

    int make_leaf(int id, int begin, int end, const Row& lo, const Row& hi) {
        const int l = static_cast<int>(leaves_.size());
        leaves_.push_back({begin, end, lo, hi});
        for (int i = begin; i < end; ++i) leaf_of_[i] = l;
        return id;
    }

    int build(int begin, int end, const Row& cell_lo, const Row& cell_hi) {
        const int id = static_cast<int>(nodes_.size());
        nodes_.push_back({begin, end, -1, 0.f, -1, -1});
        if (end - begin <= leaf_size_) return make_leaf(id, begin, end, cell_lo, cell_hi);
        Row lo = Row::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
        for (int i = begin; i < end; ++i) {
            Eigen::Map<const Row> p(src_ + order_[i] * Dim);
            lo = lo.cwiseMin(p);
            hi = hi.cwiseMax(p);
        }
        int axis;
        const float extent = (hi - lo).maxCoeff(&axis);
        if (!(extent > 0.f)) return make_leaf(id, begin, end, cell_lo, cell_hi);  // all equal
        const int mid = begin + (end - begin) / 2;
        std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                         [&](int64_t a, int64_t b) {
                             return src_[a * Dim + axis] < src_[b * Dim + axis];
                         });
        const float split = src_[order_[mid] * Dim + axis];
        // left cell: coordinate <= split, right cell: >= split (ties may sit on either side)
        Row left_hi = cell_hi, right_lo = cell_lo;
        left_hi[axis] = split;
        right_lo[axis] = split;
        const int l = build(begin, mid, cell_lo, left_hi);
        const int r = build(mid, end, right_lo, cell_hi);
        nodes_[id].axis = axis;
        nodes_[id].split = split;
        nodes_[id].left = l;
        nodes_[id].right = r;
        return id;
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

    void nn_rec(int id, const float* q, int& idx, float& best, float mindist, float* off) const {
        const Node& nd = nodes_[id];
        if (nd.axis < 0) {
            for (int i = nd.begin; i < nd.end; ++i) {
                const float d = sq_bounded(q, pts_.data() + static_cast<size_t>(i) * Dim, best);
                if (d < best) {
                    best = d;
                    idx = static_cast<int>(order_[i]);
                }
            }
            return;
        }
        const float diff = q[nd.axis] - nd.split;
        nn_rec(diff < 0 ? nd.left : nd.right, q, idx, best, mindist, off);
        const float old = off[nd.axis];
        const float far_dist = mindist - old * old + diff * diff;
        if (far_dist < best) {
            off[nd.axis] = diff;
            nn_rec(diff < 0 ? nd.right : nd.left, q, idx, best, far_dist, off);
            off[nd.axis] = old;
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
    std::vector<int64_t> order_;  // tree position -> caller's row
    std::vector<int> pos_;        // caller's row -> tree position
    std::vector<float> pts_;      // rows in tree order
    std::vector<Node> nodes_;
    std::vector<Leaf> leaves_;
    std::vector<int> leaf_of_;    // tree position -> its leaf
};

}  // namespace tripod
