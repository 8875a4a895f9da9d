# SPDX-License-Identifier: BSD-3-Clause
"""A reconstruction's heavy independent steps on an :mod:`.engine`: fragment building (one
call per station) and fragment-pair registrations (odometry pairs, loop candidates).

In process (the default engine) these are the plain loops of before: one
:func:`~.fragments.build_fragment` per station, one
:func:`~.odometry.register_fragments` per pair, sharing the run's :class:`~.odometry.CloudCache`.
On Ray, a fragment task gets only its station's packets (a slice of the recording); every
fragment's points are put once in the object store, and a registration task takes a run of
consecutive pairs with references to the fragments they need (a task prepares each of its
fragments once, in its own cache). Registration depends only on the two clouds, their IMU
attitudes and the config (the cache only saves work), so both engines give the same bytes
when ``num_threads`` is the same.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from .config import OdometryConfig
from .engine import InProcess, chunks
from .fragments import Fragment, build_fragment
from .inputs import LidarPackets
from .odometry import CloudCache, PairResult, register_fragments
from .placement import Extrinsic, ImuOrientation
from .stations import Station

_IN_PROCESS = InProcess()


def thread_workers(num_threads: int, n_items: int) -> int:
    """Threads for ``n_items`` independent calls in process: ``num_threads`` (0: every core),
    at most one per item. With more than one, each call runs on one thread (the native core
    releases the GIL; its results do not depend on the thread count)."""
    return min(max(1, num_threads or (os.cpu_count() or 1)), max(1, n_items))


@contextmanager
def blas_one_thread():
    """BLAS (numpy's and scipy's OpenBLAS) on one thread inside: the pipeline runs its stations,
    windows and pairs side by side on its own threads, each calling BLAS on small matrices
    ((N, 3) @ (3, 3), 3-column least squares); OpenBLAS's own threads then only spin and wait
    for each other (on dev seed 0 at load 6: calibration 5.3 -> 4.3 CPU-s, fragments 4.2 ->
    3.1). Each product is computed by one thread either way (the same values). The limit is
    process-wide (threadpoolctl): two reconstructions on threads of one process share it, which
    changes their speed only."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _threaded_map(fn, calls: list[tuple], workers: int, step=None) -> list:
    """``[fn(*c) for c in calls]`` on ``workers`` threads, in order; ``step(k)`` as each
    result arrives in order."""
    out = []
    with ThreadPoolExecutor(workers) as pool:
        for k, r in enumerate(pool.map(lambda c: fn(*c), calls)):
            out.append(r)
            if step is not None:
                step(k)
    return out


def _fragment_task(payload: np.ndarray, lidar_ns: np.ndarray, return_mode: str,
                   station: Station, orient: ImuOrientation, ext: Extrinsic, voxel_m: float,
                   min_range: float, max_range: float, num_threads: int,
                   with_intensity: bool, anchor_fit: bool = True,
                   anchor_max_deviation_deg: float = 0.3, denoise_firings: int = 0,
                   denoise_fit: str = "mean", denoise_max_step_m: float = 0.15) -> Fragment:
    """One station's fragment from its own packets (``payload``, ``lidar_ns``: the station's
    slice; ``station`` with its original packet indices)."""
    n = len(lidar_ns)
    lidar = LidarPackets(np.zeros(n, np.int64), lidar_ns, payload, return_mode)
    local = Station(station.index, station.start_ns, station.end_ns, 0, n, station.label)
    frag = build_fragment(lidar, local, orient, ext, voxel_m, min_range, max_range, num_threads,
                          with_intensity=with_intensity, anchor_fit=anchor_fit,
                          anchor_max_deviation_deg=anchor_max_deviation_deg,
                          denoise_firings=denoise_firings, denoise_fit=denoise_fit,
                          denoise_max_step_m=denoise_max_step_m)
    frag.station = station
    return frag


