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


def fragments_of_capture(capture_dir: str | Path, frame: str = "world") -> list[np.ndarray]:
    """Fragments (one (N, 3) float32 array [m] per station, in firing order) of a simulated
    capture: ``frame="world"`` places every point with the true pose at its firing time;
    ``frame="lidar"`` keeps the decoded sensor-frame points (what the lidar itself reports)."""
    if frame not in ("world", "lidar"):
        raise ValueError(f"frame must be 'world' or 'lidar', not {frame!r}")
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
                xyz = world[sel] if frame == "world" else pts.xyz[sel]
                out.append(np.ascontiguousarray(xyz, np.float32))
    return out


def simulated_fragments(scene: str, seed: int, stations: int = 1, nthreads: int = 0,
                        frames: tuple[str, ...] = ("world",)) -> list[np.ndarray]:
    """Simulate ``scene`` with ``seed`` (defaults of ``tripod simulate`` otherwise) and return
    its fragments, (N, 3) float32 [m] each; with several ``frames`` (see
    :func:`fragments_of_capture`), the fragments of each frame one after the other."""
    from ..sim.capture import simulate
    from ..sim.config import SimConfig

    with tempfile.TemporaryDirectory(prefix="tripod-sim-") as tmp:
        simulate(SimConfig(scene=scene, seed=seed, stations=stations), tmp, nthreads=nthreads)
        return [f for frame in frames for f in fragments_of_capture(tmp, frame)]
