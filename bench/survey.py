# SPDX-License-Identifier: BSD-3-Clause
"""What the survey deliverables (stations.e57, map.laz, labels) cost ``tripod reconstruct``.

One simulated capture (``tripod simulate``, cached), reconstructed three times in one process:
survey files off; E57 + LAZ without labels; E57 + LAZ with the segmenter's labels (the first
run that imports torch, as the CLI would). Prints the fragments and outputs stage times and the
processing / recording ratio of each.

    .venv/bin/python bench/survey.py --scene room --stations 12
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="room")
    ap.add_argument("--stations", type=int, default=6)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-reconstruct"))
    args = ap.parse_args()

    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.pipeline import reconstruct
    from tripod_processor.reconstruction.placement import load_extrinsic_file
    from tripod_processor.sim import SimConfig, simulate
    from tripod_shared.config_io import load_config

    cap = args.work / f"{args.scene}-{args.stations}-{args.seed}"
    if not (cap / "meta.json").is_file():
        simulate(SimConfig.model_validate({"scene": args.scene, "stations": args.stations,
                                           "seed": args.seed}), cap)
    q, lever = load_extrinsic_file(cap / "gt" / "calibration.json")
    base = {"placement.extrinsic.q_imu_lidar": q, "placement.extrinsic.lever_arm_m": lever,
            "output.report": False}
    runs = [("survey off", {"output.write_e57": False, "output.write_las": "none"}),
            ("E57 + LAZ, no labels", {"output.survey_labels": False}),
            ("E57 + LAZ + labels", {"output.survey_labels": True})]
    print(f"{args.scene}, {args.stations} stations, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    for name, extra in runs:
        cfg = load_config(ReconstructConfig, overrides={**base, **extra})
        t0 = time.perf_counter()
        res = reconstruct(cap, args.work / f"survey-{name.split()[0]}", cfg, quiet=True)
        wall = time.perf_counter() - t0
        s, cpu = res.stage_s, res.stage_s["_cpu"]
        print(f"{name:>22}: fragments {s['fragments']:.2f} s ({cpu['fragments']:.2f} CPU), "
              f"outputs {s['outputs']:.2f} s ({cpu['outputs']:.2f} CPU), all stages "
              f"{res.processing_s:.2f} s ({res.processing_cpu_s:.2f} CPU; call {wall:.2f} s), "
              f"processing/recording {res.processing_s / res.recording.duration_s:.3f} "
              f"(CPU {res.processing_cpu_s / res.recording.duration_s:.3f}); "
              f"map {res.map_points:,} points")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
