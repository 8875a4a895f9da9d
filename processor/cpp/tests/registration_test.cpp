// SPDX-License-Identifier: BSD-3-Clause
// Local registration recovers a known transform (every method), bit-identical for any thread
// count; degenerate and too-small inputs give a status or an exception, never a silent pose.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <memory>
#include <tuple>

#include "test_clouds.hpp"
#include "tripod_core/registration.hpp"

namespace tripod {
namespace {

Eigen::Matrix4d known_transform() {
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    T.topLeftCorner<3, 3>() = (Eigen::AngleAxisd(0.06, Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitX()))
                                  .toRotationMatrix();
    T.topRightCorner<3, 1>() << 0.12, -0.08, 0.03;
    return T;
}

PointsXYZ transformed(const PointsXYZ& p, const Eigen::Matrix4d& T) {
    PointsXYZ out(p.rows(), 3);
    const Eigen::Matrix3f R = T.topLeftCorner<3, 3>().cast<float>();
    const Eigen::Vector3f t = T.topRightCorner<3, 1>().cast<float>();
    for (Eigen::Index i = 0; i < p.rows(); ++i) out.row(i) = (R * p.row(i).transpose() + t).transpose();
    return out;
}

double rotation_error_deg(const Eigen::Matrix4d& A, const Eigen::Matrix4d& B) {
    const Eigen::Matrix3d dR = A.topLeftCorner<3, 3>().transpose() * B.topLeftCorner<3, 3>();
    return std::acos(std::clamp((dR.trace() - 1.0) / 2.0, -1.0, 1.0)) * 180.0 / M_PI;
}

class RegistrationTest : public ::testing::TestWithParam<std::tuple<Method, int>> {};

TEST_P(RegistrationTest, RecoversKnownTransform) {
    const auto [method, threads] = GetParam();
    const PointsXYZ target_pts = test::box_room(20000, 0.005, 21);
    // source = target seen from a frame moved by T^-1, so T_target_source = T (other samples)
    const Eigen::Matrix4d T_true = known_transform();
    const PointsXYZ source_pts = transformed(test::box_room(20000, 0.005, 22), T_true.inverse());
    Neighborhood nb;
    nb.k_neighbors = 20;
    const Eigen::Vector3d view(3, 2, 1.3);
    const auto target = prepare_cloud(target_pts, nb, view, 0.005, threads);
    const auto source = prepare_cloud(source_pts, nb, view, 0.005, threads);
    RegistrationOptions opt;
    opt.method = method;
    opt.max_correspondence_distances = {0.5, 0.1};
    opt.num_threads = threads;
    const RegistrationResult r =
        register_local(*source, *target, Eigen::Matrix4d::Identity(), opt);
    EXPECT_TRUE(r.converged) << r.status;
    // source and target are different samples of the surfaces: point-to-point pairs a point with
    // a neighbouring sample, not its true match, and keeps a small bias the surface-aware
    // residuals remove
    const bool p2p = method == Method::kPointToPoint;
    EXPECT_LT(rotation_error_deg(r.T_target_source, T_true), p2p ? 0.15 : 0.05);
    EXPECT_LT((r.T_target_source.topRightCorner<3, 1>() - T_true.topRightCorner<3, 1>()).norm(),
              p2p ? 5e-3 : 2e-3);
    EXPECT_GT(r.fitness, 0.95);

    // the same bits with one thread
    opt.num_threads = 1;
    const auto t1 = prepare_cloud(target_pts, nb, view, 0.005, 1);
    const auto s1 = prepare_cloud(source_pts, nb, view, 0.005, 1);
    const RegistrationResult r1 = register_local(*s1, *t1, Eigen::Matrix4d::Identity(), opt);
    EXPECT_TRUE((r1.T_target_source.array() == r.T_target_source.array()).all());
    EXPECT_EQ(r1.iterations, r.iterations);
}

INSTANTIATE_TEST_SUITE_P(
    MethodsAndThreads, RegistrationTest,
    ::testing::Combine(::testing::Values(Method::kPointToPoint, Method::kPointToPlane, Method::kGICP,
                                         Method::kVGICP, Method::kSymmetric, Method::kLM),
                       ::testing::Values(1, 2, 4)));

// GICP inverts plane-form covariances in closed form: the same solution as the general 3x3
// inverse of the same covariances (a copy of the clouds without the plane form).
TEST(Registration, GicpClosedFormMatchesGeneralCovariances) {
    const Eigen::Matrix4d T_true = known_transform();
    Neighborhood nb;
    const Eigen::Vector3d view(3, 2, 1.3);
    const auto tgt = prepare_cloud(test::box_room(15000, 0.005, 61), nb, view, 0.005, 2);
    const auto src = prepare_cloud(transformed(test::box_room(15000, 0.005, 62), T_true.inverse()),
                                   nb, view, 0.005, 2);
    ASSERT_GT(tgt->cov_scale, 0);
    const auto general = [](const PreparedCloud& c) {
        auto g = std::make_unique<PreparedCloud>();
        g->points = c.points;
        g->normals = c.normals;
        g->covariances = c.covariances;
        g->normal_valid = c.normal_valid;
        g->tree = std::make_unique<KdTree<3>>(g->points.data(), g->points.rows());
        return g;  // cov_scale 0: general covariances
    };
    const auto tgt_g = general(*tgt), src_g = general(*src);
    for (size_t i = 0; i < src->covariances.size(); i += 997) {
        const Eigen::Vector3d n = src->normals.row(i).transpose();
        const Eigen::Matrix3d form =
            src->cov_scale * (Eigen::Matrix3d::Identity() - src->cov_plane * n * n.transpose());
        EXPECT_LT((form - src->covariances[i]).norm(), 1e-12 * src->cov_scale);
    }
    RegistrationOptions opt;
    opt.method = Method::kGICP;
    opt.max_correspondence_distances = {0.5, 0.1};
    const RegistrationResult a = register_local(*src, *tgt, Eigen::Matrix4d::Identity(), opt);
    const RegistrationResult b = register_local(*src_g, *tgt_g, Eigen::Matrix4d::Identity(), opt);
    EXPECT_TRUE(a.converged) << a.status;
    EXPECT_EQ(a.iterations, b.iterations);
    EXPECT_LT((a.T_target_source - b.T_target_source).norm(), 1e-9);
    EXPECT_NEAR(a.final_error, b.final_error, 1e-6 * b.final_error);
    EXPECT_LT((a.information - b.information).norm(), 1e-6 * b.information.norm());
    EXPECT_LT(rotation_error_deg(a.T_target_source, T_true), 0.05);
}

TEST(Registration, SinglePlaneIsDegenerate) {
    PointsXYZ floor = test::box_room(7000, 0.002, 30);
    PointsXYZ only_floor(1000, 3);
    int n = 0;
    for (Eigen::Index i = 0; i < floor.rows() && n < 1000; i += 7) only_floor.row(n++) = floor.row(i);
    Neighborhood nb;
    const auto c = prepare_cloud(only_floor, nb, Eigen::Vector3d(3, 2, 1.3), 0.005, 2);
    RegistrationOptions opt;
    opt.method = Method::kPointToPlane;
    const RegistrationResult r = register_local(*c, *c, Eigen::Matrix4d::Identity(), opt);
    EXPECT_EQ(r.status, "degenerate");
    EXPECT_LT(r.condition, 1e-4);
}

TEST(Registration, OrientedPairsOnlySurfacesSeenFromTheSameSide) {
    // normals of both clouds face the sensor inside the room: oriented pairs agree as they are
    Neighborhood nb;
    nb.k_neighbors = 12;
    const Eigen::Vector3d view(3, 2, 1.3);
    const auto tgt = prepare_cloud(test::box_room(12000, 0.002, 41), nb, view, 0.005, 2);
    const auto src = prepare_cloud(test::box_room(12000, 0.002, 42), nb, view, 0.005, 2);
    RegistrationOptions opt;
    opt.method = Method::kPointToPlane;
    opt.max_correspondence_distances = {0.15};
    opt.oriented = true;
    opt.loss = Loss::kHuber;
    opt.loss_scale = 0.01;
    opt.min_correspondences = 100;
    Eigen::Matrix4d T0 = Eigen::Matrix4d::Identity();
    T0(0, 3) = 0.03;
    T0(1, 3) = -0.02;
    const RegistrationResult r = register_local(*src, *tgt, T0, opt);
    EXPECT_TRUE(r.converged) << r.status;
    EXPECT_LT((r.T_target_source.topRightCorner<3, 1>().norm()), 2e-3);
    EXPECT_GT(r.residual_rmse, 0.0);
    EXPECT_LT(r.residual_rmse, 0.01);
    // a normal flipped on one side is no pair when oriented, the same pair when sign-free
    // (about 1% of the points, at edges and corners, have normals off by more than 60 deg)
    opt.min_correspondences = 1000;
    PreparedCloud flipped;
    flipped.points = src->points;
    flipped.normals = -src->normals;
    flipped.covariances = src->covariances;
    flipped.normal_valid = src->normal_valid;
    flipped.tree = std::make_unique<KdTree<3>>(flipped.points.data(), flipped.points.rows());
    const RegistrationResult none = register_local(flipped, *tgt, T0, opt);
    EXPECT_EQ(none.status, "too_few_correspondences");
    opt.oriented = false;
    const RegistrationResult free = register_local(flipped, *tgt, T0, opt);
    EXPECT_TRUE(free.converged) << free.status;
    EXPECT_LT((free.T_target_source.topRightCorner<3, 1>().norm()), 2e-3);
}

TEST(Registration, MaxSourceUsesAnEvenStride) {
    Neighborhood nb;
    const PointsXYZ pts = test::box_room(20000, 0.002, 51);
    const auto c = prepare_cloud(pts, nb, Eigen::Vector3d(3, 2, 1.3), 0.005, 2);
    RegistrationOptions opt;
    opt.method = Method::kGICP;
    opt.max_correspondence_distances = {0.2};
    opt.max_source = 2000;
    Eigen::Matrix4d T0 = Eigen::Matrix4d::Identity();
    T0(0, 3) = 0.05;
    const RegistrationResult r = register_local(*c, *c, T0, opt);
    EXPECT_TRUE(r.converged) << r.status;
    EXPECT_LE(r.num_inliers, 2000);
    EXPECT_GT(r.num_inliers, 1900);
    EXPECT_LT((r.T_target_source.topRightCorner<3, 1>().norm()), 1e-3);
}

TEST(Registration, TooSmallCloudThrows) {
    PointsXYZ two(2, 3);
    two << 0, 0, 0, 1, 0, 0;
    Neighborhood nb;
    const auto c = prepare_cloud(two, nb, Eigen::Vector3d::Zero(), 0.005, 1);
    RegistrationOptions opt;
    EXPECT_THROW(register_local(*c, *c, Eigen::Matrix4d::Identity(), opt), std::invalid_argument);
}

}  // namespace
}  // namespace tripod
