// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/registration_voxels.hpp"

#include <stdexcept>

namespace tripod::detail {

GaussianVoxels::GaussianVoxels(const PreparedCloud& target, double resolution)
    : resolution_(resolution), inv_res_(1.0 / resolution) {
    if (!(resolution > 0) || !std::isfinite(resolution))
        throw std::invalid_argument("voxel resolution must be finite and > 0");
    const int64_t n = target.points.rows();
    uint64_t cap = 16;
    while (cap < static_cast<uint64_t>(2 * n)) cap <<= 1;  // load factor <= 1/2
    mask_ = cap - 1;
    slots_.assign(cap, -1);
    std::vector<int> count;
    keys_.reserve(n / 4 + 1);
    for (int64_t i = 0; i < n; ++i) {
        const Eigen::Vector3d p = target.points.row(i).transpose().cast<double>();
        const uint64_t key = pack(p);
        uint64_t s = hash(key) & mask_;
        int v;
        while ((v = slots_[s]) >= 0 && keys_[v] != key) s = (s + 1) & mask_;
        if (v < 0) {
            v = static_cast<int>(keys_.size());
            slots_[s] = v;
            keys_.push_back(key);
            means_.push_back(Eigen::Vector3d::Zero());
            covs_.push_back(Eigen::Matrix3d::Zero());
            count.push_back(0);
        }
        means_[v] += p;
        covs_[v] += target.covariances[i];
        ++count[v];
    }
    for (size_t v = 0; v < means_.size(); ++v) {
        means_[v] /= count[v];
        covs_[v] /= count[v];
    }
}

}  // namespace tripod::detail
