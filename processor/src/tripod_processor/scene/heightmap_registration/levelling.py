# SPDX-License-Identifier: BSD-3-Clause
"""Levelling a labelled scan on its floor plane: the frame where only yaw and an x-y shift
remain between two scans."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..planes import CEILING, FLOOR, extract_planes


def _rot_to_z(n: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit n onto +z."""
    n = n / np.linalg.norm(n)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(v), n[2]
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


@dataclass
class LevelledScan:
    """A scan on its floor: T_level_scan (4, 4) puts the floor at z = 0 with +z up; ``xy``/``z``
    are the points standing between floor and ceiling in that frame, ``floor_xy`` the floor's."""

    T_level_scan: np.ndarray
    xy: np.ndarray
    z: np.ndarray
    floor_xy: np.ndarray
    height: float
    labels: np.ndarray
    #: the floor is a plane with (almost) nothing below it: its height can be trusted (a
    #: table top taken for the floor by a scan that saw no floor has walls below it)
    floor_trusted: bool = True


def level_scan(points, labels, *, seed: int = 0, max_points: int = 200_000,
               gravity: bool = False, max_tilt_deg: float = 1.0) -> LevelledScan:
    """Level a labelled scan on its largest floor plane (and measure the ceiling height).

    ``gravity``: the scan's z is already up along gravity (levelled by its IMU up): the floor is
    then the lowest sizeable floor plane within 10 deg of horizontal, refines the levelling only
    when within ``max_tilt_deg`` of it (a sparse, grazing floor can fit worse than the IMU), and
    without one the floor height comes from the lowest floor-labelled (else lowest) points: a
    lidar with its spin axis vertical sees little floor in a small room, but gravity still
    levels it. ``floor_trusted``: the floor is a plane with under 1 % of the points below it."""
    P = np.asarray(points, np.float64)
    labels = np.asarray(labels)
    ok = np.isfinite(P).all(1)
    P, labels = P[ok], labels[ok]
    if len(P) > max_points:  # planes and images need no more
        idx = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
        P, labels = P[idx], labels[idx]
    planes = extract_planes(P, labels, classes=(FLOOR, CEILING), min_points=200, seed=seed)
    floors = [p for p in planes if p.label == FLOOR
              and (not gravity or abs(p.normal[2]) > np.cos(np.radians(10.0)))]
    T = np.eye(4)
    if floors:
        fl = max(floors, key=lambda p: len(p.indices))
        if gravity:  # the lowest sizeable one: a sparse floor can be smaller than a table top
            big = [p for p in floors if len(p.indices) >= 0.2 * len(fl.indices)]
            fl = min(big, key=lambda p: float(np.median(P[p.indices, 2])))
        floor_idx = fl.indices
        if not gravity or abs(fl.normal[2]) > np.cos(np.radians(max_tilt_deg)):
            T[:3, :3] = _rot_to_z(fl.normal)
            T[2, 3] = fl.offset  # n.x + d = 0 on the floor -> z' = n.x + d
        else:  # keep gravity's level; the floor gives its height only
            T[2, 3] = -float(np.median(P[floor_idx, 2]))
    elif gravity:
        on_floor = labels == FLOOR
        zf = P[on_floor, 2] if on_floor.sum() >= 50 else P[:, 2]
        T[2, 3] = -float(np.percentile(zf, 1.0 if on_floor.sum() >= 50 else 0.5))
        floor_idx = np.flatnonzero(np.abs(P[:, 2] + T[2, 3]) < 0.05)
    else:
        raise ValueError("no floor plane found: cannot level the scan")
    R = T[:3, :3]
    Q = P @ R.T + T[:3, 3]
    ceilings = [p for p in planes if p.label == CEILING]
    if ceilings:
        cl = max(ceilings, key=lambda p: len(p.indices))
        height = float(np.median(Q[cl.indices, 2]))
    else:
        height = float(np.percentile(Q[:, 2], 99.5))
    band = (Q[:, 2] > 0.10) & (Q[:, 2] < height - 0.10)
    trusted = bool(floors) and float((Q[:, 2] < -0.10).mean()) < 0.01
    return LevelledScan(T, Q[band, :2], Q[band, 2], Q[floor_idx, :2], height, labels[band],
                        trusted)
