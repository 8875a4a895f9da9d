// SPDX-License-Identifier: BSD-3-Clause
// Deterministic test clouds for the gtests: a noisy box room with a few objects, and PCL copies.
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <random>

#include "tripod_core/voxel_grid.hpp"

namespace tripod::test {

/// Points on the six faces of a w x d x h box [m] (plus a pillar), Gaussian noise `sigma` [m].
inline PointsXYZ box_room(int n, double sigma, unsigned seed = 7, double w = 6.0, double d = 4.0,
                          double h = 2.6) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::normal_distribution<double> g(0.0, sigma);
    PointsXYZ p(n, 3);
    for (int i = 0; i < n; ++i) {
        const double a = u(rng), b = u(rng);
        double x, y, z;
        switch (i % 7) {
            case 0: x = a * w, y = b * d, z = 0; break;        // floor
            case 1: x = a * w, y = b * d, z = h; break;        // ceiling
            case 2: x = 0, y = a * d, z = b * h; break;        // walls
            case 3: x = w, y = a * d, z = b * h; break;
            case 4: x = a * w, y = 0, z = b * h; break;
            case 5: x = a * w, y = d, z = b * h; break;
            default: {                                         // a 0.4 m square pillar
                const double s = a * 1.6, t = b * h;
                const int side = static_cast<int>(s / 0.4);
                const double r = s - side * 0.4;
                x = 2.0 + (side == 0 ? r : side == 1 ? 0.4 : side == 2 ? 0.4 - r : 0.0);
                y = 1.5 + (side == 0 ? 0.0 : side == 1 ? r : side == 2 ? 0.4 : 0.4 - r);
                z = t;
            }
        }
        p(i, 0) = static_cast<float>(x + g(rng));
        p(i, 1) = static_cast<float>(y + g(rng));
        p(i, 2) = static_cast<float>(z + g(rng));
    }
    return p;
}

inline pcl::PointCloud<pcl::PointXYZ>::Ptr to_pcl(const PointsXYZ& p) {
    pcl::PointCloud<pcl::PointXYZ>::Ptr c(new pcl::PointCloud<pcl::PointXYZ>);
    c->resize(p.rows());
    for (Eigen::Index i = 0; i < p.rows(); ++i) (*c)[i] = pcl::PointXYZ(p(i, 0), p(i, 1), p(i, 2));
    return c;
}

}  // namespace tripod::test
