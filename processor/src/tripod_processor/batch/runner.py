# SPDX-License-Identifier: BSD-3-Clause
"""Run a batch on Ray: one task per recording, up-to-date recordings skipped, results collected
as they finish.

Engine: by default a local Ray instance started for the batch and stopped after it
(``workers`` CPUs, no dashboard, warnings only); with ``address`` (``auto`` or ``HOST:PORT``)
a running cluster, left running. Every node must see the input and output paths at the same
place (a shared file system): the tasks read the inputs and write the outputs themselves, only
small dicts travel through Ray.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..reconstruction.engine import EngineError, start_ray
from . import manifest
from .discovery import BatchRecording
from .tasks import job_of, reconstruct_recording

__all__ = ["BatchResult", "EngineError", "plan", "run_batch"]


@dataclass
class BatchResult:
    """What a batch did: one dict per recording (``status`` done | skipped | failed), in the
    order of discovery, plus the engine's numbers."""

    outdir: Path
    outcomes: list[dict]
    wall_s: float = 0.0
    engine: str = ""
    engine_start_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    merge: object = None  # reconstruction.merge.MergeResult with --merge

    def count(self, status: str) -> int:
        return sum(o["status"] == status for o in self.outcomes)


def plan(recs: list[BatchRecording], outdir: Path, cfg_dict: dict, cfg_hash: str,
         force: bool = False) -> tuple[list[dict], list[dict]]:
    """Split into jobs to run and outcomes already done (skipped: outputs complete, input and
    config unchanged)."""
    jobs, skipped = [], []
    for r in recs:
        rec_out = outdir / r.name
        try:
            fp = manifest.input_fingerprint(r.files)
        except OSError:
            fp = None
        if not force and fp is not None:
            ok, _why = manifest.up_to_date(rec_out, fp, cfg_hash)
            if ok:
                man = manifest.read_manifest(rec_out) or {}
                skipped.append({"name": r.name, "status": "skipped", "error": "",
                                "summary": man.get("summary", {}), "outdir": str(rec_out),
                                "wall_s": 0.0})
                continue
        jobs.append(job_of(r, rec_out, cfg_dict, cfg_hash))
    return jobs, skipped


def _init_ray(workers: int, address: str | None, cpus_per_task: int = 1, split: bool = False):
    # results are small dicts: a small object store spares the shared machine's /dev/shm; a
    # large recording split into tasks keeps its stations' packets and fragments there (spilled
    # to disk past that size)
    return start_ray(workers, address, cpus_per_task, object_store_mb=256 if split else 80)


def run_batch(recs: list[BatchRecording], outdir: Path, cfg_dict: dict, cfg_hash: str, *,
              workers: int = 1, address: str | None = None, cpus_per_task: int = 1,
              max_retries: int = 2, force: bool = False, split_large: int = 0,
              on_done: Callable[[dict, int, int], None] | None = None) -> BatchResult:
    """Reconstruct every recording not up to date as its own Ray task.

    ``split_large``: a recording of at least that many stations (0: none) runs its fragments,
    odometry pairs and loop candidates as further tasks on the same engine
    (:mod:`..reconstruction.scaleout`; the same outputs, byte for byte).
    ``on_done(outcome, n_finished, n_total)`` is called as each recording finishes (progress).
    """
    t0 = time.perf_counter()
    outdir.mkdir(parents=True, exist_ok=True)
    jobs, skipped = plan(recs, outdir, cfg_dict, cfg_hash, force)
    for j in jobs:  # what a recording's own tasks need (large recordings)
        j.update(split_large=split_large, cpus_per_task=cpus_per_task, max_retries=max_retries)
    by_name: dict[str, dict] = {o["name"]: o for o in skipped}
    total = len(recs)
    for o in skipped:
        if on_done:
            on_done(o, len(by_name), total)
    res = BatchResult(outdir, [], engine="none (all up to date)")
    if jobs:
        t_engine = time.perf_counter()
        ray, res.engine = _init_ray(workers, address, cpus_per_task, split_large > 0)
        res.engine_start_s = time.perf_counter() - t_engine
        try:
            task = ray.remote(num_cpus=cpus_per_task, max_retries=max_retries)(
                reconstruct_recording)
            pending = {task.remote(j): j for j in jobs}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    job = pending.pop(ref)
                    try:
                        out = ray.get(ref)
                    except Exception as exc:  # noqa: BLE001  worker died past its retries
                        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                        out = {"name": job["name"], "status": "failed", "summary": {},
                               "error": f"{type(exc).__name__}: {first}",
                               "outdir": job["outdir"], "wall_s": 0.0}
                    by_name[job["name"]] = out
                    if on_done:
                        on_done(out, len(by_name), total)
        finally:
            # stops the local instance; on a cluster, only disconnects (it keeps running)
            ray.shutdown()
    res.outcomes = [by_name[r.name] for r in recs]
    res.wall_s = time.perf_counter() - t0
    return res
