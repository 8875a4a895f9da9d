# SPDX-License-Identifier: BSD-3-Clause
"""Fragment-to-fragment registration for odometry and loop closures.

The IMU gives each fragment's attitude (roll and pitch exact, yaw slowly drifting), so the
rotation between two fragments is known up to a small yaw error. The translation is seeded by a
top-down correlation of the gravity-aligned fragments (walls dominate the image), then refined
coarse-to-fine by the registration core, starting from the IMU rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..preprocess import voxel_downsample
from .config import OdometryConfig


@dataclass
class PairResult:
    """T_target_source (4, 4) and its quality; information ordered (tx, ty, tz, rx, ry, rz)."""

    T_target_source: np.ndarray
    fitness: float
    rmse: float
    information: np.ndarray
    ok: bool
    seed: str = ""


def _o3d_cloud(xyz: np.ndarray):
    import open3d as o3d

    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.asarray(xyz, dtype=np.float64))
    return pc


def _information(src_pc, tgt_pc, max_corr: float, T: np.ndarray, rmse: float,
                 cfg: OdometryConfig) -> np.ndarray:
    """Pose information from the point correspondences, whitened by the inlier RMSE and capped.

    Open3D orders (rx, ry, rz, tx, ty, tz) and leaves the noise out; we reorder to
    (t, r), divide by σ² with σ the inlier RMSE, and cap every eigenvalue at the configured
    floor sigmas: thousands of correlated correspondences would otherwise claim micrometres.
    """
    import open3d as o3d

    info_rt = np.asarray(o3d.pipelines.registration.get_information_matrix_from_point_clouds(
        src_pc, tgt_pc, max_corr, T))
    perm = [3, 4, 5, 0, 1, 2]
    info = info_rt[np.ix_(perm, perm)] / max(rmse, 1e-3) ** 2
    cap = np.array([1 / cfg.sigma_floor_m**2] * 3 + [1 / np.radians(cfg.sigma_floor_deg)**2] * 3)
    # cap in the scaled eigenbasis: S^-1/2 info S^-1/2 must not exceed the identity
    s = 1.0 / np.sqrt(cap)
    scaled = info * np.outer(s, s)
    w, V = np.linalg.eigh(0.5 * (scaled + scaled.T))
    w = np.clip(w, 0.0, 1.0)
    scaled = (V * w) @ V.T
    return scaled / np.outer(s, s)


def icp_refine(source: np.ndarray, target: np.ndarray, T_init: np.ndarray,
               cfg: OdometryConfig, num_threads: int = 0,
               voxels: list[float] | None = None) -> PairResult:
    """Coarse-to-fine GICP of ``source`` onto ``target`` (both (N, 3) [m]) from ``T_init``, over
    ``voxels`` (default: the configured schedule)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxels = list(cfg.voxels_m if voxels is None else voxels)
    T = np.asarray(T_init, dtype=np.float64).copy()
    src_pc = tgt_pc = None
    fit, rmse, corr = 0.0, np.inf, voxels[-1] * 3
    for voxel in voxels:
        s = voxel_downsample(source, voxel, num_threads)
        t = voxel_downsample(target, voxel, num_threads)
        if len(s) < 20 or len(t) < 20:
            return PairResult(T, 0.0, np.inf, np.zeros((6, 6)), False)
        src_pc, tgt_pc = _o3d_cloud(s), _o3d_cloud(t)
        corr = 3.0 * voxel
        if cfg.method == "gicp":
            est = reg.TransformationEstimationForGeneralizedICP()
            for pc in (src_pc, tgt_pc):
                pc.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(2.5 * voxel, 20))
        elif cfg.method == "plane":
            est = reg.TransformationEstimationPointToPlane()
            tgt_pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(2.5 * voxel, 20))
        else:
            est = reg.TransformationEstimationPointToPoint()
        z_prior = T[2, 3]
        res = reg.registration_icp(src_pc, tgt_pc, corr, T, est,
                                   reg.ICPConvergenceCriteria(1e-7, 1e-7, 40))
        T = np.asarray(res.transformation).copy()
        if cfg.lock_z:
            T[2, 3] = z_prior
        fit, rmse = float(res.fitness), float(res.inlier_rmse)
    info = _information(src_pc, tgt_pc, corr, T, rmse, cfg)
    return PairResult(T, fit, rmse, info, fit >= cfg.min_fitness)


