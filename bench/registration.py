# SPDX-License-Identifier: BSD-3-Clause
"""Registration benchmark: tripod vs small_gicp vs Open3D on real scans with truth and on
simulated (digital-twin) station pairs.

One run prints three tables:

1. per pair: rotation error [deg], translation error, CPU time on one thread [ms] (downsampling,
   normals/covariances, k-d tree and alignment all included, from raw points), its ratios to
   small_gicp's GICP and VGICP on the same pair in the same run, and wall time on 1 and 2
   threads with their ratio (thread scaling);
2. per tool and method: success rate, median errors, geometric-mean CPU ratios;
3. global registration on a symmetric room: flips with gravity (tripod) and without (Open3D).

Every tool gets the same settings where it allows them:

- voxel: the target's bounding-box diagonal / 100 (origin-aligned voxel grid everywhere);
- neighbours for normals/covariances: 20;
- one correspondence distance, 10 voxels; VGICP voxels of that edge (tripod's VGICP uses the
  stage distance as its voxel edge, small_gicp gets ``voxel_resolution`` = the same);
- at most 64 iterations; an update below 0.1 deg and 0.01 voxel stops tripod and small_gicp
  (small_gicp's defaults are 0.1 deg and 1 mm, scaled here with the cloud). Open3D stops on a
  relative fitness/RMSE change below 1e-6, its only criteria;
- tripod's default two-stage schedule (10 v, 3 v) is one extra row (``gicp 2-stage``): the
  peers' Python APIs take one distance.

Pairs: Stanford bunny bun045 -> bun000 (published poses), PCL bun0 -> bun4 (published 4x4),
PCL room_scan2 -> room_scan1 from the NDT tutorial's guess (reference good to ~2 deg / 10 cm
only, so success there is 2 deg / 10 cm), and three simulated VLP-16 station pairs
(``tripod_processor.sim``) from identity. Success elsewhere: rotation < 1 deg and translation
< 1 voxel.

    .venv/bin/python bench/registration.py            # full run (a few minutes on 2 cores)
    .venv/bin/python bench/registration.py --quick    # 1 repeat, fewer global trials
    .venv/bin/python bench/registration.py --threads  # thread scaling only (idle machine)
    .venv/bin/python bench/registration.py --idle     # thread scaling + single-thread ratios
Open3D's OpenMP thread count is fixed at import, so its rows run in child processes; without
Open3D installed its rows are left out (said in the output).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

NEIGHBORS = 20
MAX_ITERATIONS = 64
ROT_EPS = np.radians(0.1)  # small_gicp's default rotation threshold [rad]
TRANS_EPS_VOXELS = 0.01  # translation threshold [voxels] (small_gicp's 1 mm on a 0.1 m voxel)
TILTS = (-15, 0, 15)
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "registration"


# ---------------------------------------------------------------------------- pairs
class Pair:
    def __init__(self, name, src, tgt, G, init=None, ok_deg=1.0, ok_m=None, kind="real"):
        self.name, self.src, self.tgt, self.G, self.kind = name, src, tgt, G, kind
        self.init = np.eye(4) if init is None else init
        diag = float(np.linalg.norm(np.ptp(tgt, axis=0)))
        self.voxel = diag / 100
        self.dist = 10 * self.voxel
        self.trans_eps = TRANS_EPS_VOXELS * self.voxel
        self.ok_deg, self.ok_m = ok_deg, (ok_m if ok_m is not None else self.voxel)


def make_pairs(data_dir: Path) -> list[Pair]:
    from tripod_processor.io import clouds as cloud_io
    from tripod_processor.sim.scenes import make_scene
    from tripod_processor.sim.station_scan import box_room, pose, station_scan

    def xyz(p):
        return cloud_io.xyz(cloud_io.read_cloud(p)).astype(np.float32)

    pairs = []
    b = data_dir / "bunny"
    if b.is_dir():
        lines = (b / "bun_conf_poses_4x4.txt").read_text().splitlines()
        i = lines.index("bun045.ply")
        G = np.array([[float(v) for v in lines[i + 1 + k].split()] for k in range(4)])
        pairs.append(Pair("bunny 045->000", xyz(b / "bun045.ply"), xyz(b / "bun000.ply"), G))
    p = data_dir / "pcl"
    if p.is_dir():
        pairs.append(Pair("pcl bun0->bun4", xyz(p / "bun0.pcd"), xyz(p / "bun4.pcd"),
                          np.loadtxt(p / "bun0_to_bun4_groundtruth.txt", comments="#")))
        init = pose(np.degrees(0.6931), (1.79387, 0.720047, 0))  # the NDT tutorial's guess
        pairs.append(Pair("pcl room_scan2->1", xyz(p / "room_scan2.pcd"),
                          xyz(p / "room_scan1.pcd"),
                          np.loadtxt(p / "room_scan2_to_room_scan1_reference.txt", comments="#"),
                          init=init, ok_deg=2.0, ok_m=0.10))
    room = make_scene("room", 3)
    w, d = room.params["width_m"], room.params["depth_m"]
    T_t, T_s = pose(0, (w / 2 - 0.5, d / 2, 1.3)), pose(8, (w / 2 + 0.3, d / 2 + 0.4, 1.3))
    pairs.append(Pair("sim room+furniture", station_scan(room, T_s, TILTS, seed=2),
                      station_scan(room, T_t, TILTS, seed=1), np.linalg.inv(T_t) @ T_s,
                      kind="sim"))
    cor = make_scene("corridor", 1)
    c = cor.params["width_m"] / 2
    T_t, T_s = pose(0, (3.0, c, 1.3)), pose(0, (4.5, c, 1.3))  # 1.5 m along the axis
    pairs.append(Pair("sim L-corridor 1.5m", station_scan(cor, T_s, TILTS, seed=4),
                      station_scan(cor, T_t, TILTS, seed=3), np.linalg.inv(T_t) @ T_s,
                      kind="sim"))
    box = box_room()
    T_t, T_s = pose(0, (3.0, 2.0, 1.3)), pose(5, (3.6, 2.3, 1.3))
    pairs.append(Pair("sim symmetric room", station_scan(box, T_s, TILTS, seed=6),
                      station_scan(box, T_t, TILTS, seed=5), np.linalg.inv(T_t) @ T_s,
                      kind="sim"))
    return pairs


def errors(T, G):
    dR = T[:3, :3].T @ G[:3, :3]
    rot = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
    return rot, float(np.linalg.norm(T[:3, 3] - G[:3, 3]))


# ---------------------------------------------------------------------------- runners
def run_tripod(method, pair, threads):
    from tripod_processor import registration as reg

    schedule = [pair.dist]
    if method == "gicp 2-stage":
        method, schedule = "gicp", [10 * pair.voxel, 3 * pair.voxel]
    r = reg.register(pair.src, pair.tgt, method=method, init=pair.init, voxel_size=pair.voxel,
                     max_correspondence_distance=schedule, num_neighbors=NEIGHBORS,
                     max_iterations=MAX_ITERATIONS, rotation_eps=ROT_EPS,
                     translation_eps=pair.trans_eps, loss="huber" if method == "lm" else "none",
                     loss_scale=pair.voxel, num_threads=threads)
    return r.T_target_source


def run_small_gicp(method, pair, threads):
    import small_gicp

    tgt, tgt_tree = small_gicp.preprocess_points(pair.tgt.astype(np.float64), pair.voxel,
                                                 num_neighbors=NEIGHBORS, num_threads=threads)
    src, _ = small_gicp.preprocess_points(pair.src.astype(np.float64), pair.voxel,
                                          num_neighbors=NEIGHBORS, num_threads=threads)
    if method == "VGICP":
        vox = small_gicp.GaussianVoxelMap(pair.dist)
        vox.insert(tgt)
        r = small_gicp.align(vox, src, pair.init, max_correspondence_distance=pair.dist,
                             num_threads=threads, max_iterations=MAX_ITERATIONS,
                             rotation_epsilon=ROT_EPS, translation_epsilon=pair.trans_eps)
    else:
        r = small_gicp.align(tgt, src, tgt_tree, pair.init, registration_type=method,
                             max_correspondence_distance=pair.dist, num_threads=threads,
                             max_iterations=MAX_ITERATIONS, rotation_epsilon=ROT_EPS,
                             translation_epsilon=pair.trans_eps)
    return r.T_target_source


def run_open3d(method, pair, threads):
    import open3d as o3d

    def prep(p):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64)))
        pc = pc.voxel_down_sample(pair.voxel)
        if method == "plane":
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NEIGHBORS))
        elif method == "gicp":
            pc.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(NEIGHBORS))
        return pc

    reg = o3d.pipelines.registration
    est = {"icp": reg.TransformationEstimationPointToPoint(),
           "plane": reg.TransformationEstimationPointToPlane(),
           "gicp": reg.TransformationEstimationForGeneralizedICP()}[method]
    crit = reg.ICPConvergenceCriteria(1e-6, 1e-6, MAX_ITERATIONS)
    s, t = prep(pair.src), prep(pair.tgt)
    if method == "gicp":
        r = reg.registration_generalized_icp(s, t, pair.dist, pair.init, est, crit)
    else:
        r = reg.registration_icp(s, t, pair.dist, pair.init, est, crit)
    return np.asarray(r.transformation)


TOOLS = {
    "tripod": (run_tripod, ["gicp", "vgicp", "plane", "icp", "symmetric", "lm", "gicp 2-stage"]),
    "small_gicp": (run_small_gicp, ["GICP", "VGICP", "PLANE_ICP", "ICP"]),
    "open3d": (run_open3d, ["icp", "plane", "gicp"]),
}


def timed(fn, method, pair, threads):
    """(T, CPU seconds, wall seconds) of one run."""
    c0, w0 = time.process_time(), time.perf_counter()
    T = fn(method, pair, threads)
    return T, time.process_time() - c0, time.perf_counter() - w0


def local_rows(tools, pairs, repeats, threads_list=(1, 2)):
    """Best of `repeats` per (pair, tool, method), runs interleaved across tools and methods so
    that the load of a shared machine falls on all of them alike."""
    rows = []
    for tool in tools:  # untimed warm-up: imports, thread pools, first allocations
        fn, methods = TOOLS[tool]
        for threads in threads_list:
            fn(methods[0], pairs[0], threads)
    for pair in pairs:
        best = {}
        for _ in range(repeats):
            for tool in tools:
                fn, methods = TOOLS[tool]
                for m in methods:
                    b = best.setdefault((tool, m), {"T": None, "cpu1": np.inf, "wall1": np.inf,
                                                    "wall2": np.inf})
                    for threads in threads_list:
                        T, cpu, wall = timed(fn, m, pair, threads)
                        if b["T"] is None or threads == 1:
                            b["T"] = T
                        if threads == 1:
                            b["cpu1"], b["wall1"] = min(b["cpu1"], cpu), min(b["wall1"], wall)
                        else:
                            b["wall2"] = min(b["wall2"], wall)
        for (tool, m), b in best.items():
            rot, tr = errors(b["T"], pair.G)
            rows.append({"pair": pair.name, "tool": tool, "method": m, "rot_deg": rot,
                         "trans_m": tr, "ok": bool(rot < pair.ok_deg and tr < pair.ok_m),
                         "cpu1_ms": b["cpu1"] * 1e3, "wall1_ms": b["wall1"] * 1e3,
                         "wall2_ms": b["wall2"] * 1e3})
    return rows


def open3d_rows(repeats, data_dir):
    """Open3D in child processes: OMP_NUM_THREADS must be set before it is imported."""
    out = {}
    for threads in (1, 2):
        env = dict(os.environ, OMP_NUM_THREADS=str(threads))
        res = subprocess.run([sys.executable, __file__, "--o3d-worker", str(threads),
                              "--repeats", str(repeats), "--data", str(data_dir)], env=env,
                             capture_output=True, text=True, check=True)
        out[threads] = json.loads(res.stdout.strip().splitlines()[-1])
    rows = out[1]
    for r, r2 in zip(rows, out[2]):
        r["wall2_ms"] = r2["wall2_ms"]
    return rows


# ---------------------------------------------------------------------------- global
def global_trials(n_tripod, n_open3d, seed=7):
    from tripod_processor import registration as reg
    from tripod_processor.sim.station_scan import box_room, pose, station_scan

    box = box_room()
    T_t = pose(0, (3.0, 2.0, 1.3))
    tgt = station_scan(box, T_t, TILTS, azimuth_step_deg=0.4, seed=5)
    rng = np.random.default_rng(seed)
    trials = []
    for k in range(max(n_tripod, n_open3d)):
        T_s = pose(rng.uniform(-180, 180), (rng.uniform(2, 5), rng.uniform(1.5, 3), 1.3))
        trials.append((station_scan(box, T_s, TILTS, azimuth_step_deg=0.4, seed=100 + k),
                       np.linalg.inv(T_t) @ T_s))

    def tilt_deg(T, G):  # angle between the estimated and the true "up" of the source
        u, g = T[:3, :3] @ [0, 0, 1.0], G[:3, :3] @ [0, 0, 1.0]
        return float(np.degrees(np.arccos(np.clip(u @ g, -1, 1))))

    def score(stats, T, G):
        stats["flips"] += tilt_deg(T, G) > 10
        stats["wrong"] += errors(T, G)[0] > 5
        stats["twin"] += errors(T, G @ pose(180.0))[0] < 5

    res = {}
    v = 0.15
    stats = {"flips": 0, "wrong": 0, "twin": 0, "n": n_tripod, "ms": []}
    for k, (src, G) in enumerate(trials[:n_tripod]):
        t0 = time.perf_counter()
        r = reg.register_global(src, tgt, voxel_size=v, gravity_aligned=True, seed=k)
        stats["ms"].append((time.perf_counter() - t0) * 1e3)
        score(stats, r.T_target_source, G)
    res["tripod FPFH+RANSAC, gravity"] = stats
    stats = {"flips": 0, "wrong": 0, "twin": 0, "n": n_tripod, "ms": []}
    for k, (src, G) in enumerate(trials[:n_tripod]):
        imu = pose(rng.normal(0, 5.0))[:3, :3] @ G[:3, :3]  # IMU relative yaw, 5 deg sigma
        t0 = time.perf_counter()
        r = reg.register_global(src, tgt, voxel_size=v, gravity_aligned=True, seed=k,
                                rotation_prior=imu, rotation_tolerance=np.radians(30))
        stats["ms"].append((time.perf_counter() - t0) * 1e3)
        score(stats, r.T_target_source, G)
    res["tripod FPFH+RANSAC, gravity + IMU yaw (5 deg sigma, 30 deg gate)"] = stats
    try:
        import open3d as o3d
    except ImportError:
        return res
    stats = {"flips": 0, "wrong": 0, "twin": 0, "n": n_open3d, "ms": []}

    def prep(p):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64)))
        pc = pc.voxel_down_sample(v)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
        f = o3d.pipelines.registration.compute_fpfh_feature(
            pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
        return pc, f

    pt, ft = prep(tgt)
    for k, (src, G) in enumerate(trials[:n_open3d]):
        t0 = time.perf_counter()
        ps, fs = prep(src)
        reg_ = o3d.pipelines.registration
        r = reg_.registration_ransac_based_on_feature_matching(
            ps, pt, fs, ft, True, 1.5 * v, reg_.TransformationEstimationPointToPoint(False), 3,
            [reg_.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             reg_.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
            reg_.RANSACConvergenceCriteria(100000, 0.999))
        stats["ms"].append((time.perf_counter() - t0) * 1e3)
        score(stats, np.asarray(r.transformation), G)
    res["open3d FPFH+RANSAC (no gravity)"] = stats
    return res


# ---------------------------------------------------------------------------- threads
def thread_scaling(pairs, repeats, threads_list=(1, 2)):
    """Wall and CPU time of tripod GICP's two stages on the pairs with >= 50k raw points:
    preparing both clouds from the raw points (downsampling, k-d tree, 20-NN normals and
    covariances) and the registration of the prepared clouds, i.e. what a call of the API on
    two raw clouds costs, best of `repeats` per thread count. The thread counts take turns
    (1, 2, 1, 2, ...) after one untimed run each, so that both see the same state of the
    machine (a background job starting halfway moves both alike), and the repeats go round
    the pairs."""
    from tripod_processor import registration as reg

    def once(pair, threads):
        c0, w0 = time.process_time(), time.perf_counter()
        s = reg.prepare(pair.src, pair.voxel, NEIGHBORS, num_threads=threads)
        t = reg.prepare(pair.tgt, pair.voxel, NEIGHBORS, num_threads=threads)
        c1, w1 = time.process_time(), time.perf_counter()
        r = reg.register(s, t, method="gicp", init=pair.init,
                         max_correspondence_distance=[pair.dist],
                         max_iterations=MAX_ITERATIONS, rotation_eps=ROT_EPS,
                         translation_eps=pair.trans_eps, num_threads=threads)
        c2, w2 = time.process_time(), time.perf_counter()
        return r, {"prepare": (w1 - w0, c1 - c0), "register": (w2 - w1, c2 - c1)}

    big = [p for p in pairs if len(p.src) + len(p.tgt) >= 50_000]
    best = {(p.name, th): {"prepare": [np.inf, np.inf], "register": [np.inf, np.inf]}
            for p in big for th in threads_list}
    iterations = {}
    for pair in big:
        for threads in threads_list:  # untimed: the worker pool is started once per process
            once(pair, threads)
    # The repeats go round the pairs (pair A 1, 2 threads, pair B 1, 2, ..., then again), so
    # one pair's repeats are spread over the whole run: a stall of the host's second CPU
    # lasting a second or so cannot hit every repeat of one pair.
    for _ in range(repeats):
        for pair in big:
            for threads in threads_list:
                r, times = once(pair, threads)
                iterations[pair.name, threads] = r.iterations
                for k, (w, c) in times.items():
                    b = best[pair.name, threads][k]
                    best[pair.name, threads][k] = [min(b[0], w), min(b[1], c)]
    rows = []
    for pair in big:
        for threads in threads_list:
            rows.append({"pair": pair.name, "points": len(pair.src) + len(pair.tgt),
                         "threads": threads, "iterations": iterations[pair.name, threads], **{
                             f"{k}_{m}": v * 1e3
                             for k, (w, c) in best[pair.name, threads].items()
                             for m, v in (("wall_ms", w), ("cpu_ms", c))}})
    return rows


def print_thread_table(con, rows, load):
    from rich.table import Table

    t = Table(title="tripod GICP thread scaling, pairs >= 50k raw points: wall and CPU time [ms], "
                    "best of the repeats; x = speed-up, wall 1 thread / wall n threads")
    for col in ("pair", "raw pts", "thr", "prepare wall", "prepare CPU", "register wall",
                "register CPU", "x prepare", "x register", "x total"):
        t.add_column(col, justify="left" if col == "pair" else "right", no_wrap=True)
    one = {r["pair"]: r for r in rows if r["threads"] == 1}
    for r in rows:
        b = one[r["pair"]]
        sp = b["prepare_wall_ms"] / r["prepare_wall_ms"]
        sr = b["register_wall_ms"] / r["register_wall_ms"]
        st = ((b["prepare_wall_ms"] + b["register_wall_ms"])
              / (r["prepare_wall_ms"] + r["register_wall_ms"]))
        t.add_row(r["pair"], str(r["points"]), str(r["threads"]), f"{r['prepare_wall_ms']:.1f}",
                  f"{r['prepare_cpu_ms']:.1f}", f"{r['register_wall_ms']:.1f}",
                  f"{r['register_cpu_ms']:.1f}", f"{sp:.2f}", f"{sr:.2f}", f"{st:.2f}")
    con.print(t)
    con.print(f"load average (1 min) at start/end: {load[0]:.2f}/{load[1]:.2f} on "
              f"{os.cpu_count()} cores (the figure needs an idle machine: load < 0.5); OpenMP "
              f"wait: OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}, "
              f"GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT', 'unset')} (set by "
              "tripod_processor at import unless given; the registration path's worker pool "
              "reads the same)")


# ---------------------------------------------------------------------------- tables
def _geo(x):
    x = np.asarray([v for v in x if np.isfinite(v) and v > 0])
    return float(np.exp(np.log(x).mean())) if len(x) else float("nan")


def print_tables(con, rows, pairs, load):
    from rich.table import Table

    ref = {(r["pair"], r["method"]): r for r in rows if r["tool"] == "small_gicp"}
    by_name = {p.name: p for p in pairs}
    t = Table(title="Local registration per pair: CPU ratios to small_gicp GICP (/G) and VGICP "
                    "(/V) on the same pair, same run; scaling = wall 1 thr / wall 2 thr")
    for col in ("pair", "tool", "method", "rot err (deg)", "trans err (mm)", "ok",
                "CPU 1 thr (ms)", "/G", "/V", "wall 2 thr (ms)", "scaling"):
        t.add_column(col, justify="left" if col in ("pair", "tool", "method") else "right")
    for r in rows:
        g, v = ref[(r["pair"], "GICP")], ref[(r["pair"], "VGICP")]
        r["ratio_G"] = r["cpu1_ms"] / g["cpu1_ms"]
        r["ratio_V"] = r["cpu1_ms"] / v["cpu1_ms"]
        r["scaling"] = r["wall1_ms"] / r["wall2_ms"]
        t.add_row(r["pair"], r["tool"], r["method"], f"{r['rot_deg']:.3f}",
                  f"{r['trans_m'] * 1e3:.2f}", "yes" if r["ok"] else "NO",
                  f"{r['cpu1_ms']:.1f}", f"{r['ratio_G']:.2f}", f"{r['ratio_V']:.2f}",
                  f"{r['wall2_ms']:.1f}", f"{r['scaling']:.2f}")
    con.print(t)
    t = Table(title="Summary over the pairs (geometric-mean CPU ratios; scaling on pairs with "
                    ">= 50k raw points)")
    for col in ("tool", "method", "success", "median rot (deg)", "median trans (voxels)",
                "CPU / sG GICP", "CPU / sG VGICP", "scaling 2 thr"):
        t.add_column(col, justify="left" if col in ("tool", "method") else "right")
    keys = []
    for r in rows:
        if (r["tool"], r["method"]) not in keys:
            keys.append((r["tool"], r["method"]))
    for tool, m in keys:
        rs = [r for r in rows if r["tool"] == tool and r["method"] == m]
        big = [r["scaling"] for r in rs
               if len(by_name[r["pair"]].src) + len(by_name[r["pair"]].tgt) >= 50_000]
        t.add_row(tool, m, f"{sum(r['ok'] for r in rs)}/{len(rs)}",
                  f"{np.median([r['rot_deg'] for r in rs]):.3f}",
                  f"{np.median([r['trans_m'] / by_name[r['pair']].voxel for r in rs]):.2f}",
                  f"{_geo([r['ratio_G'] for r in rs]):.2f}",
                  f"{_geo([r['ratio_V'] for r in rs]):.2f}",
                  f"{_geo(big):.2f}" if big else "-")
    con.print(t)
    con.print("pairs (raw source/target points, voxel [m], correspondence distance [m]): "
              + "; ".join(f"{p.name} {len(p.src)}/{len(p.tgt)} v={p.voxel:.4f} d={p.dist:.3f}"
                          for p in pairs))
    con.print(f"load average (1 min) at start/end of the local runs: {load[0]:.1f}/{load[1]:.1f} "
              f"on {os.cpu_count()} cores")


# ---------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 repeat, 10 global trials")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--data", type=Path, default=DATA, help="the shared registration data")
    ap.add_argument("--no-global", action="store_true", help="skip the global table")
    ap.add_argument("--threads", action="store_true",
                    help="only the thread-scaling table of tripod GICP (5 repeats)")
    ap.add_argument("--idle", action="store_true",
                    help="the figures that need an idle machine, in one run (about a minute "
                         "idle): the thread-scaling table (15 repeats), then the per-pair and "
                         "summary tables of tripod and small_gicp (CPU ratios, 5 repeats; no "
                         "Open3D, no global table)")
    ap.add_argument("--o3d-worker", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    pairs = make_pairs(args.data.resolve())
    if args.o3d_worker:
        rows = local_rows(["open3d"], pairs, repeats, threads_list=(args.o3d_worker,))
        for r in rows:  # this process has one thread count only
            if args.o3d_worker == 2:
                r["cpu1_ms"] = r["wall1_ms"] = float("nan")
            else:
                r["wall2_ms"] = float("nan")
        print(json.dumps(rows))
        return 0

    from rich.console import Console

    con = Console(width=150)
    load0 = os.getloadavg()[0]
    if args.threads or args.idle:
        rows = thread_scaling(pairs, args.repeats or (15 if args.idle else 5))
        print_thread_table(con, rows, (load0, os.getloadavg()[0]))
        if args.threads:
            return 0
        load0 = os.getloadavg()[0]
        rows = local_rows(["tripod", "small_gicp"], pairs, 5)
        print_tables(con, rows, pairs, (load0, os.getloadavg()[0]))
        return 0
    rows = local_rows(["tripod", "small_gicp"], pairs, repeats)
    try:
        import open3d  # noqa: F401

        o3d_rows = open3d_rows(repeats, args.data.resolve())
        for r in o3d_rows:
            r["wall1_ms"] = r["cpu1_ms"]  # one OpenMP thread: wall ~ CPU
        rows += o3d_rows
    except ImportError:
        con.print("open3d is not installed: its rows are left out")
    print_tables(con, rows, pairs, (load0, os.getloadavg()[0]))
    if args.no_global:
        return 0
    from rich.table import Table

    g = global_trials(10 if args.quick else 50, 5)
    t = Table(title="Global registration, symmetric empty room (7 x 4.5 x 2.8 m), random yaw and "
                    "position, voxel 0.15 m")
    for col in ("method", "trials", "flipped (tilt > 10 deg)", "wrong (rot err > 5 deg)",
                "of which the 180 deg twin", "median wall (ms), all cores"):
        t.add_column(col, justify="left" if col == "method" else "right")
    for k, s in g.items():
        t.add_row(k, str(s["n"]), str(s["flips"]), str(s["wrong"]), str(s["twin"]),
                  f"{np.median(s['ms']):.0f}")
    con.print(t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
