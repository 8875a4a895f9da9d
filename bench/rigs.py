# SPDX-License-Identifier: BSD-3-Clause
"""Rig-family benchmark (issue 12): tripod reconstruct, no calibration given, on random rigs.

Captures of random rigs drawn by ``sim.rigs.draw_rig`` (mount tilt 0-90 deg, lever arm 0-20 cm,
IMU latency 0-10 ms + jitter, motor or hand-turned pans with pauses and reversals, 0.9-1.2
turns, stations of 4-60 s, carries of 2-30 s, small rooms to 40 m halls and 30 m corridors,
single and dual returns).

Per capture: station precision / recall (a found station matches a true one when their
lidar-time spans overlap by more than half of the true one, and neither overlaps another by
more than min(1 s, 20 % of the true station): a station cut in two or two merged are errors),
station ATE (RMSE after alignment, matched by lidar time to the truth, IMU latency on),
map-to-mesh median, the calibration errors (lever arm across the pan axis [mm], IMU time
offset [ms], mount rotation [deg]; n/a where the result carries no estimate) and the
processing / recording time (CPU time of every stage, all threads; and wall time, which is
the issue's measure on 2 cores: run with ``--jobs 1`` on an idle machine, the load average is
printed). Then the summary and the worst capture with its parameters.

Seeds: test seeds (``sim.rigs.TEST_SEEDS``, from 10000) by default, development seeds
(0-9999) with ``--dev``. Never tune on the test seeds.

    .venv/bin/python bench/rigs.py                  # 50 captures on test seeds 10000..10049
    .venv/bin/python bench/rigs.py --quick          # 4 captures on development seeds 0..3
    .venv/bin/python bench/rigs.py --dev -n 20 --jobs 2 --json rigs.json
    .venv/bin/python bench/rigs.py --dev --seeds 3 17 --set stations.min_station_s=2
    .venv/bin/python bench/rigs.py --dev --seeds 0 1 2 --jobs 1 --stages   # cost, 2 cores
Simulated captures are cached under --work (default /tmp/tripod-bench-rigs/sim) by seed and a
hash of their config; reconstructions are redone every run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

#: bump when the simulator's output (meta.json truth included) for one config changes: it
#: invalidates the capture cache (2: time offset truth with the lidar receive delay)
SIM_CACHE_VERSION = 2


# ------------------------------------------------------------------------- simulation (cached)
def capture_dir(work: Path, seed: int) -> tuple[Path, object]:
    from tripod_processor.sim.rigs import draw_rig

    cfg = draw_rig(seed)
    key = hashlib.sha256(json.dumps([SIM_CACHE_VERSION, cfg.model_dump(mode="json")],
                                    sort_keys=True).encode()).hexdigest()[:12]
    return work / "sim" / f"seed{seed}-{key}", cfg


def simulate_cached(work: Path, seed: int, threads: int) -> tuple[Path, object, float]:
    """(capture dir, SimConfig, CPU seconds spent simulating; 0 when cached)."""
    from tripod_processor.sim import simulate

    d, cfg = capture_dir(work, seed)
    if (d / "meta.json").is_file():
        return d, cfg, 0.0
    tmp = d.with_name(d.name + f".tmp{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    c0 = time.process_time()
    simulate(cfg, tmp, nthreads=threads)
    cpu = time.process_time() - c0
    shutil.rmtree(d, ignore_errors=True)
    os.replace(tmp, d)
    return d, cfg, cpu


def _true_offset_ms(cap: Path, res) -> float | None:
    """The IMU time offset the processor should find, in its own terms (its clock map), when
    it can say (``evaluation.true_time_offset_ns``); else None (meta.json's value is used)."""
    from tripod_processor.reconstruction import evaluation

    fn = getattr(evaluation, "true_time_offset_ns", None)
    return None if fn is None else fn(cap, res.recording) * 1e-6


def run_one(work: str, seed: int, threads: int, sets: dict | None = None,
            keep: bool = False) -> dict:
    """Simulate (cached) and reconstruct one rig; every number of its row. The reconstruction's
    outputs (~400 MB per capture) are deleted once scored unless ``keep``."""
    from tripod_processor.sim.rigs import describe
    from tripod_processor.sim.truth import (calibration_errors, match_stations, score_stations,
                                            true_station_spans)

    work_p = Path(work)
    row: dict = {"seed": seed}
    try:
        cap, cfg, sim_cpu = simulate_cached(work_p, seed, threads)
        row.update(rig=describe(cfg), sim_cpu_s=sim_cpu, config=cfg.model_dump(mode="json"))
        meta = json.loads((cap / "meta.json").read_text())
        truth = meta["truth"]
        row["recording_s"] = meta["derived"]["duration_s"]

        from tripod_shared.config_io import load_config

        from tripod_processor.reconstruction.config import ReconstructConfig
        from tripod_processor.reconstruction.evaluation import evaluate_run, load_sim_truth
        from tripod_processor.reconstruction.inputs import RecordingError
        from tripod_processor.reconstruction.pipeline import reconstruct, summary

        rcfg = load_config(ReconstructConfig, overrides={"num_threads": threads,
                                                         **(sets or {})})
        out = work_p / "out" / f"seed{seed}"
        shutil.rmtree(out, ignore_errors=True)
        true_iv = true_station_spans(truth)
        try:
            res = reconstruct(cap, out, rcfg, quiet=True)
        except RecordingError as exc:
            row.update(error=str(exc).splitlines()[0][-160:],
                       **match_stations(true_iv, np.zeros((0, 2), np.int64)))
            return row
        row.update(score_stations(truth, [[s.start_ns, s.end_ns]
                                          for s in res.segmentation.stations]))
        truth_t, truth_T = load_sim_truth(cap)
        acc = evaluate_run(out, truth_t, truth_T, cap / "mesh.ply")
        result = summary(res)
        row.update(ate_cm=acc["ate_cm"], ate_deg=acc["ate_deg"],
                   m2m_mm=10 * acc["map_to_mesh_median_cm"],
                   proc_cpu_s=res.processing_cpu_s, proc_wall_s=res.processing_s,
                   load_1min=os.getloadavg()[0],
                   stage_wall_s={k: v for k, v in res.stage_s.items() if k != "_cpu"},
                   stage_cpu_s=dict(res.stage_s.get("_cpu", {})),
                   **calibration_errors(result, truth, _true_offset_ms(cap, res)))
        row.update(_lever_by_mount(result, truth))
        # the lever-arm fit's own account (where a start or refit rule fired)
        row["lever_notes"] = [n for n in res.notes if "lever-arm fit" in n or "lever arm from" in n]
    except Exception as exc:  # a crash is a result of the benchmark too: one line, counted
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:160]
        row["trace"] = traceback.format_exc(limit=3)
        row.setdefault("recall", 0.0)
        row.setdefault("precision", 0.0)
    finally:
        if not keep:
            shutil.rmtree(Path(work) / "out" / f"seed{seed}", ignore_errors=True)
    return row


