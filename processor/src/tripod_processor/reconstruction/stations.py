# SPDX-License-Identifier: BSD-3-Clause
"""Split a recording into stations: periods when the tripod stands (its head may turn).

Stationarity comes from the lidar and the IMU together: short windows of points are rotated by
the IMU (and the extrinsic) into the head-pivot frame, where a standing tripod sees the same
scene whatever the head does; a window is "still" when it lies on the window ``still_gap_s``
earlier (median nearest-neighbour distance over range below ``still_threshold``). Runs of still windows
longer than ``min_station_s`` are stations. The operator's ``mark`` events label the stations
they fall in; a mark outside every still period is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .config import StationConfig
from .inputs import LidarPackets, decode_points
from .placement import Extrinsic, ImuOrientation


@dataclass
class Station:
    """One station: lidar-time span [start_ns, end_ns) and its packets [packet_start, packet_stop)."""

    index: int
    start_ns: int
    end_ns: int
    packet_start: int
    packet_stop: int
    label: str = ""

    @property
    def mid_ns(self) -> int:
        return (self.start_ns + self.end_ns) // 2

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9


@dataclass
class Segmentation:
    stations: list[Station]
    t_ns: np.ndarray  # (K,) window times
    motion_m: np.ndarray  # (K,) median displacement against the window still_gap_s before
    still: np.ndarray  # (K,) bool
    notes: list[str] = field(default_factory=list)


def _window_cloud(lidar: LidarPackets, a: int, b: int, orient: ImuOrientation, ext: Extrinsic,
                  n_max: int, rng: np.random.Generator) -> np.ndarray:
    """Points of packets [a, b) in the head-pivot frame, at most n_max (random subset)."""
    pts = decode_points(lidar, a, b, min_range=0.5)
    if len(pts) > n_max:
        pts = pts[rng.choice(len(pts), n_max, replace=False)]
    if len(pts) == 0:
        return np.zeros((0, 3))
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    R_wi = orient.rotation_at(pts["time_ns"])
    return np.einsum("nij,nj->ni", R_wi, xyz @ ext.R_imu_lidar.T + ext.lever_arm_m)


def _relative_displacement(ref: np.ndarray, query: np.ndarray) -> float:
    """Median of (distance to the nearest reference point) / range over the query points.

    Dividing by the range makes the test independent of the room's size: a single sweep samples
    surfaces along its 16 rings, so even a standing tripod's windows differ by up to half the
    ring spacing, which grows with range; a carried tripod shifts near points the most.
    """
    d, _ = cKDTree(ref).query(query, k=1, distance_upper_bound=2.0)
    d[~np.isfinite(d)] = 2.0
    r = np.maximum(np.linalg.norm(query, axis=1), 0.5)
    return float(np.median(d / r))


def segment_stations(lidar: LidarPackets, orient: ImuOrientation, ext: Extrinsic,
                     cfg: StationConfig, marks_lidar_ns: list[tuple[int, str]] | None = None,
                     step_s: float = 0.25, window_s: float = 0.1, n_points: int = 12000,
                     n_query: int = 1500,
                     progress=None) -> Segmentation:
    """Find the stations of a recording (see the module docstring)."""
    t0, t1 = int(lidar.lidar_ns[0]), int(lidar.lidar_ns[-1])
    step, win = int(step_s * 1e9), int(window_s * 1e9)
    times = np.arange(t0, t1 - win, step, dtype=np.int64)
    gap = max(1, int(round(cfg.still_gap_s / step_s)))
    rng = np.random.default_rng(0)
    clouds: list[np.ndarray] = []
    motion = np.full(len(times), np.inf)
    for k, t in enumerate(times):
        a, b = np.searchsorted(lidar.lidar_ns, [t, t + win])
        clouds.append(_window_cloud(lidar, int(a), int(b), orient, ext, n_points, rng))
        j = k - gap
        if j >= 0 and len(clouds[j]) > 50 and len(clouds[k]) > 50:
            motion[k] = _relative_displacement(clouds[j], clouds[k][:n_query])
        if j >= 0:
            clouds[j] = None  # type: ignore[call-overload]  (bounded memory)
        if progress is not None:
            progress.update(1)
    # a window is still when it matches the window gap before or the window gap after it
    still_pair = motion < cfg.still_threshold
    still = still_pair.copy()
    still[: len(still) - gap] |= still_pair[gap:]

    stations: list[Station] = []
    trim = int(cfg.trim_s * 1e9)
    k = 0
    while k < len(times):
        if not still[k]:
            k += 1
            continue
        e = k
        while e + 1 < len(times) and still[e + 1]:
            e += 1
        s_ns, e_ns = int(times[k]) + trim, int(times[e]) + win - trim
        if (e_ns - s_ns) * 1e-9 >= cfg.min_station_s:
            a, b = np.searchsorted(lidar.lidar_ns, [s_ns, e_ns])
            stations.append(Station(len(stations), s_ns, e_ns, int(a), int(b)))
        k = e + 1
    notes = []
    if marks_lidar_ns and cfg.use_marks:
        for t_mark, label in marks_lidar_ns:
            hit = [s for s in stations if s.start_ns - 2 * step <= t_mark <= s.end_ns + 2 * step]
            if hit:
                hit[0].label = label or hit[0].label
            else:
                notes.append(f"mark {label!r} at {t_mark * 1e-9:.3f} s falls in no still period")
    return Segmentation(stations, times, motion, still, notes)
