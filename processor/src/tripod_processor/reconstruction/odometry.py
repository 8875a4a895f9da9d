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
    #: share of either fragment's points in the other's free space (``free_space``; nan when
    #: not checked)
    violation: float = float("nan")
    #: the registration core's status of the last stage
    status: str = ""


def information_target_frame(info_rt_source: np.ndarray, T_target_source: np.ndarray
                             ) -> np.ndarray:
    """Convert the registration core's information to the pose graph's convention.

    The core's ξ = (ω, v) is a right perturbation T·exp(ξ) in the source frame; the pose graph's
    error is e = (e_t, e_r) with the translation error in the target frame and the rotation error
    in the source frame, so ω = e_r and v = Rᵀ e_t: ξ = J e with J = [[0, I], [Rᵀ, 0]], and the
    information of e is Jᵀ Λ J.
    """
    R = np.asarray(T_target_source)[:3, :3]
    J = np.zeros((6, 6))
    J[0:3, 3:6] = np.eye(3)
    J[3:6, 0:3] = R.T
    return J.T @ info_rt_source @ J


def _cap_information(info: np.ndarray, cfg: OdometryConfig) -> np.ndarray:
    """Cap the information at the configured floor sigmas (every eigenvalue of the scaled
    matrix at most 1): thousands of correlated correspondences would otherwise claim
    micrometres and make the pose graph's outlier gate meaningless."""
    cap = np.array([1 / cfg.sigma_floor_m**2] * 3 + [1 / np.radians(cfg.sigma_floor_deg)**2] * 3)
    s = 1.0 / np.sqrt(cap)
    scaled = info * np.outer(s, s)
    w, V = np.linalg.eigh(0.5 * (scaled + scaled.T))
    scaled = (V * np.clip(w, 0.0, 1.0)) @ V.T
    return scaled / np.outer(s, s)


def patch_support(src_points: np.ndarray, src_normals: np.ndarray, tgt_points: np.ndarray,
                  tgt_normals: np.ndarray, T_target_source: np.ndarray, max_dist: float,
                  cell_m: float, voxel_m: float, normal_share: float = 0.1,
                  max_source: int = 40_000, planar_ratio: float = 0.1) -> np.ndarray:
    """The overlap's surface support per patch, (3, 3) in the target frame: the sum over the
    ``cell_m`` cells of the overlap (source points within ``max_dist`` of a target point whose
    normal agrees, cosine > 0.5) of each cell's normal spread (the mean n nᵀ of its points,
    its eigen-directions holding less than ``normal_share`` dropped: a wall's normal noise is
    no vertical support) times its covered share (its points over a full cell's at
    ``voxel_m``, at most 1). dᵀ S d counts the surface patches that constrain a translation
    along the unit d. Normals of 0 (invalid) are ignored."""
    from scipy.spatial import cKDTree

    src = np.asarray(src_points, np.float64)
    ns = np.asarray(src_normals, np.float64)
    keep = np.linalg.norm(ns, axis=1) > 0.5
    src, ns = src[keep], ns[keep]
    if len(src) > max_source:
        step = int(np.ceil(len(src) / max_source))
        src, ns = src[::step], ns[::step]
    tgt = np.asarray(tgt_points, np.float64)
    nt = np.asarray(tgt_normals, np.float64)
    S = np.zeros((3, 3))
    if len(src) == 0 or len(tgt) == 0:
        return S
    R, t = np.asarray(T_target_source)[:3, :3], np.asarray(T_target_source)[:3, 3]
    p = src @ R.T + t
    n = ns @ R.T
    d, j = cKDTree(tgt).query(p, distance_upper_bound=max_dist)
    hit = np.isfinite(d)
    hit[hit] &= np.einsum("ij,ij->i", n[hit], nt[j[hit]]) > 0.5
    if not hit.any():
        return S
    p, n = p[hit], n[hit]
    full = (cell_m / voxel_m) ** 2
    _, cell, counts = np.unique(np.floor(p / cell_m).astype(np.int64), axis=0,
                                return_inverse=True, return_counts=True)
    cell = cell.ravel()
    M = np.zeros((len(counts), 3, 3))
    np.add.at(M, cell, n[:, :, None] * n[:, None, :])
    M /= counts[:, None, None]
    w, V = np.linalg.eigh(M)
    w = np.where(w >= normal_share, w, 0.0)
    # a planar cell (its points' thickness under a ``planar_ratio`` of their spread in the
    # plane) is one plane: its normal from the cell's points, whose scatter averages out the
    # range noise that tilts the 12-neighbour normals of a far wall (dev 722: walls at 6-7 m
    # with |n . up| 0.4 on average, 5 cells' worth of vertical support that was not there)
    mean = np.zeros((len(counts), 3))
    np.add.at(mean, cell, p)
    mean /= counts[:, None]
    q = p - mean[cell]
    C = np.zeros((len(counts), 3, 3))
    np.add.at(C, cell, q[:, :, None] * q[:, None, :])
    lc, Vc = np.linalg.eigh(C / counts[:, None, None])
    planar = (counts >= 10) & (lc[:, 0] < planar_ratio * lc[:, 1])
    w[planar] = [0.0, 0.0, 1.0]
    V[planar] = Vc[planar][:, :, [1, 2, 0]]
    w *= np.minimum(1.0, counts / full)[:, None]
    return np.einsum("ckj,cj,clj->kl", V, w, V)


