# SPDX-License-Identifier: BSD-3-Clause
"""``tripod batch``: many recordings, one Ray task each.

``discovery`` (paths → recordings: daemon-split MCAP groups, pcap + IMU log pairs, simulator
folders), ``tasks`` (one recording's reconstruction, as a Ray task runs it: the library function
of ``tripod reconstruct``), ``manifest`` (skip what is up to date), ``runner`` (the Ray engine:
local or a cluster), ``index`` (index.md / index.html / batch.json). With ``merge``, the
finished recordings are then joined into one model (:mod:`..reconstruction.merge`) in
``OUTDIR/merged/``.
"""

from __future__ import annotations

import time
from pathlib import Path

from .discovery import BatchRecording, discover
from .index import write_index
from .manifest import config_hash
from .runner import BatchResult, run_batch

__all__ = ["BatchRecording", "BatchResult", "batch_reconstruct", "discover", "merged_folder",
           "run_batch", "write_index"]


def merged_folder(outdir: str | Path, recs: list[BatchRecording]) -> Path:
    """``OUTDIR/merged`` (``merged-model`` when a recording is called ``merged``)."""
    names = {r.name for r in recs}
    return Path(outdir) / ("merged" if "merged" not in names else "merged-model")


def batch_reconstruct(recs: list[BatchRecording], outdir: str | Path, cfg, *, workers: int = 1,
                      address: str | None = None, max_retries: int = 2, force: bool = False,
                      split_large: int = 0, on_done=None, merge=None, on_merge=None
                      ) -> BatchResult:
    """Reconstruct ``recs`` (from :func:`discover`) with the reconstruction config ``cfg``
    into ``outdir/<name>/``, then write the index. ``cfg.num_threads`` is each task's CPU
    count on the engine. ``split_large``: a recording of at least that many stations runs its
    fragments and registrations as further tasks on the engine (0: never; the same outputs).

    ``merge``: a :class:`~..reconstruction.merge.MergeConfig` to join every finished recording
    into one model in :func:`merged_folder` (``res.merge`` holds its
    :class:`~..reconstruction.merge.MergeResult`; ``on_merge(step, done, total)`` progress).
    """
    from tripod_shared.config_io import dump_config

    outdir = Path(outdir)
    cpus = max(int(cfg.num_threads), 1)
    t0 = time.time_ns()
    res = run_batch(recs, outdir, cfg.model_dump(mode="json"), config_hash(dump_config(cfg)),
                    workers=workers, address=address, cpus_per_task=cpus,
                    max_retries=max_retries, force=force, split_large=split_large,
                    on_done=on_done)
    meta = {"engine": res.engine, "wall_s": res.wall_s, "engine_start_s": res.engine_start_s,
            "started_unix_ns": t0, "notes": res.notes}
    if merge is not None:
        from ..reconstruction.merge import merge_recordings, merge_summary

        done = [o for o in res.outcomes if o["status"] in ("done", "skipped")]
        t1 = time.perf_counter()
        if done:
            res.merge = merge_recordings([o["outdir"] for o in done], merged_folder(outdir, recs),
                                         merge, [o["name"] for o in done], progress=on_merge)
            summ = merge_summary(res.merge)
            meta["merge"] = {"folder": str(res.merge.outdir), "wall_s": time.perf_counter() - t1,
                             **{k: summ[k] for k in ("stations", "merged_stations", "components",
                                                     "links_kept", "recording_pairs_joined",
                                                     "recording_pairs_left_out",
                                                     "recording_pairs_proximity")}}
        else:
            res.notes.append("merge: no finished recording to merge")
    write_index(outdir, res.outcomes, meta)
    return res
