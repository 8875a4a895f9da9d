# SPDX-License-Identifier: BSD-3-Clause
"""``tripod reconstruct``: a recording in, a registered indoor model out.

Stages: read → clocks → stations → IMU time offset → fragments → odometry → loop closures and
pose graph → outputs (map, fragments, pose graph, TUM, Foxglove MCAP, config) → report.
"""

from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tripod_shared.config_io import dump_config

from ..io import clouds as cloud_io
from ..preprocess import mls_smooth, voxel_downsample
from . import outputs
from .config import ReconstructConfig
from .fragments import Fragment
from .inputs import Recording, RecordingError, read_recording
from .odometry import CloudCache
from .placement import Extrinsic, ImuOrientation, fit_clock_map, pose_world_lidar
from .scaleout import blas_one_thread, build_fragments
from .slam import SlamResult, inv, run_odometry, run_slam
from .stations import Segmentation, segment_stations

# the time offset's joins (turns and surfaces), at DEBUG with the numbers in ``record.offset_join``
# (a dict): for diagnosis only, no output depends on it
_join_log = logging.getLogger("tripod_processor.reconstruction.offset_joins")


def _log_join(stage: str, **numbers) -> None:
    if _join_log.isEnabledFor(logging.DEBUG):
        d = {"stage": stage, **{k: (None if v is None else float(v)) for k, v in numbers.items()}}
        _join_log.debug("offset join %s: %s", stage, d, extra={"offset_join": d})


@dataclass
class ReconstructResult:
    outdir: Path
    recording: Recording
    segmentation: Segmentation
    fragments: list[Fragment]
    slam: SlamResult
    extrinsic: Extrinsic
    time_offset_ns: int
    host_minus_lidar_ns: int
    stage_s: dict[str, float] = field(default_factory=dict)
    map_points: int = 0
    files: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    time_offset_info: dict = field(default_factory=dict)
    calibration: dict = field(default_factory=dict)  # effective calibration (calibration.json)
    engine: str = "in-process"  # where fragments and registrations ran (.engine)

    @property
    def station_t_ns(self) -> np.ndarray:
        return np.array([f.station.mid_ns for f in self.fragments], dtype=np.int64)

    @property
    def processing_s(self) -> float:
        """Wall time of all stages [s]."""
        return float(sum(v for k, v in self.stage_s.items() if k != "_cpu"))

    @property
    def processing_cpu_s(self) -> float:
        """CPU time of all stages, all threads [s] (a busy machine inflates wall time)."""
        return float(sum(self.stage_s.get("_cpu", {}).values()))


class _Stage:
    """Times a stage into ``stage_s`` and gives it a progress bar."""

    def __init__(self, res_times: dict, name: str, total: int | None, quiet: bool):
        self.times, self.name, self.total, self.quiet = res_times, name, total, quiet

    def __enter__(self):
        self.t0 = time.perf_counter()
        self.c0 = time.process_time()
        self.bar = tqdm(total=self.total, desc=f"{self.name:>12}", unit="", leave=True,
                        disable=self.quiet, dynamic_ncols=True)
        return self.bar

    def __exit__(self, *exc):
        self.bar.close()
        self.times[self.name] = self.times.get(self.name, 0.0) + time.perf_counter() - self.t0
        cpu = self.times.setdefault("_cpu", {})
        cpu[self.name] = cpu.get(self.name, 0.0) + time.process_time() - self.c0


def reconstruct(recording_path: str | os.PathLike, outdir: str | os.PathLike,
                cfg: ReconstructConfig | None = None, *, imu_log=None, quiet: bool = False,
                engine=None, engine_min_stations: int = 0) -> ReconstructResult:
    """Run the whole reconstruction; see the module docstring. Raises RecordingError on input
    that cannot be reconstructed (one-line message).

    ``engine`` (:mod:`.engine`, e.g. :func:`.engine.ray_engine`): fragments, odometry pairs and
    loop candidates run as its tasks when the recording has at least ``engine_min_stations``
    stations; the outputs are the same bytes as in process (for the same ``num_threads``).

    BLAS runs on one thread meanwhile (:func:`.scaleout.blas_one_thread`): the stages run their
    own work side by side on ``num_threads`` threads. The report's work runs on one background
    thread beside the stages (pyplot's import while the recording is read, the station timeline
    and the plane fits while the odometry and the pose graph run, its other pictures and the
    MCAP while the outputs are written).
    """
    with blas_one_thread(), ThreadPoolExecutor(1) as bg:
        return _reconstruct(recording_path, outdir, cfg or ReconstructConfig(), bg,
                            imu_log=imu_log, quiet=quiet, engine=engine,
                            engine_min_stations=engine_min_stations)


