# SPDX-License-Identifier: BSD-3-Clause
"""tripod processor: turns tripod recordings into registered indoor models.

Data flows one way: recording (MCAP / pcap) → decode → placement (IMU) → fragments →
registration → pose graph → model → segmentation / heightmaps / compression.
Heavy dependencies (torch, open3d) are imported lazily by the modules that need them.
"""

import os as _os

# OpenMP threads of the native core wait passively (sleep) between parallel regions unless the
# user chose otherwise. libgomp's default spin-wait keeps an idle thread burning a core; on a
# busy workstation that makes 2 threads slower than 1 (measured on 2 shared cores at load 7:
# GICP wall 313 ms spinning vs 118 ms passive); on an idle one passive costs microseconds per
# region (tens of µs on a VM: the core keeps its parallel regions few and lets threads take
# over each other's chunks, tripod_core/parallel_chunks.hpp). A short spin (GOMP_SPINCOUNT=30000)
# was measured again for issue 17: 2 threads 1.85x faster than 1 at real-time priority, but 2-3x
# slower than 1 at load 20 without it. Set before _ext loads libgomp, which reads it once.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
