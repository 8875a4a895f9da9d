# SPDX-License-Identifier: BSD-3-Clause
"""Batch benchmark: ``tripod batch`` over N small simulated recordings on the default local Ray
engine, 1 worker against 2 (one CPU and one reconstruction thread per task), side by side.

Reports per run: wall time (engine start included, and without it), recordings per minute, the
throughput ratio 2 vs 1 workers, and the load average before and after (the machine may be
shared: a busy machine caps the ratio, whatever the engine does). Outputs of both runs are
compared (station poses byte for byte).

    .venv/bin/python bench/batch.py                       # 8 recordings, 3 stations each
    .venv/bin/python bench/batch.py --recordings 4 --stations 2
Captures are cached under --work (default /tmp/tripod-bench-batch).
"""

from __future__ import annotations

import argparse
import os
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=8)
    ap.add_argument("--stations", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-batch"))
    args = ap.parse_args(argv)

    from rich.console import Console
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
    con = Console(width=140)
    con.print(t)
    (r1, r2) = rows[0][1], rows[1][1]
    ratio = r1.wall_s / r2.wall_s
    ratio_run = (r1.wall_s - r1.engine_start_s) / (r2.wall_s - r2.engine_start_s)
    same = all((Path(a["outdir"]) / "stations.tum").read_bytes()
               == (Path(b["outdir"]) / "stations.tum").read_bytes()
               for a, b in zip(r1.outcomes, r2.outcomes) if a["status"] == b["status"] == "done")
    con.print(f"throughput 2 vs 1 workers: {ratio:.2f}x (engine start excluded: {ratio_run:.2f}x); "
              f"station poses identical between the runs: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
