// SPDX-License-Identifier: BSD-3-Clause
// Conversions shared by the binding files, and the registry that assembles them into one module.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <cstring>
#include <initializer_list>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
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

namespace detail {
template <typename C>
auto data_of(C& c) -> decltype(c.data()) {
    return c.data();  // std::vector, Eigen matrices (row-major where 2-D), ...
}
template <typename T>
T* data_of(std::unique_ptr<T[]>& c) {
    return c.get();
}
}  // namespace detail

/// THE way the bindings hand memory to numpy: move `container` (a std::vector, a row-major
/// Eigen matrix or a std::unique_ptr<T[]>) to the heap and return a numpy array of `shape` over
/// its storage, owned by a capsule that deletes it when the array dies (no copy). `Extra` adds
/// nanobind ndarray annotations (nb::shape<-1, 3>, nb::ndim<1>) for the stubs. The registration
/// bindings may adopt it too; keep the name stable. A result class that holds such arrays
/// exposes them with nb::rv_policy::reference (the array has its owner already; the default
/// reference_internal would refuse it).
template <typename... Extra, typename Container>
auto owned_array(Container&& container, std::initializer_list<size_t> shape) {
    using C = std::decay_t<Container>;
    static_assert(!std::is_lvalue_reference_v<Container>, "owned_array takes ownership: move");
    using T = std::remove_pointer_t<decltype(detail::data_of(std::declval<C&>()))>;
    auto* heap = new C(std::move(container));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<C*>(p); });
    T* data = detail::data_of(*heap);
    static std::remove_const_t<T> no_elements{};  // an empty container may have no storage
    return nb::ndarray<nb::numpy, T, Extra...>(data ? data : &no_elements, shape.size(),
                                                shape.begin(), owner);
}

/// A 1-D numpy array that takes over a vector (no copy).
template <typename T>
auto owned_array(std::vector<T>&& v) {
    const size_t n = v.size();
    return owned_array<nb::ndim<1>>(std::move(v), {n});
}

/// Move an Eigen cloud into an (N, 3) numpy array (no copy).
inline CloudOut to_numpy(tripod::PointsXYZ&& m) {
    const size_t n = static_cast<size_t>(m.rows());
    return owned_array<nb::shape<-1, 3>>(std::move(m), {n, 3});
}

}  // namespace tripod_bind

/// Define the binding function of one topic; it is called when the module is initialised.
#define TRIPOD_BINDING(topic)                                                          \
    static void tripod_bind_##topic(nanobind::module_& m);                             \
    static const tripod_bind::AutoBind tripod_autobind_##topic(#topic, tripod_bind_##topic); \
    static void tripod_bind_##topic(nanobind::module_& m)
