# SPDX-License-Identifier: BSD-3-Clause
"""Per-point input features of the segmenter: local shape at three scales, height in the room,
horizontal context (is this surface the boundary of the scanned space?) and the planar segment
the point lies on (:mod:`.segments`: how long and how tall is its plane?).

Everything heavy runs in the C++ core (one crossing per cloud, O(N) after one sort), and on the
centroids of 4 cm voxels (:func:`voxel_features`), so features come at millions of points per
second. Clouds are expected z-up (the IMU places them so);
the model is trained with a few degrees of tilt so that small errors do not matter.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ... import _ext
from ...preprocess import as_cloud, local_shape, voxel_assign
from .segments import planar_segments, wall_planes

FEATURE_NAMES = (
    "abs_nz_s", "linearity_s", "planarity_s", "scattering_s", "log_count_s",
    "abs_nz_l", "linearity_l", "planarity_l", "scattering_l",
    "abs_nz_xl", "linearity_xl", "planarity_xl", "scattering_xl",
    "h_floor", "h_ceiling", "h_relative",
    "open_fraction", "free_distance",
    "column_bottom", "column_top", "above_column_bottom", "below_column_top", "log_column_count",
    "segment_log_length", "segment_height_fraction", "segment_bottom", "segment_top",
    "segment_log_area", "segment_abs_nz",
    "segment_open_fraction", "segment_free_distance",
    "segment_residual", "coarse_residual",
    "coarse_log_length", "coarse_height_fraction", "coarse_bottom", "coarse_top",
    "coarse_log_area", "coarse_abs_nz", "coarse_open_fraction", "coarse_free_distance",
)
SMALL_VOXEL = 0.05  # [m], 3x3x3 voxels -> 15 cm neighbourhood
LARGE_VOXEL = 0.15  # [m], 45 cm neighbourhood
XL_VOXEL = 0.4  # [m], 1.2 m neighbourhood: a wall is planar at this scale, a pillar is not
COARSE_SEGMENT_VOXEL = 0.25  # [m] second segmentation: sparse (far, grazing) walls are planar
COARSE_SEGMENT_OFFSET = 0.06  # [m] at this scale
COLUMN_CELL = 0.10  # [m]
LABEL_VOXEL = 0.04  # [m] points in one such voxel share features and label


def _shape(ls: np.ndarray) -> tuple[np.ndarray, ...]:
    l0, l1, l2 = ls[:, 3], ls[:, 4], ls[:, 5]
    s2 = np.maximum(l2, 1e-12)
    return np.abs(ls[:, 2]), (l2 - l1) / s2, (l1 - l0) / s2, l0 / s2


def floor_and_ceiling(z: np.ndarray, abs_nz: np.ndarray, bin_m: float = 0.05) -> tuple[float, float]:
    """Floor and ceiling heights [m] of a z-up indoor cloud.

    The lowest and highest 5 cm slabs that hold at least a quarter as many horizontal points
    (|n_z| > 0.95) as the fullest slab. Desks and shelves are horizontal too but smaller than the
    floor and ceiling seen from inside. Falls back to the 1st/99th height percentiles.
    """
    zf = z[np.isfinite(z)]
    if zf.size == 0:
        return 0.0, 1.0
    horiz = z[(abs_nz > 0.95) & np.isfinite(z)]
    if horiz.size < 100:
        lo, hi = np.percentile(zf, [1, 99])
        return float(lo), float(max(hi, lo + 0.5))
    lo, hi = horiz.min(), horiz.max()
    nb = max(1, int(np.ceil((hi - lo) / bin_m)) + 1)
    hist, edges = np.histogram(horiz, bins=nb, range=(lo, lo + nb * bin_m))
    strong = np.flatnonzero(hist >= 0.25 * hist.max())
    # refine each to the median of the horizontal points of its slab and the neighbours
    def centre(b):
        sel = horiz[(horiz >= edges[max(b - 1, 0)]) & (horiz < edges[min(b + 2, nb)])]
        return float(np.median(sel))
    z_floor, z_ceil = centre(strong[0]), centre(strong[-1])
    if z_ceil - z_floor < 1.0:  # one dominant level only (no ceiling scanned, or no floor)
        lo_p, hi_p = np.percentile(zf, [1, 99])
        if z_floor - lo_p > hi_p - z_ceil:
            z_floor = float(lo_p)
        else:
            z_ceil = float(hi_p)
    return z_floor, max(z_ceil, z_floor + 0.5)


def _segment_description(seg: np.ndarray, nz: np.ndarray, z_floor: float,
                         z_ceil: float) -> np.ndarray:
    """(N, 6) features of each point's planar segment from ``segments.py``'s (N, 5) stats
    (horizontal span, vertical span, lowest z, highest z, area) and its |n_z|: log horizontal
    span, vertical span over the room's height, bottom above the floor and top below the
    ceiling [m], log area, |n_z|."""
    room_h = z_ceil - z_floor
    return np.column_stack([np.log1p(seg[:, 0]), np.clip(seg[:, 1] / room_h, 0, 2),
                            np.clip(seg[:, 2] - z_floor, -2, 12),
                            np.clip(z_ceil - seg[:, 3], -2, 12), np.log1p(seg[:, 4]), nz])


def _segment_mean(segment: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each point's mean of ``values`` over its segment (-1: its own value)."""
    ok = segment >= 0
    out = values.astype(np.float32).copy()
    if ok.any():
        s = segment[ok]
        cnt = np.maximum(np.bincount(s), 1)
        out[ok] = (np.bincount(s, weights=values[ok]) / cnt)[s]
    return out


