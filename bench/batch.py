# SPDX-License-Identifier: BSD-3-Clause
"""Batch benchmark, side by side:

1. **throughput** — ``tripod batch`` over N small simulated recordings on the default local Ray
   engine, 1 worker against 2 (one CPU and one reconstruction thread per task): wall time
   (engine start included, and without it), recordings per minute, the ratio 2 vs 1 workers,
   the load average before and after (a busy machine caps the ratio whatever the engine
   does); station poses of both runs compared byte for byte;
2. **the merged building** — the digital twin's two-wing building surveyed as 8 recordings
   (223 stations, ``sim.survey_building``), reconstructed by ``tripod batch`` (2 workers) and
   merged (``--merge``), scored against the truth: station ATE over every station (the merged
   frame aligned once), links between recordings found / true / false
   (:func:`~tripod_processor.reconstruction.evaluation.evaluate_merge`);
3. **one recording spread** (``--scaleout N``) — an N-station room reconstructed in process
   and with its fragments and registrations as Ray tasks on ``--workers`` CPUs;
4. **cost growth** (``--growth``, instead of 2) — the building's recordings reconstructed, then
   merged for ~50, ~100, ~200 stations and all, each merge in its own process: CPU, wall and
   peak RSS per size and per step, extrapolated to 10,000 stations.

    .venv/bin/python bench/batch.py                       # both parts
    .venv/bin/python bench/batch.py --building none       # throughput only (the wall-clock figure)
    .venv/bin/python bench/batch.py --recordings 0 --building small   # the tests' small building
    .venv/bin/python bench/batch.py --recordings 0 --building full --growth  # cost growth
    .venv/bin/python bench/batch.py --recordings 0 --building none --scaleout 8  # one recording

Captures and outputs are cached under --work (default /tmp/tripod-bench-batch); the building's
reconstructions are re-used when up to date (``--force`` to redo them).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path


def captures(work: Path, n: int, stations: int) -> list[Path]:
    from tripod_processor.sim import SimConfig, simulate

    out = []
    for k in range(n):
        d = work / "captures" / f"room-{stations}-{k}"
        if not (d / "meta.json").is_file():
            simulate(SimConfig.model_validate({"scene": "room", "stations": stations,
                                               "seed": 100 + k}), d, nthreads=2)
        out.append(d)
    return out


def throughput(args, con) -> None:
    from rich.table import Table

    from tripod_shared.config_io import load_config
    from tripod_processor.batch import batch_reconstruct, discover
    from tripod_processor.reconstruction.config import ReconstructConfig

    recs_paths = captures(args.work, args.recordings, args.stations)
    recs, _ = discover(recs_paths)
    cfg = load_config(ReconstructConfig, overrides={"num_threads": 1,
                                                    "output.write_mcap": False})
    rows = []
    for workers in (1, 2):
        load0 = os.getloadavg()
        res = batch_reconstruct(recs, args.work / f"out-{workers}", cfg, workers=workers,
                                force=True)
        load1 = os.getloadavg()
        failed = res.count("failed")
        task_s = sum(o["wall_s"] for o in res.outcomes)
        rows.append((workers, res, load0, load1, failed, task_s))

    t = Table(title=f"tripod batch: {len(recs)} recordings x {args.stations} stations "
                    f"(room), local Ray, {os.cpu_count()} CPUs", header_style="bold")
    for c in ("workers", "wall s", "Ray start s", "rec/min", "rec/min w/o start", "Σ task wall s",
              "Σ task CPU s", "failed", "load 1 min before/after"):
        t.add_column(c, justify="right")
    for workers, res, l0, l1, failed, task_s in rows:
        run_s = res.wall_s - res.engine_start_s
        cpu_s = sum(o["summary"].get("processing_cpu_s", 0.0) for o in res.outcomes)
        t.add_row(str(workers), f"{res.wall_s:.1f}", f"{res.engine_start_s:.1f}",
                  f"{60 * len(recs) / res.wall_s:.2f}", f"{60 * len(recs) / run_s:.2f}",
                  f"{task_s:.1f}", f"{cpu_s:.1f}", str(failed), f"{l0[0]:.1f} / {l1[0]:.1f}")
    con.print(t)
    (r1, r2) = rows[0][1], rows[1][1]
    ratio = r1.wall_s / r2.wall_s
    ratio_run = (r1.wall_s - r1.engine_start_s) / (r2.wall_s - r2.engine_start_s)
    same = all((Path(a["outdir"]) / "stations.tum").read_bytes()
               == (Path(b["outdir"]) / "stations.tum").read_bytes()
               for a, b in zip(r1.outcomes, r2.outcomes) if a["status"] == b["status"] == "done")
    con.print(f"throughput 2 vs 1 workers: {ratio:.2f}x (engine start excluded: {ratio_run:.2f}x); "
              f"station poses identical between the runs: {same}")


def building_config(calibration: Path):
    """The building's reconstruction config: the rig's mount calibration (the same for every
    capture, as a user passes ``--calibration``), one thread per task, and only the outputs the
    merge reads (no MCAP, PCD, per-recording report or map smoothing: CPU for 223 stations)."""
    from tripod_shared.config_io import load_config
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.placement import load_extrinsic_file

    q, lever = load_extrinsic_file(calibration)
    return load_config(ReconstructConfig, overrides={
        "num_threads": 1, "output.write_mcap": False, "output.write_pcd": False,
        "output.report": False, "output.smooth_radius_m": 0.0,
        "placement.extrinsic.q_imu_lidar": q, "placement.extrinsic.lever_arm_m": lever})


def merge_config(args):
    """The building's merge settings: ``--workers`` threads, ``--shortlist-k`` when given."""
    from tripod_processor.reconstruction.merge import MergeConfig

    extra = {} if args.shortlist_k is None else {"shortlist_k": args.shortlist_k}
    return MergeConfig(num_threads=args.workers, **extra)


