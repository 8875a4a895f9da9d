# SPDX-License-Identifier: BSD-3-Clause
"""``tripod register --method heightmaps``: global registration by plan-heightmap matching."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ._common import EXIT_FAILED, fail, unit_hint


def register_heightmaps_cmd(source: Path, target: Path, output: Path | None, threads: int,
                            dumps, source_up: str | None = None, target_up: str | None = None
                            ) -> None:
    """Segment both clouds, match their plan heightmaps, print the JSON result.

    Each cloud's up direction comes from ``source_up`` / ``target_up`` ("X,Y,Z", the command
    line) or else its file (``tripod up`` header comment); with one the cloud is levelled
    before matching and the answer turned back into its frame, without one it must be roughly
    z up (the floor plane then absorbs a small tilt)."""
    import numpy as np

    from ..io import clouds as cloud_io
    from ..scene.gravity import parse_up
    from ..scene.heightmap_registration import register_by_heightmaps

    ups, up_from = [], []
    try:
        src_c, src_meta = cloud_io.read_cloud_meta(source)
        tgt_c, tgt_meta = cloud_io.read_cloud_meta(target)
        src = cloud_io.xyz(src_c, dtype=np.float32)
        tgt = cloud_io.xyz(tgt_c, dtype=np.float32)
        for given, meta in ((source_up, src_meta), (target_up, tgt_meta)):
            ups.append(parse_up(given) if given else meta.up)
            up_from.append("--up" if given else "file" if meta.up is not None else "none")
    except (OSError, ValueError) as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    t0 = time.perf_counter()
    try:
        r = register_by_heightmaps(src, tgt, num_threads=threads, source_up=ups[0],
                                   target_up=ups[1])
    except ValueError as exc:
        fail(f"heightmap registration: {exc}")
    out = {"source": str(source), "target": str(target), "method": "heightmaps",
           "up": {"source": None if ups[0] is None else np.round(ups[0], 9).tolist(),
                  "source_from": up_from[0],
                  "target": None if ups[1] is None else np.round(ups[1], 9).tolist(),
                  "target_from": up_from[1]},
           "T_target_source": np.round(r.T_target_source, 9).tolist(),
           "success": bool(r.success), "image_score": r.score,
           "structure_fitness": r.structure_fitness,
           "free_space_violation": r.free_space_violation, "ambiguity": r.ambiguity,
           "twin_ambiguity": r.twin_ambiguity, "consistent_ratio": r.consistent_ratio,
           "height_observed": r.height_observed,
           "proposer": r.proposer, "hypotheses": r.hypotheses,
           "fitness": r.fitness, "inlier_rmse_m": r.inlier_rmse, "hu_distance": r.hu_distance,
           "stage_seconds": {k: round(v, 4) for k, v in r.stages.items()},
           "wall_time_s": time.perf_counter() - t0}
    text = dumps(out)
    print(text)
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text + "\n")
        output.with_name(output.stem + ".options.json").write_text(
            json.dumps({"method": "heightmaps", "threads": threads, "source_up": source_up,
                        "target_up": target_up}, indent=2))
    if not r.success:  # exit 1 as for a failed local or global registration
        fail("heightmap registration did not pass its check (too little verified overlap, free "
             "space seen through, or an equally good answer elsewhere, e.g. a turned twin)" + unit_hint(src, tgt),
             code=EXIT_FAILED)
