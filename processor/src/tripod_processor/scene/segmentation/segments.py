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


def segment_consistent(probabilities: np.ndarray, segment: np.ndarray,
                       power: float = 1.0) -> np.ndarray:
    """Second stage: make the class probabilities of one planar segment agree.

    Each point's probabilities are multiplied by the mean probabilities of its segment and
    renormalised (a product of the local and the segment-wide evidence). A patch of a wall that
    the per-point network doubts (behind a radiator, beside a door) is outvoted by the metres of
    the same plane around it; a point that is confidently something else keeps its label, and
    small segments (furniture, pillar faces) only vote among themselves.

    probabilities : (N, C) float32, rows sum to 1; segment : (N,) int, -1 = none (kept as is)
    power : the segment's mean enters raised to this power (2: its evidence counts twice)
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
    q = p[ok] * (mean[s] if power == 1.0 else mean[s] ** power).astype(np.float32)
    out[ok] = q / np.maximum(q.sum(1, keepdims=True), 1e-30)
    return out


#: :func:`wall_planes` settings: segments of at least this many voxels take part
PLANE_MIN_VOXELS = 8
PLANE_MAX_ANGLE_DEG = 3.0  # coplanar segments: normals within this
PLANE_MAX_OFFSET = 0.04  # [m] ... and plane offsets within this
PLANE_MAX_NZ = 0.2  # |n_z| of a vertical plane
PLANE_GATE = 0.03  # [m] a member voxel farther than this from the plane is left out
PLANE_SNAP = 0.04  # [m] a voxel of a small segment this close to a plane joins it ...
PLANE_MARGIN = 0.3  # [m] ... when within the plane's extent (members' span + this)


def wall_planes(points, segment) -> np.ndarray:
    """Vertical planes made of planar segments that lie in one plane even when they are apart,
    and the sparse voxels on them: the third stage of the segmenter's plane consistency.

    A wall is cut into separate segments by doors, furniture in front of it and occlusion: a
    narrow pier beside a door, the strip above a wardrobe, a far wall seen through a doorway in
    a few sparse lines. Segments of at least :data:`PLANE_MIN_VOXELS` voxels that are vertical
    and flat (least-squares plane of their voxels) are joined when their normals agree within
    :data:`PLANE_MAX_ANGLE_DEG` and their offsets within :data:`PLANE_MAX_OFFSET`; groups of two
    or more segments are planes. Voxels of small segments within :data:`PLANE_SNAP` of a plane
    and inside its extent join it; member voxels farther than :data:`PLANE_GATE` from it (a
    board on the wall) are left out. The pairs are found by one sort on the offsets
    (:func:`_coplanar_pairs`), not by the S x S matrix of all pairs.

    points : (M, 3) [m] voxel centroids, z up; segment : (M,) int planar segment of each
    (:func:`planar_segments`, -1 none). Returns (M,) int64 plane id, -1 for no plane.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    seg = np.asarray(segment)
    m = len(seg)
    out = np.full(m, -1, np.int64)
    ok = seg >= 0
    if not ok.any():
        return out
    idx = np.flatnonzero(ok)
    s = seg[ok]
    c = np.asarray(points, np.float64)[ok]
    ns = int(s.max()) + 1
    cnt = np.bincount(s, minlength=ns).astype(np.float64)
    mean = np.stack([np.bincount(s, c[:, k], ns) for k in range(3)], 1) / np.maximum(cnt, 1)[:, None]
    d = c - mean[s]
    big = np.flatnonzero(cnt >= PLANE_MIN_VOXELS)
    if len(big) < 2:
        return out
    cov = np.zeros((ns, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(s, d[:, i] * d[:, j], ns) / np.maximum(cnt, 1)
    w, v = np.linalg.eigh(cov[big])
    n = v[:, :, 0]
    flat = (np.abs(n[:, 2]) < PLANE_MAX_NZ) & (w[:, 0] < 0.02 ** 2) & (w[:, 1] > 4 * w[:, 0])
    big, n = big[flat], n[flat]
    if len(big) < 2:
        return out
    # horizontal normal as an angle in [0, pi) (a plane has no side) and the offset along it
    th = np.arctan2(n[:, 1], n[:, 0]) % np.pi
    n2 = np.stack([np.cos(th), np.sin(th)], 1)
    off = (n2 * mean[big, :2]).sum(1)
    a, b = _coplanar_pairs(th, off)
    k = len(big)
    _, comp = connected_components(coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(k, k)),
                                   directed=False)
    multi = np.bincount(comp)[comp] >= 2
    seg_plane = np.full(ns, -1, np.int64)
    seg_plane[big[multi]] = comp[multi]
    g = seg_plane[s]
    # each plane from its members' horizontal scatter; members off it are left out, voxels of
    # small segments on it (within its extent) join it
    small = (cnt[s] < PLANE_MIN_VOXELS) & (g < 0)
    cand = np.flatnonzero(small)
    best_d = np.full(len(cand), np.inf)
    best_g = np.full(len(cand), -1, np.int64)
    xc = c[cand]
    # the members of each plane (ascending, as np.flatnonzero(g == pid) gives them) from one
    # sort, and the candidates sorted by x and by y: each plane looks only at those within its
    # band's range along the axis where that range is shorter
    by_plane = np.argsort(g, kind="stable")
    first = np.searchsorted(g[by_plane], np.arange(-1, int(g.max()) + 2))
    by_axis = [np.argsort(xc[:, ax], kind="stable") for ax in (0, 1)]
    sorted_axis = [xc[by_axis[ax], ax] for ax in (0, 1)]
    for pid in np.unique(g[g >= 0]):
        mem = by_plane[first[pid + 1]:first[pid + 2]]
        q = c[mem]
        mu = q[:, :2].mean(0)
        qc = q[:, :2] - mu
        _, vec = np.linalg.eigh(qc.T @ qc)
        nrm, tan = vec[:, 0], vec[:, 1]
        g[mem[np.abs(qc @ nrm) > PLANE_GATE]] = -1
        tm = qc @ tan
        # the band's (|dist| < PLANE_SNAP, tt within the extent + PLANE_MARGIN) range along x
        # and y, widened by a micrometre: the candidates outside it cannot pass the test below
        t_lo, t_hi = tm.min() - PLANE_MARGIN, tm.max() + PLANE_MARGIN
        corners = mu + (np.array([t_lo, t_hi])[:, None, None] * tan
                        + np.array([-PLANE_SNAP, PLANE_SNAP])[None, :, None] * nrm).reshape(4, 2)
        lo, hi = corners.min(0) - 1e-6, corners.max(0) + 1e-6
        ax = int(np.argmin(hi - lo))
        sel = np.sort(by_axis[ax][np.searchsorted(sorted_axis[ax], lo[ax]):
                                  np.searchsorted(sorted_axis[ax], hi[ax], side="right")])
        xq = xc[sel]
        dist = np.abs((xq[:, :2] - mu) @ nrm)
        tt = (xq[:, :2] - mu) @ tan
        inside = ((dist < PLANE_SNAP) & (tt > t_lo) & (tt < t_hi)
                  & (xq[:, 2] > q[:, 2].min() - PLANE_MARGIN)
                  & (xq[:, 2] < q[:, 2].max() + PLANE_MARGIN) & (dist < best_d[sel]))
        best_d[sel[inside]] = dist[inside]
        best_g[sel[inside]] = pid
    g[cand] = best_g
    out[idx] = g
    return out


def _coplanar_pairs(th: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, b), a < b, in row-major order: the pairs of vertical planes whose normal angles
    ``th`` [rad, in [0, pi)] agree within :data:`PLANE_MAX_ANGLE_DEG` (angles near 0 and near pi
    are the same plane with the offset's sign flipped) and whose offsets ``off`` [m] agree
    within :data:`PLANE_MAX_OFFSET`. The same test as on the full k x k matrix, but only on the
    pairs whose offsets (or offset and flipped offset) are that close, found by one sort: a
    building's wall segments share a few angles (all pairs would pass the angle test) but
    spread over many offsets."""
    k = len(off)
    order = np.argsort(off, kind="stable")
    so = off[order]
    pos = np.arange(k)
    pairs = []
    for centre in (so, -so):  # |off_a - off_b| small (no wrap), |off_a + off_b| small (wrap)
        lo = np.searchsorted(so, centre - PLANE_MAX_OFFSET - 1e-9)
        hi = np.searchsorted(so, centre + PLANE_MAX_OFFSET + 1e-9, side="right")
        n = hi - lo
        i = np.repeat(pos, n)
        j = lo.repeat(n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
        pairs.append((order[i], order[j]))
    a = np.concatenate([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    a, b = np.minimum(a, b), np.maximum(a, b)
    key = np.unique(a[a < b] * np.int64(k) + b[a < b])  # sorted: row-major order
    a, b = key // k, key % k
    # the test of the k x k matrix, pair by pair (the same arithmetic, so the same pairs)
    dth = np.abs(th[a] - th[b])
    wrap = dth > np.pi / 2  # angles near 0 and near pi: the same plane, the offset flips sign
    dth = np.where(wrap, np.pi - dth, dth)
    doff = np.abs(off[a] - np.where(wrap, -off[b], off[b]))
    keep = (dth < np.deg2rad(PLANE_MAX_ANGLE_DEG)) & (doff < PLANE_MAX_OFFSET)
    return a[keep], b[keep]
