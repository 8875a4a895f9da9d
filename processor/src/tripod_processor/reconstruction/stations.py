# SPDX-License-Identifier: BSD-3-Clause
"""Split a recording into stations: periods when the tripod stands (its head may turn).

A station is a period in which the head only turns about its pan axis, about a pivot that does
not move. Two cues, each blind to the rig's calibration:

* **IMU**: the rotation between two moments ``still_gap_s`` apart is a pure turn about the pan
  axis (a rig constant in the IMU frame, found as the dominant axis of the IMU's turns); its
  *swing* (what is not about that axis) stays below ``still_tilt_deg`` at a station. Carrying
  sways the head. A motor or a hand, an uneven speed, a pause or a reversal all keep the swing
  at zero.
* **lidar**: short windows of points are rotated by the IMU about the pivot; the shift of the
  pivot between two windows is fitted to the range changes along the directions both windows
  sampled. An unknown lever arm ℓ shows at a standing tripod as a shift (R_k − R_j)·ℓ, linear in
  ℓ, so ℓ's error is fitted over the windows the IMU calls still and taken out; what is left,
  below ``still_threshold`` [m], is stillness.

Runs of still windows are merged when the pivot did not move across the gap between them (a
station is never cut in two); runs of at least ``min_station_s`` are stations, shorter ones are
reported. The operator's ``mark`` events label the stations they fall in, and split a still run
that holds two marks; a mark outside every station is reported.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..decode.timed import decode_xyz_time
from .config import StationConfig
from .inputs import LidarPackets
from .placement import Extrinsic, ImuOrientation, place_points, pose_world_lidar


@dataclass
class Station:
    """One station: lidar-time span [start_ns, end_ns) and its packets [packet_start, packet_stop)."""

    index: int
    start_ns: int
    end_ns: int
    packet_start: int
    packet_stop: int
    label: str = ""

    @property
    def mid_ns(self) -> int:
        return (self.start_ns + self.end_ns) // 2

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9


@dataclass
class Segmentation:
    stations: list[Station]
    t_ns: np.ndarray  # (K,) window times
    motion_m: np.ndarray  # (K,) pivot shift against the window still_gap_s before [m]
    still: np.ndarray  # (K,) bool
    notes: list[str] = field(default_factory=list)
    tilt_deg: np.ndarray | None = None  # (K,) swing off the pan axis over still_gap_s [deg]
    #: still periods too short for a station: (start_ns, end_ns)
    short: list[tuple[int, int]] = field(default_factory=list)
    #: marks (lidar ns, label) and the pan axis (IMU frame) the IMU cue used
    marks: list[tuple[int, str]] = field(default_factory=list)
    pan_axis_imu: np.ndarray | None = None
    #: lever-arm error taken out of the lidar cue [m], IMU frame (ℓ_true − ℓ_used, across the
    #: pan axis; a first guess the calibration refines)
    lever_correction_m: np.ndarray | None = None
    merged_gaps: int = 0  # gaps between still runs closed because the pivot did not move


def _window_cloud(lidar: LidarPackets, a: int, b: int, orient: ImuOrientation, ext: Extrinsic,
                  n_max: int, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """Points of packets [a, b) in the head-pivot frame, at most n_max (random subset), and the
    lidar time [ns] whose IMU attitude placed them."""
    pts = _window_points(lidar, a, b)
    return _place_window(lidar, a, _window_sample(pts, _window_subset(len(pts[0]), n_max, rng)),
                         orient, ext)


def _window_points(lidar: LidarPackets, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (N, 3) float32, time_ns (N,)) of packets [a, b) (one thread: windows run side by
    side)."""
    return decode_xyz_time(lidar.payload, lidar.lidar_ns, a, b, min_range=0.5, num_threads=1)[:2]


