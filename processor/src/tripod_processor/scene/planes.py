# SPDX-License-Identifier: BSD-3-Clause
"""Scene understanding, part 2: planar surfaces of the labelled classes, with their outlines.

Per class (ceiling, floor, wall), repeatedly:

1. **hypothesise** — RANSAC with one point and its local normal (from the C++ voxel moments) per
   hypothesis, scored on a random subset with a distance and a normal-agreement test;
2. **refine** — least squares (PCA) on the inliers, with a robust-statistics test: the inlier
   band is 3 sigma of the residuals, sigma from their median absolute deviation (so the band
   adapts to the sensor noise), iterated to convergence;
3. **split** — the inliers are cut into connected pieces on a 2-D grid in the plane (gaps wider
   than ``gap`` separate them: two walls in one plane either side of a door are two segments),
   each refitted; every piece gets its polygon outline (boundary of the occupied cells,
   simplified).

Planes are n . x + d = 0 with unit n pointing into the room (floor up, ceiling down, walls
towards the cloud's centre).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..preprocess import as_cloud, local_shape

CEILING, FLOOR, WALL, OTHER = 0, 1, 2, 3
PLANAR_CLASSES = (CEILING, FLOOR, WALL)


@dataclass
class Plane:
    """One planar segment.

    label : class of its points (0 ceiling, 1 floor, 2 wall)
    normal : (3,) unit normal pointing into the room; offset : d in n . x + d = 0 [m]
    indices : (K,) int64 indices of its points in the input cloud
    origin : (3,) a point on the plane [m]; axes : (2, 3) in-plane unit axes u, v (u x v = n)
    outline : (M, 3) polygon corners on the plane [m], counter-clockwise seen from the room
    sigma : robust residual spread (1.4826 MAD) [m]; area : occupied area [m^2]
    """

    label: int
    normal: np.ndarray
    offset: float
    indices: np.ndarray
    origin: np.ndarray
    axes: np.ndarray
    outline: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sigma: float = 0.0
    area: float = 0.0

    def distance(self, points) -> np.ndarray:
        """Signed distances [m] of (N, 3) points, positive on the room side."""
        return np.asarray(points, np.float64) @ self.normal + self.offset

    def to_plane_coords(self, points) -> np.ndarray:
        """(N, 2) in-plane coordinates (u, v) [m] of (N, 3) points."""
        return (np.asarray(points, np.float64) - self.origin) @ self.axes.T

    def as_dict(self) -> dict:
        return {"label": int(self.label), "normal": self.normal.tolist(), "offset": float(self.offset),
                "origin": self.origin.tolist(), "axes": self.axes.tolist(),
                "outline": np.round(self.outline, 4).tolist(), "sigma": float(self.sigma),
                "area": float(self.area), "num_points": int(len(self.indices))}


def _fit(p: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares plane of (K, 3) points: the smallest eigenvector of their covariance."""
    c = p.mean(0)
    q = p - c
    _, vec = np.linalg.eigh(q.T @ q)
    n = vec[:, 0]
    return n, float(-n @ c), c


def _robust_refine(p: np.ndarray, n: np.ndarray, d: float, min_band: float, max_band: float,
                   iters: int = 6):
    """Iterated LS fit with a 3-sigma (MAD) inlier band; returns (n, d, mask, sigma)."""
    band = max_band
    mask = np.abs(p @ n + d) < band
    sigma = band / 3
    for _ in range(iters):
        if mask.sum() < 3:
            break
        n, d, _ = _fit(p[mask])
        r = p @ n + d
        sigma = 1.4826 * float(np.median(np.abs(r[mask] - np.median(r[mask]))))
        new_band = float(np.clip(3.0 * sigma, min_band, max_band))
        new_mask = np.abs(r) < new_band
        if np.array_equal(new_mask, mask) and abs(new_band - band) < 1e-4:
            break
        mask, band = new_mask, new_band
    return n, d, mask, sigma


