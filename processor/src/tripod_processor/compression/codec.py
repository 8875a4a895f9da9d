# SPDX-License-Identifier: BSD-3-Clause
"""Geometry codec: points <-> ``.tpc`` bytes, in one of two modes.

* ``octree`` (codec ``octree-ctx22``): the learned-context octree below; any cloud.
* ``predictive`` (codec ``predictive-sph1``, :mod:`.predictive`): an ordered sensor scan coded
  point by point in spherical coordinates about the sensor; keeps every point, in order.
* ``auto`` (the default): both, at once on two threads, keeping the smaller file (so a cloud
  without scan structure gets exactly the octree file).
Both modes keep every point within the same maximum error, ``voxel_size * sqrt(3) / 2``.

Pipeline of the octree mode: 1. choose the voxel grid (origin = bounding-box corner, voxel size
from the error bound or the rate target); 2. quantise to sorted unique Morton codes (C++);
3. range-code the octree with the learned probability table (C++); 4. wrap in the container.
:func:`decode` checks the container and the model id, decodes the octree and returns the voxel
centres. Points that fall in one voxel are merged (the output has one point per occupied voxel).
An optional per-point intensity becomes the mean intensity of each voxel (rounded), coded as a
second section: deltas in Morton order, LZMA (xz, with its own CRC).
"""

from __future__ import annotations

import lzma
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import predictive
from .container import ContainerError, pack, unpack
from .model import DEFAULT_WEIGHTS, load_table

CODEC_NAME = "octree-ctx22"
MODES = ("auto", "octree", "predictive")
# Per-context adaptation on top of the learned prior: rate 1/(n + 8) after n updates, at least
# 1/128 (the learned probability counts as 8 observations; chosen on held-out clouds).
DEFAULT_ADAPT_SHIFT = 7
DEFAULT_ADAPT_PRIOR = 8


class CodecError(ValueError):
    """A cloud that cannot be encoded, or a file this codec cannot decode (one-line message)."""


@dataclass(frozen=True)
class EncodeInfo:
    """What :func:`encode` did: the grid and the sizes (for reports)."""

    voxel_size: float  # [m] (predictive mode: the grid step of the same maximum error)
    depth: int  # octree depth (0 in the predictive mode)
    n_points: int  # finite input points
    n_voxels: int  # decoded points (octree: occupied voxels; predictive: n_points)
    n_bytes: int  # whole file
    mode: str = "octree"  # "octree" or "predictive"

    @property
    def bits_per_point(self) -> float:
        """Bits per finite input point (the MPEG convention)."""
        return 8.0 * self.n_bytes / max(self.n_points, 1)


def voxel_size_for_error(max_error_m: float) -> float:
    """Voxel edge [m] whose centre is within ``max_error_m`` of every point in it (sqrt(3)/2)."""
    return 2.0 * max_error_m / math.sqrt(3.0)


def grid_for(points: np.ndarray, voxel_size: float) -> tuple[np.ndarray, int]:
    """(origin (3,) float64 [m], depth) of the grid covering ``points`` at ``voxel_size``."""
    from .. import _ext

    if not (voxel_size > 0 and math.isfinite(voxel_size)):
        raise CodecError(f"voxel size must be a positive number, got {voxel_size}")
    lo = points.min(0).astype(np.float64)
    cells = np.floor((points.max(0).astype(np.float64) - lo) / voxel_size).max() + 1
    depth = max(1, math.ceil(math.log2(cells)))
    if depth > _ext.OCTREE_MAX_DEPTH:
        raise CodecError(f"voxel size {voxel_size:g} m is too fine for a cloud spanning "
                         f"{cells * voxel_size:.1f} m (max {2**_ext.OCTREE_MAX_DEPTH} voxels/axis)")
    return lo, depth


