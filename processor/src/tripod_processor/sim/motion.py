# SPDX-License-Identifier: BSD-3-Clause
"""The tripod acquisition as a continuous, vectorised trajectory.

Frames (all right-handed, metres):

``world``  the scene frame, z up.
``base``   the tripod head: origin on the pan axis at the tilt pivot, z along the pan axis
           (vertical up to the small levelling error), x the heading of the tripod.
           At a station it is static; its pose there is the *station pose* T_world_base.
``pan``    ``base`` turned about its z axis by the pan angle phi(t): T_base_pan = Rz(phi).
``lidar``  the VLP-16 frame exactly as velodyne-decoder outputs points (x at azimuth 0,
           y to the left, z up along the spin axis). T_pan_lidar = translation ``lever_arm_m``
           and rotation Ry(``tilt_deg``): the spin axis is tilted so the 30 deg vertical field
           of view sweeps floor and ceiling as the head pans.
``imu``    rigidly attached to the lidar: T_lidar_imu (small known extrinsic).

Timeline (seconds from the capture start): at every station the head rests ``settle_s``,
pans one full turn plus ``pan_overlap_deg`` in ``pan_s`` (raised-cosine speed ramps), rests
``settle_s`` again; between stations the tripod is carried for ``transit_s`` (longer for long
walks: peak speed ``max_carry_speed_m_s``) along the scene's route (minimum-jerk progress,
sway in roll/pitch/height/sideways, heading change up to ``max_yaw_change_deg``).
The lidar and IMU stream the whole time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import MotionConfig


def rot_x(a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about x by angles ``a`` [rad]."""
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(-1, 3, 3)


def rot_y(a: np.ndarray) -> np.ndarray:
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(-1, 3, 3)


def rot_z(a: np.ndarray) -> np.ndarray:
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(-1, 3, 3)


def rpy_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """3x3 rotation Rz(yaw) Ry(pitch) Rx(roll), angles in degrees."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    return (rot_z(y) @ rot_y(p) @ rot_x(r))[0]


def _smooth_polyline(pts: np.ndarray, closed: bool, cut: float = 0.5, iters: int = 3) -> np.ndarray:
    """Round the corners of a polyline by corner cutting, at most ``cut`` metres from a corner,
    so the carried tripod never turns on the spot (bounded acceleration)."""
    for _ in range(iters):
        n = len(pts)
        if n < 3:
            return pts
        out = [] if closed else [pts[0]]
        rng = range(n) if closed else range(1, n - 1)
        for i in rng:
            p, a, b = pts[i], pts[i - 1], pts[(i + 1) % n]
            da, db = a - p, b - p
            la, lb = np.linalg.norm(da), np.linalg.norm(db)
            ca, cb = min(cut, 0.25 * la), min(cut, 0.25 * lb)
            out += [p + da / max(la, 1e-12) * ca, p + db / max(lb, 1e-12) * cb]
        if not closed:
            out.append(pts[-1])
        pts = np.asarray(out)
        cut *= 0.5
    return pts


class Route:
    """Arc-length parametrised 2D polyline (optionally a loop)."""

    def __init__(self, pts: np.ndarray, closed: bool):
        pts = _smooth_polyline(np.asarray(pts, dtype=np.float64), closed)
        if closed:
            pts = np.vstack([pts, pts[:1]])
        self.pts = pts
        self.closed = closed
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.s[-1])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (N, 2), unit tangents (N, 2)) at arc lengths ``s`` [m]."""
        s = np.asarray(s, dtype=np.float64)
        s = np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)
        i = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.pts) - 2)
        d = self.pts[i + 1] - self.pts[i]
        ln = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        f = ((s - self.s[i]) / ln[:, 0])[:, None]
        return self.pts[i] + f * d, d / ln


@dataclass
class Station:
    index: int
    t_pan_start_s: float  # capture-relative seconds
    t_pan_end_s: float
    position: np.ndarray  # (3,) world, base origin
    yaw_rad: float
    roll_rad: float
    pitch_rad: float
    arc_m: float  # route arc length
    lateral_m: float

    @property
    def R_world_base(self) -> np.ndarray:
        return (rot_z(self.yaw_rad) @ rot_y(self.pitch_rad) @ rot_x(self.roll_rad))[0]