def _shape_and_context(p: np.ndarray, nt: int, f: np.ndarray) -> tuple[float, float]:
    """Columns 0-22 of ``f`` (local shape at three scales, height, column context: the C++
    core); returns the floor and ceiling heights [m]."""
    ls_s = local_shape(p, SMALL_VOXEL, nt)
    ls_l = local_shape(p, LARGE_VOXEL, nt)
    nz_s, lin_s, pla_s, sca_s = _shape(ls_s)
    nz_l, lin_l, pla_l, sca_l = _shape(ls_l)
    xl = _shape(local_shape(p, XL_VOXEL, nt))
    z = p[:, 2]
    z_floor, z_ceil = floor_and_ceiling(z, nz_s)
    room_h = z_ceil - z_floor
    # rays are "open" when they leave the scanned extent without meeting the band's occupancy
    upright = (nz_s < 0.7).astype(np.uint8)
    opt = _ext._ColumnContextOptions()
    opt.cell_size, opt.z_low, opt.z_high = COLUMN_CELL, z_floor + 0.2, z_ceil - 0.2
    opt.num_directions, opt.skip, opt.max_range, opt.num_threads = 16, 0.25, 100.0, nt
    cc = _ext.column_context(p, upright, opt)
    f[:, 0], f[:, 1], f[:, 2], f[:, 3] = nz_s, lin_s, pla_s, sca_s
    f[:, 4] = np.log1p(ls_s[:, 6])
    f[:, 5], f[:, 6], f[:, 7], f[:, 8] = nz_l, lin_l, pla_l, sca_l
    f[:, 9], f[:, 10], f[:, 11], f[:, 12] = xl
    f[:, 13] = np.clip(z - z_floor, -2, 12)
    f[:, 14] = np.clip(z_ceil - z, -2, 12)
    f[:, 15] = np.clip((z - z_floor) / room_h, -1, 2)
    f[:, 16] = cc[:, 0]
    f[:, 17] = np.log1p(cc[:, 1])
    f[:, 18] = np.clip(cc[:, 2] - z_floor, -2, 12)
    f[:, 19] = np.clip(z_ceil - cc[:, 3], -2, 12)
    f[:, 20] = np.clip(z - cc[:, 2], 0, 12)
    f[:, 21] = np.clip(cc[:, 3] - z, 0, 12)
    f[:, 22] = cc[:, 4]
    return z_floor, z_ceil


def _fine_segments_and_planes(p: np.ndarray, nt: int):
    """:func:`.segments.planar_segments` on the 10 cm grid (with residuals) and the
    :func:`.segments.wall_planes` made of its segments."""
    seg, seg_nz, segment, res = planar_segments(p, nt, residual=True)
    return seg, seg_nz, segment, res, wall_planes(p, segment)


