# SPDX-License-Identifier: BSD-3-Clause
"""The run's report: ``report.md`` with PNGs (matplotlib, Agg).

Pictures: the top-down map with the trajectory and stations; odometry against optimised station
poses; the station segmentation over time; the thesis' error analysis — every fragment's
horizontal and vertical plane-fit residuals as violin plots with the median and the 2.5 % and
97.5 % quantiles marked.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .config import ReconstructConfig
from .evaluation import plane_fit_errors


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_topdown(path: Path, map_xyz: np.ndarray, T_st: np.ndarray, traj_T: np.ndarray,
                 disconnected: list[int] | None = None) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    if len(map_xyz):
        sel = map_xyz[np.random.default_rng(0).choice(len(map_xyz), min(len(map_xyz), 60_000),
                                                     replace=False)]
        z = sel[:, 2]
        lo, hi = np.percentile(z, [5, 95])
        keep = (z > lo + 0.1 * (hi - lo)) & (z < hi - 0.1 * (hi - lo))  # walls, not floor/ceiling
        ax.scatter(sel[keep, 0], sel[keep, 1], s=0.2, c="0.35", lw=0, rasterized=True)
    if len(traj_T):
        ax.plot(traj_T[:, 0, 3], traj_T[:, 1, 3], "-", c="tab:blue", lw=0.8, label="trajectory")
    ax.plot(T_st[:, 0, 3], T_st[:, 1, 3], "o", c="tab:red", ms=5, label="stations")
    for k, T in enumerate(T_st):
        ax.annotate(str(k), T[:2, 3], textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("map (top-down, walls) with trajectory and stations")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_odometry_vs_optimized(path: Path, T_odom: np.ndarray, T_opt: np.ndarray) -> None:
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2), dpi=110)
    ax[0].plot(T_odom[:, 0, 3], T_odom[:, 1, 3], "o--", c="tab:orange", ms=4, label="odometry")
    ax[0].plot(T_opt[:, 0, 3], T_opt[:, 1, 3], "o-", c="tab:blue", ms=4, label="pose graph")
    ax[0].set_aspect("equal")
    ax[0].set_xlabel("x [m]")
    ax[0].set_ylabel("y [m]")
    ax[0].legend(fontsize=8)
    ax[0].set_title("station positions")
    d = np.linalg.norm(T_odom[:, :3, 3] - T_opt[:, :3, 3], axis=1) * 100
    ax[1].bar(np.arange(len(d)), d, color="tab:purple")
    ax[1].set_xlabel("station")
    ax[1].set_ylabel("|odometry − optimised| [cm]")
    ax[1].set_title("correction by loop closures")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_segmentation(path: Path, t_ns: np.ndarray, motion: np.ndarray, still: np.ndarray,
                      spans: list[tuple[int, int]], threshold: float) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 2.8), dpi=110)
    t0 = t_ns[0] if len(t_ns) else 0
    ts = (t_ns - t0) * 1e-9
    m = np.where(np.isfinite(motion), motion, np.nan)
    ax.plot(ts, m, "-", c="0.3", lw=0.8, label="pivot shift")
    ax.axhline(threshold, c="tab:red", lw=0.8, ls="--", label="still threshold")
    for a, b in spans:
        ax.axvspan((a - t0) * 1e-9, (b - t0) * 1e-9, color="tab:green", alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("pivot shift in 0.5 s [m]")
    ax.set_title("station segmentation (green: stations)")
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_plane_violins(path: Path, errors: list[dict[str, np.ndarray]]) -> dict:
    """Violin plots of horizontal and vertical plane-fit residuals per fragment [cm]; returns the
    per-fragment statistics (median, 2.5 %, 97.5 % [m])."""
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(max(6, 0.6 * len(errors) + 2), 6.5), dpi=110,
                             sharex=True)
    stats = {"horizontal": [], "vertical": []}
    for ax, kind in zip(axes, ("horizontal", "vertical")):
        data, pos = [], []
        for k, e in enumerate(errors):
            r = e[kind]
            if len(r) >= 10:
                # the violin's shape from a sample; the statistics from every residual
                shape = r if len(r) <= 5000 else np.random.default_rng(k).choice(r, 5000)
                data.append(shape * 100)
                pos.append(k)
                stats[kind].append({"fragment": k, "n": int(len(r)),
                                    "median": float(np.median(r)),
                                    "p2_5": float(np.percentile(r, 2.5)),
                                    "p97_5": float(np.percentile(r, 97.5)),
                                    "rms": float(np.sqrt(np.mean(r**2)))})
        if data:
            parts = ax.violinplot(data, positions=pos, showextrema=False, widths=0.8)
            for b in parts["bodies"]:
                b.set_facecolor("tab:blue" if kind == "horizontal" else "tab:green")
                b.set_alpha(0.5)
            for p, st in zip(pos, stats[kind]):
                q = np.array([st["p2_5"], st["median"], st["p97_5"]]) * 100
                ax.hlines(q[1], p - 0.35, p + 0.35, colors="k", lw=1.4)
                ax.hlines([q[0], q[2]], p - 0.25, p + 0.25, colors="tab:red", lw=1.0)
        ax.axhline(0, c="0.6", lw=0.6)
        ax.set_ylabel(f"{kind} plane residual [cm]")
    axes[0].set_title("fragment plane-fit errors (black: median; red: 2.5 % and 97.5 %)")
    axes[-1].set_xlabel("fragment (station)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return stats


def write_report(res, cfg: ReconstructConfig, s: dict) -> Path:
    """Write ``report.md`` and its PNGs into the run's output folder; return the report path.

    ``res`` is the run's ``pipeline.ReconstructResult``, ``s`` its ``pipeline.summary`` (passed
    in, so that this module does not import the pipeline that calls it)."""
    out = res.outdir
    slam = res.slam
    main = [k for k in range(len(res.fragments)) if slam.component[k] == 0]
    from ..io import clouds as cloud_io
    from .outputs import read_tum

    map_xyz = cloud_io.xyz(cloud_io.read_ply(out / "map.ply"))
    _, traj_T = read_tum(out / "trajectory.tum")
    plot_topdown(out / "report_topdown.png", map_xyz, slam.T_optimized[main], traj_T,
                 slam.disconnected)
    plot_odometry_vs_optimized(out / "report_odometry.png", slam.T_odometry[main],
                               slam.T_optimized[main])
    seg = res.segmentation
    plot_segmentation(out / "report_stations.png", seg.t_ns, seg.motion_m, seg.still,
                      [(s.start_ns, s.end_ns) for s in seg.stations], cfg.stations.still_threshold)
    # plane fits on a random sample of each fragment: the residuals keep their statistics, the
    # RANSAC gets far cheaper
    rng = np.random.default_rng(0)

    def sample(p, n=15_000):
        return p if len(p) <= n else p[rng.choice(len(p), n, replace=False)]

    errors = [plane_fit_errors(sample(f.points), f.up_in_lidar, min_inliers=60, seed=k)
              for k, f in enumerate(res.fragments)]
    stats = plot_plane_violins(out / "report_planes.png", errors)

    def med(kind):
        v = [x["median"] for x in stats[kind]]
        sp = [x["p97_5"] - x["p2_5"] for x in stats[kind]]
        return (f"{np.median(np.abs(v)) * 1000:.2f} mm median offset, "
                f"{np.median(sp) * 100:.2f} cm median 95 % spread" if v else "no planes found")

    lines = [
        "# tripod reconstruction report", "",
        f"Recording `{s['recording']}`: {s['recording_s']:.1f} s, {s['lidar_packets']} lidar "
        f"packets, {s['imu_samples']} IMU samples, {s['marks']} station marks; hour from "
        f"{s['hour_source']}.", "",
        "| quantity | value |", "|---|---|",
        f"| stations | {s['stations']} ({len(slam.disconnected)} disconnected) |",
        f"| odometry edges (rejected) / loop edges (rejected) | {s['odometry_edges']} "
        f"({s['odometry_edges_rejected']}) / {s['loop_edges']} ({s['loop_edges_rejected']}) |",
        f"| loop candidates | {s['loop_candidates']} |",
        f"| IMU time offset | {s['imu_time_offset_ms']:.2f} ms |",
        f"| host − lidar clock | {s['host_minus_lidar_ms']:.3f} ms |",
        f"| extrinsic | q_imu_lidar {np.round(s['extrinsic']['q_imu_lidar'], 5).tolist()}, "
        f"lever arm {np.round(s['extrinsic']['lever_arm_m'], 4).tolist()} m "
        f"({s['extrinsic']['source']}) |",
        f"| map points | {s['map_points']} |",
        f"| processing | {s['processing_s']:.1f} s wall, {s['processing_cpu_s']:.1f} s CPU "
        f"({s['processing_s'] / max(s['recording_s'], 1e-9):.3f} of the recording time) |",
        f"| horizontal plane fit | {med('horizontal')} |",
        f"| vertical plane fit | {med('vertical')} |", "",
        "## Map and trajectory", "", "![top-down](report_topdown.png)", "",
        "## Odometry and pose graph", "", "![odometry](report_odometry.png)", "",
        "| edge | kind | fitness | inlier RMSE [cm] | chi2 | kept |", "|---|---|---|---|---|---|",
    ]
    g = slam.graph_result
    gi = 0
    index = {k: m for m, k in enumerate(main)}
    for e in slam.edges:
        if e.i in index and e.j in index and g is not None:
            chi, kept = g.edge_chi2[gi], g.edge_inlier[gi]
            gi += 1
        else:
            chi, kept = float("nan"), False
        lines.append(f"| {e.i}→{e.j} | {e.kind} | {e.fitness:.3f} | {e.rmse * 100:.2f} | "
                     f"{chi:.1f} | {'yes' if kept else 'no'} |")
    lines += ["", "## Stations", "", "![stations](report_stations.png)", "",
              "| station | start [s] | duration [s] | label |", "|---|---|---|---|"]
    t0 = res.recording.lidar.lidar_ns[0]
    for f in res.fragments:
        st = f.station
        lines.append(f"| {st.index} | {(st.start_ns - t0) * 1e-9:.2f} | {st.duration_s:.2f} | "
                     f"{st.label} |")
    lines += ["", "## Fragment plane-fit errors", "",
              "Residuals of the large planes (RANSAC, then least squares) of every fragment: "
              "floor and ceiling (horizontal) and walls (vertical). They measure how crisp the "
              "IMU placement makes a fragment: range noise, de-skew and calibration errors all "
              "widen them.", "", "![planes](report_planes.png)", ""]
    if s["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in s["notes"]] + [""]
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    from .outputs import write_json

    write_json(out / "plane_errors.json", stats)
    return path
