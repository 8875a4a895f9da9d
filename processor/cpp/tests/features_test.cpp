// SPDX-License-Identifier: BSD-3-Clause
// Normals and curvature against pcl::NormalEstimation (k-NN PCA), for 1, 2 and 4 threads.
#include <gtest/gtest.h>
#include <pcl/features/normal_3d.h>
#include <pcl/search/kdtree.h>

#include <cmath>

#include "test_clouds.hpp"
#include "tripod_core/features.hpp"

namespace tripod {
namespace {

class NormalsTest : public ::testing::TestWithParam<int> {};

TEST_P(NormalsTest, MatchPclNormalEstimation) {
    const PointsXYZ cloud = test::box_room(30000, 0.003, 9);
    const Eigen::Vector3d viewpoint(3.0, 2.0, 1.3);  // inside the room
    Neighborhood nb;
    nb.k_neighbors = 20;
    const LocalGeometry ours = estimate_local_geometry(cloud, nb, viewpoint, GetParam());

    pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> ne;
    ne.setInputCloud(test::to_pcl(cloud));
    ne.setSearchMethod(pcl::search::KdTree<pcl::PointXYZ>::Ptr(new pcl::search::KdTree<pcl::PointXYZ>));
    ne.setKSearch(20);
    ne.setViewPoint(3.0f, 2.0f, 1.3f);
    pcl::PointCloud<pcl::Normal> theirs;
    ne.compute(theirs);

    ASSERT_EQ(ours.normals.rows(), cloud.rows());
    int agree = 0, compared = 0;
    for (Eigen::Index i = 0; i < cloud.rows(); ++i) {
        const pcl::Normal& n = theirs[i];
        if (!ours.valid[i] || !std::isfinite(n.normal_x)) continue;
        ++compared;
        const double dot = ours.normals(i, 0) * n.normal_x + ours.normals(i, 1) * n.normal_y +
                           ours.normals(i, 2) * n.normal_z;
        // same orientation rule (towards the viewpoint) and the same PCA: the same vector
        if (dot > 0.9999 && std::abs(ours.curvature[i] - n.curvature) < 1e-4) ++agree;
    }
    EXPECT_GT(compared, cloud.rows() * 99 / 100);
    // PCL accumulates the covariance in float: near-isotropic neighbourhoods (the pillar's
    // edges) may pick another eigenvector; everything else agrees
    EXPECT_GT(agree, compared * 995 / 1000) << agree << " of " << compared;
}

TEST_P(NormalsTest, IndependentOfThreadCount) {
    const PointsXYZ cloud = test::box_room(20000, 0.01, 10);
    Neighborhood nb;
    nb.k_neighbors = 15;
    nb.radius = 0.3;
    const LocalGeometry a = estimate_local_geometry(cloud, nb, Eigen::Vector3d(1, 1, 1), 1);
    const LocalGeometry b = estimate_local_geometry(cloud, nb, Eigen::Vector3d(1, 1, 1), GetParam());
    EXPECT_TRUE((a.normals.array() == b.normals.array()).all());
    EXPECT_TRUE((a.covariances.array() == b.covariances.array()).all());
}

INSTANTIATE_TEST_SUITE_P(Threads, NormalsTest, ::testing::Values(1, 2, 4));

TEST(StatisticalOutlierRemoval, RemovesFarOutliers) {
    PointsXYZ cloud = test::box_room(5000, 0.005, 12);
    cloud.row(100) << 50.f, 50.f, 50.f;
    cloud.row(2000) << -40.f, 3.f, 1.f;
    const auto kept = statistical_outlier_removal(cloud, 10, 2.0, 2);
    EXPECT_EQ(std::count(kept.begin(), kept.end(), 100), 0);
    EXPECT_EQ(std::count(kept.begin(), kept.end(), 2000), 0);
    EXPECT_GT(kept.size(), 4800u);
}

}  // namespace
}  // namespace tripod
