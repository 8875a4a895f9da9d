# SPDX-License-Identifier: BSD-3-Clause
"""A small tripod capture with known truth for the reconstruction tests: box rooms with box
obstacles ray-cast analytically (vectorised), VLP-16 packets encoded for velodyne-decoder's own
beam geometry, an IMU with yaw drift, noise and a clock offset, written as a tripod MCAP.

This is a test fixture, independent of ``tripod simulate`` (the digital twin); it keeps the
reconstruction tests small and self-contained.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import velodyne_decoder as vd
from tripod_shared.messages import Event, ImuSample
from tripod_shared.recording import RecordingWriter

SEQ_US = 55.296
LASER_US = 2.304
BLOCK_US = 2 * SEQ_US
PACKET_US = 12 * BLOCK_US


def _beam_geometry():
    """Per channel (16): unit direction at azimuth 0 and origin, as velodyne-decoder decodes."""

    def pkt(dist):
        b = bytearray()
        for _ in range(12):
            b += b"\xff\xee" + struct.pack("<H", 0)
            for _ in range(32):
                b += struct.pack("<HB", int(dist / 0.002), 100)
        return bytes(b + struct.pack("<I", 0) + bytes([0x37, 0x22]))

    out = []
    for dist in (10.0, 20.0):
        pv = vd.PacketVector()
        pv.append(vd.VelodynePacket(0.0, pkt(dist)))
        _, p = vd.ScanDecoder(vd.Config(model=vd.Model.VLP16)).decode(pv, as_pcl_structs=True)
        out.append(np.stack([p["x"], p["y"], p["z"]], 1)[:16].astype(np.float64))
    d = (out[1] - out[0]) / 10.0
    elev = np.arcsin(np.clip(d[:, 2], -1, 1))
    vo = out[0][:, 2] - 10.0 * np.sin(elev)
    return elev, vo


@dataclass
class Box:
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


@dataclass
class Scene:
    room: Box
    obstacles: list[Box] = field(default_factory=list)

    def raycast(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Distance along unit rays (N,3) from origins inside the room to the first surface."""
        lo, hi = np.array(self.room.lo), np.array(self.room.hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_exit = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
        t = t_exit.min(axis=1)
        for b in self.obstacles:
            blo, bhi = np.array(b.lo), np.array(b.hi)
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (blo - o) / d
                t2 = (bhi - o) / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tmax >= tmin) & (tmin > 0)
            t = np.where(hit & (tmin < t), tmin, t)
        return t


def default_scene() -> Scene:
    return Scene(Box((0, 0, 0), (9.0, 6.0, 2.7)),
                 [Box((3.0, 2.0, 0.0), (3.4, 2.4, 2.7)), Box((6.5, 4.0, 0.0), (7.7, 4.8, 0.75)),
                  Box((1.0, 4.6, 0.0), (1.6, 6.0, 1.9))])


@dataclass
class Truth:
    station_mid_ns: list[int]
    T_world_lidar_mid: list[np.ndarray]  # true poses (world: the scene frame)
    R_imu_lidar: np.ndarray
    lever_arm_m: np.ndarray
    imu_time_offset_ns: int  # IMU host stamp − true time − (lidar host − lidar time)
    t0_ns: int
    stations_span_ns: list[tuple[int, int]]
    trajectory_t_ns: np.ndarray  # (M,) lidar time [ns], 200 Hz
    trajectory_T: np.ndarray  # (M, 4, 4) true T_world_lidar


