# SPDX-License-Identifier: BSD-3-Clause
"""Free-space consistency of two station fragments placed by a registration.

A station sees through the space in front of its nearest return in every direction. Two
fragments placed right never put a point of one where the other saw through; placed wrong they
do, even when their surfaces overlap well: in a corridor a fragment slid along the axis keeps
both long walls on each other (a high overlap), and its end wall, its corner or the far leg of
an L then stand in the other station's free space.

Each fragment's range image is its nearest return per ``BIN_DEG`` direction about its origin
(the lidar at the station's middle time), eroded over the 3 x 3 neighbourhood (only space seen
through in every neighbouring direction is free, so surfaces at grazing angles and the bins'
edges give no false violations); a point violates free space when it lies in front of that
range by more than ``margin_m`` + ``rel`` x range (the margin covers the lidar's travel about
the pan axis within a station, up to the lever arm, and the range noise).
"""

from __future__ import annotations

import numpy as np

#: angular cell of the range images [deg]
BIN_DEG = 1.0


def image_shape(bin_deg: float = BIN_DEG) -> tuple[int, int]:
    """(azimuth bins, elevation bins) of a range image with ``bin_deg`` cells."""
    return int(round(360 / bin_deg)), int(round(180 / bin_deg)) + 1


def direction_bins(P: np.ndarray, bin_deg: float = BIN_DEG
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(azimuth bin, elevation bin, range [m]) of points (N, 3) about the origin."""
    r = np.linalg.norm(P, axis=1)
    az = np.arctan2(P[:, 1], P[:, 0]) + np.pi
    el = np.arcsin(np.clip(P[:, 2] / np.maximum(r, 1e-9), -1.0, 1.0)) + np.pi / 2
    step = np.radians(bin_deg)
    na, ne = image_shape(bin_deg)
    i = np.minimum((az / step).astype(np.int64), na - 1)
    j = np.minimum((el / step).astype(np.int64), ne - 1)
    return i, j, r


def range_image(points: np.ndarray, bin_deg: float = BIN_DEG) -> np.ndarray:
    """(360, 181) float32 (at 1 deg ``bin_deg``): the nearest return [m] per direction of a
    fragment (its own frame, (N, 3) [m]; a 5-6 cm voxel cloud is dense enough), eroded over
    3 x 3 bins; inf where nothing returned."""
    from scipy import ndimage

    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    img = np.full(image_shape(bin_deg), np.inf)
    if len(P):
        i, j, r = direction_bins(P, bin_deg)
        np.minimum.at(img, (i, j), r)
    return ndimage.minimum_filter(img, size=3, mode="wrap").astype(np.float32)


def violation(points: np.ndarray, T_img_points: np.ndarray, img: np.ndarray,
              margin_m: float = 0.3, rel: float = 0.05) -> float:
    """Share of ``points`` (N, 3) [m], placed in the image's frame by ``T_img_points`` (4, 4),
    that lie where the image's station saw through (among those in a direction it saw)."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(P):
        return 0.0
    P = P @ T_img_points[:3, :3].T + T_img_points[:3, 3]
    i, j, r = direction_bins(P)
    lim = img[i, j].astype(np.float64)
    seen = np.isfinite(lim)
    if not seen.any():
        return 0.0
    return float((seen & (r < (1.0 - rel) * lim - margin_m)).sum() / seen.sum())


def mutual_violation(source: np.ndarray, target: np.ndarray, T_target_source: np.ndarray,
                     img_source: np.ndarray, img_target: np.ndarray,
                     viewpoint_source=(0.0, 0.0, 0.0), viewpoint_target=(0.0, 0.0, 0.0)
                     ) -> float:
    """The larger share of either cloud's points lying in the other station's free space, the
    pair placed by ``T_target_source`` (4, 4). Each image is about its station's sensor, at
    ``viewpoint_*`` [m] in that cloud's frame (the origin for a fragment in its lidar frame)."""
    T = np.asarray(T_target_source, dtype=np.float64)
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    to_t, to_s = T.copy(), Ti
    to_t[:3, 3] -= np.asarray(viewpoint_target, dtype=np.float64).reshape(3)
    to_s[:3, 3] -= np.asarray(viewpoint_source, dtype=np.float64).reshape(3)
    return max(violation(source, to_t, img_target), violation(target, to_s, img_source))
