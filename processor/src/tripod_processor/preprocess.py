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


def estimate_normals(
    points,
    num_neighbors: int = 20,
    radius: float = 0.0,
    viewpoint=(0.0, 0.0, 0.0),
    num_threads: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Normals and covariances by PCA of each point's neighbourhood (k-NN or radius).

    Parameters
    ----------
    points : (N, 3) array_like of float [m]
        Must be finite.
    num_neighbors : int
        k nearest neighbours (the point itself included); with ``radius`` > 0 a cap.
    radius : float
        Neighbourhood radius [m]; 0 uses k-NN only.
    viewpoint : (3,) sequence of float
        Normals are flipped to face it (the sensor position) [m].
    num_threads : int
        0 uses every core.

    Returns
    -------
    normals : (N, 3) float64 unit normals (0 where not ``valid``)
    covariances : (N, 3, 3) float64 neighbourhood covariances [m^2]
    curvature : (N,) float64 surface variation lambda_min / sum(lambda) (0 = flat)
    valid : (N,) bool, False where the neighbourhood had < 3 points or was collinear
    """
    pts = _finite_cloud(points)
    if num_neighbors < 1 and not radius > 0:
        raise ValueError("num_neighbors must be >= 1 (or give a radius)")
    g = _ext.estimate_normals(pts, int(num_neighbors), float(radius),
                              np.asarray(viewpoint, dtype=np.float64).reshape(3),
                              int(num_threads))
    return g.normals, g.covariances.reshape(-1, 3, 3), g.curvature, g.valid


def statistical_outlier_removal(
    points, num_neighbors: int = 20, std_ratio: float = 2.0, num_threads: int = 0
) -> np.ndarray:
    """Indices of the points kept by statistical outlier removal (as PCL's filter).

    A point is an outlier when its mean distance to its ``num_neighbors`` nearest neighbours
    exceeds mean + ``std_ratio`` * std of that distance over the cloud.

    Parameters
    ----------
    points : (N, 3) array_like of float [m], finite
    num_neighbors : int
    std_ratio : float
    num_threads : int

    Returns
    -------
    (M,) int64 ndarray of kept row indices, ascending.
    """
    pts = _finite_cloud(points)
    if num_neighbors < 1:
        raise ValueError("num_neighbors must be >= 1")
    return _ext.statistical_outlier_removal(pts, int(num_neighbors), float(std_ratio),
                                            int(num_threads))


def mls_smooth(points, radius: float, num_threads: int = 0, fit_voxel: float = 0.0
               ) -> np.ndarray:
    """Moving-least-squares smoothing: project each point onto a local quadratic surface.

    Each point's neighbours within ``radius`` (Gaussian weights, sigma = radius / 2) define a
    plane by weighted PCA and a second-order height polynomial over it; the point moves onto that
    surface along the normal. Points with fewer than 6 neighbours stay where they are.

    Parameters
    ----------
    points : (N, 3) array_like of float [m], finite
    radius : float
        [m], > 0 (a few times the point spacing).
    num_threads : int
    fit_voxel : float
        0: one surface per point, fitted around it. > 0 [m]: one surface per voxel centroid of
        this size (a fraction of ``radius``, e.g. half), and each point is projected onto the
        surface of its nearest centroid: the same neighbourhoods with far fewer fits (a dense
        map has several points per ``radius / 2`` voxel).

    Returns
    -------
    (N, 3) float32 ndarray, row i the smoothed point i.
    """
    pts = _finite_cloud(points)
    if not radius > 0:
        raise ValueError("radius must be > 0")
    if not fit_voxel >= 0 or not np.isfinite(fit_voxel):
        raise ValueError(f"fit_voxel must be a finite number >= 0, got {fit_voxel!r}")
    return _ext.mls_smooth(pts, float(radius), int(num_threads), float(fit_voxel))


def normal_space_sampling(normals, num_samples: int, bins_per_axis: int = 4,
                          seed: int = 0) -> np.ndarray:
    """Normal-space sampling (Rusinkiewicz & Levoy 2001): indices spread evenly over normals.

    Normals are bucketed on a ``bins_per_axis``^3 grid over their components and drawn round-robin
    across buckets, so that rare orientations (a door frame, a step) survive the subsampling
    that ICP needs to stay well constrained.

    Parameters
    ----------
    normals : (N, 3) array_like of float, unit
    num_samples : int
        Wanted samples; all N indices when it is >= N.
    bins_per_axis : int
    seed : int

    Returns
    -------
    (M,) int64 ndarray of row indices, ascending, M = min(num_samples, N).
    """
    nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64))
    if nrm.ndim != 2 or nrm.shape[1] != 3:
        raise ValueError(f"expected (N, 3) normals, got shape {nrm.shape}")
    if bins_per_axis < 1:
        raise ValueError("bins_per_axis must be >= 1")
    return _ext.normal_space_sampling(nrm, int(num_samples), int(bins_per_axis), int(seed))


def compute_fpfh(points, normals, radius: float, max_neighbors: int = 100,
                 num_threads: int = 0) -> np.ndarray:
    """Fast Point Feature Histograms (3 x 11 bins as PCL and Open3D; each third sums to 200).

    Parameters
    ----------
    points : (N, 3) array_like of float [m], finite
    normals : (N, 3) array_like of float, unit (from :func:`estimate_normals`)
    radius : float
        Feature radius [m] (about 5 voxels).
    max_neighbors : int
        Cap on the neighbourhood (nearest first); 0 = no cap.
    num_threads : int

    Returns
    -------
    (N, 33) float32 ndarray; rows of points with < 2 neighbours are zero.
    """
    pts = _finite_cloud(points)
    nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64))
    if nrm.shape != pts.shape:
        raise ValueError(f"normals must have the shape of points {pts.shape}, got {nrm.shape}")
    if not radius > 0:
        raise ValueError("radius must be > 0")
    return _ext.compute_fpfh(pts, nrm, float(radius), int(max_neighbors), int(num_threads))


def local_shape(points, voxel_size: float, num_threads: int = 0,
                radius_voxels: int = 1) -> np.ndarray:
    """Per-point local shape from voxel moments (the one Python owner of
    ``_ext.voxel_local_shape``).

    Parameters
    ----------
    points : (N, 3) array_like of float [m]
    voxel_size : voxel edge [m]; the neighbourhood is the ``radius_voxels`` ring of voxels
    num_threads : 0 uses every core

    Returns
    -------
    (N, 7) float32: normal nx ny nz, covariance eigenvalues l0 <= l1 <= l2 [m^2], neighbour count.
    """
    return _ext.voxel_local_shape(as_cloud(points), float(voxel_size), int(radius_voxels),
                                  int(num_threads))


def voxel_assign(points, voxel_size: float, num_threads: int = 0):
    """Group points by voxel (the one Python owner of ``_ext.voxel_assign``).

    Returns
    -------
    centroids (M, 3) float32 [m], point_voxel (N,) int32 (-1 for non-finite points),
    counts (M,) int32.
    """
    v = _ext.voxel_assign(as_cloud(points), float(voxel_size), int(num_threads))
    return v.centroids, v.point_voxel, v.counts


def point_normals(points, voxel_size: float = 0.05, num_threads: int = 0) -> np.ndarray:
    """(N, 3) float32 unit normals (sign arbitrary) from the voxel moments of :func:`local_shape`."""
    return local_shape(points, voxel_size, num_threads)[:, :3]


def _finite_cloud(points) -> np.ndarray:
    pts = as_cloud(points)
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN or inf: drop them first (e.g. "
                         "points[np.isfinite(points).all(axis=1)])")
    return pts


# ---- per-voxel attributes (numpy): the same lattice as ``voxel_downsample(align="origin")`` ----
_KEY_BITS = 21  # per axis: |index| < 2^20 voxels (20 km at 2 cm)


def voxel_keys(points, voxel_size: float) -> np.ndarray:
    """(N,) int64 key of each point's voxel on the origin lattice (index = floor(p / size)),
    the lattice of :func:`voxel_downsample`; a centroid it returns has its voxel's key (but for
    float rounding on a voxel face)."""
    idx = np.floor(np.asarray(points, dtype=np.float64)[:, :3] / voxel_size).astype(np.int64)
    idx += 1 << (_KEY_BITS - 1)
    np.clip(idx, 0, (1 << _KEY_BITS) - 1, out=idx)
    return (idx[:, 0] << (2 * _KEY_BITS)) | (idx[:, 1] << _KEY_BITS) | idx[:, 2]


def voxel_sums(keys: np.ndarray, values: np.ndarray, counts: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sum and count of the finite ``values`` (N,) per voxel key: (sorted unique keys (M,),
    sums (M,) float64, counts (M,) int64). ``counts`` (N,): each entry stands for that many
    points (to merge partial sums: pass the sums as ``values``)."""
    v = np.asarray(values, dtype=np.float64)
    c = np.ones(len(v), np.int64) if counts is None else np.asarray(counts, dtype=np.int64)
    ok = np.isfinite(v)
    if not ok.all():
        keys, v, c = keys[ok], v[ok], c[ok]
    if len(keys) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    order = np.argsort(keys)
    ks = keys[order]
    start = np.flatnonzero(np.concatenate(([True], ks[1:] != ks[:-1])))
    return ks[start], np.add.reduceat(v[order], start), np.add.reduceat(c[order], start)


def voxel_mean(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the finite ``values`` (N,) per voxel key: (sorted unique keys (M,), means (M,)
    float32); a voxel with no finite value is absent."""
    uk, s, c = voxel_sums(keys, values)
    return uk, (s / np.maximum(c, 1)).astype(np.float32)


def voxel_majority(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The most frequent integer value per voxel key (ties: the smallest value): (sorted unique
    keys (M,), values (M,) int64)."""
    vals = np.asarray(values, dtype=np.int64)
    order = np.lexsort((vals, keys))
    k, v = keys[order], vals[order]
    new_run = np.ones(len(k), bool)
    new_run[1:] = (k[1:] != k[:-1]) | (v[1:] != v[:-1])
    starts = np.flatnonzero(new_run)
    run_len = np.diff(np.append(starts, len(k)))
    rk, rv = k[starts], v[starts]
    # per key, the longest run first (stable: the smallest value among equal lengths)
    best = np.lexsort((-run_len, rk))
    rk, rv = rk[best], rv[best]
    first = np.ones(len(rk), bool)
    first[1:] = rk[1:] != rk[:-1]
    return rk[first], rv[first]


def lookup_keys(table_keys: np.ndarray, table_values: np.ndarray, keys: np.ndarray,
                missing) -> np.ndarray:
    """``table_values`` at ``keys`` in the sorted ``table_keys``; ``missing`` where absent."""
    if len(table_keys) == 0:
        return np.full(len(keys), missing, dtype=np.asarray(table_values).dtype)
    i = np.searchsorted(table_keys, keys)
    i = np.minimum(i, len(table_keys) - 1)
    hit = table_keys[i] == keys
    return np.where(hit, np.asarray(table_values)[i], missing)
