# SPDX-License-Identifier: BSD-3-Clause
"""The height of a registered pair when no shared floor or ceiling tells it.

Two levelled scans that share a floor (or a ceiling) get their relative height from it. When
neither is shared (a vertical lidar's narrow band of walls sees no floor and no ceiling) the
height is left to the level ICP, which walls do not constrain: the pose slides up or down.
:func:`height_evidence` looks for what does fix it in 3-D: *horizontal patches* both scans
saw (table and cabinet tops, sills, shelves, the floor or ceiling where one was seen but not
trusted): 20 cm cells whose points spread in two directions (not one scan line) with a normal
within 18 deg of vertical and under 1.5 cm of thickness. Every source patch votes, with every
target patch within 20 cm in plan and 0.5 m in height, for the height correction between them;
a real surface seen by both gives a peak (2 cm window), a scan without such surfaces a flat
histogram. The height is *observable* when the peak holds enough votes and stands well above
the flat level and any other peak 5 cm or more away; otherwise it is reported unobservable (the
registration's ``success`` is then false: its height is a guess).

A height that shared planes gave (both floors, else both ceilings: :func:`.pipeline._level_height`)
is checked against an independent measure of it (:func:`plane_height_contradicted`): the
horizontal patches at the final pose, less the planes that gave it. A gravity-levelled scan
that saw no floor (a vertical lidar's band) can take a level table or bed top with nothing seen
below it for a trusted floor, and its pair then slides by that surface's height with
``success`` true; when the patches say the height is off by more than
:data:`MAX_HEIGHT_DISAGREEMENT_M` the height is reported unobservable instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: [m] most the height from shared floors (or ceilings) may differ from the horizontal patches'
#: peak before it is not trusted: the success limit of the heightmap pairs (5 cm); the true
#: floors and ceilings of the dev vertical pairs agreed within ~3 cm (their planes' medians)
MAX_HEIGHT_DISAGREEMENT_M = 0.05

#: votes within 0.5 m, 1 cm bins; the peak is the best 5-bin (+/- 2 cm) window
_RANGE_M, _BIN_M, _HALF_WINDOW = 0.5, 0.01, 2


@dataclass
class HeightEvidence:
    """dz : height correction [m] to add to the source along the target's up (the peak's
    vote-weighted mean; 0 when not observable); votes : votes in the peak's window; total :
    all votes; peak_ratio : the peak's votes over what a flat histogram puts in its window;
    runner_up : the best other window (>= 5 cm away) over the peak's; observable : the peak is
    a clear one (enough votes, ratio and margin over the runner-up)."""

    dz: float
    votes: int
    total: int
    peak_ratio: float
    runner_up: float
    observable: bool


def horizontal_patches(P: np.ndarray, cell_m: float = 0.20, min_points: int = 8,
                       max_thickness_m: float = 0.015, min_spread_m: float = 0.025,
                       max_tilt_cos: float = 0.95) -> np.ndarray:
    """Centres (K, 3) [m] of the horizontal patches of a levelled cloud ``P`` (N, 3), +z up:
    cells of ``cell_m`` holding >= ``min_points`` whose smallest principal axis is within
    acos(``max_tilt_cos``) of vertical with a spread (sigma) under ``max_thickness_m`` along it
    and over ``min_spread_m`` along the middle axis (a surface, not a scan line)."""
    P = np.asarray(P, np.float64).reshape(-1, 3)
    if len(P) < min_points:
        return np.zeros((0, 3))
    k = np.floor(P / cell_m).astype(np.int64)
    k -= k.min(0)
    key = (k[:, 0] * (k[:, 1].max() + 1) + k[:, 1]) * (k[:, 2].max() + 1) + k[:, 2]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    bounds = np.r_[0, np.flatnonzero(np.diff(ks)) + 1, len(ks)]
    counts = np.diff(bounds)
    keep = np.flatnonzero(counts >= min_points)
    if not len(keep):
        return np.zeros((0, 3))
    # per-cell mean and covariance by sums (no Python loop over points)
    cell_of = np.repeat(np.arange(len(counts)), counts)
    Q = P[order]
    n = counts[:, None].astype(np.float64)
    mean = np.zeros((len(counts), 3))
    np.add.at(mean, cell_of, Q)
    mean /= n
    D = Q - mean[cell_of]
    cov = np.zeros((len(counts), 3, 3))
    np.add.at(cov, cell_of, D[:, :, None] * D[:, None, :])
    cov = cov[keep] / n[keep, :, None]
    w, v = np.linalg.eigh(cov)  # ascending
    ok = ((np.abs(v[:, 2, 0]) > max_tilt_cos) & (w[:, 0] < max_thickness_m ** 2)
          & (w[:, 1] > min_spread_m ** 2))
    return mean[keep][ok]


def height_evidence(source_level: np.ndarray, target_level: np.ndarray, min_votes: int = 15,
                    min_ratio: float = 4.0, max_runner_up: float = 0.6) -> HeightEvidence:
    """Height evidence of a registered pair, both clouds in the target's level frame (+z up,
    the source already placed by the registration). See the module docstring."""
    from scipy.spatial import cKDTree

    ps, pt = horizontal_patches(source_level), horizontal_patches(target_level)
    none = HeightEvidence(0.0, 0, 0, 0.0, 1.0, False)
    if not len(ps) or not len(pt):
        return none
    tree = cKDTree(pt[:, :2])
    dz = []
    for c, js in zip(ps, tree.query_ball_point(ps[:, :2], 0.20)):
        if js:
            d = pt[js, 2] - c[2]
            dz.append(d[np.abs(d) < _RANGE_M])
    dz = np.concatenate(dz) if dz else np.zeros(0)
    if not len(dz):
        return none
    nb = int(round(2 * _RANGE_M / _BIN_M))
    hist = np.histogram(dz, bins=nb, range=(-_RANGE_M, _RANGE_M))[0]
    win = np.convolve(hist, np.ones(2 * _HALF_WINDOW + 1, int), mode="same")
    i = int(np.argmax(win))
    peak = int(win[i])
    flat = len(dz) * (2 * _HALF_WINDOW + 1) / nb
    far = np.abs(np.arange(nb) - i) >= 5  # windows >= 5 cm away
    runner = float(win[far].max() / peak) if far.any() and peak else 1.0
    centre = -_RANGE_M + (i + 0.5) * _BIN_M
    sel = np.abs(dz - centre) <= (_HALF_WINDOW + 0.5) * _BIN_M
    ratio = peak / max(flat, 1e-9)
    ok = peak >= min_votes and ratio >= min_ratio and runner <= max_runner_up
    return HeightEvidence(float(dz[sel].mean()) if ok else 0.0, peak, len(dz), float(ratio),
                          runner, bool(ok))


def plane_height_contradicted(source_level: np.ndarray, target_level: np.ndarray, *,
                              max_disagreement_m: float = MAX_HEIGHT_DISAGREEMENT_M
                              ) -> tuple[bool, str]:
    """Whether the height a registered pair took from shared planes (floors or ceilings) is
    contradicted, both clouds in the target's level frame (+z up, the source placed by the
    registration), the planes that gave the height left out: the horizontal patches both scans
    saw give an observable correction (:func:`height_evidence`) larger than
    ``max_disagreement_m``. (The ceilings' difference on shared floors is no such measure: a
    procedural open plan's two trusted ceilings differed by 1.49 m at the true pose on dev seed
    302.) Returns (contradicted, why)."""
    ev = height_evidence(source_level, target_level)
    if ev.observable and abs(ev.dz) > max_disagreement_m:
        return True, f"horizontal patches say {ev.dz * 100:.1f} cm"
    return False, ""