def _window_subset(n: int, n_max: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """(kept indices in firing order, their positions in the random sample's order) of n points
    when more than n_max; None when all are kept. Drawn in window order (deterministic)."""
    if n <= n_max:
        return None
    sel = rng.choice(n, n_max, replace=False)  # random order: any prefix is a sample
    o = np.argsort(sel)
    order = np.empty(n_max, dtype=np.intp)
    order[o] = np.arange(n_max)
    # placed in firing order (the native placement's fast path), given back in the sample's
    return sel[o], order


def _window_sample(pts: tuple[np.ndarray, np.ndarray], subset) -> tuple:
    """(xyz, time_ns, order or None): the window's points reduced to the drawn subset."""
    if subset is None:
        return pts[0], pts[1], None
    keep, order = subset
    return pts[0][keep], pts[1][keep], order


def _place_window(lidar: LidarPackets, a: int, sample: tuple, orient: ImuOrientation,
                  ext: Extrinsic) -> tuple[np.ndarray, int]:
    """:func:`_window_cloud` after the decode and the draw (:func:`_window_sample`)."""
    xyz, t_ns, order = sample
    if len(xyz) == 0:
        return np.zeros((0, 3)), int(lidar.lidar_ns[min(a, len(lidar.lidar_ns) - 1)])
    # R_wi(t) (R_il x + l) = T_wl(a) · (the point placed in the lidar frame at a)
    anchor = int(t_ns[len(t_ns) // 2])
    placed = place_points(xyz, t_ns, orient, ext, anchor, num_threads=1)
    T_a = pose_world_lidar(orient, ext, np.array([anchor]))[0]
    p = placed.astype(np.float64) @ T_a[:3, :3].T + T_a[:3, 3]
    return (p if order is None else p[order]), anchor


def _window_shifts(lidar: LidarPackets, times: np.ndarray, win: int, gap: int,
                   orient: ImuOrientation, ext: Extrinsic, n_points: int, n_query: int,
                   rng: np.random.Generator, num_threads: int, progress=None,
                   reuse: dict | None = None, reuse_max_bytes: int = 512 << 20,
                   ahead: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(anchors (K,), pivot shifts D (K, 3) against the window ``gap`` before (NaN: unknown),
    their projectors Pm (K, 3, 3)) of the windows at ``times``.

    A pipeline on ``num_threads`` threads (the native decode and placement and the k-d trees
    run without the GIL), with no barrier between windows: each window's decode is a task;
    its random subset is drawn on the calling thread in window order as the decodes come in
    (so the result does not depend on the threads); then one task places the window and fits
    it against the window ``gap`` before, once that one is placed (tasks start in submission
    order, so the wait ends). At most ``ahead`` windows are decoded or placed ahead of the
    oldest unfinished one (bounded memory).

    ``reuse``: a dict kept between two passes over one recording (another rig calibration): the
    first keeps the decoded samples there (up to ``reuse_max_bytes``), the second places them
    again instead of decoding and drawing, and leaves ``rng`` where the draws would have."""
    import threading
    from collections import deque
    from concurrent.futures import Future, ThreadPoolExecutor

    K = len(times)
    anchors = np.zeros(K, dtype=np.int64)
    D = np.full((K, 3), np.nan)
    Pm = np.zeros((K, 3, 3))
    placed: dict[int, Future] = {}  # window -> its placed cloud (pivot frame)
    lock = threading.Lock()
    ab = np.searchsorted(lidar.lidar_ns, np.stack([times, times + win], axis=1))

    key = (int(times[0]) if K else 0, K, win, n_points, id(lidar))
    cached = reuse.get("samples") if reuse is not None and reuse.get("key") == key else None
    keep: list | None = [] if reuse is not None and cached is None else None
    kept_bytes = 0

    def place_and_fit(k: int, sample: tuple) -> None:
        try:
            c, anchors[k] = _place_window(lidar, int(ab[k, 0]), sample, orient, ext)
        except BaseException as exc:  # window k + gap waits for this placement
            placed[k].set_exception(exc)
            raise
        with lock:
            placed[k].set_result(c)
            ref_f = placed.get(k - gap)
        ref = ref_f.result() if ref_f is not None else None  # submitted (so started) before k
        if ref is not None and len(ref) > 50 and len(c) > 50:
            f = pivot_shift_fit(ref, c[:n_query])
            if f is not None:
                D[k], Pm[k] = f

    workers = max(1, num_threads or (os.cpu_count() or 1))
    with ThreadPoolExecutor(workers) as pool:
        decoded: deque = deque()  # (window, future of its points), in window order
        fitted: deque = deque()  # (window, future of its placement and fit), in window order
        nxt = 0  # next window to decode
        for k in range(K):
            while cached is None and nxt < K and nxt < k + ahead:
                decoded.append((nxt, pool.submit(_window_points, lidar, int(ab[nxt, 0]),
                                                 int(ab[nxt, 1]))))
                nxt += 1
            if cached is not None:
                sample = cached[k]
            else:
                _, pts = decoded.popleft()
                sample = _window_sample(pts.result(),
                                        _window_subset(len(pts.result()[0]), n_points, rng))
                if keep is not None:
                    keep.append(sample)
                    kept_bytes += sum(x.nbytes for x in sample if x is not None)
                    if kept_bytes > reuse_max_bytes:
                        keep = None  # too long a recording to keep: the next pass decodes
            with lock:
                placed[k] = Future()
            fitted.append((k, pool.submit(place_and_fit, k, sample)))
            while fitted and (len(fitted) >= ahead or fitted[0][1].done()):
                j, fut = fitted.popleft()
                fut.result()  # raises what the task raised
                with lock:
                    placed.pop(j - gap, None)  # bounded memory: j - gap is no one's reference
                if progress is not None:
                    progress.update(1)
        for j, fut in fitted:
            fut.result()
            if progress is not None:
                progress.update(1)
    if cached is not None:
        rng.bit_generator.state = reuse["rng_state"]
    elif keep is not None:
        reuse.update(key=key, samples=keep, rng_state=rng.bit_generator.state)
    return anchors, D, Pm


def _ranges(p: np.ndarray) -> np.ndarray:
    """|p| of each row of p (N, 3), rounded as ``np.linalg.norm(p, axis=1)`` rounds it
    ((x² + y²) + z², then the root) without its reduction's overhead (~8x faster here)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.sqrt(x * x + y * y + z * z)


def _beyond(p: np.ndarray, min_range: float) -> tuple[np.ndarray, np.ndarray]:
    """(the rows of p (N, 3) farther than ``min_range`` [m], their ranges); p itself when
    every row is (no copy)."""
    r = _ranges(p)
    ok = r > min_range
    return (p, r) if ok.all() else (p[ok], r[ok])


def matched_directions(u_ref: np.ndarray, u_q: np.ndarray, max_dist: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(dist (M,), idx (M,)): each query direction's nearest reference direction strictly
    closer than ``max_dist`` (chord length of unit vectors), exactly as
    ``cKDTree(u_ref).query(u_q, k=1, distance_upper_bound=max_dist)`` gives them (inf /
    ``len(u_ref)`` where none is).

    A native grid search (no tree to build: ~5x faster here); where two references lie at
    exactly the same distance from a query (dual returns can give the same direction twice) it
    does not know which one cKDTree would keep, so the call is answered by cKDTree itself."""
    from .. import _ext

    dist, idx, ties = _ext.nearest_within(np.ascontiguousarray(u_ref, dtype=np.float64),
                                          np.ascontiguousarray(u_q, dtype=np.float64),
                                          float(max_dist))
    if ties:
        # an unbalanced tree builds ~2x faster and queries alike here
        tree = cKDTree(u_ref, balanced_tree=False, compact_nodes=False)
        dist, idx = tree.query(u_q, k=1, distance_upper_bound=max_dist)
    return dist, idx


def pivot_shift_fit(ref: np.ndarray, query: np.ndarray, max_angle_deg: float = 0.3
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """The pivot's shift d (3,) [m] between two windows and the projector P (3, 3) onto the
    directions the shared view constrains (pivot frame); None when fewer than 50 directions
    match.

    A standing tripod sees the same range in every direction from the pivot whatever the head
    does. If the pivot moved by d, the range along direction u changes by about −u·d, so a
    robust least-squares fit of d to the range changes measures the motion in whatever
    directions the shared view constrains. Only directions sampled by both windows (within
    ``max_angle_deg``) are compared, because a tilted lidar on a panning head sweeps different
    parts of the sphere from moment to moment. Residuals are weighted by range: a direction
    mismatch of δ moves an oblique surface's range by about r·δ·tan(incidence), so far points
    (a 40 m hall) are noisier by nature, not because the tripod moves.
    """
    ref, r_ref = _beyond(ref, 0.3)
    query, r_q = _beyond(query, 0.3)
    if len(ref) < 50 or len(query) < 50:
        return None
    u_q = query / r_q[:, None]
    dist, idx = matched_directions(ref / r_ref[:, None], u_q, np.radians(max_angle_deg))
    hit = np.isfinite(dist)
    if hit.sum() < 50:
        return None
    A = -u_q[hit]
    b = r_q[hit] - r_ref[idx[hit]]
    # noise model [m]: 3 cm range noise plus the range change of a direction mismatch
    sig = np.hypot(0.03, r_q[hit] * dist[hit] * 2.0)
    wgt = 1.0 / sig
    A_w, b_w = A * wgt[:, None], b * wgt
    keep = np.ones(len(b), dtype=bool)
    d = np.zeros(3)
    for _ in range(3):  # least squares, then trim outliers (occlusion edges, grazing surfaces)
        d, *_ = np.linalg.lstsq(A_w[keep], b_w[keep], rcond=None)
        res = b_w - A_w @ d
        mad = np.median(np.abs(res[keep] - np.median(res[keep]))) + 1e-6
        keep = np.abs(res) < 3.0 * 1.4826 * mad
        if keep.sum() < 20:
            return None
    # only the directions the shared view constrains
    w, V = np.linalg.eigh(A[keep].T @ A[keep] / keep.sum())
    Vo = V[:, w > 0.05]
    return d, Vo @ Vo.T


def pivot_shift(ref: np.ndarray, query: np.ndarray, max_angle_deg: float = 0.3) -> float:
    """|P·d| of :func:`pivot_shift_fit` [m]; NaN when fewer than 50 directions match."""
    fit = pivot_shift_fit(ref, query, max_angle_deg)
    return float("nan") if fit is None else float(np.linalg.norm(fit[1] @ fit[0]))


def _swing_deg(R_a: np.ndarray, R_b: np.ndarray, axis_imu: np.ndarray) -> np.ndarray:
    """Angle [deg] by which the pan axis moved in the world between attitudes R_a and R_b
    (N, 3, 3): the swing of R_aᵀR_b off a pure turn about ``axis_imu``."""
    ua = np.einsum("nij,j->ni", R_a, axis_imu)
    ub = np.einsum("nij,j->ni", R_b, axis_imu)
    return np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", ua, ub), -1.0, 1.0)))


def _imu_pan_axis(R: np.ndarray) -> np.ndarray:
    """The dominant turn axis (IMU frame) of consecutive attitudes R (K, 3, 3)."""
    from scipy.spatial.transform import Rotation

    if len(R) < 3:
        return np.array([0.0, 0.0, 1.0])
    v = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:])).as_rotvec()
    w, V = np.linalg.eigh(v.T @ v)
    b = V[:, -1]
    return b if float(np.sum(v @ b)) >= 0 else -b


def _fit_lever_correction(D: np.ndarray, Pm: np.ndarray, M: np.ndarray, use: np.ndarray,
                          axis_imu: np.ndarray, threshold: float) -> np.ndarray:
    """e (3,) with P_k·d_k ≈ P_k·M_k·e over the windows ``use`` (robust; across the pan axis).

    D (K, 3) pivot shifts, Pm (K, 3, 3) their projectors, M (K, 3, 3) = R_k − R_j."""
    from .calibration import _perp_basis

    U = _perp_basis(axis_imu)
    e = np.zeros(3)
    sel = np.flatnonzero(use)
    for _ in range(4):
        if len(sel) < 4:
            break
        A = np.einsum("kij,kjl,lm->kim", Pm[sel], M[sel], U).reshape(-1, 2)
        y = np.einsum("kij,kj->ki", Pm[sel], D[sel]).reshape(-1)
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        e = U @ c
        res = np.linalg.norm(np.einsum("kij,kj->ki", Pm[use], D[use] - np.einsum(
            "kij,j->ki", M[use], e)), axis=1)
        lim = max(threshold, 3.0 * float(np.median(res)))
        sel = np.flatnonzero(use)[res < lim]
    return e


def segment_stations(lidar: LidarPackets, orient: ImuOrientation, ext: Extrinsic,
                     cfg: StationConfig, marks_lidar_ns: list[tuple[int, str]] | None = None,
                     step_s: float = 0.5, window_s: float = 0.1, n_points: int = 12000,
                     n_query: int = 4000,
                     progress=None, num_threads: int = 1, reuse: dict | None = None
                     ) -> Segmentation:
    """Find the stations of a recording (see the module docstring); the windows on
    ``num_threads`` threads (0: all cores; the result does not depend on it). ``reuse``: one
    dict passed to every pass over a recording keeps its decoded windows between them (the
    result does not depend on it)."""
    t0, t1 = int(lidar.lidar_ns[0]), int(lidar.lidar_ns[-1])
    step, win = int(step_s * 1e9), int(window_s * 1e9)
    times = np.arange(t0, t1 - win, step, dtype=np.int64)
    K = len(times)
    gap = max(1, int(round(cfg.still_gap_s / step_s)))
    rng = np.random.default_rng(0)
    anchors, D, Pm = _window_shifts(lidar, times, win, gap, orient, ext, n_points, n_query, rng,
                                    num_threads, progress, reuse)
    # the IMU's view: at a station the head only turns about its pan axis
    R_w = orient.rotation_at(anchors) if K else np.zeros((0, 3, 3))
    axis = _imu_pan_axis(R_w[::max(1, gap)] if K > 3 * gap else R_w)
    tilt = np.zeros(K)
    if K > gap:
        tilt[gap:] = _swing_deg(R_w[:-gap], R_w[gap:], axis)
    moving_imu = tilt > cfg.still_tilt_deg
    # the lidar's view with the lever arm's own apparent shift taken out: fitted on the windows
    # the IMU calls still whose shift a lever arm of up to 0.3 m could explain
    M = np.zeros((K, 3, 3))
    if K > gap:
        M[gap:] = R_w[gap:] - R_w[:-gap]
    known = np.isfinite(D[:, 0])
    Dz = np.where(known[:, None], D, 0.0)
    raw = np.linalg.norm(np.einsum("kij,kj->ki", Pm, Dz), axis=1)
    bound = cfg.still_threshold + 0.3 * np.linalg.norm(M, ord=2, axis=(1, 2))
    cand = known & ~moving_imu & (raw < bound)
    e = _fit_lever_correction(Dz, Pm, M, cand, axis, cfg.still_threshold)
    motion = np.full(K, np.inf)
    motion[known] = np.linalg.norm(np.einsum("kij,kj->ki", Pm[known], Dz[known] - np.einsum(
        "kij,j->ki", M[known], e)), axis=1)
    # a time offset error δ turns window k against window k − gap about the pan axis by
    # δ·(ω_k − ω_{k−gap}) (and twists a window whose rate changes): nothing at a steady pan, but
    # at a hand pan's reversal or pause a fraction of a degree, which a 20-40 m hall turns into
    # centimetres of apparent shift; those windows are placed again with the offset free (a
    # carry's shift stays)
    motion = _offset_tolerant_motion(lidar, times, win, gap, orient, ext, axis, e, motion,
                                     ~moving_imu, cfg, n_points, n_query,
                                     num_threads=num_threads)
    # unknown (too little shared view): take the neighbours' verdict
    bad = ~np.isfinite(motion)
    if bad.any() and (~bad).any():
        good = np.flatnonzero(~bad)
        motion[bad] = np.interp(np.flatnonzero(bad), good, motion[good])
    # a 3-window median removes single spikes (a person walking by, a bad match)
    if len(motion) >= 3:
        padded = np.concatenate([motion[:1], motion, motion[-1:]])
        motion = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    # a window is still when it matches the window gap before or the window gap after it
    still_pair = (motion < cfg.still_threshold) & ~moving_imu
    still = still_pair.copy()
    still[: len(still) - gap] |= still_pair[gap:]

    runs = _runs(still)
    ctx = _Ctx(lidar, orient, ext, times, win, R_w, axis, e, cfg, rng, n_points, n_query,
               num_threads)
    runs, merged = _merge_runs(runs, ctx)
    marks = sorted(marks_lidar_ns or []) if cfg.use_marks else []
    runs = _split_by_marks(runs, marks, times, win)

    stations: list[Station] = []
    short: list[tuple[int, int]] = []
    notes: list[str] = []
    trim = int(cfg.trim_s * 1e9)
    for k, e_k in runs:
        r0, r1 = int(times[k]), int(times[e_k]) + win
        if (r1 - r0) * 1e-9 >= cfg.min_station_s:
            s_ns, e_ns = r0 + trim, r1 - trim
            a, b = np.searchsorted(lidar.lidar_ns, [s_ns, e_ns])
            stations.append(Station(len(stations), s_ns, e_ns, int(a), int(b)))
        elif (r1 - r0) * 1e-9 >= 1.0:
            short.append((r0, r1))
            notes.append(f"still period of {(r1 - r0) * 1e-9:.1f} s at {(r0 - t0) * 1e-9:.1f} s "
                         f"is shorter than a station ({cfg.min_station_s:g} s): not used")
    for t_mark, label in marks:
        hit = [s for s in stations if s.start_ns - 2 * step <= t_mark <= s.end_ns + 2 * step]
        if hit:
            hit[0].label = label or hit[0].label
        else:
            notes.append(f"mark {label!r} at {(t_mark - t0) * 1e-9:.3f} s falls in no station")
    if merged:
        notes.append(f"{merged} short interruption(s) of stillness inside stations ignored (the "
                     "pivot did not move across them)")
    return Segmentation(stations, times, motion, still, notes, tilt, short, list(marks), axis, e,
                        merged)


def _pan_rate(orient: ImuOrientation, axis: np.ndarray, t_ns: np.ndarray,
              h_ns: int = 50_000_000) -> np.ndarray:
    """Signed turn rate about the pan axis (K,) [rad/s] at ``t_ns`` (central difference)."""
    if not len(t_ns):
        return np.zeros(0)
    Ra = orient.rotation_at(t_ns - h_ns // 2)
    Rb = orient.rotation_at(t_ns + h_ns // 2)
    ua = _pan_angle(Ra, axis)
    ub = _pan_angle(Rb, axis)
    return np.angle(np.exp(1j * (ub - ua))) / (h_ns * 1e-9)


def _offset_tolerant_motion(lidar: LidarPackets, times: np.ndarray, win: int, gap: int,
                            orient: ImuOrientation, ext: Extrinsic, axis: np.ndarray,
                            e: np.ndarray, motion: np.ndarray, imu_still: np.ndarray,
                            cfg: StationConfig, n_points: int, n_query: int, n_grid: int = 5,
                            num_threads: int = 1, block: int = 32) -> np.ndarray:
    """``motion`` with the windows that look moving only where the pan rate changes refitted.

    A window k the IMU calls still, whose shift exceeds ``still_threshold`` while the pan rate
    changes across it and window k − gap (by Δω: a reversal, a pause, a hand's uneven speed),
    is placed again, with window k − gap, at time offsets δ ∈ [−δmax, δmax] from the current
    one (δmax = ``cfg.max_time_offset_error_ms``; a grid, then a finer one around the best):
    its motion is the smallest shift over δ. An offset error turns each point about the pan
    axis by δ·ω(t) — a turn of one window against the other, and a twist inside a window where
    the rate changes — and nothing else; a carry moves the pivot, which no δ explains. Each
    window's points are drawn with its own seed (the result does not depend on the order or
    the threads; ``num_threads`` windows and offsets side by side, 0: all cores)."""
    from concurrent.futures import ThreadPoolExecutor

    K = len(times)
    out = motion.copy()
    dmax_ns = int(cfg.max_time_offset_error_ms * 1e6)
    if K <= gap or dmax_ns <= 0:
        return out
    # the pan rate's spread over each window and the one gap before it
    sub = np.linspace(0, win, 5).astype(np.int64)
    rate = _pan_rate(orient, axis, (times[:, None] + sub[None, :]).reshape(-1)).reshape(K, -1)
    lo, hi = rate.min(axis=1), rate.max(axis=1)
    spread = np.zeros(K)
    spread[gap:] = np.maximum(hi[gap:], hi[:-gap]) - np.minimum(lo[gap:], lo[:-gap])
    todo = np.flatnonzero(np.isfinite(motion) & (motion >= cfg.still_threshold) & imu_still
                          & (spread * dmax_ns * 1e-9 > np.radians(0.01)))
    todo = todo[todo >= gap]
    # only a stretch of such windows with a window that looks still (or unknown) on either side
    # is placed again: the refit bridges a reversal or pause inside a station, and never
    # extends a station at its ends, where the pan ramps up or down as the tripod settles or
    # is lifted (a settle's sway there is partly explained by a turn, and the station then
    # took in the sway's points: a 2.4 m odometry break in the building's 02-east-south)
    moved = np.isfinite(motion) & (motion >= cfg.still_threshold)
    keep = []
    for run in np.split(todo, np.flatnonzero(np.diff(todo) > 1) + 1) if len(todo) else []:
        a, b = int(run[0]) - 1, int(run[-1]) + 1
        if a >= gap and b < K and not moved[a] and not moved[b]:
            keep.append(run)
    todo = np.concatenate(keep) if keep else todo[:0]
    if not len(todo):
        return out
    ab = np.searchsorted(lidar.lidar_ns, np.stack([times, times + win], axis=1))

    def sample(k: int) -> tuple:
        pts = _window_points(lidar, int(ab[k, 0]), int(ab[k, 1]))
        rng = np.random.default_rng([0x5EED, k])
        return _window_sample(pts, _window_subset(len(pts[0]), n_points, rng))

    grid = np.linspace(-dmax_ns, dmax_ns, n_grid).astype(np.int64)
    step = int(2 * dmax_ns // (n_grid - 1))
    fine = np.linspace(-step, step, n_grid + 2)[1:-1].astype(np.int64)
    # every window's samples, then every (window, offset) placement and every (window pair,
    # offset) fit, side by side on threads (decode, placement and k-d trees run without the
    # GIL; each value is computed alone, so the result does not depend on the threads); blocks
    # bound the samples kept
    workers = max(1, num_threads or (os.cpu_count() or 1))
    with ThreadPoolExecutor(workers) as pool:
        for b in range(0, len(todo), block):
            ks = todo[b:b + block].tolist()
            need = sorted(set(ks) | {k - gap for k in ks})
            samples = dict(zip(need, pool.map(sample, need)))
            ks = [k for k in ks if len(samples[k - gap][0]) > 50 and len(samples[k][0]) > 50]
            ev = _ShiftEvaluator(lidar, ab, samples, orient, ext, e, gap, n_query, pool)
            vals = np.array(ev.values([(k, int(g)) for k in ks for g in grid])
                            ).reshape(len(ks), -1)
            best = grid[np.argmin(vals, axis=1)] if len(ks) else grid[:0]
            vf = np.array(ev.values([(k, int(c) + int(f)) for k, c in zip(ks, best)
                                     for f in fine])).reshape(len(ks), -1)
            for i, k in enumerate(ks):
                out[k] = min(float(out[k]), float(vals[i].min()), float(vf[i].min()))
    return out


class _ShiftEvaluator:
    """The shifts of :func:`_offset_tolerant_motion` for one block of windows: the motion of
    window k against window k − gap, both placed at a time offset δ from the current one.

    Each (window, δ) is placed once (window k at δ is also window k + gap's reference at δ)
    and each (k, δ) is fitted once (the fine grid's δ = 0 is the coarse grid's best), on the
    pool's threads; every value is the same number as when computed alone. One call's
    placements are kept until its fits are done: at most 2 × block windows × the offsets of the
    call (each 12,000 points × 24 bytes: ~90 MB for a block of 32 isolated windows on the
    coarse grid of 5)."""

    def __init__(self, lidar: LidarPackets, ab: np.ndarray, samples: dict, orient: ImuOrientation,
                 ext: Extrinsic, e: np.ndarray, gap: int, n_query: int, pool) -> None:
        self.lidar, self.ab, self.samples, self.orient, self.ext = lidar, ab, samples, orient, ext
        self.e, self.gap, self.n_query, self.pool = e, gap, n_query, pool
        self._shift: dict[tuple[int, int], float] = {}

    def _orient(self, d_ns: int) -> ImuOrientation:
        return self.orient.with_offset(self.orient.time_offset_ns + int(d_ns))

    def _place(self, w: int, d_ns: int) -> tuple[np.ndarray, int]:
        return _place_window(self.lidar, int(self.ab[w, 0]), self.samples[w], self._orient(d_ns),
                             self.ext)

    def _fit(self, k: int, d_ns: int, placed: dict) -> float:
        ref, a_j = placed[(k - self.gap, d_ns)]
        c, a_k = placed[(k, d_ns)]
        fit = pivot_shift_fit(ref, c[:self.n_query])
        if fit is None:
            return float("inf")
        R_j, R_k = self._orient(d_ns).rotation_at(np.array([a_j, a_k]))
        d, P = fit
        return float(np.linalg.norm(P @ (d - (R_k - R_j) @ self.e)))

    def values(self, tasks: list[tuple[int, int]]) -> list[float]:
        """The shift [m] of each (window k, offset δ [ns]) in ``tasks`` (inf: no fit)."""
        new = [t for t in dict.fromkeys(tasks) if t not in self._shift]
        keys = sorted({(w, d) for k, d in new for w in (k - self.gap, k)})
        placed = dict(zip(keys, self.pool.map(lambda wd: self._place(*wd), keys)))
        for t, v in zip(new, self.pool.map(lambda kd: self._fit(*kd, placed), new)):
            self._shift[t] = v
        return [self._shift[t] for t in tasks]


def _runs(still: np.ndarray) -> list[tuple[int, int]]:
    """[first, last] window indices of the runs of True."""
    out = []
    k = 0
    while k < len(still):
        if not still[k]:
            k += 1
            continue
        e = k
        while e + 1 < len(still) and still[e + 1]:
            e += 1
        out.append((k, e))
        k = e + 1
    return out


@dataclass
class _Ctx:
    lidar: LidarPackets
    orient: ImuOrientation
    ext: Extrinsic
    times: np.ndarray
    win: int
    R_w: np.ndarray
    axis: np.ndarray
    e: np.ndarray
    cfg: StationConfig
    rng: np.random.Generator
    n_points: int
    n_query: int
    num_threads: int = 1  # 0: all cores


def _same_place(ctx: _Ctx, pairs: list[tuple[int, int]], pool) -> list[bool | None]:
    """For each pair of windows (i, j): did the pivot stay put between them (lever-arm
    correction applied)? None when the two share too little view to say.

    The windows are decoded side by side on ``pool``, their random subsets drawn from
    ``ctx.rng`` in pair order (i before j, as one pair after the other would), then each pair
    placed and fitted side by side: the votes do not depend on the threads."""
    wins = [k for ij in pairs for k in ij]
    ab = [np.searchsorted(ctx.lidar.lidar_ns, [ctx.times[k], ctx.times[k] + ctx.win])
          for k in wins]
    pts = list(pool.map(lambda x: _window_points(ctx.lidar, int(x[0]), int(x[1])), ab))
    samples = [_window_sample(p, _window_subset(len(p[0]), ctx.n_points, ctx.rng)) for p in pts]

    def vote(m: int) -> bool | None:
        i, j = pairs[m]
        out = [_place_window(ctx.lidar, int(ab[2 * m + n][0]), samples[2 * m + n], ctx.orient,
                             ctx.ext)[0] for n in (0, 1)]
        if len(out[0]) < 50 or len(out[1]) < 50:
            return None
        fit = pivot_shift_fit(out[0], out[1][: ctx.n_query])
        if fit is None:
            return None
        d, P = fit
        if np.linalg.matrix_rank(P) < 2:
            return None
        r = np.linalg.norm(P @ (d - (ctx.R_w[j] - ctx.R_w[i]) @ ctx.e))
        return bool(r < ctx.cfg.still_threshold)

    return list(pool.map(vote, range(len(pairs))))


def _pan_angle(R_w: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The head's turn about the pan axis (K,) [rad], unwrapped, from a reference direction."""
    from .calibration import _perp_basis

    u = _perp_basis(axis)[:, 0]
    v = np.einsum("kij,j->ki", R_w, u)  # a direction across the pan axis, in the world
    return np.unwrap(np.arctan2(v[:, 1], v[:, 0]))


def _merge_runs(runs: list[tuple[int, int]], ctx: _Ctx, max_gap_s: float = 10.0
                ) -> tuple[list[tuple[int, int]], int]:
    """Close the gaps between still runs across which the pivot did not move: the head swung
    by less than ``still_tilt_deg`` from one to the other, and the lidar sees no shift between
    a window at the end of the first and one at the start of the second at the nearest pan
    angle (a station is never cut in two by a noisy moment)."""
    if len(runs) < 2:
        return runs, 0
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max(1, ctx.num_threads or (os.cpu_count() or 1))) as pool:
        return _merge_runs_on(runs, ctx, max_gap_s, pool)


def _merge_runs_on(runs: list[tuple[int, int]], ctx: _Ctx, max_gap_s: float, pool
                   ) -> tuple[list[tuple[int, int]], int]:
    """:func:`_merge_runs` with each gap's two votes side by side on ``pool``."""
    step_ns = int(ctx.times[1] - ctx.times[0]) if len(ctx.times) > 1 else 1
    pan = _pan_angle(ctx.R_w, ctx.axis)
    out = [runs[0]]
    merged = 0
    for k, e in runs[1:]:
        pk, pe = out[-1]
        gap_s = (ctx.times[k] - ctx.times[pe]) * 1e-9
        if gap_s > max_gap_s:
            out.append((k, e))
            continue
        # the IMU: no swing between the end of one run and the start of the next
        sw = _swing_deg(ctx.R_w[pe:pe + 1], ctx.R_w[k:k + 1], ctx.axis)[0]
        # ... and no swing at any moment of the gap against the run before it
        sw_gap = _swing_deg(np.repeat(ctx.R_w[pe:pe + 1], k - pe + 1, axis=0),
                            ctx.R_w[pe:k + 1], ctx.axis).max()
        if sw > ctx.cfg.still_tilt_deg or sw_gap > 2 * ctx.cfg.still_tilt_deg:
            out.append((k, e))
            continue
        # the lidar: windows of the two runs at the nearest pan angles (the most shared view)
        ii = np.arange(max(pk, pe - int(5e9 / step_ns)), pe + 1)
        jj = np.arange(k, min(e, k + int(5e9 / step_ns)) + 1)
        dphi = np.abs(np.angle(np.exp(1j * (pan[ii][:, None] - pan[jj][None, :]))))
        order = np.argsort(dphi, axis=None)[:2]
        votes = _same_place(ctx, [(int(ii[o // len(jj)]), int(jj[o % len(jj)])) for o in order],
                            pool)
        votes = [v for v in votes if v is not None]
        if votes and all(votes):
            out[-1] = (pk, e)
            merged += 1
        else:
            out.append((k, e))
    return out, merged


def _split_by_marks(runs: list[tuple[int, int]], marks: list[tuple[int, str]],
                    times: np.ndarray, win: int) -> list[tuple[int, int]]:
    """A run holding two or more marks is split halfway between them (the operator's marks win
    over a merge)."""
    out = []
    for k, e in runs:
        inside = [t for t, _ in marks if times[k] <= t <= times[e] + win]
        if len(inside) < 2:
            out.append((k, e))
            continue
        cuts = [(a + b) // 2 for a, b in zip(inside[:-1], inside[1:])]
        s = k
        for c in cuts:
            m = int(np.searchsorted(times, c))
            if s < m - 1:
                out.append((s, m - 1))
            s = m + 1
        if s <= e:
            out.append((s, e))
    return out
