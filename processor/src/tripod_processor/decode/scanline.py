# SPDX-License-Identifier: BSD-3-Clause
"""Range smoothing along a laser's scan line, for the decoder's native point records (the
fragments' decoding, :func:`.timed.decode_xyz_time`).

A VLP-16's range noise (~3 cm, along the beam) leaves a surface as thick as the noise in a
fragment; along one laser's scan line, at 0.2° firing steps, a surface's range varies smoothly,
so each point's range is replaced by a local fit of its laser's ranges over ``firings`` firings
either side (same laser, same return; a neighbour more than ``max_step_m`` from the point's
own range is left out: a depth edge is not smoothed across) and the beam direction is kept.

Fits (``fit``):

- ``"mean"``: the mean range (:func:`.timed.denoise_ranges`, the calibration's): the least
  noise (1/√(2h+1) of it on a full window), but biased where the range curves along the line
  (a plane at incidence θ: r'' = r(1 + 2 tan²θ) per rad², bias r''·Δφ²·h(h+1)/6, 1.3 mm at
  3 m and 60° for h = 5 at 0.2° a firing) and, on a window cut short by an edge or a missing
  return, by the slope (r·tanθ·Δφ per firing times the window's mean offset: centimetres).
- ``"linear"``: a least-squares line r(u) evaluated at u = 0 (u: firings from the point, by
  time): the mean on a full window, free of the slope's bias on a cut one.
- ``"quadratic"``: a least-squares parabola (Savitzky-Golay on a full window): free of the
  curvature's bias too, at about twice the mean's noise variance (0.21 vs 0.09 on 11 points).

A fit with too few neighbours for its order falls back to the next lower one (quadratic →
linear with < 4 points or a singular system, linear → mean with < 3).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

#: a VLP-16 firing sequence (16 lasers) every 55.296 µs [ns]
FIRING_PERIOD_NS = 55_296

ScanlineFit = Literal["mean", "linear", "quadratic"]
FITS: tuple[str, ...] = ("mean", "linear", "quadratic")


def smooth_scanline_ranges(points: np.ndarray, firings: int, max_step_m: float = 0.15,
                           fit: ScanlineFit = "mean") -> np.ndarray:
    """x, y, z (M, 3) float32 [m, lidar frame] of the decoder's points with each range smoothed
    along its laser's scan line (module doc).

    Parameters
    ----------
    points : (M,) :data:`.native.POINT_DTYPE` of one decoder call (x, y, z, ring, return_type,
        time_offset_ns: int32 ns from the call's first packet, lidar clock)
    firings : int, half-window in firings (0: the points' x, y, z as they are)
    max_step_m : float, [m] a neighbour farther than this in range is not used
    fit : "mean", "linear" or "quadratic"
    """
    if fit not in FITS:
        raise ValueError(f"scan-line fit {fit!r}: one of {', '.join(FITS)}")
    xyz = np.empty((len(points), 3), np.float32)
    xyz[:, 0], xyz[:, 1], xyz[:, 2] = points["x"], points["y"], points["z"]
    if firings <= 0 or len(points) < 2:
        return xyz
    key = points["ring"].astype(np.uint16) | (points["return_type"].astype(np.uint16) << 4)
    t = points["time_offset_ns"]
    # a call's points come in firing order: a stable sort by laser and return (a radix sort
    # for 16-bit keys) leaves each scan line in time order; else (never seen) sort by time too
    order = np.argsort(key, kind="stable")
    ks, ts = key[order], t[order].astype(np.int64)
    same = ks[1:] == ks[:-1]
    if np.any((ts[1:] < ts[:-1]) & same):
        order = np.lexsort((t, key))
        ks, ts = key[order], t[order].astype(np.int64)
    r = np.sqrt(np.einsum("ij,ij->i", xyz, xyz, dtype=np.float64))
    rs = r[order]
    smooth = fit_ranges(rs, ks, ts, firings, max_step_m, fit)
    scale = np.empty(len(rs))
    scale[order] = smooth / np.maximum(rs, 1e-9)
    # the float64 product rounded into float32 as it is written (as .astype(np.float32) rounds
    # it: the same to the bit, without the (M, 3) float64 temporary)
    return np.multiply(xyz, scale[:, None], out=np.empty_like(xyz))


def fit_ranges(rs: np.ndarray, ks: np.ndarray, ts: np.ndarray, firings: int,
                max_step_m: float, fit: str) -> np.ndarray:
    """The fitted range [m] (float64) at each point of scan-line-ordered ranges ``rs`` [m]
    (keys ``ks``: one per laser and return; times ``ts`` [ns], any zero, increasing within a
    key); the one fit behind :func:`smooth_scanline_ranges` and
    :func:`.timed.denoise_ranges`."""
    n = len(rs)
    order = {"mean": 0, "linear": 1, "quadratic": 2}[fit]
    # moments of the neighbours (the point itself included): S_k = Σ u^k, T_k = Σ u^k (r - r_i),
    # u = firings from the point (by time): centred on the point, so float32 holds them
    # (ranges to µm, u to 1e-3 firing, at most 2·firings + 1 terms)
    r32 = rs.astype(np.float32)
    max_u = np.float32(firings + 0.5)
    S = [np.ones(n, np.float32)] + [np.zeros(n, np.float32) for _ in range(2 * order)]
    T = [np.zeros(n, np.float32) for _ in range(order + 1)]
    for o in range(1, min(firings, n - 1) + 1):
        dr = r32[o:] - r32[:-o]
        ok = ks[o:] == ks[:-o]
        ok &= np.abs(dr) < max_step_m
        if order == 0:
            ok &= (ts[o:] - ts[:-o]) <= int(max_u * FIRING_PERIOD_NS)
        else:
            # the later point seen from the earlier one (> 0), from the int64 time difference:
            # the timed records' absolute times over a station would leave float32 offsets
            # from the first point a tenth of a firing coarse
            u = ((ts[o:] - ts[:-o]) / FIRING_PERIOD_NS).astype(np.float32)
            ok &= u <= max_u
            u *= ok
        dr *= ok
        S[0][:-o] += ok
        S[0][o:] += ok
        T[0][:-o] += dr
        T[0][o:] -= dr
        if order == 0:
            continue
        # the earlier point sees the later at +u, the later sees the earlier at -u
        uk = u
        for k in range(1, 2 * order + 1):
            if k > 1:
                uk = uk * u
            S[k][:-o] += uk
            if k % 2:
                S[k][o:] -= uk
            else:
                S[k][o:] += uk
        udr = u * dr  # (+u)(r_later - r_earlier) = (-u)(r_earlier - r_later)
        T[1][:-o] += udr
        T[1][o:] += udr
        if order == 2:
            udr *= u
            T[2][:-o] += udr
            T[2][o:] -= udr
    S = [x.astype(np.float64) for x in S]
    T = [x.astype(np.float64) for x in T]
    mean = T[0] / S[0]
    if order == 0:
        return rs + mean
    lin = _solve_linear(S, T, mean)
    if order == 1:
        return rs + lin
    return rs + _solve_quadratic(S, T, lin)


def _solve_linear(S: list, T: list, mean: np.ndarray) -> np.ndarray:
    """The intercept of the least-squares line; the mean where under 3 points or singular."""
    det = S[0] * S[2] - S[1] * S[1]
    good = (S[0] >= 3) & (det > 1e-9 * np.maximum(S[0] * S[2], 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (S[2] * T[0] - S[1] * T[1]) / det
    return np.where(good, a, mean)


def _solve_quadratic(S: list, T: list, lin: np.ndarray) -> np.ndarray:
    """The intercept of the least-squares parabola (Cramer's rule on the 3x3 normal
    equations); the line's where under 4 points or near singular."""
    s0, s1, s2, s3, s4 = S
    t0, t1, t2 = T
    c00 = s2 * s4 - s3 * s3
    c01 = s1 * s4 - s3 * s2
    c02 = s1 * s3 - s2 * s2
    det = s0 * c00 - s1 * c01 + s2 * c02
    scale = s0 * s2 * s4
    good = (s0 >= 4) & (det > 1e-6 * np.maximum(scale, 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (t0 * c00 - s1 * (t1 * s4 - s3 * t2) + s2 * (t1 * s3 - s2 * t2)) / det
    return np.where(good, a, lin)
