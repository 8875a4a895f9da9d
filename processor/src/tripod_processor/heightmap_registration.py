# SPDX-License-Identifier: BSD-3-Clause
"""Registration of two indoor scans by matching their floor heightmaps.

Both clouds are levelled on their floor plane (which fixes roll, pitch and height), then each
becomes a *plan heightmap*: an image over the floor plane whose pixels hold the height of the
tallest point standing on it (walls reach the ceiling, furniture stops lower). Matching the two
images under a 2-D rotation and translation gives the remaining yaw and x-y shift:

1. **coarse** — for every yaw on a grid (default 2 deg) the source points are turned and
   rasterised, and the translation comes from an FFT cross-correlation with the target image
   (zero-mean, normalised); the best peak wins;
2. **fine** — the same at a finer pixel and yaw step around the coarse answer, with a
   sub-pixel parabolic peak;
3. **3-D** — the image transform is lifted to T_target_source through the two levelling
   transforms; Hu moments of the two floor footprints and the correlation peak are reported;
4. **verify** (and optionally refine) — the best few coarse answers are refined; the one with
   the highest image score among those whose overlap (fitness) passes wins (symmetric rooms
   overlap equally well under each symmetry, only the furniture in the image tells them
   apart); point-to-plane ICP polishes it; fitness and inlier RMSE say whether to trust it.

Exposed to ``tripod register`` as its heightmap method through :func:`register_by_heightmaps`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .planes import CEILING, FLOOR, extract_planes


@dataclass
class HeightmapMatch:
    """Result: T_target_source (4, 4) maps source points into the target frame.

    score : normalised correlation of the plan heightmaps at the match (0..1)
    fitness, inlier_rmse : overlap share and RMSE [m] of the ICP check (within ``max_distance``)
    hu_distance : distance of the floor footprints' log Hu moments (0 = same shape)
    success : the check passed (fitness >= min_fitness)
    seconds : wall time; stages : per-stage times [s]
    """

    T_target_source: np.ndarray
    score: float
    fitness: float
    inlier_rmse: float
    hu_distance: float
    success: bool
    seconds: float
    stages: dict = field(default_factory=dict)


def _rot_to_z(n: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit n onto +z."""
    n = n / np.linalg.norm(n)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(v), n[2]
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


@dataclass
class LevelledScan:
    """A scan on its floor: T_level_scan (4, 4) puts the floor at z = 0 with +z up; ``xy``/``z``
    are the points standing between floor and ceiling in that frame, ``floor_xy`` the floor's."""

    T_level_scan: np.ndarray
    xy: np.ndarray
    z: np.ndarray
    floor_xy: np.ndarray
    height: float
    labels: np.ndarray


def level_scan(points, labels, *, seed: int = 0, max_points: int = 200_000) -> LevelledScan:
    """Level a labelled scan on its largest floor plane (and measure the ceiling height)."""
    P = np.asarray(points, np.float64)
    labels = np.asarray(labels)
    ok = np.isfinite(P).all(1)
    P, labels = P[ok], labels[ok]
    if len(P) > max_points:  # planes and images need no more
        idx = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
        P, labels = P[idx], labels[idx]
    planes = extract_planes(P, labels, classes=(FLOOR, CEILING), min_points=200, seed=seed)
    floors = [p for p in planes if p.label == FLOOR]
    if not floors:
        raise ValueError("no floor plane found: cannot level the scan")
    fl = max(floors, key=lambda p: len(p.indices))
    R = _rot_to_z(fl.normal)
    T = np.eye(4)
    T[:3, :3] = R
    T[2, 3] = fl.offset  # n.x + d = 0 on the floor -> z' = n.x + d
    Q = P @ R.T + T[:3, 3]
    ceilings = [p for p in planes if p.label == CEILING]
    if ceilings:
        cl = max(ceilings, key=lambda p: len(p.indices))
        height = float(np.median(Q[cl.indices, 2]))
    else:
        height = float(np.percentile(Q[:, 2], 99.5))
    band = (Q[:, 2] > 0.10) & (Q[:, 2] < height - 0.10)
    return LevelledScan(T, Q[band, :2], Q[band, 2], Q[fl.indices, :2], height, labels[band])


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


def _xcorr_peak(F_target: np.ndarray, src: np.ndarray, window=None, extra=None):
    """Peak of the circular cross-correlation (shift of src onto target) with sub-pixel refinement.
    window: optional ((i0, j0), radius) limiting the search to shifts near (i0, j0);
    extra: optional (F_target2, src2), a second channel whose correlation is added."""
    from scipy import fft

    X = F_target * np.conj(fft.rfft2(src, workers=-1))
    if extra is not None:
        X = X + extra[0] * np.conj(fft.rfft2(extra[1], workers=-1))
    c = fft.irfft2(X, s=src.shape, workers=-1)
    if window is not None:
        (i0, j0), r = window
        H, W = c.shape
        ii = (np.arange(-r, r + 1) + i0) % H
        jj = (np.arange(-r, r + 1) + j0) % W
        sub = c[np.ix_(ii, jj)]
        a, b = np.unravel_index(int(np.argmax(sub)), sub.shape)
        i, j = int(ii[a]), int(jj[b])
    else:
        i, j = np.unravel_index(int(np.argmax(c)), c.shape)
    peak = float(c[i, j])
    H, W = c.shape

    def parabola(m1, z0, p1):
        den = m1 - 2 * z0 + p1
        return 0.0 if abs(den) < 1e-12 else 0.5 * (m1 - p1) / den

    di = parabola(c[(i - 1) % H, j], peak, c[(i + 1) % H, j])
    dj = parabola(c[i, (j - 1) % W], peak, c[i, (j + 1) % W])
    si = (i + di + H / 2) % H - H / 2  # wrap to signed shifts
    sj = (j + dj + W / 2) % W - W / 2
    return peak, np.array([si, sj])


