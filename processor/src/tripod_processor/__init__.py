# SPDX-License-Identifier: BSD-3-Clause
"""tripod processor: turns tripod recordings into registered indoor models.

Data flows one way: recording (MCAP / pcap) → decode → placement (IMU) → fragments →
registration → pose graph → model → segmentation / heightmaps / compression.
Heavy dependencies (torch, open3d) are imported lazily by the modules that need them.
"""

__version__ = "0.1.0"