def build_fragments(engine, lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                    ext: Extrinsic, voxel_m: float, min_range: float, max_range: float,
                    num_threads: int = 0, with_intensity: bool = False, progress=None,
                    anchor_fit: bool = True, anchor_max_deviation_deg: float = 0.3,
                    denoise_firings: int = 0, denoise_fit: str = "mean",
                    denoise_max_step_m: float = 0.15, chunk_pipeline: bool = True
                    ) -> list[Fragment]:
    """:func:`~.fragments.build_fragment` for every station, in station order. ``progress``: a
    bar (``update(1)`` per station). In process the stations run side by side, one a thread;
    ``chunk_pipeline`` (on more than one thread): a thread with no station left helps those
    still running with their chunks (:func:`~.fragments.build_fragments_shared`, the same
    fragments to the bit)."""
    step = (lambda _k: progress.update(1)) if progress is not None else None
    engine = engine or _IN_PROCESS
    if not engine.distributed:
        cores = thread_workers(num_threads, 1 << 30)
        if chunk_pipeline and cores > 1 and stations:
            # no thread idle while the longest station finishes alone (the same fragments)
            from .fragments import build_fragments_shared

            return build_fragments_shared(
                lidar, stations, orient, ext, voxel_m, min_range, max_range, cores,
                num_threads, with_intensity, step,
                anchor_fit=anchor_fit, anchor_max_deviation_deg=anchor_max_deviation_deg,
                denoise_firings=denoise_firings, denoise_fit=denoise_fit,
                denoise_max_step_m=denoise_max_step_m)
        # stations side by side on threads, one thread each (decode, placement and voxel filter
        # run natively without the GIL; a fragment does not depend on the threads)
        workers = thread_workers(num_threads, len(stations))
        inner = num_threads if workers == 1 else 1

        def one(st: Station) -> Fragment:
            return build_fragment(lidar, st, orient, ext, voxel_m, min_range, max_range,
                                  inner, with_intensity=with_intensity, anchor_fit=anchor_fit,
                                  anchor_max_deviation_deg=anchor_max_deviation_deg,
                                  denoise_firings=denoise_firings, denoise_fit=denoise_fit,
                                  denoise_max_step_m=denoise_max_step_m)

        calls = [(st,) for st in stations]
        if workers == 1:
            return engine.map(one, calls, step)
        return _threaded_map(one, calls, workers, step)
    h_orient, h_ext = engine.put(orient), engine.put(ext)
    calls = [(lidar.payload[st.packet_start:st.packet_stop],
              lidar.lidar_ns[st.packet_start:st.packet_stop], lidar.return_mode, st, h_orient,
              h_ext, voxel_m, min_range, max_range, num_threads, with_intensity, anchor_fit,
              anchor_max_deviation_deg, denoise_firings, denoise_fit, denoise_max_step_m)
             for st in stations]
    return engine.map(_fragment_task, calls, step)


def _register_run(pairs: list[tuple], cfg: OdometryConfig, num_threads: int,
                  *points: np.ndarray) -> list[PairResult]:
    """Register a run of pairs in one task, one cache: ``pairs`` are (source, target,
    R_world_source, R_world_target, T_guess, tilt_known) with source and target positions in
    ``points``."""
    cache = CloudCache(cfg.point_sigma_m, num_threads)
    return [register_fragments(points[s], points[t], R_s, R_t, cfg, num_threads, T_guess=g,
                               cache=cache, keys=(s, t), tilt_known=tk)
            for s, t, R_s, R_t, g, tk in pairs]


def register_pairs(engine, frags: list[Fragment], pairs: list[tuple[int, int]],
                   cfg: OdometryConfig, num_threads: int = 0, cache: CloudCache | None = None,
                   guesses: list[np.ndarray | None] | None = None, progress=None
                   ) -> list[PairResult]:
    """``register_fragments(frags[j] onto frags[i])`` for every ``(j, i)`` in ``pairs`` (source
    j, target i; ``guesses[k]``: T_i_j to try first, or None), results in the order of
    ``pairs``. In process: ``cache`` (keys: station indices) is shared with the run's other
    steps. ``progress``: a bar (``update(n)`` as n pairs finish)."""
    guesses = guesses if guesses is not None else [None] * len(pairs)
    engine = engine or _IN_PROCESS
    if not engine.distributed:
        cache = cache or CloudCache(cfg.point_sigma_m, num_threads)
        workers = thread_workers(num_threads, len(pairs))
        inner = num_threads if workers == 1 else 1

        def one(j: int, i: int, g) -> PairResult:
            return register_fragments(frags[j].points, frags[i].points, frags[j].R_world_lidar,
                                      frags[i].R_world_lidar, cfg, inner, T_guess=g,
                                      cache=cache, keys=(j, i),
                                      tilt_known=frags[j].tilt_fitted and frags[i].tilt_fitted)

        step = (lambda _k: progress.update(1)) if progress is not None else None
        calls = [(j, i, g) for (j, i), g in zip(pairs, guesses)]
        if workers == 1:
            return engine.map(one, calls, step)
        # pairs side by side: every fragment they use prepared in the shared cache first (side
        # by side too), so no two pairs prepare one fragment at once
        used = sorted({f for p in pairs for f in p})
        _threaded_map(lambda f: cache.prepare_all(f, frags[f].points, cfg, 1),
                      [(f,) for f in used], workers)
        return _threaded_map(one, calls, workers, step)
    calls = []
    runs = chunks(len(pairs), engine.slots)
    for run in runs:
        order: dict[int, int] = {}  # station -> position among the task's clouds
        items = []
        for k in run:
            j, i = pairs[k]
            s, t = order.setdefault(j, len(order)), order.setdefault(i, len(order))
            items.append((s, t, frags[j].R_world_lidar, frags[i].R_world_lidar, guesses[k],
                          frags[j].tilt_fitted and frags[i].tilt_fitted))
        calls.append((items, cfg, num_threads, *(engine.put(frags[f].points) for f in order)))
    step = (lambda k: progress.update(len(runs[k]))) if progress is not None else None
    results = engine.map(_register_run, calls, step)
    return [r for run in results for r in run]
