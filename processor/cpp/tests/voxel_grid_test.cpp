// SPDX-License-Identifier: BSD-3-Clause
// voxel_downsample against pcl::VoxelGrid (same lattice: floor(p / size)), for 1, 2 and 4 threads.
#include <gtest/gtest.h>
#include <pcl/filters/voxel_grid.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "test_clouds.hpp"
#include "tripod_core/voxel_grid.hpp"

namespace tripod {
namespace {

using Key = std::array<long, 3>;

std::vector<std::pair<Key, Eigen::Vector3f>> keyed(const float* xyz, size_t stride, size_t n,
                                                   double size) {
    std::vector<std::pair<Key, Eigen::Vector3f>> out;
    out.reserve(n);
    for (size_t i = 0; i < n; ++i) {
        const float* p = xyz + i * stride;
        // a centroid lies inside its voxel, so its own floor() gives the voxel key
        out.push_back({Key{static_cast<long>(std::floor(p[0] / size)),
                           static_cast<long>(std::floor(p[1] / size)),
                           static_cast<long>(std::floor(p[2] / size))},
                       Eigen::Vector3f(p[0], p[1], p[2])});
    }
    std::sort(out.begin(), out.end(), [](auto& a, auto& b) { return a.first < b.first; });
    return out;
}

class VoxelGridTest : public ::testing::TestWithParam<int> {};

TEST_P(VoxelGridTest, MatchesPclVoxelGrid) {
    const PointsXYZ cloud = test::box_room(200000, 0.01);
    for (const double size : {0.05, 0.1, 0.25}) {
        const PointsXYZ ours = voxel_downsample(cloud, size, GetParam(), VoxelAlign::kOrigin);

        pcl::VoxelGrid<pcl::PointXYZ> vg;
        vg.setInputCloud(test::to_pcl(cloud));
        vg.setLeafSize(size, size, size);
        pcl::PointCloud<pcl::PointXYZ> theirs;
        vg.filter(theirs);

        ASSERT_EQ(ours.rows(), static_cast<Eigen::Index>(theirs.size())) << "voxel " << size;
        const auto a = keyed(ours.data(), 3, ours.rows(), size);
        const auto b = keyed(&theirs[0].x, sizeof(pcl::PointXYZ) / sizeof(float), theirs.size(),
                             size);
        for (size_t i = 0; i < a.size(); ++i) {
            ASSERT_EQ(a[i].first, b[i].first);
            // PCL sums in float, we sum in double: equal to float rounding of ~1e3 terms
            EXPECT_LT((a[i].second - b[i].second).norm(), 2e-5f);
        }
    }
}

TEST_P(VoxelGridTest, OutputIsIndependentOfThreadCount) {
    const PointsXYZ cloud = test::box_room(100000, 0.02, 11);
    const PointsXYZ one = voxel_downsample(cloud, 0.07, 1);
    const PointsXYZ many = voxel_downsample(cloud, 0.07, GetParam());
    ASSERT_EQ(one.rows(), many.rows());
    EXPECT_TRUE((one.array() == many.array()).all());
}

// Rows in the order of a scan (each chunk of rows covers one part of the room, as the PCL room
// scan's do), with non-finite rows among them: the chunks, the parts of the merge and the
// stealing between threads must not change a bit, on any thread count and either lattice.
TEST(VoxelGrid, ScanOrderedRowsGiveTheSameOutputOnAnyThreadCount) {
    PointsXYZ cloud = test::box_room(150000, 0.02, 5);
    std::vector<Eigen::Index> order(cloud.rows());
    for (Eigen::Index i = 0; i < cloud.rows(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](Eigen::Index a, Eigen::Index b) {
        return std::atan2(cloud(a, 1), cloud(a, 0)) < std::atan2(cloud(b, 1), cloud(b, 0));
    });
    PointsXYZ scan(cloud.rows(), 3);
    for (Eigen::Index i = 0; i < cloud.rows(); ++i) scan.row(i) = cloud.row(order[i]);
    for (Eigen::Index i = 0; i < scan.rows(); i += 997) scan(i, i % 3) = NAN;
    for (const VoxelAlign align : {VoxelAlign::kOrigin, VoxelAlign::kMinBound}) {
        const PointsXYZ one = voxel_downsample(scan, 0.05, 1, align);
        for (const int threads : {2, 3, 5, 8}) {
            const PointsXYZ many = voxel_downsample(scan, 0.05, threads, align);
            ASSERT_EQ(one.rows(), many.rows()) << threads << " threads";
            EXPECT_TRUE((one.array() == many.array()).all()) << threads << " threads";
        }
    }
}

TEST(VoxelGrid, DropsNonFiniteAndRejectsBadSize) {
    PointsXYZ p(3, 3);
    p << 0.01f, 0.01f, 0.01f, NAN, 0.f, 0.f, 0.02f, 0.02f, 0.02f;
    const PointsXYZ out = voxel_downsample(p, 0.1, 1);
    ASSERT_EQ(out.rows(), 1);
    EXPECT_NEAR(out(0, 0), 0.015f, 1e-7f);
    EXPECT_THROW(voxel_downsample(p, 0.0, 1), std::invalid_argument);
}

INSTANTIATE_TEST_SUITE_P(Threads, VoxelGridTest, ::testing::Values(1, 2, 4));

}  // namespace
}  // namespace tripod
