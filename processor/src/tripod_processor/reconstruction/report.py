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


def plot_station_timeline(path: Path, seg, t0_ns: int, threshold_m: float, tilt_deg: float
                          ) -> None:
    """The station timeline: the lidar's pivot shift and the IMU's swing off the pan axis over
    time with their thresholds, and a band of still windows, stations (numbered), still periods
    too short for a station, and the operator's marks."""
    plt = _plt()
    fig, ax = plt.subplots(3, 1, figsize=(11, 5.2), dpi=110, sharex=True,
                           gridspec_kw={"height_ratios": [2, 1.3, 0.9]})
    ts = (seg.t_ns - t0_ns) * 1e-9
    m = np.where(np.isfinite(seg.motion_m), seg.motion_m, np.nan)
    ax[0].plot(ts, np.maximum(m, 1e-4), "-", c="0.3", lw=0.8, label="pivot shift (lidar)")
    ax[0].axhline(threshold_m, c="tab:red", lw=0.8, ls="--", label="still threshold")
    ax[0].set_yscale("log")
    ax[0].set_ylabel("pivot shift\nin 0.5 s [m]")
    ax[0].legend(fontsize=7, loc="upper right")
    if seg.tilt_deg is not None:
        ax[1].plot(ts, np.maximum(seg.tilt_deg, 1e-3), "-", c="tab:purple", lw=0.8,
                   label="swing off the pan axis (IMU)")
        ax[1].axhline(tilt_deg, c="tab:red", lw=0.8, ls="--")
        ax[1].set_yscale("log")
        ax[1].legend(fontsize=7, loc="upper right")
    ax[1].set_ylabel("swing\nin 0.5 s [°]")
    b = ax[2]
    still = np.asarray(seg.still, dtype=bool)
    dt = float(ts[1] - ts[0]) if len(ts) > 1 else 0.5
    for k in np.flatnonzero(still):
        b.axvspan(ts[k], ts[k] + dt, ymin=0.0, ymax=0.3, color="0.75", lw=0)
    for st in seg.stations:
        a, e = (st.start_ns - t0_ns) * 1e-9, (st.end_ns - t0_ns) * 1e-9
        b.axvspan(a, e, ymin=0.35, ymax=0.95, color="tab:green", alpha=0.6, lw=0)
        b.text(0.5 * (a + e), 0.65, str(st.index), ha="center", va="center", fontsize=7)
        for x in (ax[0], ax[1]):
            x.axvspan(a, e, color="tab:green", alpha=0.12, lw=0)
    for a_ns, e_ns in getattr(seg, "short", []):
        b.axvspan((a_ns - t0_ns) * 1e-9, (e_ns - t0_ns) * 1e-9, ymin=0.35, ymax=0.95,
                  color="tab:orange", alpha=0.7, lw=0)
    for t_mark, label in getattr(seg, "marks", []):
        x = (t_mark - t0_ns) * 1e-9
        for a_ in ax:
            a_.axvline(x, c="tab:blue", lw=0.8)
        b.text(x, 1.0, f" {label}", fontsize=6, va="bottom", color="tab:blue", rotation=30)
    b.set_yticks([])
    b.set_ylim(0, 1)
    b.set_xlabel("time [s]")
    b.set_ylabel("still /\nstations", fontsize=8)
    ax[0].set_title("station timeline (grey: still windows; green: stations; orange: still but "
                    "too short; blue: marks)", fontsize=9)
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