def voxel_codes(points: np.ndarray, voxel_size: float, num_threads: int = 0
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """Sorted unique Morton codes (uint64) of the occupied voxels of the grid of
    :func:`grid_for`, its origin (3,) float64 [m] and depth: the one Python owner of
    ``_ext.voxelize_morton``. ``points`` (N, 3) float32 C-contiguous [m]."""
    from .. import _ext

    origin, depth = grid_for(points, voxel_size)
    return _ext.voxelize_morton(points, origin, voxel_size, depth, num_threads), origin, depth


def _finite(points: np.ndarray, intensity: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray | None]:
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float32)[:, :3])
    ok = np.isfinite(p).all(1)
    if intensity is not None:
        intensity = np.asarray(intensity, np.float64).reshape(-1)
        if len(intensity) != len(p):
            raise CodecError(f"{len(intensity)} intensities for {len(p)} points")
        ok &= np.isfinite(intensity)
    if ok.all():
        return p, intensity
    return np.ascontiguousarray(p[ok]), None if intensity is None else intensity[ok]


def _spread3(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF),
                        (8, 0x100F00F00F00F00F), (4, 0x10C30C30C30C30C3),
                        (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _voxel_means(points: np.ndarray, values: np.ndarray, origin: np.ndarray, voxel_size: float,
                 depth: int, codes: np.ndarray) -> np.ndarray:
    """Mean of ``values`` per voxel, in the order of the sorted voxel ``codes``."""
    q = np.floor((points.astype(np.float64) - origin) / voxel_size)
    q = np.clip(q, 0, 2**depth - 1).astype(np.uint64)
    point_codes = (_spread3(q[:, 0]) << np.uint64(2)) | (_spread3(q[:, 1]) << np.uint64(1)) \
        | _spread3(q[:, 2])
    idx = np.searchsorted(codes, point_codes)
    total = np.bincount(idx, weights=values, minlength=len(codes))
    return total / np.maximum(np.bincount(idx, minlength=len(codes)), 1)


_XZ_FILTERS = [{"id": lzma.FILTER_DELTA, "dist": 1}, {"id": lzma.FILTER_LZMA2, "preset": 9}]


def _encode_intensity(means: np.ndarray) -> tuple[bytes, dict]:
    v = np.clip(np.rint(means), 0, 65535)
    dtype = "<u1" if v.max(initial=0) <= 255 else "<u2"
    data = v.astype(dtype).tobytes()
    return lzma.compress(data, format=lzma.FORMAT_XZ, filters=_XZ_FILTERS), {
        "dtype": dtype, "codec": "xz-delta"}


def _decode_intensity(section: bytes, info: dict, n_voxels: int) -> np.ndarray:
    try:
        raw = lzma.decompress(section, format=lzma.FORMAT_XZ)
    except lzma.LZMAError as exc:
        raise CodecError(f"corrupt intensity section: {exc}") from None
    dtype = np.dtype(info.get("dtype", "<u1"))
    if len(raw) != n_voxels * dtype.itemsize:
        raise CodecError("corrupt intensity section: wrong length")
    return np.frombuffer(raw, dtype)


def encode(points: np.ndarray, voxel_size: float, *, mode: str = "auto", origin=None,
           intensity: np.ndarray | None = None, adapt_shift: int = DEFAULT_ADAPT_SHIFT,
           adapt_prior: int = DEFAULT_ADAPT_PRIOR, weights=DEFAULT_WEIGHTS,
           num_threads: int = 0) -> tuple[bytes, EncodeInfo]:
    """Encode a cloud so that every point moves by at most ``voxel_size * sqrt(3) / 2``.

    Parameters
    ----------
    points : (N, 3) float array [m]; non-finite rows are dropped.
    voxel_size : voxel edge [m] of the octree grid; every point moves by at most
        voxel_size * sqrt(3) / 2 (the predictive mode keeps the same bound).
    mode : "auto" (both, the smaller file), "octree" or "predictive"
    origin : (3,) sensor position [m] for the predictive mode (default: (0, 0, 0), the frame of
        a sensor-frame scan; a PCD VIEWPOINT is the usual source)
    intensity : optional (N,) per-point values >= 0 (octree: rounded mean per voxel;
        predictive: rounded, per point)
    adapt_shift, adapt_prior : octree only: 0 for the static learned table; else each context
        adapts towards the coded bits at rate 1/(n + adapt_prior) after n updates (at least
        1/2^adapt_shift), or at the fixed rate 1/2^adapt_shift when adapt_prior is 0.

    Returns
    -------
    (file bytes, EncodeInfo)
    """
    if mode not in MODES:
        raise CodecError(f"unknown mode {mode!r} (use one of {', '.join(MODES)})")
    if not (voxel_size > 0 and math.isfinite(voxel_size)):
        raise CodecError(f"voxel size must be a positive number, got {voxel_size}")
    p, inten = _finite(points, intensity)
    if mode == "predictive":
        out = _encode_predictive(p, inten, voxel_size, origin, num_threads)
        if out is None:
            raise CodecError("the predictive mode cannot keep this error bound here")
        return out
    if mode == "octree" or len(p) == 0:
        return _encode_octree(p, inten, voxel_size, adapt_shift, adapt_prior, weights,
                              num_threads)
    # auto: both modes at once (each releases the GIL; two cores give both for the wall time
    # of the slower, the octree), keeping the smaller file
    with ThreadPoolExecutor(1) as pool:
        octree_job = pool.submit(_encode_octree, p, inten, voxel_size, adapt_shift, adapt_prior,
                                 weights, num_threads)
        pred = _encode_predictive(p, inten, voxel_size, origin, num_threads)
        try:
            octree = octree_job.result()
        except CodecError:  # a grid too fine for the octree: the predictive file may still do
            if pred is None:
                raise
            return pred
    if pred is None or pred[1].n_bytes >= octree[1].n_bytes:
        return octree
    return pred


def _encode_predictive(p: np.ndarray, inten: np.ndarray | None, voxel_size: float, origin,
                       num_threads: int) -> tuple[bytes, EncodeInfo] | None:
    max_error = voxel_size * math.sqrt(3.0) / 2.0
    header = {"codec": predictive.CODEC_NAME, "n_points": int(len(p)), "n_voxels": int(len(p)),
              "voxel_size": float(voxel_size), "max_error_bound": float(max_error)}
    if len(p) == 0:
        grid = predictive.ScanGrid(np.zeros(3), 1.0, 2, 1.0)
        stream, checksum, worst, part_bits = b"", 0, 0.0, (0.0, 0.0, 0.0)
    else:
        coded = predictive.encode_points(p, max_error, origin, num_threads)
        if coded is None:
            return None
        stream, grid, checksum, worst, part_bits = coded
    # bits per point by part: where the rate goes (information for reports)
    split = {k: round(b / max(len(p), 1), 4) for k, b in zip(("elevation", "azimuth", "range"),
                                                                 part_bits)}
    header.update(grid.header(), checksum=int(checksum), max_error=float(worst),
                  bits_per_point_by_part=split)
    sections = [stream, grid.table_section()]
    if inten is not None:
        section, header["intensity"] = _encode_intensity(inten)
        sections.append(section)
    data = pack(header, sections, version=2)
    return data, EncodeInfo(voxel_size, 0, len(p), len(p), len(data), "predictive")


def _encode_octree(p: np.ndarray, inten: np.ndarray | None, voxel_size: float, adapt_shift: int,
                   adapt_prior: int, weights, num_threads: int) -> tuple[bytes, EncodeInfo]:
    from .. import _ext

    table = load_table(weights)
    header = {"codec": CODEC_NAME, "model_id": table.model_id, "adapt_shift": int(adapt_shift),
              "adapt_prior": int(adapt_prior), "n_points": int(len(p)),
              "voxel_size": float(voxel_size)}
    if len(p) == 0:
        header.update(origin=[0.0, 0.0, 0.0], depth=1, n_voxels=0)
        data = pack(header, [b""], version=1)
        return data, EncodeInfo(voxel_size, 1, 0, 0, len(data))
    codes, origin, depth = voxel_codes(p, voxel_size, num_threads)
    stream = _ext.octree_encode(codes, depth, table.p0, int(adapt_shift), int(adapt_prior))
    header.update(origin=[float(v) for v in origin], depth=depth, n_voxels=int(len(codes)))
    sections = [stream]
    if inten is not None:
        section, header["intensity"] = _encode_intensity(
            _voxel_means(p, inten, origin, voxel_size, depth, codes))
        sections.append(section)
    data = pack(header, sections, version=1)  # readable by every tripod since format 1
    return data, EncodeInfo(voxel_size, depth, len(p), len(codes), len(data))


def decode(data: bytes, *, weights=DEFAULT_WEIGHTS, num_threads: int = 0
           ) -> tuple[np.ndarray, dict]:
    """Decode ``.tpc`` bytes to ((M, 3) float32 voxel centres [m], header dict).

    Raises :class:`ContainerError` / :class:`CodecError` (one-line messages) on a foreign,
    corrupt or truncated file, or one made with another context model.
    """
    points, _attributes, header = decode_cloud(data, weights=weights, num_threads=num_threads)
    return points, header


def decode_cloud(data: bytes, *, weights=DEFAULT_WEIGHTS, num_threads: int = 0
                 ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    """:func:`decode`, with the per-point attributes stored: ({"intensity": (M,)} or {})."""
    from .. import _ext

    header, sections = unpack(data)
    if header.get("codec") in predictive.CODEC_NAMES:
        return _decode_predictive(header, sections, num_threads)
    if header.get("codec") != CODEC_NAME:
        raise CodecError(f"unsupported codec {header.get('codec')!r} (this tripod reads "
                         f"{', '.join(repr(c) for c in (CODEC_NAME, *predictive.CODEC_NAMES))})")
    table = load_table(weights)
    if header.get("model_id") != table.model_id:
        raise CodecError(f"file was coded with context model {header.get('model_id')}, this "
                         f"tripod has {table.model_id}")
    try:
        n_voxels, depth = int(header["n_voxels"]), int(header["depth"])
        origin = np.asarray(header["origin"], np.float64).reshape(3)
        voxel_size, shift = float(header["voxel_size"]), int(header["adapt_shift"])
        prior = int(header["adapt_prior"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ContainerError(f"corrupt .tpc header: {exc}") from None
    attributes = {}
    if n_voxels == 0:
        return np.zeros((0, 3), np.float32), attributes, header
    if len(sections) != 1 + ("intensity" in header):
        raise ContainerError("corrupt .tpc file: unexpected sections")
    try:
        codes = _ext.octree_decode(sections[0], depth, n_voxels, table.p0, shift, prior)
    except (RuntimeError, ValueError) as exc:
        raise CodecError(str(exc)) from None
    if "intensity" in header:
        attributes["intensity"] = _decode_intensity(sections[1], header["intensity"], n_voxels)
    return _ext.morton_to_points(codes, origin, voxel_size, num_threads), attributes, header


def _decode_predictive(header: dict, sections: list[bytes], num_threads: int
                       ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    try:
        n_points, checksum = int(header["n_points"]), int(header["checksum"])
        if len(sections) != 2 + ("intensity" in header):
            raise ContainerError("corrupt .tpc file: unexpected sections")
        grid = predictive.ScanGrid.from_header(header, sections[1])
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ContainerError):
            raise
        raise ContainerError(f"corrupt .tpc header: {exc}") from None
    attributes = {}
    if n_points == 0:
        return np.zeros((0, 3), np.float32), attributes, header
    try:
        points = predictive.decode_points(sections[0], n_points, grid, checksum, num_threads)
    except (RuntimeError, ValueError) as exc:
        raise CodecError(str(exc).replace("\n", " ")) from None
    if "intensity" in header:
        attributes["intensity"] = _decode_intensity(sections[2], header["intensity"], n_points)
    return points, attributes, header


def encode_to_rate(points: np.ndarray, bits_per_point: float, **kw) -> tuple[bytes, EncodeInfo]:
    """Encode with the finest voxel size whose rate is <= ``bits_per_point`` (bisection)."""
    p, inten = _finite(points, kw.pop("intensity", None))
    kw["intensity"] = inten
    if len(p) == 0:
        return encode(p, 1.0, **kw)
    ext = float((p.max(0) - p.min(0)).max()) or 1.0
    lo, hi = math.log(ext / 2.0**20), math.log(ext / 2.0)  # fine ... coarse
    best = encode(p, math.exp(hi), **kw)
    if best[1].bits_per_point > bits_per_point:
        return best  # even the coarsest grid exceeds the target: return the smallest file
    for _ in range(14):
        mid = 0.5 * (lo + hi)
        trial = encode(p, math.exp(mid), **kw)
        if trial[1].bits_per_point <= bits_per_point:
            best, hi = trial, mid
        else:
            lo = mid
    return best


__all__ = ["CODEC_NAME", "MODES", "CodecError", "ContainerError", "EncodeInfo", "decode",
           "decode_cloud", "encode",
           "encode_to_rate", "grid_for", "voxel_size_for_error"]
