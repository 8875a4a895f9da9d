// SPDX-License-Identifier: BSD-3-Clause
// Pose graph: a square loop with perturbed initial poses returns to the truth; a wrong loop
// closure is rejected as an outlier; bad input throws.
#include <gtest/gtest.h>

#include <cmath>

#include "tripod_core/pose_graph.hpp"

namespace tripod {
namespace {

Pose3d pose(double x, double y, double yaw) {
    Pose3d p;
    p.p << x, y, 0.0;
    p.q = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
    return p;
}

PoseGraphEdge edge(int from, int to, const Pose3d& a, const Pose3d& b, bool loop) {
    PoseGraphEdge e;
    e.from = from;
    e.to = to;
    e.T_from_to.q = a.q.conjugate() * b.q;
    e.T_from_to.p = a.q.conjugate() * (b.p - a.p);
    e.information = Eigen::Matrix<double, 6, 6>::Identity() * 1e4;
    e.is_loop = loop;
    return e;
}

class PoseGraphTest : public ::testing::Test {
protected:
    void SetUp() override {
        for (int i = 0; i < 8; ++i) {
            const double a = i * M_PI / 4;
            truth.push_back(pose(3 * std::cos(a), 3 * std::sin(a), a + M_PI / 2));
        }
        for (int i = 0; i < 8; ++i) edges.push_back(edge(i, (i + 1) % 8, truth[i], truth[(i + 1) % 8], i == 7));
        for (size_t i = 0; i < truth.size(); ++i) {
            Pose3d p = truth[i];
            p.p += Eigen::Vector3d(0.05 * i, -0.03 * i, 0.01 * i);  // drift
            p.q = p.q * Eigen::Quaterniond(Eigen::AngleAxisd(0.01 * i, Eigen::Vector3d::UnitZ()));
            initial.push_back(p);
        }
        initial[0] = truth[0];
    }
    std::vector<Pose3d> truth, initial;
    std::vector<PoseGraphEdge> edges;
};

TEST_F(PoseGraphTest, LoopReturnsToTruth) {
    PoseGraphOptions opt;
    opt.num_threads = 2;
    const PoseGraphResult r = optimize_pose_graph(initial, edges, {}, opt);
    EXPECT_TRUE(r.converged) << r.message;
    EXPECT_EQ(r.rejected, 0);
    ASSERT_EQ(r.poses.size(), truth.size());
    for (size_t i = 0; i < truth.size(); ++i) {
        EXPECT_LT((r.poses[i].p - truth[i].p).norm(), 1e-6) << "node " << i;
        EXPECT_LT(r.poses[i].q.angularDistance(truth[i].q), 1e-6) << "node " << i;
    }
    EXPECT_LT(r.final_cost, r.initial_cost);
}

TEST_F(PoseGraphTest, WrongLoopClosureIsRejected) {
    // a second, wrong loop closure: node 2 seen 1.5 m from where it is
    PoseGraphEdge bad = edge(0, 2, truth[0], truth[2], true);
    bad.T_from_to.p.x() += 1.5;
    edges.push_back(bad);
    edges.push_back(edge(1, 3, truth[1], truth[3], true));
    PoseGraphOptions opt;
    const PoseGraphResult r = optimize_pose_graph(initial, edges, {}, opt);
    ASSERT_EQ(r.edge_inlier.size(), edges.size());
    EXPECT_EQ(r.edge_inlier[8], 0);
    EXPECT_EQ(r.edge_inlier[9], 1);
    for (size_t i = 0; i < truth.size(); ++i) EXPECT_LT((r.poses[i].p - truth[i].p).norm(), 1e-4);
}

TEST_F(PoseGraphTest, BadIndexThrows) {
    edges.push_back(edge(0, 42, truth[0], truth[1], true));
    EXPECT_THROW(optimize_pose_graph(initial, edges, {}, PoseGraphOptions{}), std::invalid_argument);
    EXPECT_THROW(optimize_pose_graph({}, {}, {}, PoseGraphOptions{}), std::invalid_argument);
}

}  // namespace
}  // namespace tripod
