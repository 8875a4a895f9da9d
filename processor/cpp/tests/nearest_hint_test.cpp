// SPDX-License-Identifier: BSD-3-Clause
// KdTree::nearest_from with the hint lists prepare_cloud() gives the tree (KdTree::set_hints):
// the same row and squared distance, bit for bit, as the search without lists (the reference:
// the same tree built without them), ties and duplicates included; and the lists are used.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "test_clouds.hpp"
#include "tripod_core/kdtree.hpp"
#include "tripod_core/registration.hpp"

namespace tripod {
namespace {

/// A noisy room, a patch of an exact 5 cm lattice (equidistant points: exact ties) and some
/// points twice (distance 0 to another point).
PointsXYZ cloud_with_ties() {
    const PointsXYZ room = test::box_room(12000, 0.004, 21);
    std::vector<Eigen::RowVector3f> rows;
    for (Eigen::Index i = 0; i < room.rows(); ++i) rows.push_back(room.row(i));
    for (int a = 0; a < 24; ++a)
        for (int b = 0; b < 24; ++b)
            rows.emplace_back(1.0f + 0.05f * a, 1.0f + 0.05f * b, 1.25f);
    for (Eigen::Index i = 0; i < room.rows(); i += 50) rows.push_back(room.row(i));
    PointsXYZ out(static_cast<Eigen::Index>(rows.size()), 3);
    for (size_t i = 0; i < rows.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = rows[i];
    return out;
}

struct Query {
    Eigen::Vector3f q;
    int hint;
};

/// ICP-like queries (each point moved by up to `step` [m], its own row as the hint), lattice
/// queries at cell centres and edge midpoints (2 or 4 lattice points equally near) with a
/// lattice point as the hint, and far queries with random hints.
std::vector<Query> queries(const PointsXYZ& p, float step, int lattice_first) {
    std::mt19937 rng(4);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    std::uniform_int_distribution<int> pick(0, static_cast<int>(p.rows()) - 1);
    std::vector<Query> out;
    for (Eigen::Index i = 0; i < p.rows(); i += 3) {
        const Eigen::Vector3f d(u(rng), u(rng), u(rng));
        out.push_back({p.row(i).transpose() + step * d, static_cast<int>(i)});
    }
    for (int a = 0; a < 23; ++a)
        for (int b = 0; b < 23; ++b) {
            const int hint = lattice_first + a * 24 + b;
            out.push_back({{1.025f + 0.05f * a, 1.025f + 0.05f * b, 1.25f}, hint});
            out.push_back({{1.025f + 0.05f * a, 1.0f + 0.05f * b, 1.25f}, hint + 24});
            out.push_back({{1.025f + 0.05f * a, 1.025f + 0.05f * b, 1.26f}, hint + 1});
        }
    for (int k = 0; k < 500; ++k)
        out.push_back({{3 + 4 * u(rng), 2 + 3 * u(rng), 1.3f + 2 * u(rng)}, pick(rng)});
    return out;
}

TEST(NearestHint, ListsGiveTheSearchesAnswerBitForBit) {
    const PointsXYZ pts = cloud_with_ties();
    const int lattice_first = 12000;
    Neighborhood nb;
    nb.k_neighbors = 20;
    for (int threads : {1, 2}) {
        const auto pc = prepare_cloud(pts, nb, Eigen::Vector3d(3, 2, 1.3), 0.005, threads);
        ASSERT_TRUE(pc->tree->has_hints());
        const KdTree<3> ref(pc->points.data(), pc->points.rows(), 20, 1);  // no lists
        ASSERT_FALSE(ref.has_hints());
        int64_t checked = 0, found = 0, ties = 0;
        for (float step : {0.002f, 0.01f, 0.05f}) {
            for (const Query& x : queries(pc->points, step, lattice_first)) {
                for (float max_sq : {0.01f, 1.0f, std::numeric_limits<float>::infinity()}) {
                    float d_new = -1, d_ref = -1;
                    const int j_new = pc->tree->nearest_from(x.q.data(), max_sq, x.hint, &d_new);
                    const int j_ref = ref.nearest_from(x.q.data(), max_sq, x.hint, &d_ref);
                    ASSERT_EQ(j_new, j_ref) << "step " << step << " hint " << x.hint;
                    ASSERT_EQ(std::memcmp(&d_new, &d_ref, sizeof d_new), 0);
                    ++checked;
                    found += j_new >= 0;
                    // another row exactly as near as the answer (the lattice, the duplicates)
                    if (j_new >= 0 && step == 0.01f && !(max_sq < 1e30f)) {
                        int same = 0;
                        for (Eigen::Index r = 0; r < pc->points.rows(); r += 1) {
                            const Eigen::Vector3f e = pc->points.row(r).transpose() - x.q;
                            const float s = (e[0] * e[0] + e[1] * e[1]) + e[2] * e[2];
                            same += s == d_new;
                        }
                        ties += same > 1;
                    }
                }
            }
        }
        EXPECT_GT(checked, 30000);
        EXPECT_GT(found, checked / 2);
        EXPECT_GT(ties, 500);  // the tie-breaking is exercised
    }
}

TEST(NearestHint, GuessedGivesTheUnhintedSearchesAnswerBitForBit) {
    const PointsXYZ pts = cloud_with_ties();
    Neighborhood nb;
    nb.k_neighbors = 12;
    const auto pc = prepare_cloud(pts, nb, Eigen::Vector3d(3, 2, 1.3), 0.005, 2);
    const KdTree<3> ref(pc->points.data(), pc->points.rows(), 20, 1);  // no lists
    std::mt19937 rng(9);
    std::uniform_int_distribution<int> pick(0, static_cast<int>(pts.rows()) - 1);
    int64_t checked = 0, found = 0;
    for (float step : {0.002f, 0.01f, 0.05f}) {
        const std::vector<Query> qs = queries(pc->points, step, 12000);
        for (size_t k = 0; k < qs.size(); ++k) {
            // guesses: the query's own row, the previous query's row, a random row, none
            const int guesses[4] = {qs[k].hint, k ? qs[k - 1].hint : -1, pick(rng), -1};
            for (int g : guesses)
                for (float max_sq : {0.0004f, 1.0f, std::numeric_limits<float>::infinity()}) {
                    float d_new = -1, d_ref = -1;
                    const int j_new = pc->tree->nearest_guessed(qs[k].q.data(), max_sq, g, &d_new);
                    const int j_ref = ref.nearest_from(qs[k].q.data(), max_sq, -1, &d_ref);
                    ASSERT_EQ(j_new, j_ref) << "step " << step << " guess " << g;
                    ASSERT_EQ(std::memcmp(&d_new, &d_ref, sizeof d_new), 0);
                    ++checked;
                    found += j_new >= 0;
                }
        }
    }
    EXPECT_GT(checked, 100000);
    EXPECT_GT(found, checked / 3);
}

TEST(NearestHint, ListsAreUsed) {
    // a wrong list (every point's only "neighbour" row 0, nothing unlisted nearer than 100 m)
    // must change the answers: the shortcut is taken, not just the search
    const PointsXYZ pts = test::box_room(5000, 0.004, 22);
    KdTree<3> tree(pts.data(), pts.rows(), 20, 1);
    const int64_t n = tree.size();
    std::vector<int> list(n * KdTree<3>::kHintList, -1);
    for (int64_t p = 0; p < n; ++p) list[p * KdTree<3>::kHintList] = 0;
    tree.set_hints(list, std::vector<float>(n, 0.f), std::vector<float>(n, 1e4f));
    const KdTree<3> ref(pts.data(), pts.rows(), 20, 1);
    int differ = 0;
    for (Eigen::Index i = 1; i < pts.rows(); i += 7) {
        const Eigen::Vector3f q = pts.row(i).transpose();  // its nearest: row i itself
        const int hint = static_cast<int>((i * 37) % pts.rows());
        differ += tree.nearest_from(q.data(), 1e30f, hint, nullptr) !=
                  ref.nearest_from(q.data(), 1e30f, hint, nullptr);
    }
    EXPECT_GT(differ, 100);
    int guessed_differ = 0;  // the guess's list too
    for (Eigen::Index i = 1; i < pts.rows(); i += 7) {
        const Eigen::Vector3f q = pts.row(i).transpose();
        const int guess = static_cast<int>((i * 37) % pts.rows());
        guessed_differ += tree.nearest_guessed(q.data(), 1e30f, guess, nullptr) !=
                          ref.nearest_from(q.data(), 1e30f, -1, nullptr);
    }
    EXPECT_GT(guessed_differ, 100);
}

TEST(NearestHint, BadListsThrow) {
    const PointsXYZ pts = test::box_room(100, 0.004, 23);
    KdTree<3> tree(pts.data(), pts.rows(), 20, 1);
    EXPECT_THROW(tree.set_hints(std::vector<int>(10, -1), std::vector<float>(100, 0.f),
                                std::vector<float>(100, 0.f)),
                 std::invalid_argument);
    EXPECT_THROW(tree.set_hints(std::vector<int>(100 * KdTree<3>::kHintList, -1),
                                std::vector<float>(100, 0.f), std::vector<float>(99, 0.f)),
                 std::invalid_argument);
    tree.set_hints({}, {}, {});
    EXPECT_FALSE(tree.has_hints());
}

}  // namespace
}  // namespace tripod
