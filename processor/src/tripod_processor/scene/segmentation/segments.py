# SPDX-License-Identifier: BSD-3-Clause
"""Planar segments of a cloud, as context for the segmenter: is this point on a large plane?

Local shape alone cannot tell a partition wall (the other room behind it, so it does not bound
the scanned space) from a cabinet front or a pillar face, nor the wall right behind a radiator
from the radiator. The plane a point lies on can: a wall's plane runs for metres and from the
floor to the ceiling, a piece of furniture's is short or ends below the ceiling.

Segments are grown on a 10 cm voxel grid (region growing as a connected-components problem):
two neighbouring voxels are joined when both are planar, their normals agree within
``max_angle_deg`` and each centroid lies within ``max_offset`` of the other's plane. Corners,
edges and curved surfaces are not planar or bend more than that, so they separate the segments.
Everything is vectorised (one sort for the neighbour search, scipy's connected components):
O(M log M) in the number of occupied voxels, a fraction of a second for a room.
"""

from __future__ import annotations

import numpy as np

from ...preprocess import local_shape, voxel_assign

SEGMENT_VOXEL = 0.10  # [m] grid of the region growing; normals from its 3x3x3 (30 cm) cube
MIN_PLANARITY = 0.5  # (l1 - l0) / l2 of a voxel's neighbourhood to take part
MAX_ANGLE_DEG = 15.0  # normals of joined voxels agree within this
MAX_OFFSET = 0.04  # [m] each centroid within this of the other voxel's plane

# the 13 "forward" offsets of the 26-neighbourhood (the other 13 are their negatives)
_OFFSETS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                     if (dx, dy, dz) > (0, 0, 0)], np.int64)


