# SPDX-License-Identifier: BSD-3-Clause
"""tripod processor: turns tripod recordings into registered indoor models.

Data flows one way: recording (MCAP / pcap) → decode → placement (IMU) → fragments →
registration → pose graph → model → segmentation / heightmaps / compression.
Heavy dependencies (torch, open3d) are imported lazily by the modules that need them.
"""

import os as _os

# How the native core's OpenMP threads wait between parallel regions, unless the user chose
# (OMP_WAIT_POLICY / GOMP_SPINCOUNT in the environment win). libgomp's default, a 3-ms spin,
# keeps an idle thread burning a core; on a busy machine that makes 2 threads slower than 1
# (2 shared cores at load 7: GICP wall 313 ms spinning vs 118 ms passive). Passive waiting costs
# a wake-up per region instead (~30-300 µs on a VM), which kept 2 threads at 1.76-1.89x of one
# on the idle 2-core VM. So: passive, plus a short spin (GOMP_SPINCOUNT=30000, ~0.3 ms, then
# sleep; libgomp never spins when it has more threads than CPUs) when the machine was quiet
# when this process started (1-min load < half the CPUs it may use): 1.82-1.98x on the idle
# VM (bench/registration.py --threads, README "Thread scaling"). Set before _ext loads libgomp,
# which reads them once per process. The registration path's own workers
# (tripod_core/thread_pool.cpp) read the same two variables when they start.


def _openmp_wait_policy(environ=_os.environ) -> None:
    if "OMP_WAIT_POLICY" in environ or "GOMP_SPINCOUNT" in environ:
        return
    environ["OMP_WAIT_POLICY"] = "PASSIVE"
    try:
        cpus = len(_os.sched_getaffinity(0))
        quiet = _os.getloadavg()[0] < 0.5 * cpus
    except (AttributeError, OSError):  # no affinity / load average on this platform
        quiet = False
    if quiet and cpus > 1:
        environ["GOMP_SPINCOUNT"] = "30000"


_openmp_wait_policy()

__version__ = "0.1.0"