def _reconstruct(recording_path, outdir, cfg: ReconstructConfig, bg: ThreadPoolExecutor, *,
                 imu_log, quiet, engine, engine_min_stations) -> ReconstructResult:
    """:func:`reconstruct` (its BLAS limit set; ``bg``: its one background thread)."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    threads = cfg.num_threads
    if cfg.output.report:
        from .report import warm_up

        bg.submit(warm_up)  # pyplot's import beside the read

    # 1. read
    with _Stage(times, "read", None, quiet):
        rec = read_recording(recording_path, imu_log)
    if rec.imu is None:
        raise RecordingError(
            f"{recording_path}: the recording has no IMU samples; placement needs the IMU "
            "orientation (record with the IMU connected, or pass an IMU log with --imu)")
    if len(rec.lidar) < 100:
        raise RecordingError(f"{recording_path}: only {len(rec.lidar)} lidar packets")

    # 2. clocks and placement model
    clock = fit_clock_map(rec.lidar)
    delta = clock.host_minus_lidar_ns
    if clock.rate != 1.0:
        notes_clock = [f"host clock runs {clock.rate:.4f}x the lidar's (a replay at that rate?); "
                       "IMU and marks mapped with the fitted rate"]
    else:
        notes_clock = []
    pc = cfg.placement
    ext = Extrinsic.from_config(pc.extrinsic.q_imu_lidar, pc.extrinsic.lever_arm_m)
    notes = list(rec.notes) + notes_clock
    orient = ImuOrientation(rec.imu, clock, int(round((pc.imu_time_offset_s or 0.0) * 1e9)),
                            smooth_s=pc.imu_smooth_s)
    imu_t = orient.t_ns
    if imu_t[0] > rec.lidar.lidar_ns[0] + 1e9 or imu_t[-1] < rec.lidar.lidar_ns[-1] - 1e9:
        notes.append("IMU samples do not cover the whole lidar recording; orientation is held "
                     "at the ends")

    # 3. stations
    n_windows = int((rec.lidar.lidar_ns[-1] - rec.lidar.lidar_ns[0]) / 0.5e9)
    marks = [(int(clock.to_lidar(np.array([h]))[0]), label) for h, label in rec.marks]
    windows: dict = {}  # the splitter's decoded windows, kept for its later passes
    with _Stage(times, "stations", n_windows, quiet) as bar:
        seg = segment_stations(rec.lidar, orient, ext, cfg.stations, marks, progress=bar,
                               num_threads=threads, reuse=windows)
    uncalibrated = (pc.extrinsic.q_imu_lidar is None or pc.extrinsic.lever_arm_m is None)
    loose_pass = not seg.stations and uncalibrated
    if loose_pass:
        # a rig far from the defaults can blur the lidar's cue everywhere: stations to
        # calibrate on from the IMU's cue alone (the second pass below decides)
        loose = cfg.stations.model_copy(update={"still_threshold": 1.0})
        with _Stage(times, "stations", n_windows, quiet) as bar:
            seg = segment_stations(rec.lidar, orient, ext, loose, marks, progress=bar,
                                   num_threads=threads, reuse=windows)
    notes += seg.notes
    if not seg.stations:
        raise RecordingError(f"{recording_path}: no station found (no period where the tripod "
                             f"stands for {cfg.stations.min_station_s:g} s)")

    # 4. calibration from the data: the mount rotation (hand-eye) when not given, then the lever
    # arm, the IMU time offset and the mount's tilts from the stations' self-consistency; the
    # segmentation above needed none of them (it takes the lever arm's apparent shift out)
    calib = None
    ext_seg = Extrinsic(ext.R_imu_lidar.copy(), ext.lever_arm_m.copy(), ext.source)
    tilt_sigma_deg = float("inf")  # hand-eye's mount tilt [deg, 1 sigma]
    from .calibration import SweepCache

    # the sweeps the calibration decodes, for its later registrations (dropped after it)
    sweeps = SweepCache(cfg.calibration.sweep_cache_mb)
    if pc.extrinsic.q_imu_lidar is None:
        ext, orient, tilt_sigma_deg = _calibrate_mount(rec, seg, orient, ext, cfg, threads, times,
                                                       quiet, notes, sweeps)
    fit_lever = pc.extrinsic.lever_arm_m is None and cfg.calibration.lever_arm
    fit_time = pc.imu_time_offset_s is None and cfg.calibration.time_offset
    fit_rot = pc.extrinsic.q_imu_lidar is None and cfg.calibration.mount_rotation
    if fit_lever or fit_time or fit_rot:
        with _Stage(times, "calibration", None, quiet):
            ext, orient, calib = _self_calibrate(rec, seg, orient, ext, cfg, fit_lever,
                                                 fit_time, fit_rot, notes, tilt_sigma_deg,
                                                 sweeps)
    sweeps.clear()
    if loose_pass or _rig_changed(ext_seg, ext):
        # 4b. the stations again with the calibrated rig: the first pass only had to find
        # stations enough to calibrate on; this one sees every station sharply
        notes = [n for n in notes if n not in seg.notes]
        with _Stage(times, "stations 2", n_windows, quiet) as bar:
            seg = segment_stations(rec.lidar, orient, ext, cfg.stations, marks, progress=bar,
                               num_threads=threads, reuse=windows)
        notes += seg.notes
        if not seg.stations:
            raise RecordingError(f"{recording_path}: no station found with the calibrated rig")
    windows.clear()
    info: dict = {}

    # 5. fragments (with their voxels' intensity when a survey file wants it)
    oc = cfg.output
    survey = oc.write_e57 or oc.write_las != "none"
    # the heavy independent steps (fragments, pair registrations) on the engine when given
    eng = engine if engine is not None and len(seg.stations) >= engine_min_stations else None
    with _Stage(times, "fragments", len(seg.stations), quiet) as bar:
        frags = build_fragments(eng, rec.lidar, seg.stations, orient, ext, cfg.fragments.voxel_m,
                                pc.min_range_m, pc.max_range_m, threads, survey, bar,
                                anchor_fit=pc.anchor_fit,
                                anchor_max_deviation_deg=pc.anchor_max_deviation_deg,
                                denoise_firings=cfg.fragments.range_denoise_firings,
                                denoise_fit=cfg.fragments.range_denoise_fit,
                                denoise_max_step_m=cfg.fragments.range_denoise_max_step_m,
                                chunk_pipeline=cfg.fragments.chunk_pipeline)
    notes += _anchor_notes(frags, pc.anchor_max_deviation_deg)
    early = None
    if cfg.output.report:
        from .report import early_figures

        # the station timeline and the fragments' plane fits beside the odometry and SLAM
        early = bg.submit(early_figures, out, seg, frags, int(rec.lidar.lidar_ns[0]), cfg)

    # 6. odometry
    cache = CloudCache(cfg.odometry.point_sigma_m, threads)
    with _Stage(times, "odometry", max(len(frags) - 1, 0), quiet) as bar:
        T_odom, odom_edges, comp, odom_notes = run_odometry(frags, cfg.odometry, threads, bar,
                                                            cache, eng)
    notes += odom_notes

    # 7. loops and pose graph
    with _Stage(times, "slam", None, quiet) as bar:
        slam = run_slam(frags, T_odom, odom_edges, comp, cfg.odometry, cfg.slam, threads, bar,
                        cache, eng)
    notes += slam.notes

    res = ReconstructResult(out, rec, seg, frags, slam, ext, orient.time_offset_ns, delta,
                            times, notes=notes, time_offset_info=info,
                            calibration=effective_calibration(ext, orient, pc, calib),
                            engine=eng.name if eng is not None else "in-process")

    # 8. outputs; the report's pictures of the fragments and poses meanwhile on the background
    # thread (the outputs' voxel filter and smoothing run natively, without the GIL); it runs
    # its tasks in order, so the early figures are done when the others start
    figures = None
    if cfg.output.report:
        from .report import report_figures, write_report

        figures = bg.submit(lambda: report_figures(res, cfg, early.result()))
    with _Stage(times, "outputs", None, quiet):
        pending = _write_outputs(res, cfg, orient, bg)
    if cfg.output.report:
        with _Stage(times, "report", None, quiet):
            res.files["report"] = str(write_report(res, cfg, summary(res), figures.result()))
    for f in pending:
        f.result()  # raises what the writer raised
    outputs.write_json(out / "result.json", summary(res))
    res.files["result"] = str(out / "result.json")
    return res


def _anchor_notes(frags: list, max_dev_deg: float) -> list[str]:
    """One note when a station's fitted anchor was not used or its pan angle not fitted."""
    kept = [f"{f.station.index} ({f.anchor})" for f in frags
            if f.anchor not in ("fit", "fit, pan slerped", "slerped")]
    pan = sum(f.anchor == "fit, pan slerped" for f in frags)
    out = []
    if kept:
        out.append(f"station anchor: {len(kept)} of {len(frags)} stations kept the slerped IMU "
                   f"attitude (too few IMU samples, or the fit more than {max_dev_deg:g}° from "
                   "it): " + ", ".join(kept))
    if pan:
        out.append(f"station anchor: {pan} of {len(frags)} stations' pan angle not fitted (no "
                   "window's residuals were white noise): taken from the slerped attitude")
    return out


