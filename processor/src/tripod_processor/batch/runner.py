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

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from . import manifest
from .discovery import BatchRecording
from .tasks import job_of, reconstruct_recording


#: environment variables that size a local worker's thread pools (a cluster's nodes keep their
#: own: Ray sets OMP_NUM_THREADS to a task's CPUs there)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class EngineError(RuntimeError):
    """Ray could not be started or reached (one-line message)."""


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


def _init_ray(workers: int, address: str | None, cpus_per_task: int = 1):
    import ray

    # no usage-stats upload attempt (offline machines), no dashboard, warnings only
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    kw = dict(include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False,
              configure_logging=True)
    if address:
        ray.init(address=address, **kw)
        return ray, f"cluster {address} ({int(ray.cluster_resources().get('CPU', 0))} CPUs)"
    # a local worker's thread pools (OpenMP, OpenBLAS, MKL) as wide as a task's CPUs, not the
    # machine's: N workers on N cores then really run N recordings side by side. The workers
    # inherit the environment of the raylet this starts; the driver's is restored after.
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    for k in THREAD_ENV:
        os.environ.setdefault(k, str(cpus_per_task))
    try:
        # results are small dicts: a small object store spares the shared machine's /dev/shm
        ray.init(num_cpus=workers, object_store_memory=80 * 1024 * 1024, **kw)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return ray, f"local Ray, {workers} worker{'s' if workers != 1 else ''}"


def run_batch(recs: list[BatchRecording], outdir: Path, cfg_dict: dict, cfg_hash: str, *,
              workers: int = 1, address: str | None = None, cpus_per_task: int = 1,
              max_retries: int = 2, force: bool = False,
              on_done: Callable[[dict, int, int], None] | None = None) -> BatchResult:
    """Reconstruct every recording not up to date as its own Ray task.

    ``on_done(outcome, n_finished, n_total)`` is called as each recording finishes (progress).
    """
    t0 = time.perf_counter()
    outdir.mkdir(parents=True, exist_ok=True)
    jobs, skipped = plan(recs, outdir, cfg_dict, cfg_hash, force)
    by_name: dict[str, dict] = {o["name"]: o for o in skipped}
    total = len(recs)
    for o in skipped:
        if on_done:
            on_done(o, len(by_name), total)
    res = BatchResult(outdir, [], engine="none (all up to date)")
    if jobs:
        t_engine = time.perf_counter()
        try:
            ray, res.engine = _init_ray(workers, address, cpus_per_task)
        except Exception as exc:  # noqa: BLE001  Ray raises several types here
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            where = f"the Ray cluster at {address}" if address else "a local Ray instance"
            raise EngineError(f"cannot use {where}: {first}") from None
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