def synth_capture(path: Path, *, stations=((2.0, 1.5, 0.0), (4.8, 1.4, 40.0), (7.0, 2.8, 100.0)),
                  station_s: float = 5.0, carry_s: float = 2.5, pan_deg_s: float = 25.0,
                  tilt_deg: float = 25.0, lever=(0.0, 0.05, 0.12), range_noise_m: float = 0.005,
                  imu_hz: float = 100.0, imu_latency_ms: float = 8.0, yaw_drift_deg_s: float = 0.02,
                  imu_noise_deg: float = 0.02, seed: int = 0, scene: Scene | None = None,
                  marks: bool = True, with_imu: bool = True, tripod_height: float = 1.4,
                  pan_wobble_deg: float = 0.0) -> Truth:
    """Write a tripod MCAP recording to ``path``; return the truth.

    Stations are (x, y, yaw_deg) of the head's pivot at ``tripod_height``. At each station the
    head pans at ``pan_deg_s`` (plus a ``pan_wobble_deg`` oscillation at 0.7 Hz) with the lidar
    tilted ``tilt_deg`` on it; between stations the
    tripod is carried (smooth translation and yaw, a little sway) while data keeps flowing.
    """
    scene = scene or default_scene()
    rng = np.random.default_rng(seed)
    elev, vo = _beam_geometry()
    R_il = Rotation.from_euler("x", tilt_deg, degrees=True).as_matrix()
    ell = np.asarray(lever, dtype=np.float64)
    t0_ns = 1_700_000_000 * 10**9 + 123_456_789
    host_minus_lidar_ns = 300_000_000  # host clock ahead of the lidar's by 0.3 s

    # ---- timeline: station, carry, station, ...
    segs = []  # (start_s, end_s, kind, k)
    t = 0.0
    for k in range(len(stations)):
        segs.append((t, t + station_s, "station", k))
        t += station_s
        if k + 1 < len(stations):
            segs.append((t, t + carry_s, "carry", k))
            t += carry_s
    total_s = t
    pans = np.zeros(len(stations))  # pan angle accumulated at the start of each station

    def head(ts: np.ndarray):
        """True pivot position (N,3) and R_world_imu (N,3,3) at times ts [s]."""
        pos = np.zeros((len(ts), 3))
        yaw = np.zeros(len(ts))
        sway = np.zeros((len(ts), 2))
        for s0, s1, kind, k in segs:
            m = (ts >= s0) & (ts < s1 + (1e-9 if s1 == total_s else 0))
            if kind == "station":
                x, y, y0 = stations[k]
                pos[m] = (x, y, tripod_height)
                yaw[m] = np.radians(y0 + pans[k]) + np.radians(pan_deg_s) * (ts[m] - s0) \
                    + np.radians(pan_wobble_deg) * np.sin(2 * np.pi * 0.7 * (ts[m] - s0))
            else:
                x0, y0_, a0 = stations[k]
                x1, y1, a1 = stations[k + 1]
                u = (ts[m] - s0) / (s1 - s0)
                w = u * u * (3 - 2 * u)
                pos[m] = np.stack([x0 + w * (x1 - x0), y0_ + w * (y1 - y0_),
                                   np.full(m.sum(), tripod_height) + 0.05 * np.sin(np.pi * u)], 1)
                end0 = np.radians(a0 + pans[k]) + np.radians(pan_deg_s) * station_s
                start1 = np.radians(a1 + pans[k + 1])
                yaw[m] = end0 + w * (start1 - end0)
                sway[m] = 0.03 * np.sin(np.pi * u)[:, None] * np.array([1.0, -0.7])
        R = Rotation.from_euler("ZYX", np.stack([yaw, sway[:, 0], sway[:, 1]], 1)).as_matrix()
        return pos, R

    # ---- lidar: packets at 600 rpm, strongest return
    n_packets = int(total_s * 1e6 / PACKET_US)
    p_idx = np.arange(n_packets)
    blk_t_us = p_idx[:, None] * PACKET_US + np.arange(12)[None, :] * BLOCK_US  # (P,12)
    omega = 3600.0  # deg/s
    az = np.empty((n_packets, 12, 2, 16))
    dist = np.empty((n_packets, 12, 32), dtype="<u2")
    ce = np.cos(elev)[None, None, :]
    for c0 in range(0, n_packets, 1000):  # bounded memory
        c1 = min(n_packets, c0 + 1000)
        fire_us = (blk_t_us[c0:c1, :, None, None] + np.arange(2)[None, None, :, None] * SEQ_US
                   + np.arange(16)[None, None, None, :] * LASER_US)  # (p,12,2,16)
        az[c0:c1] = (omega * fire_us * 1e-6) % 360.0
        pos, R_wi = head(blk_t_us[c0:c1].ravel() * 1e-6)
        R_wl = R_wi @ R_il
        p_wl = pos + np.einsum("nij,j->ni", R_wi, ell)
        a = np.radians(az[c0:c1]).reshape(-1, 2, 16)
        d_l = np.stack([ce * np.cos(a), -ce * np.sin(a),
                        np.broadcast_to(np.sin(elev), a.shape)], -1)
        o_l = np.zeros(d_l.shape)
        o_l[..., 2] = vo
        d_w = np.einsum("nij,nskj->nski", R_wl, d_l)
        o_w = p_wl[:, None, None, :] + np.einsum("nij,nskj->nski", R_wl, o_l)
        r = scene.raycast(o_w.reshape(-1, 3), d_w.reshape(-1, 3))
        r = r + rng.normal(0.0, range_noise_m, r.shape)
        bad = ~np.isfinite(r) | (r > 100) | (r < 0.5)
        dd = np.clip(np.round(np.nan_to_num(r) / 0.002), 0, 65535).astype("<u2")
        dd[bad] = 0
        dist[c0:c1] = dd.reshape(c1 - c0, 12, 32)

    toh0_us = (t0_ns // 1000) % (3600 * 10**6)
    buf = np.zeros((n_packets, 1206), dtype=np.uint8)
    blocks = buf[:, :1200].reshape(n_packets, 12, 100)
    blocks[:, :, 0] = 0xFF
    blocks[:, :, 1] = 0xEE
    az_block = np.round(az[:, :, 0, 0] * 100).astype("<u2") % 36000
    blocks[:, :, 2:4] = az_block[..., None].view(np.uint8).reshape(n_packets, 12, 2)
    ch = blocks[:, :, 4:].reshape(n_packets, 12, 32, 3)
    ch[..., 0:2] = dist[..., None].view(np.uint8).reshape(n_packets, 12, 32, 2)
    ch[..., 2] = 100
    toh = ((toh0_us + np.round(p_idx * PACKET_US).astype(np.int64)) % (3600 * 10**6)).astype("<u4")
    buf[:, 1200:1204] = toh[:, None].view(np.uint8).reshape(n_packets, 4)
    buf[:, 1204], buf[:, 1205] = 0x37, 0x22
    lidar_ns = t0_ns + np.round(p_idx * PACKET_US * 1000).astype(np.int64)
    # host receive: the clock offset plus the time to fill the packet and a little jitter
    host_ns = lidar_ns + host_minus_lidar_ns + int(PACKET_US * 1000) + rng.integers(
        0, 200_000, n_packets)

    # ---- IMU: q_world_imu with yaw drift and noise; host stamp late by the latency
    imu_t = np.arange(0.0, total_s, 1.0 / imu_hz)
    _, R_imu_true = head(imu_t)
    drift = Rotation.from_euler("z", (yaw_drift_deg_s * imu_t)[:, None], degrees=True)
    noise = Rotation.from_rotvec(rng.normal(0, np.radians(imu_noise_deg), (len(imu_t), 3)))
    q = (drift * Rotation.from_matrix(R_imu_true) * noise).as_quat()  # x, y, z, w
    imu_host = t0_ns + np.round(imu_t * 1e9).astype(np.int64) + host_minus_lidar_ns + int(
        imu_latency_ms * 1e6) + rng.integers(0, 500_000, len(imu_t))

    # ---- write the MCAP in time order
    items = [(int(h), 0, k) for k, h in enumerate(host_ns)]
    if with_imu:
        items += [(int(h), 1, k) for k, h in enumerate(imu_host)]
    mids, spans, T_mid = [], [], []
    for s0, s1, kind, k in segs:
        if kind != "station":
            continue
        mid = 0.5 * (s0 + s1)
        mids.append(t0_ns + int(mid * 1e9))
        spans.append((t0_ns + int(s0 * 1e9), t0_ns + int(s1 * 1e9)))
        pp, RR = head(np.array([mid]))
        T = np.eye(4)
        T[:3, :3] = RR[0] @ R_il
        T[:3, 3] = pp[0] + RR[0] @ ell
        T_mid.append(T)
        if marks:
            items.append((t0_ns + int((s0 + 1.0) * 1e9) + host_minus_lidar_ns, 2, k))
    items.sort()
    with RecordingWriter(path) as w:
        for h, kind, k in items:
            if kind == 0:
                w.write_lidar_packet(h, buf[k].tobytes())
            elif kind == 1:
                x, y, z, ww = q[k]
                w.write_imu(ImuSample(h, float(ww), float(x), float(y), float(z)))
            else:
                w.write_event(Event(h, "mark", f"station-{k}"))
    tt = np.arange(0.0, total_s, 0.005)
    pp, RR = head(tt)
    traj = np.tile(np.eye(4), (len(tt), 1, 1))
    traj[:, :3, :3] = RR @ R_il
    traj[:, :3, 3] = pp + RR @ ell
    return Truth(mids, T_mid, R_il, ell, int(imu_latency_ms * 1e6), t0_ns, spans,
                 t0_ns + np.round(tt * 1e9).astype(np.int64), traj)
