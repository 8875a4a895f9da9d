# SPDX-License-Identifier: BSD-3-Clause
"""Small labelled scans shared by the scene-understanding tests (cached per session)."""

from __future__ import annotations

import functools

import numpy as np

from tripod_processor.sim.rooms import free_station, make_room, scan


@functools.lru_cache(maxsize=None)
def room_scan(seed: int, kind: str | None = None, head_steps: int = 12, noise_m: float = 0.03,
              station_seed: int = 0):
    """(points, labels, scene, station) of one synthetic room scanned from one station."""
    scene = make_room(seed, kind=kind)
    st = free_station(scene, np.random.default_rng(station_seed))
    p, lab = scan(scene, st, head_steps=head_steps, noise_m=noise_m, seed=seed)
    return p, lab, scene, st