def planar_segments(points, num_threads: int = 0, voxel: float = SEGMENT_VOXEL,
                    min_planarity: float = MIN_PLANARITY, max_angle_deg: float = MAX_ANGLE_DEG,
                    max_offset: float = MAX_OFFSET, residual: bool = False):
    """Grow planar segments over a voxel grid and describe the segment of every point.

    Parameters
    ----------
    points : (N, 3) float32 [m], z up (typically the 4 cm voxel centroids of a cloud)
    num_threads : threads of the C++ local-shape pass, 0 = all

    Returns
    -------
    stats : (N, 5) float32 per point, of the segment its voxel belongs to:
        horizontal span [m] (bounding-box diagonal in x-y), vertical span [m], lowest z [m],
        highest z [m], area [m^2] (occupied voxels x voxel^2). Points of voxels that are not
        planar form a segment of their own voxel.
    normal_z : (N,) float32 |n_z| of the segment (area-weighted mean of its voxel normals).
    segment : (N,) int64 segment id of every point (-1 for non-finite points).
    residual : (N,) float32, only with ``residual=True``: the point's distance [m] from the
        least-squares plane of its segment's voxel centroids (0 for segments of fewer than 4
        voxels). A board, picture or radiator a few cm off a wall joins the wall's segment (its
        voxels straddle both) but sits off the wall's plane.
    Non-finite points get zeros.
    """
    p = np.ascontiguousarray(points, np.float32)
    n = len(p)
    stats = np.zeros((n, 5), np.float32)
    normal_z = np.zeros(n, np.float32)
    segment = np.full(n, -1, np.int64)
    res = np.zeros(n, np.float32)
    empty = (stats, normal_z, segment, res) if residual else (stats, normal_z, segment)
    if n == 0:
        return empty
    cen, point_voxel, counts = voxel_assign(p, voxel, num_threads)
    m = len(cen)
    if m == 0:
        return empty
    ls = local_shape(cen, voxel, num_threads)
    nrm = ls[:, :3].astype(np.float64)
    l0, l1, l2 = ls[:, 3], ls[:, 4], np.maximum(ls[:, 5], 1e-12)
    planar = ((l1 - l0) / l2 > min_planarity) & (ls[:, 6] >= 4)

    # neighbour search: voxel keys sorted once, 13 searchsorted lookups
    ijk = np.floor(cen.astype(np.float64) / voxel).astype(np.int64)
    ijk -= ijk.min(0) - 1
    dims = ijk.max(0) + 2
    key = (ijk[:, 2] * dims[1] + ijk[:, 1]) * dims[0] + ijk[:, 0]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    cos_max = np.cos(np.deg2rad(max_angle_deg))
    src, dst = [], []
    cand = np.flatnonzero(planar)
    for off in _OFFSETS:
        nk = ((ijk[cand, 2] + off[2]) * dims[1] + ijk[cand, 1] + off[1]) * dims[0] + ijk[cand, 0] + off[0]
        pos = np.minimum(np.searchsorted(skey, nk), m - 1)
        hit = skey[pos] == nk
        a, b = cand[hit], order[pos[hit]]
        ok = planar[b]
        a, b = a[ok], b[ok]
        d = (cen[b] - cen[a]).astype(np.float64)
        ok = ((np.abs((nrm[a] * nrm[b]).sum(1)) > cos_max)
              & (np.abs((nrm[a] * d).sum(1)) < max_offset)
              & (np.abs((nrm[b] * d).sum(1)) < max_offset))
        src.append(a[ok])
        dst.append(b[ok])
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    src_a, dst_a = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(len(src_a), np.int8), (src_a, dst_a)), shape=(m, m))
    _, comp = connected_components(graph, directed=False)

    # per-segment bounding box, area and mean |n_z|
    lo = np.full((comp.max() + 1, 3), np.inf)
    hi = np.full((comp.max() + 1, 3), -np.inf)
    c64 = cen.astype(np.float64)
    for k in range(3):
        np.minimum.at(lo[:, k], comp, c64[:, k])
        np.maximum.at(hi[:, k], comp, c64[:, k])
    cells = np.bincount(comp).astype(np.float64)
    nz = np.bincount(comp, weights=np.abs(nrm[:, 2])) / cells
    seg = np.empty((len(cells), 5), np.float32)
    seg[:, 0] = np.hypot(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
    seg[:, 1] = hi[:, 2] - lo[:, 2]
    seg[:, 2] = lo[:, 2]
    seg[:, 3] = hi[:, 2]
    seg[:, 4] = cells * voxel * voxel
    ok = point_voxel >= 0
    stats[ok] = seg[comp[point_voxel[ok]]]
    normal_z[ok] = nz[comp[point_voxel[ok]]]
    segment[ok] = comp[point_voxel[ok]]
    if not residual:
        return stats, normal_z, segment
    # least-squares plane of every segment of >= 4 voxels from its centroids' moments
    big = cells >= 4
    mean = np.stack([np.bincount(comp, weights=c64[:, k]) / cells for k in range(3)], 1)
    d = c64 - mean[comp]
    cov = np.zeros((len(cells), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(comp, weights=d[:, i] * d[:, j]) / cells
    _, vec = np.linalg.eigh(cov[big])
    normal = np.zeros((len(cells), 3))
    normal[big] = vec[:, :, 0]
    sid = comp[point_voxel[ok]]
    dist = np.abs(((p[ok].astype(np.float64) - mean[sid]) * normal[sid]).sum(1))
    res[ok] = np.where(big[sid], dist, 0.0)
    return stats, normal_z, segment, res


def segment_consistent(probabilities: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """Second stage: make the class probabilities of one planar segment agree.

    Each point's probabilities are multiplied by the mean probabilities of its segment and
    renormalised (a product of the local and the segment-wide evidence). A patch of a wall that
    the per-point network doubts (behind a radiator, beside a door) is outvoted by the metres of
    the same plane around it; a point that is confidently something else keeps its label, and
    small segments (furniture, pillar faces) only vote among themselves.

    probabilities : (N, C) float32, rows sum to 1; segment : (N,) int, -1 = none (kept as is)
    Returns (N, C) float32.
    """
    p = np.asarray(probabilities, np.float32)
    seg = np.asarray(segment)
    ok = seg >= 0
    if not ok.any():
        return p.copy()
    s = seg[ok]
    cnt = np.bincount(s).astype(np.float64)
    used = cnt > 0
    mean = np.zeros((len(cnt), p.shape[1]), np.float64)
    for k in range(p.shape[1]):
        mean[used, k] = np.bincount(s, weights=p[ok, k], minlength=len(cnt))[used] / cnt[used]
    out = p.copy()
    q = p[ok] * mean[s].astype(np.float32)
    out[ok] = q / np.maximum(q.sum(1, keepdims=True), 1e-30)
    return out