def _channels(xy, z, labels, lo, pixel, shape) -> list[np.ndarray]:
    """Plan heightmap channels: walls (occupancy) and the rest (tallest point [m]); each
    normalised. Walls give the room's outline, the rest breaks its symmetries."""
    wall = labels == 2
    return [_normalise(_raster(xy[wall], np.ones(wall.sum()), lo, pixel, shape)),
            _normalise(_raster(xy[~wall], z[~wall], lo, pixel, shape))]


def _search(src: LevelledScan, tgt: LevelledScan, yaws: np.ndarray, pixel: float, window=None,
            max_points: int = 30_000, seed: int = 0, keep: int = 1, other_weight: float = 2.0):
    """The ``keep`` best (score, yaw, shift [m]) over the yaws (at least 20 deg apart); shift maps
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
        peak, shift = _xcorr_peak(F_t[0] + 0.0, S_c[0], win, extra=(other_weight * F_t[1], S_c[1]))
        results.append((peak, float(yaw), shift * pixel))
    results.sort(key=lambda r: -r[0])
    out = []
    for r in results:
        if all(abs((r[1] - o[1] + np.pi) % (2 * np.pi) - np.pi) > np.deg2rad(20) for o in out):
            out.append(r)
        if len(out) == keep:
            break
    return out


def hu_moments(mask: np.ndarray) -> np.ndarray:
    """The 7 Hu invariant moments of a binary image (rotation, scale, translation invariant)."""
    ys, xs = np.nonzero(mask)
    if len(xs) < 3:
        return np.zeros(7)
    m00 = float(len(xs))
    xm, ym = xs.mean(), ys.mean()
    x, y = xs - xm, ys - ym

    def eta(p, q):
        return float(np.sum(x ** p * y ** q)) / m00 ** (1 + (p + q) / 2)

    n20, n02, n11 = eta(2, 0), eta(0, 2), eta(1, 1)
    n30, n03, n21, n12 = eta(3, 0), eta(0, 3), eta(2, 1), eta(1, 2)
    h = np.empty(7)
    h[0] = n20 + n02
    h[1] = (n20 - n02) ** 2 + 4 * n11 ** 2
    h[2] = (n30 - 3 * n12) ** 2 + (3 * n21 - n03) ** 2
    h[3] = (n30 + n12) ** 2 + (n21 + n03) ** 2
    h[4] = ((n30 - 3 * n12) * (n30 + n12) * ((n30 + n12) ** 2 - 3 * (n21 + n03) ** 2)
            + (3 * n21 - n03) * (n21 + n03) * (3 * (n30 + n12) ** 2 - (n21 + n03) ** 2))
    h[5] = ((n20 - n02) * ((n30 + n12) ** 2 - (n21 + n03) ** 2)
            + 4 * n11 * (n30 + n12) * (n21 + n03))
    h[6] = ((3 * n21 - n03) * (n30 + n12) * ((n30 + n12) ** 2 - 3 * (n21 + n03) ** 2)
            - (n30 - 3 * n12) * (n21 + n03) * (3 * (n30 + n12) ** 2 - (n21 + n03) ** 2))
    return h


def _footprint_mask(xy: np.ndarray, pixel: float = 0.1) -> np.ndarray:
    from scipy import ndimage

    lo = xy.min(0)
    ij = np.floor((xy - lo) / pixel).astype(np.int64)
    m = np.zeros(ij.max(0) + 1, bool)
    m[ij[:, 0], ij[:, 1]] = True
    return ndimage.binary_fill_holes(ndimage.binary_closing(m, iterations=3))


def _log_hu(h):
    return -np.sign(h) * np.log10(np.abs(h) + 1e-30)


def register_by_heightmaps(source, target, *, source_labels=None, target_labels=None,
                           coarse_pixel: float = 0.10, coarse_step_deg: float = 2.0,
                           fine_pixel: float = 0.05, fine_step_deg: float = 0.5,
                           refine: bool = True, max_distance: float = 0.10,
                           min_fitness: float = 0.2, candidates: int = 3, other_weight: float = 2.0,
                           weights=None, seed: int = 0,
                           num_threads: int = 0) -> HeightmapMatch:
    """Rigid transform between two overlapping indoor scans by matching floor heightmaps.

    Parameters
    ----------
    source, target : (N, 3), (M, 3) array_like [m], roughly z up (levelled by an IMU; the floor
        plane absorbs any tilt), in any yaw and position
    source_labels, target_labels : (N,), (M,) class labels (0 ceiling, 1 floor, 2 wall, 3 other),
        or None to run the segmenter
    coarse_pixel, coarse_step_deg : image pixel [m] and yaw step [deg] of the global search
    fine_pixel, fine_step_deg : of the local refinement
    refine : polish the image answer with point-to-plane ICP (Open3D); else only verify with it
    max_distance : correspondence distance of the ICP check [m]
    min_fitness : overlap share needed to call the match a success
    candidates : coarse answers (yaws 20 deg apart) refined and checked (a symmetric room has as
        many equally good image matches as symmetries)
    other_weight : weight of the non-wall channel in the image score (2: chosen after the first
        benchmark run, where three symmetry twins won with 1; checked on 20 other pairs)
    weights : segmenter weights when labels are None

    Returns
    -------
    :class:`HeightmapMatch` with ``T_target_source`` (4, 4): x_target = T @ x_source.
    """
    t0 = time.perf_counter()
    stages = {}
    S = np.asarray(source, np.float64)
    Tg = np.asarray(target, np.float64)
    if source_labels is None or target_labels is None:
        from .segmentation import Segmenter

        seg = Segmenter(weights, num_threads)
        source_labels = seg(S.astype(np.float32)) if source_labels is None else source_labels
        target_labels = seg(Tg.astype(np.float32)) if target_labels is None else target_labels
        stages["segment"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    ls = level_scan(S, source_labels, seed=seed)
    lt = level_scan(Tg, target_labels, seed=seed)
    stages["level"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    # the image must stay small for big halls: a coarser pixel there
    extent = float(max(np.ptp(lt.xy, 0).max(), np.ptp(ls.xy, 0).max())) if len(lt.xy) and len(ls.xy) else 10.0
    cp = max(coarse_pixel, extent / 150)
    fp = max(fine_pixel, extent / 400)
    yaws = np.deg2rad(np.arange(0.0, 360.0, coarse_step_deg))
    coarse = _search(ls, lt, yaws, cp, seed=seed, keep=candidates, other_weight=other_weight)
    stages["coarse"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    hu_s = _log_hu(hu_moments(_footprint_mask(ls.floor_xy)))
    hu_t = _log_hu(hu_moments(_footprint_mask(lt.floor_xy)))
    hu_d = float(np.abs(hu_s[:4] - hu_t[:4]).sum())
    checker = _IcpCheck(S, Tg, max_distance)
    best = None
    for score0, yaw0, shift0 in coarse:
        fine = yaw0 + np.deg2rad(np.arange(-coarse_step_deg, coarse_step_deg + 1e-9, fine_step_deg))
        score, yaw, shift = _search(ls, lt, fine, fp, window=(shift0, int(np.ceil(2 * cp / fp)) + 2),
                                    seed=seed, other_weight=other_weight)[0]
        # image transform: target_xy = R(yaw) source_xy + shift (in the levelled frames)
        c, s = np.cos(yaw), np.sin(yaw)
        M = np.eye(4)
        M[:2, :2] = [[c, -s], [s, c]]
        M[:2, 3] = shift
        T = np.linalg.inv(lt.T_level_scan) @ M @ ls.T_level_scan
        fitness = checker.fitness(T)
        # the image score decides (walls, floor and ceiling of a symmetric hall overlap equally
        # well under each symmetry, so overlap alone would pick at random); overlap only vetoes
        key = (fitness >= min_fitness, score)
        if best is None or key > best[0]:
            best = (key, score, T)
    stages["fine"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    _, score, T = best
    fitness, rmse, T = checker.final(T, refine)
    stages["verify"] = time.perf_counter() - t1
    return HeightmapMatch(T, float(score), fitness, rmse, hu_d, fitness >= min_fitness,
                          time.perf_counter() - t0, stages)


class _IcpCheck:
    """Overlap of two clouds under a transform (Open3D), and the final point-to-plane polish."""

    def __init__(self, S, Tg, max_distance: float, voxel: float = 0.05) -> None:
        import open3d as o3d

        self.o3d = o3d
        self.max_distance = max_distance

        def pcd(p, v):
            c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
            c = c.voxel_down_sample(v)
            c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * v, max_nn=20))
            return c

        self.src, self.tgt = pcd(S, voxel), pcd(Tg, voxel)
        self.src_coarse = self.src.voxel_down_sample(0.15)

    def fitness(self, T) -> float:
        reg = self.o3d.pipelines.registration
        return float(reg.evaluate_registration(self.src_coarse, self.tgt, 2 * self.max_distance, T).fitness)

    def final(self, T, refine: bool):
        reg = self.o3d.pipelines.registration
        if refine:
            res = reg.registration_icp(self.src, self.tgt, self.max_distance, T,
                                       reg.TransformationEstimationPointToPlane(),
                                       reg.ICPConvergenceCriteria(max_iteration=30))
            T = np.asarray(res.transformation)
        res = reg.evaluate_registration(self.src, self.tgt, self.max_distance, T)
        return float(res.fitness), float(res.inlier_rmse), np.asarray(T)