def cap_by_patches(info: np.ndarray, support: np.ndarray, cfg: OdometryConfig) -> np.ndarray:
    """``info`` (6, 6; the pose graph's order, translation in the target frame) capped so that
    along no translation direction d it claims more than dᵀ S d / ``patch_sigma_m``² +
    1 / ``patch_sigma_max_m``² (S: :func:`patch_support`), the rotation at the floor's cap;
    the matrix is whitened by the cap and its eigenvalues clipped at 1 (as
    :func:`_cap_information`)."""
    C = np.zeros((6, 6))
    C[:3, :3] = support / cfg.patch_sigma_m**2 + np.eye(3) / cfg.patch_sigma_max_m**2
    C[3:, 3:] = np.eye(3) / np.radians(cfg.sigma_floor_deg) ** 2
    return _cap_whitened(info, C)


class CloudCache:
    """Fragments prepared for registration (tree, covariances) once per voxel size.

    Every voxel size at least twice ``base_voxel`` is filtered from the fragment's
    ``base_voxel`` cloud (itself filtered once from the full fragment), not from the full
    fragment again: one pass over the dense cloud per fragment."""

    def __init__(self, point_sigma: float, num_threads: int = 0, base_voxel: float = 0.06):
        self.point_sigma, self.num_threads = point_sigma, num_threads
        self.base_voxel = base_voxel
        self._c: dict = {}

    def down(self, key, points: np.ndarray, voxel: float, threads: int | None = None
             ) -> np.ndarray:
        """The fragment voxel-filtered at ``voxel`` (its own frame), float32 (N, 3)."""
        k = ("down", key, voxel)
        if k not in self._c:
            if voxel == self.base_voxel or voxel < 2 * self.base_voxel:
                src = points
            else:
                src = self.down(key, points, self.base_voxel, threads)
            self._c[k] = voxel_downsample(src, voxel, self._threads(threads))
        return self._c[k]

    def _threads(self, threads: int | None) -> int:
        return self.num_threads if threads is None else threads

    def oriented(self, key, points: np.ndarray, voxel: float, threads: int | None = None):
        """The cloud at ``voxel`` prepared with 12-neighbour normals facing the fragment's
        sensor (its origin), for :func:`oriented_refine`."""
        from ..registration import pairwise as reg

        k = ("oriented", key, voxel)
        if k not in self._c:
            self._c[k] = reg.prepare(self.down(key, points, voxel, threads), num_neighbors=12,
                                     point_sigma=self.point_sigma,
                                     num_threads=self._threads(threads))
        return self._c[k]

    def coarse(self, key, points: np.ndarray, voxel: float, threads: int | None = None
               ) -> np.ndarray:
        """The cloud voxel-filtered at ``voxel`` (its own frame): the top-down seeds' input."""
        return self.down(key, points, voxel, threads).astype(np.float64)

    def get(self, key, points: np.ndarray, voxel: float, threads: int | None = None):
        from ..registration import pairwise as reg

        k = (key, voxel)
        if k not in self._c:
            self._c[k] = reg.prepare(self.down(key, points, voxel, threads), num_neighbors=20,
                                     point_sigma=self.point_sigma,
                                     num_threads=self._threads(threads))
        return self._c[k]

    def prepare_all(self, key, points: np.ndarray, cfg: OdometryConfig,
                    threads: int | None = None) -> None:
        """Everything :func:`register_fragments` takes of one fragment, ahead (the same clouds
        as on first use: the native filters and fits do not depend on the threads)."""
        self.coarse(key, points, cfg.voxels_m[0] * 0.5, threads)
        for v in cfg.voxels_m:
            self.get(key, points, v, threads)
        if cfg.oriented_refine:
            self.oriented(key, points, ORIENTED_VOXEL_M, threads)
        if cfg.free_space_check:
            self.range_image(key, points, threads)

    def range_image(self, key, points: np.ndarray, threads: int | None = None) -> np.ndarray:
        """The fragment's range image (``free_space.range_image``) from its cloud at
        ``ORIENTED_VOXEL_M``."""
        from ..registration.free_space import range_image

        k = ("range", key)
        if k not in self._c:
            self._c[k] = range_image(self.down(key, points, ORIENTED_VOXEL_M, threads))
        return self._c[k]


