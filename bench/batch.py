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
   (:func:`~tripod_processor.reconstruction.evaluation.evaluate_merge`).

    .venv/bin/python bench/batch.py                       # both parts
    .venv/bin/python bench/batch.py --building none       # throughput only (the wall-clock figure)
    .venv/bin/python bench/batch.py --recordings 0 --building small   # the tests' small building
Captures and outputs are cached under --work (default /tmp/tripod-bench-batch); the building's
reconstructions are re-used when up to date (``--force`` to redo them).
"""

from __future__ import annotations

import argparse
import os
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


def building(args, con) -> None:
    from rich.table import Table

    from tripod_shared.config_io import load_config
    from tripod_processor.batch import batch_reconstruct, discover, merged_folder
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.evaluation import evaluate_merge
    from tripod_processor.reconstruction.merge import MergeConfig, merge_summary
    from tripod_processor.reconstruction.placement import load_extrinsic_file
    from tripod_processor.sim.survey_building import simulate_survey

    survey = args.work / f"building-{args.building}"
    t0 = time.perf_counter()
    dirs = simulate_survey(survey, args.building, seed=0, pan_s=5.0, nthreads=2,
                           progress=lambda i, n: con.print(f"simulated {i}/{n}"))
    sim_s = time.perf_counter() - t0
    recs, _ = discover(dirs)
    # the rig's mount calibration (the same for every capture), as a user passes --calibration
    q, lever = load_extrinsic_file(dirs[0] / "gt" / "calibration.json")
    cfg = load_config(ReconstructConfig, overrides={
        "num_threads": 1, "output.write_mcap": False, "placement.extrinsic.q_imu_lidar": q,
        "placement.extrinsic.lever_arm_m": lever})
    out = args.work / f"building-{args.building}-out"
    load0 = os.getloadavg()
    res = batch_reconstruct(recs, out, cfg, workers=args.workers, force=args.force,
                            merge=MergeConfig(num_threads=args.workers))
    load1 = os.getloadavg()
    ms = merge_summary(res.merge)
    names = [o["name"] for o in res.outcomes if o["status"] != "failed"]
    ev = evaluate_merge(merged_folder(out, recs), {n: out / n for n in names},
                        {d.name: d for d in dirs})
    rec_cpu = sum(o["summary"].get("processing_cpu_s", 0.0) for o in res.outcomes)
    n_st = ms["stations"]
    t = Table(title=f"merged building ({args.building}): {len(recs)} recordings, {n_st} stations "
                    f"reconstructed; batch {args.workers} workers", header_style="bold")
    t.add_column("figure")
    t.add_column("value", justify="right")
    comps = ms["components"]
    rows = [
        ("stations in the merged model / all", f"{ms['merged_stations']} / {n_st}"),
        ("components (recordings each)", ", ".join(str(len(c["recordings"])) for c in comps)),
        ("station ATE [cm] / [deg]", f"{ev['ate_cm']:.2f} / {ev['ate_deg']:.3f}"),
        ("max station error [cm] / [deg]", f"{ev['max_err_cm']:.2f} / {ev['max_err_deg']:.3f}"),
        ("true links between recordings", str(ev["true_links"])),
        ("links kept / true found / false / weak",
         f"{ev['links_kept']} / {ev['true_links_found']} / {ev['false_links']} / "
         f"{ev['weak_links_kept']}"),
        ("link recall / precision", f"{ev['link_recall']:.3f} / {ev['link_precision']:.3f}"),
        ("recording pairs joined / all",
         f"{ms['recording_pairs_joined']} / {len(ms['recording_pairs'])}"),
        ("reconstruction CPU s (Σ recordings) / per station", f"{rec_cpu:.0f} / "
         f"{rec_cpu / max(n_st, 1):.2f}"),
        ("merge CPU s / wall s", f"{ms['processing_cpu_s']:.0f} / {ms['processing_s']:.0f}"),
        ("merge CPU s by stage", ", ".join(f"{k} {v:.0f}" for k, v in
                                           ms["stage_cpu_s"].items())),
        ("batch wall s (reconstruct + merge)", f"{res.wall_s:.0f}"),
        ("simulation wall s (cached when 0)", f"{sim_s:.0f}"),
        ("load 1 min before / after", f"{load0[0]:.1f} / {load1[0]:.1f}"),
    ]
    for a, b in rows:
        t.add_row(a, b)
    con.print(t)
    for f in ev["false_link_list"][:10]:
        con.print(f"false link: {f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=8, help="throughput part (0: skip it)")
    ap.add_argument("--stations", type=int, default=3)
    ap.add_argument("--building", choices=("full", "small", "none"), default="full")
    ap.add_argument("--workers", type=int, default=2, help="workers of the building's batch")
    ap.add_argument("--force", action="store_true", help="reconstruct the building again")
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-batch"))
    args = ap.parse_args(argv)

    from rich.console import Console

    con = Console(width=140)
    con.print(f"load average {os.getloadavg()}, {os.cpu_count()} CPUs")
    if args.recordings > 0:
        throughput(args, con)
    if args.building != "none":
        building(args, con)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