def _lever_by_mount(result: dict, truth: dict) -> dict:
    """The lever arm's error [mm] along the lidar's spin axis and in its scan plane (across the
    pan axis, the true mount's axes) with the run's own sigmas there (``lever_arm_by_mount``):
    how honest the sigma is. Empty where the run did not estimate the lever arm."""
    from scipy.spatial.transform import Rotation

    cal = result.get("calibration") or {}
    bm = (cal.get("estimate") or {}).get("lever_arm_by_mount") or {}
    if (cal.get("lever_arm_m") is None or (cal.get("source") or {}).get("lever_arm_m") != "data"
            or "sigma_along_spin_axis_m" not in bm):
        return {}
    q = truth["q_imu_lidar_wxyz"]
    z = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()[:, 2]
    b = np.asarray(truth["pan_axis_imu"], float)
    w = z - b * (b @ z)
    if np.linalg.norm(w) < 1e-6:
        return {}
    w /= np.linalg.norm(w)
    d = np.asarray(cal["lever_arm_m"], float) - np.asarray(truth["lever_arm_imu_m"], float)
    return {"lever_spin_mm": 1000 * abs(float(w @ d)),
            "lever_spin_sigma_mm": 1000 * bm["sigma_along_spin_axis_m"],
            "lever_plane_mm": 1000 * abs(float(np.cross(b, w) @ d)),
            "lever_plane_sigma_mm": 1000 * bm["sigma_in_scan_plane_m"]}


