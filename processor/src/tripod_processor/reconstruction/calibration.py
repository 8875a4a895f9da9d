# SPDX-License-Identifier: BSD-3-Clause
"""Lidar–IMU calibration from the data: the IMU's time offset, and the mount rotation.

Both use the same principle: the right calibration makes a station's fragment crisp. Crispness
is the RMS distance of sample points to the plane of their nearest neighbours (small for sharp
walls, larger when a wrong offset or mount smears them while the head turns).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .inputs import LidarPackets, decode_points
from .placement import Extrinsic, ImuOrientation, place_points
from .stations import Station


def plane_spread(points: np.ndarray, n_query: int = 4000, k: int = 12, seed: int = 0) -> float:
    """RMS point-to-local-plane distance [m] of a cloud (lower is crisper)."""
    rng = np.random.default_rng(seed)
    q = points[rng.choice(len(points), min(n_query, len(points)), replace=False)]
    _, idx = cKDTree(points).query(q, k=k)
    nb = points[idx]  # (Q,k,3)
    c = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("qki,qkj->qij", c, c) / k
    w = np.linalg.eigvalsh(cov)[:, 0]  # smallest eigenvalue: variance off the plane
    return float(np.sqrt(np.mean(np.clip(w, 0, None))))


def _station_sample(lidar: LidarPackets, st: Station, max_points: int):
    pts = decode_points(lidar, st.packet_start, st.packet_stop, min_range=0.5, max_range=30.0)
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(1).choice(len(pts), max_points, replace=False)]
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    return xyz, pts["time_ns"]


def most_turning_station(stations: list[Station], orient: ImuOrientation) -> Station:
    """The station over which the head turns the most (strongest signal for calibration)."""
    best, best_turn = stations[0], -1.0
    for st in stations:
        t = np.linspace(st.start_ns, st.end_ns, 20).astype(np.int64)
        turn = float(np.sum(orient.angular_rate(t[1:-1]))) * (st.end_ns - st.start_ns) * 1e-9 / 18
        if turn > best_turn:
            best, best_turn = st, turn
    return best


def estimate_time_offset(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                         ext: Extrinsic, search_s: float, max_points: int = 120_000
                         ) -> tuple[int, dict]:
    """IMU time offset [ns] (added to its lidar-clock stamps) that makes a fragment crispest.

    A grid over ±search_s in 10 ms steps, then golden-section refinement to 0.5 ms.
    Returns (offset_ns, diagnostics).
    """
    st = most_turning_station(stations, orient)
    xyz, t_ns = _station_sample(lidar, st, max_points)

    def cost(off_s: float) -> float:
        o = orient.with_offset(int(round(off_s * 1e9)))
        return plane_spread(place_points(xyz, t_ns, o, ext, st.mid_ns))

    grid = np.arange(-search_s, search_s + 1e-9, 0.01)
    costs = np.array([cost(g) for g in grid])
    k = int(np.argmin(costs))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    g = (np.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    while b - a > 0.0005:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
    best = 0.5 * (a + b)
    return int(round(best * 1e9)), {
        "station": st.index, "grid_s": grid.tolist(), "spread_m": costs.tolist(),
        "best_s": best, "best_spread_m": min(fc, fd), "zero_spread_m": cost(0.0)}
