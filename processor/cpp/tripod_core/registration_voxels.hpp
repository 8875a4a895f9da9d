// SPDX-License-Identifier: BSD-3-Clause
// Gaussian voxels of a target cloud for voxelised GICP (VGICP, Koide et al. 2021): each voxel
// holds the mean of its points and the mean of their GICP covariances, and a source point's
// correspondence is the voxel it falls in (one hash look-up instead of a k-d tree search).
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <vector>

#include "tripod_core/registration.hpp"

namespace tripod::detail {

/// Voxel means and covariances in an open-addressing hash table keyed by the voxel's integer
/// coordinates (21 bits each, packed into one 64-bit key).
class GaussianVoxels {
public:
    /// Voxelise `target` (its points and GICP covariances) with edge `resolution` [m].
    GaussianVoxels(const PreparedCloud& target, double resolution);

    /// Index of the voxel holding p (in target coordinates), or -1.
    int find(const Eigen::Vector3d& p) const {
        const uint64_t key = pack(p);
        for (uint64_t s = hash(key) & mask_;; s = (s + 1) & mask_) {
            const int v = slots_[s];
            if (v < 0) return -1;
            if (keys_[v] == key) return v;
        }
    }

    double resolution() const { return resolution_; }
    size_t size() const { return means_.size(); }
    const Eigen::Vector3d& mean(int v) const { return means_[v]; }
    const Eigen::Matrix3d& covariance(int v) const { return covs_[v]; }

private:
    uint64_t pack(const Eigen::Vector3d& p) const {
        constexpr int64_t kOff = int64_t(1) << 20;  // +-1e6 voxels per axis
        constexpr uint64_t kMask = (uint64_t(1) << 21) - 1;
        const auto c = [&](double x) {
            return static_cast<uint64_t>(static_cast<int64_t>(std::floor(x * inv_res_)) + kOff) &
                   kMask;
        };
        return c(p.x()) | (c(p.y()) << 21) | (c(p.z()) << 42);
    }
    static uint64_t hash(uint64_t k) {  // splitmix64 finaliser
        k ^= k >> 30;
        k *= 0xbf58476d1ce4e5b9ULL;
        k ^= k >> 27;
        k *= 0x94d049bb133111ebULL;
        return k ^ (k >> 31);
    }

    double resolution_, inv_res_;
    uint64_t mask_ = 0;
    std::vector<int> slots_;  // hash slot -> voxel index (-1: empty)
    std::vector<uint64_t> keys_;
    std::vector<Eigen::Vector3d> means_;
    std::vector<Eigen::Matrix3d> covs_;
};

}  // namespace tripod::detail