def building(args, con) -> None:
    from rich.table import Table

    from tripod_processor.batch import batch_reconstruct, discover, merged_folder
    from tripod_processor.reconstruction.evaluation import evaluate_merge
    from tripod_processor.reconstruction.merge import merge_summary
    from tripod_processor.sim.survey_building import simulate_survey

    survey = args.survey or args.work / f"building-{args.building}"
    t0 = time.perf_counter()
    dirs = simulate_survey(survey, args.building, seed=0, pan_s=5.0, nthreads=2,
                           progress=lambda i, n: con.print(f"simulated {i}/{n}"))
    sim_s = time.perf_counter() - t0
    if args.only:
        keep = set(args.only.split(","))
        dirs = [d for d in dirs if d.name in keep]
    recs, _ = discover(dirs)
    cfg = building_config(dirs[0] / "gt" / "calibration.json")
    out = args.work / f"building-{args.building}-out"
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    if args.merge_only:
        # the reconstructions already in OUT (whatever config made them) merged again: for a
        # change to the merge only
        from tripod_processor.reconstruction.merge import merge_recordings

        done = [r for r in recs if (out / r.name / "result.json").is_file()]
        merge = merge_recordings([out / r.name for r in done], merged_folder(out, recs),
                                 merge_config(args),
                                 names=[r.name for r in done])
        outcomes = [{"name": r.name, "status": "reused", "summary": json.loads(
            (out / r.name / "result.json").read_text())} for r in done]
    else:
        res = batch_reconstruct(recs, out, cfg, workers=args.workers, force=args.force,
                                merge=merge_config(args))
        merge, outcomes = res.merge, res.outcomes
    wall = time.perf_counter() - t0
    # the merge runs in this process (the reconstructions in Ray workers): its peak RSS
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    load1 = os.getloadavg()
    ms = merge_summary(merge)
    names = [o["name"] for o in outcomes if o["status"] != "failed"]
    ev = evaluate_merge(merged_folder(out, recs), {n: out / n for n in names},
                        {d.name: d for d in dirs})
    rec_cpu = sum(o["summary"].get("processing_cpu_s", 0.0) for o in outcomes)
    n_st = ms["stations"]
    # recording pairs the shortlist left out although they share true links
    lost_true = sum(1 for x in ev["pairs"].values()
                    if not x.get("shortlisted", True) and x["true_links"])
    t = Table(title=f"merged building ({args.building}): {len(recs)} recordings, {n_st} stations "
                    f"reconstructed; batch {args.workers} workers", header_style="bold")
    t.add_column("figure")
    t.add_column("value", justify="right")
    comps = ms["components"]
    rows = [
        ("stations in the merged model / all", f"{ms['merged_stations']} / {n_st}"),
        ("components (recordings each)", ", ".join(str(len(c["recordings"])) for c in comps)),
        ("station ATE cm / deg", f"{ev['ate_cm']:.2f} / {ev['ate_deg']:.3f}"),
        ("max station error cm / deg", f"{ev['max_err_cm']:.2f} / {ev['max_err_deg']:.3f}"),
        ("true links between recordings", str(ev["true_links"])),
        ("links kept / true found / false / weak",
         f"{ev['links_kept']} / {ev['true_links_found']} / {ev['false_links']} / "
         f"{ev['weak_links_kept']}"),
        ("link recall / precision", f"{ev['link_recall']:.3f} / {ev['link_precision']:.3f}"),
        ("recording pairs joined / all (of them by proximity)",
         f"{ms['recording_pairs_joined']} / {len(ms['recording_pairs'])} "
         f"({ms.get('recording_pairs_proximity', 0)})"),
        ("recording pairs shortlisted / left out (true pairs left out)",
         f"{ms['recording_pairs_shortlisted']} / {ms['recording_pairs_left_out']} "
         f"({lost_true})"),
        ("reconstruction CPU s (Σ recordings) / per station", f"{rec_cpu:.0f} / "
         f"{rec_cpu / max(n_st, 1):.2f}"),
        ("merge CPU s / wall s", f"{ms['processing_cpu_s']:.0f} / {ms['processing_s']:.0f}"),
        ("merge CPU s by stage", ", ".join(f"{k} {v:.0f}" for k, v in
                                           ms["stage_cpu_s"].items())),
        ("merge: bench process peak RSS MB", f"{peak_mb:.0f}"),
        ("batch wall s (reconstruct + merge)" if not args.merge_only else
         "merge wall s (reconstructions re-used as they are)", f"{wall:.0f}"),
        ("simulation wall s (cached when 0)", f"{sim_s:.0f}"),
        ("load 1 min before / after", f"{load0[0]:.1f} / {load1[0]:.1f}"),
    ]
    for a, b in rows:
        t.add_row(a, b)
    con.print(t)
    for f in ev["false_link_list"][:10]:
        con.print(f"false link: {f}")
    (args.work / f"building-{args.building}-eval.json").write_text(json.dumps(
        {"eval": ev, "merge": {k: v for k, v in ms.items() if k != "recording_pairs"},
         "peak_rss_mb": peak_mb, "load": [load0, load1]}, indent=1, default=str))
    detail_tables(con, ev)


