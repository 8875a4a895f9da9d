# SPDX-License-Identifier: BSD-3-Clause
"""Registration of two indoor scans by matching their plan heightmaps.

Both clouds are levelled on their floor plane (the IMU keeps them near gravity; the floor fixes
roll, pitch and height exactly), so only yaw and an x-y shift remain. Each scan becomes a *plan
heightmap*: an image over the floor whose pixels hold the height of the tallest point standing
there (walls reach the ceiling, furniture stops lower). Three matchers propose image transforms
(yaw, shift), each good where the others are weak:

1. **dense correlation** — for every yaw on a grid (2 deg) the source is turned and rasterised
   and the shift comes from an FFT cross-correlation with the target (walls and the rest as two
   channels); the best peaks of distinct yaws are kept (a rectangular room has two or four
   near-equal peaks: its symmetry twins);
2. **keypoints** — ORB (OpenCV) corners of the two heightmap images, matched by descriptor and
   filtered by a 2-D rigid RANSAC (two matches per hypothesis); the best consensus sets are kept;
3. **shapes** — the connected blobs of non-wall content (furniture, columns), described by their
   rotation-invariant Hu moments, area and height, matched and filtered by the same RANSAC.

Every proposal is refined by correlation at a finer pixel and yaw step, lifted to 3-D through the
two levelling transforms, polished by a short point-to-plane ICP on the registration core and
**verified in 3-D**: the share of the source's walls and furniture that land on target surfaces.
The twins of a symmetric room overlap equally well in floor, ceiling and bare walls; the
furniture and the relief of the walls (doors, windows, radiators) do not, so the verification,
not the image score, picks the answer. The winner is reported with its runner-up's score
(``ambiguity``): ``success`` needs enough verified overlap and a clear winner, so a pair that
does not overlap, or an empty symmetric room, comes back as a failure instead of a guess.

Exposed to ``tripod register`` as its heightmap method through :func:`register_by_heightmaps`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .planes import CEILING, FLOOR, OTHER, WALL, extract_planes


@dataclass
class HeightmapMatch:
    """Result: T_target_source (4, 4) maps source points into the target frame.

    score : normalised image correlation of the plan heightmaps at the match (0..1)
    structure_fitness : share of each scan's wall and non-planar points (10 cm voxels) within
        ``max_distance`` of the other's surface, mean of both directions: the 3-D verification
    ambiguity : best structure fitness among the other (distinct) hypotheses / the winner's
        (1: as good an answer elsewhere, e.g. an empty symmetric room)
    fitness, inlier_rmse : overlap share of all source points and RMSE [m] after the final ICP
    hu_distance : distance of the floor footprints' log Hu moments (0 = same shape)
    proposer : which matcher proposed the answer ("correlation", "keypoints", "shapes")
    hypotheses : number of distinct hypotheses verified
    free_space_violation : share of either scan's structure the other saw through, at the answer
    success : structure_fitness >= min_fitness, free_space_violation <= max_violation and
        ambiguity <= max_ambiguity
    seconds : wall time; stages : per-stage times [s]
    verified : (proposer, verification score, T_target_source, structure fitness, free-space
        violation) of every verified hypothesis, best first (score = fitness - weight x violation)
    """

    T_target_source: np.ndarray
    score: float
    structure_fitness: float
    free_space_violation: float
    ambiguity: float
    fitness: float
    inlier_rmse: float
    hu_distance: float
    proposer: str
    hypotheses: int
    success: bool
    seconds: float
    stages: dict = field(default_factory=dict)
    verified: list = field(default_factory=list)


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


# ------------------------------------------------------------------------ keypoints and shapes
def plan_image(scan: "LevelledScan", pixel: float, border: int = 24):
    """8-bit plan heightmap of a levelled scan (tallest point over the floor, ceiling = 255) and
    its origin: pixel [i, j] covers x = lo_x + i * pixel, y = lo_y + j * pixel.

    Returns (img (H, W) uint8, lo (2,) [m]); ``border`` empty pixels around the content.
    """
    from scipy import ndimage

    lo = scan.xy.min(0) - border * pixel if len(scan.xy) else np.zeros(2)
    hi = scan.xy.max(0) + border * pixel if len(scan.xy) else np.ones(2)
    shape = tuple(int(v) for v in np.ceil((hi - lo) / pixel) + 1)
    img = _raster(scan.xy, scan.z / max(scan.height, 1e-3), lo, pixel, shape)
    img = ndimage.grey_closing(img, size=3)  # close the gaps between scan lines
    return np.clip(img * 255, 0, 255).astype(np.uint8), lo


def _ij_to_xy(ij: np.ndarray, lo: np.ndarray, pixel: float) -> np.ndarray:
    return lo + (ij + 0.5) * pixel


def orb_keypoints(img: np.ndarray, max_features: int = 1500):
    """ORB keypoints (row-column positions (K, 2)) and descriptors (K, 32) uint8 of an image."""
    import cv2

    orb = cv2.ORB_create(nfeatures=max_features, scaleFactor=1.3, nlevels=3, edgeThreshold=19,
                         patchSize=19, fastThreshold=10)
    kps, desc = orb.detectAndCompute(img, None)
    if desc is None or len(kps) < 2:
        return np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    ij = np.array([(k.pt[1], k.pt[0]) for k in kps])  # cv2 gives (column, row)
    return ij, desc


def match_binary(da: np.ndarray, db: np.ndarray, k: int = 2) -> np.ndarray:
    """Pairs (M, 2) of indices: each descriptor of ``da`` with its ``k`` nearest in ``db``
    (Hamming). Repetitive structure (a row of identical windows) has no unique best match, so
    more than the best is kept and the RANSAC sorts them."""
    import cv2

    if len(da) == 0 or len(db) == 0:
        return np.zeros((0, 2), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    out = [(m.queryIdx, m.trainIdx) for ms in bf.knnMatch(da, db, k=min(k, len(db))) for m in ms]
    return np.array(out, np.int64).reshape(-1, 2)


def shape_blobs(scan: "LevelledScan", pixel: float = 0.05, min_area: float = 0.08,
                max_area: float = 6.0):
    """Blobs of "other" content in the plan (furniture, columns, cabinets) with shape
    descriptors: centroids (K, 2) [m] and descriptors (K, 7): log |Hu| 1-4 (rotation
    invariant), log area [m^2], median and top height [m]."""
    from scipy import ndimage

    keep = scan.labels == OTHER
    xy, z = scan.xy[keep], scan.z[keep]
    if len(xy) < 10:
        return np.zeros((0, 2)), np.zeros((0, 7))
    lo = xy.min(0) - 2 * pixel
    shape = tuple(int(v) for v in np.ceil((xy.max(0) + 2 * pixel - lo) / pixel) + 1)
    h = _raster(xy, z, lo, pixel, shape)
    mask = ndimage.binary_closing(h > 0, iterations=2)
    lab, n = ndimage.label(mask)
    cents, descs = [], []
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        m = lab[sl] == k
        area = m.sum() * pixel ** 2
        if not (min_area <= area <= max_area):
            continue
        ii, jj = np.nonzero(m)
        c = np.array([ii.mean() + sl[0].start, jj.mean() + sl[1].start])
        hv = h[sl][m]
        hv = hv[hv > 0]
        hu = _log_hu(hu_moments(m))[:4]
        cents.append(_ij_to_xy(c, lo, pixel))
        descs.append([*(hu / 3.0), np.log(area), 2 * np.median(hv), 2 * hv.max()])
    if not cents:
        return np.zeros((0, 2)), np.zeros((0, 7))
    return np.array(cents), np.array(descs)


def match_nearest(da: np.ndarray, db: np.ndarray, k: int = 2, max_distance: float = 1.5):
    """Pairs (M, 2): each row of ``da`` with its ``k`` nearest rows of ``db`` (Euclidean)
    closer than ``max_distance``."""
    if len(da) == 0 or len(db) == 0:
        return np.zeros((0, 2), np.int64)
    d = np.linalg.norm(da[:, None, :] - db[None, :, :], axis=2)
    nn = np.argsort(d, axis=1)[:, :k]
    pairs = [(i, j) for i in range(len(da)) for j in nn[i] if d[i, j] < max_distance]
    return np.array(pairs, np.int64).reshape(-1, 2)


def rigid_2d_ransac(a: np.ndarray, b: np.ndarray, *, inlier_m: float = 0.15,
                    min_separation_m: float = 0.5, iterations: int = 3000, keep: int = 3,
                    min_inliers: int = 4, seed: int = 0):
    """2-D rigid transforms b ~ R(yaw) a + t from putative matches, RANSAC with two matches per
    hypothesis (a pair of matches whose lengths disagree by more than ``inlier_m`` is skipped).

    Parameters
    ----------
    a, b : (M, 2) matched positions [m] (source, target)
    keep : consensus sets returned, best first, each after removing the previous one's inliers

    Returns
    -------
    list of (inliers, yaw [rad], t (2,) [m]), refined by least squares on the inliers.
    """
    rng = np.random.default_rng(seed)
    out = []
    alive = np.ones(len(a), bool)
    for _ in range(keep):
        idx = np.flatnonzero(alive)
        if len(idx) < max(2, min_inliers):
            break
        i = idx[rng.integers(0, len(idx), iterations)]
        j = idx[rng.integers(0, len(idx), iterations)]
        da, db = a[j] - a[i], b[j] - b[i]
        la, lb = np.linalg.norm(da, axis=1), np.linalg.norm(db, axis=1)
        ok = (la > min_separation_m) & (np.abs(la - lb) < inlier_m)
        if not ok.any():
            break
        i, j, da, db = i[ok], j[ok], da[ok], db[ok]
        yaw = np.arctan2(db[:, 1], db[:, 0]) - np.arctan2(da[:, 1], da[:, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        mid_a, mid_b = (a[i] + a[j]) / 2, (b[i] + b[j]) / 2
        t = mid_b - np.stack([c * mid_a[:, 0] - s * mid_a[:, 1],
                              s * mid_a[:, 0] + c * mid_a[:, 1]], 1)
        A, B = a[idx], b[idx]
        px = c[:, None] * A[None, :, 0] - s[:, None] * A[None, :, 1] + t[:, :1]
        py = s[:, None] * A[None, :, 0] + c[:, None] * A[None, :, 1] + t[:, 1:]
        inl = (px - B[None, :, 0]) ** 2 + (py - B[None, :, 1]) ** 2 < inlier_m ** 2
        # one source point counts once however many of its matches agree
        src_ids = np.unique(a[idx], axis=0, return_inverse=True)[1].ravel()
        counts = np.array([len(np.unique(src_ids[r])) for r in inl])
        best = int(np.argmax(counts))
        if counts[best] < min_inliers:
            break
        members = idx[inl[best]]
        y, tt = _fit_rigid_2d(a[members], b[members])
        out.append((members, y, tt))
        alive[members] = False
    return out


def _fit_rigid_2d(a: np.ndarray, b: np.ndarray):
    """Least-squares yaw [rad] and t (2,) with b ~ R(yaw) a + t."""
    ma, mb = a.mean(0), b.mean(0)
    A, B = a - ma, b - mb
    yaw = float(np.arctan2((A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0]).sum(),
                           (A * B).sum()))
    c, s = np.cos(yaw), np.sin(yaw)
    return yaw, mb - np.array([[c, -s], [s, c]]) @ ma


# ----------------------------------------------------------------------------------- pipeline
def register_by_heightmaps(source, target, *, source_labels=None, target_labels=None,
                           coarse_pixel: float = 0.10, coarse_step_deg: float = 2.0,
                           fine_pixel: float = 0.05, fine_step_deg: float = 0.5,
                           feature_pixel: float = 0.05, candidates: int = 40, verify: int = 8,
                           use_keypoints: bool = True, use_shapes: bool = True,
                           max_distance: float = 0.08, min_fitness: float = 0.4,
                           max_ambiguity: float = 0.97, max_violation: float = 0.05,
                           other_weight: float = 2.0,
                           free_space_weight: float = 10.0, viewpoint_source=(0.0, 0.0, 0.0),
                           viewpoint_target=(0.0, 0.0, 0.0), weights=None, seed: int = 0,
                           num_threads: int = 0) -> HeightmapMatch:
    """Rigid transform between two overlapping indoor scans by matching plan heightmaps.

    Parameters
    ----------
    source, target : (N, 3), (M, 3) array_like [m], roughly z up (levelled by an IMU; the floor
        plane absorbs any tilt), in any yaw and position
    source_labels, target_labels : (N,), (M,) class labels (0 ceiling, 1 floor, 2 wall, 3 other),
        or None to run the segmenter
    coarse_pixel, coarse_step_deg : image pixel [m] and yaw step [deg] of the dense search
    fine_pixel, fine_step_deg : of the refinement of every hypothesis
    feature_pixel : pixel [m] of the images the keypoints and shapes are found on
    candidates : best distinct answers (yaws 20 deg or shifts 1 m apart) the dense search
        proposes (five correlation peaks per yaw); all proposals are screened in 3-D as they
        are, the best ``verify`` of them refined, polished by ICP and verified
    use_keypoints, use_shapes : also propose from ORB keypoints / Hu-moment shape matches
    max_distance : inlier distance of the 3-D verification [m]
    min_fitness : verified structure overlap needed to call the match a success
    max_ambiguity : runner-up / winner verification score above which the answer is not unique
    max_violation : share of structure seen through by the other scan above which the answer is
        inconsistent (two different rooms of similar shape overlap well, but not in free space)
    free_space_weight : weight of that share against the structure fitness when ranking
        hypotheses (a point seen through is a contradiction, a missing overlap is only unseen)
    viewpoint_source, viewpoint_target : (3,) the sensor position in each cloud's frame [m]
        (a fragment's origin): the free-space check and the normals' orientation need it
    other_weight : weight of the non-wall channel in the correlation score
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
    source_labels, target_labels = np.asarray(source_labels), np.asarray(target_labels)

    # 1. level both scans on their floors
    t1 = time.perf_counter()
    ls = level_scan(S, source_labels, seed=seed)
    lt = level_scan(Tg, target_labels, seed=seed)
    stages["level"] = time.perf_counter() - t1

    # 2. proposals (yaw, shift) of the levelled source onto the levelled target
    t1 = time.perf_counter()
    extent = (float(max(np.ptp(lt.xy, 0).max(), np.ptp(ls.xy, 0).max()))
              if len(lt.xy) and len(ls.xy) else 10.0)
    cp = max(coarse_pixel, extent / 150)  # the images stay small for big halls
    fp = max(fine_pixel, extent / 400)
    yaws = np.deg2rad(np.arange(0.0, 360.0, coarse_step_deg))
    proposals = [(yaw, shift, "correlation", score) for score, yaw, shift in
                 _search(ls, lt, yaws, cp, seed=seed, keep=candidates, other_weight=other_weight,
                         shifts=5)]
    stages["correlation"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    fpx = max(feature_pixel, extent / 400)
    if use_keypoints:
        img_s, lo_s = plan_image(ls, fpx)
        img_t, lo_t = plan_image(lt, fpx)
        ij_s, d_s = orb_keypoints(img_s)
        ij_t, d_t = orb_keypoints(img_t)
        m = match_binary(d_s, d_t)
        if len(m) >= 4:
            a = _ij_to_xy(ij_s[m[:, 0]], lo_s, fpx)
            b = _ij_to_xy(ij_t[m[:, 1]], lo_t, fpx)
            for inl, yaw, t in rigid_2d_ransac(a, b, inlier_m=3 * fpx, min_inliers=6, seed=seed):
                proposals.append((yaw, t, "keypoints", float(len(inl))))
        stages["keypoints"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    if use_shapes:
        c_s, h_s = shape_blobs(ls, fpx)
        c_t, h_t = shape_blobs(lt, fpx)
        m = match_nearest(h_s, h_t, k=3)
        if len(m) >= 3:
            for inl, yaw, t in rigid_2d_ransac(c_s[m[:, 0]], c_t[m[:, 1]], inlier_m=0.2,
                                                min_inliers=3, seed=seed):
                proposals.append((yaw, t, "shapes", float(len(inl))))
        stages["shapes"] = time.perf_counter() - t1

    # 3. screen the distinct proposals in 3-D as they are (loose distance, free space), then
    #    refine the best by correlation (fine pixel and yaw) and lift them to 3-D
    t1 = time.perf_counter()
    check = _Verifier(S, source_labels, Tg, target_labels, max_distance, viewpoint_source,
                      viewpoint_target, num_threads)
    screened = []
    for yaw0, shift0, who, _ in proposals:
        yaw0, shift0 = float(yaw0), np.asarray(shift0, np.float64)
        if any(_close(yaw0, shift0, h[1], h[2]) for h in screened):
            continue
        T0 = _lift(ls, lt, yaw0, shift0)
        pre = (check.structure_fitness(T0, 3 * cp, screen=True)
               - free_space_weight * check.free_space_violation(T0, screen=True))
        screened.append((pre, yaw0, shift0, who))
    screened.sort(key=lambda h: -h[0])
    hyps = []
    for _, yaw0, shift0, who in screened[:verify]:
        fine = yaw0 + np.deg2rad(np.arange(-coarse_step_deg, coarse_step_deg + 1e-9, fine_step_deg))
        win = (shift0, int(np.ceil(2 * cp / fp)) + 2)
        score, yaw, shift = _search(ls, lt, fine, fp, window=win,
                                    seed=seed, other_weight=other_weight)[0]
        hyps.append((score, who, _lift(ls, lt, yaw, shift)))
    stages["screen+refine"] = time.perf_counter() - t1

    # 4. verify in 3-D: short ICP, then the share of walls and furniture on the other's
    #    surfaces, less what either scan saw through
    t1 = time.perf_counter()
    checked = []
    for score, who, T in hyps:
        T_icp = check.polish(T)
        fit, viol = check.structure_fitness(T_icp), check.free_space_violation(T_icp)
        checked.append((fit - free_space_weight * viol, score, who, T_icp, fit, viol))
    checked.sort(key=lambda c: -c[0])
    best = checked[0]
    others = [c for c in checked[1:] if not _same_pose(c[3], best[3])]
    if best[0] <= 0:  # even the best contradicts free space or barely overlaps: no winner
        ambiguity = 1.0
    else:
        ambiguity = max(0.0, others[0][0] / best[0]) if others else 0.0
    stages["verify"] = time.perf_counter() - t1

    # 5. final polish at full density
    t1 = time.perf_counter()
    T, fitness, rmse = check.final(best[3])
    sfit = check.structure_fitness(T)
    stages["final"] = time.perf_counter() - t1
    hu_s = _log_hu(hu_moments(_footprint_mask(ls.floor_xy)))
    hu_t = _log_hu(hu_moments(_footprint_mask(lt.floor_xy)))
    hu_d = float(np.abs(hu_s[:4] - hu_t[:4]).sum())
    viol = check.free_space_violation(T)
    ok = sfit >= min_fitness and viol <= max_violation and ambiguity <= max_ambiguity
    return HeightmapMatch(T, float(best[1]), float(sfit), float(viol), float(ambiguity), fitness,
                          rmse, hu_d,
                          best[2], len(checked), bool(ok), time.perf_counter() - t0, stages,
                          [(c[2], c[0], c[3], c[4], c[5]) for c in checked])


def _close(yaw_a, shift_a, yaw_b, shift_b, yaw_tol=np.deg2rad(3.0), shift_tol=0.3) -> bool:
    dy = abs((yaw_a - yaw_b + np.pi) % (2 * np.pi) - np.pi)
    ds = float(np.linalg.norm(np.asarray(shift_a) - np.asarray(shift_b)))
    return dy < yaw_tol and ds < shift_tol


def _same_pose(A, B, deg: float = 3.0, m: float = 0.2) -> bool:
    E = np.linalg.inv(A) @ B
    ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return ang < deg and np.linalg.norm(E[:3, 3]) < m


def _lift(ls: "LevelledScan", lt: "LevelledScan", yaw: float, shift) -> np.ndarray:
    """T_target_source from the image transform target_xy = R(yaw) source_xy + shift (levelled)."""
    c, s = np.cos(yaw), np.sin(yaw)
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    M[:2, 3] = shift
    return np.linalg.inv(lt.T_level_scan) @ M @ ls.T_level_scan


class _RangeImage:
    """Nearest return per direction around a scan's viewpoint: a spherical image (``step_deg``
    bins of azimuth and elevation) of the smallest range, eroded over the 3 x 3 neighbourhood so
    that only space seen through in every neighbouring direction counts as free."""

    def __init__(self, P: np.ndarray, viewpoint, step_deg: float = 0.5) -> None:
        from scipy import ndimage

        self.v = np.asarray(viewpoint, np.float64).reshape(3)
        self.step = np.radians(step_deg)
        self.shape = (int(round(2 * np.pi / self.step)), int(round(np.pi / self.step)) + 1)
        i, j, r = self._bins(P)
        img = np.full(self.shape, np.inf)
        np.minimum.at(img, (i, j), r)
        self.img = ndimage.minimum_filter(img, size=3, mode="wrap")

    def _bins(self, P):
        d = np.asarray(P, np.float64) - self.v
        r = np.linalg.norm(d, axis=1)
        az = np.arctan2(d[:, 1], d[:, 0]) + np.pi
        el = np.arcsin(np.clip(d[:, 2] / np.maximum(r, 1e-9), -1, 1)) + np.pi / 2
        i = np.minimum((az / self.step).astype(np.int64), self.shape[0] - 1)
        j = np.minimum((el / self.step).astype(np.int64), self.shape[1] - 1)
        return i, j, r

    def seen_through(self, P) -> np.ndarray:
        """(N,) bool: the point lies clearly in front of the nearest return in its direction."""
        i, j, r = self._bins(P)
        lim = self.img[i, j]
        return np.isfinite(lim) & (r < 0.95 * lim - 0.10)


def _in_free_space(P: np.ndarray, rimg: _RangeImage) -> float:
    return float(rimg.seen_through(P).mean()) if len(P) else 0.0


class _Verifier:
    """3-D checks of hypotheses on the registration core: a short point-to-plane ICP, and the
    share of the source's structure (walls and non-planar content, 10 cm voxels) that lands
    within ``max_distance`` of a target point. Floor and ceiling are left out of that share:
    they overlap under any yaw once both scans are levelled."""

    def __init__(self, S, labels_s, Tg, labels_t, max_distance: float, viewpoint_s, viewpoint_t,
                 num_threads: int = 0) -> None:
        from scipy.spatial import cKDTree

        from .preprocess import voxel_downsample
        from .registration import prepare

        self.max_distance = max_distance
        self.threads = num_threads
        self.src = prepare(S.astype(np.float32), 0.10, num_threads=num_threads)
        self.tgt = prepare(Tg.astype(np.float32), 0.10, num_threads=num_threads)
        self._S, self._Tg = S, Tg
        def structure(P, lab):
            st = P[(lab == WALL) | (lab == OTHER)]
            if len(st) < 100:  # a scan of floor and ceiling only: use everything
                st = P
            return np.asarray(voxel_downsample(st.astype(np.float32), 0.10), np.float64)

        self.struct, self.struct_t = structure(S, labels_s), structure(Tg, labels_t)
        # an even subset for screening many hypotheses
        self.few = self.struct[:: max(1, len(self.struct) // 3000)]
        self.few_t = self.struct_t[:: max(1, len(self.struct_t) // 3000)]
        self.range_s = _RangeImage(S, viewpoint_s)
        self.range_t = _RangeImage(Tg, viewpoint_t)
        def surface(P):
            dense = prepare(P.astype(np.float32), 0.04, num_neighbors=12, num_threads=num_threads)
            pts = np.asarray(dense.points, np.float64)
            return cKDTree(pts), pts, dense.normals, dense.normal_valid

        self.surf_s, self.surf_t = surface(S), surface(Tg)

    def free_space_violation(self, T, screen: bool = False) -> float:
        """Share of each scan's structure that the other scan saw through (points lying in front
        of the other's nearest return in their direction, by more than 5 % + 10 cm), averaged
        over both directions; 0 for a consistent pose."""
        Ti = np.linalg.inv(T)
        a, b = (self.few, self.few_t) if screen else (self.struct, self.struct_t)
        a = _in_free_space(a @ T[:3, :3].T + T[:3, 3], self.range_t)
        b = _in_free_space(b @ Ti[:3, :3].T + Ti[:3, 3], self.range_s)
        return 0.5 * (a + b)

    def structure_fitness(self, T, max_distance: float | None = None,
                          screen: bool = False) -> float:
        """Share of the structure within ``max_distance`` of the other scan's surface, the mean
        of both directions (source on target, target on source): the nearest point within
        30 cm counts, distance measured along its normal (a sparse scan has gaps between its
        lines that a point-to-point test would count as misses)."""
        Ti = np.linalg.inv(T)
        tol = self.max_distance if max_distance is None else max_distance
        a, b = (self.few, self.few_t) if screen else (self.struct, self.struct_t)
        return 0.5 * (self._on_surface(a @ T[:3, :3].T + T[:3, 3], self.surf_t, tol)
                      + self._on_surface(b @ Ti[:3, :3].T + Ti[:3, 3], self.surf_s, tol))

    def _on_surface(self, p, surf, tol: float) -> float:
        tree, pts, nrm, nok = surf
        d, j = tree.query(p, distance_upper_bound=max(0.3, tol))
        near = np.isfinite(d)
        jj = j[near]
        dist = np.where(nok[jj], np.abs(np.einsum("ij,ij->i", p[near] - pts[jj], nrm[jj])), d[near])
        return float((dist < tol).sum() / max(len(p), 1))

    def polish(self, T) -> np.ndarray:
        from .registration import register

        try:
            r = register(self.src, self.tgt, "plane", init=T,
                         max_correspondence_distance=[0.4, 0.15], max_iterations=15,
                         num_threads=self.threads)
        except ValueError:  # too few correspondences: judge the hypothesis as proposed
            return T
        T2 = r.T_target_source
        # a hypothesis ICP tipped over (tilted) is not one the levelled images proposed
        tilt = np.degrees(np.arccos(np.clip((T2[:3, :3] @ T[:3, :3].T)[2, 2], -1, 1)))
        return T2 if tilt < 3.0 else T

    def final(self, T):
        """Point-to-plane ICP on oriented normals (each facing its scan's viewpoint): a wall
        seen from both of its sides (a partition between two rooms) is two faces, and plain ICP
        would pull them together. Returns (T, fitness, inlier RMSE [m])."""
        from . import _ext
        from .preprocess import voxel_downsample
        from .registration import prepare

        def oriented(P, v):
            return prepare(voxel_downsample(P.astype(np.float32), 0.05), num_neighbors=12,
                           viewpoint=v, point_sigma=0.03, num_threads=self.threads)

        src, tgt = oriented(self._S, self.range_s.v), oriented(self._Tg, self.range_t.v)
        T2 = np.ascontiguousarray(T, dtype=np.float64)
        r = None
        for dist in (0.15, 0.08):
            r = _ext.oriented_point_to_plane(src._native, tgt._native, T2, dist, 15, 0.03, 0.5,
                                             60_000, int(self.threads))
            T2 = np.asarray(r["T_target_source"], np.float64)
        if not r["linearized"] or not _same_pose(T2, T, 2.0, 0.3):  # ran away: keep verified
            return np.asarray(T), float("nan"), float("nan")
        return T2, float(r["fitness"]), float(r["rmse"])
