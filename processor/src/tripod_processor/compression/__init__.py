# SPDX-License-Identifier: BSD-3-Clause
"""Point cloud geometry compression with a learned context model (``tripod compress``).

Two geometry modes share one container: the learned-context octree (any cloud), described here,
and the predictive mode for ordered sensor scans (:mod:`.predictive`); ``mode="auto"`` (the
default) tries both and keeps the smaller file.

The codec quantises a cloud to a voxel grid, builds its octree, and range-codes every child
occupancy bit with a probability from a small neural network (the *context model*) that looks at
already-coded neighbours at the child and parent levels. The network is tabulated once, in exact
integer arithmetic, so encoder and decoder agree bit for bit; per-context adaptation on top of
the learned prior tracks the statistics of the cloud at hand. Files are ``.tpc`` containers
(see :mod:`.container`).

>>> data = compress(points, error=0.002)      # every point within 2 mm
>>> decoded = decompress(data)                # (M, 3) float32, one point per occupied voxel
"""

from __future__ import annotations

import numpy as np

from .codec import (CODEC_NAME, MODES, CodecError, EncodeInfo, decode, decode_cloud, encode,
                    encode_to_rate, voxel_size_for_error)
from .container import ContainerError, read_header


def compress(points: np.ndarray, *, error: float | None = None, voxel_size: float | None = None,
             bpp: float | None = None, intensity: np.ndarray | None = None, mode: str = "auto",
             origin=None, num_threads: int = 0) -> bytes:
    """Compress a cloud to ``.tpc`` bytes.

    Parameters
    ----------
    points : (N, 3) float array [m]
    error : maximum distance [m] of any point from its decoded position (voxel = 2 error/sqrt 3)
    voxel_size : voxel edge [m] (instead of ``error``)
    bpp : target bits per input point: the finest grid that fits (instead of ``error``)
    intensity : optional (N,) per-point intensity, kept as the rounded mean of each voxel
        (octree) or per point (predictive)
    mode : "auto" (both modes, the smaller file), "octree" or "predictive"
    origin : (3,) sensor position [m] for the predictive mode (default (0, 0, 0))

    Exactly one of ``error``, ``voxel_size``, ``bpp`` must be given.
    """
    return compress_with_info(points, error=error, voxel_size=voxel_size, bpp=bpp,
                              intensity=intensity, mode=mode, origin=origin,
                              num_threads=num_threads)[0]


def compress_with_info(points: np.ndarray, *, error: float | None = None,
                       voxel_size: float | None = None, bpp: float | None = None,
                       intensity: np.ndarray | None = None, mode: str = "auto", origin=None,
                       num_threads: int = 0) -> tuple[bytes, EncodeInfo]:
    """:func:`compress`, also returning the :class:`EncodeInfo` (grid, counts, rate)."""
    given = [v is not None for v in (error, voxel_size, bpp)]
    if sum(given) != 1:
        raise CodecError("give exactly one of error, voxel_size, bpp")
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise CodecError(f"expected (N, 3) points, got shape {pts.shape}")
    if bpp is not None:
        if not bpp > 0:
            raise CodecError(f"bits per point must be > 0, got {bpp}")
        return encode_to_rate(pts, bpp, intensity=intensity, mode=mode, origin=origin,
                              num_threads=num_threads)
    if error is not None:
        if not error > 0:
            raise CodecError(f"error must be > 0, got {error}")
        voxel_size = voxel_size_for_error(error)
    return encode(pts, float(voxel_size), intensity=intensity, mode=mode, origin=origin,
                  num_threads=num_threads)


def decompress(data: bytes, num_threads: int = 0) -> np.ndarray:
    """Decode ``.tpc`` bytes to (M, 3) float32 points [m] (octree: voxel centres; predictive:
    every input point, in input order)."""
    return decode(data, num_threads=num_threads)[0]


def read_info(data: bytes) -> dict:
    """The verified header of ``.tpc`` bytes (codec, model id, grid, counts, sizes)."""
    return read_header(data)[0]


__all__ = ["CODEC_NAME", "MODES", "CodecError", "ContainerError", "EncodeInfo", "compress",
           "compress_with_info", "decode_cloud", "decompress", "read_info"]