# ---- translation seed: top-down correlation of the gravity-aligned fragments ------------------
def _topdown(points_w: np.ndarray, cell: float, half: int) -> np.ndarray:
    ij = np.floor(points_w[:, :2] / cell).astype(np.int64) + half
    ok = (ij >= 0).all(1) & (ij < 2 * half).all(1)
    img = np.zeros((2 * half, 2 * half))
    np.add.at(img, (ij[ok, 0], ij[ok, 1]), 1.0)
    img = np.log1p(img)
    return img - img.mean()


def translation_seeds(target_w: np.ndarray, source_w: np.ndarray, cell: float,
                      extent_m: float = 16.0, n_peaks: int = 3) -> list[np.ndarray]:
    """Candidate d (3,) [m] with target_w ≈ source_w + d, best first.

    Both clouds are gravity-aligned and rotated alike (world attitude from the IMU), each about
    its own origin. Phase correlation of their top-down images gives the horizontal shift; the
    vertical one comes from correlating height histograms.
    """
    half = int(np.ceil(extent_m / cell))
    A = np.fft.rfft2(_topdown(target_w, cell, half), s=(4 * half, 4 * half))
    B = np.fft.rfft2(_topdown(source_w, cell, half), s=(4 * half, 4 * half))
    R = A * np.conj(B)
    R /= np.abs(R) + 1e-9
    corr = np.fft.irfft2(R, s=(4 * half, 4 * half))
    # z: correlate height histograms (floor and ceiling are strong peaks)
    zc = 0.02
    bins = np.arange(-6.0, 6.0 + zc, zc)
    ht, _ = np.histogram(target_w[:, 2], bins)
    hs, _ = np.histogram(source_w[:, 2], bins)
    zcorr = np.correlate(np.log1p(ht) - np.log1p(ht).mean(), np.log1p(hs) - np.log1p(hs).mean(),
                         "full")
    dz = (int(np.argmax(zcorr)) - (len(hs) - 1)) * zc
    seeds = []
    flat = corr.ravel().copy()
    n = 4 * half
    for _ in range(n_peaks):
        k = int(np.argmax(flat))
        i, j = divmod(k, n)
        di = i if i < n // 2 else i - n
        dj = j if j < n // 2 else j - n
        seeds.append(np.array([di * cell, dj * cell, dz]))
        # suppress the neighbourhood of this peak
        for ii in range(i - 3, i + 4):
            for jj in range(j - 3, j + 4):
                flat[(ii % n) * n + (jj % n)] = -np.inf
    return seeds


def register_fragments(source: np.ndarray, target: np.ndarray, R_world_source: np.ndarray,
                       R_world_target: np.ndarray, cfg: OdometryConfig, num_threads: int = 0,
                       T_guess: np.ndarray | None = None) -> PairResult:
    """T_target_source between two fragments, with the IMU attitude as rotation prior.

    Tries ``T_guess`` first when given (loop closures from the current map), then the top-down
    seeds; keeps the best-fitting verified result.
    """
    R_ts = R_world_target.T @ R_world_source
    candidates: list[tuple[str, np.ndarray]] = []
    if T_guess is not None:
        candidates.append(("guess", np.asarray(T_guess, dtype=np.float64)))
    coarse = cfg.voxels_m[0] * 0.5
    tw = voxel_downsample(np.asarray(target) @ R_world_target.T, coarse, num_threads)
    sw = voxel_downsample(np.asarray(source) @ R_world_source.T, coarse, num_threads)
    for k, d in enumerate(translation_seeds(tw.astype(np.float64), sw.astype(np.float64),
                                            cfg.seed_cell_m)):
        T = np.eye(4)
        T[:3, :3] = R_ts
        T[:3, 3] = R_world_target.T @ d
        candidates.append((f"topdown{k}", T))
    # every start through the coarse stages; only the best one through the fine stages
    n_coarse = max(1, min(2, len(cfg.voxels_m) - 1))
    coarse_v, fine_v = cfg.voxels_m[:n_coarse], cfg.voxels_m[n_coarse:]
    best: PairResult | None = None
    for name, T0 in candidates:
        r = icp_refine(source, target, T0, cfg, num_threads, coarse_v)
        r.seed = name
        if best is None or (r.fitness, -r.rmse) > (best.fitness, -best.rmse):
            best = r
        if name == "guess" and r.fitness > 0.7:
            break  # a good start from the map: no need to search
    assert best is not None
    if fine_v:
        seed = best.seed
        best = icp_refine(source, target, best.T_target_source, cfg, num_threads, fine_v)
        best.seed = seed
    return best
