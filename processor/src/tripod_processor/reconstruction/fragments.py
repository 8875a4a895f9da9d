# SPDX-License-Identifier: BSD-3-Clause
"""Fragments: every packet of a station placed by the IMU into one dense, de-skewed cloud in the
lidar frame at the station's middle time."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ..decode.timed import decode_xyz_time
from ..preprocess import lookup_keys, voxel_downsample, voxel_keys, voxel_sums
from .inputs import LidarPackets
from .placement import (Extrinsic, ImuOrientation, place_points, pose_world_lidar,
                        station_anchor_rotation)
from .stations import Station


@dataclass
class Fragment:
    """A station's cloud and its IMU attitude.

    Attributes
    ----------
    station : Station
    points : (N, 3) float32 [m], lidar frame at ``station.mid_ns``, voxel-filtered
    R_world_lidar : (3, 3) IMU attitude of that frame (yaw from the drifting IMU; fitted over
        the station's samples, :func:`~.placement.station_anchor_rotation`, unless asked not to)
    raw_points : int, points placed before the voxel filter
    intensity : (N,) float32 or None, mean reflectivity (0–255) of each point's voxel (NaN: a
        centroid on a voxel face that missed its voxel); built only when asked (survey outputs)
    anchor : how the anchor attitude came ("slerped": not fitted; else the fit's ``outcome``,
        :func:`~.placement.station_anchor_rotation`: "fit", "fit, pan slerped", or why the
        slerped one was kept, e.g. "off by 0.41°")
    """

    station: Station
    points: np.ndarray
    R_world_lidar: np.ndarray
    raw_points: int
    intensity: np.ndarray | None = None
    anchor: str = "slerped"

    @property
    def tilt_fitted(self) -> bool:
        """Was the anchor's tilt averaged over the station's IMU samples (not one slerped
        sample)? The pan angle may still be slerped ("fit, pan slerped")."""
        return self.anchor in ("fit", "fit, pan slerped")

    @property
    def up_in_lidar(self) -> np.ndarray:
        """The world's +z seen in the fragment's frame (the gravity prior)."""
        return self.R_world_lidar.T @ np.array([0.0, 0.0, 1.0])


def build_fragment(lidar: LidarPackets, station: Station, orient: ImuOrientation, ext: Extrinsic,
                   voxel_m: float, min_range: float, max_range: float,
                   num_threads: int = 0, chunk: int = 1000, max_points: int = 6_000_000,
                   with_intensity: bool = False, anchor_fit: bool = True,
                   anchor_max_deviation_deg: float = 0.3, denoise_firings: int = 0,
                   denoise_fit: str = "mean", denoise_max_step_m: float = 0.15) -> Fragment:
    """Decode, place and voxel-filter one station's packets.

    Decodes and places the station in chunks of ``chunk`` packets, then voxel-filters all its
    placed points at once (a 10 s station is ~3 M points, 36 MB); a long station is bounded by
    filtering what has gathered at half the voxel whenever it passes ``max_points``.
    ``with_intensity``: also the mean intensity of each output voxel (from every placed point;
    per-voxel sums are kept per chunk and merged at the end). ``anchor_fit``: the fragment's
    frame is the lidar's at the IMU attitude fitted over the station's samples
    (:func:`~.placement.station_anchor_rotation`) rather than slerped at its middle time, whose
    white noise would turn the whole station; the points are placed at the slerped attitude and
    moved rigidly onto the fitted one. A fit more than ``anchor_max_deviation_deg`` from the
    slerped attitude is not used (``Fragment.anchor`` says why). ``denoise_firings`` > 0: the
    ranges smoothed along each laser's scan line over that many firings either side with
    ``denoise_fit``, leaving out neighbours farther than ``denoise_max_step_m`` [m] in range,
    before placement (:mod:`..decode.scanline`).

    The chunks (:func:`chunk_points`) are independent until gathered in order
    (:func:`fragment_from_chunks`): :func:`build_fragments_shared` lets idle threads help.
    """
    chunks = (chunk_points(lidar, a, b, station, orient, ext, voxel_m, min_range, max_range,
                           num_threads, with_intensity, denoise_firings, denoise_fit,
                           denoise_max_step_m)
              for a, b in station_chunks(station, chunk))
    return fragment_from_chunks(chunks, station, orient, ext, voxel_m, num_threads, max_points,
                                with_intensity, anchor_fit, anchor_max_deviation_deg)


def station_chunks(station: Station, chunk: int = 1000) -> list[tuple[int, int]]:
    """The packet ranges [a, b) of ``chunk`` packets that :func:`build_fragment` decodes."""
    return [(a, min(station.packet_stop, a + chunk))
            for a in range(station.packet_start, station.packet_stop, chunk)]


def chunk_points(lidar: LidarPackets, a: int, b: int, station: Station, orient: ImuOrientation,
                 ext: Extrinsic, voxel_m: float, min_range: float, max_range: float,
                 num_threads: int = 0, with_intensity: bool = False, denoise_firings: int = 0,
                 denoise_fit: str = "mean", denoise_max_step_m: float = 0.15):
    """Packets [a, b) of ``station`` decoded (ranges smoothed) and placed in its lidar frame at
    ``station.mid_ns``: (placed (N, 3) float32, the intensity's per-voxel sums or None), or
    None when the chunk has no point. Independent of the other chunks and of the threads."""
    xyz, t_ns, inten = decode_xyz_time(lidar.payload, lidar.lidar_ns, a, b,
                                       min_range=min_range, max_range=max_range,
                                       num_threads=num_threads, with_intensity=with_intensity,
                                       denoise_firings=denoise_firings,
                                       denoise_fit=denoise_fit,
                                       denoise_max_step_m=denoise_max_step_m)
    if len(xyz) == 0:
        return None
    placed = place_points(xyz, t_ns, orient, ext, station.mid_ns, num_threads)
    # per-chunk sums: a chunk revisits its voxels every rotation
    sums = voxel_sums(voxel_keys(placed, voxel_m), inten) if with_intensity else None
    return placed, sums


def fragment_from_chunks(chunks, station: Station, orient: ImuOrientation, ext: Extrinsic,
                         voxel_m: float, num_threads: int = 0, max_points: int = 6_000_000,
                         with_intensity: bool = False, anchor_fit: bool = True,
                         anchor_max_deviation_deg: float = 0.3) -> Fragment:
    """The fragment of ``station`` from its chunks' :func:`chunk_points` (an iterable, in
    packet order): gathered, voxel-filtered (at half the voxel whenever more than
    ``max_points`` have gathered), intensity merged, anchored (:func:`build_fragment`).
    ``num_threads``: the filters' threads, or a function giving them as each filter starts
    (the result does not depend on them)."""

    def threads() -> int:
        return num_threads() if callable(num_threads) else num_threads

    parts, raw = [], 0
    key_parts = []
    gathered, limit = 0, max_points
    for c in chunks:
        if c is None:
            continue
        placed, sums = c
        raw += len(placed)
        parts.append(placed)
        if with_intensity:
            key_parts.append(sums)
        gathered += len(placed)
        if gathered > limit:
            parts = [voxel_downsample(np.concatenate(parts), voxel_m * 0.5, threads())]
            gathered = len(parts[0])
            limit = gathered + max_points
    if parts:
        down = voxel_downsample(np.concatenate(parts), voxel_m, threads())
    else:
        down = np.zeros((0, 3), np.float32)
    T = pose_world_lidar(orient, ext, np.array([station.mid_ns]))[0]
    R = T[:3, :3]
    intensity = None
    if with_intensity:
        if key_parts:
            uk, s, c = voxel_sums(*(np.concatenate(a) for a in zip(*key_parts)))
            intensity = lookup_keys(uk, (s / c).astype(np.float32), voxel_keys(down, voxel_m),
                                    np.float32(np.nan))
        else:
            intensity = np.zeros(0, np.float32)
    how = "slerped"
    if anchor_fit:
        # x_fit = R_fitᵀ·(R_slerp·x + R_wi·ℓ − R_wi_fit·ℓ): the frame the fitted attitude gives
        info: dict = {}
        R_wi = station_anchor_rotation(orient, station.start_ns, station.end_ns, station.mid_ns,
                                       max_deviation_deg=anchor_max_deviation_deg, info=info)
        how = info["outcome"]
        R_fit = R_wi @ ext.R_imu_lidar
        C = R_fit.T @ R
        o = R_fit.T @ (T[:3, 3] - R_wi @ ext.lever_arm_m)
        down = (down.astype(np.float64) @ C.T + o).astype(np.float32)
        R = R_fit
    return Fragment(station, down, R, raw, intensity, how)


class _StationChunks:
    """One station's chunks (:func:`station_chunks`), claimed in packet order by its owner and
    by the threads that help it; each result kept until its owner takes it."""

    def __init__(self, ranges: list[tuple[int, int]]):
        self.ranges = ranges
        self.next = 0  # the first chunk nobody has claimed
        self.results: list = [None] * len(ranges)
        self.ready = [threading.Event() for _ in ranges]


def build_fragments_shared(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                           ext: Extrinsic, voxel_m: float, min_range: float, max_range: float,
                           workers: int, num_threads: int = 0, with_intensity: bool = False,
                           step=None, chunk: int = 1000, max_points: int = 6_000_000,
                           **kw) -> list[Fragment]:
    """:func:`build_fragment` of every station, in station order, the same fragments to the
    bit, on ``workers`` threads: the stations side by side, one a thread (its owner, which
    gathers and filters its chunks in packet order); a thread with no station left to take
    decodes and places the next unclaimed chunks (:func:`chunk_points`) of the stations still
    running instead of waiting for the longest to finish alone (dev seed 2: 7 stations of 23-34
    s on 2 threads), and the last station's filter runs on every thread. ``step(k)`` as
    station k is done, in order; ``kw``: :func:`build_fragment`'s anchor and smoothing
    keywords."""
    from concurrent.futures import ThreadPoolExecutor

    anchor = {k: kw.pop(k) for k in ("anchor_fit", "anchor_max_deviation_deg") if k in kw}
    queues = [_StationChunks(station_chunks(st, chunk)) for st in stations]
    lock = threading.Lock()
    state = {"next_station": 0, "running": set()}
    out: list = [None] * len(stations)
    done = [threading.Event() for _ in stations]

    def compute(q: _StationChunks, k: int, st: Station) -> None:
        a, b = q.ranges[k]
        try:
            q.results[k] = (True, chunk_points(lidar, a, b, st, orient, ext, voxel_m, min_range,
                                               max_range, 1, with_intensity, **kw))
        except BaseException as exc:  # the owner raises it
            q.results[k] = (False, exc)
        q.ready[k].set()

    def owned(q: _StationChunks, st: Station):
        for k in range(len(q.ranges)):
            with lock:
                mine = q.next == k
                if mine:
                    q.next += 1
            if mine:
                compute(q, k, st)
            q.ready[k].wait()
            ok, v = q.results[k]
            q.results[k] = None
            if not ok:
                raise v
            yield v

    def filter_threads() -> int:
        # every thread once no other station is left
        with lock:
            alone = state["next_station"] >= len(stations) and len(state["running"]) == 1
        return num_threads if alone else 1

    def worker() -> None:
        while True:
            with lock:
                s = state["next_station"]
                if s < len(stations):
                    state["next_station"] += 1
                    state["running"].add(s)
            if s >= len(stations):
                break
            try:
                out[s] = (True, fragment_from_chunks(owned(queues[s], stations[s]), stations[s],
                                                     orient, ext, voxel_m, filter_threads,
                                                     max_points, with_intensity, **anchor))
            except BaseException as exc:
                out[s] = (False, exc)
            with lock:
                state["running"].discard(s)
            done[s].set()
        while True:  # no station left to take: help those still running with their chunks
            with lock:
                claim = None
                for s in sorted(state["running"]):
                    q = queues[s]
                    if q.next < len(q.ranges):
                        claim = (s, q.next)
                        q.next += 1
                        break
            if claim is None:
                return
            compute(queues[claim[0]], claim[1], stations[claim[0]])

    with ThreadPoolExecutor(max(1, workers)) as pool:
        futs = [pool.submit(worker) for _ in range(max(1, workers))]
        for k in range(len(stations)):
            done[k].wait()
            if not out[k][0]:
                raise out[k][1]
            if step is not None:
                step(k)
        for f in futs:
            f.result()
    return [v for _, v in out]
