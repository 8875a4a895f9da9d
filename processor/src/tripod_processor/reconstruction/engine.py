# SPDX-License-Identifier: BSD-3-Clause
"""Where a reconstruction's heavy independent steps run: in this process (the default), or as
tasks on Ray (``tripod reconstruct --address``, large recordings in ``tripod batch``).

An engine has two calls: ``put(obj)`` (a handle to pass to tasks; on Ray the object is stored
once in the object store and every task that takes its handle reads it from there, zero-copy
for numpy arrays) and ``map(fn, calls)`` (``fn(*args)`` for every ``args`` in ``calls``,
results in the order of ``calls``; ``progress(k)`` as call k finishes). Handles must be
top-level arguments of a call, where Ray resolves them. On Ray, ``fn`` must be a module-level
function (a task ships it by reference); when its result depends on its arguments only, the two
engines give the same bytes.

:func:`start_ray` starts or joins Ray for ``tripod batch`` and ``tripod reconstruct``.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

#: environment variables that size a local worker's thread pools (a cluster's nodes keep their
#: own: Ray sets OMP_NUM_THREADS to a task's CPUs there)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class EngineError(RuntimeError):
    """Ray could not be started or reached (one-line message)."""


class InProcess:
    """Every call in this process, one after the other (the default engine)."""

    name = "in-process"
    slots = 1
    distributed = False

    def put(self, obj: Any) -> Any:
        return obj

    def map(self, fn: Callable, calls: Sequence[tuple],
            progress: Callable[[int], None] | None = None) -> list:
        out = []
        for k, args in enumerate(calls):
            out.append(fn(*args))
            if progress is not None:
                progress(k)
        return out

    def close(self) -> None:
        pass


class RayEngine:
    """Every call a Ray task (``num_cpus=cpus_per_task``; a task whose worker process dies is
    run again, up to ``max_retries`` times; an exception raised by ``fn`` is raised here, as its
    own type). ``owns``: :meth:`close` stops Ray (a local instance started for this run)."""

    distributed = True

    def __init__(self, ray, cpus_per_task: int = 1, max_retries: int = 2, owns: bool = False,
                 name: str = "Ray"):
        self.ray, self.cpus_per_task, self.max_retries = ray, max(int(cpus_per_task), 1), max_retries
        self.owns, self.name = owns, name
        self._remote: dict[Callable, Any] = {}
        self._puts: dict[int, tuple[Any, Any]] = {}

    @classmethod
    def attached(cls, cpus_per_task: int = 1, max_retries: int = 2) -> RayEngine:
        """The Ray this process is already part of (inside a ``tripod batch`` task)."""
        import ray

        return cls(ray, cpus_per_task, max_retries, owns=False, name="Ray (the batch's engine)")

    @property
    def slots(self) -> int:
        """How many tasks the cluster runs at once."""
        cpus = self.ray.cluster_resources().get("CPU", 1)
        return max(int(cpus) // self.cpus_per_task, 1)

    def put(self, obj: Any) -> Any:
        """The object stored once per engine (the same object again gives the same handle)."""
        k = id(obj)
        if k not in self._puts:
            self._puts[k] = (obj, self.ray.put(obj))  # holds obj: its id stays unique
        return self._puts[k][1]

    def map(self, fn: Callable, calls: Sequence[tuple],
            progress: Callable[[int], None] | None = None) -> list:
        if fn not in self._remote:
            self._remote[fn] = self.ray.remote(num_cpus=self.cpus_per_task,
                                               max_retries=self.max_retries)(fn)
        remote = self._remote[fn]
        refs = [remote.remote(*args) for args in calls]
        where = {ref: k for k, ref in enumerate(refs)}
        out: list = [None] * len(refs)
        pending = list(refs)
        while pending:
            ready, pending = self.ray.wait(pending, num_returns=1)
            for ref in ready:
                k = where[ref]
                out[k] = self.ray.get(ref)
                if progress is not None:
                    progress(k)
        return out

    def close(self) -> None:
        self._puts.clear()
        if self.owns:
            self.ray.shutdown()


def chunks(n: int, slots: int, per_slot: int = 3) -> list[range]:
    """``range(n)`` cut into consecutive runs, about ``per_slot`` runs per slot (enough to keep
    every slot busy while runs differ in cost; few enough that neighbours share a task's
    prepared clouds)."""
    if n <= 0:
        return []
    size = max(1, math.ceil(n / max(slots * per_slot, 1)))
    return [range(a, min(a + size, n)) for a in range(0, n, size)]


def start_ray(workers: int, address: str | None, cpus_per_task: int = 1,
              object_store_mb: int = 80):
    """Start a local Ray instance (``workers`` CPUs) or join the cluster at ``address``
    (``auto`` or ``HOST:PORT``). Returns (ray module, a description). Raises
    :class:`EngineError` with one line when that fails.

    No usage-stats upload attempt (offline machines), no dashboard, warnings only. A local
    worker's thread pools (OpenMP, OpenBLAS, MKL) are as wide as a task's CPUs, not the
    machine's: N workers on N cores then really run N tasks side by side (the workers inherit
    the environment of the raylet this starts; the driver's is restored after).
    """
    try:
        import ray
    except ImportError:  # pragma: no cover  Ray is a processor dependency
        raise EngineError("Ray is not installed (pip install 'ray>=2')") from None

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    kw = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": False,
          "configure_logging": True}
    try:
        if address:
            ray.init(address=address, **kw)
            return ray, f"cluster {address} ({int(ray.cluster_resources().get('CPU', 0))} CPUs)"
        saved = {k: os.environ.get(k) for k in THREAD_ENV}
        for k in THREAD_ENV:
            os.environ.setdefault(k, str(cpus_per_task))
        try:
            ray.init(num_cpus=workers, object_store_memory=object_store_mb * 1024 * 1024, **kw)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    except Exception as exc:  # noqa: BLE001  Ray raises several types here
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise EngineError(f"cannot use {where}: {first}") from None
    return ray, f"local Ray, {workers} worker{'s' if workers != 1 else ''}"


def ray_engine(workers: int = 1, address: str | None = None, cpus_per_task: int = 1,
               max_retries: int = 2, object_store_mb: int = 256) -> RayEngine:
    """A :class:`RayEngine` on a local instance started here (stopped by ``close``) or on the
    cluster at ``address`` (left running; ``close`` only disconnects)."""
    ray, desc = start_ray(workers, address, cpus_per_task, object_store_mb)
    return RayEngine(ray, cpus_per_task, max_retries, owns=True, name=desc)
