// SPDX-License-Identifier: BSD-3-Clause
// tripod_processor._ext: one module assembled from the binding files (one per topic), each of
// which registers itself with TRIPOD_BINDING(topic). Static registration runs at load, before
// NB_MODULE's init; topics bind in name order so the module is the same on every build.
#include <algorithm>

#include "common.hpp"

NB_MODULE(_ext, m) {
    m.doc() = "tripod native core (private: use the tripod_processor Python API)";
    auto fns = tripod_bind::binding_registry();
    std::sort(fns.begin(), fns.end());
    for (auto& [name, fn] : fns) fn(m);
}