def trajectory(res: ReconstructResult, orient: ImuOrientation, hz: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """T_map_lidar at ``hz`` over the whole recording.

    Within a station: the optimised station pose moved by the IMU's rotation about the head's
    pivot. Between stations (carry): the IMU attitude, with the map correction (yaw drift and
    position) interpolated between the neighbouring stations; the carry's position is therefore
    interpolated, not measured.
    """
    lidar_ns = res.recording.lidar.lidar_ns
    t = np.arange(lidar_ns[0], lidar_ns[-1], int(1e9 / hz), dtype=np.int64)
    T_imu = pose_world_lidar(orient, res.extrinsic, t)
    main = [k for k in range(len(res.fragments)) if res.slam.component[k] == 0]
    if not main:
        return t[:0], T_imu[:0]
    # each station's frame as its fragment has it (the anchor attitude, fitted or slerped)
    ext = res.extrinsic
    T_mid = np.tile(np.eye(4), (len(main), 1, 1))
    for i, k in enumerate(main):
        R_wl = res.fragments[k].R_world_lidar
        T_mid[i, :3, :3] = R_wl
        T_mid[i, :3, 3] = R_wl @ ext.R_imu_lidar.T @ ext.lever_arm_m
    # correction C_k with T_map_lidar(t) = C_k · T_imu(t) inside station k
    C = np.array([res.slam.T_optimized[k] @ inv(T_mid[i]) for i, k in enumerate(main)])
    from scipy.spatial.transform import Rotation, Slerp

    starts = np.array([res.fragments[k].station.start_ns for k in main])
    ends = np.array([res.fragments[k].station.end_ns for k in main])
    out = np.empty_like(T_imu)
    key_t = np.concatenate([[s, e] for s, e in zip(starts, ends)]).astype(np.float64)
    key_C = np.concatenate([[c, c] for c in C])
    # strictly increasing keys for Slerp
    key_t = key_t + np.arange(len(key_t)) * 1e-3
    slerp = Slerp(key_t, Rotation.from_matrix(key_C[:, :3, :3]))
    tc = np.clip(t.astype(np.float64), key_t[0], key_t[-1])
    R = slerp(tc).as_matrix()
    p = np.stack([np.interp(tc, key_t, key_C[:, i, 3]) for i in range(3)], axis=1)
    Cs = np.tile(np.eye(4), (len(t), 1, 1))
    Cs[:, :3, :3] = R
    Cs[:, :3, 3] = p
    out = Cs @ T_imu
    return t, out


def _calibrate_mount(rec, seg, orient, ext, cfg, threads, times, quiet, notes, sweeps=None):
    """(extrinsic, orientation, tilt sigma [deg]) with the mount rotation calibrated from the
    data (hand-eye; the sigma of its tilt from the pairs' axis scatter, inf when it failed);
    identity, and a note, when that fails. When the lever arm is not given either, hand-eye's
    rough one is the self-calibration's starting point."""
    from .calibration import calibrate_mount

    tilt_sigma_deg = float("inf")
    with _Stage(times, "mount calib", None, quiet):
        try:
            cal, calib_info = calibrate_mount(
                rec.lidar, seg.stations, orient, threads,
                denoise_firings=cfg.calibration.range_denoise_firings,
                turn_ladder=cfg.calibration.mount_turn_ladder, sweep_cache=sweeps)
            ell = ext.lever_arm_m
            if (cfg.placement.extrinsic.lever_arm_m is None
                    and np.linalg.norm(cal.lever_arm_m) < 0.3):
                ell = cal.lever_arm_m
            ext = Extrinsic(cal.R_imu_lidar, ell, "calibrated rotation")
            tilt_sigma_deg = float(calib_info.get("tilt_sigma_deg", float("inf")))
            notes.append("lidar-IMU mount rotation calibrated from the data (hand-eye, "
                         f"{calib_info['pairs']} sweep pairs of median turn "
                         f"{calib_info['turn_deg_median']:.1f}°, median residual "
                         f"{calib_info['rotation_residual_deg_median']:.2f}°, tilt σ "
                         f"{tilt_sigma_deg:.2f}°)")
            if not tilt_sigma_deg < cfg.calibration.mount_tilt_warn_deg:
                # the turn axis of small turns is the registrations' noise: the tilt is
                # degrees uncertain, the surfaces' fit below has to find it
                notes.append(f"WARNING: hand-eye's mount tilt poorly observable (σ "
                             f"{tilt_sigma_deg:.2f}° from its {calib_info['pairs']} sweep pairs' "
                             f"axis scatter; median turn {calib_info['turn_deg_median']:.1f}°): "
                             "the head's turns share too little view to register big ones")
        except ValueError as exc:
            ext.source = "default"
            notes.append(f"mount calibration failed ({exc}): identity assumed")
    return ext, orient.with_offset(orient.time_offset_ns), tilt_sigma_deg


def _rig_changed(a: Extrinsic, b: Extrinsic) -> bool:
    """Did the calibration move the rig enough to change what the station splitter sees (the
    lever arm by 5 mm, the mount by 0.1°)?"""
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_matrix(a.R_imu_lidar.T @ b.R_imu_lidar).magnitude()
    return bool(np.linalg.norm(a.lever_arm_m - b.lever_arm_m) > 0.005
                or np.degrees(dR) > 0.1)


def _self_calibrate(rec, seg, orient, ext, cfg, fit_lever, fit_time, fit_rot, notes,
                    tilt_sigma_deg=float("inf"), sweeps=None):
    """(extrinsic, orientation, SelfCalibration | None) refined from the stations' geometry;
    what the data cannot see well is warned about (and a time offset not seen at all is kept
    at the prior). ``tilt_sigma_deg``: hand-eye's mount tilt sigma (the starting ``ext``'s),
    against which a mount tilt the surfaces see poorly is weighed (:func:`_weigh_tilt`).
    ``sweeps`` (:class:`calibration.SweepCache`): the decoded sweeps shared by the turns'
    registrations (hand-eye's too)."""
    cc = cfg.calibration
    from .calibration import SweepCache

    # the stations' sample points, for the surfaces' later fits on the same stations
    points = SweepCache(cc.station_points_cache_mb)
    turn = None
    fit_time_surf = fit_time
    mount_free = fit_rot  # the mount not given: its turn about the pan axis is hand-eye's so far
    if fit_time and cc.time_offset_from_turns:
        # the time offset first, from the head's turns and the carries' (registrations, all
        # but blind to the lever arm: see _turns_again_with_lever): the surfaces' fit below
        # starts from it
        turn = _turns_time_offset(rec, seg, orient, ext, cfg, sweeps)
        if turn.sigma_ms <= cc.max_turns_time_offset_sigma_ms:
            orient = orient.with_offset(turn.offset_ns)
        else:
            turn = None
    turn_lever = None
    if fit_lever and cc.lever_from_turns:
        ext_turns = ext
        ext, turn_lever = _lever_start_from_turns(rec, seg, orient, ext, cfg, notes, sweeps)
        if turn is not None and turn_lever is not None:
            turn, orient = _turns_again_with_lever(rec, seg, orient, ext_turns, ext, turn, cfg,
                                                   notes, sweeps)
    # the turns' offset joins the surfaces' fit as a prior: offset and lever arm together
    prior = {} if turn is None or not cc.joint_time_prior else {
        "time_prior_ns": turn.offset_ns, "time_prior_sigma_ms": turn.sigma_ms}
    split = cc.split_iterations if fit_lever else 0  # the lever-arm fit's split-residual steps
    pps = _points_per_station(seg.stations, orient, ext.R_imu_lidar, cfg)
    try:
        cal = _fit_surfaces(rec, seg, orient, ext, cfg, pps, fit_lever=fit_lever,
                            fit_time=fit_time_surf, fit_rotation=fit_rot,
                            split_iterations=split, iterations=8 + split,
                            points_cache=points, **prior)
        if fit_rot:
            _tilt_spread_sigma(rec, seg, orient, cfg, cal, pps, fit_lever, fit_time_surf, prior,
                               points_cache=points)
        if fit_rot and not cal.rotation_observable:
            # the stations' surfaces hardly see the mount's tilt (a spin axis near the pan axis
            # in a small room: the tilt's blur is its angle times the range); hand-eye's sees it
            # no better there. More stations, then the two weighed by their sigmas; the rest
            # again with the tilt held
            R_tilt, how = _weigh_tilt(rec, seg, orient, ext, cfg, cal, fit_lever,
                                      fit_time_surf, prior, tilt_sigma_deg, points)
            ext = Extrinsic(R_tilt, ext.lever_arm_m.copy(), ext.source)
            if fit_lever or fit_time_surf:
                # pps: the sample size chosen with the mount before the tilt was weighed
                cal = _fit_surfaces(rec, seg, orient, ext, cfg, pps, fit_lever=fit_lever,
                                    fit_time=fit_time_surf, fit_rotation=False,
                                    split_iterations=split, iterations=8 + split,
                                    points_cache=points, **prior)
            fit_rot = False
            notes.append(how)
    except ValueError as exc:
        notes.append(f"self-calibration failed ({exc}): the lever arm and time offset stay at "
                     "their priors")
        return ext, orient, None
    if fit_lever and split == 0:
        # the start was one station's hand-eye lever arm (the turns' too uncertain, or off)
        cal = _refit_far_lever(rec, seg, orient, ext, cfg, cal, fit_time_surf, fit_rot, prior,
                               notes, uncertain_start=turn_lever is None, points_cache=points)
    if turn_lever is not None:
        _spin_axis_lever_from_turns(cal, turn_lever, cc.lever_spin_sigma_inflation,
                                    cc.lever_spin_sigma_floor_mm * 1e-3)
    if fit_lever:
        by_mount = cal.lever_arm_by_mount() or {}
        tilt = by_mount.get("spin_axis_from_pan_axis_deg", 0.0)
        if tilt >= cc.side_mount_warn_deg and "sigma_along_spin_axis_m" in by_mount:
            # the spin-axis component shows only at vertical edges: its sigma from the surfaces
            # counts no error of the mount's tilt or the time offset, which it takes up
            notes.append(
                f"WARNING: lidar spin axis {tilt:.0f}° from the pan axis: the lever arm along it "
                f"(σ {by_mount['sigma_along_spin_axis_m'] * 1000:.1f} mm from the "
                f"{'surfaces and turns' if turn_lever is not None else 'surfaces'}; "
                "not counting a mount-tilt or time-offset error) is seen only at vertical edges "
                "and can be centimetres off; in the scan plane σ "
                f"{by_mount['sigma_in_scan_plane_m'] * 1000:.1f} mm. Measure it if it matters "
                "(--set placement.extrinsic.lever_arm_m=...)")
        if cal.lever_arm_observable:
            pass
        else:
            notes.append("WARNING: lever arm poorly observable (σ "
                         f"{np.max(cal.lever_arm_sigma_m) * 1000:.1f} mm): few surfaces seen "
                         "from opposite sides of the pan")
    off = orient.time_offset_ns
    # the surfaces' own offset (without the turns' prior), for a re-measure of the turns below
    surfaces = (_surfaces_own_offset(cal, turn if prior else None)
                if turn is not None and cc.turn_remeasure_after_surfaces else None)
    if turn is not None and _join_log.isEnabledFor(logging.DEBUG):
        own = _surfaces_own_offset(cal, turn if prior else None)
        _log_join("first", turns_ms=turn.offset_ns * 1e-6, turns_sigma_ms=turn.sigma_ms,
                  surf_ms=None if own is None else own[0] * 1e-6,
                  surf_sigma_ms=None if own is None else own[1],
                  fit_ms=cal.time_offset_ns * 1e-6, fit_sigma_ms=cal.time_offset_sigma_ms,
                  joint=bool(prior))
    widen = cc.surface_time_sigma_floor_ms > 0 or cc.surface_time_consistency
    if turn is not None and prior and widen:
        _rejoin_joint_with_widened_surfaces(cal, turn, cc)
    if turn is not None and prior:
        # the joint fit holds both: its offset and sigma are the result
        cal.time_offset_method = "turns and surfaces (joint)"
        cal.turns = turn.to_dict()
    elif turn is not None:
        # the surfaces' estimate joins the turns' when it is sure and agrees (inverse-variance
        # mean); else the turns' alone
        s_t, s_s = turn.sigma_ms, cal.time_offset_sigma_ms
        d_ms = (cal.time_offset_ns - turn.offset_ns) * 1e-6
        if s_s <= cc.max_time_offset_sigma_ms and abs(d_ms) < 3 * np.hypot(s_t, s_s):
            if widen:
                s_s = _surface_sigma_for_join(d_ms, s_t, s_s, cc.surface_time_sigma_floor_ms,
                                              cc.surface_time_consistency)
            w = s_s**2 / (s_t**2 + s_s**2)  # the turns' weight
            cal.time_offset_ns = int(round(turn.offset_ns + (1 - w) * d_ms * 1e6))
            cal.time_offset_sigma_ms = float(1 / np.sqrt(1 / s_t**2 + 1 / s_s**2))
            cal.time_offset_method = "turns and surfaces"
        else:
            cal.time_offset_ns, cal.time_offset_sigma_ms = turn.offset_ns, s_t
            cal.time_offset_method = "turns"
        cal.time_offset_observable = bool(cal.time_offset_sigma_ms < 0.5)
        cal.turns = turn.to_dict()
    if turn is not None and prior:
        cal.time_offset_observable = bool(cal.time_offset_sigma_ms < 0.5)
    if fit_time:
        # the turns' sigma is honest (their scatter); the surfaces' alone is optimistic
        limit = (cc.max_turns_time_offset_sigma_ms if turn is not None
                 else cc.max_time_offset_sigma_ms)
        if cal.time_offset_sigma_ms <= limit:
            off = cal.time_offset_ns
            if not cal.time_offset_observable:
                notes.append(f"WARNING: IMU time offset poorly observable (σ "
                             f"{cal.time_offset_sigma_ms:.2f} ms): the head turns at a nearly "
                             "constant rate (a time offset then only turns each station)")
        else:
            notes.append(f"WARNING: IMU time offset not observable (σ "
                         f"{cal.time_offset_sigma_ms:.1f} ms): kept at "
                         f"{orient.time_offset_ns * 1e-6:.2f} ms")
    R = cal.R_imu_lidar if fit_rot else ext.R_imu_lidar
    ell = cal.lever_arm_m if fit_lever else ext.lever_arm_m
    src = ext.source if not fit_lever else (
        "calibrated" if ext.source.startswith("calibrated") or fit_rot else "config rotation, "
        "calibrated lever arm")
    ext_out = Extrinsic(R, ell, src)
    if fit_time and turn is not None and cc.turn_remeasure_after_surfaces:
        off = _turns_after_surfaces(rec, seg, orient.with_offset(off), ext_out, cfg, cal,
                                    surfaces, off, notes, sweeps)
    if mount_free and cc.mount_yaw_from_carries:
        ext_out = _mount_yaw_from_carries(rec, seg, orient.with_offset(off), ext_out, cfg, cal,
                                          fit_lever, notes, sweeps)
    return ext_out, orient.with_offset(off), cal


def _mount_yaw_from_carries(rec, seg, orient, ext, cfg, cal, fit_lever, notes, sweeps=None):
    """``ext`` turned about the pan axis by the carries' estimate of the mount's turn there
    (:func:`calibration.mount_yaw_from_carries`) when its sigma is within
    ``calibration.mount_yaw_max_sigma_deg``; the lever arm (IMU frame) turns with it when it was
    estimated, so the lever arm in the lidar frame, and every station's geometry, stay as they
    are (the stations cannot see that turn); a lever arm given in the config stays. ``cal``
    follows (mount, lever arm and its basis, ``mount_yaw``)."""
    from .calibration import mount_yaw_from_carries

    cc = cfg.calibration
    my = mount_yaw_from_carries(rec.lidar, seg.stations, orient, ext, cfg.num_threads,
                                pairs_per_carry=cc.mount_yaw_pairs_per_carry,
                                denoise_firings=cc.range_denoise_firings,
                                pan_axis_imu=cal.pan_axis_imu, sweep_cache=sweeps)
    if my is None:
        return ext
    d, s = np.degrees(my.angle_rad), np.degrees(my.sigma_rad)
    applied = bool(s <= cc.mount_yaw_max_sigma_deg)
    cal.mount_yaw = {**my.to_dict(), "applied": applied}
    notes.append(f"mount's turn about the pan axis from {my.carries} carries ({my.pairs} sweep "
                 f"pairs): {d:+.2f} ± {s:.2f}°, "
                 + ("applied" if applied else
                    f"not applied (σ over {cc.mount_yaw_max_sigma_deg:g}°: hand-eye's kept)"))
    if not applied:
        return ext
    Rb = my.rotation()
    R = Rb @ ext.R_imu_lidar
    ell = Rb @ ext.lever_arm_m if fit_lever else ext.lever_arm_m.copy()
    cal.R_imu_lidar = R
    if fit_lever:
        cal.lever_arm_m = Rb @ cal.lever_arm_m
        if cal.lever_basis_imu is not None:
            cal.lever_basis_imu = Rb @ cal.lever_basis_imu
    return Extrinsic(R, ell, ext.source)


def _fit_surfaces(rec, seg, orient, ext, cfg, points_per_station: int, **fit):
    """``calibration.self_calibrate`` on the recording's stations with the run's common
    settings (threads, range smoothing, yaw drift and its prior, ``max_stations`` unless
    ``fit`` gives it); ``fit``: what this call fits and how (``fit_lever``, ``fit_time``,
    ``fit_rotation``, iterations, the time prior)."""
    from .calibration import pan_axis_in_imu, self_calibrate, spin_axis_from_pan_axis_deg

    cc = cfg.calibration
    fit.setdefault("max_stations", cc.max_stations)
    if cc.tilt_range_weight_exp > 0 and "range_weight_exp" not in fit:
        # a lidar near the pan axis sees its tilt at the far floor and ceiling: drawn denser
        tilt = spin_axis_from_pan_axis_deg(pan_axis_in_imu(orient, seg.stations),
                                           ext.R_imu_lidar)
        if tilt < cc.side_mount_warn_deg:
            fit["range_weight_exp"] = cc.tilt_range_weight_exp
    return self_calibrate(rec.lidar, seg.stations, orient, ext, num_threads=cfg.num_threads,
                          denoise_firings=cc.range_denoise_firings,
                          fit_yaw_drift=cc.fit_yaw_drift,
                          points_per_station=points_per_station,
                          yaw_drift_prior_deg_per_min=cc.yaw_drift_prior_deg_per_min, **fit)


def _points_per_station(rec_stations, orient, R_imu_lidar, cfg) -> int:
    """Sample points a station for the surfaces' fit: ``calibration.side_points_per_station``
    on a lidar at least ``side_mount_warn_deg`` from the pan axis (its lever arm along the spin
    axis is seen only at vertical edges, and was mostly the sampling's noise in a hall with
    80,000; 160,000 by default, see the config), else ``calibration.near_points_per_station``
    (80,000 by default, ``self_calibrate``'s own)."""
    from .calibration import pan_axis_in_imu, spin_axis_from_pan_axis_deg

    cc = cfg.calibration
    tilt = spin_axis_from_pan_axis_deg(pan_axis_in_imu(orient, rec_stations), R_imu_lidar)
    return (cc.side_points_per_station if tilt >= cc.side_mount_warn_deg
            else cc.near_points_per_station)


def _turns_time_offset(rec, seg, orient, ext, cfg, sweeps=None):
    """The IMU time offset from the head's turns and the carries
    (:func:`calibration.time_offset_from_turns` with the config's keywords), its sweeps
    de-skewed by ``orient`` and ``ext``."""
    from .calibration import carry_spans, time_offset_from_turns

    cc = cfg.calibration
    carries = carry_spans(seg.stations) if cc.time_offset_from_carries else None
    return time_offset_from_turns(rec.lidar, seg.stations, orient, ext, cfg.num_threads,
                                  max_stations=cc.max_turn_stations, carries=carries,
                                  denoise_firings=cc.range_denoise_firings,
                                  passes=cc.turn_passes,
                                  pairs_per_station=cc.turn_pairs_per_station,
                                  pairs_per_carry=cc.turn_pairs_per_carry,
                                  station_information=cc.turn_station_information,
                                  uses_per_sweep=cc.turn_sweep_uses,
                                  combine=cc.turn_combine,
                                  carry_floor_ms=cc.turn_carry_floor_ms,
                                  cluster_outlier_z=cc.turn_cluster_outlier_z,
                                  carry_mount=cc.turn_carry_mount,
                                  anchor_smooth_s=cc.turn_anchor_smooth_s,
                                  sweep_cache=sweeps)


def _turns_again_with_lever(rec, seg, orient, ext_turns, ext, turn, cfg, notes, sweeps=None):
    """(turn, orient): the turns' time offset ``turn`` (found with ``ext_turns``, ``orient``
    already at its offset) measured again with ``ext``'s lever arm when that lies more than
    ``calibration.turn_relever_mm`` from ``ext_turns``' (and the new one applied when its sigma
    allows); else both as they are.

    A lever-arm error ε leaves each 0.1-s sweep smeared by the head's swing while it pans at
    rate ω (ω × ε over the sweep: ~1 cm at 40°/s and 15 cm), unlike the two ends of the sweep;
    that seam turns the sweep's registration by an angle that grows with ω, so a pair's angle
    changes with the rate change ω_j − ω_k, as an offset error does (dev seeds 40, 631: the
    turns 1.8 / 2.1 ms off with hand-eye's lever arm, 0.1 / 1.5 with the true one)."""
    cc = cfg.calibration
    moved_mm = 1000 * float(np.linalg.norm(ext.lever_arm_m - ext_turns.lever_arm_m))
    if not (cc.turn_relever_mm > 0 and moved_mm > cc.turn_relever_mm):
        return turn, orient
    again = _turns_time_offset(rec, seg, orient, ext, cfg, sweeps)
    if not again.sigma_ms <= cc.max_turns_time_offset_sigma_ms:
        return turn, orient
    notes.append(f"turns' time offset measured again with the turns' lever arm ({moved_mm:.0f}"
                 f" mm from the first's): {turn.offset_ns * 1e-6:.2f} -> "
                 f"{again.offset_ns * 1e-6:.2f} ms")
    return again, orient.with_offset(again.offset_ns)


def _surfaces_own_offset(cal, prior_turn):
    """(offset_ns, sigma_ms) of the surfaces' fit ``cal`` alone: with ``prior_turn`` (the
    turns' offset it took as a prior) taken out of its posterior (Gaussian: the offset's
    marginal information is the data's plus the prior's, its mean their weighted mean), or
    None when nothing is left (a prior-dominated offset)."""
    m, s = float(cal.time_offset_ns), float(cal.time_offset_sigma_ms)
    if not (np.isfinite(s) and s > 0):
        return None
    if prior_turn is None:
        return m, s
    s_p = float(prior_turn.sigma_ms)
    if not (np.isfinite(s_p) and s_p > 0):
        return None
    info = 1.0 / s**2 - 1.0 / s_p**2
    if not info > 0.05 / s_p**2:  # the data's own information under 5 % of the prior's
        return None
    m_own = (m / s**2 - float(prior_turn.offset_ns) / s_p**2) / info
    return m_own, float(1.0 / np.sqrt(info))


def _surface_sigma_for_join(d_ms, turn_sigma_ms, surf_sigma_ms, floor_ms=0.0,
                            consistency=False) -> float:
    """The surfaces' own offset's sigma [ms] as weighed in a join with the turns': at least
    ``floor_ms``, and with ``consistency`` at least sqrt(d² − σ_turns²) for a disagreement of
    ``d_ms`` (the two then within one combined sigma)."""
    s = max(float(surf_sigma_ms), float(floor_ms))
    if consistency:
        s = max(s, float(np.sqrt(max(d_ms**2 - float(turn_sigma_ms) ** 2, 0.0))))
    return s


def _rejoin_joint_with_widened_surfaces(cal, turn, cc) -> None:
    """The joint fit's offset ``cal`` (the turns' ``turn`` as its prior) joined again with the
    surfaces' own sigma widened (:func:`_surface_sigma_for_join` with ``cc``'s floor and
    consistency): the Gaussian marginal of the offset, the turns' times the surfaces' own. As
    it was when the surfaces' own is prior-dominated or its sigma is not widened."""
    own = _surfaces_own_offset(cal, turn)
    if own is None:
        return
    s_t = float(turn.sigma_ms)
    d_ms = (own[0] - float(turn.offset_ns)) * 1e-6
    s_w = _surface_sigma_for_join(d_ms, s_t, own[1], cc.surface_time_sigma_floor_ms,
                                  cc.surface_time_consistency)
    if not s_w > own[1]:
        return
    w = s_w**2 / (s_t**2 + s_w**2)  # the turns' weight
    _log_join("joint rejoined", before_ms=cal.time_offset_ns * 1e-6, surf_sigma_ms=own[1],
              surf_sigma_widened_ms=s_w, turns_weight=w)
    cal.time_offset_ns = int(round(float(turn.offset_ns) + (1 - w) * d_ms * 1e6))
    cal.time_offset_sigma_ms = float(1 / np.sqrt(1 / s_t**2 + 1 / s_w**2))


def _join_with_surfaces(turn_ns, turn_sigma_ms, surfaces, max_surface_sigma_ms,
                        surface_sigma_floor_ms=0.0, consistency=False):
    """(offset_ns, sigma_ms, joined): the turns' offset joined by inverse variance with the
    surfaces' own ``surfaces`` ((offset_ns, sigma_ms) or None) when that is within
    ``max_surface_sigma_ms`` and agrees (within 3 sigma); else the turns' alone. The surfaces'
    sigma it is weighed with: :func:`_surface_sigma_for_join` (``surface_sigma_floor_ms``,
    ``consistency``; by default its own)."""
    m, s = float(turn_ns), float(turn_sigma_ms)
    if surfaces is None:
        return m, s, False
    m_s, s_s = surfaces
    d_ms = (m_s - m) * 1e-6
    if not (s_s <= max_surface_sigma_ms and abs(d_ms) < 3 * np.hypot(s, s_s)):
        return m, s, False
    if surface_sigma_floor_ms > 0 or consistency:
        s_s = _surface_sigma_for_join(d_ms, s, s_s, surface_sigma_floor_ms, consistency)
    w = s_s**2 / (s**2 + s_s**2)  # the turns' weight
    return m + (1 - w) * d_ms * 1e6, float(1 / np.sqrt(1 / s**2 + 1 / s_s**2)), True


def _turns_after_surfaces(rec, seg, orient, ext, cfg, cal, surfaces, off_ns, notes,
                          sweeps=None):
    """The time offset [ns] with the turns measured again, de-skewed by the surfaces' fit's
    lever arm and mount ``ext`` (``orient`` at the offset so far, ``off_ns``): the new turns'
    offset joined by inverse variance with the surfaces' own (``surfaces``, the first turns'
    prior out) when that is sure and agrees, else the new turns' alone; ``off_ns`` when the
    new turns are unsure. ``cal``'s offset, sigma and method follow."""
    cc = cfg.calibration
    again = _turns_time_offset(rec, seg, orient, ext, cfg, sweeps)
    if not again.sigma_ms <= cc.max_turns_time_offset_sigma_ms:
        _log_join("after", turns_ms=again.offset_ns * 1e-6, turns_sigma_ms=again.sigma_ms,
                  fit_ms=off_ns * 1e-6, unsure=True, before_ms=off_ns * 1e-6)
        notes.append(f"turns' time offset after the surfaces' fit unsure (σ "
                     f"{again.sigma_ms:.1f} ms): kept {off_ns * 1e-6:.2f} ms")
        return off_ns
    m, s, joined = _join_with_surfaces(again.offset_ns, again.sigma_ms, surfaces,
                                       cc.max_time_offset_sigma_ms,
                                       cc.surface_time_sigma_floor_ms,
                                       cc.surface_time_consistency)
    _log_join("after", turns_ms=again.offset_ns * 1e-6, turns_sigma_ms=again.sigma_ms,
              surf_ms=None if surfaces is None else surfaces[0] * 1e-6,
              surf_sigma_ms=None if surfaces is None else surfaces[1],
              fit_ms=m * 1e-6, fit_sigma_ms=s, joined=joined, before_ms=off_ns * 1e-6)
    how = "turns (after surfaces)" + (" and surfaces" if joined else "")
    notes.append(f"turns' time offset measured again with the surfaces' lever arm: "
                 f"{again.offset_ns * 1e-6:.2f} ± {again.sigma_ms:.2f} ms; "
                 + (f"surfaces' own {surfaces[0] * 1e-6:.2f} ± {surfaces[1]:.2f} ms; "
                    if surfaces is not None else "surfaces' own: prior-dominated; ")
                 + f"{off_ns * 1e-6:.2f} -> {m * 1e-6:.2f} ms")
    cal.time_offset_ns, cal.time_offset_sigma_ms = int(round(m)), s
    cal.time_offset_method = how
    cal.time_offset_observable = bool(s < 0.5)
    cal.turns = {**(cal.turns or {}), "after_surfaces": again.to_dict()}
    return int(round(m))


def _lever_start_from_turns(rec, seg, orient, ext, cfg, notes, sweeps=None):
    """``ext`` with the lever arm the surfaces' fit starts from: on a lidar at least
    ``calibration.side_mount_warn_deg`` from the pan axis, hand-eye's over several stations'
    turns (:func:`calibration.lever_arm_from_turns`, the mount held) when its sigma is below
    ``lever_turn_max_sigma_mm``; else ``ext`` as it is (one station's hand-eye lever arm).
    On such a mount the surfaces hardly move the component along the spin axis (it shifts scan
    planes along themselves) and close a start far off in the scan plane only part way, so the
    start is most of the result (dev seed 87: one station's 148 mm off, the fit's 94 mm)."""
    from .calibration import lever_arm_from_turns, pan_axis_in_imu, spin_axis_from_pan_axis_deg

    cc = cfg.calibration
    b = pan_axis_in_imu(orient, seg.stations)
    tilt = spin_axis_from_pan_axis_deg(b, ext.R_imu_lidar)
    if tilt < cc.side_mount_warn_deg:
        return ext, None
    lt = lever_arm_from_turns(rec.lidar, seg.stations, orient, ext, cfg.num_threads,
                              max_stations=cc.lever_turn_stations,
                              max_pairs=cc.lever_turn_pairs,
                              denoise_firings=cc.range_denoise_firings,
                              sweep_cache=sweeps)
    if lt is None:
        return ext, None
    sig_mm = 1000 * float(np.sqrt(np.max(np.linalg.eigvalsh(lt.cov_m2))))
    if not sig_mm < cc.lever_turn_max_sigma_mm:
        notes.append(f"lever arm from {lt.stations} stations' turns too uncertain (σ "
                     f"{sig_mm:.0f} mm): the fit starts from one station's")
        return ext, None
    notes.append(f"lever-arm fit started from {lt.stations} stations' turns ({lt.pairs} sweep "
                 f"pairs, σ {sig_mm:.1f} mm; lidar spin axis {tilt:.0f}° from the pan axis)")
    return Extrinsic(ext.R_imu_lidar, lt.lever_arm_m, ext.source), lt


def _refit_far_lever(rec, seg, orient, ext, cfg, cal, fit_time, fit_rot, prior, notes,
                     uncertain_start: bool = False, points_cache=None):
    """``cal``, or the lever-arm fit continued from it with split residuals
    (``calibration.lever_refit_split_iterations``) when the lidar is on its side (at least
    ``side_mount_warn_deg`` from the pan axis) and ``cal``'s lever arm ended more than
    ``lever_refit_move_mm`` across the pan axis from its start (``ext``'s), or, with
    ``lever_refit_uncertain_start``, whatever its move when ``uncertain_start`` (the start was
    not the turns' lever arm but one station's hand-eye one: the all-points planes hardly move
    the component along the spin axis, so a start far off there ends far off, dev seed 8399:
    85 -> 83 mm; the movement gate cannot tell that from a converged fit, dev seed 383, whose
    continuation the keep rule below drops).

    The all-points planes sit between a surface and its double and take up part of the gap, so
    a start far off in the scan plane is closed only part way (dev seed 455, 33 x 23 m hall,
    73°, 19.1-cm lever from a zero start: 135 mm off; its turns' lever was too uncertain and
    hand-eye's one-station lever 2 m off). The split residuals (a voxel's later points to its
    earlier points' plane) see the whole gap; run from the start they misplaced a hall's station
    (dev seed 8399), so only here, from a result the usual fit has already brought near. The
    continuation is kept only when it moved the lever arm more than ``lever_refit_keep_mm``
    further: from a converged result the split fit drifts a few mm instead (dev seed 245)."""
    from scipy.spatial.transform import Rotation

    from .calibration import across_axis, spin_axis_from_pan_axis_deg

    cc = cfg.calibration
    if cc.lever_refit_move_mm <= 0:
        return cal
    b = cal.pan_axis_imu
    R = cal.R_imu_lidar if fit_rot else ext.R_imu_lidar
    tilt = spin_axis_from_pan_axis_deg(b, R)
    moved_mm = 1000 * float(np.linalg.norm(across_axis(cal.lever_arm_m - ext.lever_arm_m, b)))
    unsure = bool(uncertain_start and cc.lever_refit_uncertain_start)
    if tilt < cc.side_mount_warn_deg or not (moved_mm > cc.lever_refit_move_mm or unsure):
        return cal
    k = cc.lever_refit_split_iterations
    start = Extrinsic(R, cal.lever_arm_m.copy(), ext.source)
    pps = _points_per_station(seg.stations, orient, R, cfg)
    o = orient.with_offset(cal.time_offset_ns) if fit_time else orient
    try:
        more = _fit_surfaces(rec, seg, o, start, cfg, pps, fit_lever=True, fit_time=fit_time,
                             fit_rotation=fit_rot, split_iterations=k,
                             iterations=k + cc.lever_refit_usual_iterations,
                             points_cache=points_cache, **prior)
    except ValueError:
        return cal
    further_mm = 1000 * float(np.linalg.norm(across_axis(more.lever_arm_m - cal.lever_arm_m, b)))
    keep = further_mm > cc.lever_refit_keep_mm
    why = "" if moved_mm > cc.lever_refit_move_mm else ", an uncertain start (not the turns')"
    notes.append(f"lever-arm fit moved {moved_mm:.0f} mm from its start{why} (lidar spin axis "
                 f"{tilt:.0f}° from the pan axis): continued with {k} split-residual "
                 f"iterations, {further_mm:.0f} mm further: "
                 + ("kept" if keep else "the first kept (it had converged)"))
    if not keep:
        return cal
    more.rotation_change_deg = float(np.degrees(Rotation.from_matrix(
        ext.R_imu_lidar.T @ more.R_imu_lidar).magnitude()))
    return more


def _spin_axis_lever_from_turns(cal, lt, inflation: float, floor_m: float = 0.0) -> None:
    """The lever arm's component along the lidar's spin axis (across the pan axis) in ``cal``:
    the surfaces' and the turns' (``lt``) by inverse variance, the surfaces' sigma there times
    ``inflation`` with ``floor_m`` added in quadrature (a model error: the inflated sigma
    shrinks with the sample, the fit's error there does not; side-room test at 160,000 points:
    3.3 mm off at 1.2 mm); the scan-plane component stays the surfaces'. The surfaces see the spin-axis
    component only at vertical edges, and their fit drifts from its start there while its sigma
    stays small (dev seeds 87, 163: 28 and 20 mm off at sigma 4.5 and 2.6 mm; the turns' 8 and
    9 mm at sigma 9 and 6 mm)."""
    b, U = cal.pan_axis_imu, cal.lever_basis_imu
    z = cal.R_imu_lidar[:, 2]
    w = z - b * (b @ z)
    if U is None or cal.lever_arm_cov_m2 is None or np.linalg.norm(w) < 1e-6:
        return
    w /= np.linalg.norm(w)
    wc = U.T @ w
    wc /= np.linalg.norm(wc)
    var_s = inflation**2 * float(wc @ cal.lever_arm_cov_m2 @ wc) + floor_m**2  # surfaces' [m²]
    var_t = lt.sigma_along_m(w) ** 2  # the turns' [m²]
    if not (var_s > 0 and var_t > 0 and np.isfinite(var_s) and np.isfinite(var_t)):
        return
    k = var_s / (var_s + var_t)  # the turns' weight
    cal.lever_arm_m = cal.lever_arm_m + k * w * float(w @ (lt.lever_arm_m - cal.lever_arm_m))
    P = np.eye(2) - np.outer(wc, wc)
    cov = P @ cal.lever_arm_cov_m2 @ P + (var_s * var_t / (var_s + var_t)) * np.outer(wc, wc)
    cal.lever_arm_cov_m2 = cov
    cal.lever_arm_sigma_m = np.sqrt(np.abs(np.diag(cov)))
    cal.lever_arm_observable = bool(np.all(cal.lever_arm_sigma_m < 0.003))


def _weigh_tilt(rec, seg, orient, ext, cfg, cal, fit_lever, fit_time, prior,
                tilt_sigma_deg: float, points_cache=None) -> tuple[np.ndarray, str]:
    """(R_imu_lidar, note) for a mount tilt the surfaces of ``cal`` (``max_stations``) do not
    pin down: fitted again on up to ``max_tilt_stations`` stations, then mixed with hand-eye's
    (``ext``, sigma ``tilt_sigma_deg``) by inverse variance when the surfaces' sigma, inflated
    by ``tilt_sigma_inflation``, is the smaller; else hand-eye's, as before.

    Hand-eye's tilt is the mean axis of one station's sweep pairs; near a spin axis on the pan
    axis in a small room it was 0.51° off (dev seed 126, 4 x 4 m, 9° mount; its sigma 0.34°)
    where 4 stations' surfaces gave 0.22° (sigma 0.078°) and 8 gave 0.11° (0.051°)."""
    from scipy.spatial.transform import Rotation

    cc = cfg.calibration
    R_he = ext.R_imu_lidar
    if not cc.tilt_from_surfaces or not np.isfinite(cal.rotation_sigma_deg):
        return R_he, ("WARNING: mount tilt poorly observable from the stations' surfaces; "
                      "hand-eye's kept")
    if cc.max_tilt_stations > cc.max_stations and len(seg.stations) > cc.max_stations:
        pps = _points_per_station(seg.stations, orient, ext.R_imu_lidar, cfg)
        more = _fit_surfaces(rec, seg, orient, ext, cfg, pps, fit_lever=fit_lever,
                             fit_time=fit_time, fit_rotation=True,
                             max_stations=cc.max_tilt_stations, points_cache=points_cache,
                             **prior)
        _tilt_spread_sigma(rec, seg, orient, cfg, more, pps, fit_lever, fit_time, prior,
                           points_cache=points_cache)
        if more.rotation_sigma_deg < cal.rotation_sigma_deg:
            cal = more
    s_s = cc.tilt_sigma_inflation * cal.rotation_sigma_deg
    s_h = tilt_sigma_deg
    if not s_s < s_h:
        return R_he, (f"WARNING: mount tilt poorly observable (surfaces σ {s_s:.2f}°, hand-eye "
                      f"σ {s_h:.2f}°); hand-eye's kept")
    # the surfaces' fit moves the tilts only (about axes across the pan axis): the mix is a
    # fraction of that turn
    w = 1.0 if not np.isfinite(s_h) else s_h**2 / (s_h**2 + s_s**2)
    d = Rotation.from_matrix(R_he.T @ cal.R_imu_lidar).as_rotvec()
    R = R_he @ Rotation.from_rotvec(w * d).as_matrix()
    s = s_s if not np.isfinite(s_h) else 1.0 / np.sqrt(1.0 / s_s**2 + 1.0 / s_h**2)
    return R, (f"WARNING: mount tilt poorly observable: the surfaces' ({len(cal.stations)} "
               f"stations, σ {s_s:.2f}°) and hand-eye's (σ {s_h:.2f}°) weighed, "
               f"{np.degrees(np.linalg.norm(w * d)):.2f}° from hand-eye's, σ {s:.2f}°")


def _tilt_spread_sigma(rec, seg, orient, cfg, cal, pps, fit_lever, fit_time, prior,
                       points_cache=None) -> None:
    """``cal``'s tilt sigma raised to the spread of its stations' own fits (each station alone,
    started from ``cal``'s result; the sigma of their mean, the larger of the two tilts) when
    ``calibration.tilt_spread_max_deg`` > 0, the lidar's spin axis lies within it of the pan
    axis, and ``cal`` used at least 3 stations; ``rotation_observable`` follows. The model's
    sigma counts every voxel's residuals as independent; a bias that a station's geometry
    shares over all of its voxels shows only as stations that disagree."""
    import dataclasses

    from scipy.spatial.transform import Rotation

    from .calibration import TILT_OBSERVABLE_SIGMA_DEG, _perp_basis, spin_axis_from_pan_axis_deg
    from .scaleout import _threaded_map, thread_workers

    cc = cfg.calibration
    b = cal.pan_axis_imu
    fitted = set(cal.stations)
    use = [st for st in seg.stations if st.index in fitted]
    if (cc.tilt_spread_max_deg <= 0 or len(use) < 3
            or spin_axis_from_pan_axis_deg(b, cal.R_imu_lidar) > cc.tilt_spread_max_deg):
        return
    start = Extrinsic(cal.R_imu_lidar, cal.lever_arm_m.copy(), "calibrated rotation")
    o = orient.with_offset(cal.time_offset_ns) if fit_time else orient
    U = _perp_basis(cal.R_imu_lidar.T @ b)  # the seen tilts (lidar frame)
    def alone(st):  # the station's own tilt against the joint one (2,) [rad], or None
        try:
            one = _fit_surfaces(rec, dataclasses.replace(seg, stations=[st]), o, start, cfg,
                                pps, fit_lever=fit_lever, fit_time=fit_time,
                                fit_rotation=True, max_stations=1, points_cache=points_cache,
                                iterations=cc.tilt_spread_iterations, **prior)
        except ValueError:
            return None
        return U.T @ Rotation.from_matrix(cal.R_imu_lidar.T @ one.R_imu_lidar).as_rotvec()

    # the stations side by side, one a thread (each fit then runs on one)
    d = [x for x in _threaded_map(alone, [(st,) for st in use],
                                  thread_workers(cfg.num_threads, len(use))) if x is not None]
    if len(d) < 3:
        return
    d = np.array(d)
    s_deg = float(np.degrees(np.sqrt(np.max(np.var(d, axis=0, ddof=1)) / len(d))))
    cal.tilt_spread_sigma_deg = s_deg
    if s_deg > cal.rotation_sigma_deg:
        cal.rotation_sigma_deg = s_deg
        cal.rotation_observable = bool(s_deg < TILT_OBSERVABLE_SIGMA_DEG)


def effective_calibration(ext: Extrinsic, orient: ImuOrientation, pc, cal) -> dict:
    """The calibration the run used, each value with its source and (when estimated) its
    uncertainty and observability (written as calibration.json)."""
    lever_src = "config" if pc.extrinsic.lever_arm_m is not None else (
        "data" if cal is not None and cal.lever_arm_sigma_m is not None
        and np.all(np.isfinite(cal.lever_arm_sigma_m)) else "default (0)")
    out = {
        "q_imu_lidar": ext.q_imu_lidar_wxyz,
        "lever_arm_m": [float(v) for v in ext.lever_arm_m],
        "imu_time_offset_s": orient.time_offset_ns * 1e-9,
        "source": {
            "q_imu_lidar": "config" if pc.extrinsic.q_imu_lidar is not None else (
                "default (identity)" if ext.source == "default" else
                "data (hand-eye, tilts refined)" if cal is not None
                and np.isfinite(cal.rotation_sigma_deg) else "data (hand-eye)"),
            "lever_arm_m": lever_src,
            "imu_time_offset_s": "config" if pc.imu_time_offset_s is not None else (
                "data" if cal is not None and np.isfinite(cal.time_offset_sigma_ms)
                else "default (0)")},
    }
    if cal is not None:
        out["estimate"] = cal.to_dict()
    return out


def _write_outputs(res: ReconstructResult, cfg: ReconstructConfig, orient: ImuOrientation,
                   background=None) -> list:
    """The run's files (see the module docstring); with ``background`` (an executor), the
    Foxglove MCAP is written there: returns the futures to wait for."""
    pending = []
    out, oc = res.outdir, cfg.output
    slam = res.slam
    main = [k for k in range(len(res.fragments)) if slam.component[k] == 0]
    # merged map in the map frame (z up); float32 (µm at 100 m), as the voxel filter takes it
    parts = []
    for k in main:
        T = slam.T_optimized[k]
        p = res.fragments[k].points @ T[:3, :3].T.astype(np.float32)
        p += T[:3, 3].astype(np.float32)
        parts.append(p)
    allp = np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)
    merged = voxel_downsample(allp, oc.map_voxel_m, cfg.num_threads) if len(allp) else allp
    centroids = merged
    if oc.smooth_radius_m > 0 and len(merged) > 10:
        merged = mls_smooth(merged, oc.smooth_radius_m, cfg.num_threads, oc.smooth_fit_voxel_m)
    res.map_points = len(merged)
    # survey attributes (intensity, station, label) of the map and the main fragments
    attrs = None
    if oc.write_e57 or oc.write_las != "none":
        from . import survey

        attrs = survey.survey_attributes(res.fragments, main, parts, centroids, merged,
                                         oc.map_voxel_m, oc.survey_labels, cfg.num_threads)
    # the map's fields: x, y, z, and with survey outputs intensity, station, label
    cloud = cloud_io.make_cloud(merged) if attrs is None else cloud_io.make_cloud(
        merged, intensity=attrs.map_intensity, station=attrs.map_station, label=attrs.map_label)
    # every cloud carries its up direction (gravity from the IMU, in the cloud's own frame)
    up_map = map_up(res, main)
    cloud_io.write_ply(out / "map.ply", cloud, up=up_map)
    res.files["map_ply"] = str(out / "map.ply")
    if oc.write_pcd:
        cloud_io.write_pcd(out / "map.pcd", cloud, up=up_map)
        res.files["map_pcd"] = str(out / "map.pcd")
    if oc.write_fragments:
        fdir = out / "fragments"
        fdir.mkdir(exist_ok=True)
        for k, f in enumerate(res.fragments):
            name = f"station_{f.station.index:03d}.ply"
            fields = {}
            if attrs is not None and k in main:
                i = main.index(k)
                fields = {"intensity": attrs.frag_intensity[i], "label": attrs.frag_label[i]}
            cloud_io.write_ply(fdir / name, cloud_io.make_cloud(f.points, **fields),
                               up=f.up_in_lidar)
        res.files["fragments"] = str(fdir)
    # poses
    t_st = res.station_t_ns
    hdr = ("tripod stations: T_map_lidar at each station's middle time; lidar time, UNIX s; "
           "map frame z up")
    outputs.write_tum(out / "stations.tum", t_st[main], slam.T_optimized[main], hdr)
    outputs.write_tum(out / "stations_odometry.tum", t_st[main], slam.T_odometry[main],
                      "odometry only (before the pose graph)")
    traj = trajectory(res, orient, oc.trajectory_hz)
    outputs.write_tum(out / "trajectory.tum", traj[0], traj[1],
                      f"tripod trajectory: T_map_lidar at {oc.trajectory_hz:g} Hz; lidar time, "
                      "UNIX s; carry positions interpolated between stations")
    res.files.update(stations=str(out / "stations.tum"), trajectory=str(out / "trajectory.tum"))
    slam.graph.save_g2o(out / "pose_graph.g2o",
                        slam.graph_result.T_world_node if slam.graph_result else None)
    res.files["pose_graph"] = str(out / "pose_graph.g2o")
    dump_config(cfg, out / "config.yaml")
    res.files["config"] = str(out / "config.yaml")
    # the effective calibration: loads back with --calibration (q_imu_lidar, lever_arm_m)
    outputs.write_json(out / "calibration.json", res.calibration)
    res.files["calibration"] = str(out / "calibration.json")
    if attrs is not None and oc.write_las != "none":
        from ..io.las import write_las

        write_las(out / f"map.{oc.write_las}", survey.map_las(merged, attrs))
        res.files["las"] = str(out / f"map.{oc.write_las}")
    if attrs is not None and oc.write_e57:
        from ..io.e57 import write_e57

        write_e57(out / "stations.e57",
                  survey.station_scans(res.fragments, main, slam.T_optimized[main], attrs))
        res.files["e57"] = str(out / "stations.e57")
    if oc.write_mcap:
        # fragments at 5 cm in the MCAP: enough to inspect, light to load
        frags_out = [voxel_downsample(res.fragments[k].points, 0.05, cfg.num_threads)
                     for k in main]
        args = (out / "reconstruction.mcap", merged, int(t_st[-1]), list(t_st[main]),
                slam.T_optimized[main], frags_out, traj)
        if background is None:
            outputs.write_foxglove_mcap(*args)
        else:
            pending.append(background.submit(outputs.write_foxglove_mcap, *args))
        res.files["mcap"] = str(out / "reconstruction.mcap")
    return pending


