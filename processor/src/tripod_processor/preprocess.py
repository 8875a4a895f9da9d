# SPDX-License-Identifier: BSD-3-Clause
"""Point cloud preprocessing on the native core (numpy in, numpy out, one crossing per cloud)."""

from __future__ import annotations

import numpy as np

from . import _ext


def as_cloud(points) -> np.ndarray:
    """(N,3) C-contiguous float32 view/copy of ``points`` (any (N,>=3) array-like)."""
    a = np.asarray(points)
    if a.ndim != 2 or a.shape[1] < 3:
        raise ValueError(f"expected an (N, 3) array of points, got shape {a.shape}")
    return np.ascontiguousarray(a[:, :3], dtype=np.float32)


VOXEL_ALIGNMENTS = ("origin", "min_bound")


def voxel_downsample(
    points, voxel_size: float, num_threads: int = 0, align: str = "origin"
) -> np.ndarray:
    """Voxel-grid downsampling: one centroid per occupied voxel.

    Parameters
    ----------
    points : (N, 3) array_like of float [m]
    voxel_size : float
        Voxel edge [m], > 0.
    num_threads : int
        0 uses every core.
    align : {"origin", "min_bound"}
        Where the voxel lattice starts. ``"origin"`` (default): index = floor(p / size), the same
        lattice for every cloud, so two overlapping scans share voxel boundaries.
        ``"min_bound"``: index = floor((p - (min(p) - size / 2)) / size), exactly Open3D's
        ``voxel_down_sample`` (same voxels, same centroids to the float32 bit).

    Returns
    -------
    (M, 3) float32 ndarray of centroids, ordered by voxel index (x, then y, then z).
    Non-finite points are dropped; an input with none left gives a (0, 3) array.
    """
    if not voxel_size > 0 or not np.isfinite(voxel_size):
        raise ValueError(f"voxel_size must be a finite number > 0, got {voxel_size!r}")
    if align not in VOXEL_ALIGNMENTS:
        raise ValueError(f"align must be one of {VOXEL_ALIGNMENTS}, got {align!r}")
    return _ext.voxel_downsample(
        as_cloud(points), float(voxel_size), int(num_threads), align == "min_bound"
    )