def _plane_axes(n: np.ndarray) -> np.ndarray:
    ref = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(ref, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return np.stack([u, v])


def _components(uv: np.ndarray, cell: float, gap: float):
    """Connected pieces of 2-D points (cells closer than ``gap`` join); yields point masks and the
    occupancy grid of each piece with its origin."""
    from scipy import ndimage

    lo = uv.min(0)
    ij = np.floor((uv - lo) / cell).astype(np.int64)
    shape = ij.max(0) + 1
    occ = np.zeros(shape, bool)
    occ[ij[:, 0], ij[:, 1]] = True
    r = max(1, int(np.ceil(gap / cell / 2)))
    grown = ndimage.binary_dilation(occ, structure=np.ones((2 * r + 1, 2 * r + 1), bool))
    lab, n = ndimage.label(grown)
    plab = lab[ij[:, 0], ij[:, 1]]
    for k in range(1, n + 1):
        m = plab == k
        yield m, occ & (lab == k), lo


def _outline(occ: np.ndarray, lo: np.ndarray, cell: float, tol: float, close: int = 2) -> np.ndarray:
    """Simplified outer boundary (K, 2) of an occupancy grid, in plane coordinates [m]: the grid
    is closed (gaps up to 2 ``close`` cells), its holes filled, and the contour enclosing the
    largest area is kept."""
    import contourpy
    from scipy import ndimage

    pad = close + 2
    z = np.pad(occ, pad)
    z = ndimage.binary_fill_holes(ndimage.binary_closing(z, iterations=close) | z)
    gen = contourpy.contour_generator(z=z.astype(np.float64), line_type=contourpy.LineType.Separate)
    lines = gen.lines(0.5)
    if not lines:
        return np.zeros((0, 2))

    def area(line):
        x, y = line[:, 0], line[:, 1]
        return abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))

    line = max(lines, key=area)  # (K, 2) in (col, row) = (j, i) grid units
    pts = np.stack([line[:, 1] - pad + 0.5, line[:, 0] - pad + 0.5], 1) * cell + lo
    if len(pts) > 1 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    return _simplify(pts, tol)