def map_up(res: ReconstructResult, main: list[int]) -> np.ndarray:
    """The up direction in the map frame (3,): the mean of the main stations' IMU up turned by
    their optimised poses (R_map_lidar · R_world_lidar^T · e_z; +z when the graph kept the
    stations level, as it should)."""
    ups = [res.slam.T_optimized[k][:3, :3] @ res.fragments[k].up_in_lidar for k in main]
    u = np.sum(ups, axis=0) if ups else np.array([0.0, 0.0, 1.0])
    n = float(np.linalg.norm(u))
    return u / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])


def summary(res: ReconstructResult) -> dict:
    """Numbers of a run (result.json and the results table)."""
    slam = res.slam
    loops = [e for e in slam.edges if e.kind == "loop"]
    g = slam.graph_result
    # graph edges are the edges between stations of the map, in order
    main = set(int(k) for k in np.flatnonzero(slam.component == 0))
    in_graph = [e for e in slam.edges if e.i in main and e.j in main]
    rej = {"loop": 0, "odometry": 0}
    if g is not None:
        for e, ok in zip(in_graph, g.edge_inlier):
            if not ok:
                rej["loop" if e.kind == "loop" else "odometry"] += 1
    return {
        "recording": res.recording.source,
        "recording_s": res.recording.duration_s,
        "processing_s": res.processing_s,
        "processing_cpu_s": res.processing_cpu_s,
        "engine": res.engine,
        "stage_s": {k: v for k, v in res.stage_s.items() if k != "_cpu"},
        "stage_cpu_s": res.stage_s.get("_cpu", {}),
        "lidar_packets": len(res.recording.lidar),
        "imu_samples": len(res.recording.imu) if res.recording.imu else 0,
        "hour_source": res.recording.hour_source,
        "stations": len(res.fragments),
        "disconnected_stations": slam.disconnected,
        "marks": len(res.recording.marks),
        "imu_time_offset_ms": res.time_offset_ns * 1e-6,
        "calibration": res.calibration,
        "host_minus_lidar_ms": res.host_minus_lidar_ns * 1e-6,
        "extrinsic": {"q_imu_lidar": res.extrinsic.q_imu_lidar_wxyz,
                      "lever_arm_m": res.extrinsic.lever_arm_m.tolist(),
                      "source": res.extrinsic.source},
        "odometry_edges": sum(e.kind == "odometry" for e in slam.edges),
        "loop_candidates": slam.loop_candidates,
        "loop_edges": len(loops),
        "loop_edges_rejected": rej["loop"],
        "odometry_edges_rejected": rej["odometry"],
        "graph_converged": bool(g.converged) if g else None,
        "map_points": res.map_points,
        "truncated": res.recording.truncated,
        "notes": res.notes,
        "files": res.files,
    }