def detail_tables(con, ev: dict) -> None:
    """Per recording (which one carries the error) and per recording pair (its hypothesis
    against the truth, its links) of :func:`evaluate_merge`'s result."""
    from rich.table import Table

    r = Table(title="per recording: station error in the merged model (one alignment), the same "
                    "stations aligned on their own, and the reconstruction alone",
              header_style="bold")
    for c in ("recording", "stations", "ATE cm / deg (merged)", "max cm", "own-aligned cm",
              "reconstruction alone cm / deg"):
        r.add_column(c, justify="right")
    for n, x in ev["recordings"].items():
        r.add_row(n, f"{x['merged_stations']} / {x['stations']}",
                  f"{x['ate_cm']:.1f} / {x['ate_deg']:.2f}", f"{x['max_err_cm']:.1f}",
                  f"{x['own_ate_cm']:.1f}", f"{x['alone_ate_cm']:.2f} / {x['alone_ate_deg']:.3f}")
    con.print(r)
    p = Table(title="per recording pair: hypothesis error against the truth, links true / kept / "
                    "true found / false / weak, twin check", header_style="bold")
    for c in ("pair", "joined", "hypothesis err m / deg", "true", "kept", "found", "false",
              "weak", "twin scores (ratio)"):
        p.add_column(c, justify="right")
    for ab, x in ev["pairs"].items():
        tw = x.get("twin", {})
        joined = (x.get("accepted") or "-") if not tw.get("cycle") else "cycle-unjoined"
        if not x.get("shortlisted", True):
            joined = f"left out ({x.get('score', 0):.2f})"
        if tw.get("ambiguous"):
            joined = "ambiguous"
        if x.get("accepted") == "proximity":  # the proximity pass linked it after all
            joined = f"proximity (was {joined})"
        err = (f"{x['hyp_err_m']:.2f} / {x['hyp_err_deg']:.2f}" if "hyp_err_m" in x else "-")
        sc = ", ".join(f"{k}: {v:.2f}" for k, v in tw.get("scores", {}).items())
        p.add_row(ab.replace("|", " x "), joined, err, str(x["true_links"]), str(x["kept"]),
                  str(x["true_found"]), str(x["false"]), str(x["weak"]),
                  f"{sc} ({tw['ratio']:.2f})" if sc else "-")
    con.print(p)