# ------------------------------------------------------------------------- report
def _f(x, fmt: str) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not np.isfinite(x)) else fmt.format(x)


def _badness(r: dict) -> tuple:
    return (r.get("recall", 0) < 1 or r.get("precision", 0) < 1 or "error" in r,
            r.get("ate_cm") or 0.0, r.get("ate_deg") or 0.0)


def _stats(rows: list[dict], key: str) -> tuple[float | None, float | None]:
    v = [r[key] for r in rows if r.get(key) is not None]
    return (float(np.median(v)), float(np.max(v))) if v else (None, None)


def print_report(rows: list[dict], title: str, wall_s: float, jobs: int) -> None:
    from rich.console import Console
    from rich.table import Table

    rows = sorted(rows, key=lambda r: r["seed"])
    threads = max(1, (os.cpu_count() or 1) // jobs)
    threads_note = f"{threads} threads, {jobs} job(s) on {os.cpu_count()} CPUs"
    t = Table(title=title)
    for c in ("seed", "rig", "stations found/true (P R)", "ATE cm / °", "map→mesh mm",
              "lever mm", "time ms", "mount °", "proc/rec CPU", "proc/rec wall"):
        t.add_column(c, justify="left" if c in ("rig",) else "right")
    for r in rows:
        if "tp" in r:
            st = f"{r['found']}/{r['true']} ({r['precision']:.0%} {r['recall']:.0%})"
            if r.get("splits") or r.get("merges"):
                st += f" split {r['splits']} merged {r['merges']}"
        else:
            st = "n/a"
        ratio = (r["proc_cpu_s"] / r["recording_s"]) if r.get("proc_cpu_s") else None
        ratio_w = (r["proc_wall_s"] / r["recording_s"]) if r.get("proc_wall_s") else None
        t.add_row(str(r["seed"]), r.get("rig", "?") + (f" [red]{r['error']}" if "error" in r
                                                       else ""),
                  st, f"{_f(r.get('ate_cm'), '{:.2f}')} / {_f(r.get('ate_deg'), '{:.3f}')}",
                  _f(r.get("m2m_mm"), "{:.1f}"), _f(r.get("lever_mm"), "{:.1f}"),
                  _f(r.get("time_ms"), "{:.2f}"), _f(r.get("mount_deg"), "{:.2f}"),
                  _f(ratio, "{:.3f}"), _f(ratio_w, "{:.3f}"))
    con = Console(width=230)
    con.print(t)
    n = len(rows)
    tp = sum(r.get("tp", 0) for r in rows)
    n_true = sum(r.get("true", 0) for r in rows)
    n_found = sum(r.get("found", 0) for r in rows)
    perfect = sum(1 for r in rows if r.get("recall") == 1.0 and r.get("precision") == 1.0)
    for r in rows:
        if r.get("proc_cpu_s"):
            r["ratio"] = r["proc_cpu_s"] / r["recording_s"]
        if r.get("proc_wall_s"):
            r["ratio_wall"] = r["proc_wall_s"] / r["recording_s"]
    s = Table(title=f"summary over {n} captures")
    for c in ("measure", "median", "worst", "goal (issue 12)"):
        s.add_column(c, justify="left" if c == "measure" else "right")
    s.add_row("station recall (pooled)", f"{tp / max(n_true, 1):.1%}", f"{tp}/{n_true}", "100 %")
    s.add_row("station precision (pooled)", f"{tp / max(n_found, 1):.1%}", f"{tp}/{n_found}",
              "100 %")
    s.add_row("captures with every station right", f"{perfect}/{n}", "", f"{n}/{n}")
    for key, name, fmt, goal in (("ate_cm", "station ATE (cm)", "{:.2f}", "≤ 1"),
                                 ("ate_deg", "station ATE (°)", "{:.3f}", "≤ 0.1"),
                                 ("m2m_mm", "map→mesh median (mm)", "{:.1f}", "≤ 10"),
                                 ("lever_mm", "lever arm across the axis (mm)", "{:.1f}", "≤ 5"),
                                 ("time_ms", "IMU time offset error (ms)", "{:.2f}", "≤ 1"),
                                 ("mount_deg", "mount rotation (°)", "{:.2f}", ""),
                                 ("ratio", "processing / recording (CPU, all threads)", "{:.3f}",
                                  ""),
                                 ("ratio_wall", f"processing / recording (wall, {threads_note})",
                                  "{:.3f}", "< 0.1 on 2 cores")):
        med, worst = _stats(rows, key)
        s.add_row(name, _f(med, fmt), _f(worst, fmt), goal)
    errors = [r for r in rows if "error" in r]
    s.add_row("runs that stopped with an error", str(len(errors)), "", "0")
    con.print(s)
    worst = max(rows, key=_badness)
    print(f"worst capture: seed {worst['seed']}: {worst.get('rig', '?')}; "
          f"stations {worst.get('found', '?')}/{worst.get('true', '?')}, ATE "
          f"{_f(worst.get('ate_cm'), '{:.2f}')} cm / {_f(worst.get('ate_deg'), '{:.3f}')}°"
          + (f"; error: {worst['error']}" if "error" in worst else ""))
    rec = sum(r.get("recording_s", 0) for r in rows)
    sim = sum(r.get("sim_cpu_s", 0) for r in rows)
    proc = sum(r.get("proc_cpu_s", 0) for r in rows)
    print(f"recording {rec:.0f} s in all; CPU: simulation {sim:.0f} s (0 when cached), "
          f"reconstruction {proc:.0f} s; wall {wall_s:.0f} s with {jobs} jobs on "
          f"{os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f} (1-min load after each capture: "
          f"max {max((r.get('load_1min', 0.0) for r in rows), default=0.0):.1f}; wall figures "
          "hold on an idle machine only)")


def print_stages(rows: list[dict]) -> None:
    """Wall / CPU seconds of each reconstruction stage per capture, and the sums."""
    from rich.console import Console
    from rich.table import Table

    rows = [r for r in sorted(rows, key=lambda r: r["seed"]) if r.get("stage_cpu_s")]
    names: list[str] = []
    for r in rows:
        names += [k for k in r["stage_cpu_s"] if k not in names]
    t = Table(title="stages: wall / CPU [s] (CPU: all threads)")
    for c in ["stage"] + [str(r["seed"]) for r in rows] + ["all"]:
        t.add_column(c, justify="left" if c == "stage" else "right")
    for k in names + ["total"]:
        cells = []
        for r in rows:
            w = (sum(r["stage_wall_s"].values()) if k == "total"
                 else r["stage_wall_s"].get(k, 0.0))
            c = sum(r["stage_cpu_s"].values()) if k == "total" else r["stage_cpu_s"].get(k, 0.0)
            cells.append(f"{w:.1f} / {c:.1f}")
        W = sum(sum(r["stage_wall_s"].values()) if k == "total" else r["stage_wall_s"].get(k, 0)
                for r in rows)
        C = sum(sum(r["stage_cpu_s"].values()) if k == "total" else r["stage_cpu_s"].get(k, 0)
                for r in rows)
        t.add_row(k, *cells, f"{W:.1f} / {C:.1f}")
    rec = sum(r["recording_s"] for r in rows)
    t.add_row("÷ recording", *[f"{sum(r['stage_wall_s'].values()) / r['recording_s']:.3f} / "
                               f"{sum(r['stage_cpu_s'].values()) / r['recording_s']:.3f}"
                               for r in rows],
              f"{sum(sum(r['stage_wall_s'].values()) for r in rows) / max(rec, 1e-9):.3f} / "
              f"{sum(sum(r['stage_cpu_s'].values()) for r in rows) / max(rec, 1e-9):.3f}")
    Console(width=230).print(t)


def main(argv: list[str] | None = None) -> int:
    from tripod_processor.sim.rigs import DEV_SEEDS, TEST_SEEDS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=50, help="number of captures (default 50)")
    ap.add_argument("--dev", action="store_true",
                    help=f"development seeds (from {DEV_SEEDS.start}) instead of test seeds "
                         f"(from {TEST_SEEDS.start})")
    ap.add_argument("--first", type=int, help="first seed (default: the first of the range)")
    ap.add_argument("--seeds", type=int, nargs="+", help="these seeds (instead of -n/--first)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="reconstruct config override, e.g. stations.min_station_s=2 "
                         "(YAML value; repeatable)")
    ap.add_argument("--quick", action="store_true",
                    help="4 captures, development seeds (a smoke run never looks at test seeds)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="captures in parallel (processes); threads per job = CPUs / jobs")
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-rigs"))
    ap.add_argument("--json", type=Path, help="also write the rows as JSON")
    ap.add_argument("--keep", action="store_true",
                    help="keep each reconstruction's outputs under WORK/out/seedN (~400 MB each; "
                         "deleted once scored by default)")
    ap.add_argument("--stages", action="store_true",
                    help="also print each stage's wall and CPU time per capture [s]")
    args = ap.parse_args(argv)
    args.dev = args.dev or args.quick
    rng = DEV_SEEDS if args.dev else TEST_SEEDS
    n = 4 if args.quick else args.n
    first = rng.start if args.first is None else args.first
    seeds = args.seeds or list(range(first, first + n))
    n = len(seeds)
    import yaml

    sets = {}
    for kv in args.set:
        if "=" not in kv:
            print(f"--set {kv}: expected KEY=VALUE", file=sys.stderr)
            return 2
        k, v = kv.split("=", 1)
        sets[k.strip()] = yaml.safe_load(v)
    if sets:
        from tripod_shared.config_io import ConfigError, load_config

        from tripod_processor.reconstruction.config import ReconstructConfig

        try:
            load_config(ReconstructConfig, overrides=sets)
        except ConfigError as exc:
            print(f"--set: {exc}", file=sys.stderr)
            return 2
    if not all(s in rng for s in seeds):
        print(f"seeds {seeds[0]}..{seeds[-1]} leave the {'development' if args.dev else 'test'} "
              f"range {rng.start}..{rng.stop - 1}", file=sys.stderr)
        return 2
    args.work.mkdir(parents=True, exist_ok=True)
    jobs = max(1, args.jobs)
    threads = max(1, (os.cpu_count() or 1) // jobs)
    w0 = time.perf_counter()
    rows = []
    if jobs == 1:
        for s in seeds:
            rows.append(run_one(str(args.work), s, threads, sets, args.keep))
            _progress(rows[-1], len(rows), n, w0)
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn")) as ex:
            futs = [ex.submit(run_one, str(args.work), s, threads, sets, args.keep) for s in seeds]
            for f in as_completed(futs):
                rows.append(f.result())
                _progress(rows[-1], len(rows), n, w0)
    wall = time.perf_counter() - w0
    kind = "development" if args.dev else "test"
    extra = f", --set {' '.join(args.set)}" if args.set else ""
    print_report(rows, f"tripod reconstruct on {n} random rigs, {kind} seeds {seeds[0]}.."
                       f"{seeds[-1]}, no calibration given{extra}", wall, jobs)
    if args.stages:
        print_stages(rows)
    if args.json:
        args.json.write_text(json.dumps(sorted(rows, key=lambda r: r["seed"]), indent=2,
                                        default=float) + "\n")
    return 0


def _progress(r: dict, done: int, n: int, w0: float) -> None:
    msg = r.get("error") or (f"P {r.get('precision', 0):.0%} R {r.get('recall', 0):.0%} ATE "
                             f"{_f(r.get('ate_cm'), '{:.2f}')} cm")
    print(f"[{done}/{n} {time.perf_counter() - w0:.0f} s] seed {r['seed']}: {msg}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