def _min_jerk(u: np.ndarray) -> np.ndarray:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def _ramp_angle(t: np.ndarray, total: float, duration: float, ramp: float) -> np.ndarray:
    """Angle after time t of a move of ``total`` in ``duration`` with raised-cosine speed ramps
    of length ``ramp`` at both ends (continuous speed and acceleration-bounded)."""
    ramp = min(ramp, duration / 2)
    w0 = total / (duration - ramp)  # cruise speed

    def up(tt):  # angle of a ramp-up phase at time tt in [0, ramp]
        return w0 * (tt / 2 - ramp / (2 * np.pi) * np.sin(np.pi * tt / ramp))

    t = np.clip(t, 0.0, duration)
    a = np.where(t < ramp, up(t), up(ramp) + w0 * (t - ramp))
    late = t > duration - ramp
    a = np.where(late, total - up(duration - t), a)
    return a


def _raised_cos(x: np.ndarray) -> np.ndarray:
    """0 -> 1 over x in [0, 1] with zero slope at both ends (clipped outside)."""
    return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0))


@dataclass
class PanPlan:
    """One station's pan, sampled: angle [rad] on a regular grid of ``dt_s`` from the pan start.

    ``pauses_s`` and ``reversals_s`` are (start, end) seconds from the pan start of the
    stretches where the head stands or turns back; ``net_rad`` the net turn.
    """

    dt_s: float
    angle: np.ndarray
    net_rad: float
    pauses_s: list[tuple[float, float]]
    reversals_s: list[tuple[float, float]]
    reversal_rad: float

    def at(self, tau: np.ndarray) -> np.ndarray:
        """Angle [rad] at ``tau`` seconds from the pan start (held outside the pan)."""
        x = np.clip(np.asarray(tau, dtype=np.float64) / self.dt_s, 0.0, len(self.angle) - 1)
        i = np.minimum(x.astype(np.int64), len(self.angle) - 2)
        f = x - i
        return self.angle[i] * (1.0 - f) + self.angle[i + 1] * f


def plan_pan(cfg: MotionConfig, net_rad: float, rng: np.random.Generator,
             dt_s: float = 5e-4) -> PanPlan:
    """A pan of ``net_rad`` in ``cfg.pan_s`` with the profile options of ``cfg``.

    Forward speed = raised-cosine ramps at both ends (``pan_ramp_s``), gaps for the pause and
    the reversal (ramps of min(pan_ramp_s, 0.5 s) into and out of them), times a speed factor
    (hand: levels uniform in 1 +/- ``pan_speed_variation``, changing every 0.5..1.5 x
    ``pan_speed_change_s`` through a min-jerk blend of up to 0.4 s). In the reversal gap the
    speed is -A sin^2 (back by ``pan_reversal_deg``). The forward part is scaled so the net turn
    is exactly ``net_rad``. Speed and its slope are continuous.
    """
    D = cfg.pan_s
    n = int(np.ceil(D / dt_s)) + 1
    tau = np.arange(n) * dt_s
    tau[-1] = min(tau[-1], D)
    r = min(cfg.pan_ramp_s, D / 4)
    rg = min(cfg.pan_ramp_s, 0.5)
    gaps: list[tuple[float, float, str]] = []
    want = []
    if cfg.pan_pause_s > 0:
        want.append(("pause", cfg.pan_pause_s))
    if cfg.pan_reversal_deg > 0:
        want.append(("reversal", cfg.pan_reversal_s))
    order = rng.permutation(len(want)) if want else []
    want = [want[i] for i in order]
    # place the gaps in order, each with its ramps, inside [r, D - r], uniformly spread
    slack = D - 2 * r - sum(w + 2 * rg for _, w in want)
    cuts = np.sort(rng.uniform(0.0, max(slack, 0.0), len(want)))
    t = r
    prev = 0.0
    for (kind, w), c in zip(want, cuts):
        t += c - prev
        prev = c
        gaps.append((t + rg, t + rg + w, kind))
        t += w + 2 * rg
    fwd = _raised_cos(tau / max(r, 1e-9)) * _raised_cos((D - tau) / max(r, 1e-9))
    for a, b, _ in gaps:
        closed = _raised_cos((a - tau) / rg) * (tau <= a) + _raised_cos((tau - b) / rg) * (tau >= b)
        fwd = fwd * closed
    if cfg.pan_profile == "hand":
        v = cfg.pan_speed_variation
        knots = [0.0]
        while knots[-1] < D:
            knots.append(knots[-1] + cfg.pan_speed_change_s * rng.uniform(0.5, 1.5))
        knots = np.asarray(knots)
        level = rng.uniform(1.0 - v, 1.0 + v, len(knots))
        j = np.clip(np.searchsorted(knots, tau, side="right") - 1, 0, len(knots) - 2)
        blend = np.minimum(0.4, 0.5 * (knots[j + 1] - knots[j]))
        u = np.clip((tau - (knots[j + 1] - blend)) / blend, 0.0, 1.0)
        fwd = fwd * (level[j] + (level[j + 1] - level[j]) * _min_jerk(u))
    rev_rad = np.radians(cfg.pan_reversal_deg)
    back = np.zeros(n)
    for a, b, kind in gaps:
        if kind == "reversal":
            inside = (tau >= a) & (tau <= b)
            back[inside] = np.sin(np.pi * (tau[inside] - a) / (b - a)) ** 2
    dtau = np.diff(tau)

    def integral(y: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * dtau)])

    F, B = integral(fwd), integral(back)
    A = rev_rad / B[-1] if B[-1] > 0 else 0.0
    c = (net_rad + rev_rad) / F[-1]
    angle = c * F - A * B
    return PanPlan(dt_s, angle, float(net_rad),
                   [(a, b) for a, b, k in gaps if k == "pause"],
                   [(a, b) for a, b, k in gaps if k == "reversal"], float(rev_rad))