def _simplify(pts: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker on a closed polyline."""
    if len(pts) < 4:
        return pts

    def dp(a: np.ndarray) -> list[int]:
        keep = [0, len(a) - 1]
        stack = [(0, len(a) - 1)]
        while stack:
            i, j = stack.pop()
            if j <= i + 1:
                continue
            seg = a[j] - a[i]
            L = np.linalg.norm(seg)
            rel = a[i + 1:j] - a[i]
            dist = np.abs(seg[0] * rel[:, 1] - seg[1] * rel[:, 0]) / L if L > 0 else np.linalg.norm(rel, axis=1)
            k = int(np.argmax(dist))
            if dist[k] > tol:
                m = i + 1 + k
                keep.append(m)
                stack += [(i, m), (m, j)]
        return sorted(set(keep))

    far = int(np.argmax(np.linalg.norm(pts - pts[0], axis=1)))
    a = dp(pts[: far + 1])
    b = dp(np.concatenate([pts[far:], pts[:1]]))
    idx = a + [far + k for k in b[1:-1]]
    return pts[idx]


def extract_planes(points, labels, *, classes=PLANAR_CLASSES, min_points: int = 500,
                   min_area: float = 0.5, max_band: float = 0.10, min_band: float = 0.01,
                   hypotheses: int = 200, sample: int = 20000, normal_deg: float = 20.0,
                   cell: float = 0.10, gap: float = 0.30, max_planes: int = 100, seed: int = 0,
                   max_search: int = 150_000, num_threads: int = 0) -> list[Plane]:
    """Planar segments of each planar class of a labelled cloud.

    Parameters
    ----------
    points : (N, 3) array_like [m]; labels : (N,) int (0 ceiling, 1 floor, 2 wall, 3 other)
    classes : which labels to extract planes of
    min_points, min_area : smallest segment kept [points], [m^2]
    max_band, min_band : limits of the inlier band (3 sigma of the residuals) [m]
    hypotheses, sample : RANSAC hypotheses per plane, points scored per hypothesis
    normal_deg : largest angle between a point's normal and the plane's [deg]
    cell, gap : grid cell of the connectivity test, widest gap inside one segment [m]
    seed : RANSAC seed (results are deterministic for a seed)
    max_search : the search runs on at most this many random points of a class; each segment
        found then takes all its points (within its band, normal test and grown footprint)
    num_threads : for the normals, 0 = all cores

    Returns
    -------
    list of :class:`Plane`, largest first within each class, classes in order ceiling, floor, wall.
    """
    p32 = as_cloud(points)
    labels = np.asarray(labels)
    if len(labels) != len(p32):
        raise ValueError(f"{len(labels)} labels for {len(p32)} points")
    rng = np.random.default_rng(seed)
    finite = np.isfinite(p32).all(1)
    centre = np.median(p32[finite], 0).astype(np.float64) if finite.any() else np.zeros(3)
    search = _Search(rng, np.cos(np.deg2rad(normal_deg)), min_points, min_area, max_band,
                     min_band, hypotheses, sample, cell, gap, max_planes, max_search, centre)
    planes: list[Plane] = []
    for c in classes:
        idx_all = np.flatnonzero((labels == c) & finite)
        if len(idx_all) < min_points:
            continue
        ls = local_shape(p32[idx_all], 0.05, num_threads)
        found = search.class_planes(int(c), idx_all, p32[idx_all].astype(np.float64), ls)
        found.sort(key=lambda pl: -len(pl.indices))
        planes += found
    return planes


@dataclass
class _Search:
    """The plane search of :func:`extract_planes` (its parameters, see there)."""

    rng: np.random.Generator
    cos_tol: float
    min_points: int
    min_area: float
    max_band: float
    min_band: float
    hypotheses: int
    sample: int
    cell: float
    gap: float
    max_planes: int
    max_search: int
    centre: np.ndarray  # (3,) median of the cloud: walls are oriented towards it

    def class_planes(self, c: int, idx_all, P, ls) -> list[Plane]:
        """Planes of class ``c``: points ``P`` (indices ``idx_all`` in the cloud), local shape
        ``ls`` of :func:`~tripod_processor.preprocess.local_shape`."""
        rng, cos_tol, max_band, min_band = self.rng, self.cos_tol, self.max_band, self.min_band
        N = ls[:, :3].astype(np.float64)
        planar = (ls[:, 4] - ls[:, 3]) / np.maximum(ls[:, 5], 1e-12) > 0.5
        # search on a random subset (fast), then give each segment all its points (accurate)
        S = np.sort(rng.choice(len(P), self.max_search, replace=False)) \
            if len(P) > self.max_search else np.arange(len(P))
        frac = len(S) / len(P)
        min_sub = max(30, int(self.min_points * frac))
        PS, NS, planar_S = P[S], N[S], planar[S]
        alive = np.ones(len(S), bool)
        assigned = np.zeros(len(P), bool)
        found: list[Plane] = []
        failures = 0
        while alive.sum() >= min_sub and len(found) < self.max_planes and failures < 3:
            live = np.flatnonzero(alive)
            best = self._best_hypothesis(PS, NS, planar_S, live, min_sub)
            if best is None:
                break
            Pl, Nl = PS[live], NS[live]
            near = np.abs(Pl @ best[0] + best[1]) < 2 * max_band
            n, d, mask, sigma = _robust_refine(Pl[near], best[0], best[1], min_band, max_band)
            agree = np.abs(Nl[near] @ n) > cos_tol
            members = live[near][mask & (np.abs(Nl[near] @ n) > cos_tol * 0.9)]
            # the tails of this surface's noise (beyond the 3-sigma band, within 6 sigma, same
            # orientation) must not seed planes of their own
            band = float(np.clip(3.0 * sigma, min_band, max_band))
            tails = live[near][(np.abs(Pl[near] @ n + d) < 2 * band) & agree]
            alive[tails] = False
            if len(members) < min_sub:
                failures += 1
                continue
            alive[members] = False
            found += self._pieces(c, idx_all, P, N, PS[members], n, d, band, assigned, min_sub)
        return found

    def _best_hypothesis(self, PS, NS, planar_S, live, min_sub):
        """(normal, offset) of the best of the RANSAC hypotheses seeded at planar live points,
        or None when none is supported by enough points."""
        rng = self.rng
        sub = live if len(live) <= self.sample else rng.choice(live, self.sample, replace=False)
        seeds_pool = sub[planar_S[sub]]
        if len(seeds_pool) == 0:
            return None
        Ps, Ns = PS[sub], NS[sub]
        cand = rng.choice(seeds_pool, min(self.hypotheses, len(seeds_pool)), replace=False)
        # all hypotheses at once: (S, H) distance and normal tests in two matrix products
        Hn = NS[cand]
        Hd = -np.einsum("ij,ij->i", Hn, PS[cand])
        ok = (np.abs(Ps @ Hn.T + Hd) < self.max_band) & (np.abs(Ns @ Hn.T) > self.cos_tol)
        scores = ok.sum(0)
        k = int(np.argmax(scores))
        if int(scores[k]) * len(live) / len(sub) < min_sub:
            return None
        return Hn[k], float(Hd[k])

    def _pieces(self, c, idx_all, P, N, members_xyz, n, d, band, assigned, min_sub) -> list[Plane]:
        """The connected pieces of one found plane, each given its full-resolution points (not
        yet ``assigned`` to another plane; marked assigned here)."""
        from scipy import ndimage

        cell, gap = self.cell, self.gap
        axes = _plane_axes(n)
        o = members_xyz.mean(0)
        uv = (members_xyz - o) @ axes.T
        # full-resolution candidates of this plane, once for all its pieces
        free = np.flatnonzero(~assigned)
        cand_full = free[(np.abs(P[free] @ n + d) < band)
                         & (np.abs(N[free] @ n) > self.cos_tol * 0.9)]
        uv_full = (P[cand_full] - o) @ axes.T
        r = max(1, int(np.ceil(gap / cell / 2)))
        out = []
        for m, occ, lo in _components(uv, cell, gap):
            area = float(occ.sum()) * cell * cell
            if m.sum() < min_sub or area < self.min_area:
                continue
            grown = ndimage.binary_dilation(occ, iterations=r)
            ij = np.floor((uv_full - lo) / cell).astype(np.int64)
            inside = (ij >= 0).all(1) & (ij[:, 0] < occ.shape[0]) & (ij[:, 1] < occ.shape[1])
            inside[inside] = grown[ij[inside, 0], ij[inside, 1]]
            seg = cand_full[inside & ~assigned[cand_full]]
            if len(seg) < self.min_points:
                continue
            n2, d2, mask2, sig2 = _robust_refine(P[seg], n, d, self.min_band, self.max_band,
                                                 iters=3)
            seg = seg[mask2]
            if len(seg) < self.min_points:  # the refit's band kept too few (or none)
                continue
            assigned[seg] = True
            out.append(self._oriented_plane(c, idx_all, P, seg, n2, d2, sig2))
        return out

    def _oriented_plane(self, c, idx_all, P, seg, n2, d2, sig2) -> Plane:
        """The :class:`Plane` of points ``seg``, its normal into the room, with its outline."""
        if c == FLOOR:
            flip = n2[2] < 0
        elif c == CEILING:
            flip = n2[2] > 0
        else:
            flip = (n2 @ self.centre + d2) < 0
        if flip:
            n2, d2 = -n2, -d2
        origin = P[seg].mean(0)
        origin = origin - (n2 @ origin + d2) * n2
        ax = _plane_axes(n2)
        uv2 = (P[seg] - origin) @ ax.T
        outline2 = np.zeros((0, 2))
        area = 0.0
        cell, gap = self.cell, self.gap
        for _, occ2, lo2 in _components(uv2, cell, gap):
            outline2 = _outline(occ2, lo2, cell, tol=cell,
                                close=max(1, int(np.ceil(gap / cell / 2))))
            area = float(occ2.sum()) * cell * cell
            break
        outline = origin + outline2 @ ax
        return Plane(int(c), n2, float(d2), idx_all[seg], origin, ax, outline, float(sig2), area)


def plane_inlier_share(points, labels, planes: list[Plane], tolerance: float = 0.05,
                       classes=PLANAR_CLASSES) -> float:
    """Share of the points labelled with a planar class that lie within ``tolerance`` [m] of a
    plane of their class (inside the plane's outline is not required)."""
    p = np.asarray(points, np.float64)
    labels = np.asarray(labels)
    sel = np.isin(labels, classes) & np.isfinite(p).all(1)
    if not sel.any():
        return float("nan")
    close = np.zeros(len(p), bool)
    for pl in planes:
        m = sel & (labels == pl.label)
        close[m] |= np.abs(pl.distance(p[m])) < tolerance
    return float(close[sel].mean())