def icp_refine(source: np.ndarray, target: np.ndarray, T_init: np.ndarray,
               cfg: OdometryConfig, num_threads: int = 0, voxels: list[float] | None = None,
               cache: CloudCache | None = None, keys=("source", "target"),
               R_prior: np.ndarray | None = None) -> PairResult:
    """Coarse-to-fine registration (the core's ``cfg.method``) of ``source`` onto ``target``
    (both (N, 3) [m]) from ``T_init`` over ``voxels`` (default: the configured schedule), with
    the IMU rotation as a weighted prior."""
    from ..registration import pairwise as reg

    cache = cache or CloudCache(cfg.point_sigma_m, num_threads)
    voxels = list(cfg.voxels_m if voxels is None else voxels)
    T = np.asarray(T_init, dtype=np.float64).copy()
    res = None
    for voxel in voxels:
        src = cache.get(keys[0], source, voxel)
        tgt = cache.get(keys[1], target, voxel)
        if len(src) < 20 or len(tgt) < 20:
            return PairResult(T, 0.0, np.inf, np.zeros((6, 6)), False)
        try:
            res = reg.register(src, tgt, method=cfg.method, init=T,
                               max_correspondence_distance=3.0 * voxel, max_iterations=30,
                               rotation_prior=R_prior,
                               rotation_prior_sigma=np.radians(cfg.rotation_prior_sigma_deg),
                               lock_z=cfg.lock_z, point_sigma=cfg.point_sigma_m,
                               num_threads=num_threads)
        except ValueError:
            return PairResult(T, 0.0, np.inf, np.zeros((6, 6)), False)
        T = res.T_target_source
    assert res is not None
    info = _cap_information(information_target_frame(res.information, T), cfg)
    ok = res.fitness >= cfg.min_fitness and res.status != "too_few_correspondences"
    return PairResult(T, float(res.fitness), float(res.inlier_rmse), info, ok, status=res.status)


# ---- final refinement: point-to-plane with oriented normals --------------------------------------
#: the voxel [m] of :func:`oriented_refine`'s clouds
ORIENTED_VOXEL_M = 0.06


