# SPDX-License-Identifier: BSD-3-Clause
"""``tripod register --method heightmaps``: global registration by plan-heightmap matching."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ._common import EXIT_FAILED, fail, unit_hint


def register_heightmaps_cmd(source: Path, target: Path, output: Path | None, threads: int,
                            dumps) -> None:
    """Segment both clouds, match their plan heightmaps, print the JSON result."""
    import numpy as np

    from ..io import clouds as cloud_io
    from ..scene.heightmap_registration import register_by_heightmaps

    try:
        src = cloud_io.xyz(cloud_io.read_cloud(source), dtype=np.float32)
        tgt = cloud_io.xyz(cloud_io.read_cloud(target), dtype=np.float32)
    except (OSError, ValueError) as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    t0 = time.perf_counter()
    try:
        r = register_by_heightmaps(src, tgt, num_threads=threads)
    except ValueError as exc:
        fail(f"heightmap registration: {exc}")
    out = {"source": str(source), "target": str(target), "method": "heightmaps",
           "T_target_source": np.round(r.T_target_source, 9).tolist(),
           "success": bool(r.success), "image_score": r.score,
           "structure_fitness": r.structure_fitness,
           "free_space_violation": r.free_space_violation, "ambiguity": r.ambiguity,
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
            json.dumps({"method": "heightmaps", "threads": threads}, indent=2))
    if not r.success:  # exit 1 as for a failed local or global registration
        fail("heightmap registration did not pass its check (too little verified overlap, free "
             "space seen through, or an equally good answer elsewhere)" + unit_hint(src, tgt),
             code=EXIT_FAILED)