def calibration_section(cal: dict) -> list[str]:
    """Markdown lines of the report's calibration section (from the run's calibration.json)."""
    est = cal.get("estimate") or {}
    src = cal.get("source", {})
    obs = est.get("observable", {})

    def seen(key):
        if key not in obs:
            return "—"
        return "well observed" if obs[key] else "**poorly observable**"

    lines = ["## Calibration", "",
             "Values the run used (`calibration.json`; it loads back with `--calibration`). "
             "Estimated from the data when the config leaves them out: the stations' own "
             "surfaces, seen at different moments of each pan, must coincide "
             "(see the README's reconstruction method).", "",
             "| quantity | value | 1σ | source | observability |", "|---|---|---|---|---|"]
    lev = np.asarray(cal.get("lever_arm_m", [0, 0, 0]))
    ls = est.get("lever_arm_sigma_m")
    lines.append(f"| lever arm (pivot → lidar, IMU frame) | {np.round(lev * 100, 2).tolist()} cm "
                 f"| {np.round(np.asarray(ls) * 1000, 2).tolist() if ls else '—'} mm (across "
                 f"the pan axis) | {src.get('lever_arm_m', '')} | {seen('lever_arm')} |")
    if est:
        lines.append(f"| lever arm across the pan axis | "
                     f"{est['lever_arm_across_axis_m'] * 100:.2f} cm | | | |")
        lines.append("| lever arm along the pan axis | kept at the prior | | | unobservable "
                     "(it moves a whole station alike; changes nothing) |")
    ts = est.get("imu_time_offset_sigma_ms")
    lines.append(f"| IMU time offset | {cal.get('imu_time_offset_s', 0.0) * 1e3:.2f} ms | "
                 f"{f'{ts:.2f} ms' if ts is not None and np.isfinite(ts) else '—'} | "
                 f"{src.get('imu_time_offset_s', '')} | {seen('time_offset')} |")
    rs = est.get("mount_rotation_sigma_deg")
    lines.append(f"| mount rotation q_imu_lidar (w, x, y, z) | "
                 f"{np.round(cal.get('q_imu_lidar', [1, 0, 0, 0]), 5).tolist()} | "
                 f"{f'{rs:.3f}° (tilts)' if rs is not None and np.isfinite(rs) else '—'} | "
                 f"{src.get('q_imu_lidar', '')} | {seen('mount_rotation')}; the turn about "
                 "the pan axis is unobservable (turns a whole station) |")
    turns = est.get("imu_time_offset_turns") if est else None
    if turns:
        # how the offset was seen: sweeps registered across the head's rate changes, at the
        # stations and while the tripod was carried between them
        lines += ["", f"IMU time offset from {est.get('imu_time_offset_method', 'the turns')}: "
                      f"{turns['pairs']} pairs of sweeps registered against each other "
                      f"({turns.get('carry_pairs', 0)} while the tripod was carried), their "
                      f"rotation rates {turns['rate_change_deg_s']:.1f}°/s apart (RMS); the "
                      f"turns alone {turns['imu_time_offset_ms']:.2f} ± "
                      f"{turns['sigma_ms']:.2f} ms."]
    if est:
        lines += ["", f"Pan axis in the IMU frame {np.round(est['pan_axis_imu'], 4).tolist()}; "
                      f"{est['pairs']} point-to-plane residuals on stations {est['stations']}, "
                      f"robust RMS {est['residual_m'] * 100:.2f} cm."]
    return lines


def report_figures(res, cfg: ReconstructConfig, early: list | None = None) -> dict:
    """The report's pictures that need only the fragments and the poses (odometry, station
    timeline, plane-fit violins), and the plane-fit statistics: the pipeline draws them while
    it writes the outputs (another thread; pyplot is not used elsewhere meanwhile). ``early``:
    what :func:`early_figures` returned for this run (the station timeline drawn and the plane
    fits done already)."""
    slam = res.slam
    main = [k for k in range(len(res.fragments)) if slam.component[k] == 0]
    plot_odometry_vs_optimized(res.outdir / "report_odometry.png", slam.T_odometry[main],
                               slam.T_optimized[main])
    if early is None:
        early = early_figures(res.outdir, res.segmentation, res.fragments,
                              int(res.recording.lidar.lidar_ns[0]), cfg)
    return plot_plane_violins(res.outdir / "report_planes.png", early)


def early_figures(out: Path, seg, fragments: list, t0_ns: int, cfg: ReconstructConfig
                  ) -> list[dict[str, np.ndarray]]:
    """The report's station timeline and every fragment's plane-fit errors (returned, for
    :func:`report_figures`): they need only the stations and the fragments, so the pipeline
    runs them on another thread while the odometry and the pose graph run."""
    plot_station_timeline(out / "report_stations.png", seg, t0_ns, cfg.stations.still_threshold,
                          cfg.stations.still_tilt_deg)
    # plane fits on a random sample of each fragment: the residuals keep their statistics, the
    # RANSAC gets far cheaper
    rng = np.random.default_rng(0)

    def sample(p, n=15_000):
        return p if len(p) <= n else p[rng.choice(len(p), n, replace=False)]

    return [plane_fit_errors(sample(f.points), f.up_in_lidar, min_inliers=60, seed=k)
            for k, f in enumerate(fragments)]


def warm_up() -> None:
    """Import pyplot (Agg) ahead of the first picture: ~0.4 s CPU that the pipeline spends on
    another thread while it reads the recording."""
    _plt()


def write_report(res, cfg: ReconstructConfig, s: dict, stats: dict | None = None) -> Path:
    """Write ``report.md`` and its PNGs into the run's output folder; return the report path.

    ``res`` is the run's ``pipeline.ReconstructResult``, ``s`` its ``pipeline.summary`` (passed
    in, so that this module does not import the pipeline that calls it); ``stats``: what
    :func:`report_figures` returned when it ran already (else it runs here)."""
    out = res.outdir
    slam = res.slam
    main = [k for k in range(len(res.fragments)) if slam.component[k] == 0]
    from ..io import clouds as cloud_io
    from .outputs import read_tum

    map_xyz = cloud_io.xyz(cloud_io.read_ply(out / "map.ply"))
    _, traj_T = read_tum(out / "trajectory.tum")
    plot_topdown(out / "report_topdown.png", map_xyz, slam.T_optimized[main], traj_T,
                 slam.disconnected)
    if stats is None:
        stats = report_figures(res, cfg)

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
        f"({s['processing_s'] / max(s['recording_s'], 1e-9):.3f} of the recording time)"
        + ("" if s.get("engine", "in-process") == "in-process" else
           f"; fragments and registrations as tasks on {s['engine']} (their CPU not counted)")
        + " |",
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
    lines += [""] + calibration_section(res.calibration)
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
