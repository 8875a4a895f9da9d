// SPDX-License-Identifier: BSD-3-Clause
// tripod_processor._ext: one module assembled from one binding file per topic.
#include <nanobind/nanobind.h>

namespace nb = nanobind;

void bind_preprocess(nb::module_& m);

NB_MODULE(_ext, m) {
    m.doc() = "tripod native core (private: use the tripod_processor Python API)";
    bind_preprocess(m);
}
