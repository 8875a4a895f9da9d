# SPDX-License-Identifier: BSD-3-Clause
"""VLP-16 model: firing schedule, ray casting on the scene, returns, and the exact packet bytes.

Firing schedule (VLP-16 manual, integer nanoseconds so nothing drifts): firing sequence ``n``
starts at ``n * 55296 ns`` after the capture start, laser ``l`` of it fires ``l * 2304 ns``
later. A data packet holds 12 blocks of 2 sequences each (single return: 24 sequences,
1327.104 us per packet, 754 packets/s) or, in dual-return mode, 6 azimuths of 2 sequences,
each reported twice: even block = last return, odd block = strongest (or second strongest
when the strongest is also the last): 663.552 us per packet, 1507 packets/s.

Each firing is a ray from its laser's origin (the lidar origin raised by the laser's vertical
offset, as the decoder assumes) at its true pose (evaluated at the middle of the
sequence: 18 us of head motion is < 0.1 mm) along the laser's elevation and the azimuth of the
motor at the exact firing time. Two rays sample the beam footprint (centre and leading edge,
``beam_divergence_mrad`` apart): their hits form the firing's returns (separate when further
apart than ``dual_min_separation_m``, else merged; with ``mixed_pixels`` a merged pair gives a
range between the two surfaces, as at real edges). Strongest = centre ray; last = farthest.
Range noise is Gaussian; no return (distance 0) on a miss, beyond ``max_range_m``, nearer than
``min_range_m``, at grazing incidence and with probability ``dropout``.

Sensor frame: the frame velodyne-decoder outputs (x at azimuth 0, azimuth clockwise seen from
above so y = -r cos(el) sin(az), z up): points decoded from these packets are in ``lidar``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tripod_shared import velodyne as v
from tripod_shared.timebase import HOUR_NS

from .beams import LASER_VERT_OFFSET_M, firing_directions
from .config import LidarConfig
from .scenes import NO_RETURN, OTHER, Scene

FIRING_NS = 2304  # between lasers, 2.304 us
SEQUENCE_NS = 55296  # between firing sequences, 55.296 us
SEQUENCES_PER_BLOCK = 2

# Packet layout as a numpy record: 12 x (flag, azimuth, 32 x (distance, reflectivity)) + tail
_CHANNEL = np.dtype([("d", "<u2"), ("r", "u1")])
_BLOCK = np.dtype([("flag", "<u2"), ("az", "<u2"), ("ch", _CHANNEL, (32,))])
PACKET_DTYPE = np.dtype([("blocks", _BLOCK, (12,)), ("ts", "<u4"), ("mode", "u1"),
                         ("product", "u1")])
assert PACKET_DTYPE.itemsize == v.DATA_PACKET_SIZE
_FLAG = int.from_bytes(v.BLOCK_FLAG_BYTES, "little")
_MODE_BYTE = {"strongest": v.RETURN_STRONGEST, "last": v.RETURN_LAST, "dual": v.RETURN_DUAL}


def sequences_per_packet(return_mode: str) -> int:
    return 12 if return_mode == "dual" else 24


def packet_period_ns(return_mode: str) -> int:
    """Data packet period [ns]: 1327104 single return, 663552 dual."""
    return sequences_per_packet(return_mode) * SEQUENCE_NS


LEG_REFLECTIVITY = 30  # dark anodised aluminium


def _hit_legs(o: np.ndarray, d: np.ndarray, tops: np.ndarray, feet: np.ndarray,
              radius: float, block: int = 65536) -> tuple[np.ndarray, np.ndarray]:
    """Nearest entry of rays into finite cylinders (the tripod legs).

    o, d : (M, 3) origins and unit directions; tops, feet : (M, L, 3) leg axis ends per ray.
    Returns (range (M,), inf where no leg is hit; |cos incidence| (M,)).
    """
    t_out = np.full(len(o), np.inf)
    c_out = np.zeros(len(o))
    down = np.nonzero(d[:, 2] < 0.05)[0]  # the legs are below the head: rays going down only
    for s in range(0, len(down), block):
        i = down[s:s + block]
        a, u = tops[i], feet[i] - tops[i]
        length = np.linalg.norm(u, axis=2)
        u = u / length[..., None]
        m = o[i, None, :] - a
        dd = d[i, None, :]
        du = (dd * u).sum(-1)
        mu = (m * u).sum(-1)
        n = dd - du[..., None] * u
        w = m - mu[..., None] * u
        A = (n * n).sum(-1)
        B = 2 * (n * w).sum(-1)
        C = (w * w).sum(-1) - radius * radius
        disc = B * B - 4 * A * C
        ok = (disc >= 0) & (A > 1e-12)
        t = (-B - np.sqrt(np.where(ok, disc, 0.0))) / np.where(ok, 2 * A, 1.0)
        sl = mu + t * du
        ok &= (t > 0) & (sl >= 0) & (sl <= length)
        t = np.where(ok, t, np.inf)
        j = np.argmin(t, axis=1)
        r = np.arange(len(i))
        tt = t[r, j]
        q = o[i] + tt[:, None] * d[i] if np.isfinite(tt).any() else None
        if q is None:
            continue
        hit = np.isfinite(tt)
        axis_pt = a[r, j] + (sl[r, j])[:, None] * u[r, j]
        nrm = (np.where(hit[:, None], q, 0.0) - axis_pt) / radius
        t_out[i] = tt
        c_out[i] = np.where(hit, np.abs((nrm * d[i]).sum(-1)), 0.0)
    return t_out, c_out


@dataclass
class PacketBatch:
    """Consecutive data packets of one chunk.

    payloads : (P, 1206) uint8, exact UDP payloads
    first_firing_ns : (P,) int64, capture-relative true time of each packet's first firing
    recv_ns : (P,) int64, host_realtime receive time (pcap time)
    labels : (P, 12, 32) uint8 class of the return in each block/channel, 255 = no return
    """

    payloads: np.ndarray
    first_firing_ns: np.ndarray
    recv_ns: np.ndarray
    labels: np.ndarray


class Vlp16:
    """Simulated VLP-16 looking at ``scene`` while moving along ``trajectory``.

    Parameters
    ----------
    cfg : LidarConfig
    scene : Scene
    trajectory : object with ``T_world_lidar(t_s) -> (R (N,3,3), p (N,3))``
    start_unix_ns : host_realtime of capture-relative time 0
    seed : int
    nthreads : ray-casting threads (0 = all cores)
    """

    def __init__(self, cfg: LidarConfig, scene: Scene, trajectory, start_unix_ns: int, seed: int,
                 nthreads: int = 0):
        import open3d as o3d

        self.cfg = cfg
        self.scene = scene
        self.trajectory = trajectory
        self.start_unix_ns = int(start_unix_ns)
        self.seed = int(seed)
        self.nthreads = nthreads
        self._o3d = o3d
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                               o3d.core.Tensor(scene.triangles.astype(np.uint32)))
        self.spp = sequences_per_packet(cfg.return_mode)
        self.period_ns = packet_period_ns(cfg.return_mode)
        rng = np.random.default_rng([seed, 0x11DA])
        self.azimuth0_deg = float(rng.uniform(0, 360))
        self.deg_per_ns = 360.0 * cfg.rpm / 60.0 / 1e9
        self._mode = _MODE_BYTE[cfg.return_mode]
        self._cos_max_inc = float(np.cos(np.radians(cfg.max_incidence_deg)))
        self.vert_offsets_m = LASER_VERT_OFFSET_M if cfg.vertical_offsets else np.zeros(16)

    # ---------------------------------------------------------------- geometry
    def azimuth_deg(self, t_ns: np.ndarray) -> np.ndarray:
        """Motor azimuth [deg, 0..360) at capture-relative times [ns]."""
        return np.mod(self.azimuth0_deg + self.deg_per_ns * np.asarray(t_ns, dtype=np.float64),
                      360.0)

    def device_toh_us(self, t_ns: np.ndarray) -> np.ndarray:
        """lidar_toh clock [us past the hour] at capture-relative times [ns] (truncated)."""
        host = self.start_unix_ns + np.asarray(t_ns, dtype=np.int64) + self.cfg.clock_offset_ns
        return (np.mod(host, HOUR_NS) // 1000).astype(np.uint32)

    def _cast(self, origins: np.ndarray, dirs: np.ndarray, legs=None):
        """(range, class, reflectivity, |cos incidence|) of each ray; range inf on a miss."""
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        ans = self._rc.cast_rays(self._o3d.core.Tensor(rays), nthreads=self.nthreads)
        t = ans["t_hit"].numpy().astype(np.float64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        prim = np.where(hit, prim, 0)
        nrm = ans["primitive_normals"].numpy()
        cos_inc = np.abs((nrm * dirs).sum(axis=1))
        cls = self.scene.classes[prim]
        refl = self.scene.reflectivity[prim]
        if legs is not None:
            tl, cl = _hit_legs(origins, dirs, legs[0], legs[1], self.trajectory.cfg.leg_radius_m)
            near = tl < t
            t = np.where(near, tl, t)
            cos_inc = np.where(near, cl, cos_inc)
            cls = np.where(near, OTHER, cls)
            refl = np.where(near, LEG_REFLECTIVITY, refl)
        return t, cls, refl, cos_inc

    # ---------------------------------------------------------------- packets
    def packets(self, first: int, count: int) -> PacketBatch:
        """Simulate data packets ``first .. first + count - 1`` of the capture."""
        cfg = self.cfg
        spp = self.spp
        n_seq = count * spp
        seq = (first * spp + np.arange(n_seq, dtype=np.int64))
        t_seq_ns = seq * SEQUENCE_NS  # (S,)
        t_fire_ns = t_seq_ns[:, None] + np.arange(16, dtype=np.int64)[None, :] * FIRING_NS
        az = self.azimuth_deg(t_fire_ns)  # (S, 16)
        R, p = self.trajectory.T_world_lidar((t_seq_ns + 15 * FIRING_NS // 2) * 1e-9)
        d_lidar = firing_directions(az)  # (S, 16, 3)
        half = np.degrees(cfg.beam_divergence_mrad * 1e-3 / 2)
        d_edge = firing_directions(az + half)
        Rt = np.ascontiguousarray(np.swapaxes(R, 1, 2))
        d1 = np.matmul(d_lidar, Rt).reshape(-1, 3)  # batched R @ d, much faster than einsum
        d2 = np.matmul(d_edge, Rt).reshape(-1, 3)
        # each laser's own origin: lidar origin + its vertical offset along the lidar z axis
        o = (p[:, None, :] + R[:, None, :, 2] * self.vert_offsets_m[None, :, None]).reshape(-1, 3)
        legs = None
        if getattr(self.trajectory.cfg, "tripod_legs", False):
            tops, feet = self.trajectory.legs_world((t_seq_ns + 15 * FIRING_NS // 2) * 1e-9)
            legs = (np.repeat(tops, 16, axis=0), np.repeat(feet, 16, axis=0))
        t1, cls1, refl1, c1 = self._cast(o, d1, legs)
        t2, cls2, refl2, c2 = self._cast(o, d2, legs)

        rng = np.random.default_rng([self.seed, 0x1DA7, first])
        m = len(t1)

        def valid(t, c):
            ok = np.isfinite(t) & (t <= cfg.max_range_m) & (t >= cfg.min_range_m)
            ok &= c >= self._cos_max_inc
            if cfg.dropout > 0:
                ok &= rng.random(m) >= cfg.dropout
            return ok

        ok1, ok2 = valid(t1, c1), valid(t2, c2)
        sep = np.abs(np.where(ok1 & ok2, t2 - t1, 0.0)) >= cfg.dual_min_separation_m
        two = ok1 & ok2 & sep  # two distinct returns
        s_ok = ok1 | ok2
        if cfg.mixed_pixels:
            # unresolved echoes from two surfaces merge into one pulse: a range in between,
            # weighted towards the centre of the footprint
            mix = ok1 & ok2 & ~sep & (np.abs(t2 - t1) > 0.02)
            w = rng.uniform(0.5, 1.0, m)
            t1 = np.where(mix, w * t1 + (1 - w) * t2, t1)
        if cfg.range_noise_m > 0:
            t1 = t1 + rng.normal(0.0, cfg.range_noise_m, m)
            t2 = t2 + rng.normal(0.0, cfg.range_noise_m, m)

        def pick(use2):
            return (np.where(use2, t2, t1), np.where(use2, cls2, cls1),
                    np.where(use2, refl2, refl1), np.where(use2, c2, c1))

        strongest = ~ok1  # centre ray, else the edge when the centre has no return
        last = strongest | (two & (t2 > t1))  # the farthest return
        nearer = strongest | (two & (t2 < t1))  # dual: strongest block when strongest is last
        strong = pick(strongest)
        far = pick(last)

        def encode(t, cls, refl, cos_inc, ok):
            dist = np.where(ok, np.clip(np.round(t / v.DISTANCE_UNIT_M), 1, 65535), 0)
            refl = refl.astype(np.float64) * (0.4 + 0.6 * cos_inc)
            refl = np.where(ok, np.clip(np.round(refl), 1, 100), 0)
            lab = np.where(ok, cls, NO_RETURN)
            return (dist.astype(np.uint16).reshape(n_seq, 16),
                    refl.astype(np.uint8).reshape(n_seq, 16),
                    lab.astype(np.uint8).reshape(n_seq, 16))

        pkt = np.zeros(count, dtype=PACKET_DTYPE)
        pkt["blocks"]["flag"] = _FLAG
        pkt["ts"] = self.device_toh_us(t_seq_ns[::spp])
        pkt["mode"] = self._mode
        pkt["product"] = cfg.product_id
        labels = np.empty((count, 12, 32), dtype=np.uint8)
        az_q = (np.round(az[:, 0] * 100).astype(np.int64) % 36000).astype(np.uint16)
        if cfg.return_mode == "dual":
            ls = encode(*far, s_ok)
            ss = encode(*pick(nearer), s_ok)
            blk_az = az_q[0::2].reshape(count, 6)
            pkt["blocks"]["az"][:, 0::2] = blk_az
            pkt["blocks"]["az"][:, 1::2] = blk_az
            for out_slice, (dd, rr, ll) in ((slice(0, None, 2), ls), (slice(1, None, 2), ss)):
                pkt["blocks"]["ch"]["d"][:, out_slice] = dd.reshape(count, 6, 32)
                pkt["blocks"]["ch"]["r"][:, out_slice] = rr.reshape(count, 6, 32)
                labels[:, out_slice] = ll.reshape(count, 6, 32)
        else:
            if cfg.return_mode == "last":
                dd, rr, ll = encode(*far, s_ok)
            else:
                dd, rr, ll = encode(*strong, s_ok)
            pkt["blocks"]["az"] = az_q[0::2].reshape(count, 12)
            pkt["blocks"]["ch"]["d"] = dd.reshape(count, 12, 32)
            pkt["blocks"]["ch"]["r"] = rr.reshape(count, 12, 32)
            labels[:] = ll.reshape(count, 12, 32)

        first_ns = t_seq_ns[::spp]
        lat = cfg.network_latency_us * 1e3 + rng.exponential(max(cfg.network_jitter_us, 1e-9) * 1e3,
                                                             count)
        recv = self.start_unix_ns + first_ns + self.period_ns + np.round(lat).astype(np.int64)
        payloads = pkt.view(np.uint8).reshape(count, v.DATA_PACKET_SIZE)
        return PacketBatch(payloads, first_ns, recv, labels)


# ------------------------------------------------------------------------- position packets


def gprmc(unix_ns: int, lat_deg: float, lon_deg: float) -> str:
    """A GPRMC sentence for UTC time ``unix_ns`` at a fixed position (speed 0)."""
    from tripod_shared.nmea import format_rmc

    return format_rmc(unix_ns, lat_deg, lon_deg)


def position_packet(toh_us: int, pps_state: int, nmea: str) -> bytes:
    """A 512-byte position (telemetry) packet: timestamp, PPS state and NMEA sentence."""
    b = bytearray(v.POSITION_PACKET_SIZE)
    b[v.POS_TIMESTAMP_OFFSET : v.POS_TIMESTAMP_OFFSET + 4] = int(toh_us).to_bytes(4, "little")
    b[v.POS_PPS_OFFSET] = pps_state
    raw = (nmea + "\r\n").encode("ascii") if nmea else b""
    b[v.POS_NMEA_OFFSET : v.POS_NMEA_OFFSET + len(raw)] = raw[: v.POS_NMEA_SIZE]
    return bytes(b)


def position_schedule(duration_ns: int, seed: int) -> np.ndarray:
    """Capture-relative send times [ns] of position packets: irregular intervals of 1.4 to
    12.4 ms (mean 6.9 ms, ~145 packets/s), as measured on the real captures in shared/data."""
    rng = np.random.default_rng([seed, 0x9050])
    n = int(duration_ns / 6.9e6) + 64
    gaps = rng.uniform(1.4e6, 12.4e6, n)
    t = np.cumsum(gaps).astype(np.int64)
    return t[t < duration_ns]
