# SPDX-License-Identifier: BSD-3-Clause
"""Sparse matching of plan heightmaps: Hu-moment shape descriptors, ORB keypoints (OpenCV),
furniture blobs, and a 2-D rigid RANSAC over their matches."""

from __future__ import annotations

import numpy as np

from ..planes import OTHER
from .correlation import _raster
from .levelling import LevelledScan


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
