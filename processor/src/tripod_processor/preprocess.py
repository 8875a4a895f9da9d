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


def voxel_downsample(points, voxel_size: float, num_threads: int = 0) -> np.ndarray:
    """Voxel-grid downsampling: one centroid per occupied voxel.

    Parameters
    ----------
    points : (N, 3) array_like of float [m]
    voxel_size : float
        Voxel edge [m], > 0. Voxels are aligned to the origin (index = floor(p / size)), as in
        Open3D's ``voxel_down_sample``.
    num_threads : int
        0 uses every core.

    Returns
    -------
    (M, 3) float32 ndarray of centroids, ordered by voxel index. Non-finite points are dropped.
    """
    if not voxel_size > 0:
        raise ValueError("voxel_size must be > 0")
    return _ext.voxel_downsample(as_cloud(points), float(voxel_size), int(num_threads))