def point_features(points, num_threads: int = 0, return_segments: bool = False):
    """Segmenter input features of every point.

    Parameters
    ----------
    points : (N, 3) array_like [m], z up
    num_threads : int, 0 = all cores

    Returns
    -------
    (N, len(FEATURE_NAMES)) float32. Non-finite points get zeros.
    With ``return_segments``, also the (N, 3) int64 planar segments of every point
    (:func:`.segments.planar_segments` on the 10 cm and the 25 cm grid) and its wall plane
    (:func:`.segments.wall_planes`), -1 for none and for non-finite points.
    """
    p = as_cloud(points)
    nt = int(num_threads)
    f = np.empty((len(p), len(FEATURE_NAMES)), np.float32)
    if nt == 1:  # one thread asked for: one after the other
        z_floor, z_ceil = _shape_and_context(p, nt, f)
        seg, seg_nz, segment, res, planes = _fine_segments_and_planes(p, 1)
        cs, cs_nz, coarse, cres = planar_segments(p, 1, voxel=COARSE_SEGMENT_VOXEL,
                                                  max_offset=COARSE_SEGMENT_OFFSET, residual=True)
    else:
        # the 10 cm segments and wall planes (numpy, one core) run on a second thread while
        # the C++ core computes local shape and column context (OpenMP, GIL released) on this
        # one, which then does the 25 cm segments (the second thread's share is the longer)
        with ThreadPoolExecutor(1) as pool:
            fine = pool.submit(_fine_segments_and_planes, p, 1)
            z_floor, z_ceil = _shape_and_context(p, nt, f)
            cs, cs_nz, coarse, cres = planar_segments(p, 1, voxel=COARSE_SEGMENT_VOXEL,
                                                      max_offset=COARSE_SEGMENT_OFFSET,
                                                      residual=True)
            seg, seg_nz, segment, res, planes = fine.result()
    # the planar segment of the point: a wall's runs for metres, floor to ceiling (segments.py)
    f[:, 23:29] = _segment_description(seg, seg_nz, z_floor, z_ceil)
    # is the plane as a whole the boundary of the scanned space?
    f[:, 29], f[:, 30] = _segment_mean(segment, f[:, 16]), _segment_mean(segment, f[:, 17])
    # a board, picture or radiator joins the wall's segment but lies a few cm off its plane
    f[:, 31], f[:, 32] = np.minimum(res, 0.5), np.minimum(cres, 0.5)
    # the same at 25 cm: far walls scanned by a few sparse lines are planar at this scale
    f[:, 33:39] = _segment_description(cs, cs_nz, z_floor, z_ceil)
    f[:, 39], f[:, 40] = _segment_mean(coarse, f[:, 16]), _segment_mean(coarse, f[:, 17])
    f[~np.isfinite(f)] = 0.0
    f[~np.isfinite(p).all(1)] = 0.0
    return (f, np.stack([segment, coarse, planes], 1)) if return_segments else f


def voxel_features(points, num_threads: int = 0, return_segments: bool = False,
                   return_centroids: bool = False):
    """Features of the occupied 4 cm voxels of a cloud, and each point's voxel.

    All the features are neighbourhood statistics at 15 cm and more, so the points of one 4 cm
    voxel would get (nearly) the same ones: computing them once per voxel centroid and running
    the network once per voxel is what makes segmentation run at millions of points per second.

    Returns
    -------
    features : (M, len(FEATURE_NAMES)) float32 of the voxel centroids
    point_voxel : (N,) int32 voxel of every point, -1 for non-finite points
    segment : (M, 3) int64 planar segments (10 cm, 25 cm grid) and wall plane of every voxel,
        only with ``return_segments``
    centroids : (M, 3) float32 voxel centroids [m], only with ``return_centroids`` (last)
    """
    p = as_cloud(points)
    centroids, point_voxel, _ = voxel_assign(p, LABEL_VOXEL, num_threads)
    if return_segments:
        f, segment = point_features(centroids, num_threads, return_segments=True)
        out = (f, point_voxel, segment)
    else:
        out = (point_features(centroids, num_threads), point_voxel)
    return out + (np.asarray(centroids, np.float32),) if return_centroids else out
