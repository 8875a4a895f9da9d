# SPDX-License-Identifier: BSD-3-Clause
"""Pairwise registration of point clouds on the native core (numpy in, numpy out, GIL released).

Local registration (:func:`register`) refines an initial guess with one of six methods (one solver);
global registration (:func:`register_global`) finds the pose from scratch with FPFH + RANSAC,
optionally constrained by gravity. Both return ``T_target_source``, the 4x4 rigid transform that
maps source coordinates into the target frame (``p_target = T @ p_source``), in metres.

Clouds used more than once (odometry against several neighbours, pose-graph edges) should be
prepared once with :func:`prepare` and passed as :class:`PreparedCloud`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .. import _ext
from ..preprocess import as_cloud, voxel_downsample

#: Local registration methods: point-to-point (closed-form SVD), point-to-plane, Generalized ICP,
#: voxelised GICP (Gaussian voxels of the target), symmetric ICP, and robust non-linear
#: point-to-plane ICP solved by Levenberg-Marquardt on each set of correspondences.
METHODS = ("icp", "plane", "gicp", "vgicp", "symmetric", "lm")
#: Robust kernels, applied to the residual whitened by ``point_sigma`` (scale ``loss_scale`` [m]).
LOSSES = ("none", "huber", "cauchy", "tukey")


@dataclass(frozen=True)
class RegistrationResult:
    """Outcome of :func:`register`.

    Attributes
    ----------
    T_target_source : (4, 4) float64 ndarray
        Rigid transform source -> target [m].
    converged : bool
        The last stage's update fell below the convergence thresholds and the problem is not
        degenerate.
    status : str
        ``"converged"``, ``"max_iterations"``, ``"degenerate"`` (some direction of the pose is not
        constrained by the geometry, e.g. a single plane or a featureless corridor) or
        ``"too_few_correspondences"``.
    iterations : int
        Iterations over all stages.
    num_inliers : int
        Source points with a target point within the final correspondence distance.
    fitness : float
        ``num_inliers / len(source)`` (Open3D's definition).
    inlier_rmse : float
        RMS distance of those pairs [m].
    residual_rmse : float
        RMS of the method's own unweighted residual over the pairs it used [m]: the point-to-
        plane distance for plane, symmetric and lm; the point distance otherwise.
    final_error : float
        Robust chi-square cost at the solution.
    information : (6, 6) float64 ndarray
        Inverse covariance of the pose for a right perturbation ``T @ exp(xi)``, ``xi = (rx, ry,
        rz, tx, ty, tz)`` in the source frame [1/rad^2, 1/m^2] (the convention of GTSAM/g2o
        pose-graph edges), assuming range noise ``point_sigma``. Locked directions (fixed
        rotation, target-frame z) lie in its null space.
    condition : float
        Smallest / largest eigenvalue of the surfaces' (point-to-plane) information, rotations
        scaled by the cloud's extent (1 = equally constrained in every direction; below 1e-4 the
        status is "degenerate"; a corridor is about 5e-3, a furnished room about 4e-2).
    """

    T_target_source: np.ndarray
    converged: bool
    status: str
    iterations: int
    num_inliers: int
    fitness: float
    inlier_rmse: float
    residual_rmse: float
    final_error: float
    information: np.ndarray
    condition: float

    @classmethod
    def _from_native(cls, r) -> "RegistrationResult":
        return cls(np.array(r.T_target_source), bool(r.converged), str(r.status),
                   int(r.iterations), int(r.num_inliers), float(r.fitness),
                   float(r.inlier_rmse), float(r.residual_rmse), float(r.final_error),
                   np.array(r.information), float(r.condition))

    @property
    def covariance(self) -> np.ndarray:
        """(6, 6) pseudo-inverse of :attr:`information` [rad^2, m^2]."""
        return np.linalg.pinv(self.information)

    def to_dict(self) -> dict:
        """JSON-friendly dict (lists for the matrices)."""
        return {
            "T_target_source": self.T_target_source.tolist(),
            "converged": self.converged,
            "status": self.status,
            "iterations": self.iterations,
            "num_inliers": self.num_inliers,
            "fitness": self.fitness,
            "inlier_rmse": self.inlier_rmse,
            "residual_rmse": self.residual_rmse,
            "final_error": self.final_error,
            "information": self.information.tolist(),
            "condition": self.condition,
        }


@dataclass(frozen=True)
class GlobalResult:
    """Outcome of :func:`register_global`.

    Attributes
    ----------
    T_target_source : (4, 4) float64 ndarray
        Rigid transform source -> target [m] (identity when ``success`` is False).
    success : bool
        A consensus of at least 3 (2 with gravity) correspondences was found.
    status : str
        ``"success"``, ``"no_correspondences"`` or ``"no_consensus"``.
    num_correspondences, num_inlier_correspondences : int
        Feature matches, and those agreeing with the pose.
    iterations : int
        RANSAC hypotheses drawn.
    fitness : float
        Fraction of (downsampled) source points within ``inlier_distance`` of the target.
    inlier_rmse : float
        [m]
    ambiguous : bool
        The twin check (``twin_check``) could not tell the pose from a twin turned about the
        up: their refined fits differ by less than ``twin_margin``. The pose is the better of
        the two all the same; an IMU yaw (``rotation_prior``) or other evidence must decide.
    twins : tuple of dict
        The twin check's candidates, the picked one first: ``turn_deg`` (0 for RANSAC's best,
        else the turn about the up from it), ``fitness`` and ``num_inlier_correspondences`` of
        the RANSAC pose, ``refined_fitness`` / ``refined_rmse`` [m] / ``refined_violation``
        (free-space violation) after the local refinement that judged them, ``score`` (what was
        compared: fitness - 10 x violation) and ``T_target_source`` (RANSAC's). Empty without
        a check (no gravity, ``twin_check`` off, or no twin drawn that fits nearly as well).
    """

    T_target_source: np.ndarray
    success: bool
    status: str
    num_correspondences: int
    num_inlier_correspondences: int
    iterations: int
    fitness: float
    inlier_rmse: float
    ambiguous: bool = False
    twins: tuple = ()

    @classmethod
    def _from_native(cls, r) -> "GlobalResult":
        return cls(np.array(r.T_target_source), bool(r.success), str(r.status),
                   int(r.num_correspondences), int(r.num_inlier_correspondences),
                   int(r.iterations), float(r.fitness), float(r.inlier_rmse))

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["T_target_source"] = self.T_target_source.tolist()
        d["twins"] = [{**t, "T_target_source": np.asarray(t["T_target_source"]).tolist()}
                      for t in self.twins]
        return d


@dataclass
class PreparedCloud:
    """A cloud ready for registration: finite points, k-d tree, normals, GICP covariances.

    Build it with :func:`prepare`. Arrays are copies made on access.
    """

    _native: object = field(repr=False)
    voxel_size: float | None = None

    def __len__(self) -> int:
        return len(self._native)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float32 [m]: the finite (and downsampled) points."""
        return self._native.points

    @property
    def normals(self) -> np.ndarray:
        """(N, 3) float64 unit normals facing the viewpoint (0 where ``normal_valid`` is False)."""
        return self._native.normals

    @property
    def normal_valid(self) -> np.ndarray:
        """(N,) bool."""
        return self._native.normal_valid

    @property
    def covariances(self) -> np.ndarray:
        """(N, 3, 3) float64 plane-regularised GICP covariances [m^2]."""
        return self._native.covariances.reshape(-1, 3, 3)

    @property
    def num_dropped(self) -> int:
        """Non-finite input rows dropped."""
        return self._native.num_dropped


def prepare(
    points,
    voxel_size: float | None = None,
    num_neighbors: int = 20,
    radius: float = 0.0,
    viewpoint: Sequence[float] = (0.0, 0.0, 0.0),
    point_sigma: float = 0.02,
    num_threads: int = 0,
) -> PreparedCloud:
    """Prepare a cloud for :func:`register`: voxel-downsample, build the tree, fit local planes.

    Parameters
    ----------
    points : (N, 3) array_like of float [m]
        Non-finite rows are dropped (counted in ``num_dropped``).
    voxel_size : float, optional
        Voxel edge [m] for downsampling (origin-aligned lattice); None keeps every point.
    num_neighbors : int
        k of the k-NN neighbourhood for normals and covariances (a cap when ``radius`` > 0).
    radius : float
        Neighbourhood radius [m]; 0 uses k-NN only.
    viewpoint : (3,) sequence of float
        The sensor position in the cloud's frame [m]: normals are oriented towards it.
    point_sigma : float
        Range noise [m]; scales GICP covariances so the cost is a chi-square.
    num_threads : int
        0 uses every core.

    Returns
    -------
    PreparedCloud
    """
    pts = as_cloud(points)
    if voxel_size is not None:
        pts = voxel_downsample(pts, voxel_size, num_threads=num_threads)
    if num_neighbors < 3 and not radius > 0:
        raise ValueError("num_neighbors must be >= 3 (or give a radius)")
    vp = np.asarray(viewpoint, dtype=np.float64).reshape(3)
    native = _ext.prepare_cloud(
        pts, int(num_neighbors), float(radius), vp, float(point_sigma), int(num_threads)
    )
    return PreparedCloud(native, voxel_size)


def _as_prepared(cloud, voxel_size, num_neighbors, point_sigma, num_threads) -> PreparedCloud:
    if isinstance(cloud, PreparedCloud):
        return cloud
    return prepare(cloud, voxel_size, num_neighbors, point_sigma=point_sigma,
                   num_threads=num_threads)


def _as_pose(T, name: str) -> np.ndarray:
    if T is None:
        return np.eye(4)
    a = np.asarray(T, dtype=np.float64)
    if a.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {a.shape}")
    return np.ascontiguousarray(a)


def default_schedule(target: PreparedCloud, voxel_size: float | None) -> list[float]:
    """The default coarse-to-fine correspondence distances [m].

    ``(10 v, 3 v)`` with ``v`` the voxel size (the first stage at least 0.3 m, for rooms), or
    without one ``(10 v, 3 v, v)`` with ``v`` the target's bounding-box diagonal / 100: one distance for a room and a statuette alike would
    let a small object's every point pair with every other (the far pairs of a partial overlap
    then hold point-to-point ICP degrees away from the truth, at its own minimum).
    """
    if voxel_size is not None:
        return [max(10 * voxel_size, 0.3), 3 * voxel_size]
    pts = target.points
    v = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) / 100 if len(pts) else 0.1
    v = v if v > 0 else 0.1
    return [10 * v, 3 * v, v]  # dense points (no voxel): a last stage at v is still well fed


