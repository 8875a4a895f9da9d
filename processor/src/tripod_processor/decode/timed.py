# SPDX-License-Identifier: BSD-3-Clause
"""Packets → points with each point's own lidar time (the reconstruction's decoding).

Decoding is the C++ core's batch VLP-16 decoder (:mod:`.native`, point for point equal to
velodyne-decoder's): one call per chunk of packets, the GIL released, OpenMP over packets. The
product byte is not looked at (an early VLP-16 says 0x21). Times are exact integer ns: the
packet's lidar time plus the firing offset.
"""

from __future__ import annotations

import numpy as np

#: a point with its absolute lidar time (x, y, z [m] lidar frame, time_ns UNIX ns, lidar clock)
TIMED_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                              ("ring", "u1"), ("return_type", "u1"), ("time_ns", "<i8")])

#: the fields a decoder point and a timed record share (the record's time is absolute)
_SHARED_FIELDS = ("x", "y", "z", "intensity", "ring", "return_type")


def decode_timed_points(payload: np.ndarray, lidar_ns: np.ndarray, start: int, stop: int, *,
                        min_range: float = 0.0, max_range: float = 200.0, chunk: int = 1000,
                        num_threads: int = 0) -> np.ndarray:
    """Decode packets ``[start, stop)`` into points in the lidar frame with per-point lidar time.

    Parameters
    ----------
    payload : (P, 1206) uint8 data packets; lidar_ns : (P,) int64 their lidar time [ns]
    chunk : int
        Packets per call; a call's time offsets are int32 ns from its first packet, so a chunk
        must span less than 2.1 s (1000 VLP-16 packets are 1.33 s).

    Returns
    -------
    structured ndarray (N,) of TIMED_POINT_DTYPE: x, y, z [m] (float32, lidar frame), intensity,
    ring, return_type, time_ns (int64, lidar time, UNIX ns).
    """
    from .native import NativeVlp16Decoder

    dec = NativeVlp16Decoder(min_range_m=float(max(min_range, 0.0)), max_range_m=float(max_range),
                             num_threads=num_threads)
    parts = []
    for s in range(start, stop, chunk):
        e = min(stop, s + chunk)
        pts = dec.decode(payload[s:e], lidar_ns[s:e]).points
        if len(pts):
            parts.append((s, pts))
    # the records filled in place, the shared fields in one multi-field copy (by position:
    # the same order both sides) and the times as lidar_ns[s] + offset: the same values as a
    # field at a time into each chunk's own records, then concatenated (2.4x cheaper)
    out = np.empty(sum(len(p) for _, p in parts), dtype=TIMED_POINT_DTYPE)
    k = 0
    for s, pts in parts:
        seg = out[k:k + len(pts)]
        seg[list(_SHARED_FIELDS)] = pts[list(_SHARED_FIELDS)]
        np.add(pts["time_offset_ns"].astype(np.int64), lidar_ns[s], out=seg["time_ns"])
        k += len(pts)
    return out