def oriented_refine(source: np.ndarray, target: np.ndarray, T_init: np.ndarray,
                    cfg: OdometryConfig, num_threads: int = 0, voxel: float = ORIENTED_VOXEL_M,
                    max_dist: float = 0.15, iterations: int = 10, max_source: int = 40_000,
                    cache: "CloudCache | None" = None, keys=("source", "target"),
                    hold_rotation: np.ndarray | None = None, lock_z: bool = False
                    ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Point-to-plane ICP that only pairs surfaces seen from the same side (the last stage).

    A wall seen from both rooms of a door is two faces a wall's thickness apart; without the
    normals' orientation, registration pairs the faces across the wall and splits the
    difference. Normals here face each fragment's sensor (the fragment origin), and a pair
    whose normals disagree (dot < 0.5) is no correspondence. Huber weights at 2 sigma; at most
    ``max_source`` source points (an even stride), the target stays dense. Runs in the native
    core (``registration.register(method="plane", oriented=True)``). ``hold_rotation``: the
    rotation R_target_source (3, 3) held fixed (``T_init``'s should be it): the translation
    only. ``lock_z``: the translation's z (the target frame's) held at ``T_init``'s.

    Returns (T_target_source, information (6, 6) in the pose graph's convention, fitness,
    inlier RMSE [m]).
    """
    from .. import registration as reg

    cache = cache or CloudCache(cfg.point_sigma_m, num_threads)
    src = cache.oriented(keys[0], source, voxel)
    tgt = cache.oriented(keys[1], target, voxel)
    sigma = cfg.point_sigma_m
    held = {} if hold_rotation is None else {"rotation_prior": hold_rotation,
                                             "rotation_prior_sigma": 0.0}
    r = reg.register(src, tgt, method="plane", init=T_init, max_correspondence_distance=max_dist,
                     max_iterations=iterations, rotation_eps=1e-6, translation_eps=1e-5,
                     loss="huber", loss_scale=2 * sigma, point_sigma=sigma, oriented=True,
                     max_source=max_source, min_correspondences=100, num_threads=num_threads,
                     lock_z=lock_z, **held)
    T = r.T_target_source
    if r.status == "too_few_correspondences":
        return T, np.zeros((6, 6)), 0.0, np.inf
    fit, rmse = r.fitness, r.residual_rmse
    # the core's information assumes residuals of sigma: scale it to the measured ones
    info = information_target_frame(r.information, T) * (sigma / max(rmse, sigma)) ** 2
    if (cfg.patch_sigma_m > 0 or cfg.flat_probe_m > 0) and hold_rotation is None:
        S = patch_support(src.points, src.normals, tgt.points, tgt.normals, T, max_dist,
                          cfg.patch_cell_m, voxel, cfg.patch_normal_share, max_source)
        if cfg.patch_sigma_m > 0:
            info = cap_by_patches(info, S, cfg)
        ev, EV = np.linalg.eigh(S)
        if cfg.flat_probe_m > 0 and ev[0] < cfg.flat_probe_support:
            def probe(T0):
                return reg.register(src, tgt, method="plane", init=T0,
                                    max_correspondence_distance=max_dist,
                                    max_iterations=iterations, rotation_eps=1e-6,
                                    translation_eps=1e-5, loss="huber", loss_scale=2 * sigma,
                                    point_sigma=sigma, oriented=True,
                                    max_source=min(max_source, 10_000), min_correspondences=100,
                                    num_threads=num_threads, rotation_prior=T[:3, :3],
                                    rotation_prior_sigma=0.0).T_target_source
            info = cap_flat_direction(info, T, EV[:, 0], cfg.flat_probe_m, probe, cfg)
    return T, info, fit, rmse


def cap_flat_direction(info: np.ndarray, T: np.ndarray, d: np.ndarray, step_m: float, refine,
                       cfg: OdometryConfig) -> np.ndarray:
    """``info`` capped along the translation direction ``d`` (unit, target frame) by how flat
    the cost is there: ``refine(T0)`` (the registration, rotation held) is started from ``T``
    moved ±``step_m`` along d, and the larger distance along d at which a start stays from
    ``T`` is the direction's sigma (at least ``sigma_floor_m``). A well-constrained direction
    brings both starts back (mm); along a flat one (dev 722's pair round a corridor's corner,
    vertical: 0.6 % of its points on horizontal surfaces) they stay where they start."""
    d = np.asarray(d, np.float64) / np.linalg.norm(d)
    off = []
    for sgn in (1.0, -1.0):
        T0 = np.array(T, dtype=np.float64)
        T0[:3, 3] += sgn * step_m * d
        off.append(abs(float((np.asarray(refine(T0))[:3, 3] - T[:3, 3]) @ d)))
    sigma_d = max(max(off), cfg.sigma_floor_m)
    C = np.zeros((6, 6))
    C[:3, :3] = (np.eye(3) - np.outer(d, d)) / cfg.sigma_floor_m**2 + np.outer(d, d) / sigma_d**2
    C[3:, 3:] = np.eye(3) / np.radians(cfg.sigma_floor_deg) ** 2
    return _cap_whitened(info, C)


def _cap_whitened(info: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``info`` whitened by the cap ``C`` (6, 6, positive definite), its eigenvalues clipped at
    1, and mapped back: no direction claims more than C does."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    half, ihalf = (V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T
    scaled = ihalf @ info @ ihalf
    w2, V2 = np.linalg.eigh(0.5 * (scaled + scaled.T))
    return half @ ((V2 * np.clip(w2, 0.0, 1.0)) @ V2.T) @ half


def level_rotation(R_target_source: np.ndarray, up_source: np.ndarray,
                   up_target: np.ndarray) -> np.ndarray:
    """``R_target_source`` turned by the smallest rotation that takes ``up_source`` (the world's
    up in the source's frame) onto ``up_target``: the relative tilt of the two attitudes, the
    yaw (about the up axis) of ``R_target_source``."""
    from scipy.spatial.transform import Rotation

    a = R_target_source @ (up_source / np.linalg.norm(up_source))
    b = up_target / np.linalg.norm(up_target)
    ax = np.cross(a, b)
    s, c = float(np.linalg.norm(ax)), float(a @ b)
    if s < 1e-15:
        return R_target_source.copy()
    return Rotation.from_rotvec(ax / s * np.arctan2(s, c)).as_matrix() @ R_target_source


#: source points of :func:`tilt_refit` (a translation only: dev seed 126's pairs 1.19 cm RMS off
#: the truth with 10 000, 1.21 with the full refine's 40 000, at a third of its CPU)
TILT_REFIT_MAX_SOURCE = 10_000


def tilt_refit(source: np.ndarray, target: np.ndarray, r: PairResult,
               R_world_source: np.ndarray, R_world_target: np.ndarray, cfg: OdometryConfig,
               num_threads: int = 0, cache: CloudCache | None = None, keys=("source", "target"),
               lock_z: bool = False) -> PairResult:
    """A registered pair ``r`` finished at the IMU's relative tilt: its rotation levelled
    (:func:`level_rotation`, the anchors' up directions) and its translation refitted by
    :func:`oriented_refine` with that rotation held; ``r`` as it was when the refit finds too
    few correspondences or moves more than 0.3 m. The information stays the registration's
    (the pose graph takes its tilt out, ``slam.tilt_free_information``).

    Why: in a small room the fragments' range noise tilts a registration 0.1-0.6° off, with
    its translation off along (dev seed 126, the whole true calibration: pairs 1.9 cm RMS off;
    refitted at the anchors' tilt, 0.006° RMS off the truth, 1.2 cm).
    """
    up = np.array([0.0, 0.0, 1.0])
    T0 = np.array(r.T_target_source, dtype=np.float64)
    T0[:3, :3] = level_rotation(T0[:3, :3], R_world_source.T @ up, R_world_target.T @ up)
    T, _info, fit, _rmse = oriented_refine(source, target, T0, cfg, num_threads, cache=cache,
                                           keys=keys, hold_rotation=T0[:3, :3],
                                           max_source=TILT_REFIT_MAX_SOURCE, lock_z=lock_z)
    if fit <= 0 or np.linalg.norm(T[:3, 3] - T0[:3, 3]) >= 0.3:
        return r
    return PairResult(T, r.fitness, r.rmse, r.information, r.ok, r.seed, r.violation, r.status)


# ---- translation seed: top-down correlation of the gravity-aligned fragments ------------------
def _topdown(points_w: np.ndarray, cell: float, half: int) -> np.ndarray:
    ij = np.floor(points_w[:, :2] / cell).astype(np.int64) + half
    ok = (ij >= 0).all(1) & (ij < 2 * half).all(1)
    img = np.zeros((2 * half, 2 * half))
    np.add.at(img, (ij[ok, 0], ij[ok, 1]), 1.0)
    img = np.log1p(img)
    return img - img.mean()


def height_shift(target_w: np.ndarray, source_w: np.ndarray, refine: bool = False,
                 bin_m: float = 0.02) -> float:
    """dz [m] with target_w ≈ source_w + dz (heights of gravity-aligned points about each
    fragment's origin): the peak of the correlation of their height histograms (``bin_m``
    bins, log counts; floor and ceiling are strong peaks). ``refine``: the peak interpolated
    between bins (a parabola through the three bins about it), else the bin's shift (the
    translation seeds')."""
    bins = np.arange(-6.0, 6.0 + bin_m, bin_m)
    ht, _ = np.histogram(np.asarray(target_w)[:, 2], bins)
    hs, _ = np.histogram(np.asarray(source_w)[:, 2], bins)
    zcorr = np.correlate(np.log1p(ht) - np.log1p(ht).mean(), np.log1p(hs) - np.log1p(hs).mean(),
                         "full")
    k = int(np.argmax(zcorr))
    frac = 0.0
    if refine and 0 < k < len(zcorr) - 1:
        a, b, c = zcorr[k - 1], zcorr[k], zcorr[k + 1]
        den = a - 2 * b + c
        if den < 0:
            frac = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    return (k + frac - (len(hs) - 1)) * bin_m


#: the floor/ceiling height histograms (:func:`horizontal_height_shift`): points whose normal
#: is within acos(0.9) of the up, their least count a fragment, and the bins [m]
HORIZONTAL_NORMAL_COS = 0.9
HORIZONTAL_MIN_POINTS = 100
HORIZONTAL_BIN_M = 0.01


def horizontal_height_shift(source: np.ndarray, target: np.ndarray, R_world_source: np.ndarray,
                            R_world_target: np.ndarray, cache: CloudCache,
                            keys=("source", "target")) -> float | None:
    """dz [m] (target_w ≈ source_w + dz, as :func:`translation_seeds`) from the heights of the
    two fragments' horizontal surfaces only (their oriented clouds' points whose normal is
    near the up, levelled by the IMU attitudes): floor and ceiling wherever each fragment sees
    them, not only in the overlap, at 1-cm bins refined between them. None when either holds
    fewer than ``HORIZONTAL_MIN_POINTS``.

    The whole clouds' histograms (the seeds') are dominated by the walls' band about the
    sensor's height on a near-vertical lidar (dev 722, pair 0->1: 0.7 cm off the truth's
    -15.1 cm with 2-cm bins and walls, 0.05 cm with horizontal surfaces at 1 cm refined; the
    six station pairs of 722: 0.03-0.12 cm)."""
    h = []
    for key, pts, R in ((keys[1], target, R_world_target), (keys[0], source, R_world_source)):
        pc = cache.oriented(key, pts, ORIENTED_VOXEL_M)
        up = np.asarray(R, np.float64).T @ np.array([0.0, 0.0, 1.0])
        n_up = np.asarray(pc.normals, np.float64) @ up
        sel = np.abs(n_up) > HORIZONTAL_NORMAL_COS
        if int(sel.sum()) < HORIZONTAL_MIN_POINTS:
            return None
        h.append(np.asarray(pc.points, np.float64)[sel] @ np.asarray(R, np.float64).T)
    return height_shift(h[0], h[1], refine=True, bin_m=HORIZONTAL_BIN_M)


def up_sigma_m(info: np.ndarray, up: np.ndarray) -> float:
    """The standard deviation [m] of a pair's translation along the unit ``up`` (its target
    frame) from its information (6, 6; the pose graph's order), the rotation marginalised;
    inf where the information holds none."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    A = 0.5 * (info + info.T)
    A = A + 1e-12 * max(float(np.trace(A)), 1.0) * np.eye(6)  # a direction held by nothing: huge
    v = float(u @ np.linalg.inv(A)[:3, :3] @ u)
    return float(np.sqrt(v)) if v > 0 else float("inf")


#: a height reset by :func:`height_from_seed` is held (``lock_z``) through the oriented refine
#: and the tilt refit where the target's z axis is within this [deg] of the world's up
HEIGHT_HOLD_MAX_DEG = 10.0


def height_from_seed(r: PairResult, dz: float | None, up_t: np.ndarray, cfg: OdometryConfig
                     ) -> tuple[PairResult, bool]:
    """``r`` with its translation's component along the world's up (``up_t``, unit, in the
    target frame) set to the floor's and ceiling's height shift ``dz``
    (:func:`horizontal_height_shift`; None: ``r`` as it is) when its registration leaves the
    height less determined than ``cfg.height_seed_gate_m`` (σ along up, :func:`up_sigma_m`);
    returns (pair, whether it was reset).

    Why (dev seed 722, a corridor round a corner seen by a near-vertical lidar, ±15° about
    the horizon: 0.6 % of the overlap's points on horizontal surfaces): the pair round the
    corner had σ_up 4.1 cm in the fine GICP; the 0.6-m GICP stage pulled its seed's height
    (0.3 cm off) to 6.9 cm, and the oriented refine, flat along up, left it at 5.4 cm while
    claiming 3 mm (the loop over it then failed the pose graph's gate). The two stations'
    floors and ceilings, seen far away in each leg, give the shift to 0.1 cm."""
    if cfg.height_seed_gate_m <= 0 or not r.ok or dz is None:
        return r, False
    if up_sigma_m(r.information, up_t) < cfg.height_seed_gate_m:
        return r, False
    u = np.asarray(up_t, np.float64) / np.linalg.norm(up_t)
    T = np.array(r.T_target_source, dtype=np.float64)
    T[:3, 3] += u * (dz - float(u @ T[:3, 3]))
    return PairResult(T, r.fitness, r.rmse, r.information, r.ok, r.seed, r.violation,
                      r.status), True


def up_from_seed_information(info: np.ndarray, up_t: np.ndarray, sigma_up_m: float
                             ) -> np.ndarray:
    """``info`` (6, 6; the pose graph's order) with its translation along the unit ``up_t``
    (target frame) measured by the height seed alone: whatever the registration claimed along
    up (with the height held: nothing) replaced by 1 / ``sigma_up_m``²."""
    u = np.asarray(up_t, np.float64) / np.linalg.norm(up_t)
    P = np.eye(6)
    P[:3, :3] -= np.outer(u, u)
    out = P @ (0.5 * (info + info.T)) @ P
    out[:3, :3] += np.outer(u, u) / sigma_up_m**2
    return out


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
    dz = height_shift(target_w, source_w, refine=False)
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


def free_space_violation(source: np.ndarray, target: np.ndarray, T_target_source: np.ndarray,
                         cfg: OdometryConfig, cache: CloudCache, keys=("source", "target")
                         ) -> float:
    """The larger share of either fragment's points (the seeds' coarse clouds) lying in the
    other station's free space with the pair placed by ``T_target_source``."""
    from ..registration.free_space import mutual_violation

    coarse = cfg.voxels_m[0] * 0.5
    return mutual_violation(cache.coarse(keys[0], source, coarse),
                            cache.coarse(keys[1], target, coarse), T_target_source,
                            cache.range_image(keys[0], source), cache.range_image(keys[1], target))


def candidate_rank(r: PairResult, consistent: bool, cfg: OdometryConfig) -> tuple:
    """The sort key of a registration candidate (larger is better): a candidate worth keeping at
    all (overlap ``min_fitness``, or ``min_fitness_free_space`` where it respects free space)
    first, then its overlap less ``free_space_weight`` x its violation beyond
    ``max_free_space_violation``, then the smaller RMSE.

    A corridor slid along its axis (37 % overlap, 3 % violation) loses to the right pose round
    the corner (27 %, 0 %); a station in a doorway (~5 % false violations at the right pose: its
    lidar swings off the pan axis at the jambs) beats a wrong pose at 20 %. Soft, not a cliff at
    the limit: the right pose of a 4 x 4 m room, still 9 cm off after the coarse stages, showed
    0.51 % and lost to a pose laying the room beside itself (41 % overlap, 0 %: everything of
    one room lies behind the other's walls), 4.2 m off (development rig 2 under a 0.1°
    perturbation of its fragments, ``bench/fragility.py``).
    """
    check = cfg.free_space_check
    excess = max(0.0, r.violation - cfg.max_free_space_violation) if check else 0.0
    score = r.fitness - cfg.free_space_weight * (excess if np.isfinite(excess) else 0.0)
    viable = r.fitness >= cfg.min_fitness or (consistent
                                              and r.fitness >= cfg.min_fitness_free_space)
    return (viable, score, -r.rmse)


def register_fragments(source: np.ndarray, target: np.ndarray, R_world_source: np.ndarray,
                       R_world_target: np.ndarray, cfg: OdometryConfig, num_threads: int = 0,
                       T_guess: np.ndarray | None = None, cache: CloudCache | None = None,
                       keys=("source", "target"), tilt_known: bool = False) -> PairResult:
    """T_target_source between two fragments, with the IMU attitude as rotation prior.

    Tries ``T_guess`` first when given (loop closures from the current map), then the top-down
    seeds; keeps the best-fitting verified result. With ``cfg.free_space_check`` a candidate
    that respects free space beats one that does not (a corridor's slide along its axis fits
    better than the truth when the stations see different legs of an L), and a pair that
    respects it is registered down to ``cfg.min_fitness_free_space``.

    ``tilt_known``: both attitudes' tilts are fitted over their stations' IMU samples
    (``Fragment.tilt_fitted``); with ``cfg.tilt_from_imu`` the result's rotation is then set to
    their relative tilt (its yaw kept) and its translation refitted with the rotation held
    (:func:`tilt_refit`).
    """
    R_ts = R_world_target.T @ R_world_source
    cache = cache or CloudCache(cfg.point_sigma_m, num_threads)
    candidates: list[tuple[str, np.ndarray]] = []
    if T_guess is not None:
        candidates.append(("guess", np.asarray(T_guess, dtype=np.float64)))
    # the seeds' clouds: voxel-filtered once per fragment in its own frame, then levelled
    coarse = cfg.voxels_m[0] * 0.5
    tw = cache.coarse(keys[1], target, coarse) @ R_world_target.T
    sw = cache.coarse(keys[0], source, coarse) @ R_world_source.T
    def seeds(extent_m: float, prefix: str) -> list[tuple[str, np.ndarray]]:
        out = []
        for k, d in enumerate(translation_seeds(tw, sw, cfg.seed_cell_m, extent_m)):
            T = np.eye(4)
            T[:3, :3] = R_ts
            T[:3, 3] = R_world_target.T @ d
            out.append((f"{prefix}{k}", T))
        return out

    candidates += seeds(cfg.seed_extent_m, "topdown")
    # every start through the coarse stages; only the best one through the fine stages. A
    # guess from the map (loop closures) wins when it converges close to itself with a good
    # overlap: in rooms that look alike, a far seed can fit better and be wrong; with a weak
    # overlap a far seed must fit better by ``guess_margin``.
    n_coarse = max(1, min(2, len(cfg.voxels_m) - 1))
    coarse_v, fine_v = cfg.voxels_m[:n_coarse], cfg.voxels_m[n_coarse:]
    check = cfg.free_space_check

    def free(r: PairResult) -> bool:
        """r respects free space (always, unchecked)."""
        if check and r.fitness > 0:
            r.violation = free_space_violation(source, target, r.T_target_source, cfg, cache,
                                               keys)
        return not check or r.violation <= cfg.max_free_space_violation

    best: PairResult | None = None
    best_key: tuple = ()
    best_free = False
    # the wide seeds join the starts only when the best of the first ones does not respect free
    # space (``seed_wide_extent_m``): a shift longer than the first images' reach is then not
    # among their seeds, and an alias of a repeating hall fits best
    wide = check and cfg.seed_wide_extent_m > cfg.seed_extent_m
    k_start = 0
    while k_start < len(candidates):
        for name, T0 in candidates[k_start:]:
            r = icp_refine(source, target, T0, cfg, num_threads, coarse_v, cache, keys, R_ts)
            r.seed = name
            consistent = free(r)
            key = candidate_rank(r, consistent, cfg)
            if name == "guess" and r.ok and consistent:
                D = np.linalg.inv(T0) @ r.T_target_source
                ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
                if np.linalg.norm(D[:3, 3]) < cfg.guess_radius_m and ang < 5.0:
                    if r.fitness >= cfg.guess_min_fitness:
                        best, best_free = r, True
                        break
                    # a weak fit near the guess: the seeds too, which must beat it by a margin
                    # (a map already wrong by an odometry pair gives a guess that converges
                    # near itself at 35-41 % overlap where the right pose overlaps 100 %)
                    key = (key[0], key[1] + cfg.guess_margin, key[2])
            if best is None or key > best_key:
                best, best_key, best_free = r, key, consistent
        k_start = len(candidates)
        if wide and not best_free:
            wide = False
            candidates += seeds(cfg.seed_wide_extent_m, "wide")
    assert best is not None
    if fine_v:
        seed = best.seed
        best = icp_refine(source, target, best.T_target_source, cfg, num_threads, fine_v, cache,
                          keys, R_ts)
        best.seed = seed
    if check and not best.ok and best.fitness >= cfg.min_fitness_free_space \
            and best.status != "too_few_correspondences" and free(best):
        best.ok = True  # little overlap, but placed where free space agrees
    # a height the overlap hardly holds: the floor's and ceiling's, wherever each fragment
    # sees them
    up_t = R_world_target.T @ np.array([0.0, 0.0, 1.0])
    height_reset = False
    if best.ok and cfg.height_seed_gate_m > 0 \
            and up_sigma_m(best.information, up_t) >= cfg.height_seed_gate_m:
        best, height_reset = height_from_seed(
            best, horizontal_height_shift(source, target, R_world_source, R_world_target, cache,
                                          keys), up_t, cfg)
    # ... held by the last stages where the target's z is the up (a near-vertical lidar)
    hold_z = height_reset and abs(float(up_t[2])) >= np.cos(np.radians(HEIGHT_HOLD_MAX_DEG))
    if best.ok and cfg.oriented_refine:
        T, info, fit, rmse = oriented_refine(source, target, best.T_target_source, cfg,
                                             num_threads, cache=cache, keys=keys, lock_z=hold_z)
        D = np.linalg.inv(best.T_target_source) @ T
        if np.linalg.norm(D[:3, 3]) < 0.3 and fit > 0.5 * best.fitness:
            best = PairResult(T, best.fitness, rmse, _cap_information(info, cfg), True, best.seed)
    if best.ok and tilt_known and cfg.tilt_from_imu:
        best = tilt_refit(source, target, best, R_world_source, R_world_target, cfg,
                          num_threads, cache, keys, lock_z=hold_z)
    if height_reset and best.ok:
        best.information = up_from_seed_information(best.information, up_t,
                                                    cfg.height_seed_sigma_m)
    if check and best.ok:
        free(best)  # the final pose's violation, for the notes
    return best