def register(
    source,
    target,
    method: str = "gicp",
    init=None,
    voxel_size: float | None = None,
    max_correspondence_distance: float | Sequence[float] | None = None,
    max_iterations: int = 64,
    rotation_eps: float = 1e-3,
    translation_eps: float = 5e-4,
    loss: str = "none",
    loss_scale: float = 0.1,
    rotation_prior=None,
    rotation_prior_sigma: float = 0.0,
    lock_z: bool = False,
    num_neighbors: int = 20,
    point_sigma: float = 0.02,
    oriented: bool = False,
    min_normal_cos: float = 0.5,
    max_source: int = 0,
    min_correspondences: int = 0,
    num_threads: int = 0,
) -> RegistrationResult:
    """Local registration: refine ``init`` so that ``target ~ T_target_source @ source``.

    Parameters
    ----------
    source, target : (N, 3) array_like of float [m] or PreparedCloud
        Arrays are prepared here (``voxel_size``, ``num_neighbors``); a PreparedCloud is used as is.
    method : {"icp", "plane", "gicp", "vgicp", "symmetric", "lm"}
        Residual model: point-to-point (closed-form SVD per iteration; Gauss-Newton when
        constrained), point-to-plane, Generalized ICP (plane-to-plane covariances), voxelised
        GICP (the target as Gaussian voxels whose edge is each stage's correspondence distance;
        a point's correspondence is the voxel it falls in: the cheapest per iteration, made for
        coarse stages), symmetric ICP (sum of both normals), or point-to-plane solved to
        convergence by Levenberg-Marquardt on each set of correspondences (use it with a
        robust ``loss``).
    init : (4, 4) array_like, optional
        Initial T_target_source; identity if None.
    voxel_size : float, optional
        Downsampling voxel [m] for array inputs.
    max_correspondence_distance : float or sequence of float, optional
        Pairs farther apart are ignored [m]. A sequence is a coarse-to-fine schedule, one stage
        per value. Default: see Notes.
    max_iterations : int
        Per stage.
    rotation_eps, translation_eps : float
        Converged when an update rotates less than this [rad] and moves less than this [m], and
        the updates shrink fast enough that the rest of the way (extrapolated from the last two)
        is below them too: a slowly creeping point-to-point ICP is not "converged".
    loss : {"none", "huber", "cauchy", "tukey"}
        Robust kernel (iteratively reweighted).
    loss_scale : float
        Kernel scale [m].
    rotation_prior : (3, 3) array_like, optional
        Prior on the rotation of T_target_source, e.g. from the IMU: R_prior =
        R_world_target^T R_world_source.
    rotation_prior_sigma : float
        Its standard deviation [rad]; 0 fixes the rotation to the prior (translation only).
    lock_z : bool
        Keep the z translation of ``init`` (tripod height unchanged between stations).
    num_neighbors : int
        k-NN for normals/covariances of array inputs.
    point_sigma : float
        Range noise [m] that whitens residuals (information matrix, robust scale).
    oriented : bool
        Plane family: both clouds' normals face their own sensor (``viewpoint`` of
        :func:`prepare`), and a pair counts only when they agree as they are, so the two faces
        of a wall seen from both rooms never pair; source points without a normal take no part.
    min_normal_cos : float
        Plane family: pairs whose normals agree less (cosine) are dropped.
    max_source : int
        Use at most this many source points (an even stride through them); 0 uses all.
    min_correspondences : int
        Fewer pairs end with ``"too_few_correspondences"`` (0: the method's minimum, 3 or 6).
    num_threads : int
        OpenMP threads; 0 uses every core.

    Returns
    -------
    RegistrationResult

    Raises
    ------
    ValueError
        Unknown method/loss, a non-rigid ``init``, bad options, or a cloud with too few finite
        points for the method (3 for icp, 6 otherwise), or a target without any normal.

    Notes
    -----
    The default correspondence distances are a two-stage schedule, see :func:`default_schedule`;
    every method takes a schedule. Clouds at an unknown offset need :func:`register_global`
    first.
    The point-to-plane family (plane, symmetric, lm) ignores pairs whose normals differ by more
    than 60 deg. Point-to-point converges linearly: give it tight ``rotation_eps`` /
    ``translation_eps`` and more iterations.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    src = _as_prepared(source, voxel_size, num_neighbors, point_sigma, num_threads)
    tgt = _as_prepared(target, voxel_size, num_neighbors, point_sigma, num_threads)
    if max_correspondence_distance is None:
        max_correspondence_distance = default_schedule(tgt, voxel_size or src.voxel_size)
    dists = np.atleast_1d(np.asarray(max_correspondence_distance, dtype=np.float64)).tolist()
    opt = _ext._RegistrationOptions()
    opt.method = method
    opt.max_correspondence_distances = dists
    opt.max_iterations = int(max_iterations)
    opt.rotation_eps = float(rotation_eps)
    opt.translation_eps = float(translation_eps)
    opt.point_sigma = float(point_sigma)
    opt.loss = loss
    opt.loss_scale = float(loss_scale)
    if rotation_prior is not None:
        R_prior = np.ascontiguousarray(np.asarray(rotation_prior, dtype=np.float64))
        if R_prior.shape != (3, 3):
            raise ValueError(f"rotation_prior must be 3x3, got shape {R_prior.shape}")
        opt.R_prior = R_prior
    opt.rotation_prior_sigma = float(rotation_prior_sigma)
    opt.lock_z = bool(lock_z)
    opt.oriented = bool(oriented)
    opt.min_normal_cos = float(min_normal_cos)
    opt.max_source = int(max_source)
    opt.min_correspondences = int(min_correspondences)
    opt.num_threads = int(num_threads)
    r = _ext.register_local(src._native, tgt._native, _as_pose(init, "init"), opt)
    return RegistrationResult._from_native(r)


def register_global(
    source,
    target,
    voxel_size: float,
    up_source: Sequence[float] | None = None,
    up_target: Sequence[float] | None = None,
    gravity_aligned: bool = False,
    normal_radius: float | None = None,
    feature_radius: float | None = None,
    inlier_distance: float | None = None,
    max_neighbors: int = 100,
    mutual_filter: bool = False,
    edge_length_ratio: float = 0.9,
    max_iterations: int = 100_000,
    confidence: float = 0.999,
    viewpoint_source: Sequence[float] = (0.0, 0.0, 0.0),
    viewpoint_target: Sequence[float] = (0.0, 0.0, 0.0),
    rotation_prior=None,
    rotation_tolerance: float = np.radians(30.0),
    seed: int = 0,
    num_threads: int = 0,
    twin_check: bool = True,
    twin_turns_deg: Sequence[float] = (180.0,),
    twin_min_fitness_ratio: float = 0.8,
    twin_margin: float = 0.01,
) -> GlobalResult:
    """Global registration from scratch: FPFH features, (mutual) matches, RANSAC.

    Parameters
    ----------
    source, target : (N, 3) array_like of float [m]
        Downsampled here with ``voxel_size`` (origin-aligned).
    voxel_size : float
        [m]; sets the default radii: normals 2 v, FPFH 5 v, inlier distance 1.5 v.
    up_source, up_target : (3,) sequence of float, optional
        Gravity: the "up" direction in each cloud's frame (from the IMU roll/pitch). When given,
        the search is over yaw and translation only, so a symmetric room cannot come out tilted
        or upside down.
    gravity_aligned : bool
        Shorthand for ``up_source = up_target = (0, 0, 1)`` (both clouds already levelled).
    normal_radius, feature_radius, inlier_distance : float, optional
        [m]; defaults from ``voxel_size`` as above.
    max_neighbors : int
        Cap on a neighbourhood's size.
    mutual_filter : bool
        Keep only mutually nearest feature matches (off by default: on sparse or repetitive
        scenes it throws away the few right matches; hypotheses are scored on the geometry).
    edge_length_ratio : float
        Reject samples whose pairwise distances differ by more than this ratio.
    max_iterations : int
        Hypotheses at most; RANSAC stops early at ``confidence``.
    confidence : float
        In (0, 1).
    viewpoint_source, viewpoint_target : (3,) sequence of float
        Sensor positions [m] (normal orientation).
    rotation_prior : (3, 3) array_like, optional
        Prior R_target_source, e.g. the IMU's relative orientation (yaw from the gyro included):
        poses rotated more than ``rotation_tolerance`` away from it are rejected. Gravity alone
        cannot tell a symmetric room from its 180 deg turned twin; this can.
    rotation_tolerance : float
        [rad], default 30 deg.
    seed : int
        Same seed, same result, whatever ``num_threads``.
    num_threads : int
        0 uses every core.
    twin_check : bool
        With gravity: RANSAC's best pose against its twins turned about the up
        (``twin_turns_deg``), the best hypotheses RANSAC drew within 20 deg of those turns. A
        twin whose clouds fit at least ``twin_min_fitness_ratio`` of the pose's fitness is a
        contender: both are refined by point-to-plane ICP on the downsampled clouds and the one
        that fits better after it, free space counted, wins (see Notes). False: RANSAC's best as it is (the pick
        before stop 37).
    twin_turns_deg : sequence of float
        [deg]; (180,) for a rectangular room, (90, 180, 270) for a square one.
    twin_min_fitness_ratio : float
        In [0, 1].
    twin_margin : float
        Refined scores closer than this are a tie: ``ambiguous`` is set.

    Returns
    -------
    GlobalResult
        Refine it with :func:`register` (``init=result.T_target_source``).

    Notes
    -----
    In a room that is nearly symmetric under a half turn (a box with a little furniture) the
    pose and its 180 deg twin put the walls, floor and ceiling on each other alike, and their
    RANSAC fitness (at 1.5 voxels, from poses good to about a voxel) ties within its noise, or
    favours the twin when it brings the two sensors closer (what one station sees and the
    other does not counts against a pose; so does the furniture's shadow): the cloud score
    alone picks the twin about as often as the truth. The twin check refines both and scores
    them by fitness less ``TWIN_FREE_SPACE_WEIGHT`` x free-space violation: the twin puts the
    column or the cabinet of one station where the other's sensor saw through to the wall;
    the truth puts nothing there. It needs each cloud in its sensor's frame
    (``viewpoint_source`` / ``viewpoint_target``: the sensor's position in it) and costs two
    local registrations of the downsampled clouds and two range images; it runs only when a
    twin fits nearly as well.
    """
    if not voxel_size > 0:
        raise ValueError("voxel_size must be > 0")
    if gravity_aligned:
        up_source = up_target = (0.0, 0.0, 1.0)
    if (up_source is None) != (up_target is None):
        raise ValueError("give both up_source and up_target, or neither")
    zero = np.zeros(3)
    us = zero if up_source is None else np.asarray(up_source, dtype=np.float64).reshape(3)
    ut = zero if up_target is None else np.asarray(up_target, dtype=np.float64).reshape(3)
    if up_source is not None and (np.linalg.norm(us) == 0 or np.linalg.norm(ut) == 0):
        raise ValueError("up vectors must be non-zero")
    src = voxel_downsample(as_cloud(source), voxel_size, num_threads=num_threads)
    tgt = voxel_downsample(as_cloud(target), voxel_size, num_threads=num_threads)
    opt = _ext._GlobalOptions()
    opt.normal_radius = float(normal_radius or 2 * voxel_size)
    opt.feature_radius = float(feature_radius or 5 * voxel_size)
    opt.max_neighbors = int(max_neighbors)
    opt.inlier_distance = float(inlier_distance or 1.5 * voxel_size)
    opt.edge_length_ratio = float(edge_length_ratio)
    opt.mutual_filter = bool(mutual_filter)
    opt.max_iterations = int(max_iterations)
    opt.confidence = float(confidence)
    opt.up_source, opt.up_target = us, ut
    opt.viewpoint_source = np.asarray(viewpoint_source, dtype=np.float64).reshape(3)
    opt.viewpoint_target = np.asarray(viewpoint_target, dtype=np.float64).reshape(3)
    if rotation_prior is not None:
        opt.R_prior = np.asarray(rotation_prior, dtype=np.float64).reshape(3, 3)
    opt.rotation_tolerance = float(rotation_tolerance)
    if not 0 <= twin_min_fitness_ratio <= 1:
        raise ValueError("twin_min_fitness_ratio must be in [0, 1]")
    gravity = up_source is not None
    turns = [float(t) for t in twin_turns_deg] if twin_check and gravity else []
    opt.twin_turns = [float(np.radians(t)) for t in turns]
    opt.seed = int(seed)
    opt.num_threads = int(num_threads)
    native = _ext.register_global(src, tgt, opt)
    res = GlobalResult._from_native(native)
    if not res.success or not turns:
        return res
    rivals = [t for t in native.twins if t.fitness >= twin_min_fitness_ratio * res.fitness]
    if not rivals:
        return res
    return _pick_twin(res, rivals, source, target, src, tgt, voxel_size, opt.inlier_distance,
                      viewpoint_source, viewpoint_target, twin_margin, num_threads)


#: weight of the free-space violation in the twin check's score (as the odometry's and the
#: merge's ``free_space_weight``: one percent of points in the other's free space costs ten
#: points of fitness)
TWIN_FREE_SPACE_WEIGHT = 10.0


def _pick_twin(res: GlobalResult, rivals, raw_src, raw_tgt, src, tgt, voxel_size: float,
               inlier_distance: float, viewpoint_source, viewpoint_target, margin: float,
               num_threads: int) -> GlobalResult:
    """RANSAC's best pose against its contending twins: each refined by point-to-plane ICP on
    the downsampled clouds (``default_schedule``, then a last stage at ``inlier_distance``) and
    scored by its refined fitness less ``TWIN_FREE_SPACE_WEIGHT`` x its free-space violation
    (the larger share of either cloud's points lying where the other's sensor saw through,
    :mod:`registration.free_space`); the best wins (see :func:`register_global`)."""
    import dataclasses

    from . import free_space as fs

    vs = np.asarray(viewpoint_source, dtype=np.float64).reshape(3)
    vt = np.asarray(viewpoint_target, dtype=np.float64).reshape(3)
    ps = prepare(src, None, 20, viewpoint=vs, num_threads=num_threads)
    pt = prepare(tgt, None, 20, viewpoint=vt, num_threads=num_threads)
    sched = default_schedule(pt, voxel_size) + [inlier_distance]
    # range images about each sensor, from the clouds at half the voxel (at most 6 cm: dense
    # enough for 1 deg cells at the range of a room, see free_space)
    fine = min(0.5 * voxel_size, 0.06)
    img_s = fs.range_image(
        _finite(voxel_downsample(as_cloud(raw_src), fine, num_threads=num_threads)) - vs)
    img_t = fs.range_image(
        _finite(voxel_downsample(as_cloud(raw_tgt), fine, num_threads=num_threads)) - vt)
    S, T_ = np.asarray(ps.points, np.float64), np.asarray(pt.points, np.float64)

    def violation(T: np.ndarray) -> float:
        return fs.mutual_violation(S, T_, T, img_s, img_t, vs, vt)

    cands = [{"turn_deg": 0.0, "T_target_source": res.T_target_source, "fitness": res.fitness,
              "inlier_rmse": res.inlier_rmse,
              "num_inlier_correspondences": res.num_inlier_correspondences}]
    for t in rivals:
        cands.append({"turn_deg": float(np.degrees(t.turn)),
                      "T_target_source": np.array(t.T_target_source),
                      "fitness": float(t.fitness), "inlier_rmse": float(t.inlier_rmse),
                      "num_inlier_correspondences": int(t.num_inlier_correspondences)})
    for c in cands:
        try:
            r = register(ps, pt, "plane", init=c["T_target_source"],
                         max_correspondence_distance=sched, max_iterations=30,
                         num_threads=num_threads)
            T, fit, rmse = r.T_target_source, float(r.fitness), float(r.inlier_rmse)
        except ValueError:
            T, fit, rmse = c["T_target_source"], 0.0, 0.0
        viol = violation(T)
        c.update(refined_fitness=fit, refined_rmse=rmse, refined_violation=viol,
                 score=fit - TWIN_FREE_SPACE_WEIGHT * viol)
    order = sorted(range(len(cands)), key=lambda k: (-cands[k]["score"], k))
    win = cands[order[0]]
    ambiguous = win["score"] - cands[order[1]]["score"] < margin
    twins = tuple(cands[k] for k in order)
    if order[0] == 0:
        return dataclasses.replace(res, ambiguous=ambiguous, twins=twins)
    return dataclasses.replace(
        res, T_target_source=np.array(win["T_target_source"]), fitness=win["fitness"],
        inlier_rmse=win["inlier_rmse"],
        num_inlier_correspondences=win["num_inlier_correspondences"], ambiguous=ambiguous,
        twins=twins)


def _finite(points) -> np.ndarray:
    P = np.asarray(points, dtype=np.float64)
    return P[np.isfinite(P).all(axis=1)]
