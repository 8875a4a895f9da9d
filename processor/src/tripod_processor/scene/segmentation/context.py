# SPDX-License-Identifier: BSD-3-Clause
"""Auto-context for the segmenter's second network: the first network's class probabilities
aggregated over what surrounds a voxel.

A voxel's own features cannot tell a door reveal (wall) from a board 3 cm proud of the wall
(other), nor the foot of a wall from a skirting cabinet; what the first network believes about
the voxel's planar segment, its wall plane, its neighbourhood and the column above and below
it can. :func:`context_features` gives, per voxel, the mean first-stage probabilities over

* the voxel itself, its 10 cm segment, its 25 cm segment and its wall plane (the segments of
  :func:`.features.voxel_features` with ``return_segments``; a voxel without one: its own);
* the voxels of its :data:`BOX_SMALL` and :data:`BOX_LARGE` cubes (a grid of the centroids);
* the voxels below it and above it in its :data:`COLUMN_CELL` x-y cell (zeros when there are
  none), with the log counts of both.

All of it is bincounts over integer groups: O(M log M) in the voxels (the grid keys' sort).
"""

from __future__ import annotations

import numpy as np

#: [m] edge of the small and the large context cube
BOX_SMALL = 0.3
BOX_LARGE = 1.0
#: [m] x-y cell of the vertical column (what is above and below the voxel)
COLUMN_CELL = 0.3

_GROUPS = ("own", "segment", "coarse", "plane", "box_s", "box_l", "below", "above")
_CLASSES = ("ceiling", "floor", "wall", "other")
CONTEXT_NAMES = tuple(f"ctx_{g}_{c}" for g in _GROUPS for c in _CLASSES) + (
    "ctx_log_below", "ctx_log_above")


def _group_mean(p: np.ndarray, group: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Mean of ``p`` over the rows of each group (all rows), for ``rows`` (group -1: the row's
    own ``p``)."""
    ok = group >= 0
    out = p[rows]
    if not ok.any():
        return out
    g = group[ok]
    if g.max() > 8 * len(g):  # sparse keys: compact them (a sort); else bins as they are
        uniq = np.unique(g)
        g = np.searchsorted(uniq, g)
        want = np.searchsorted(uniq, group[rows])
    else:
        want = group[rows]
    k = p.shape[1]
    # one bincount over (group, class) bins: each bin sums its rows in order, as one per class
    sums = np.bincount((g[:, None] * k + np.arange(k)).ravel(), weights=p[ok].ravel(),
                       minlength=(int(g.max()) + 1) * k).reshape(-1, k)
    sel = ok[rows]
    out[sel] = sums[want[sel]] / np.maximum(np.bincount(g), 1)[want[sel], None]
    return out


def _cell_keys(xyz: np.ndarray, cell: float) -> np.ndarray:
    """One int64 key per row of the ``cell`` [m] grid cell of ``xyz`` (M, D) (D = 2 or 3)."""
    ijk = np.floor(xyz.astype(np.float64) / cell).astype(np.int64)
    ijk -= ijk.min(0)
    key = np.zeros(len(ijk), np.int64)
    for d in range(ijk.shape[1]):
        key = key * (int(ijk[:, d].max()) + 1) + ijk[:, d]
    return key


def _column(p: np.ndarray, centroids: np.ndarray, cell: float, rows: np.ndarray):
    """Mean ``p`` of the voxels below and above each of ``rows`` in its x-y cell, and their
    counts."""
    m = len(p)
    key = _cell_keys(centroids[:, :2], cell)
    order = np.lexsort((centroids[:, 2], key))
    sk = key[order]
    start = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
    size = np.diff(np.r_[start, m])
    cs = np.vstack([np.zeros((1, p.shape[1])), np.cumsum(p[order].astype(np.float64), 0)])
    where = np.empty(m, np.int64)
    where[order] = np.arange(m)
    pos = where[rows]  # sorted position of each row, the first and the size of its cell
    cell_of = np.searchsorted(start, pos, side="right") - 1
    first, n = start[cell_of], size[cell_of]
    below = cs[pos] - cs[first]
    above = cs[first + n] - cs[first] - below - p[rows]
    n_below = (pos - first).astype(np.float64)
    n_above = n - 1 - n_below
    return (below / np.maximum(n_below, 1)[:, None], above / np.maximum(n_above, 1)[:, None],
            n_below, n_above)


def context_features(probabilities: np.ndarray, segment: np.ndarray, centroids: np.ndarray,
                     rows: np.ndarray | None = None) -> np.ndarray:
    """(len(rows), len(CONTEXT_NAMES)) float32 context of the voxels ``rows`` (None: all, M).

    probabilities : (M, 4) first-stage class probabilities of the voxels;
    segment : (M, 3) int64 10 cm segment, 25 cm segment, wall plane (-1: none);
    centroids : (M, 3) voxel centroids [m], z up. The means run over all M voxels.
    """
    p = np.asarray(probabilities, np.float32)
    seg = np.asarray(segment)
    c = np.asarray(centroids, np.float32)
    m = len(p)
    if seg.shape != (m, 3) or c.shape != (m, 3):
        raise ValueError(f"context_features: {m} probabilities need (M, 3) segments and "
                         f"centroids, got {seg.shape} and {c.shape}")
    rows = np.arange(m) if rows is None else np.asarray(rows, np.int64)
    out = np.empty((len(rows), len(CONTEXT_NAMES)), np.float32)
    if len(rows) == 0:
        return out
    out[:, 0:4] = p[rows]
    for j in range(3):
        out[:, 4 + 4 * j:8 + 4 * j] = _group_mean(p, seg[:, j], rows)
    out[:, 16:20] = _group_mean(p, _cell_keys(c, BOX_SMALL), rows)
    out[:, 20:24] = _group_mean(p, _cell_keys(c, BOX_LARGE), rows)
    below, above, nb, na = _column(p, c, COLUMN_CELL, rows)
    out[:, 24:28], out[:, 28:32] = below, above
    out[:, 32], out[:, 33] = np.log1p(nb), np.log1p(na)
    return out
