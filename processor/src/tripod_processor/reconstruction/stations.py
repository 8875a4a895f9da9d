# SPDX-License-Identifier: BSD-3-Clause
"""Split a recording into stations: periods when the tripod stands (its head may turn).

Stationarity comes from the lidar and the IMU together: short windows of points are rotated by
the IMU (and the extrinsic) into the head-pivot frame, where a standing tripod sees the same
scene whatever the head does; a window is "still" when the pivot shift fitted to the range
changes along the directions it shares with the window ``still_gap_s`` earlier is below
``still_threshold`` [m], and the IMU's pan axis (the tripod's vertical) has not tilted by more
than ``still_tilt_deg`` in that time (carrying sways it). Runs of still windows
longer than ``min_station_s`` are stations. The operator's ``mark`` events label the stations
they fall in; a mark outside every still period is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..decode.timed import decode_timed_points
from .config import StationConfig
from .inputs import LidarPackets
from .placement import Extrinsic, ImuOrientation, place_points, pose_world_lidar


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
    tilt_deg: np.ndarray | None = None  # (K,) change of the pan axis over still_gap_s [deg]


def _window_cloud(lidar: LidarPackets, a: int, b: int, orient: ImuOrientation, ext: Extrinsic,
                  n_max: int, rng: np.random.Generator) -> np.ndarray:
    """Points of packets [a, b) in the head-pivot frame, at most n_max (random subset)."""
    pts = decode_timed_points(lidar.payload, lidar.lidar_ns, a, b, min_range=0.5)
    if len(pts) == 0:
        return np.zeros((0, 3))
    order = None
    if len(pts) > n_max:
        sel = rng.choice(len(pts), n_max, replace=False)  # random order: any prefix is a sample
        keep = np.sort(sel)  # placed in firing order (the native placement's fast path) ...
        order = np.searchsorted(keep, sel)  # ... and given back in the sample's order
        pts = pts[keep]
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    # R_wi(t) (R_il x + l) = T_wl(a) · (the point placed in the lidar frame at a)
    anchor = int(pts["time_ns"][len(pts) // 2])
    placed = place_points(xyz, pts["time_ns"], orient, ext, anchor, num_threads=1)
    T_a = pose_world_lidar(orient, ext, np.array([anchor]))[0]
    p = placed.astype(np.float64) @ T_a[:3, :3].T + T_a[:3, 3]
    return p if order is None else p[order]


def pivot_shift(ref: np.ndarray, query: np.ndarray, max_angle_deg: float = 0.3) -> float:
    """How far the head's pivot moved between two windows [m], from the ranges along the
    directions both windows sampled (pivot frame).

    A standing tripod sees the same range in every direction from the pivot whatever the head
    does. If the pivot moved by d, the range along direction u changes by about −u·d, so a
    robust least-squares fit of d to the range changes measures the motion in whatever
    directions the shared view constrains (weakly constrained directions are left out). Only
    directions sampled by both windows (within ``max_angle_deg``) are compared, because a tilted
    lidar on a panning head sweeps different parts of the sphere from moment to moment.
    NaN when fewer than 50 directions match.
    """
    r_ref = np.linalg.norm(ref, axis=1)
    r_q = np.linalg.norm(query, axis=1)
    ok_r, ok_q = r_ref > 0.3, r_q > 0.3
    ref, r_ref, query, r_q = ref[ok_r], r_ref[ok_r], query[ok_q], r_q[ok_q]
    if len(ref) < 50 or len(query) < 50:
        return float("nan")
    u_q = query / r_q[:, None]
    # exact nearest neighbours; an unbalanced tree builds ~2x faster and queries alike here
    tree = cKDTree(ref / r_ref[:, None], balanced_tree=False, compact_nodes=False)
    dist, idx = tree.query(u_q, k=1,
                                                    distance_upper_bound=np.radians(max_angle_deg))
    hit = np.isfinite(dist)
    if hit.sum() < 50:
        return float("nan")
    A = -u_q[hit]
    b = r_q[hit] - r_ref[idx[hit]]
    keep = np.ones(len(b), dtype=bool)
    d = np.zeros(3)
    for _ in range(3):  # least squares, then trim outliers (occlusion edges, grazing surfaces)
        d, *_ = np.linalg.lstsq(A[keep], b[keep], rcond=None)
        res = b - A @ d
        mad = np.median(np.abs(res[keep] - np.median(res[keep]))) + 1e-6
        keep = np.abs(res) < 3.0 * 1.4826 * mad
        if keep.sum() < 20:
            return float("nan")
    # only the directions the shared view constrains
    w, V = np.linalg.eigh(A[keep].T @ A[keep] / keep.sum())
    d_obs = V[:, w > 0.05] @ (V[:, w > 0.05].T @ d)
    return float(np.linalg.norm(d_obs))


def segment_stations(lidar: LidarPackets, orient: ImuOrientation, ext: Extrinsic,
                     cfg: StationConfig, marks_lidar_ns: list[tuple[int, str]] | None = None,
                     step_s: float = 0.5, window_s: float = 0.1, n_points: int = 12000,
                     n_query: int = 4000,
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
            motion[k] = pivot_shift(clouds[j], clouds[k][:n_query])
        if j >= 0:
            clouds[j] = None  # type: ignore[call-overload]  (bounded memory)
        if progress is not None:
            progress.update(1)
    # unknown (too little shared view): take the neighbours' verdict
    bad = ~np.isfinite(motion)
    if bad.any() and (~bad).any():
        good = np.flatnonzero(~bad)
        motion[bad] = np.interp(np.flatnonzero(bad), good, motion[good])
    # the IMU's view: a standing tripod's pan axis stays put; carrying sways it. The pan axis
    # in the IMU frame is the mean of the world's up seen by the IMU (the base is level at
    # every station, and sway averages out).
    tilt = np.zeros(len(times))
    if len(times) > gap:
        R_all = orient.rotation_at(times + win // 2)
        b = np.einsum("nji,j->ni", R_all, np.array([0.0, 0.0, 1.0])).mean(axis=0)
        b /= np.linalg.norm(b)
        axis_w = np.einsum("nij,j->ni", R_all, b)
        c = np.clip(np.einsum("ni,ni->n", axis_w[gap:], axis_w[:-gap]), -1.0, 1.0)
        tilt[gap:] = np.degrees(np.arccos(c))
    moving_imu = tilt > cfg.still_tilt_deg
    # a 3-window median removes single spikes (a person walking by, a bad match)
    if len(motion) >= 3:
        padded = np.concatenate([motion[:1], motion, motion[-1:]])
        motion = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    # a window is still when it matches the window gap before or the window gap after it
    still_pair = (motion < cfg.still_threshold) & ~moving_imu
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
    return Segmentation(stations, times, motion, still, notes, tilt)
