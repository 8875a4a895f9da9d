// SPDX-License-Identifier: BSD-3-Clause
// Conversions shared by the binding files, and the registry that assembles them into one module.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "tripod_core/voxel_grid.hpp"

namespace tripod_bind {
namespace nb = nanobind;

// ---- registry: each binding file registers itself with TRIPOD_BINDING(topic) { ... } ----------
using BindFn = void (*)(nb::module_&);
inline std::vector<std::pair<std::string, BindFn>>& binding_registry() {
    static std::vector<std::pair<std::string, BindFn>> fns;
    return fns;
}
struct AutoBind {
    AutoBind(const char* name, BindFn fn) { binding_registry().emplace_back(name, fn); }
};

// ---- numpy <-> Eigen ------------------------------------------------------------------------
using CloudIn = nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
using CloudOut = nb::ndarray<nb::numpy, float, nb::shape<-1, 3>>;

/// Copy an (N,3) float32 numpy array into an Eigen row-major matrix (one copy per cloud).
inline tripod::PointsXYZ to_eigen(const CloudIn& a) {
    tripod::PointsXYZ m(static_cast<Eigen::Index>(a.shape(0)), 3);
    if (a.shape(0)) std::memcpy(m.data(), a.data(), sizeof(float) * 3 * a.shape(0));
    return m;
}

/// Move an Eigen cloud into a numpy array owned by a capsule (no copy).
inline CloudOut to_numpy(tripod::PointsXYZ&& m) {
    auto* heap = new tripod::PointsXYZ(std::move(m));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<tripod::PointsXYZ*>(p); });
    return CloudOut(heap->data(), {static_cast<size_t>(heap->rows()), 3}, owner);
}

}  // namespace tripod_bind

/// Define the binding function of one topic; it is called when the module is initialised.
#define TRIPOD_BINDING(topic)                                                          \
    static void tripod_bind_##topic(nanobind::module_& m);                             \
    static const tripod_bind::AutoBind tripod_autobind_##topic(#topic, tripod_bind_##topic); \
    static void tripod_bind_##topic(nanobind::module_& m)
