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
        _, idx = pc.segment_plane(distance_m, 3, 100)
        if len(idx) < min_inliers:
            break
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


# ---- a merged model of many recordings (tripod batch --merge) ----------------------------------
def evaluate_merge(merged_dir, recording_dirs: dict, sim_dirs: dict, *, true_overlap: float = 0.3,
                   false_overlap: float = 0.1, link_tol_m: float = 0.10,
                   link_tol_deg: float = 1.0) -> dict:
    """Accuracy of a merged model against the simulator's truth of every recording.

    ``recording_dirs`` / ``sim_dirs``: {recording name: its reconstruction folder / its
    ``tripod simulate`` folder}; all captures share the building frame.

    - station ATE over every station of the merged model (``stations.tum``), the merged frame
      aligned to the building frame once (:func:`align_poses`);
    - links between recordings: a station pair of two recordings is a *true link* when its true
      fragments overlap: the mean share of each fragment's points (20 cm voxels) within 20 cm of
      the other's, both placed by the truth, is at least ``true_overlap``. A kept link is
      *false* when that share is below ``false_overlap`` or its relative pose is off the truth by
      more than ``link_tol_m`` / ``link_tol_deg``; pairs in between are weak (neither needed
      nor false). Recall = true links kept / true links; precision = kept links not false /
      kept links;
    - per recording (``recordings``: {name: ...}): its stations' ATE in the merged model under
      the one alignment (which recording carries the error), the same stations aligned on
      their own (bent inside the model) and its own reconstruction's ATE aligned alone (its
      error inside the recording);
    - per recording pair (``pairs``: {"A|B": ...}): true links, links kept / true found /
      false / weak, and, where the merge's ``result.json`` gives the pair's hypothesis
      (``recording_pairs[].T_a_b``), its error against the truth [m] / [deg] (each recording's
      frame placed in the building frame by its own reconstruction aligned to the truth).
    """
    import csv
    from pathlib import Path

    from .merge import MergeConfig, _Coarse, load_recording
    from .outputs import read_tum

    merged = Path(merged_dir)
    truth = {n: load_sim_truth(d) for n, d in sim_dirs.items()}
    # stations of the merged model
    t, T = read_tum(merged / "stations.tum")
    with open(merged / "stations.csv") as fh:
        rows = list(csv.DictReader(fh))
    T_true = np.empty_like(T)
    for i, row in enumerate(rows):
        tt, TT = truth[row["recording"]]
        tt = same_hour(tt, t[i:i + 1])
        T_true[i] = interpolate_poses(tt, TT, t[i:i + 1])[0]
    e = pose_errors(T, T_true)
    A_all = align_poses(T, T_true)
    # true links: every cross-recording station pair, from the truth
    names = list(recording_dirs)
    recs = [load_recording(recording_dirs[n], n) for n in names]
    mc = MergeConfig()
    coarse = _Coarse(recs, mc.overlap_voxel_m)
    T_st = []
    for r in recs:
        tt, TT = truth[r.name]
        T_st.append(interpolate_poses(same_hour(tt, r.t_ns), TT, r.t_ns))
    key = {(r.name, r.index[k]): (ri, k) for ri, r in enumerate(recs) for k in range(len(r.t_ns))}
    true_pairs, share = set(), {}
    for A in range(len(recs)):
        for B in range(A + 1, len(recs)):
            for a in range(len(recs[A].t_ns)):
                for b in range(len(recs[B].t_ns)):
                    Tab = np.linalg.inv(T_st[A][a]) @ T_st[B][b]
                    if np.linalg.norm(Tab[:3, 3]) > mc.max_link_distance_m:
                        continue
                    ov = coarse.overlap((A, a), (B, b), Tab, mc.overlap_distance_m)
                    share[(A, a, B, b)] = ov
                    if ov >= true_overlap:
                        true_pairs.add((A, a, B, b))
    kept, false_links, found, false_set = 0, [], set(), set()
    with open(merged / "links.csv") as fh:
        for row in csv.DictReader(fh):
            if row["kept"] != "1":
                continue
            A, a = key[(row["recording_a"], int(row["station_a"]))]
            B, b = key[(row["recording_b"], int(row["station_b"]))]
            if A > B:
                A, a, B, b = B, b, A, a
            kept += 1
            found.add((A, a, B, b))
    # a kept link's pose error needs its measured T_a_b: the merged poses carry it (the graph
    # agrees with its kept links), so compare the merged relative pose with the truth
    pos = {(row["recording"], int(row["station_index"])): i for i, row in enumerate(rows)}
    for A, a, B, b in sorted(found):
        ov = share.get((A, a, B, b), 0.0)
        ia, ib = pos.get((names[A], recs[A].index[a])), pos.get((names[B], recs[B].index[b]))
        err_m = err_deg = float("nan")
        if ia is not None and ib is not None:
            E = np.linalg.inv(np.linalg.inv(T_true[ia]) @ T_true[ib]) @ (np.linalg.inv(T[ia])
                                                                          @ T[ib])
            err_m = float(np.linalg.norm(E[:3, 3]))
            err_deg = float(np.degrees(Rotation.from_matrix(E[:3, :3]).magnitude()))
        if ov < false_overlap or not (err_m <= link_tol_m and err_deg <= link_tol_deg):
            false_set.add((A, a, B, b))
            false_links.append({"a": f"{names[A]}#{recs[A].index[a]}",
                                "b": f"{names[B]}#{recs[B].index[b]}", "true_overlap": ov,
                                "err_m": err_m, "err_deg": err_deg})
    hit = len((true_pairs & found) - false_set)
    # per recording: which one carries the error
    rec_of = np.array([row["recording"] for row in rows])
    per_rec, T_world_rec = {}, {}
    for ri, r in enumerate(recs):
        m = rec_of == r.name
        alone = pose_errors(r.T, T_st[ri])
        A_r = align_poses(r.T, T_st[ri])
        T_world_rec[r.name] = A_r
        d = (np.linalg.norm((A_all @ T[m])[:, :3, 3] - T_true[m, :3, 3], axis=1) if m.any()
             else np.zeros(0))
        E = np.linalg.inv(T_true[m]) @ (A_all @ T[m])
        dr = np.degrees(Rotation.from_matrix(E[:, :3, :3]).magnitude()) if m.any() else d
        per_rec[r.name] = {
            "stations": int(len(r.t_ns)), "merged_stations": int(m.sum()),
            "ate_cm": float(100 * np.sqrt(np.mean(d**2))) if m.any() else float("nan"),
            "ate_deg": float(np.sqrt(np.mean(dr**2))) if m.any() else float("nan"),
            "max_err_cm": float(100 * d.max()) if m.any() else float("nan"),
            # its stations in the merged model aligned on their own (bent inside the model?)
            "own_ate_cm": (pose_errors(T[m], T_true[m]).ate_m * 100 if m.any()
                           else float("nan")),
            "alone_ate_cm": alone.ate_m * 100, "alone_ate_deg": alone.ate_deg}
    # per recording pair: links, and the hypothesis against the truth
    hyp = {}
    res_file = merged / "result.json"
    if res_file.is_file():
        import json

        for p in json.loads(res_file.read_text()).get("recording_pairs", []):
            hyp[(p["a"], p["b"])] = p
    per_pair = {}
    for A in range(len(recs)):
        for B in range(A + 1, len(recs)):
            ab = {q for q in true_pairs if q[0] == A and q[2] == B}
            fd = {q for q in found if q[0] == A and q[2] == B}
            fs = {q for q in false_set if q[0] == A and q[2] == B}
            row = {"true_links": len(ab), "kept": len(fd), "true_found": len(ab & fd - fs),
                   "false": len(fs), "weak": len(fd - ab - fs)}
            p = hyp.get((names[A], names[B]))
            if p is not None:
                row.update(accepted=p.get("accepted", ""), twin=p.get("twin", {}),
                           shortlisted=p.get("shortlisted", True), score=p.get("score"))
                if p.get("T_a_b") is not None:
                    H = np.asarray(p["T_a_b"], dtype=np.float64)
                    H_true = np.linalg.inv(T_world_rec[names[A]]) @ T_world_rec[names[B]]
                    E = np.linalg.inv(H_true) @ H
                    row.update(hyp_err_m=float(np.linalg.norm(E[:3, 3])),
                               hyp_err_deg=float(np.degrees(
                                   Rotation.from_matrix(E[:3, :3]).magnitude())))
            per_pair[f"{names[A]}|{names[B]}"] = row
    return {"stations": int(len(t)), "ate_cm": e.ate_m * 100, "ate_deg": e.ate_deg,
            "max_err_cm": e.max_m * 100, "max_err_deg": e.max_deg,
            "true_links": len(true_pairs), "true_links_found": hit,
            "links_kept": kept, "false_links": len(false_links),
            "weak_links_kept": len(found - true_pairs - false_set),
            "link_recall": hit / len(true_pairs) if true_pairs else 1.0,
            "link_precision": (kept - len(false_links)) / kept if kept else 1.0,
            "false_link_list": false_links, "recordings": per_rec, "pairs": per_pair}
