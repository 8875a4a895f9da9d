# SPDX-License-Identifier: BSD-3-Clause
"""Plan heightmaps as images and their dense matching: rasterisation and FFT cross-correlation
over a grid of yaws (walls and the rest as two channels)."""

from __future__ import annotations

import numpy as np

from .levelling import LevelledScan


def _raster(xy: np.ndarray, val: np.ndarray, lo: np.ndarray, pixel: float, shape) -> np.ndarray:
    ij = np.floor((xy - lo) / pixel).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
    img = np.zeros(shape, np.float32)
    np.maximum.at(img, (ij[ok, 0], ij[ok, 1]), val[ok].astype(np.float32))
    return img


def _normalise(img: np.ndarray) -> np.ndarray:
    m = img > 0
    out = np.zeros_like(img)
    if m.any():
        out[m] = img[m] - img[m].mean() * 0.5  # keep empty space at zero: only structure matches
        out /= np.sqrt((out ** 2).sum()) + 1e-12
    return out


def _xcorr_peaks(F_target: np.ndarray, src: np.ndarray, window=None, extra=None,
                 n_peaks: int = 1, suppress_px: int = 10):
    """Peaks of the circular cross-correlation (shift of src onto target) with sub-pixel
    refinement: a list of (value, shift (2,) [px]), best first.

    window: optional ((i0, j0), radius) limiting the search to shifts near (i0, j0) (one peak);
    extra: optional (F_target2, src2), a second channel whose correlation is added;
    n_peaks: without a window, that many peaks at least ``suppress_px`` apart (a corridor or a
    row of equal rooms matches at several shifts under one yaw)."""
    from scipy import fft

    X = F_target * np.conj(fft.rfft2(src, workers=-1))
    if extra is not None:
        X = X + extra[0] * np.conj(fft.rfft2(extra[1], workers=-1))
    c = fft.irfft2(X, s=src.shape, workers=-1)
    H, W = c.shape
    if window is not None:
        (i0, j0), r = window
        ii = (np.arange(-r, r + 1) + i0) % H
        jj = (np.arange(-r, r + 1) + j0) % W
        sub = c[np.ix_(ii, jj)]
        a, b = np.unravel_index(int(np.argmax(sub)), sub.shape)
        found = [(int(ii[a]), int(jj[b]))]
    else:
        work = c.copy()
        found = []
        for _ in range(n_peaks):
            i, j = np.unravel_index(int(np.argmax(work)), work.shape)
            found.append((int(i), int(j)))
            ri = np.arange(i - suppress_px, i + suppress_px + 1) % H
            rj = np.arange(j - suppress_px, j + suppress_px + 1) % W
            work[np.ix_(ri, rj)] = -np.inf

    def parabola(m1, z0, p1):
        den = m1 - 2 * z0 + p1
        return 0.0 if abs(den) < 1e-12 else 0.5 * (m1 - p1) / den

    out = []
    for i, j in found:
        peak = float(c[i, j])
        di = parabola(c[(i - 1) % H, j], peak, c[(i + 1) % H, j])
        dj = parabola(c[i, (j - 1) % W], peak, c[i, (j + 1) % W])
        si = (i + di + H / 2) % H - H / 2  # wrap to signed shifts
        sj = (j + dj + W / 2) % W - W / 2
        out.append((peak, np.array([si, sj])))
    return out


def _channels(xy, z, labels, lo, pixel, shape) -> list[np.ndarray]:
    """Plan heightmap channels: walls (occupancy) and the rest (tallest point [m]); each
    normalised. Walls give the room's outline, the rest breaks its symmetries."""
    wall = labels == 2
    return [_normalise(_raster(xy[wall], np.ones(wall.sum()), lo, pixel, shape)),
            _normalise(_raster(xy[~wall], z[~wall], lo, pixel, shape))]


def _search(src: LevelledScan, tgt: LevelledScan, yaws: np.ndarray, pixel: float, window=None,
            max_points: int = 30_000, seed: int = 0, keep: int = 1, other_weight: float = 2.0,
            shifts: int = 1):
    """The ``keep`` best distinct (score, yaw, shift [m]) over the yaws (``shifts`` correlation
    peaks per yaw); shift maps
    the rotated source xy onto the target xy. The score is the walls' correlation plus
    ``other_weight`` times the rest's: walls of a box room match equally well under its
    symmetries, the furniture must outvote them."""
    from scipy import fft

    rng = np.random.default_rng(seed)
    sx, sz, sl = src.xy, src.z, src.labels
    if len(sx) > max_points:
        k = rng.choice(len(sx), max_points, replace=False)
        sx, sz, sl = sx[k], sz[k], sl[k]
    r_src = float(np.sqrt((sx ** 2).sum(1)).max()) if len(sx) else 1.0
    t_lo, t_hi = tgt.xy.min(0), tgt.xy.max(0)
    span = (t_hi - t_lo) + 2 * r_src + 1.0
    n = int(2 ** np.ceil(np.log2(max(32, span.max() / pixel))))
    lo = t_lo - r_src - 0.5
    shape = (n, n)
    F_t = [fft.rfft2(c) for c in _channels(tgt.xy, tgt.z, tgt.labels, lo, pixel, shape)]
    results = []
    for yaw in yaws:
        c, s = np.cos(yaw), np.sin(yaw)
        rx = sx @ np.array([[c, s], [-s, c]])  # rows: R(yaw) x
        S_c = _channels(rx, sz, sl, lo, pixel, shape)
        win = None
        if window is not None:
            centre = np.round(window[0] / pixel).astype(int)
            win = ((int(centre[0]), int(centre[1])), int(window[1]))
        # summed correlation of the channels; the peak position from their sum
        for peak, shift in _xcorr_peaks(F_t[0] + 0.0, S_c[0], win,
                                        extra=(other_weight * F_t[1], S_c[1]),
                                        n_peaks=shifts, suppress_px=int(np.ceil(1.0 / pixel))):
            results.append((peak, float(yaw), shift * pixel))
    results.sort(key=lambda r: -r[0])
    out = []
    for r in results:  # distinct: yaws 20 deg apart, or shifts 1 m apart under a near yaw
        if all(abs((r[1] - o[1] + np.pi) % (2 * np.pi) - np.pi) > np.deg2rad(20)
               or np.linalg.norm(r[2] - o[2]) > 1.0 for o in out):
            out.append(r)
        if len(out) == keep:
            break
    return out
