# SPDX-License-Identifier: BSD-3-Clause
"""Accuracy against ground truth: station ATE, odometry drift, map-to-mesh distance, and the
thesis' fragment plane-fit errors (which need no truth)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def interpolate_poses(t_ref: np.ndarray, T_ref: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Poses (Q, 4, 4) at ``t_query`` from a trajectory (slerp + linear; clamped at the ends)."""
    t_ref = np.asarray(t_ref, dtype=np.int64)
    tq = np.clip(np.asarray(t_query, dtype=np.int64), t_ref[0], t_ref[-1])
    x = (t_ref - t_ref[0]).astype(np.float64)
    xq = (tq - t_ref[0]).astype(np.float64)
    R = Slerp(x, Rotation.from_matrix(T_ref[:, :3, :3]))(xq).as_matrix()
    out = np.tile(np.eye(4), (len(tq), 1, 1))
    out[:, :3, :3] = R
    for i in range(3):
        out[:, i, 3] = np.interp(xq, x, T_ref[:, i, 3])
    return out


def umeyama_rigid(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid T (4, 4) minimising Σ|dst − T·src|² (no scale), points (N, 3)."""
    ms, md = src.mean(0), dst.mean(0)
    H = (src - ms).T @ (dst - md)
    U, _, Vt = np.linalg.svd(H)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = md - R @ ms
    return T


@dataclass
class PoseErrors:
    ate_m: float  # RMSE of position after rigid alignment [m]
    ate_deg: float  # RMSE of orientation after the same alignment [deg]
    max_m: float
    max_deg: float
    per_station_m: np.ndarray
    per_station_deg: np.ndarray


def align_poses(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """Rigid A (4, 4) with A·T_est ≈ T_true using orientations and positions: the chordal mean of
    R_true R_estᵀ for the rotation, then the mean position offset. Well conditioned for any
    number of stations (positions alone are not when the stations lie on a line)."""
    M = np.einsum("nij,nkj->ik", T_true[:, :3, :3], T_est[:, :3, :3])
    U, _, Vt = np.linalg.svd(M)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = (T_true[:, :3, 3] - T_est[:, :3, 3] @ R.T).mean(axis=0)
    return A


def pose_errors(T_est: np.ndarray, T_true: np.ndarray, align: str = "poses") -> PoseErrors:
    """Absolute trajectory error of station poses (N, 4, 4) against truth.

    ``align``: ``poses`` (:func:`align_poses`), ``umeyama`` (rigid fit of positions, as evo's
    ``-a``; needs N ≥ 3) or ``first`` (the first station's pose mapped onto the truth, as for
    drift).
    """
    if align == "poses":
        A = align_poses(T_est, T_true)
    elif align == "umeyama" and len(T_est) >= 3:
        A = umeyama_rigid(T_est[:, :3, 3], T_true[:, :3, 3])
    else:
        A = T_true[0] @ np.linalg.inv(T_est[0])
    E = np.linalg.inv(T_true) @ (A @ T_est)
    dt = np.linalg.norm(T_true[:, :3, 3] - (A @ T_est)[:, :3, 3], axis=1)
    dr = np.degrees(Rotation.from_matrix(E[:, :3, :3]).magnitude())
    return PoseErrors(float(np.sqrt(np.mean(dt**2))), float(np.sqrt(np.mean(dr**2))),
                      float(dt.max()), float(dr.max()), dt, dr)


def odometry_drift(T_odom: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(drift in % of path length, path length [m]): the end station's position error of the
    odometry chain, started on the truth at the first station, over the true path length."""
    path = float(np.sum(np.linalg.norm(np.diff(T_true[:, :3, 3], axis=0), axis=1)))
    e = pose_errors(T_odom, T_true, align="first")
    return (100.0 * float(e.per_station_m[-1]) / path if path > 0 else float("nan")), path


def map_to_mesh(points: np.ndarray, mesh_path: str, T_mesh_map: np.ndarray | None = None,
                max_points: int = 200_000) -> np.ndarray:
    """Unsigned distances [m] from (a sample of) map points to a triangle mesh (PLY/OBJ/...)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"{mesh_path}: no triangles")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    p = np.asarray(points, dtype=np.float64)
    if len(p) > max_points:
        p = p[np.random.default_rng(0).choice(len(p), max_points, replace=False)]
    if T_mesh_map is not None:
        p = p @ T_mesh_map[:3, :3].T + T_mesh_map[:3, 3]
    d = scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()
    return d.astype(np.float64)


# ---- plane-fit errors of a fragment (the thesis' error analysis) --------------------------------
def plane_fit_errors(points: np.ndarray, up: np.ndarray, *, distance_m: float = 0.05,
                     min_inliers: int = 500, max_planes: int = 8, seed: int = 0
                     ) -> dict[str, np.ndarray]:
    """Signed point-to-plane residuals [m] of the large planes of a fragment, split into
    horizontal (floor, ceiling: normal within 10° of ``up``) and vertical (walls: normal within
    10° of horizontal) planes. Planes by RANSAC (Open3D), largest first."""
    import open3d as o3d

    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    o3d.utility.random.seed(seed)
    out = {"horizontal": [], "vertical": []}
    for _ in range(max_planes):
        if len(pc.points) < min_inliers:
            break
        model, idx = pc.segment_plane(distance_m, 3, 100)
        if len(idx) < min_inliers:
            break
        n = np.asarray(model[:3])
        nn = np.linalg.norm(n)
        n, d = n / nn, model[3] / nn
        inl = np.asarray(pc.select_by_index(idx).points)
        # least-squares refit on the inliers, then residuals
        c = inl.mean(0)
        w, V = np.linalg.eigh(np.cov((inl - c).T))
        n = V[:, 0]
        res = (inl - c) @ n
        cosang = abs(float(n @ up))
        if cosang > np.cos(np.radians(10)):
            out["horizontal"].append(res)
        elif cosang < np.sin(np.radians(10)):
            out["vertical"].append(res)
        pc = pc.select_by_index(idx, invert=True)
    return {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in out.items()}


def load_sim_truth(sim_dir) -> tuple[np.ndarray, np.ndarray]:
    """True T_world_lidar of a ``tripod simulate`` capture on the lidar time line:
    (t_ns (M,), T (M, 4, 4)). The simulator stamps its truth in host time; the lidar clock runs
    ``lidar_clock_offset_ns`` ahead (gt/clocks.json)."""
    import json
    from pathlib import Path

    from .outputs import read_tum

    d = Path(sim_dir)
    t, T = read_tum(d / "gt" / "trajectory.tum")
    clocks = json.loads((d / "gt" / "clocks.json").read_text())
    return t + int(clocks.get("lidar_clock_offset_ns", 0)), T


def true_time_offset_ns(sim_dir, recording) -> int:
    """The IMU time offset a processor should find for a ``tripod simulate`` capture, in the
    processor's terms: what to add to the IMU's de-jittered, clock-mapped stamps to put each
    sample at the lidar time of the instant it describes.

    That is minus the IMU's latency *plus* the receive delay of the lidar packets that the host
    → lidar clock map absorbs (a packet is stamped at its first firing and arrives after its
    last: ~1.4 ms for a VLP-16), so it is not simply −latency_ms."""
    import json
    from pathlib import Path

    from tripod_shared.timebase import same_hour_shift_ns

    from .placement import ImuOrientation, fit_clock_map

    d = Path(sim_dir)
    raw = np.loadtxt(d / "gt" / "imu_truth.csv", delimiter=",", dtype=np.int64, usecols=(0, 1))
    clocks = json.loads((d / "gt" / "clocks.json").read_text())
    true_lidar = raw[:, 1] + int(clocks["lidar_clock_offset_ns"])
    base = ImuOrientation(recording.imu, fit_clock_map(recording.lidar))._base_t
    n = min(len(base), len(true_lidar))
    shift = same_hour_shift_ns(int(true_lidar[0]), int(base[0]))
    return int(np.median(true_lidar[:n] + shift - base[:n]))


def same_hour(truth_t_ns: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    """Truth times moved by whole hours onto our time line.

    Lidar time carries only µs past the hour; its hour comes from GPRMC or the recording host's
    clock. A capture recorded by the daemon later (a replay) keeps every µs-past-the-hour but
    gets the replay's hour, so truth and result differ by a whole number of hours.
    """
    from tripod_shared.timebase import same_hour_shift_ns

    shift = same_hour_shift_ns(int(truth_t_ns[0]), int(t_ns[0])) if len(t_ns) else 0
    inside = truth_t_ns[0] <= t_ns[0] <= truth_t_ns[-1]
    return truth_t_ns if inside else truth_t_ns + shift


def evaluate_run(outdir, truth_t_ns: np.ndarray, truth_T: np.ndarray,
                 mesh_path=None) -> dict:
    """Accuracy of a finished run (its stations.tum, stations_odometry.tum, map.ply) against a
    true trajectory on the lidar time line (and the scene mesh, when given)."""
    from pathlib import Path

    from ..io import clouds as cloud_io
    from .outputs import read_tum

    out = Path(outdir)
    t, T_opt = read_tum(out / "stations.tum")
    _, T_odo = read_tum(out / "stations_odometry.tum")
    truth_t_ns = same_hour(truth_t_ns, t)
    T_true = interpolate_poses(truth_t_ns, truth_T, t)
    e_odo = pose_errors(T_odo, T_true)
    e_opt = pose_errors(T_opt, T_true)
    drift, path = odometry_drift(T_odo, T_true)
    r = {"stations": int(len(t)), "path_m": path,
         "ate_odometry_cm": e_odo.ate_m * 100, "ate_odometry_deg": e_odo.ate_deg,
         "ate_cm": e_opt.ate_m * 100, "ate_deg": e_opt.ate_deg,
         "max_err_cm": e_opt.max_m * 100, "max_err_deg": e_opt.max_deg,
         "odometry_drift_pct": drift}
    if mesh_path is not None:
        A = align_poses(T_opt, T_true)
        pts = cloud_io.xyz(cloud_io.read_ply(out / "map.ply"))
        d = map_to_mesh(pts, str(mesh_path), A)
        r["map_to_mesh_median_cm"] = float(np.median(d)) * 100
        r["map_to_mesh_p95_cm"] = float(np.percentile(d, 95)) * 100
    return r