def decode_xyz_time(payload: np.ndarray, lidar_ns: np.ndarray, start: int, stop: int, *,
                    min_range: float = 0.0, max_range: float = 200.0, chunk: int = 1000,
                    num_threads: int = 0, with_intensity: bool = False,
                    denoise_firings: int = 0, denoise_fit: str = "mean",
                    denoise_max_step_m: float = 0.15
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The points of :func:`decode_timed_points` (the same points in the same order) as plain
    arrays, without the per-point record: the hot path of fragments and station windows.

    ``denoise_firings`` > 0: each range smoothed along its laser's scan line over that many
    firings either side (:func:`.scanline.smooth_scanline_ranges` with ``denoise_fit`` and
    ``denoise_max_step_m``, per call of ``chunk`` packets: its points' ring and return type
    never leave the call); 0: the decoder's x, y, z as they are.

    Returns
    -------
    xyz : (N, 3) float32 [m], lidar frame
    time_ns : (N,) int64, lidar time, UNIX ns
    intensity : (N,) float32, or None unless ``with_intensity``
    """
    from numpy.lib import recfunctions as rfn

    from .native import NativeVlp16Decoder
    from .scanline import smooth_scanline_ranges

    dec = NativeVlp16Decoder(min_range_m=float(max(min_range, 0.0)), max_range_m=float(max_range),
                             num_threads=num_threads)
    xyz, t, inten = [], [], []
    for s in range(start, stop, chunk):
        e = min(stop, s + chunk)
        pts = dec.decode(payload[s:e], lidar_ns[s:e]).points
        if len(pts) == 0:
            continue
        if denoise_firings > 0:
            xyz.append(smooth_scanline_ranges(pts, denoise_firings, denoise_max_step_m,
                                              denoise_fit))
        else:
            xyz.append(rfn.structured_to_unstructured(pts[["x", "y", "z"]]))
        t.append(lidar_ns[s] + pts["time_offset_ns"].astype(np.int64))
        if with_intensity:
            inten.append(pts["intensity"].astype(np.float32))
    if not xyz:
        return (np.zeros((0, 3), np.float32), np.zeros(0, np.int64),
                np.zeros(0, np.float32) if with_intensity else None)
    one = len(xyz) == 1
    return (xyz[0] if one else np.concatenate(xyz), t[0] if one else np.concatenate(t),
            (inten[0] if one else np.concatenate(inten)) if with_intensity else None)


def denoise_ranges(pts: np.ndarray, firings: int = 5, max_step_m: float = 0.1,
                   fit: str = "mean", at: np.ndarray | None = None) -> np.ndarray:
    """The points' xyz (N, 3) float64 [m, lidar frame] with each range smoothed along its
    laser's scan line: ``fit`` ("mean", "linear", "quadratic") over the same laser's and
    return's ranges within ``firings`` firings either side (±1° at 600 rpm for 5), leaving out
    a neighbour more than ``max_step_m`` from the point's own range (a depth edge is not
    smoothed across); the beam's direction is kept. The fit is :mod:`.scanline`'s (the
    fragments' smoothing); this is its form for :data:`TIMED_POINT_DTYPE` records (absolute
    times, any order), the calibration's.

    Why: two sweeps' noisy points bias a registration's rotation by tenths of a degree in a
    small room (dev seed 2, 4 × 4 m, 12° mount: 0.41° about the tilt axis at 45° turns; 0.02°
    with ``firings=5``, as without noise), and that bias is hand-eye's mount-tilt error.
    ``firings`` 0 returns the points as they are. ``at`` (indices into ``pts``): the xyz of
    those points only (len(at), 3), smoothed over all of ``pts`` and equal to the bit to
    ``denoise_ranges(pts, ...)[at]``, at the cost of ``len(at)`` points rather than ``len(pts)``
    (the calibration's stations keep a tenth of the points they decode)."""
    from .scanline import FITS, fit_ranges

    if fit not in FITS:
        raise ValueError(f"scan-line fit {fit!r}: one of {', '.join(FITS)}")
    if at is not None and fit == "mean" and firings > 0 and len(pts) >= 2:
        return _denoise_mean_at(pts, firings, max_step_m, np.asarray(at, dtype=np.int64))
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    if firings <= 0 or len(pts) < 2:
        return xyz if at is None else xyz[np.asarray(at, dtype=np.int64)]
    r = np.linalg.norm(xyz, axis=1)
    order, ks, ts = _scanline_order(pts)
    rs = r[order]
    smooth = fit_ranges(rs, ks, ts, firings, max_step_m, fit)
    scale = np.empty(len(rs))
    scale[order] = smooth / np.maximum(rs, 1e-9)
    out = xyz * scale[:, None]
    return out if at is None else out[np.asarray(at, dtype=np.int64)]


def _scanline_order(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order, keys, times) of ``pts`` (TIMED_POINT_DTYPE) in scan-line order: by laser and
    return (key = ring·256 + return type), then time. Decoded packets come in time order: a
    stable sort by the 16-bit key (a radix sort) is then that order, ties kept in input order
    as ``np.lexsort((time, key))`` keeps them; else (never seen) the lexicographic sort."""
    key = pts["ring"].astype(np.uint16) * np.uint16(256) + pts["return_type"].astype(np.uint16)
    t = pts["time_ns"]
    order = np.argsort(key, kind="stable")
    ks, ts = key[order], t[order]
    if np.any((ts[1:] < ts[:-1]) & (ks[1:] == ks[:-1])):
        order = np.lexsort((t, key))
        ks, ts = key[order], t[order]
    return order, ks.astype(np.int64), ts


def _denoise_mean_at(pts: np.ndarray, firings: int, max_step_m: float,
                     at: np.ndarray) -> np.ndarray:
    """:func:`denoise_ranges`'s "mean" fit at the points ``at`` only: each one's window of
    ``firings`` scan-line neighbours either side gathered, and the ranges, sums and their
    order as :func:`.scanline.fit_ranges` has them (float32 sums, the later neighbour o then
    the earlier o, o = 1..firings), so the same xyz to the bit."""
    from .scanline import FIRING_PERIOD_NS

    n = len(pts)
    order, ks, ts = _scanline_order(pts)
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n)
    P = pos[at]
    offs = np.arange(-firings, firings + 1)
    Wp = P[:, None] + offs[None, :]  # (m, 2f+1) scan-line positions of each window
    valid = (Wp >= 0) & (Wp < n)
    Wp = np.clip(Wp, 0, n - 1)
    G = order[Wp]  # the windows' points (input indices)
    xyz_w = np.stack([pts["x"][G], pts["y"][G], pts["z"][G]], axis=2).astype(np.float64)
    r_w = np.linalg.norm(xyz_w.reshape(-1, 3), axis=1).reshape(G.shape)
    r32 = r_w.astype(np.float32)
    k_w = ks[Wp]
    t_w = ts[Wp]
    lim = int(np.float32(firings + 0.5) * FIRING_PERIOD_NS)
    c = firings  # the point's own column
    S0 = np.ones(len(at), np.float32)
    T0 = np.zeros(len(at), np.float32)
    for o in range(1, min(firings, n - 1) + 1):
        for col, sgn in ((c + o, 1), (c - o, -1)):
            # later minus earlier, as fit_ranges takes each pair's difference
            dr = r32[:, col] - r32[:, c] if sgn > 0 else r32[:, c] - r32[:, col]
            ok = valid[:, col] & (k_w[:, col] == k_w[:, c])
            ok &= np.abs(dr) < max_step_m
            ok &= (t_w[:, col] - t_w[:, c] if sgn > 0 else t_w[:, c] - t_w[:, col]) <= lim
            dr *= ok
            S0 += ok
            if sgn > 0:
                T0 += dr
            else:
                T0 -= dr
    rs = r_w[:, c]
    smooth = rs + T0.astype(np.float64) / S0.astype(np.float64)
    return xyz_w[:, c] * (smooth / np.maximum(rs, 1e-9))[:, None]
