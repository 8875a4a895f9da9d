# SPDX-License-Identifier: BSD-3-Clause
"""``tripod batch``: many recordings, one Ray task each.

``discovery`` (paths → recordings: daemon-split MCAP groups, pcap + IMU log pairs, simulator
folders), ``tasks`` (one recording's reconstruction, as a Ray task runs it: the library function
of ``tripod reconstruct``), ``manifest`` (skip what is up to date), ``runner`` (the Ray engine:
local or a cluster), ``index`` (index.md / index.html / batch.json).
"""

from __future__ import annotations

import time
from pathlib import Path

from .discovery import BatchRecording, discover
from .index import write_index
from .manifest import config_hash
from .runner import BatchResult, run_batch

__all__ = ["BatchRecording", "BatchResult", "batch_reconstruct", "discover", "run_batch",
           "write_index"]


def batch_reconstruct(recs: list[BatchRecording], outdir: str | Path, cfg, *, workers: int = 1,
                      address: str | None = None, max_retries: int = 2, force: bool = False,
                      on_done=None) -> BatchResult:
    """Reconstruct ``recs`` (from :func:`discover`) with the reconstruction config ``cfg``
    into ``outdir/<name>/``, then write the index. ``cfg.num_threads`` is each task's CPU
    count on the engine."""
    from tripod_shared.config_io import dump_config

    outdir = Path(outdir)
    cpus = max(int(cfg.num_threads), 1)
    t0 = time.time_ns()
    res = run_batch(recs, outdir, cfg.model_dump(mode="json"), config_hash(dump_config(cfg)),
                    workers=workers, address=address, cpus_per_task=cpus,
                    max_retries=max_retries, force=force, on_done=on_done)
    write_index(outdir, res.outcomes, {"engine": res.engine, "wall_s": res.wall_s,
                                       "engine_start_s": res.engine_start_s,
                                       "started_unix_ns": t0, "notes": res.notes})
    return res
