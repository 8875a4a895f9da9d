# SPDX-License-Identifier: BSD-3-Clause
"""Fragments from the digital twin (``tripod simulate``) for training and held-out tests.

A fragment is what one station of the tripod sees: the capture is simulated into a temporary
directory, decoded with velodyne-decoder, every point placed with the true pose at its firing
time (T_world_lidar from the ground truth), and the points of each station's pan kept together.
"""

from __future__ import annotations

import csv
import tempfile
from pathlib import Path

import numpy as np

SCENES = ("room", "office", "corridor", "two_rooms", "hall")


def fragments_of_capture(capture_dir: str | Path) -> list[np.ndarray]:
    """World-frame fragments (one (N, 3) float32 array [m] per station) of a simulated capture."""
    from ..sim.fidelity import decode_capture, load_meta, place_points

    capture_dir = Path(capture_dir)
    _meta, cfg = load_meta(capture_dir)
    pts = decode_capture(capture_dir)
    _scene, world, _origins = place_points(pts, cfg)
    out = []
    with open(capture_dir / "gt" / "stations.csv") as fh:
        for row in csv.DictReader(fh):
            sel = (pts.host_ns >= int(row["pan_start_ns"])) & (pts.host_ns <= int(row["pan_end_ns"]))
            if sel.any():
                out.append(np.ascontiguousarray(world[sel], np.float32))
    return out


def simulated_fragments(scene: str, seed: int, stations: int = 1,
                        nthreads: int = 0) -> list[np.ndarray]:
    """Simulate ``scene`` with ``seed`` (defaults of ``tripod simulate`` otherwise) and return
    its fragments, (N, 3) float32 [m] each."""
    from ..sim.capture import simulate
    from ..sim.config import SimConfig

    with tempfile.TemporaryDirectory(prefix="tripod-sim-") as tmp:
        simulate(SimConfig(scene=scene, seed=seed, stations=stations), tmp, nthreads=nthreads)
        return fragments_of_capture(tmp)
