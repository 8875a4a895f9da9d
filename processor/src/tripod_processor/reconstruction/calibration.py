# SPDX-License-Identifier: BSD-3-Clause
"""Lidar–IMU calibration from the data: the IMU's time offset, and the mount rotation.

Both use the same principle: the right calibration makes a station's fragment crisp. Crispness
is the RMS distance of sample points to the plane of their nearest neighbours (small for sharp
walls, larger when a wrong offset or mount smears them while the head turns).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..decode.timed import decode_timed_points, decode_xyz_time, denoise_ranges
from .inputs import LidarPackets
from .placement import Extrinsic, ImuOrientation, place_points
from .scaleout import _threaded_map, thread_workers
from .stations import Station

#: the calibration's sweeps and station points have their ranges smoothed along the scan line
#: over this many firings either side (``decode.timed.denoise_ranges``; config
#: ``calibration.range_denoise_firings``)
DENOISE_FIRINGS = 5
#: a sweep of up to this many packets is decoded and smoothed in one decoder call
#: (:func:`_sweep_points`; the decoder's int32 time offsets span 2.1 s, 1,000 packets 1.33 s)
_SWEEP_CHUNK = 1000
#: :func:`~tripod_processor.decode.timed.denoise_ranges`'s default neighbour step [m]
_DENOISE_MAX_STEP_M = 0.1
#: [deg] a mount tilt whose sigma is under this counts as observable from the stations' surfaces
#: (:attr:`SelfCalibration.rotation_observable`)
TILT_OBSERVABLE_SIGMA_DEG = 0.05


def plane_spread(points: np.ndarray, n_query: int = 4000, k: int = 12, seed: int = 0) -> float:
    """RMS point-to-local-plane distance [m] of a cloud (lower is crisper)."""
    rng = np.random.default_rng(seed)
    q = points[rng.choice(len(points), min(n_query, len(points)), replace=False)]
    _, idx = cKDTree(points).query(q, k=k)
    nb = points[idx]  # (Q,k,3)
    c = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("qki,qkj->qij", c, c) / k
    w = np.linalg.eigvalsh(cov)[:, 0]  # smallest eigenvalue: variance off the plane
    return float(np.sqrt(np.mean(np.clip(w, 0, None))))


def _station_sample(lidar: LidarPackets, st: Station, max_points: int):
    pts = decode_timed_points(lidar.payload, lidar.lidar_ns, st.packet_start, st.packet_stop,
                              min_range=0.5, max_range=30.0)
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(1).choice(len(pts), max_points, replace=False)]
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    return xyz, pts["time_ns"]


def most_turning_station(stations: list[Station], orient: ImuOrientation) -> Station:
    """The station over which the head turns the most (strongest signal for calibration)."""
    best, best_turn = stations[0], -1.0
    for st in stations:
        t = np.linspace(st.start_ns, st.end_ns, 20).astype(np.int64)
        turn = float(np.sum(orient.angular_rate(t[1:-1]))) * (st.end_ns - st.start_ns) * 1e-9 / 18
        if turn > best_turn:
            best, best_turn = st, turn
    return best


def estimate_time_offset(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                         ext: Extrinsic, search_s: float, max_points: int = 80_000,
                         min_gain: float = 0.01) -> tuple[int, dict]:
    """IMU time offset [ns] (added to its lidar-clock stamps) that makes a fragment crispest.

    Golden-section search over ±search_s down to 1 ms (the blur grows with the offset's error, so
    the cost is unimodal around the truth), on points farther than 2 m (a wrong offset smears
    them the most). When the best offset sharpens the fragment by less than ``min_gain``
    (relative), the data carry no evidence and the offset stays 0.
    Returns (offset_ns, diagnostics).
    """
    st = most_turning_station(stations, orient)
    xyz, t_ns = _station_sample(lidar, st, 3 * max_points)
    far = np.linalg.norm(xyz, axis=1) > 2.0
    if far.sum() > 1000:
        xyz, t_ns = xyz[far], t_ns[far]
    # At a constant turn rate a time offset only turns the whole fragment (no blur); it shows
    # where the rate changes. Keep the points fired while the head accelerates (and an equal
    # share of the others, for the geometry to compare against).
    grid_t = np.linspace(st.start_ns, st.end_ns, 200).astype(np.int64)
    rate = orient.angular_rate(grid_t)
    acc = np.abs(np.gradient(rate, (grid_t - grid_t[0]) * 1e-9))
    if acc.max() > 0.2:  # [rad/s²]: there are ramps to use
        a_pts = np.interp(t_ns, grid_t, acc)
        hot = a_pts > 0.5 * acc.max()
        if hot.sum() > 2000:
            rng = np.random.default_rng(3)
            cold = np.flatnonzero(~hot)
            cold = rng.choice(cold, min(len(cold), int(hot.sum())), replace=False)
            sel = np.concatenate([np.flatnonzero(hot), cold])
            xyz, t_ns = xyz[sel], t_ns[sel]
    if len(xyz) > max_points:
        keep = np.random.default_rng(2).choice(len(xyz), max_points, replace=False)
        xyz, t_ns = xyz[keep], t_ns[keep]

    def cost(off_s: float) -> float:
        o = orient.with_offset(int(round(off_s * 1e9)))
        return plane_spread(place_points(xyz, t_ns, o, ext, st.mid_ns), n_query=6000)

    a, b = -search_s, search_s
    g = (np.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    evals = [(c, fc), (d, fd)]
    while b - a > 0.001:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
            evals.append((c, fc))
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
            evals.append((d, fd))
    best = 0.5 * (a + b)
    f_best, f_zero = min(fc, fd), cost(0.0)
    if f_best > f_zero * (1.0 - min_gain):
        best = 0.0
    evals.sort()
    return int(round(best * 1e9)), {
        "station": st.index, "offsets_s": [e[0] for e in evals],
        "spread_m": [e[1] for e in evals], "best_s": best, "best_spread_m": f_best,
        "zero_spread_m": f_zero}


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _turn_angles_deg(R0: np.ndarray, R: np.ndarray, near: tuple[float, ...]) -> np.ndarray:
    """Angles [deg] of the turns R0ᵀ·R_n (``R0`` (3, 3) or (N, 3, 3), ``R`` (N, 3, 3)), only
    ever compared with the thresholds ``near``: from the trace (arccos, ~1e-12° off), and
    within 1e-6° of a threshold as ``Rotation.from_matrix(R0ᵀ·R_n).magnitude()`` has them, so
    every comparison with a threshold comes out as with scipy's angles (the pair choices the
    same to the bit) at a tenth of the cost."""
    from scipy.spatial.transform import Rotation

    one = R0.ndim == 2
    c = np.einsum("ij,nij->n" if one else "nij,nij->n", R0, R)  # trace(R0ᵀ R_n)
    ang = np.degrees(np.arccos(np.clip((c - 1.0) / 2.0, -1.0, 1.0)))
    close = np.zeros(len(ang), dtype=bool)
    for x in near:
        close |= np.abs(ang - float(x)) < 1e-6
    if close.any():
        ang[close] = np.degrees(Rotation.from_matrix(
            np.einsum("ji,njk->nik", R0, R[close]) if one
            else np.einsum("nji,njk->nik", R0[close], R[close])).magnitude())
    return ang


def _prepare_sweep(points: np.ndarray, num_threads: int):
    """A sweep prepared as :func:`_register_sweeps` prepares an array (10-cm voxels, GICP's
    neighbourhoods and covariances), or None where it cannot be (too few points): a sweep that
    joins several pairs (hand-eye's, the turns' offset with ``turn_sweep_uses`` 2) is prepared
    once, the registrations the same to the bit."""
    from ..registration import pairwise as reg

    try:
        return reg.prepare(points, 0.1, 20, point_sigma=0.02, num_threads=num_threads)
    except ValueError:
        return None


def _register_sweeps(src, tgt, init: np.ndarray, num_threads: int):
    """GICP of one short lidar sweep onto another (10-cm voxels, 1 m → 15 cm correspondences);
    None when the registration cannot run (too few points after downsampling). ``src``,
    ``tgt``: (N, 3) arrays, or :func:`_prepare_sweep`'s (None: could not be prepared)."""
    from ..registration import pairwise as reg

    if src is None or tgt is None:
        return None
    try:
        return reg.register(src, tgt, method="gicp", init=init, voxel_size=0.1,
                            max_correspondence_distance=[1.0, 0.3, 0.15],
                            num_threads=num_threads)
    except ValueError:
        return None


class SweepCache:
    """The calibration's decoded sweeps (the packets of a window, their ranges smoothed along
    the scan line: lidar frame, before any de-skew) kept for the later registrations of a run.

    Hand-eye, the turns' lever arm and every pass of the turns' time offset (the first, its
    second at the new offset, the re-measure after the surfaces' fit) de-skew the same windows
    of the same stations again with another offset, mount or lever arm; what they decode is the
    same each time. Keyed by the window's packet range, the range cut and the smoothing; kept
    while the total stays within ``max_mb`` (0: nothing kept, every call decodes). Thread-safe
    (stations' sweeps are made side by side); the arrays kept are read-only."""

    def __init__(self, max_mb: float = 256.0):
        self.max_bytes = int(max(0.0, float(max_mb)) * 2**20)
        self.nbytes = 0
        self.hits = 0
        self.misses = 0
        self._d: dict = {}
        self._lock = threading.Lock()

    def get(self, key, make):
        """The value kept for ``key``, else ``make()`` (kept while the cap allows)."""
        with self._lock:
            v = self._d.get(key)
            if v is not None:
                self.hits += 1
                return v
            self.misses += 1
        v = make()
        nb = sum(a.nbytes for a in v)
        if nb and self.max_bytes > 0:
            for a in v:
                a.setflags(write=False)
            with self._lock:
                if key not in self._d and self.nbytes + nb <= self.max_bytes:
                    self._d[key] = v
                    self.nbytes += nb
        return v

    def clear(self) -> None:
        with self._lock:
            self._d.clear()
            self.nbytes = 0