def scaleout(args, con) -> None:
    """One recording's heavy steps (fragments, odometry pairs, loop candidates) in process
    against Ray tasks on a local instance of ``--workers`` CPUs: wall and driver CPU per stage,
    station poses compared byte for byte (``tripod reconstruct`` against ``--workers N``)."""
    from rich.table import Table

    from tripod_shared.config_io import load_config
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.engine import ray_engine
    from tripod_processor.reconstruction.pipeline import reconstruct

    from tripod_processor.reconstruction.placement import load_extrinsic_file

    (cap,) = captures(args.work, 1, args.scaleout)
    q, lever = load_extrinsic_file(cap / "gt" / "calibration.json")  # no calibration stage
    cfg = load_config(ReconstructConfig, overrides={
        "num_threads": 1, "output.write_mcap": False, "output.report": False,
        "placement.extrinsic.q_imu_lidar": q, "placement.extrinsic.lever_arm_m": lever})
    steps = ("fragments", "odometry", "slam")
    runs = []
    for name in ("in process", f"Ray, {args.workers} workers"):
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        eng = ray_engine(args.workers, None, 1) if name.startswith("Ray") else None
        t_eng = time.perf_counter() - t0
        try:
            res = reconstruct(cap, args.work / f"scaleout-{args.scaleout}-{len(runs)}", cfg,
                              quiet=True, engine=eng)
        finally:
            if eng is not None:
                eng.close()
        runs.append((name, res, t_eng, time.perf_counter() - t0, load0, os.getloadavg()[0]))
    t = Table(title=f"one recording, {args.scaleout} stations (room): heavy steps in process vs "
                    f"Ray tasks, {os.cpu_count()} CPUs", header_style="bold")
    for c in ("engine", *[f"{k} wall s" for k in steps], "3 steps wall s", "Ray start s",
              "total wall s", "driver CPU s (3 steps)", "load 1 min before/after"):
        t.add_column(c, justify="right")
    for name, res, t_eng, wall, l0, l1 in runs:
        w = [res.stage_s.get(k, 0.0) for k in steps]
        cpu = sum(res.stage_s["_cpu"].get(k, 0.0) for k in steps)
        t.add_row(name, *[f"{x:.1f}" for x in w], f"{sum(w):.1f}", f"{t_eng:.1f}",
                  f"{wall:.1f}", f"{cpu:.1f}", f"{l0:.1f} / {l1:.1f}")
    con.print(t)
    a, b = (sum(r[1].stage_s.get(k, 0.0) for k in steps) for r in runs)
    same = ((runs[0][1].outdir / "stations.tum").read_bytes()
            == (runs[1][1].outdir / "stations.tum").read_bytes())
    con.print(f"heavy steps {a / b:.2f}x faster on {args.workers} workers; station poses "
              f"identical: {same}")


_MERGE_CHILD = """
import json, sys
from tripod_processor.reconstruction.merge import MergeConfig, merge_recordings
dirs, out, threads = json.loads(sys.argv[1]), sys.argv[2], int(sys.argv[3])
merge_recordings(dirs, out, MergeConfig(num_threads=threads))
"""

#: the merge's steps, as its result.json names them (read and submaps: the fragments loaded)
MERGE_STEPS = ("read", "submaps", "hypotheses", "verify", "links", "pose graph", "outputs")


def _prefixes(recs: list[dict], sizes: tuple[int, ...]) -> list[int]:
    """The numbers of the first recordings that reach each size in stations (and all)."""
    acc, out, left = 0, [], list(sizes)
    for k, o in enumerate(recs):
        acc += o["summary"]["stations"]
        while left and acc >= left[0]:
            out.append(k + 1)
            left.pop(0)
    return sorted(set(out + [len(recs)]))


