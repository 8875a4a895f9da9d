# SPDX-License-Identifier: BSD-3-Clause
"""IMU placement of lidar points: clock alignment, orientation slerp at each point's firing time,
the lidar–IMU extrinsic and time offset, and de-skewed fragments.

Frames and model
----------------
``world``  z up along gravity (the IMU's reference; its yaw drifts without a magnetometer)
``imu``    the IMU body, rigidly on the tripod head
``lidar``  the sensor frame velodyne-decoder decodes into

Within a station the head turns about a fixed pivot c, so the lidar's pose at time t is::

    R_world_lidar(t) = R_world_imu(t) · R_imu_lidar
    p_world_lidar(t) = c + R_world_imu(t) · ℓ          (ℓ: lever arm pivot → lidar, IMU frame)

A station's fragment is expressed in the lidar frame at its middle time t_m, where c cancels::

    x_frag = R_world_lidar(t_m)ᵀ · ( R_world_imu(t)·(R_imu_lidar·x + ℓ) − R_world_imu(t_m)·ℓ )

where R_world_imu(t_m), the station's *anchor*, is fitted over all of the station's IMU samples
(:func:`station_anchor_rotation`) rather than slerped between two: one sample's white noise
would turn the whole station.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .inputs import ImuTrack, LidarPackets


# ---- clocks ----------------------------------------------------------------------------------
def host_to_lidar_offset_ns(lidar: LidarPackets) -> int:
    """Offset host_realtime − lidar time of the packets' arrival, taken at the latency floor.

    Packets arrive with the network/driver latency on top of the fixed clock offset; the 1st
    percentile of (host − lidar) is the offset plus the smallest latency, robust to bursts.
    """
    d = lidar.host_ns - lidar.lidar_ns
    return int(np.percentile(d, 1.0))


@dataclass(frozen=True)
class ClockMap:
    """host_realtime → lidar time: lidar = lidar_ref + (host − host_ref − latency) / rate.

    ``rate`` is the host clock's speed against the lidar's (1 for live data up to ppm drift;
    a replay at 4x into the daemon gives 4). ``latency_ns`` is the receive latency floor.
    """

    host_ref_ns: int
    lidar_ref_ns: int
    rate: float = 1.0
    latency_ns: int = 0

    def to_lidar(self, host_ns: np.ndarray) -> np.ndarray:
        h = np.asarray(host_ns, dtype=np.int64) - self.host_ref_ns - self.latency_ns
        return self.lidar_ref_ns + np.round(h / self.rate).astype(np.int64)

    @property
    def host_minus_lidar_ns(self) -> int:
        return int(self.host_ref_ns + self.latency_ns - self.lidar_ref_ns)


def fit_clock_map(lidar: LidarPackets) -> ClockMap:
    """Fit the host clock against the lidar's from the packets' two stamps.

    The rate is a least-squares slope (robust to the latency's jitter over a recording of many
    seconds); the latency floor is the 1st percentile of the residuals, as for a constant offset.
    """
    h0, l0 = int(lidar.host_ns[0]), int(lidar.lidar_ns[0])
    x = (lidar.lidar_ns - l0).astype(np.float64)
    y = (lidar.host_ns - h0).astype(np.float64)
    rate = 1.0
    if len(x) > 100 and x[-1] - x[0] > 1e9:
        rate = float(np.polyfit(x, y, 1)[0])
        if abs(rate - 1.0) < 1e-3:  # crystal drift only: keep the offset model exact
            rate = 1.0
    lat = int(np.percentile(y - rate * x, 1.0))
    return ClockMap(h0, l0, rate, lat)


def dejitter_periodic(host_ns: np.ndarray, max_gap_s: float = 0.5) -> np.ndarray:
    """Stamps of a periodic sensor without the host's read jitter.

    An IMU reports at a fixed rate of its own oscillator, but each sample is stamped when the
    host happens to read it (serial buffering, scheduling, several samples per read: jitter of
    milliseconds). Within each run (split where nothing came for ``max_gap_s``, e.g. a replug),
    sample k is fitted as t0 + k·P by least squares and put at the latency floor (1st percentile
    of the residuals): the jitter goes, the smallest latency stays.

    When the residuals spread over more than 5 periods, either the host stalled (samples read
    late, in a burst: only positive delays) or samples were lost (every later sample then looks
    a period *early*). The run is then fitted to its lower envelope; if no sample lies more than
    half a period before that line, the stall is removed the same way, otherwise samples were
    lost and the raw stamps are kept.
    """
    t = np.asarray(host_ns, dtype=np.int64)
    out = t.astype(np.float64).copy()
    breaks = np.flatnonzero(np.diff(t) > max_gap_s * 1e9) + 1
    start = 0
    for end in list(breaks) + [len(t)]:
        n = end - start
        if n >= 50:
            k = np.arange(n, dtype=np.float64)
            y = (t[start:end] - t[start]).astype(np.float64)
            P, c = np.polyfit(k, y, 1)
            r = y - (P * k + c)
            if P > 0 and np.percentile(r, 99) - np.percentile(r, 1) < 5 * P:
                out[start:end] = t[start] + c + np.percentile(r, 1.0) + P * k
            else:
                fit = _lower_envelope_fit(k, y)
                if fit is not None:
                    out[start:end] = t[start] + fit[1] + fit[0] * k
        start = end
    out = np.round(out).astype(np.int64)
    # strictly increasing for interpolation (raw stamps may repeat: several samples per read)
    return _strictly_increasing(out)


def _lower_envelope_fit(k: np.ndarray, y: np.ndarray) -> tuple[float, float] | None:
    """Line P·k + c under the stamps y [ns] of sample indices k, fitted to the least-delayed
    samples; None when some sample comes too early for it (a lost sample shifts the indices)."""
    keep = np.ones(len(k), dtype=bool)
    for _ in range(6):  # refit on the least-delayed fifth of the samples
        P, c = np.polyfit(k[keep], y[keep], 1)
        r = y - (P * k + c)
        keep = r <= np.percentile(r, 20)
        if keep.sum() < 10:
            return None
    floor = np.percentile(r, 1.0)
    if P <= 0 or np.mean(r < floor - 0.5 * P) > 0.002:
        return None
    # a lost sample moves the envelope by a period from there on: the least delay of each
    # stretch of 25 samples must stay on one line (a stall lifts only a few stretches)
    m = len(r) // 25
    if m >= 4:
        lows = r[: m * 25].reshape(m, 25).min(axis=1)
        if np.percentile(lows, 90) - np.percentile(lows, 10) > 0.5 * P:
            return None
    return float(P), float(c + floor)


def _strictly_increasing(t: np.ndarray) -> np.ndarray:
    out = t.copy()
    for k in range(1, len(out)):
        if out[k] <= out[k - 1]:
            out[k] = out[k - 1] + 1
    return out


@dataclass
class Extrinsic:
    """Mounting of the lidar on the head: R_imu_lidar (3, 3) and lever arm ℓ (3,) [m] in the IMU
    frame from the head's pivot to the lidar origin."""

    R_imu_lidar: np.ndarray
    lever_arm_m: np.ndarray
    source: str = "config"  # config | calibrated | default

    @classmethod
    def identity(cls) -> "Extrinsic":
        return cls(np.eye(3), np.zeros(3), "default")

    @classmethod
    def from_config(cls, q_wxyz, lever) -> "Extrinsic":
        R = np.eye(3) if q_wxyz is None else Rotation.from_quat(
            [q_wxyz[1], q_wxyz[2], q_wxyz[3], q_wxyz[0]]).as_matrix()
        ell = np.zeros(3) if lever is None else np.asarray(lever, dtype=np.float64)
        return cls(R, ell, "config")

    @property
    def q_imu_lidar_wxyz(self) -> list[float]:
        x, y, z, w = Rotation.from_matrix(self.R_imu_lidar).as_quat()
        return [float(w), float(x), float(y), float(z)]


