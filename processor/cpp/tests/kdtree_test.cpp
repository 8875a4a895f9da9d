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

TEST(KdTree, EmptyTreeFindsNothing) {
    const KdTree<3> tree(nullptr, 0);
    const float q[3] = {0, 0, 0};
    int idx = 0;
    float d2 = 0;
    EXPECT_EQ(tree.knn(q, 1, &idx, &d2), 0);
    EXPECT_EQ(tree.nearest(q, 1.f, nullptr), -1);
}

}  // namespace
}  // namespace tripod
