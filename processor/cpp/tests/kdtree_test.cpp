// SPDX-License-Identifier: BSD-3-Clause
// KdTree<3> k-NN, nearest and radius search against pcl::KdTreeFLANN (exact search).
#include <gtest/gtest.h>
#include <pcl/kdtree/kdtree_flann.h>

#include <algorithm>
#include <random>
#include <tuple>
#include <vector>

#include "test_clouds.hpp"
#include "tripod_core/kdtree.hpp"

namespace tripod {
namespace {

class KdTreeTest : public ::testing::TestWithParam<std::tuple<int, int>> {};  // (leaf, k)

TEST_P(KdTreeTest, KnnMatchesPcl) {
    const auto [leaf, k] = GetParam();
    const PointsXYZ cloud = test::box_room(50000, 0.02, 3);
    const KdTree<3> tree(cloud.data(), cloud.rows(), leaf);
    pcl::KdTreeFLANN<pcl::PointXYZ> flann;
    flann.setInputCloud(test::to_pcl(cloud));

    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(-0.5f, 6.5f);
    std::vector<int> idx(k), pidx(k);
    std::vector<float> d2(k), pd2(k);
    for (int q = 0; q < 500; ++q) {
        const float p[3] = {u(rng), u(rng) * 0.7f, u(rng) * 0.45f};
        ASSERT_EQ(tree.knn(p, k, idx.data(), d2.data()), k);
        ASSERT_EQ(flann.nearestKSearch(pcl::PointXYZ(p[0], p[1], p[2]), k, pidx, pd2), k);
        for (int j = 0; j < k; ++j) {
            EXPECT_NEAR(d2[j], pd2[j], 1e-5f * std::max(1.f, pd2[j]));
            if (j) {
                EXPECT_LE(d2[j - 1], d2[j]);
            }
        }
        float nd2 = -1;
        const int nn = tree.nearest(p, 1e30f, &nd2);
        ASSERT_GE(nn, 0);
        EXPECT_NEAR(nd2, pd2[0], 1e-5f * std::max(1.f, pd2[0]));
    }
}

TEST_P(KdTreeTest, RadiusMatchesPcl) {
    const auto [leaf, k] = GetParam();
    const PointsXYZ cloud = test::box_room(20000, 0.02, 4);
    const KdTree<3> tree(cloud.data(), cloud.rows(), leaf);
    pcl::KdTreeFLANN<pcl::PointXYZ> flann;
    flann.setInputCloud(test::to_pcl(cloud));
    std::vector<int> idx, pidx;
    std::vector<float> d2, pd2;
    const float radius = 0.02f * static_cast<float>(k);
    for (int i = 0; i < cloud.rows(); i += 97) {
        const float* p = cloud.row(i).data();
        tree.radius(p, radius, idx, d2);
        flann.radiusSearch(pcl::PointXYZ(p[0], p[1], p[2]), radius, pidx, pd2);
        std::sort(idx.begin(), idx.end());
        std::sort(pidx.begin(), pidx.end());
        EXPECT_EQ(idx, pidx) << "query row " << i;
    }
}

INSTANTIATE_TEST_SUITE_P(LeafAndK, KdTreeTest,
                         ::testing::Combine(::testing::Values(1, 8, 32), ::testing::Values(1, 5, 20)));

// The k-NN of a whole cloud in groups equals per-point k-NN, and each point's neighbour set is
// the same whatever the groups (so results do not depend on how threads split the cloud); a
// cloud on a lattice (many equal distances) exercises the tie-breaking.
TEST(KdTree, KnnRangeMatchesKnnWhateverTheGroups) {
    PointsXYZ lattice(4000, 3);
    for (int i = 0; i < 4000; ++i)
        lattice.row(i) << float(i % 20) * 0.05f, float((i / 20) % 20) * 0.05f, float(i / 400) * 0.05f;
    for (const PointsXYZ& cloud : {test::box_room(20000, 0.01, 11), lattice}) {
        const KdTree<3> tree(cloud.data(), cloud.rows());
        for (int k : {1, 7, 20}) {
            std::vector<std::vector<int>> first(cloud.rows());
            for (int group : {1, 16, 64, 100000}) {
                const std::vector<int> g = tree.groups(group);
                ASSERT_EQ(g.front(), 0);
                ASSERT_EQ(g.back(), cloud.rows());
                KdTree<3>::KnnScratch scratch;
                std::vector<int> idx(k);
                std::vector<float> d2(k);
                int next = 0;
                for (size_t b = 0; b + 1 < g.size(); ++b) {
                    ASSERT_LT(g[b], g[b + 1]);
                    tree.knn_range(k, g[b], g[b + 1], scratch,
                                   [&](int64_t pos, const int* nbr, const float* dist, int m) {
                        ASSERT_EQ(pos, next++);
                        ASSERT_EQ(m, k);
                        ASSERT_EQ(tree.knn(tree.point_at(pos), k, idx.data(), d2.data()), k);
                        std::vector<float> got(dist, dist + m);
                        std::sort(got.begin(), got.end());
                        for (int j = 0; j < m; ++j) {
                            ASSERT_EQ(got[j], d2[j]) << "position " << pos << " neighbour " << j;
                            const float* a = tree.point_at(pos);
                            const float* c = tree.point_at(nbr[j]);
                            const float e0 = a[0] - c[0], e1 = a[1] - c[1], e2 = a[2] - c[2];
                            ASSERT_EQ(dist[j], e0 * e0 + e1 * e1 + e2 * e2);
                        }
                        std::vector<int> set(nbr, nbr + m);
                        std::sort(set.begin(), set.end());
                        if (first[pos].empty())
                            first[pos] = set;
                        else
                            ASSERT_EQ(set, first[pos]) << "position " << pos << " group " << group;
                    });
                }
                ASSERT_EQ(next, cloud.rows());
            }
        }
    }
}

// A warm-started nearest neighbour (any hint, near or far) finds the nearest distance.
TEST(KdTree, NearestFromAnyHintIsTheNearest) {
    const PointsXYZ cloud = test::box_room(30000, 0.01, 12);
    const KdTree<3> tree(cloud.data(), cloud.rows());
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-0.5f, 6.5f);
    std::uniform_int_distribution<int> row(0, static_cast<int>(cloud.rows()) - 1);
    std::normal_distribution<float> jitter(0.f, 0.05f);
    for (int t = 0; t < 3000; ++t) {
        float q[3];
        int hint;
        if (t % 2) {  // near a point, hinted by it (ICP's later iterations)
            hint = row(rng);
            for (int a = 0; a < 3; ++a) q[a] = cloud(hint, a) + jitter(rng);
        } else {  // anywhere, hinted by any point
            q[0] = u(rng), q[1] = u(rng) * 0.7f, q[2] = u(rng) * 0.45f;
            hint = t % 4 ? row(rng) : -1;
        }
        for (float max_sq : {1e30f, 0.01f}) {
            float d_ref = -1, d = -1;
            const int ref = tree.nearest(q, max_sq, &d_ref);
            const int got = tree.nearest_from(q, max_sq, hint, &d);
            ASSERT_EQ(got < 0, ref < 0);
            ASSERT_EQ(d, d_ref) << "query " << t;
        }
    }
}

// A tree built on several threads (subtrees as tasks) is the same tree: same order, same
// groups, same answers, also with runs of equal points (leaves that end a subtree early).
TEST(KdTree, BuildIsIndependentOfThreadCount) {
    PointsXYZ dup = test::box_room(30000, 0.01, 12);
    for (int i = 0; i < 6000; ++i) dup.row(10000 + i) = dup.row(10000);  // one point 6001 times
    for (const PointsXYZ& cloud : {test::box_room(60000, 0.01, 13), dup}) {
        const KdTree<3> one(cloud.data(), cloud.rows(), 20, 1);
        for (int threads : {2, 4}) {
            const KdTree<3> many(cloud.data(), cloud.rows(), 20, threads);
            ASSERT_EQ(one.order(), many.order());
            ASSERT_EQ(one.groups(32), many.groups(32));
            std::vector<int> ia(20), ib(20);
            std::vector<float> da(20), db(20);
            for (int i = 0; i < cloud.rows(); i += 37) {
                const float* q = cloud.row(i).data();
                ASSERT_EQ(one.knn(q, 20, ia.data(), da.data()), many.knn(q, 20, ib.data(), db.data()));
                ASSERT_EQ(ia, ib);
                ASSERT_EQ(da, db);
                const float p[3] = {q[0] + 0.03f, q[1] - 0.02f, q[2] + 0.01f};
                float d1 = 0, d2 = 0;
                ASSERT_EQ(one.nearest_from(p, 0.01f, i, &d1), many.nearest_from(p, 0.01f, i, &d2));
                ASSERT_EQ(d1, d2);
            }
        }
    }
}

TEST(KdTree, EmptyTreeFindsNothing) {
    const KdTree<3> tree(nullptr, 0);
    const float q[3] = {0, 0, 0};
    int idx = 0;
    float d2 = 0;
    EXPECT_EQ(tree.knn(q, 1, &idx, &d2), 0);
    EXPECT_EQ(tree.nearest(q, 1.f, nullptr), -1);
    EXPECT_EQ(tree.nearest_from(q, 1.f, -1, nullptr), -1);
    EXPECT_EQ(tree.groups(16), std::vector<int>{0});
}

}  // namespace
}  // namespace tripod