class Trajectory:
    """Continuous pose of every frame of the rig; evaluate at arrays of times.

    Parameters
    ----------
    route_xy : (K, 2) route of the scene [m]
    closed : whether the route is a loop
    n_stations : number of stations
    cfg : MotionConfig
    rng : numpy Generator (stations, headings, sway phases)
    floor_z : height of the floor [m]; tripod heights are above it
    pan_rng : numpy Generator for the pan profiles (only drawn from when ``cfg`` asks for more
        than the original motor pan; default: one seeded from ``rng``'s state is not taken, so
        the stations of a default config never change)
    """

    def __init__(self, route_xy: np.ndarray, closed: bool, n_stations: int, cfg: MotionConfig,
                 rng: np.random.Generator, floor_z: float = 0.0,
                 pan_rng: np.random.Generator | None = None):
        self.cfg = cfg
        self.route = Route(route_xy, closed)
        self.n = n_stations
        L = self.route.length
        n = n_stations
        if closed:
            spacing = L / n if cfg.route_span == 1.0 else cfg.route_span * L / n
            s = rng.uniform(0, L) + spacing * np.arange(n)
        else:
            spacing = L / n if cfg.route_span == 1.0 else cfg.route_span * L / n
            s = spacing * (np.arange(n) + 0.5)
        s = s + rng.uniform(-0.2, 0.2, n) * spacing
        if not closed:
            s = np.clip(s, 0.0, L)
        s = np.maximum.accumulate(s)  # never walk backwards along the route
        lateral = rng.uniform(-1, 1, n) * cfg.station_lateral_jitter_m
        yaw = np.empty(n)
        yaw[0] = rng.uniform(-np.pi, np.pi)
        yaw[1:] = yaw[0] + np.cumsum(rng.uniform(-1, 1, n - 1) * np.radians(cfg.max_yaw_change_deg))
        level = np.radians(cfg.level_error_deg)
        roll, pitch = rng.normal(0, level, n), rng.normal(0, level, n)
        self.floor_z = floor_z
        height = floor_z + rng.uniform(cfg.tripod_height_m[0], cfg.tripod_height_m[1], n)
        # carrying time: at least transit_s, longer when the walk would exceed the peak speed
        # (minimum-jerk progress peaks at 1.875 x the mean speed)
        walk = np.abs(np.diff(s)) if n > 1 else np.zeros(0)
        self.transit_s = np.maximum(cfg.transit_s, 1.875 * walk / cfg.max_carry_speed_m_s)
        dwell = 2 * cfg.settle_s + cfg.pan_s
        self.period_start_s = np.concatenate([[0.0], np.cumsum(dwell + self.transit_s)])[:n]
        self.duration_s = float(self.period_start_s[-1] + dwell)
        self.pan_total_rad = np.radians(360.0 + cfg.pan_overlap_deg)
        self.stations: list[Station] = []
        for k in range(n):
            p2, tan = self.route.at(np.array([s[k]]))
            normal = np.array([-tan[0, 1], tan[0, 0]])
            xy = p2[0] + lateral[k] * normal
            t0 = self.period_start_s[k] + cfg.settle_s
            self.stations.append(Station(k, t0, t0 + cfg.pan_s, np.array([xy[0], xy[1], height[k]]),
                                         float(yaw[k]), float(roll[k]), float(pitch[k]),
                                         float(s[k]), float(lateral[k])))
        # sway: per-transit random phases and amplitude factors
        self._sway_phase = rng.uniform(0, 2 * np.pi, (max(n - 1, 1), 5))
        self._sway_gain = rng.uniform(0.6, 1.0, (max(n - 1, 1), 5))
        # pan profiles: None = the original motor pan (``_ramp_angle``, bit for bit)
        self.pans: list[PanPlan] | None = None
        if not cfg.is_motor_default:
            prng = pan_rng if pan_rng is not None else np.random.default_rng(0x9A4)
            turns = (cfg.pan_turns if cfg.pan_turns is not None
                     else 1.0 + cfg.pan_overlap_deg / 360.0)
            nets = 2 * np.pi * (turns + cfg.pan_turns_jitter * prng.uniform(-1, 1, n))
            self.pans = [plan_pan(cfg, float(x), prng) for x in nets]
            self._pan_before = np.concatenate([[0.0], np.cumsum(nets)])[:n]
        self.R_pan_lidar = rot_y(np.radians(cfg.tilt_deg))[0]
        self.t_pan_lidar = np.asarray(cfg.lever_arm_m, dtype=np.float64)

    # ------------------------------------------------------------------ base and pan
    def base_state(self, t: np.ndarray):
        """Base position (N, 3), yaw, roll, pitch (N,) [rad] and pan angle phi (N,) [rad]."""
        cfg = self.cfg
        t = np.asarray(t, dtype=np.float64)
        k = np.clip(np.searchsorted(self.period_start_s, t, side="right") - 1, 0, self.n - 1)
        local = t - self.period_start_s[k]  # time since this station's period began
        st = self.stations
        pos = np.array([s.position for s in st])
        yaw = np.array([s.yaw_rad for s in st])
        roll = np.array([s.roll_rad for s in st])
        pitch = np.array([s.pitch_rad for s in st])
        arc = np.array([s.arc_m for s in st])
        lat = np.array([s.lateral_m for s in st])

        out_p = pos[k].copy()
        out_yaw, out_roll, out_pitch = yaw[k].copy(), roll[k].copy(), pitch[k].copy()
        # pan angle: completed turns of earlier stations plus the current one
        if self.pans is None:
            phi = k * self.pan_total_rad + _ramp_angle(local - cfg.settle_s, self.pan_total_rad,
                                                        cfg.pan_s, cfg.pan_ramp_s)
        else:
            phi = self._pan_before[k].copy()
            for kk in np.unique(k):
                m = k == kk
                phi[m] += self.pans[kk].at(local[m] - cfg.settle_s)

        t_transit = local - (2 * cfg.settle_s + cfg.pan_s)
        moving = (t_transit > 0) & (k < self.n - 1)
        if np.any(moving):
            i = np.nonzero(moving)[0]
            kk = k[i]
            u = np.clip(t_transit[i] / self.transit_s[kk], 0.0, 1.0)
            g = _min_jerk(u)
            win = np.sin(np.pi * u)  # sway only while carried
            a0, a1 = arc[kk], arc[kk + 1]
            if self.route.closed:
                a1 = np.where(a1 < a0, a1 + self.route.length, a1)
            xy, tan = self.route.at(a0 + (a1 - a0) * g)
            normal = np.stack([-tan[:, 1], tan[:, 0]], axis=1)
            ph, gain = self._sway_phase[kk], self._sway_gain[kk]
            tt = t_transit[i]
            side = lat[kk] + (lat[kk + 1] - lat[kk]) * g
            side = side + cfg.sway_side_m * gain[:, 0] * np.sin(
                2 * np.pi * 0.9 * tt + ph[:, 0]) * win
            xy = xy + side[:, None] * normal
            z = pos[kk, 2] + (pos[kk + 1, 2] - pos[kk, 2]) * g
            z = z + cfg.lift_m * win**2 + cfg.sway_height_m * gain[:, 1] * np.sin(
                2 * np.pi * 1.8 * tt + ph[:, 1]) * win
            out_p[i] = np.stack([xy[:, 0], xy[:, 1], z], axis=1)
            out_yaw[i] = yaw[kk] + (yaw[kk + 1] - yaw[kk]) * g
            amp = np.radians(cfg.sway_tilt_deg)
            out_roll[i] = roll[kk] + (roll[kk + 1] - roll[kk]) * g + amp * gain[:, 2] * np.sin(
                2 * np.pi * 0.9 * tt + ph[:, 2]) * win
            out_pitch[i] = pitch[kk] + (pitch[kk + 1] - pitch[kk]) * g + amp * gain[:, 3] * np.sin(
                2 * np.pi * 1.3 * tt + ph[:, 3]) * win
        return out_p, out_yaw, out_roll, out_pitch, phi

    def pan_net_rad(self, k: int) -> float:
        """Net turn of station k's pan [rad]."""
        return self.pan_total_rad if self.pans is None else self.pans[k].net_rad

    def still_intervals_s(self) -> np.ndarray:
        """(n, 2) capture-relative [s] spans when the tripod stands at each station (its head
        may turn): from the end of the carry before to the start of the carry after."""
        dwell = 2 * self.cfg.settle_s + self.cfg.pan_s
        a = self.period_start_s.copy()
        return np.stack([a, a + dwell], axis=1)

    def T_world_base(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R (N, 3, 3), p (N, 3)) of the base in the world."""
        p, yaw, roll, pitch, _ = self.base_state(t)
        return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), p

    def legs_world(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tripod legs at times t: tops and feet (N, 3, 3) [m] in the world (leg, xyz).

        Three legs 120 deg apart in the base frame, hinged 0.06 m from the pan axis 0.12 m
        below the head, feet ``leg_spread_m`` from the axis on the floor of the current (or
        last) station; they move rigidly with the base while carried.
        """
        t = np.asarray(t, dtype=np.float64)
        R, p = self.T_world_base(t)
        k = np.clip(np.searchsorted(self.period_start_s, t, side="right") - 1, 0, self.n - 1)
        h = np.array([s.position[2] for s in self.stations])[k] - self.floor_z  # (N,)
        a = np.radians([0.0, 120.0, 240.0])
        top = np.stack([0.06 * np.cos(a), 0.06 * np.sin(a), np.full(3, -0.12)], axis=1)
        sp = self.cfg.leg_spread_m
        foot = np.stack([np.broadcast_to(sp * np.cos(a), (len(t), 3)),
                         np.broadcast_to(sp * np.sin(a), (len(t), 3)),
                         -np.repeat(h[:, None], 3, axis=1)], axis=2)  # (N, 3, 3)
        tops_w = p[:, None, :] + np.einsum("nij,lj->nli", R, top)
        feet_w = p[:, None, :] + np.matmul(foot, np.swapaxes(R, 1, 2))
        return tops_w, feet_w

    def T_world_lidar(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_world_lidar (N, 3, 3), p_world_lidar (N, 3)) at capture-relative times t [s]."""
        p, yaw, roll, pitch, phi = self.base_state(t)
        R_world_pan = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll) @ rot_z(phi)
        R = R_world_pan @ self.R_pan_lidar
        return R, p + R_world_pan @ self.t_pan_lidar

    def station_of(self, t: np.ndarray) -> np.ndarray:
        """Index of the station whose pan contains t, -1 outside pans (N,) int."""
        t = np.asarray(t, dtype=np.float64)
        k = np.clip(np.searchsorted(self.period_start_s, t, side="right") - 1, 0, self.n - 1)
        local = t - self.period_start_s[k]
        inside = (local >= self.cfg.settle_s) & (local <= self.cfg.settle_s + self.cfg.pan_s)
        return np.where(inside, k, -1)