def growth(args, con) -> None:
    """Cost growth with the number of stations: the building's recordings reconstructed
    (``tripod batch``, re-used when up to date), then the merge of its first recordings up to
    ~50, ~100, ~200 stations and all, each merge in its own process at nice 0 of this one: CPU
    time (user + system) and peak RSS from the kernel's accounting of that process (wait4),
    wall time, and each step's CPU and wall from its result.json. The reconstruction's cost is
    per recording (independent tasks): Σ CPU from the batch and the largest worker peak RSS.
    Ends with the extrapolation to ``--extrapolate`` stations (each step's growth exponent
    between the two largest sizes)."""
    import json
    import math
    import subprocess
    import sys

    from rich.table import Table

    from tripod_processor.batch import batch_reconstruct, discover
    from tripod_processor.sim.survey_building import simulate_survey

    survey = args.survey or args.work / f"building-{args.building}"
    dirs = simulate_survey(survey, args.building, seed=0, pan_s=5.0, nthreads=2,
                           progress=lambda i, n: con.print(f"simulated {i}/{n}"))
    recs_found, _ = discover(dirs)
    cfg = building_config(dirs[0] / "gt" / "calibration.json")
    out = args.work / f"building-{args.building}-out"
    load0 = os.getloadavg()
    res = batch_reconstruct(recs_found, out, cfg, workers=args.workers, force=args.force)
    recs = [o for o in res.outcomes if o["status"] != "failed"]
    con.print(f"batch: {len(recs)} recordings ({res.count('skipped')} up to date), "
              f"{res.wall_s:.0f} s wall, load {load0[0]:.1f} -> {os.getloadavg()[0]:.1f}")
    rows = []
    for n in _prefixes(recs, tuple(int(x) for x in args.sizes.split(","))):
        dest = args.work / f"growth-{n}"
        l0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _MERGE_CHILD,
                                 json.dumps([o["outdir"] for o in recs[:n]]), str(dest), "1"])
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        if status != 0:
            con.print(f"merge of {n} recordings failed (status {status})")
            continue
        r = json.loads((dest / "result.json").read_text())
        rec = recs[:n]
        rows.append({
            "recordings": n, "stations": r["stations"],
            "rec_cpu": sum(o["summary"].get("processing_cpu_s", 0.0) for o in rec),
            "rec_wall": sum(o["summary"].get("processing_s", 0.0) for o in rec),
            "rec_rss": max((o["summary"].get("worker_peak_rss_mb", 0.0) for o in rec),
                           default=0.0),
            "cpu": ru.ru_utime + ru.ru_stime, "wall": wall, "rss": ru.ru_maxrss / 1024,
            "step_cpu": r["stage_cpu_s"], "step_wall": r["stage_s"],
            "load": (l0, os.getloadavg()[0])})

    t = Table(title=f"cost growth: {args.building} building, the first recordings merged "
                    "(one process each, 1 thread); CPU = user + system", header_style="bold")
    for c in ("recordings", "stations", "reconstruct CPU s Σ (/station)",
              "reconstruct worker peak RSS MB", "merge CPU s (/station)", "merge wall s",
              "merge peak RSS MB (/station)", "load 1 min before/after"):
        t.add_column(c, justify="right")
    for x in rows:
        st = x["stations"]
        t.add_row(str(x["recordings"]), str(st), f"{x['rec_cpu']:.0f} ({x['rec_cpu'] / st:.2f})",
                  f"{x['rec_rss']:.0f}", f"{x['cpu']:.0f} ({x['cpu'] / st:.2f})",
                  f"{x['wall']:.0f}", f"{x['rss']:.0f} ({x['rss'] / st:.1f})",
                  f"{x['load'][0]:.1f} / {x['load'][1]:.1f}")
    con.print(t)
    if len(rows) < 2:
        return
    # per step: CPU (wall) at each size; growth exponent b (cost ~ N^b) between the two largest
    # sizes and the CPU extrapolated with it; memory extrapolated linearly (a fixed base)
    a, b = rows[-2], rows[-1]
    target = args.extrapolate
    lr = math.log(b["stations"] / a["stations"])

    def power(ca: float, cb: float) -> tuple[str, float]:
        if cb <= 0:
            return "-", 0.0
        # a step that did nothing at the smaller size (one recording: no pair): assumed to
        # grow with the pairs of recordings, N^2
        e = math.log(cb / ca) / lr if ca > 0 else 2.0
        return f"{e:.2f}" + ("" if ca > 0 else " (assumed)"), cb * (target / b["stations"]) ** e

    e = Table(title=f"per step: CPU s (wall s) at each size, growth exponent b between "
                    f"{a['stations']} and {b['stations']} stations, CPU extrapolated to "
                    f"{target:,} stations", header_style="bold")
    e.add_column("step")
    for x in rows:
        e.add_column(f"{x['stations']} st.", justify="right")
    for c in ("b", f"CPU h at {target:,}"):
        e.add_column(c, justify="right")
    # the reconstruction: independent per recording, linear in stations by construction
    rec_x = b["rec_cpu"] / b["stations"] * target
    e.add_row("reconstruct (Σ recordings)", *[f"{x['rec_cpu']:.0f} ({x['rec_wall']:.0f})"
                                              for x in rows],
              "1 (independent)", f"{rec_x / 3600:.1f}")
    worst = ("reconstruct", rec_x)
    total = 0.0
    for k in MERGE_STEPS:
        ex, cx = power(a["step_cpu"].get(k, 0.0), b["step_cpu"].get(k, 0.0))
        total += cx
        e.add_row(f"merge: {k}", *[f"{x['step_cpu'].get(k, 0.0):.1f} "
                                   f"({x['step_wall'].get(k, 0.0):.0f})" for x in rows],
                  ex, f"{cx / 3600:.1f}")
        if cx > worst[1]:
            worst = (f"merge: {k}", cx)
    slope = (b["rss"] - a["rss"]) / max(b["stations"] - a["stations"], 1)
    rss_x = b["rss"] + slope * (target - b["stations"])
    e.add_row("merge peak RSS MB", *[f"{x['rss']:.0f}" for x in rows],
              f"+{slope:.1f} MB/station", f"{rss_x / 1024:.0f} GB")
    con.print(e)
    con.print(f"at {target:,} stations: reconstruction {rec_x / 3600:.1f} CPU h (spread over "
              f"workers), merge {total / 3600:.1f} CPU h in one process, bounded in time by "
              f"{worst[0]}; merge memory ~{rss_x / 1024:.0f} GB in one process")
    con.print(f"load average after: {os.getloadavg()}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=8, help="throughput part (0: skip it)")
    ap.add_argument("--stations", type=int, default=3)
    ap.add_argument("--building", choices=("full", "small", "none"), default="full")
    ap.add_argument("--workers", type=int, default=2, help="workers of the building's batch")
    ap.add_argument("--force", action="store_true", help="reconstruct the building again")
    ap.add_argument("--only", default="",
                    help="building: these recordings only (comma-separated names, e.g. "
                         "03-west-north,04-west-south)")
    ap.add_argument("--merge-only", action="store_true",
                    help="building: merge the reconstructions already in WORK/building-SIZE-out "
                         "again (whatever config made them; no batch): for a change to the merge")
    ap.add_argument("--shortlist-k", type=int, default=None,
                    help="building: merge.shortlist_k (each recording's best partners verified; "
                         "0: every pair; default the merge's)")
    ap.add_argument("--growth", action="store_true",
                    help="instead of the building's score: cost growth of the reconstruction "
                         "and the merge for ~50, ~100, ~200 and all stations")
    ap.add_argument("--scaleout", type=int, default=0, metavar="STATIONS",
                    help="one recording of that many stations, in process vs Ray tasks on "
                         "--workers (0: skip)")
    ap.add_argument("--sizes", default="50,100,200",
                    help="growth: station counts the first recordings are merged up to")
    ap.add_argument("--extrapolate", type=int, default=10_000,
                    help="stations the growth is extrapolated to")
    ap.add_argument("--survey", type=Path, default=None,
                    help="the building's captures (default WORK/building-SIZE; simulated there "
                         "when missing)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-batch"))
    args = ap.parse_args(argv)

    from rich.console import Console

    con = Console(width=140)
    con.print(f"load average {os.getloadavg()}, {os.cpu_count()} CPUs")
    if args.recordings > 0:
        throughput(args, con)
    if args.scaleout > 0:
        scaleout(args, con)
    if args.building != "none":
        if args.growth:
            growth(args, con)
        else:
            building(args, con)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
