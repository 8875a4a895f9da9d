# SPDX-License-Identifier: BSD-3-Clause
"""Lidar–IMU calibration from the data: the IMU's time offset, and the mount rotation.

Both use the same principle: the right calibration makes a station's fragment crisp. Crispness
is the RMS distance of sample points to the plane of their nearest neighbours (small for sharp
walls, larger when a wrong offset or mount smears them while the head turns).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..decode.timed import decode_timed_points
from .inputs import LidarPackets
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
    pts = decode_timed_points(lidar.payload, lidar.lidar_ns, st.packet_start, st.packet_stop,
                              min_range=0.5, max_range=30.0)
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
                         ext: Extrinsic, search_s: float, max_points: int = 80_000,
                         min_gain: float = 0.01) -> tuple[int, dict]:
    """IMU time offset [ns] (added to its lidar-clock stamps) that makes a fragment crispest.

    Golden-section search over ±search_s down to 1 ms (the blur grows with the offset's error, so
    the cost is unimodal around the truth), on points farther than 2 m (a wrong offset smears
    them the most). When the best offset sharpens the fragment by less than ``min_gain``
    (relative), the data carry no evidence and the offset stays 0.
    Returns (offset_ns, diagnostics).
    """
    st = most_turning_station(stations, orient)
    xyz, t_ns = _station_sample(lidar, st, 3 * max_points)
    far = np.linalg.norm(xyz, axis=1) > 2.0
    if far.sum() > 1000:
        xyz, t_ns = xyz[far], t_ns[far]
    # At a constant turn rate a time offset only turns the whole fragment (no blur); it shows
    # where the rate changes. Keep the points fired while the head accelerates (and an equal
    # share of the others, for the geometry to compare against).
    grid_t = np.linspace(st.start_ns, st.end_ns, 200).astype(np.int64)
    rate = orient.angular_rate(grid_t)
    acc = np.abs(np.gradient(rate, (grid_t - grid_t[0]) * 1e-9))
    if acc.max() > 0.2:  # [rad/s²]: there are ramps to use
        a_pts = np.interp(t_ns, grid_t, acc)
        hot = a_pts > 0.5 * acc.max()
        if hot.sum() > 2000:
            rng = np.random.default_rng(3)
            cold = np.flatnonzero(~hot)
            cold = rng.choice(cold, min(len(cold), int(hot.sum())), replace=False)
            sel = np.concatenate([np.flatnonzero(hot), cold])
            xyz, t_ns = xyz[sel], t_ns[sel]
    if len(xyz) > max_points:
        keep = np.random.default_rng(2).choice(len(xyz), max_points, replace=False)
        xyz, t_ns = xyz[keep], t_ns[keep]

    def cost(off_s: float) -> float:
        o = orient.with_offset(int(round(off_s * 1e9)))
        return plane_spread(place_points(xyz, t_ns, o, ext, st.mid_ns), n_query=6000)

    a, b = -search_s, search_s
    g = (np.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    evals = [(c, fc), (d, fd)]
    while b - a > 0.001:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
            evals.append((c, fc))
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
            evals.append((d, fd))
    best = 0.5 * (a + b)
    f_best, f_zero = min(fc, fd), cost(0.0)
    if f_best > f_zero * (1.0 - min_gain):
        best = 0.0
    evals.sort()
    return int(round(best * 1e9)), {
        "station": st.index, "offsets_s": [e[0] for e in evals],
        "spread_m": [e[1] for e in evals], "best_s": best, "best_spread_m": f_best,
        "zero_spread_m": f_zero}


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def calibrate_mount(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                    num_threads: int = 0, step_s: float = 0.3, window_s: float = 0.1,
                    max_pairs: int = 16) -> tuple[Extrinsic, dict]:
    """The lidar's mount on the IMU (R_imu_lidar, lever arm) from the data (hand-eye).

    While the head turns at a station, the lidar's motion between two short windows, measured by
    registering them (A, lidar frame), and the IMU's (B, IMU frame) are one rigid motion seen in
    two frames: the rotation axes satisfy a = R_lidar_imu·b, and the lidar's translation
    t_A = R_lidar_imu·(B − I)·ℓ for the lever arm ℓ (pivot → lidar, IMU frame). Rotation: Kabsch
    on the axis pairs, or the shortest rotation taking b onto a when every turn is about one axis
    (a pan). What a single axis leaves open — a turn about the pan axis, a shift along it — does
    not change the fragments (see the reconstruction README), so it is set to zero.
    Returns (Extrinsic with source "calibrated", diagnostics).
    """
    from scipy.spatial.transform import Rotation

    from ..registration import pairwise as reg

    st = most_turning_station(stations, orient)
    t0 = st.start_ns
    times = np.arange(t0, st.end_ns - int(window_s * 1e9), int(step_s * 1e9), dtype=np.int64)
    clouds = []
    for t in times:
        a, b = np.searchsorted(lidar.lidar_ns, [t, t + int(window_s * 1e9)])
        pts = decode_timed_points(lidar.payload, lidar.lidar_ns, int(a), int(b), min_range=0.5,
                                  max_range=40.0)
        clouds.append(np.stack([pts["x"], pts["y"], pts["z"]], 1))
    A_list, B_list = [], []
    for k in range(min(len(times) - 1, max_pairs)):
        if len(clouds[k]) < 500 or len(clouds[k + 1]) < 500:
            continue
        R_a = orient.rotation_at(np.array([times[k] + int(window_s * 0.5e9)]))[0]
        R_b = orient.rotation_at(np.array([times[k + 1] + int(window_s * 0.5e9)]))[0]
        B = R_a.T @ R_b
        try:
            r = reg.register(clouds[k + 1], clouds[k], method="gicp", voxel_size=0.1,
                             max_correspondence_distance=[1.0, 0.3, 0.15],
                             num_threads=num_threads)
        except ValueError:
            continue
        if r.fitness < 0.5:
            continue
        A_list.append(r.T_target_source)
        B_list.append(B)
    if len(A_list) < 3:
        raise ValueError("too few usable turns to calibrate the lidar mount from the data")
    a = np.array([_rotvec(A[:3, :3]) for A in A_list])
    b = np.array([_rotvec(B) for B in B_list])
    # weights: bigger turns are better measured
    w = np.linalg.norm(b, axis=1)
    H = (b * w[:, None]).T @ a  # Σ w b aᵀ
    U, S, Vt = np.linalg.svd(H)
    if S[1] > 0.2 * S[0]:  # turns about at least two axes: the full rotation
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R_li = Vt.T @ D @ U.T
    else:  # one axis: the shortest rotation taking the mean b onto the mean a
        bb = (b * w[:, None]).sum(0)
        aa = (a * w[:, None]).sum(0)
        bb /= np.linalg.norm(bb)
        aa /= np.linalg.norm(aa)
        ax = np.cross(bb, aa)
        s, c = np.linalg.norm(ax), float(bb @ aa)
        R_li = np.eye(3) if s < 1e-12 else Rotation.from_rotvec(
            ax / s * np.arctan2(s, c)).as_matrix()
    R_il = R_li.T
    # lever arm: (B − I) ℓ = R_il t_A, least squares (minimum norm along the unseen axis)
    M = np.concatenate([B - np.eye(3) for B in B_list])
    y = np.concatenate([R_il @ A[:3, 3] for A in A_list])
    ell, *_ = np.linalg.lstsq(M, y, rcond=0.05)
    resid = [np.degrees(Rotation.from_matrix(A[:3, :3].T @ (R_li @ B @ R_il)).magnitude())
             for A, B in zip(A_list, B_list)]
    return Extrinsic(R_il, ell, "calibrated"), {
        "station": st.index, "pairs": len(A_list), "axis_singular_values": S.tolist(),
        "rotation_residual_deg_median": float(np.median(resid))}