def _one_hemisphere(q_wxyz: np.ndarray) -> np.ndarray:
    """A copy of the attitude track (K, 4) with each quaternion's sign chosen on its
    predecessor's hemisphere, so neighbours slerp (and smooth) the short way."""
    q = np.array(q_wxyz)  # a copy, its dtype kept
    for k in range(1, len(q)):
        if np.dot(q[k], q[k - 1]) < 0:
            q[k] = -q[k]
    return q


def smooth_quaternions(t_ns: np.ndarray, q_wxyz: np.ndarray, span_s: float) -> np.ndarray:
    """Zero-phase smoothing of an attitude track (K, 4) w, x, y, z (one hemisphere along the
    track) sampled at ``t_ns`` (K,) [ns, non-decreasing]: at each sample, the rotation vectors
    of its neighbours within ±span_s/2 relative to it are fitted by a quadratic in time (a
    Savitzky–Golay filter on the manifold) and the fit's value at the sample is taken. A
    symmetric window adds no lag (an IMU time offset estimated on the result is unbiased) and a
    quadratic keeps a steadily changing turn rate (ramps, a hand's speed changes); white noise
    per sample drops by √(0.21) at 11 samples. Samples with fewer than 5 neighbours in the
    window (ends, gaps) are kept as they are."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q_wxyz, dtype=np.float64)
    K = len(q)
    if K < 5 or span_s <= 0:
        return q.copy()
    t = np.asarray(t_ns, dtype=np.int64)
    dt_med = float(np.median(np.diff(t))) if K > 1 else 0.0
    h = int(np.ceil(0.5 * span_s * 1e9 / max(dt_med, 1.0)))
    if h < 1:
        return q.copy()
    half = 0.5 * span_s * 1e9 + 0.5 * dt_med
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    Rinv = R.inv()
    S = np.zeros((K, 5))  # Σ w x^k, k = 0..4
    B = np.zeros((K, 3, 3))  # Σ w x^k r, k = 0..2
    for j in range(-h, h + 1):
        idx = np.clip(np.arange(K) + j, 0, K - 1)
        x = (t[idx] - t).astype(np.float64) / half  # [window half-spans]
        w = ((np.arange(K) + j >= 0) & (np.arange(K) + j < K) & (np.abs(x) <= 1.0))
        w = w.astype(np.float64)
        r = (Rinv * R[idx]).as_rotvec() if j else np.zeros((K, 3))
        xp = np.ones(K)
        for k in range(5):
            S[:, k] += w * xp
            if k < 3:
                B[:, k] += (w * xp)[:, None] * r
            xp = xp * x
    A = np.stack([S[:, 0:3], S[:, 1:4], S[:, 2:5]], axis=1)  # (K, 3, 3) normal matrix
    ok = S[:, 0] >= 5
    ok &= np.abs(np.linalg.det(A)) > 1e-30
    out = q.copy()
    if not ok.any():
        return out
    coef = np.linalg.solve(A[ok], B[ok])  # (n, 3, 3): rows = polynomial terms
    corr = Rotation.from_rotvec(coef[:, 0, :])
    qs = (R[ok] * corr).as_quat()[:, [3, 0, 1, 2]]
    qs *= np.sign(np.einsum("ij,ij->i", qs, q[ok]))[:, None]
    out[ok] = qs
    return out


class ImuOrientation:
    """q_world_imu on the lidar time line, interpolated by slerp.

    Parameters
    ----------
    imu : ImuTrack
    host_minus_lidar_ns : int or ClockMap
        A constant offset (:func:`host_to_lidar_offset_ns`) or a fitted :func:`fit_clock_map`.
    time_offset_ns : int
        IMU latency correction added after the clock mapping (estimated or configured).
    smooth_s : float
        Span [s] of the zero-phase smoothing of the samples (:func:`smooth_quaternions`; 0:
        the raw samples). An IMU's fused attitude carries white noise per sample (0.05° per
        axis on the IMU Brick 2.0); a station's fragment is anchored on the attitude at one
        moment, so that noise turns the whole station.
    """

    def __init__(self, imu: ImuTrack, host_minus_lidar_ns: "int | ClockMap",
                 time_offset_ns: int = 0, smooth_s: float = 0.0):
        self.imu = imu
        if isinstance(host_minus_lidar_ns, ClockMap):
            clock = host_minus_lidar_ns
        else:
            clock = ClockMap(0, -int(host_minus_lidar_ns))
        self.clock = clock
        self.host_minus_lidar_ns = clock.host_minus_lidar_ns
        self.time_offset_ns = int(time_offset_ns)
        q = _one_hemisphere(imu.q_wxyz)
        self._base_t = clock.to_lidar(dejitter_periodic(imu.host_ns))
        self.smooth_s = float(smooth_s)
        self._q = smooth_quaternions(self._base_t, q, smooth_s) if smooth_s > 0 else q

    @property
    def t_ns(self) -> np.ndarray:
        """Sample times on the lidar time line [ns] (read-only; computed once per offset)."""
        cached = getattr(self, "_t_cache", None)
        if cached is None or cached[0] != self.time_offset_ns:
            t = self._base_t + self.time_offset_ns
            t.setflags(write=False)
            cached = self._t_cache = (self.time_offset_ns, t)
        return cached[1]

    def with_offset(self, time_offset_ns: int) -> "ImuOrientation":
        o = ImuOrientation.__new__(ImuOrientation)
        o.imu, o.clock, o.host_minus_lidar_ns, o._q, o._base_t, o.smooth_s = (
            self.imu, self.clock, self.host_minus_lidar_ns, self._q, self._base_t,
            self.smooth_s)
        o.time_offset_ns = int(time_offset_ns)
        if hasattr(self, "_slerp_cache"):
            o._slerp_cache = self._slerp_cache
        o._smoothed_cache = self._smoothed_tracks()
        return o

    def _smoothed_tracks(self) -> dict:
        """span [s] -> smoothed quaternions (K, 4), shared by ``with_offset`` copies."""
        if not hasattr(self, "_smoothed_cache"):
            self._smoothed_cache = {}
        return self._smoothed_cache

    def smoothed(self, span_s: float) -> "ImuOrientation":
        """This track at the same offset with the raw samples smoothed over ``span_s``
        (:func:`smooth_quaternions`, zero-phase), computed once per track and span (the
        ``with_offset`` copies share it): a low-noise attitude for what changes with the
        offset, where the samples' own noise must stay put (:func:`calibration.fit_turn_offset`
        with ``anchor_smooth_s``)."""
        cache = self._smoothed_tracks()
        key = round(float(span_s), 6)
        if key not in cache:
            q = _one_hemisphere(self.imu.q_wxyz)
            cache[key] = smooth_quaternions(self._base_t, q, span_s) if span_s > 0 else q
        o = ImuOrientation.__new__(ImuOrientation)
        o.imu, o.clock, o.host_minus_lidar_ns, o._base_t = (
            self.imu, self.clock, self.host_minus_lidar_ns, self._base_t)
        o._q, o.smooth_s, o.time_offset_ns = cache[key], float(span_s), self.time_offset_ns
        o._smoothed_cache = cache
        return o

    def _slerp_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per interval k of the samples (k, k+1): (its length [ns] as float64, at least 1;
        the angle θ_k between the two quaternions [rad]; sin θ_k, 1 where tiny; tiny: sin θ_k
        < 1e-9). Computed once per track (``with_offset`` copies share it): the slerp's
        per-interval terms, gathered per point by :meth:`quat_at`, are the same numbers as
        when computed per point."""
        cached = getattr(self, "_slerp_cache", None)
        if cached is None or cached[0] is not self._q:
            q = self._q
            if len(q) >= 2:
                a, b, dt = q[:-1], q[1:], np.diff(self._base_t).astype(np.float64)
            else:  # one sample: the one interval from it to itself
                a, b, dt = q[:1], q[:1], np.zeros(1)
            dt = np.maximum(dt, 1.0)
            theta = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))
            s = np.sin(theta)
            small = s < 1e-9
            cached = self._slerp_cache = (q, (dt, theta, np.where(small, 1.0, s), small))
        return cached[1]

    def quat_at(self, t_ns: np.ndarray) -> np.ndarray:
        """Slerp of q_world_imu at lidar times ``t_ns`` (N,) → (N, 4) w, x, y, z; clamped at ends."""
        t = np.asarray(t_ns, dtype=np.int64)
        ts = self.t_ns
        i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
        dt_k, theta_k, s_k, small_k = self._slerp_table()
        u = np.clip((t - ts[i]).astype(np.float64) / dt_k[i], 0.0, 1.0)
        q0, q1 = self._q[i], self._q[i + 1]
        theta, s, small = theta_k[i], s_k[i], small_k[i]
        w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / s)
        w1 = np.where(small, u, np.sin(u * theta) / s)
        q = w0[:, None] * q0 + w1[:, None] * q1
        # |q| as np.linalg.norm(q, axis=1) sums it (w² + x², + y², + z², in that order: the
        # same to the bit), without its (N, 4) temporaries: 2.5x cheaper
        n2 = q[:, 0] * q[:, 0]
        for c in (1, 2, 3):
            n2 += q[:, c] * q[:, c]
        return q / np.sqrt(n2)[:, None]

    def rotation_at(self, t_ns: np.ndarray) -> np.ndarray:
        """R_world_imu at lidar times ``t_ns`` (N,) → (N, 3, 3)."""
        q = self.quat_at(t_ns)
        return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()

    def angular_rate(self, t_ns: np.ndarray, dt_ns: int = 50_000_000) -> np.ndarray:
        """Rotation rate magnitude [rad/s] at ``t_ns`` from a central difference over dt_ns."""
        t = np.asarray(t_ns, dtype=np.int64)
        Ra = Rotation.from_quat(self.quat_at(t - dt_ns // 2)[:, [1, 2, 3, 0]])
        Rb = Rotation.from_quat(self.quat_at(t + dt_ns // 2)[:, [1, 2, 3, 0]])
        return (Ra.inv() * Rb).magnitude() / (dt_ns * 1e-9)


def station_anchor_rotation(orient: ImuOrientation, start_ns: int, end_ns: int, anchor_ns: int,
                            spans_s: tuple[float, ...] = (1.0, 0.5, 0.25),
                            max_deviation_deg: float = 0.3,
                            info: dict | None = None) -> np.ndarray:
    """R_world_imu (3, 3) at ``anchor_ns`` fitted over the IMU samples of a station [start_ns,
    end_ns) instead of slerped from the two samples around it.

    A station's fragment is expressed in the lidar frame at one moment; the IMU's white noise
    at that moment (0.05° per axis on the IMU Brick 2.0) would turn the whole station. While
    the tripod stands, the head only turns about its pan axis, fixed both in the IMU (a_i) and
    in the world (a_w): R_k = Exp(φ_k·a_w)·R_m for every sample k. So

    1. a_i is the dominant axis of the turns between samples 1 s apart (eigenvector of
       Σ v vᵀ, v = log(R_kᵀ R_{k+s})), and a_w the mean of R_k·a_i over *all* the station's
       samples: the tilt of the anchor (2 of its 3 angles, gravity in particular) is averaged
       over the whole station;
    2. the pan angle φ_k of each sample (a direction across a_i, seen in the plane across a_w)
       is fitted by a quadratic in time over a window centred on the anchor (the longest of
       ``spans_s`` that the station holds on both sides) whose residuals are the samples' own
       white noise: their RMS within 1.3 σ (2 σ for the shortest span) and their lag-1
       autocorrelation within 3/√n (a
       hand's speed change or a reversal near the anchor leaves a smooth, correlated misfit
       and takes a shorter span). σ is the smaller of two estimates: from the pan angle's
       second differences (which a hand's jerks inflate) and from the tilt's scatter about a_w
       (which a swaying tripod inflates; the noise is the same on every axis). With no span
       passing, φ(anchor) is the slerped sample's pan angle; else the fit's value there.

    R_m maps the IMU frame (u_i, a_i×u_i, a_i) onto the world's (u(φ), a_w×u(φ), a_w). A head
    that does not turn fits too (a_i is then arbitrary and R_k·a_i constant).

    **Guard**: the fitted attitude must stay within ``max_deviation_deg`` of the slerped one
    (the slerped sample's noise is 0.05° per axis: 0.3° is 6 σ); else the model does not hold
    (the station's edge carries a part of the walk, the head wobbles on its axis) and the
    slerped attitude is returned. It is also returned with fewer than 10 samples.

    ``info``: when given, filled with ``outcome`` ("fit", "fit, pan slerped" or why the slerped
    attitude was kept: "few samples", "off by X°"), ``deviation_deg`` (fitted vs slerped) and
    ``sigma_deg`` (the per-axis noise estimate).
    """
    info = {} if info is None else info
    R_slerp = orient.rotation_at(np.array([int(anchor_ns)]))[0]
    t = orient.t_ns
    i0, i1 = np.searchsorted(t, [int(start_ns), int(end_ns)])
    if i1 - i0 < 10 or not (t[i0] <= anchor_ns <= t[i1 - 1]):
        info.update(outcome="few samples", deviation_deg=0.0, sigma_deg=float("nan"))
        return R_slerp
    ts = t[i0:i1]
    R = Rotation.from_quat(orient._q[i0:i1][:, [1, 2, 3, 0]])
    Rm = R.as_matrix()
    # 1. the pan axis in the IMU frame, then in the world
    dt_med = float(np.median(np.diff(ts)))
    s = int(np.clip(round(1e9 / max(dt_med, 1.0)), 1, max(1, len(ts) // 2)))
    v = (R[:-s].inv() * R[s:]).as_rotvec()
    _, V = np.linalg.eigh(v.T @ v)
    a_i = V[:, -1]
    A_w = Rm @ a_i  # (K, 3) the pan axis seen by every sample
    a_w = A_w.mean(axis=0)
    a_w /= np.linalg.norm(a_w)
    # the tilt's scatter about a_w: 2 axes of white noise, a Rayleigh angle (median 1.1774 σ)
    tilt = np.arccos(np.clip(A_w @ a_w, -1.0, 1.0))
    sigma_tilt = float(np.median(tilt)) / 1.1774
    # 2. pan angles about a_w of a direction across a_i
    u_i = np.cross(a_i, [1.0, 0.0, 0.0] if abs(a_i[0]) < 0.9 else [0.0, 1.0, 0.0])
    u_i /= np.linalg.norm(u_i)
    e1 = np.cross(a_w, [1.0, 0.0, 0.0] if abs(a_w[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a_w, e1)
    d = Rm @ u_i
    phi = np.unwrap(np.arctan2(d @ e2, d @ e1))
    x = (ts - int(anchor_ns)).astype(np.float64) * 1e-9  # [s]
    # the samples' own noise: second differences (a steady turn's rate changes far less in
    # 10 ms; a hand's jerk does not) and the tilt's scatter
    dd = np.diff(phi, 2)
    sigma_dd = 1.4826 * float(np.median(np.abs(dd - np.median(dd)))) / np.sqrt(6.0)
    sigma = min(sigma_dd, sigma_tilt) + 1e-12
    half_max = min(-float(x[0]), float(x[-1]))  # a window the station holds on both sides
    phi_m, how = None, "fit"
    for span in spans_s:
        sel = np.abs(x) <= min(0.5 * span, half_max)
        n = int(sel.sum())
        if n < 7:
            continue
        A = np.stack([np.ones(n), x[sel], x[sel] ** 2], axis=1)
        c, *_ = np.linalg.lstsq(A, phi[sel], rcond=None)
        r = phi[sel] - A @ c
        rms = float(np.sqrt(np.mean(r**2)))
        rho1 = float(r[1:] @ r[:-1]) / max(float(r @ r), 1e-30)
        # the shortest span: a mild misfit (within 2 σ) still beats one sample's noise
        k_rms = 2.0 if span == spans_s[-1] else 1.3
        if rms <= k_rms * sigma and rho1 <= 3.0 / np.sqrt(n):
            phi_m = float(c[0])
            break
    if phi_m is None:  # no window fits as white noise: the pan angle where the samples put it
        phi_m, how = float(np.interp(0.0, x, phi)), "fit, pan slerped"
    u_w = np.cos(phi_m) * e1 + np.sin(phi_m) * e2
    B_i = np.stack([u_i, np.cross(a_i, u_i), a_i], axis=1)
    B_w = np.stack([u_w, np.cross(a_w, u_w), a_w], axis=1)
    R_fit = B_w @ B_i.T
    dev = float(np.degrees(Rotation.from_matrix(R_slerp.T @ R_fit).magnitude()))
    info.update(deviation_deg=dev, sigma_deg=float(np.degrees(sigma)))
    if not dev <= max_deviation_deg:
        info["outcome"] = f"off by {dev:.2f}°"
        return R_slerp
    info["outcome"] = how
    return R_fit


def pose_world_lidar(orient: ImuOrientation, ext: Extrinsic, t_ns) -> np.ndarray:
    """T_world_lidar (N, 4, 4) at times t_ns with the head's pivot at the world origin."""
    R_wi = orient.rotation_at(np.atleast_1d(t_ns))
    T = np.tile(np.eye(4), (len(R_wi), 1, 1))
    T[:, :3, :3] = R_wi @ ext.R_imu_lidar
    T[:, :3, 3] = R_wi @ ext.lever_arm_m
    return T


def place_points(xyz: np.ndarray, t_ns: np.ndarray, orient: ImuOrientation, ext: Extrinsic,
                 anchor_ns: int, num_threads: int = 0) -> np.ndarray:
    """De-skew points into the lidar frame at ``anchor_ns`` (see the module's model).

    Runs in the native core (one crossing per call, OpenMP over points).

    Parameters
    ----------
    xyz : (N, 3) float [m], lidar frame at each point's firing time
    t_ns : (N,) int64, firing times on the lidar time line
    anchor_ns : int, the time whose lidar frame the result is expressed in

    Returns
    -------
    (N, 3) float32 [m]
    """
    from .. import _ext
    from ..preprocess import as_cloud

    return _ext.place_points(
        as_cloud(xyz), np.ascontiguousarray(t_ns, dtype=np.int64),
        np.ascontiguousarray(orient.t_ns, dtype=np.int64),
        np.ascontiguousarray(orient._q, dtype=np.float64),
        np.ascontiguousarray(ext.R_imu_lidar, dtype=np.float64),
        np.ascontiguousarray(ext.lever_arm_m, dtype=np.float64), int(anchor_ns), int(num_threads))


def load_extrinsic_file(path) -> tuple[list[float], list[float]]:
    """(q_imu_lidar w,x,y,z, lever arm [m]) from a calibration file.

    Accepted: YAML/JSON with ``q_imu_lidar`` and ``lever_arm_m`` (our convention), or the
    ``gt/calibration.json`` of ``tripod simulate`` (``T_pan_lidar``: the lidar on the head's pan
    frame; ``T_lidar_imu``: the IMU on the lidar), from which R_imu_lidar = R_lidar_imuᵀ and the
    lever arm, pivot → lidar in the IMU frame, is ℓ = R_imu_lidar · R_pan_lidarᵀ · t_pan_lidar.
    """
    import yaml

    with open(path, encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a calibration mapping")
    if "q_imu_lidar" in data:
        return [float(v) for v in data["q_imu_lidar"]], [float(v) for v in
                                                         data.get("lever_arm_m", [0, 0, 0])]
    if "T_pan_lidar" in data and "T_lidar_imu" in data:
        T_pl = np.asarray(data["T_pan_lidar"], dtype=np.float64)
        T_li = np.asarray(data["T_lidar_imu"], dtype=np.float64)
        R_il = T_li[:3, :3].T
        ell = R_il @ T_pl[:3, :3].T @ T_pl[:3, 3]
        x, y, z, w = Rotation.from_matrix(R_il).as_quat()
        return [float(w), float(x), float(y), float(z)], ell.tolist()
    raise ValueError(f"{path}: expected q_imu_lidar/lever_arm_m or T_pan_lidar/T_lidar_imu")