def _sweep_points(lidar: LidarPackets, a: int, b: int, min_range: float, denoise_firings: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The points of packets [a, b) (returns ``min_range``–40 m), ranges smoothed along the
    scan line: (xyz (N, 3) float32 [m] lidar frame, firing times (N,) int64 [ns]).

    A window of at most :data:`_SWEEP_CHUNK` packets (a sweep: 0.1 s is 75) is one decoder call
    smoothed as the fragments smooth theirs (:func:`~tripod_processor.decode.timed.
    decode_xyz_time`, without the per-point records: half the cost), the same points and xyz to
    the bit as :func:`~tripod_processor.decode.timed.denoise_ranges` of the records (the same
    fit, scan lines and neighbours; ``tests/processor/test_calibration_sweep_cache.py``)."""
    if 0 <= b - a <= _SWEEP_CHUNK:
        xyz, t, _ = decode_xyz_time(lidar.payload, lidar.lidar_ns, a, b, min_range=min_range,
                                    max_range=40.0, chunk=_SWEEP_CHUNK,
                                    denoise_firings=denoise_firings,
                                    denoise_max_step_m=_DENOISE_MAX_STEP_M)
        return xyz, t
    pts = decode_timed_points(lidar.payload, lidar.lidar_ns, a, b,
                              min_range=min_range, max_range=40.0)
    if not len(pts):
        return np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    return (denoise_ranges(pts, denoise_firings).astype(np.float32),
            np.asarray(pts["time_ns"], dtype=np.int64))


def _sweep(lidar: LidarPackets, orient: ImuOrientation, ext: Extrinsic, start_ns: int,
           win_ns: int, num_threads: int, min_range: float = 0.5,
           denoise_firings: int = DENOISE_FIRINGS, with_times: bool = False,
           cache: SweepCache | None = None):
    """The packets of [start_ns, start_ns + win_ns) (lidar time) de-skewed by the IMU to the
    window's middle with ``ext``: (N, 3) float64 [m]; returns nearer than ``min_range`` [m]
    left out; ranges smoothed along the scan line over ``denoise_firings`` firings either side
    (:func:`~tripod_processor.decode.timed.denoise_ranges`; 0: as measured). ``with_times``:
    (points, their firing times (N,) int64 [ns]). ``cache``: the decoded window taken from it
    (or kept in it) instead of decoded again; the same result to the bit."""
    a, b = (int(x) for x in np.searchsorted(lidar.lidar_ns, [start_ns, start_ns + win_ns]))
    if cache is None:
        xyz, t = _sweep_points(lidar, a, b, min_range, denoise_firings)
    else:
        xyz, t = cache.get((id(lidar.payload), a, b, float(min_range), int(denoise_firings)),
                           lambda: _sweep_points(lidar, a, b, min_range, denoise_firings))
    if not len(xyz):
        return (np.zeros((0, 3)), np.zeros(0, np.int64)) if with_times else np.zeros((0, 3))
    out = place_points(xyz, t, orient, ext, int(start_ns) + win_ns // 2,
                       num_threads).astype(np.float64)
    return (out, t.copy()) if with_times else out


def _turn_pairs(lidar: LidarPackets, st: Station, orient: ImuOrientation, R_guess: np.ndarray,
                num_threads: int, step_s: float, window_s: float, max_pairs: int,
                pair_turn_deg: float, denoise_firings: int = DENOISE_FIRINGS,
                turn_ladder: int = 0, sweep_cache: SweepCache | None = None
                ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One station's sweep pairs for hand-eye: (A_list, B_list), A the lidar's motion between
    two short windows (registration, lidar frame, 4x4), B the IMU's relative rotation (IMU
    frame, 3x3); sweeps de-skewed by the IMU with the mount ``R_guess`` and no lever arm.

    Pairs turned by ``pair_turn_deg`` (a rotation's axis is the better measured the bigger
    the turn; a near-vertical spin axis sees little of floor and ceiling, and only the axis
    tells its tilt), spread over the station, the IMU's turn as the registration's start;
    where big turns share too little view (a mount on its side), smaller ones, then
    consecutive windows.

    ``turn_ladder`` k > 0: between ``pair_turn_deg`` and consecutive windows, k more levels
    halving the turn each (45°: 22.5, 11.25, ...), and the pairs that registered at a level
    given up are kept. A lidar 24° off the pan axis in a 34 x 24 m hall (dev seed 5621)
    registers its 45° pairs to 0.1° but shares only 38-49 % of the view between them (the
    tilted scan band moves up and down the walls as the head turns), under the 0.5 fitness
    gate, and half its 22.5° pairs: its pairs were consecutive windows of ~2°, whose axis
    the registration's noise sets (the mount tilt 5-11° off per station). 0: the old ladder
    (``pair_turn_deg``, its half, consecutive windows; a level's pairs dropped when it fails).
    ``sweep_cache``: the windows' decoded points shared with the run's other registrations."""
    from scipy.spatial.transform import Rotation

    t0 = st.start_ns
    win = int(window_s * 1e9)
    times = np.arange(t0, st.end_ns - win, int(step_s * 1e9), dtype=np.int64)
    ext_g = Extrinsic(R_guess, np.zeros(3), "guess")
    R_w = orient.rotation_at(times + win // 2)
    clouds: dict[int, np.ndarray] = {}
    prepared: dict[int, object] = {}

    def cloud(k: int) -> np.ndarray:
        # a sweep de-skewed to its middle by the IMU (with the guess of the mount)
        if k not in clouds:
            clouds[k] = _sweep(lidar, orient, ext_g, int(times[k]), win, num_threads,
                               denoise_firings=denoise_firings, cache=sweep_cache)
        return clouds[k]

    def ready(k: int):
        # ... prepared for registration once (a sweep joins up to two pairs a level)
        if k not in prepared:
            prepared[k] = _prepare_sweep(cloud(k), num_threads)
        return prepared[k]

    def pairs_turned(min_deg: float) -> list[tuple[int, int]]:
        out = []
        for k in range(len(times) - 1):
            ang = _turn_angles_deg(R_w[k], R_w[k + 1:], (min_deg,))
            j = np.flatnonzero(ang >= min_deg)
            if len(j):
                out.append((k, k + 1 + int(j[0])))
        if len(out) > max_pairs:
            out = [out[i] for i in np.linspace(0, len(out) - 1, max_pairs).astype(int)]
        return out

    def measure(pairs):
        A_list, B_list = [], []
        for k, j in pairs:
            ck, cj = cloud(k), cloud(j)
            if len(ck) < 500 or len(cj) < 500:
                continue
            B = R_w[k].T @ R_w[j]
            init = np.eye(4)
            init[:3, :3] = R_guess.T @ B @ R_guess
            r = _register_sweeps(ready(j), ready(k), init, num_threads)
            if r is None:
                continue
            # a turn's angle is the same in any frame: a registration that disagrees with
            # the IMU's by more than 1° slipped (a corridor, little shared view)
            ang_a = Rotation.from_matrix(r.T_target_source[:3, :3]).magnitude()
            ang_b = Rotation.from_matrix(B).magnitude()
            if r.fitness < 0.5 or abs(np.degrees(ang_a - ang_b)) > 1.0:
                continue
            A_list.append(r.T_target_source)
            B_list.append(B)
        return A_list, B_list

    A_list, B_list = [], []
    kept_A: list[np.ndarray] = []  # pairs registered at levels given up (turn_ladder)
    kept_B: list[np.ndarray] = []
    levels = ([pair_turn_deg / 2**k for k in range(turn_ladder + 2)] if turn_ladder > 0
              else [pair_turn_deg, pair_turn_deg / 2]) + [0.0]
    for min_deg in levels:
        pairs = pairs_turned(min_deg)
        probe = pairs[:: max(1, len(pairs) // 4)][:4]  # a few first: do such turns register?
        A_list, B_list = measure(probe)
        if len(A_list) >= 3 or min_deg == 0.0:
            more = measure([p for p in pairs if p not in probe])
            A_list, B_list = A_list + more[0], B_list + more[1]
            break
        if turn_ladder > 0:
            kept_A += A_list
            kept_B += B_list
    return kept_A + A_list, kept_B + B_list


def calibrate_mount(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                    num_threads: int = 0, step_s: float = 0.3, window_s: float = 0.1,
                    max_pairs: int = 16, pair_turn_deg: float = 45.0,
                    guess: Extrinsic | None = None, denoise_firings: int = DENOISE_FIRINGS,
                    turn_ladder: int = 0, sweep_cache: SweepCache | None = None
                    ) -> tuple[Extrinsic, dict]:
    """The lidar's mount on the IMU (R_imu_lidar, lever arm) from the data (hand-eye).

    While the head turns at a station, the lidar's motion between two short windows, measured by
    registering them (A, lidar frame), and the IMU's (B, IMU frame) are one rigid motion seen in
    two frames: the rotation axes satisfy a = R_lidar_imu·b, and the lidar's translation
    t_A = R_lidar_imu·(B − I)·ℓ for the lever arm ℓ (pivot → lidar, IMU frame). Rotation: Kabsch
    on the axis pairs, or the shortest rotation taking b onto a when every turn is about one axis
    (a pan). What a single axis leaves open — a turn about the pan axis, a shift along it — does
    not change the fragments (see the reconstruction README), so it is set to zero.
    Pairs: :func:`_turn_pairs` on the station the head turns most in.
    Returns (Extrinsic with source "calibrated", diagnostics).
    """
    from scipy.spatial.transform import Rotation

    st = most_turning_station(stations, orient)
    R_guess = np.eye(3) if guess is None else guess.R_imu_lidar
    A_list, B_list = _turn_pairs(lidar, st, orient, R_guess, num_threads, step_s, window_s,
                                 max_pairs, pair_turn_deg, denoise_firings, turn_ladder,
                                 sweep_cache)
    if len(A_list) < 3:
        raise ValueError("too few usable turns to calibrate the lidar mount from the data")
    a = np.array([_rotvec(A[:3, :3]) for A in A_list])
    b = np.array([_rotvec(B) for B in B_list])
    # weights: bigger turns are better measured
    w = np.linalg.norm(b, axis=1)
    H = (b * w[:, None]).T @ a  # Σ w b aᵀ
    U, S, Vt = np.linalg.svd(H)
    if S[1] > 0.2 * S[0]:  # turns about at least two axes: the full rotation
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R_li = Vt.T @ D @ U.T
    else:  # one axis: the shortest rotation taking the mean b onto the mean a
        # the axis has no sign: a pair turned back (a hand pan's reversal) has a and b both
        # reversed, and summed as they are it cancels the forward pairs (dev seed 383: one
        # 13° pair in a reversal against fifteen of 3° left the sum 2 % of its terms' and the
        # tilt 6.4° off). Each pair is signed along the principal axis (H's first left
        # singular vector) first: its sign does not matter, a pair across it is flipped
        sgn = np.where(b @ U[:, 0] < 0, -1.0, 1.0)
        if np.all(sgn == sgn[0]):
            sgn[:] = 1.0  # no pair reversed: the sums as they were (bit-identical)
        bb = (b * (w * sgn)[:, None]).sum(0)
        aa = (a * (w * sgn)[:, None]).sum(0)
        bb /= np.linalg.norm(bb)
        aa /= np.linalg.norm(aa)
        ax = np.cross(bb, aa)
        s, c = np.linalg.norm(ax), float(bb @ aa)
        R_li = np.eye(3) if s < 1e-12 else Rotation.from_rotvec(
            ax / s * np.arctan2(s, c)).as_matrix()
    R_il = R_li.T
    # lever arm: (B − I) ℓ = R_il t_A, least squares (minimum norm along the unseen axis)
    M = np.concatenate([B - np.eye(3) for B in B_list])
    y = np.concatenate([R_il @ A[:3, 3] for A in A_list])
    ell, *_ = np.linalg.lstsq(M, y, rcond=0.05)
    resid = [np.degrees(Rotation.from_matrix(A[:3, :3].T @ (R_li @ B @ R_il)).magnitude())
             for A, B in zip(A_list, B_list)]
    return Extrinsic(R_il, ell, "calibrated"), {
        "station": st.index, "pairs": len(A_list), "axis_singular_values": S.tolist(),
        "rotation_residual_deg_median": float(np.median(resid)),
        "turn_deg_median": float(np.degrees(np.median(np.linalg.norm(b, axis=1)))),
        "tilt_sigma_deg": _axis_tilt_sigma_deg(a, b, R_li)}


@dataclass
class TurnLeverArm:
    """The lever arm across the pan axis from the head's turns at several stations
    (:func:`lever_arm_from_turns`).

    lever_arm_m : (3,) [m] pivot → lidar, IMU frame (its component along the pan axis is the
    given extrinsic's); cov_m2 : (2, 2) [m²] covariance of the two components across the pan
    axis in ``basis_imu`` ((3, 2)); pairs : sweep pairs used; stations : their count."""

    lever_arm_m: np.ndarray
    cov_m2: np.ndarray
    basis_imu: np.ndarray
    pairs: int
    stations: int

    def sigma_along_m(self, u: np.ndarray) -> float:
        """1-sigma [m] along the unit direction ``u`` (IMU frame, across the pan axis)."""
        c = self.basis_imu.T @ u
        return float(np.sqrt(max(c @ self.cov_m2 @ c, 0.0)))


def lever_arm_from_turns(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                         ext: Extrinsic, num_threads: int = 0, *, max_stations: int = 8,
                         step_s: float = 0.3, window_s: float = 0.1, max_pairs: int = 16,
                         pair_turn_deg: float = 45.0, denoise_firings: int = DENOISE_FIRINGS,
                         sweep_cache: SweepCache | None = None) -> TurnLeverArm | None:
    """Hand-eye's lever arm (:func:`calibrate_mount`: (B − I)·ℓ = R_il·t_A per sweep pair) with
    the mount ``ext.R_imu_lidar`` held and the pairs of up to ``max_stations`` stations (those
    the head turns most in) pooled; only the two components across the pan axis are solved.

    One station's 16 pairs left it 25–130 mm off across the pan axis on a lidar on its side
    (dev seeds 87, 205: 0.1-s sweeps of a scan fan standing on edge register loosely along the
    spin axis), and the stations' surfaces cannot correct the component along the spin axis
    (it moves scan planes along themselves): there the start is the result. Pairs are
    Huber-weighted (1.345 MAD sigma); the covariance is the residuals' scatter, at least the
    stations' cluster-robust (sandwich) one (a station's pairs share its surfaces and its
    scan pattern). None when fewer than 6 pairs register."""
    use = _pick_stations(stations, orient, max_stations)
    b = pan_axis_in_imu(orient, use)
    U = _perp_basis(b)
    R_il = ext.R_imu_lidar
    ell_along = b * float(b @ ext.lever_arm_m)
    Ms, ys, gid = [], [], []
    # the stations side by side on threads (each registration on num_threads when one runs at
    # a time: the same pairs to the bit on any count), gathered in station order
    workers = thread_workers(num_threads, len(use))
    inner = num_threads if workers == 1 else 1
    per_station = _threaded_map(
        lambda st: _turn_pairs(lidar, st, orient, R_il, inner, step_s, window_s, max_pairs,
                               pair_turn_deg, denoise_firings, sweep_cache=sweep_cache),
        [(st,) for st in use], workers)
    for q, (A_list, B_list) in enumerate(per_station):
        for A, B in zip(A_list, B_list):
            Mk = (B - np.eye(3))
            Ms.append(Mk @ U)
            ys.append(R_il @ A[:3, 3] - Mk @ ell_along)
            gid.append(q)
    if len(Ms) < 6:
        return None
    X = np.concatenate(Ms)  # (3n, 2)
    y = np.concatenate(ys)  # (3n,)
    fit = _huber_lsq_clustered(X, y, np.repeat(np.asarray(gid), 3), iters=5, scale_floor=1e-4)
    if fit is None:
        return None
    c, cov, n_groups = fit
    return TurnLeverArm(ell_along + U @ c, cov, U, len(Ms), n_groups)


def _huber_lsq_clustered(X: np.ndarray, y: np.ndarray, groups: np.ndarray, *, iters: int,
                         scale_floor: float):
    """The linear least squares X·c ≈ y, Huber-weighted by IRLS (``iters`` rounds, 1.345 MAD
    sigma, the scale at least ``scale_floor``): (c, cov, number of groups), cov the weighted
    residuals' scatter, at least the cluster-robust (sandwich) one over ``groups`` (rows of one
    group share its errors) when there are three or more; None when the normal matrix is
    singular."""
    wgt = np.ones(len(y))
    for _ in range(iters):
        XW = X * wgt[:, None]
        H = XW.T @ X
        if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e10:
            return None
        c = np.linalg.solve(H, XW.T @ y)
        e = y - X @ c
        sc = 1.4826 * float(np.median(np.abs(e))) + scale_floor
        wgt = np.minimum(1.0, 1.345 * sc / np.maximum(np.abs(e), 1e-12))
    XW = X * wgt[:, None]
    Hi = np.linalg.inv(XW.T @ X)
    cov = Hi * float(np.sum(wgt * e**2) / max(len(y) - X.shape[1], 1))
    uniq = np.unique(groups)
    if len(uniq) >= 3:
        S = np.array([XW[groups == q].T @ e[groups == q] for q in uniq])
        V = Hi @ (S.T @ S) @ Hi * len(uniq) / (len(uniq) - 1)
        if np.trace(V) > np.trace(cov):
            cov = V
    return c, cov, len(uniq)


def _axis_tilt_sigma_deg(a: np.ndarray, b: np.ndarray, R_li: np.ndarray) -> float:
    """1-sigma [deg] of hand-eye's mount tilt: the RMS angle between each pair's turn axis as the
    lidar's registration saw it (rows of ``a``, rotation vectors, lidar frame) and the IMU's
    (``b``, IMU frame) mapped by the fit ``R_li``.

    Not divided by the square root of the pairs: they are one station's sweeps registered
    against each other, so they share its surfaces and its scan pattern, and their errors do not
    average out (on a spin axis near the pan axis in a 4 x 4 m room, dev seed 126, the pairs'
    mean axis is 0.51 deg off with 16 pairs whose RMS is of that size)."""
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ok = (na > 1e-9) & (nb > 1e-9)
    if not ok.any():
        return float("inf")
    ua = a[ok] / na[ok, None]
    ub = (b[ok] @ R_li.T) / nb[ok, None]
    ang = np.arccos(np.clip(np.sum(ua * ub, axis=1), -1.0, 1.0))
    return float(np.degrees(np.sqrt(np.mean(ang**2))))


# ---- self-calibration: lever arm, time offset and mount rotation from the stations' geometry ----
def pan_axis_in_imu(orient: ImuOrientation, stations: list[Station], step_s: float = 0.2
                    ) -> np.ndarray:
    """The head's pan axis b (3,) in the IMU frame: the rate-weighted mean axis of the IMU's
    short relative rotations R(t)ᵀR(t+step) over the stations (sign: the dominant turn)."""
    from scipy.spatial.transform import Rotation

    vecs = []
    for st in stations:
        t = np.arange(st.start_ns, st.end_ns - int(step_s * 1e9), int(step_s * 1e9),
                      dtype=np.int64)
        if len(t) < 2:
            continue
        Ra = orient.rotation_at(t)
        Rb = orient.rotation_at(t + int(step_s * 1e9))
        vecs.append(Rotation.from_matrix(np.einsum("nji,njk->nik", Ra, Rb)).as_rotvec())
    if not vecs:
        return np.array([0.0, 0.0, 1.0])
    v = np.concatenate(vecs)
    # sign-free mean axis: the principal direction of Σ v vᵀ (bigger turns weigh more)
    w, V = np.linalg.eigh(v.T @ v)
    b = V[:, -1]
    if float(np.sum(v @ b)) < 0:
        b = -b
    return b / np.linalg.norm(b)


def _perp_basis(b: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to unit vector b."""
    a = np.array([1.0, 0.0, 0.0]) if abs(b[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(b, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(b, u)], axis=1)



def across_axis(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The component of ``v`` across the unit vector ``axis`` (the pan axis: the lever arm's
    part that the pan moves)."""
    return v - axis * (axis @ v)


def spin_axis_from_pan_axis_deg(pan_axis: np.ndarray, R_imu_lidar: np.ndarray) -> float:
    """Angle [deg, 0-90] of the lidar's spin axis from the pan axis (IMU frame): 0 upright,
    90 on its side."""
    return float(np.degrees(np.arccos(min(1.0, abs(float(pan_axis @ R_imu_lidar[:, 2]))))))

@dataclass
class SelfCalibration:
    """Rig calibration estimated from the stations' own geometry (``self_calibrate``).

    Attributes
    ----------
    R_imu_lidar : (3, 3) refined mount rotation
    lever_arm_m : (3,) [m] pivot → lidar in the IMU frame; its component along ``pan_axis_imu``
        is the prior's (unobservable: it moves every fragment rigidly along the pan axis)
    lever_arm_sigma_m : (2,) [m] 1-sigma of the two components across the pan axis
    pan_axis_imu : (3,) unit pan axis in the IMU frame
    time_offset_ns : int, added to the IMU's lidar-clock stamps
    time_offset_sigma_ms : float [ms] 1-sigma
    rotation_sigma_deg : float [deg] 1-sigma of the two observable mount tilts (largest)
    time_offset_observable, lever_arm_observable, rotation_observable : bool
    stations : list of station indices used; residual_m : robust residual RMS [m]
    """

    R_imu_lidar: np.ndarray
    lever_arm_m: np.ndarray
    lever_arm_sigma_m: np.ndarray
    pan_axis_imu: np.ndarray
    time_offset_ns: int
    time_offset_sigma_ms: float
    rotation_sigma_deg: float
    rotation_change_deg: float
    time_offset_observable: bool
    lever_arm_observable: bool
    rotation_observable: bool
    stations: list[int]
    residual_m: float
    pairs: int
    iterations: list[dict] = field(default_factory=list)
    #: where the time offset came from: "surfaces" (this fit) or "turns"
    #: (:func:`time_offset_from_turns`, whose diagnostics ``turns`` holds)
    time_offset_method: str = "surfaces"
    turns: dict | None = None
    #: (2, 2) [m²] covariance of the lever arm's two components across the pan axis, in the
    #: basis ``lever_basis_imu`` ((3, 2), IMU frame); None when not fitted
    lever_arm_cov_m2: np.ndarray | None = None
    lever_basis_imu: np.ndarray | None = None
    #: the IMU's heading drift about the world's vertical [deg/min] fitted with the rest
    #: (``fit_yaw_drift``); NaN when not fitted
    yaw_drift_deg_per_min: float = float("nan")
    #: the mount's turn about the pan axis from the carries (:func:`mount_yaw_from_carries`,
    #: its ``to_dict``) when it was estimated; None: held at hand-eye's (unobservable from the
    #: stations)
    mount_yaw: dict | None = None
    #: [deg] the spread of the stations' own tilt fits (sigma of their mean) that the
    #: pipeline's ``calibration.tilt_spread_max_deg`` measured; NaN when not measured
    tilt_spread_sigma_deg: float = float("nan")

    def lever_arm_by_mount(self) -> dict | None:
        """The lever arm's sigma along the lidar's spin axis (projected across the pan axis)
        and in its scan plane, with the spin axis's angle from the pan axis [deg]. A lidar on
        its side sees the spin-axis component only at vertical edges (the scan planes of
        opposite pan angles coincide, shifted along their normal), the in-plane one at every
        wall (it doubles walls seen from opposite sides of the pan)."""
        if self.lever_arm_cov_m2 is None or self.lever_basis_imu is None:
            return None
        b = self.pan_axis_imu
        z = self.R_imu_lidar[:, 2]
        tilt = spin_axis_from_pan_axis_deg(b, self.R_imu_lidar)
        w = across_axis(z, b)
        if np.linalg.norm(w) < 1e-6:
            return {"spin_axis_from_pan_axis_deg": tilt}
        w /= np.linalg.norm(w)
        s = np.cross(b, w)
        C = self.lever_basis_imu @ self.lever_arm_cov_m2 @ self.lever_basis_imu.T
        return {"spin_axis_from_pan_axis_deg": tilt,
                "sigma_along_spin_axis_m": float(np.sqrt(max(w @ C @ w, 0.0))),
                "sigma_in_scan_plane_m": float(np.sqrt(max(s @ C @ s, 0.0)))}

    @property
    def lever_arm_across_m(self) -> float:
        """Length of the lever arm across the pan axis [m]."""
        b = self.pan_axis_imu
        return float(np.linalg.norm(across_axis(self.lever_arm_m, b)))

    def to_dict(self) -> dict:
        from scipy.spatial.transform import Rotation

        by_mount = self.lever_arm_by_mount()

        x, y, z, w = Rotation.from_matrix(self.R_imu_lidar).as_quat()
        return {
            "q_imu_lidar": [float(w), float(x), float(y), float(z)],
            "lever_arm_m": self.lever_arm_m.tolist(),
            "lever_arm_across_axis_m": self.lever_arm_across_m,
            "lever_arm_sigma_m": self.lever_arm_sigma_m.tolist(),
            "lever_arm_along_axis": "unobservable (shifts every fragment rigidly along the pan "
                                    "axis; kept at the prior)",
            "pan_axis_imu": self.pan_axis_imu.tolist(),
            "imu_time_offset_ms": self.time_offset_ns * 1e-6,
            "imu_time_offset_sigma_ms": self.time_offset_sigma_ms,
            "imu_time_offset_method": self.time_offset_method,
            **({"imu_time_offset_turns": self.turns} if self.turns else {}),
            "mount_rotation_sigma_deg": self.rotation_sigma_deg,
            "mount_rotation_change_deg": self.rotation_change_deg,
            "observable": {"lever_arm": self.lever_arm_observable,
                           "time_offset": self.time_offset_observable,
                           "mount_rotation": self.rotation_observable},
            **({"lever_arm_by_mount": by_mount} if by_mount else {}),
            "stations": self.stations, "residual_m": self.residual_m, "pairs": self.pairs,
            **({"imu_yaw_drift_deg_per_min": self.yaw_drift_deg_per_min}
               if np.isfinite(self.yaw_drift_deg_per_min) else {}),
            **({"mount_yaw_from_carries": self.mount_yaw} if self.mount_yaw else {}),
            **({"mount_tilt_spread_sigma_deg": self.tilt_spread_sigma_deg}
               if np.isfinite(self.tilt_spread_sigma_deg) else {}),
        }


def _pick_stations(stations: list[Station], orient: ImuOrientation, n: int) -> list[Station]:
    """Up to n stations with the most turning (spread over the recording when tied)."""
    def turn(st):
        t = np.linspace(st.start_ns, st.end_ns, 24).astype(np.int64)
        return float(np.sum(orient.angular_rate(t[1:-1]))) * (st.end_ns - st.start_ns) / 22e9

    ranked = sorted(stations, key=turn, reverse=True)
    return sorted(ranked[:n], key=lambda s: s.start_ns)


#: range [m] below which ``_station_points``' range weighting leaves a point's weight at 1
RANGE_WEIGHT_REF_M = 3.0


def _station_points(lidar: LidarPackets, st: Station, n: int, seed: int, max_range: float,
                    orient: ImuOrientation | None = None,
                    denoise_firings: int = DENOISE_FIRINGS, cache: SweepCache | None = None,
                    range_weight_exp: float = 0.0):
    """About n points of a station (every few packets decoded, their ranges smoothed along the
    scan line over ``denoise_firings`` firings either side, then a random subset). With
    ``orient``, points fired while the head turns slowly (rests, ramps, a hand's pauses) are
    taken 4x as densely: the time offset shows only between those and the fast ones.
    ``range_weight_exp`` > 0: a point at range r is drawn max(1, r / RANGE_WEIGHT_REF_M) ** exp
    times as often (the far surfaces, thinly sampled, reach the voxels' 10-point minimum).

    ``cache`` (:class:`SweepCache`): the result kept for a later call with the same station,
    sample size, seed, range cut, smoothing and slow-turn rates (what the sample depends on: the
    surfaces' fit runs again on the same stations after the mount tilt is weighed), the same
    arrays to the bit; the slow-turn rates are the 200 the weights come from, so a call at
    another time offset draws its own sample."""
    n_pk = st.packet_stop - st.packet_start
    stride = max(1, int(n_pk * 300 / (10 * n)))  # ~300 points a packet after the range cut
    rate = None
    if orient is not None:
        grid = np.linspace(st.start_ns, st.end_ns, 200).astype(np.int64)
        rate = np.linalg.norm(_world_rate(orient, grid), axis=1)

    def make():
        idx = np.arange(st.packet_start, st.packet_stop, stride)
        pts = decode_timed_points(lidar.payload[idx], lidar.lidar_ns[idx], 0, len(idx),
                                  min_range=1.0, max_range=max_range)
        if len(pts) <= n:
            return denoise_ranges(pts, denoise_firings), pts["time_ns"].astype(np.int64)
        rng = np.random.default_rng(seed)
        w = np.ones(len(pts))
        if rate is not None:
            slow = np.interp(pts["time_ns"], grid, rate) < 0.7 * np.percentile(rate, 95)
            w[slow] = 4.0
        if range_weight_exp > 0:
            r_m = np.sqrt(pts["x"].astype(np.float64) ** 2 + pts["y"].astype(np.float64) ** 2
                          + pts["z"].astype(np.float64) ** 2)
            w *= np.maximum(r_m / RANGE_WEIGHT_REF_M, 1.0) ** range_weight_exp
        keep = np.sort(rng.choice(len(pts), n, replace=False, p=w / w.sum()))
        # the kept points' ranges smoothed over all the decoded ones (the same to the bit as
        # smoothing all, then keeping: a tenth of the cost)
        xyz = denoise_ranges(pts, denoise_firings, at=keep)
        return xyz, pts["time_ns"][keep].astype(np.int64)

    if cache is None:
        return make()
    key = ("station", id(lidar.payload), int(st.packet_start), int(st.packet_stop),
           int(st.start_ns), int(st.end_ns), int(n), int(seed), float(max_range),
           int(denoise_firings), None if rate is None else rate.tobytes(), float(range_weight_exp))
    return cache.get(key, make)


def _world_rate(orient: ImuOrientation, t_ns: np.ndarray, h_ns: int = 100_000_000
                ) -> np.ndarray:
    """World-frame angular velocity (N, 3) [rad/s] of the IMU at t_ns (central difference of
    the quaternions over h_ns: q_b ⊗ q_a* ≈ (1, ω h / 2)). A long baseline: the IMU's
    per-sample noise (0.05° at 100 Hz) would make a 10 ms difference noisier than the rate
    (and a noisy Jacobian biases the time offset toward zero)."""
    qa = orient.quat_at(t_ns - h_ns // 2)
    qb = orient.quat_at(t_ns + h_ns // 2)
    wa, va = qa[:, 0], -qa[:, 1:]  # conjugate of q_a
    wb, vb = qb[:, 0], qb[:, 1:]
    w = wb * wa - np.einsum("ni,ni->n", vb, va)
    v = wb[:, None] * va + wa[:, None] * vb + np.cross(vb, va)
    v *= np.sign(w)[:, None]
    return 2.0 * v / (h_ns * 1e-9)


def _voxel_plane_residuals(p: np.ndarray, J: np.ndarray, t: np.ndarray, voxel_m: float,
                           sep_ns: int, split: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-plane residuals (M,) and their Jacobians (M, n_p) of the points of planar voxels
    seen at moments at least ``sep_ns`` apart.

    Every voxel of ``voxel_m`` holding at least 10 points gets the plane of its points (centroid
    c, normal n: the covariance's smallest eigenvector); each point's residual is n·(p − c),
    whose Jacobian n·(J − J̄) is the point's own sensitivity less the voxel's mean — zero when
    every point of the voxel was fired at one moment (such voxels carry no information and are
    left out)."""
    k3 = np.floor(p / voxel_m).astype(np.int64) & 0x1FFFFF  # 21 bits a axis (±100 km at 0.1 m)
    keys = (k3[:, 0] << 42) | (k3[:, 1] << 21) | k3[:, 2]
    _, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    V = len(cnt)
    t_lo = np.full(V, np.iinfo(np.int64).max)
    t_hi = np.full(V, np.iinfo(np.int64).min)
    np.minimum.at(t_lo, inv, t)
    np.maximum.at(t_hi, inv, t)
    ok_v = (cnt >= 10) & (t_hi - t_lo > sep_ns)
    sel = ok_v[inv]
    if sel.sum() < 100:
        return np.zeros(0), np.zeros((0, J.shape[2]))
    if split:
        return _split_plane_residuals(p[sel], J[sel], t[sel], inv[sel], t_lo, t_hi)
    # compact the chosen voxels
    vid = np.cumsum(ok_v) - 1
    iv = vid[inv[sel]]
    ps, Js = p[sel], J[sel]
    W = int(ok_v.sum())
    c, d, ev, nrm, Jbar = _voxel_planes(ps, Js, iv, W)
    planar = ev[:, 0] < 0.2 * ev[:, 1]
    keep = planar[iv]
    ivk = iv[keep]  # the planar voxels' points' voxels (gathered once, not per array)
    nn = nrm[ivk]
    r = np.einsum("qi,qi->q", nn, d[keep])
    Jr = np.einsum("qi,qij->qj", nn, Js[keep] - Jbar[ivk])
    return r, Jr


def stacked_matmul(R: np.ndarray, M: np.ndarray) -> np.ndarray:
    """R (N, 3, 3) @ M (3, k) → (N, 3, k) as one (3N, 3) @ (3, k) product: one BLAS call
    instead of numpy's N small ones (80,000 attitudes: 28 → 6 ms), the same numbers
    (``tests/processor/test_reconstruction_cost.py`` checks them against the stacked product)."""
    R = np.ascontiguousarray(R)
    return (R.reshape(-1, 3) @ M).reshape(len(R), 3, M.shape[1])


def _huber_normal_equations(r: np.ndarray, Jr: np.ndarray):
    """(robust sigma [m], H, g) of residuals ``r`` (M,) with Jacobians ``Jr`` (M, n): sigma from
    the MAD, Huber weights at 1.345 sigma, H = Jᵀ W J and g = Jᵀ W r."""
    s = 1.4826 * float(np.median(np.abs(r - np.median(r)))) + 1e-6
    hub = 1.345 * s
    wgt = np.where(np.abs(r) < hub, 1.0, hub / np.maximum(np.abs(r), 1e-12))
    JW = Jr * wgt[:, None]
    return s, JW.T @ Jr, JW.T @ r


def _voxel_planes(p: np.ndarray, J: np.ndarray, iv: np.ndarray, W: int):
    """Per voxel (``iv``: each point's voxel, 0..W-1): centroid c (W, 3), the points' offsets
    from it d (N, 3), the covariance's eigenvalues ev (W, 3, ascending), the plane normal
    (W, 3) and the mean Jacobian J̄ (W, 3, K)."""
    n = np.bincount(iv, minlength=W).astype(np.float64)
    c = np.stack([np.bincount(iv, p[:, i], W) for i in range(3)], axis=1) / n[:, None]
    d = p - c[iv]
    cov = np.zeros((W, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(iv, d[:, i] * d[:, j], W) / n
    ev, evec = np.linalg.eigh(cov)
    Jf = J.reshape(len(J), -1)
    Jbar = np.stack([np.bincount(iv, Jf[:, m], W) for m in range(Jf.shape[1])], axis=1)
    Jbar = (Jbar / n[:, None]).reshape(W, 3, -1)
    return c, d, ev, evec[:, :, 0], Jbar


def _split_plane_residuals(p: np.ndarray, J: np.ndarray, t: np.ndarray, inv: np.ndarray,
                           t_lo: np.ndarray, t_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of each voxel's later points (after the middle of its time span) to the plane
    of its earlier ones, with Jacobians n·(J − J̄_early).

    The plane of all of a voxel's points sits between a surface and its double (a wrong lever
    arm shifts what is seen at one part of the pan against another) and tilts to take up part
    of the gap, so each Gauss–Newton step sees only part of the error; a voxel doubled by more
    than its planarity allows leaves the fit. The earlier points' plane is the surface as one
    part of the pan saw it: the later points' residuals are the whole gap, and the voxel stays
    as long as the earlier points alone are planar."""
    late = t > (t_lo[inv] + t_hi[inv]) // 2
    e = ~late
    key = inv
    uk, iv, ne = np.unique(key[e], return_inverse=True, return_counts=True)
    W = len(uk)
    iv = iv.reshape(-1)
    c, _, ev, nrm, Jbar = _voxel_planes(p[e], J[e], iv, W)
    good = (ne >= 6) & (ev[:, 0] < 0.2 * ev[:, 1])
    # the later points of the voxels whose earlier points make a plane
    pos = np.searchsorted(uk, key[late])
    pos_c = np.minimum(pos, W - 1)
    has = (pos < W) & (uk[pos_c] == key[late]) & good[pos_c]
    k = pos_c[has]
    li = np.flatnonzero(late)[has]  # the kept later points (one gather of J, not two)
    pl, Jl = p[li], J[li]
    nn = nrm[k]
    r = np.einsum("qi,qi->q", nn, pl - c[k])
    Jr = np.einsum("qi,qij->qj", nn, Jl - Jbar[k])
    return r, Jr


def self_calibrate(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                   ext: Extrinsic, *, fit_lever: bool = True, fit_time: bool = True,
                   fit_rotation: bool = True, max_stations: int = 4,
                   points_per_station: int = 80_000, voxel_m: float = 0.25,
                   min_separation_s: float = 0.3, iterations: int = 8,
                   max_range: float = 60.0, sigma_inflation: float = 3.0,
                   num_threads: int = 0, time_prior_ns: int | None = None,
                   time_prior_sigma_ms: float = float("inf"),
                   split_iterations: int = 0,
                   denoise_firings: int = DENOISE_FIRINGS,
                   fit_yaw_drift: bool = False,
                   yaw_drift_prior_deg_per_min: float = float("inf"),
                   points_cache: SweepCache | None = None,
                   range_weight_exp: float = 0.0) -> SelfCalibration:
    """Lever arm, IMU time offset and mount rotation that make every station self-consistent.

    At a standing station the head turns about a fixed pivot, so a surface seen at two moments
    of the pan lands in the same place only with the right calibration. With the pivot at the
    origin, a point x (lidar frame, fired at t) lands at

        p = R_wi(t − δ) · (R_il · exp([φ]×) · x + ℓ)

    which is linear in small changes of the lever arm ℓ (∂p/∂ℓ = R_wi), the time offset δ
    (∂p/∂δ = −[ω_w]× p, ω_w the IMU's world rate) and the mount rotation φ
    (∂p/∂φ = −R_wi R_il [x]×). Each station's sample points are gathered in ``voxel_m``
    voxels (larger in the first iterations); a planar voxel whose points were fired at least
    ``min_separation_s`` apart (different parts of the pan) pulls them onto one plane (:func:`_voxel_plane_residuals`, the plane adjustment of BALM).
    Gauss–Newton on the point-to-plane distances (Huber weights, voxels renewed each iteration)
    gives the calibration and, from the normal matrix, its covariance (times
    ``sigma_inflation``: a voxel's residuals share its fitted plane).

    ``fit_yaw_drift`` (opt-in): the IMU's heading drift c [rad/s] (a fused attitude without
    magnetometer turns slowly about the world's vertical z; the simulator's
    ``imu.yaw_drift_deg_per_min`` has the same sign) joins the fit as a nuisance parameter: a
    point lands at Rz(−c·(t − t_st))·p, t_st the station's middle (∂p/∂c = −(t − t_st)·(z × p)),
    with a prior c = 0 ± ``yaw_drift_prior_deg_per_min``. Left out, it turns the later part of
    a pan against the earlier by c·Δt, a shift growing with range, which the lever arm takes up
    in part where it shifts surfaces the same way: along the spin axis of a lidar on its side
    (opposite pan angles: the scan plane shifted along its normal;
    ``tests/processor/test_calibration_yaw_drift.py``).

    What a pan about one axis b cannot see is held at the prior: ℓ along b (moves the fragment
    rigidly) and the mount's turn about b (turns it). The time offset is seen where the turn
    rate changes (the pan's start and stop, a hand-turned head); at a constant rate it only
    turns the fragment, and its sigma says so. ``time_prior_ns`` / ``time_prior_sigma_ms``: an
    independent estimate of the offset (the head's turns, :func:`time_offset_from_turns`) joins
    the fit as one more residual, so the offset and the lever arm, which a hand pan's uneven
    rate makes correlate, are estimated together and the result's sigma is the joint one.

    The stations' sampling and residuals run side by side on ``num_threads`` threads (0: every
    core), one station a thread, gathered in station order: the same result on any count.
    ``points_cache`` (:class:`SweepCache`): the stations' sample points kept for the run's later
    fits (:func:`_station_points`; the same result to the bit). ``range_weight_exp``: the
    sample drawn denser at range (:func:`_station_points`; 0: uniform).
    """
    from scipy.spatial.transform import Rotation

    use = _pick_stations(stations, orient, max_stations)
    workers = thread_workers(num_threads, len(use))
    b = pan_axis_in_imu(orient, use)
    U_l = _perp_basis(b)  # lever arm directions across the pan axis (IMU frame)
    R_il = ext.R_imu_lidar.copy()
    ell = ext.lever_arm_m.astype(np.float64).copy()
    off = orient.time_offset_ns
    data = _threaded_map(_station_points, [
        (lidar, st, points_per_station, 11 + k, max_range, orient if fit_time else None,
         denoise_firings, points_cache, range_weight_exp) for k, st in enumerate(use)], workers)
    sep_ns = int(min_separation_s * 1e9)
    cols = (["l1", "l2"] if fit_lever else []) + (["dt"] if fit_time else []) + (
        ["r1", "r2"] if fit_rotation else []) + (["yd"] if fit_yaw_drift else [])
    drift = 0.0  # [rad/s] the IMU's heading drift about the world's vertical (fit_yaw_drift)
    n_p = len(cols)
    history: list[dict] = []
    H = np.zeros((n_p, n_p))
    s_rob, n_pairs = float("nan"), 0
    prev_step = None
    for it in range(iterations):
        o = orient.with_offset(off)
        U_r = _perp_basis(R_il.T @ b)  # mount tilts the pan can see (lidar frame)
        H = np.zeros((n_p, n_p))
        g = np.zeros(n_p)
        all_r, all_J = [], []
        # coarse to fine: a large lever-arm error doubles surfaces by twice its size, which
        # small voxels would see as two planes (or none)
        split = it < split_iterations
        vox = voxel_m * max(1.0, 2.4 / (1.0 + it - (split_iterations if not split else 0)))

        def station_residuals(xyz, t):  # one station's (r, Jr); stations side by side
            if len(xyz) < 500:
                return np.zeros(0), None
            R_wi = o.rotation_at(t)
            if fit_yaw_drift:
                # the heading drift taken out: Rz(−c·(t − t_st)) about the world's vertical
                dts = (t - (int(t.min()) + int(t.max())) // 2) * 1e-9  # [s] from the middle
                R_wi = np.matmul(Rotation.from_rotvec(
                    np.outer(-drift * dts, [0.0, 0.0, 1.0])).as_matrix(), R_wi)
            v = xyz @ R_il.T + ell
            p = np.einsum("nij,nj->ni", R_wi, v)
            J = np.zeros((len(p), 3, n_p))
            c = 0
            if fit_lever:
                J[:, :, c:c + 2] = stacked_matmul(R_wi, U_l)
                c += 2
            if fit_time:
                # a later offset reads the IMU earlier: R(t − δ), ∂p/∂δ = −ω × p
                w = _world_rate(o, t)  # (N, 3) [rad/s]
                J[:, :, c] = -np.cross(w, p)
                c += 1
            if fit_rotation:
                # ∂p/∂φ·u = −R_wi R_il [x]× u = −R_wi R_il (x × u) for the seen tilts u ∈ U_r
                R_wl = stacked_matmul(R_wi, R_il)
                for m in range(2):
                    J[:, :, c + m] = -np.einsum("nij,nj->ni", R_wl, np.cross(xyz, U_r[:, m]))
                c += 2
            if fit_yaw_drift:
                # ∂p/∂c = −(t − t_st)·(z × p)
                J[:, 0, c] = dts * p[:, 1]
                J[:, 1, c] = -dts * p[:, 0]
            return _voxel_plane_residuals(p, J, t, vox, sep_ns, split)

        for r, Jr in _threaded_map(station_residuals, data, workers):
            if len(r):
                all_r.append(r)
                all_J.append(Jr)
        if not all_r:
            raise ValueError("no surface seen twice at a station: nothing to calibrate on")
        r = np.concatenate(all_r)
        Jr = np.concatenate(all_J)
        n_pairs = len(r)
        s_rob, H, g = _huber_normal_equations(r, Jr)
        if fit_time and time_prior_ns is not None and np.isfinite(time_prior_sigma_ms):
            # the offset's prior (the head's turns) as one more residual, in the units of the
            # data's information (H / (s² · inflation²) is the inverse covariance)
            it_c = 2 if fit_lever else 0
            w_p = (s_rob * sigma_inflation / (time_prior_sigma_ms * 1e-3)) ** 2
            H[it_c, it_c] += w_p
            g[it_c] += w_p * (off - time_prior_ns) * 1e-9
        if fit_yaw_drift and np.isfinite(yaw_drift_prior_deg_per_min):
            # the drift's prior 0 ± σ, one more residual as the offset's
            w_d = (s_rob * sigma_inflation / np.radians(yaw_drift_prior_deg_per_min / 60.0)) ** 2
            H[-1, -1] += w_d
            g[-1] += w_d * drift
        # scale columns for conditioning; tiny eigenvalues (no information) are left out
        sc = np.sqrt(np.maximum(np.diag(H), 1e-30))
        Hs = H / np.outer(sc, sc)
        ew, EV = np.linalg.eigh(Hs)
        keep = ew > 1e-6 * ew.max()
        step_s = -(EV[:, keep] @ ((EV[:, keep].T @ (g / sc)) / ew[keep]))
        step = step_s / sc
        # the planes refitted each iteration absorb part of the error (a blurred surface gets a
        # tilted normal), so steps shrink geometrically; a parameter whose steps keep their
        # sign and shrink by ρ is moved to the limit of that series (Aitken), ≤ 3x the step
        if prev_step is not None:
            rho = step / np.where(np.abs(prev_step) > 0, prev_step, np.inf)
            acc = (rho > 0.05) & (rho < 0.8)
            step = np.where(acc, step / (1.0 - np.clip(rho, 0.0, 2.0 / 3.0)), step)
        prev_step = step_s / sc
        c = 0
        if fit_lever:
            ell = ell + U_l @ step[c:c + 2]
            c += 2
        if fit_time:
            dt_s = float(np.clip(step[c], -0.05, 0.05))
            off = int(round(off + dt_s * 1e9))
            c += 1
        if fit_rotation:
            phi = U_r @ step[c:c + 2]
            R_il = R_il @ Rotation.from_rotvec(phi).as_matrix()
            c += 2
        if fit_yaw_drift:
            drift += float(step[c])
        history.append({"residual_m": s_rob, "pairs": n_pairs, "step": step.tolist(),
                        "lever_arm_m": ell.tolist(), "time_offset_ms": off * 1e-6,
                        **({"yaw_drift_deg_per_min": np.degrees(drift) * 60.0}
                           if fit_yaw_drift else {})})
        small = (not fit_lever or np.all(np.abs(step[:2]) < 1e-4)) and (
            not fit_time or abs(step[2 if fit_lever else 0]) < 5e-5)
        if small and vox <= voxel_m and not split:
            break
    if split_iterations > 0 and fit_lever:
        # the covariance from the split residuals at the result: the all-points planes take up
        # part of any error along a weakly seen direction (a lidar on its side: the lever arm
        # along its spin axis), which makes their information, and sigma, optimistic there
        o = orient.with_offset(off)
        U_r = _perp_basis(R_il.T @ b)
        split, vox = True, voxel_m
        res = [x for x in _threaded_map(station_residuals, data, workers) if len(x[0])]
        if res:
            r = np.concatenate([x[0] for x in res])
            Jr = np.concatenate([x[1] for x in res])
            s_sp, H_sp, _ = _huber_normal_equations(r, Jr)
            if fit_time and time_prior_ns is not None and np.isfinite(time_prior_sigma_ms):
                H_sp[2, 2] += (s_sp * sigma_inflation / (time_prior_sigma_ms * 1e-3)) ** 2
            if fit_yaw_drift and np.isfinite(yaw_drift_prior_deg_per_min):
                H_sp[-1, -1] += (s_sp * sigma_inflation
                                 / np.radians(yaw_drift_prior_deg_per_min / 60.0)) ** 2
            # the larger of the two per parameter (each is a lower bound of the truth's spread)
            try:
                c_sp = np.linalg.inv(H_sp) * s_sp**2
                c_all = np.linalg.inv(H) * s_rob**2
                if np.all(np.diag(c_sp) >= np.diag(c_all)):
                    H, s_rob = H_sp, s_sp
            except np.linalg.LinAlgError:
                pass
    # covariance: robust residual variance over the information, inflated (shared planes)
    try:
        cov = np.linalg.inv(H) * s_rob**2 * sigma_inflation**2
    except np.linalg.LinAlgError:
        cov = np.full((n_p, n_p), np.inf)
    sig = np.sqrt(np.abs(np.diag(cov)))
    c = 0
    l_sig = np.full(2, np.nan)
    t_sig = float("nan")
    r_sig = float("nan")
    l_cov = None
    if fit_lever:
        l_sig = sig[c:c + 2]
        l_cov = cov[c:c + 2, c:c + 2].copy()
        c += 2
    if fit_time:
        t_sig = float(sig[c]) * 1e3
        c += 1
    if fit_rotation:
        r_sig = float(np.degrees(sig[c:c + 2].max()))
    rot_change = float(np.degrees(Rotation.from_matrix(ext.R_imu_lidar.T @ R_il).magnitude()))
    return SelfCalibration(
        R_il, ell, l_sig, b, off, t_sig, r_sig, rot_change,
        time_offset_observable=bool(fit_time and t_sig < 0.5),
        lever_arm_observable=bool(fit_lever and np.all(l_sig < 0.003)),
        rotation_observable=bool(fit_rotation and r_sig < TILT_OBSERVABLE_SIGMA_DEG),
        stations=[st.index for st in use], residual_m=s_rob, pairs=n_pairs, iterations=history,
        lever_arm_cov_m2=l_cov, lever_basis_imu=U_l if fit_lever else None,
        yaw_drift_deg_per_min=float(np.degrees(drift) * 60.0) if fit_yaw_drift else float("nan"))


# ---- the mount's turn about the pan axis from the carries ------------------------------------------
@dataclass
class MountYaw:
    """The mount's turn about the pan axis from the carries' sweep pairs
    (:func:`mount_yaw_from_carries`): ``angle_rad`` to turn ``R_imu_lidar`` (and with it the
    lever arm in the IMU frame) about ``pan_axis_imu`` (IMU frame), its 1-sigma, the pairs and
    carries it came from."""

    angle_rad: float
    sigma_rad: float
    pairs: int
    carries: int
    pan_axis_imu: np.ndarray

    def rotation(self) -> np.ndarray:
        """R (3x3, IMU frame): the turn by ``angle_rad`` about the pan axis."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_rotvec(self.angle_rad * self.pan_axis_imu).as_matrix()

    def to_dict(self) -> dict:
        return {"angle_deg": float(np.degrees(self.angle_rad)),
                "sigma_deg": float(np.degrees(self.sigma_rad)), "pairs": self.pairs,
                "carries": self.carries}


def mount_yaw_from_carries(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                           ext: Extrinsic, num_threads: int = 0, *, pairs_per_carry: int = 16,
                           max_carries: int = 8, denoise_firings: int = DENOISE_FIRINGS,
                           min_pairs: int = 6, pan_axis_imu: np.ndarray | None = None,
                           sweep_cache: SweepCache | None = None) -> MountYaw | None:
    """The mount's turn about the pan axis, which no station sees, from the carries.

    At a station the head turns about the pan axis b only, so hand-eye and the surfaces see the
    mount's two tilts but not its turn about b: R_imu_lidar turned by α about b, with the lever
    arm (IMU frame) turned alike, places every station the same, turned by α about its pivot
    (the lever arm in the lidar frame is unchanged). Hand-eye's mount holds whatever α the
    registrations' noise left (dev seeds 83, 87, 40, 609: 1.2–2.2°), and a lever arm of 15–20 cm
    read in the IMU frame is then 4–6 mm off. While the tripod is carried it turns about every
    axis: two 0.1-s sweeps 0.2–0.5 s apart (:func:`turn_measurements`' carry pairs, returns
    within 1.5 m left out) registered against each other give the lidar's relative rotation A,
    the IMU predicts P with the mount; a small mount correction ε (R_imu_lidar·exp([ε]×)) turns
    P by (I − Pᵀ)ε (:func:`_mount_jacobian`). The three components of ε are fitted to every
    pair's rotation error (whitened by its registration's information), Huber-weighted; σ from
    the scatter, at least the carries' cluster-robust one. Returned: ε's component about b in
    the IMU frame (α = b·(R_imu_lidar ε)); the tilts are left to the surfaces (they see them
    better). ``pan_axis_imu``: b (IMU frame; default: the stations' own). None with fewer than
    ``min_pairs`` pairs or a singular fit. ``sweep_cache``: the run's decoded sweeps (the turns'
    carry windows are among them)."""
    from scipy.spatial.transform import Rotation

    from .placement import pose_world_lidar

    spans = carry_spans(stations)
    if not spans or pairs_per_carry <= 0:
        return None
    tm = turn_measurements(lidar, stations, orient, ext, num_threads, pairs_per_station=0,
                           carries=spans, max_carries=max_carries,
                           pairs_per_carry=pairs_per_carry, denoise_firings=denoise_firings,
                           sweep_cache=sweep_cache)
    meas = [m for m, c in zip(tm.meas, tm.is_carry) if c]
    if len(meas) < min_pairs:
        return None
    rows, X = [], []
    for tk, tj, A, _, W in meas:
        T = pose_world_lidar(orient, ext, np.array([tk, tj], dtype=np.int64))
        P = (np.linalg.inv(T[0]) @ T[1])[:3, :3]
        rows.append(W @ Rotation.from_matrix(P.T @ A[:3, :3]).as_rotvec())
        X.append(W @ _mount_jacobian(orient, ext, tk, tj, P))
    fit = _huber_lsq_clustered(np.vstack(X), np.concatenate(rows),
                               np.repeat(tm.cluster[tm.is_carry], 3), iters=6, scale_floor=1e-12)
    if fit is None:
        return None
    eps, cov, n_carries = fit
    b = pan_axis_in_imu(orient, stations) if pan_axis_imu is None else np.asarray(pan_axis_imu)
    u = ext.R_imu_lidar.T @ b  # the pan axis in the lidar frame: α = u·ε
    alpha = float(u @ eps)
    sigma = float(np.sqrt(max(float(u @ cov @ u), 0.0)))
    return MountYaw(alpha, sigma, len(meas), n_carries, b)


# ---- IMU time offset from the head's turns (lidar sweeps registered against each other) ---------
@dataclass
class TurnTimeOffset:
    """IMU time offset from sweep-to-sweep registrations (``time_offset_from_turns``).

    offset_ns : int, added to the IMU's lidar-clock stamps; sigma_ms : 1-sigma [ms] (inf when
    nothing was measured); pairs : registrations used (stations' and carries');
    rate_change_deg_s : RMS change of the rotation rate between the two sweeps of a pair (what
    makes the offset visible); carry_pairs : how many of the pairs were taken while the tripod
    was carried."""

    offset_ns: int
    sigma_ms: float
    pairs: int
    rate_change_deg_s: float
    carry_pairs: int = 0
    #: the cluster (station or carry, :class:`TurnMeasurements`' numbering) left out as
    #: disagreeing with all the others (``cluster_outlier_z``), or None
    dropped_cluster: int | None = None

    def to_dict(self) -> dict:
        d = {"imu_time_offset_ms": self.offset_ns * 1e-6, "sigma_ms": self.sigma_ms,
             "pairs": self.pairs, "rate_change_deg_s": self.rate_change_deg_s,
             "carry_pairs": self.carry_pairs}
        if self.dropped_cluster is not None:
            d["dropped_cluster"] = self.dropped_cluster
        return d


def time_offset_from_turns(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                           ext: Extrinsic, num_threads: int = 0, *, passes: int = 2,
                           redo_ms: float = 0.5, redo_max_sigma_ms: float = 4.0,
                           **kw) -> TurnTimeOffset:
    """The IMU time offset from the head's turns, at any pan profile (see
    :func:`_turn_offset_pass`). The sweeps are de-skewed by the IMU at the current offset, which
    bends them a little where the rate changes; a second pass de-skews them at the first pass's
    offset when it moved by more than ``redo_ms``."""
    res = _turn_offset_pass(lidar, stations, orient, ext, num_threads, **kw)
    for _ in range(passes - 1):
        # no second pass for an offset too uncertain to be used or one that hardly moved
        moved_ns = abs(res.offset_ns - orient.time_offset_ns)
        if not res.sigma_ms <= redo_max_sigma_ms or moved_ns < redo_ms * 1e6:
            break
        orient = orient.with_offset(res.offset_ns)
        res = _turn_offset_pass(lidar, stations, orient, ext, num_threads, **kw)
    return res


def carry_spans(stations: list[Station], min_s: float = 1.0) -> list[tuple[int, int]]:
    """Lidar-time spans [ns] between consecutive stations, at least ``min_s`` long: the tripod
    is being carried (lifted, walked, turned, set down), its head turning faster and more
    unevenly than most pans."""
    order = sorted(stations, key=lambda s: s.start_ns)
    return [(a.end_ns, b.start_ns) for a, b in zip(order[:-1], order[1:])
            if b.start_ns - a.end_ns >= min_s * 1e9]


def max_pair_turn_deg(a_lidar: np.ndarray, band_deg: float = 12.0, floor_deg: float = 20.0
                      ) -> float:
    """The largest turn [deg] about the pan axis (``a_lidar``: unit, lidar frame) at which two
    sweeps still see the same surfaces everywhere round the lidar. A VLP-16 sees a band of
    ±15° about its equator; with the spin axis tilted τ from the pan axis, a turn α moves the
    band's elevation by up to 2τ·sin(α/2) (small angles), so α ≤ 2·asin(band / τ) keeps the two
    bands within ``band_deg`` of each other: any turn for τ ≤ band (a spin axis near the pan
    axis sees the same ring after any turn), ~80° at 18°, ``floor_deg`` for a lidar on its
    side (whose sweeps overlap near the pan axis only)."""
    tilt = float(np.degrees(np.arccos(min(1.0, abs(float(a_lidar[2]))))))
    if tilt <= band_deg:
        return 180.0
    return float(max(floor_deg, 2.0 * np.degrees(np.arcsin(band_deg / tilt))))


def _rotation_whitener(information: np.ndarray) -> np.ndarray:
    """W (3, 3) with Wᵀ W = the rotation's information of a registration (its 6x6 information,
    rotation first, with the translation marginalised out: Schur complement), the symmetric
    square root; directions with no information get a millionth of the largest."""
    I6 = np.asarray(information, dtype=np.float64)
    I_rr = I6[:3, :3] - I6[:3, 3:] @ np.linalg.pinv(I6[3:, 3:]) @ I6[3:, :3]
    ew, EV = np.linalg.eigh(0.5 * (I_rr + I_rr.T))
    ew = np.maximum(ew, 1e-6 * max(float(ew.max()), 1e-12))
    return (EV * np.sqrt(ew)) @ EV.T


def _axis_information_sqrt(information: np.ndarray, a: np.ndarray) -> float:
    """The square root of a registration's information [1/rad²] about its rotation's component
    along the unit axis ``a`` (its 6x6 information, rotation first; the translation and the two
    other turns marginalised out: Schur complements)."""
    I6 = np.asarray(information, dtype=np.float64)
    I_rr = I6[:3, :3] - I6[:3, 3:] @ np.linalg.pinv(I6[3:, 3:]) @ I6[3:, :3]
    B = np.column_stack([a, _perp_basis(a)])
    Ib = B.T @ (0.5 * (I_rr + I_rr.T)) @ B
    i_a = Ib[0, 0] - Ib[0, 1:] @ np.linalg.pinv(Ib[1:, 1:]) @ Ib[1:, 0]
    return float(np.sqrt(max(i_a, 1e-12 * max(float(np.trace(I_rr)), 1e-12))))


def _pick_pairs(dr: np.ndarray, k: np.ndarray, j: np.ndarray, n_times: int, n_pairs: int,
                uses_per_sweep: int = 1) -> list[tuple[int, int, float]]:
    """The candidate sweep pairs (k, j) with the largest rate change ``dr`` first (ties in
    (k, j) order), each sweep in at most ``uses_per_sweep`` pairs, at most ``n_pairs`` (none
    for 0)."""
    if n_pairs <= 0:
        return []
    order = np.lexsort((j, k, -dr))
    used = np.zeros(n_times, dtype=np.int64)
    chosen = []
    for m in order:
        a, b = int(k[m]), int(j[m])
        if used[a] >= uses_per_sweep or used[b] >= uses_per_sweep:
            continue
        chosen.append((a, b, float(dr[m])))
        used[a] += 1
        used[b] += 1
        if len(chosen) >= n_pairs:
            break
    return chosen


def carry_pairs(orient: ImuOrientation, span: tuple[int, int], n_pairs: int, *,
                step_s: float = 0.1, window_s: float = 0.1,
                carry_pair_s: tuple[float, float] = (0.2, 0.5), max_turn_deg: float = 180.0,
                min_rate_change_deg_s: float = 4.0
                ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, float]]]:
    """The sweep pairs :func:`turn_measurements` registers in one carry (lidar-time ``span``
    [ns]): (sweep start times [ns], their middles [ns], chosen (k, j, rate change [rad/s])).
    Sweeps of ``window_s`` every ``step_s``, pairs ``carry_pair_s`` apart turned at most
    ``max_turn_deg``, where the carried head's rotation rate (a vector) changes most (at least
    ``min_rate_change_deg_s``), each sweep in one pair, at most ``n_pairs``."""
    win = int(window_s * 1e9)
    times = np.arange(span[0], span[1] - win, int(step_s * 1e9), dtype=np.int64)
    mids = times + win // 2
    lo = max(1, int(round(carry_pair_s[0] / step_s)))
    hi = max(lo, int(round(carry_pair_s[1] / step_s)))
    if len(times) <= lo:
        return times, mids, []
    R_w = orient.rotation_at(mids)
    w_w = _world_rate(orient, mids, 50_000_000)  # (N, 3) [rad/s]
    cand_dr, cand_k, cand_j = [], [], []
    for lag in range(lo, min(hi, len(times) - 1) + 1):
        k = np.arange(len(times) - lag)
        j = k + lag
        ang = _turn_angles_deg(R_w[k], R_w[j], (max_turn_deg,))
        dr = np.linalg.norm(w_w[j] - w_w[k], axis=1)
        ok = (np.degrees(dr) >= min_rate_change_deg_s) & (ang <= max_turn_deg)
        cand_dr.append(dr[ok])
        cand_k.append(k[ok])
        cand_j.append(j[ok])
    chosen = _pick_pairs(np.concatenate(cand_dr), np.concatenate(cand_k),
                         np.concatenate(cand_j), len(times), n_pairs)
    return times, mids, chosen


def turn_measurements(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                      ext: Extrinsic, num_threads: int = 0, *, max_stations: int = 8,
                      pairs_per_station: int = 6, step_s: float = 0.1,
                      window_s: float = 0.1, min_turn_deg: float = 3.0,
                      max_turn_deg: float | None = None, max_pair_s: float = 10.0,
                      min_rate_change_deg_s: float = 4.0,
                      carries: list[tuple[int, int]] | None = None, max_carries: int = 8,
                      pairs_per_carry: int = 6, carry_pair_s: tuple[float, float] = (0.2, 0.5),
                      carry_min_range_m: float = 1.5,
                      denoise_firings: int = DENOISE_FIRINGS,
                      station_information: bool = False,
                      uses_per_sweep: int = 1,
                      carry_velocity: bool = False,
                      sweep_cache: SweepCache | None = None) -> "TurnMeasurements":
    """The sweep pairs of one pass of the IMU time offset from the head's turns
    (:func:`_turn_offset_pass`, which fits them: :func:`fit_turn_offset`).

    Two short sweeps of a station (``window_s``, de-skewed by the IMU) are registered against
    each other: their relative rotation A is the head's true turn between the two moments. The
    IMU predicts it from its attitudes at those moments less the offset δ; a δ error turns the
    prediction about the pan axis by δ·(ω_j − ω_k), the change of the pan rate between the two
    sweeps. Pairs are chosen where the rate changes most (a motor's ramps, a hand's uneven
    speed, a pause, a reversal), turned ``min_turn_deg`` up to what the mount's sweeps share
    everywhere (:func:`max_pair_turn_deg`, unless ``max_turn_deg``: a spin axis near the pan
    axis pairs sweeps far apart in a hand pan, whose rate differs more the longer apart), at
    most ``max_pair_s`` apart; each sweep in at most ``uses_per_sweep`` pairs (a registration
    costs less than de-skewing a sweep, and each pair's registration error is its own). The
    stations (up to ``max_stations``,
    those the head turns most in) are pooled: one offset for the recording, each pair weighted
    by its own information (δ's effect grows with the rate change). δ and the IMU's yaw drift
    (a slow turn about the vertical that a fused attitude without magnetometer accumulates:
    0.5°/min is 0.02° over a 2-s pair, as much as a 1-ms error at 20°/s of rate change) are
    the least-squares fit of the registrations' angles about the pan axis (a mount tilt error
    turns them about other axes), outliers trimmed.

    ``carries`` (lidar-time spans [ns] between stations, :func:`carry_spans`; up to
    ``max_carries``, the longest): while the tripod is carried its head turns about every axis,
    lifted, swayed and turned to the next heading, with rate changes of tens of °/s within half a
    second — far more than a slow hand pan's few °/s, and present whatever the pan profile. Up to
    ``pairs_per_carry`` pairs of sweeps ``carry_pair_s`` apart (close enough for the carry's
    unknown shift to stay within the registration's reach; the rotation is all that is used)
    join the fit with all three components of their rotation error (δ·(ω_j − ω_k) about any
    axis; the yaw drift about the world's vertical seen in the sweep's frame). Returns nearer
    than ``carry_min_range_m`` are left out of them (the operator carrying it, the tripod's own
    legs). Each kind's residuals are weighed by its own robust scale.

    δ's sigma: from the residuals' scatter, at least the stations' and carries' cluster-robust
    (sandwich) one (a station's pairs share its errors), times ``sigma_inflation`` (on 6
    development rigs the errors were 2.3 sigma RMS without it). A pan at a perfectly constant
    rate with no ramp and no carry gives no pair (sigma inf).

    ``sweep_cache`` (:class:`SweepCache`): the sweeps' decoded points shared with the run's
    other passes and registrations (the same measurements to the bit).
    """
    from scipy.spatial.transform import Rotation

    from .placement import pose_world_lidar

    use = _pick_stations(stations, orient, max_stations)
    b = pan_axis_in_imu(orient, use)
    a_l = ext.R_imu_lidar.T @ b  # the pan axis in the lidar frame
    turn_max = max_pair_turn_deg(a_l) if max_turn_deg is None else float(max_turn_deg)
    win = int(window_s * 1e9)
    max_lag = max(1, int(round(max_pair_s / step_s)))

    def rel(o: ImuOrientation, tk: int, tj: int) -> np.ndarray:
        T = pose_world_lidar(o, ext, np.array([tk, tj], dtype=np.int64))
        return np.linalg.inv(T[0]) @ T[1]

    #: one measurement: (t_k, t_j [ns], A measured (4x4), rate change [°/s], the rotation
    #: error's whitener W (3x3) for a carry's pair, a weight (float) for a station's)
    Meas = tuple[int, int, np.ndarray, float, "np.ndarray | float"]

    def register_chosen(times: np.ndarray, mids: np.ndarray, chosen, num_threads: int,
                        min_range: float, moving: bool = False) -> list[Meas]:
        """The measurements of the chosen pairs that registered well (``moving``: a carry's)."""
        meas: list[Meas] = []
        clouds: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        prepared: dict[int, object] = {}

        def cloud(k: int) -> tuple[np.ndarray, np.ndarray]:
            if k not in clouds:
                clouds[k] = _sweep(lidar, orient, ext, int(times[k]), win, num_threads,
                                   min_range, denoise_firings, with_times=True,
                                   cache=sweep_cache)
            return clouds[k]

        def ready(k: int):
            # ... prepared for registration once (``uses_per_sweep``: up to that many pairs)
            if k not in prepared:
                prepared[k] = _prepare_sweep(cloud(k)[0], num_threads)
            return prepared[k]

        for k, j, dr in chosen:
            (ck, tk_pts), (cj, tj_pts) = cloud(k), cloud(j)
            if len(ck) < 500 or len(cj) < 500:
                continue
            init = rel(orient, int(mids[k]), int(mids[j]))
            r = _register_sweeps(ready(j), ready(k), init, num_threads)
            if r is None:
                continue
            A = r.T_target_source
            if moving and carry_velocity:
                # the carried head also walks (~1 m/s: a 10-cm smear over a sweep, which
                # the IMU's rotations do not take out and which turns with the head between
                # the two sweeps, biasing their rotation): the pivot's velocity from the pair's
                # shift (less the lever arm's swing), each sweep de-skewed by it, again
                T = pose_world_lidar(orient, ext, np.array([mids[k], mids[j]], np.int64))
                dt = (int(mids[j]) - int(mids[k])) * 1e-9
                v_w = (T[0, :3, :3] @ A[:3, 3] - (T[1, :3, 3] - T[0, :3, 3])) / dt
                ck2 = ck + np.outer((tk_pts - int(mids[k])) * 1e-9, T[0, :3, :3].T @ v_w)
                cj2 = cj + np.outer((tj_pts - int(mids[j])) * 1e-9, T[1, :3, :3].T @ v_w)
                r2 = _register_sweeps(cj2, ck2, A, num_threads)
                if r2 is not None:
                    r, A = r2, r2.T_target_source
            slip = np.degrees(Rotation.from_matrix(init[:3, :3].T @ A[:3, :3]).magnitude())
            if r.fitness < 0.5 or slip > 1.0:
                continue
            # W, the pair's weight: a carry's rotation error is used about every axis, each as
            # well as the registration saw it (a 3x3 whitener: a lidar on its side sees a fan,
            # some turns hardly show); a station's pair gives its angle about the pan axis only,
            # weighed alike (1.0) or, with ``station_information``, by what the registration saw
            # of that turn (the other two and the shift marginalised out)
            if moving:
                W = _rotation_whitener(r.information)
            elif station_information:
                W = _axis_information_sqrt(r.information, a_l)
            else:
                W = 1.0
            meas.append((int(mids[k]), int(mids[j]), A, float(np.degrees(dr)), W))
        return meas

    def station_turns(st: Station, num_threads: int) -> list[Meas]:
        """One station's measurements; stations and carries run side by side on threads (each
        registration on ``num_threads``, bit-identical on any)."""
        times = np.arange(st.start_ns, st.end_ns - win, int(step_s * 1e9), dtype=np.int64)
        if len(times) < 3:
            return []
        mids = times + win // 2
        R_w = orient.rotation_at(mids)
        rate = np.einsum("ni,ni->n", _world_rate(orient, mids, 50_000_000),
                         np.einsum("nij,j->ni", R_w, b))  # signed pan rate [rad/s]
        cand_dr, cand_k, cand_j = [], [], []
        for k in range(len(times) - 1):
            hi = min(len(times), k + 1 + max_lag)
            ang = _turn_angles_deg(R_w[k], R_w[k + 1:hi], (min_turn_deg, turn_max))
            j = np.flatnonzero((ang >= min_turn_deg) & (ang <= turn_max)) + k + 1
            dr = np.abs(rate[j] - rate[k])
            ok = np.degrees(dr) >= min_rate_change_deg_s
            cand_dr.append(dr[ok])
            cand_k.append(np.full(int(ok.sum()), k))
            cand_j.append(j[ok])
        if not cand_dr:
            return []
        chosen = _pick_pairs(np.concatenate(cand_dr), np.concatenate(cand_k),
                             np.concatenate(cand_j), len(times), pairs_per_station,
                             uses_per_sweep)
        return register_chosen(times, mids, chosen, num_threads, 0.5)

    def carry_turns(span: tuple[int, int], num_threads: int) -> list[Meas]:
        """One carry's measurements (:func:`carry_pairs`), as :func:`station_turns`."""
        times, mids, chosen = carry_pairs(orient, span, pairs_per_carry, step_s=step_s,
                                          window_s=window_s, carry_pair_s=carry_pair_s,
                                          max_turn_deg=turn_max,
                                          min_rate_change_deg_s=min_rate_change_deg_s)
        return register_chosen(times, mids, chosen, num_threads, carry_min_range_m, True)

    spans = sorted(carries or [], key=lambda c: c[0] - c[1])[:max_carries]  # longest first
    jobs = [(station_turns, st) for st in use] + [(carry_turns, c) for c in sorted(spans)]
    workers = thread_workers(num_threads, len(jobs))
    inner = num_threads if workers == 1 else 1
    per_job = _threaded_map(lambda f, x: f(x, inner), jobs, workers)
    tm = TurnMeasurements(
        meas=[m for ms in per_job for m in ms],
        cluster=np.concatenate([np.full(len(ms), q) for q, ms in enumerate(per_job)]
                               + [np.zeros(0, dtype=np.int64)]).astype(np.int64),
        is_carry=np.concatenate([np.full(len(ms), q >= len(use)) for q, ms in enumerate(per_job)]
                                + [np.zeros(0, dtype=bool)]).astype(bool),
        a_lidar=a_l)
    return tm


_FIT_KEYS = ("sigma_inflation", "combine", "carry_mount", "carry_floor_ms", "anchor_smooth_s",
             "cluster_outlier_z")


def _turn_offset_pass(lidar: LidarPackets, stations: list[Station], orient: ImuOrientation,
                      ext: Extrinsic, num_threads: int = 0, **kw) -> TurnTimeOffset:
    """One pass of the IMU time offset from the head's turns: the sweep pairs
    (:func:`turn_measurements`, its keywords) fitted (:func:`fit_turn_offset`, its keywords)."""
    fit_kw = {k: kw.pop(k) for k in _FIT_KEYS if k in kw}
    tm = turn_measurements(lidar, stations, orient, ext, num_threads, **kw)
    return fit_turn_offset(tm, orient, ext, **fit_kw)


@dataclass
class TurnMeasurements:
    """The sweep pairs registered by :func:`_turn_offset_pass`: ``meas`` (t_k, t_j [ns],
    A measured (4x4), rate change [°/s], W: a carry's 3x3 whitener or a station's weight),
    each pair's ``cluster`` (its station or carry) and ``is_carry``, and the pan axis in the
    lidar frame ``a_lidar``."""

    meas: list
    cluster: np.ndarray
    is_carry: np.ndarray
    a_lidar: np.ndarray

    def subset(self, sel: np.ndarray) -> "TurnMeasurements":
        idx = np.flatnonzero(sel)
        return TurnMeasurements([self.meas[i] for i in idx], self.cluster[idx],
                                self.is_carry[idx], self.a_lidar)


def fit_turn_offset(tm: TurnMeasurements, orient: ImuOrientation, ext: Extrinsic, *,
                    sigma_inflation: float = 2.0, combine: str = "joint",
                    carry_mount: bool = False, carry_floor_ms: float = 0.0,
                    anchor_smooth_s: float = 0.0, cluster_outlier_z: float = 0.0
                    ) -> TurnTimeOffset:
    """The offset from the registered pairs (:func:`_fit_turns_once`, its keywords), with
    ``cluster_outlier_z`` > 0 one cluster (a station's or a carry's pairs) left out when it
    disagrees with all the others (:func:`cluster_outlier`): a station whose registrations
    share one bias (a small room's view, a sway) or a span mis-taken for a carry pulls the whole
    offset, which the pairs' trimming (one pair at a time, against the pooled fit that cluster
    already pulled) does not catch. 0: every cluster kept (the old fit, to the bit)."""
    fk = dict(sigma_inflation=sigma_inflation, combine=combine, carry_mount=carry_mount,
              carry_floor_ms=carry_floor_ms, anchor_smooth_s=anchor_smooth_s)
    res = _fit_turns_once(tm, orient, ext, **fk)
    if not cluster_outlier_z > 0 or not np.isfinite(res.sigma_ms):
        return res
    out = cluster_outlier(tm, orient, ext, cluster_outlier_z, pooled=res, **fk)
    if out is None:
        return res
    q, _, rest = out
    rest.dropped_cluster = int(q)
    return rest


def cluster_outlier(tm: TurnMeasurements, orient: ImuOrientation, ext: Extrinsic, z_max: float,
                    pooled: TurnTimeOffset | None = None, **fit_kw
                    ) -> tuple[int, float, TurnTimeOffset] | None:
    """(cluster, z, the others' fit) for the cluster of ``tm`` furthest from the pooled fit
    (``pooled``, else fitted here) in its own and the pool's sigma, when its own offset lies
    more than ``z_max`` from the others' fit: z = |δ_c − δ_rest| / hypot(σ_c, σ_rest), all as
    :func:`_fit_turns_once` gives them with ``fit_kw`` (a cluster alone: "joint"). None when
    it does not, or when fewer than 3 clusters have an offset of their own (two that disagree
    cannot tell which is off). Costs a fit of each cluster alone (a few pairs each) and one of
    all but the suspect."""
    if pooled is None:
        pooled = _fit_turns_once(tm, orient, ext, **fit_kw)
    if not (np.isfinite(pooled.sigma_ms) and pooled.sigma_ms > 0):
        return None
    own = {}
    for q in np.unique(tm.cluster):
        sel = tm.cluster == q
        if int(sel.sum()) >= 4:
            r = _fit_turns_once(tm.subset(sel), orient, ext, **{**fit_kw, "combine": "joint"})
            if np.isfinite(r.sigma_ms) and r.sigma_ms > 0:
                own[int(q)] = r
    if len(own) < 3:
        return None

    def dev(r: TurnTimeOffset, other: TurnTimeOffset) -> float:
        return abs(r.offset_ns - other.offset_ns) * 1e-6 / float(np.hypot(r.sigma_ms,
                                                                         other.sigma_ms))

    q = max(own, key=lambda c: dev(own[c], pooled))
    rest = _fit_turns_once(tm.subset(tm.cluster != q), orient, ext, **fit_kw)
    if not (np.isfinite(rest.sigma_ms) and rest.sigma_ms > 0):
        return None
    z = dev(own[q], rest)
    return (q, float(z), rest) if z > z_max else None


def _fit_turns_once(tm: TurnMeasurements, orient: ImuOrientation, ext: Extrinsic, *,
                    sigma_inflation: float = 2.0, combine: str = "joint",
                    carry_mount: bool = False, carry_floor_ms: float = 0.0,
                    anchor_smooth_s: float = 0.0) -> TurnTimeOffset:
    """The offset from the registered pairs (:func:`_turn_offset_pass`). ``combine``:
    "joint": stations' and carries' rows in one least-squares fit (each kind weighed by its
    robust scale); "split": each kind fitted alone (:func:`_fit_turn_rows`), then joined by
    inverse variance with the carries' sigma floored at ``carry_floor_ms`` (their pairs share
    the mount's and the carry's errors, which their scatter does not show) and both inflated
    by the Birge ratio when the two disagree by more than their sigmas allow. ``carry_mount``:
    the carries' rows also fit a small correction of the mount rotation (the hand-eye
    equation's: a mount error turns a carried pair's rotation by (I − Pᵀ)ε, which otherwise
    leaks into the offset). ``anchor_smooth_s`` > 0: the prediction keeps the IMU samples'
    noise where the sweeps were de-skewed (``orient``'s offset, as measured) and moves with the
    offset by the track smoothed over that span (:func:`_predicted_turns`); 0: slerped from the
    samples at each offset tried, which draws the fit toward ``orient``'s offset."""
    off0 = orient.time_offset_ns
    if len(tm.meas) < 4:
        return TurnTimeOffset(off0, float("inf"), len(tm.meas), 0.0)
    if combine == "joint":
        res = _fit_turn_rows(tm, orient, ext, carry_mount, anchor_smooth_s)
        return TurnTimeOffset(res.offset_ns, res.sigma_ms * sigma_inflation, res.pairs,
                              res.rate_change_deg_s, res.carry_pairs)
    if combine != "split":
        raise ValueError(f"unknown combine {combine!r}")
    fits = {}
    for kind in (False, True):
        sel = tm.is_carry == kind
        if sel.sum() >= 4:
            r = _fit_turn_rows(tm.subset(sel), orient, ext, carry_mount, anchor_smooth_s)
            if np.isfinite(r.sigma_ms) and r.sigma_ms > 0:
                fits[kind] = r
    if not fits:
        return TurnTimeOffset(off0, float("inf"), len(tm.meas), 0.0)
    est = {k: (r.offset_ns * 1e-6, r.sigma_ms) for k, r in fits.items()}
    off_ms, sig = _join_kinds(est.get(False), est.get(True), carry_floor_ms)
    n = sum(r.pairs for r in fits.values())
    rc = float(np.sqrt(sum(r.pairs * r.rate_change_deg_s**2 for r in fits.values())
                       / max(n, 1)))
    return TurnTimeOffset(int(round(off_ms * 1e6)), sig * sigma_inflation, n, rc,
                          sum(r.carry_pairs for r in fits.values()))


def _join_kinds(stations: tuple[float, float] | None, carries: tuple[float, float] | None,
                carry_floor_ms: float = 0.0) -> tuple[float, float]:
    """(offset, sigma) [ms] of the stations' and the carries' (offset, sigma) [ms] (either
    None): the carries' sigma floored at ``carry_floor_ms`` (added in quadrature: their pairs
    share the mount's error and the carry's, which their scatter does not show), then the
    inverse-variance mean, its sigma grown by the Birge ratio when the two are further apart
    than their sigmas allow. The floor weighs the carries against the stations: the carries
    alone keep their own sigma (as the joint fit gave them: a floored one would often miss
    ``max_turns_time_offset_sigma_ms``, and the surfaces' fit weighs it as a prior anyway)."""
    if stations is None or carries is None:
        only = stations if carries is None else carries
        return float(only[0]), float(only[1])
    parts = [stations, (carries[0], float(np.hypot(carries[1], carry_floor_ms)))]
    o = np.array([p[0] for p in parts])
    w = 1.0 / np.array([p[1] for p in parts]) ** 2
    mean = float(np.sum(w * o) / np.sum(w))
    chi2 = float(np.sum(w * (o - mean) ** 2))  # 1 degree of freedom with both kinds
    return mean, float(max(1.0, np.sqrt(chi2)) / np.sqrt(np.sum(w)))


def _mount_jacobian(orient: ImuOrientation, ext: Extrinsic, tk: int, tj: int,
                    P: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """d(rotvec(Pᵀ A))/dε (3x3) for a small mount correction R_imu_lidar·exp(ε): numerically,
    the predicted relative rotation P moved by each small turn of the mount."""
    from scipy.spatial.transform import Rotation

    from .placement import pose_world_lidar

    J = np.zeros((3, 3))
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        ext_i = Extrinsic(ext.R_imu_lidar @ Rotation.from_rotvec(e).as_matrix(),
                          ext.lever_arm_m, ext.source)
        T = pose_world_lidar(orient, ext_i, np.array([tk, tj], dtype=np.int64))
        P_i = (np.linalg.inv(T[0]) @ T[1])[:3, :3]
        # the true A is P_i (the mount truly turned by ε): the residual rotvec(Pᵀ A) it makes
        J[:, i] = Rotation.from_matrix(P.T @ P_i).as_rotvec() / h
    return J


def _predicted_turns(meas: list, orient: ImuOrientation, ext: Extrinsic,
                     anchor_smooth_s: float = 0.0):
    """predict(offset_ns) -> (M, 3, 3): each pair's relative rotation R_k^T R_j (lidar frames at
    its two sweeps' middles) as the IMU predicts it at that offset.

    ``anchor_smooth_s`` 0: the attitudes slerped from the samples at that offset. Each sweep,
    though, was de-skewed to the attitude slerped at its middle at ``orient``'s offset, so its
    registration carries that attitude's white noise (0.05° a sample per axis, ~70 mdeg on a
    pair against 10-30 mdeg for 1 ms of offset), and the prediction cancels it only at that
    same offset: the fit is drawn toward the offset the sweeps were de-skewed at (on dev seed
    171, de-skewed 5.3 ms off, the turns' estimate moved 1-2 ms that way). With
    ``anchor_smooth_s`` > 0 the prediction keeps the samples' noise of ``orient``'s offset and
    only the change with the offset comes from the track smoothed over that span
    (:meth:`ImuOrientation.smoothed`): R_k(δ) = R̂_k(δ₀) · S_k(δ₀)ᵀ S_k(δ)."""
    from .placement import pose_world_lidar

    t = np.array([[m[0], m[1]] for m in meas], dtype=np.int64).reshape(-1)
    n = len(meas)

    def rotations(o: ImuOrientation) -> np.ndarray:
        return pose_world_lidar(o, ext, t)[:, :3, :3].reshape(n, 2, 3, 3)

    if anchor_smooth_s > 0:
        R0 = rotations(orient)
        smooth = orient.smoothed(anchor_smooth_s)
        S0 = rotations(smooth)

    def predict(off: int) -> np.ndarray:
        if anchor_smooth_s > 0:
            S = rotations(smooth.with_offset(off))
            R = R0 @ np.swapaxes(S0, -1, -2) @ S  # R̂(δ₀) · (S(δ₀)ᵀ S(δ))
        else:
            R = rotations(orient.with_offset(off))
        return np.swapaxes(R[:, 0], -1, -2) @ R[:, 1]

    return predict


def _fit_turn_rows(tm: TurnMeasurements, orient: ImuOrientation, ext: Extrinsic,
                   carry_mount: bool = False, anchor_smooth_s: float = 0.0) -> TurnTimeOffset:
    """The least-squares fit of :func:`_turn_offset_pass` over ``tm``'s pairs (sigma not yet
    inflated): δ, the IMU's yaw drift and, with ``carry_mount``, a small mount correction in
    the carries' rows; outliers trimmed, each kind weighed by its robust scale.
    ``anchor_smooth_s`` > 0: the prediction at an offset keeps the samples' noise where the
    sweeps were de-skewed (``orient``'s offset) and moves by the track smoothed over that span
    (:func:`_predicted_turns`)."""
    from scipy.spatial.transform import Rotation

    from .placement import pose_world_lidar

    meas, is_carry, a_l = tm.meas, tm.is_carry, tm.a_lidar
    off0 = orient.time_offset_ns
    h_ns = 2_000_000
    if len(meas) < 4:
        return TurnTimeOffset(off0, float("inf"), len(meas), 0.0)

    def rel(o: ImuOrientation, tk: int, tj: int) -> np.ndarray:
        T = pose_world_lidar(o, ext, np.array([tk, tj], dtype=np.int64))
        return np.linalg.inv(T[0]) @ T[1]

    predict = _predicted_turns(meas, orient, ext, anchor_smooth_s)

    # rows: a station's pair gives its angle about the pan axis, a carry's all three; each row
    # knows its pair, cluster (station or carry) and kind
    row_pair = np.concatenate([np.full(3 if c else 1, m) for m, c in enumerate(is_carry)])
    cl_of = tm.cluster[row_pair]
    row_carry = is_carry[row_pair]
    # the mount's correction needs carried pairs enough to see it (it is three more unknowns)
    fit_mount = bool(carry_mount and int(is_carry.sum()) >= 6)
    dt_s = np.array([(m[1] - m[0]) * 1e-9 for m in meas])  # [s] between the sweeps
    z_j = np.zeros((len(meas), 3))  # the world's vertical in the later sweep's lidar frame
    if is_carry.any():
        t_j = np.array([m[1] for m in meas], dtype=np.int64)
        z_j = pose_world_lidar(orient, ext, t_j)[:, 2, :3]
    drift = np.concatenate([(meas[m][4] @ z_j[m] if c else np.full(1, meas[m][4])) * dt_s[m]
                            for m, c in enumerate(is_carry)])
    keep = np.ones(len(meas), dtype=bool)
    w_row = np.ones(len(row_pair))  # a carry row's weight: the stations' scale over its own
    off = off0
    sig = float("inf")
    for it in range(4):
        o = orient.with_offset(off)
        P_all, Ph_all = predict(off), predict(off + h_ns)
        r_parts, g_parts, m_parts = [], [], []
        for m, (tk, tj, A, _, W) in enumerate(meas):
            P = P_all[m]
            rv = Rotation.from_matrix(P.T @ A[:3, :3]).as_rotvec()
            gv = Rotation.from_matrix(P.T @ Ph_all[m]).as_rotvec() / (h_ns * 1e-9)
            Jm = (_mount_jacobian(o, ext, tk, tj, rel(o, tk, tj)[:3, :3])
                  if fit_mount and is_carry[m] else None)
            if is_carry[m]:
                r_parts.append(W @ rv)
                g_parts.append(W @ gv)
                if fit_mount:
                    m_parts.append(W @ Jm)
            else:
                r_parts.append([W * (a_l @ rv)])
                g_parts.append([W * (a_l @ gv)])
                if fit_mount:
                    m_parts.append(np.zeros((1, 3)))  # a turn about the pan axis: blind to it
        r_ = np.concatenate(r_parts)
        g_ = np.concatenate(g_parts)
        # r = g·δ + drift·c (+ J·ε): δ the offset's correction [s], c the IMU's yaw drift
        # [rad/s], ε the mount's correction [rad]
        cols = [g_, drift]
        X = np.column_stack(cols + ([np.concatenate(m_parts)] if fit_mount else []))
        rk = keep[row_pair]
        n = int(rk.sum())
        Xk, wk = X[rk], w_row[rk]
        H = Xk.T @ (Xk * wk[:, None])
        if not np.all(np.isfinite(H)) or H[0, 0] <= 0:
            break
        if fit_mount and (int((keep & is_carry).sum()) < 6 or np.linalg.cond(H) > 1e12):
            X = X[:, :2]  # too few carried pairs for the mount: δ and the drift
            Xk = X[rk]
            H = Xk.T @ (Xk * wk[:, None])
        if n < 6 or np.linalg.cond(H) > 1e12:
            X = X[:, :1]  # too few pairs for the drift: δ alone
            Xk = X[rk]
            H = Xk.T @ (Xk * wk[:, None])
        sol = np.linalg.solve(H, Xk.T @ (wk * r_[rk]))
        e = r_ - X @ sol
        d = float(sol[0])
        dof = max(n - X.shape[1], 1)
        s_res = float(np.sqrt(np.sum(wk * e[rk] ** 2) / dof))
        Hi = np.linalg.inv(H)
        sig = float(np.sqrt(Hi[0, 0])) * s_res * 1e3 if n >= 3 else float("inf")
        # pairs of one station (or carry) share its errors (its pan axis, its view): the
        # cluster-robust (sandwich) variance over them, when there are enough, bounds sigma below
        groups = np.unique(cl_of[rk])
        if len(groups) >= 3:
            we = w_row * e
            U = np.array([X[rk & (cl_of == q)].T @ we[rk & (cl_of == q)] for q in groups])
            V = Hi @ (U.T @ U) @ Hi * len(groups) / (len(groups) - 1)
            sig = max(sig, float(np.sqrt(max(V[0, 0], 0.0))) * 1e3)
        off = int(round(off + np.clip(d, -0.05, 0.05) * 1e9))
        # each kind's robust scale (a station's rows in radians, a carry's whitened); the
        # 0.005° floor matters for the stations' only
        scales = {}
        for kind in (False, True):
            sel = rk & (row_carry == kind)
            if sel.any():
                scales[kind] = 1.4826 * float(np.median(np.abs(e[sel]))) + np.radians(0.005)
        scale_row = np.where(row_carry, scales.get(True, np.inf), scales.get(False, np.inf))
        bad = np.zeros(len(meas), dtype=bool)
        np.logical_or.at(bad, row_pair, ~(np.abs(e) < 3.0 * scale_row))
        new_keep = ~bad  # a pair is trimmed when any of its rows is an outlier
        if new_keep.sum() >= 4:
            keep = new_keep
        if len(scales) == 2:
            w_row = np.where(row_carry, (scales[False] / scales[True]) ** 2, 1.0)
    rc = float(np.sqrt(np.mean([m[3] ** 2 for m, k in zip(meas, keep) if k])))
    return TurnTimeOffset(off, sig, int(keep.sum()), rc, int((keep & is_carry).sum()))
