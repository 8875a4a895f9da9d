# SPDX-License-Identifier: BSD-3-Clause
"""One recording's reconstruction as a self-contained job: what a Ray task runs.

The job is plain data (paths as strings, the config as a dict) so it pickles to any node; the
task calls the same library function as ``tripod reconstruct``
(:func:`tripod_processor.reconstruction.pipeline.reconstruct`) and returns a plain dict.
A recording that cannot be reconstructed returns ``status="failed"`` with a one-line error
(it never raises, so one bad recording never stops the others); a worker process that dies is
a system failure that Ray retries (``max_retries``), and the retried task starts from an
empty output folder. A recording of at least ``job["split_large"]`` stations runs its
fragments and registrations as further tasks on the same engine (nested Ray tasks; a task
waiting for them gives its CPU back meanwhile).
"""

from __future__ import annotations

import os
import resource
import shutil
import socket
import time
import traceback
from pathlib import Path

from . import manifest


def job_of(rec, outdir: Path, cfg_dict: dict, cfg_hash: str) -> dict:
    """The job for one :class:`~.discovery.BatchRecording`."""
    return {"name": rec.name, "kind": rec.kind, "inputs": [str(p) for p in rec.inputs],
            "imu": str(rec.imu) if rec.imu else None, "files": [str(p) for p in rec.files],
            "outdir": str(outdir), "config": cfg_dict, "config_sha256": cfg_hash}


def _one_line(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__


def reconstruct_recording(job: dict) -> dict:
    """Reconstruct one recording into ``job['outdir']`` and write its manifest.

    Returns {name, status: "done" | "failed", error, summary, outdir, wall_s, host, pid}.
    """
    from ..reconstruction.config import ReconstructConfig
    from ..reconstruction.inputs import RecordingError
    from ..reconstruction.pipeline import reconstruct, summary

    t0 = time.perf_counter()
    out = Path(job["outdir"])
    base = {"name": job["name"], "outdir": str(out), "host": socket.gethostname(),
            "pid": os.getpid()}
    try:
        # a previous attempt (failed, killed, other inputs) leaves nothing behind
        if out.exists():
            shutil.rmtree(out)
        fingerprint = manifest.input_fingerprint([Path(p) for p in job["files"]])
        cfg = ReconstructConfig.model_validate(job["config"])
        inputs = [Path(p) for p in job["inputs"]]
        engine = None
        if job.get("split_large", 0) > 0:
            # a large recording's fragments and registrations: tasks on the batch's engine
            from ..reconstruction.engine import RayEngine

            engine = RayEngine.attached(job.get("cpus_per_task", 1), job.get("max_retries", 2))
        res = reconstruct(inputs[0] if len(inputs) == 1 else inputs, out, cfg,
                          imu_log=job["imu"], quiet=True, engine=engine,
                          engine_min_stations=job.get("split_large", 0))
        # the worker's peak RSS so far [MB] (a worker runs tasks one after another: at least
        # this recording's peak)
        summ = {**_small(summary(res)),
                "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
        manifest.write_manifest(out, fingerprint, job["config_sha256"], summ)
        return {**base, "status": "done", "error": "", "summary": summ,
                "wall_s": time.perf_counter() - t0}
    except (RecordingError, OSError, ValueError) as exc:
        err = _one_line(exc)
    except Exception as exc:  # noqa: BLE001  a bug on one recording must not stop the batch
        tb = traceback.extract_tb(exc.__traceback__)
        err = _one_line(exc) + (f" ({Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else "")
    return {**base, "status": "failed", "error": err, "summary": {},
            "wall_s": time.perf_counter() - t0}


_KEYS = ("recording_s", "processing_s", "processing_cpu_s", "engine", "stations",
         "disconnected_stations", "odometry_edges", "loop_edges", "map_points", "ate_cm", "ate_deg", "files", "notes")


def _small(summ: dict) -> dict:
    """The numbers the batch table and index show (JSON-safe)."""
    return {k: summ[k] for k in _KEYS if k in summ}
