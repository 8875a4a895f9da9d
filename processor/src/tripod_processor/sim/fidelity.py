# SPDX-License-Identifier: BSD-3-Clause
"""Checks that a simulated capture is what the devices would emit and that its truth holds.

Used by the tests and by ``bench/sim_fidelity.py``. Points are decoded with the same decoder
as real data (velodyne-decoder's ``StreamDecoder``), placed with the *true* pose at their firing
time (rebuilt from ``meta.json``: the capture is deterministic per seed) and compared with the
scene mesh; labels are joined to decoded points through (firing time, ring, return type).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tripod_shared import tfp
from tripod_shared import velodyne as v
from tripod_shared.timebase import HOUR_NS, toh_ns_to_unix_ns, unwrap_toh_us

from ..io.imu_log import ImuLogReader
from ..io.pcap import PcapReader
from .capture import CAPTURE_FILE, IMU_FILE, LABELS_FILE, META_FILE, build_rig
from .config import SimConfig
from .beams import LASER_RING, LASER_VERT_OFFSET_M
from .lidar import FIRING_NS, SEQUENCE_NS, sequences_per_packet

#: velodyne-decoder return_type values
DEC_STRONGEST, DEC_LAST, DEC_BOTH = 1, 2, 3
_LASER_OF_RING = np.argsort(LASER_RING)


def load_meta(capture_dir: str | Path) -> tuple[dict, SimConfig]:
    meta = json.loads((Path(capture_dir) / META_FILE).read_text())
    return meta, SimConfig.model_validate(meta["config"])


@dataclass
class DecodedPoints:
    """Decoded points of a capture: xyz (N, 3) [m] lidar frame, host_ns (N,) true firing time on
    host_realtime (from the device time and the known lidar clock offset), ring (N,),
    return_type (N,), intensity (N,), toh_us (N,) float device time [us past the hour]."""

    xyz: np.ndarray
    host_ns: np.ndarray
    ring: np.ndarray
    return_type: np.ndarray
    intensity: np.ndarray
    toh_us: np.ndarray


def decode_capture(capture_dir: str | Path, max_packets: int | None = None) -> DecodedPoints:
    """Decode ``capture.pcap`` with velodyne-decoder (VLP-16 model, default calibration)."""
    import velodyne_decoder as vd

    meta, cfg = load_meta(capture_dir)
    # the geometry the capture was made with: built-in VLP-16 (manual's vertical offsets) or
    # the bundled nominal calibration without them
    calib = None if cfg.lidar.vertical_offsets else vd.get_bundled_calibration("VLP-16.yml")
    dec = vd.StreamDecoder(vd.Config(model=vd.Model.VLP16, calibration=calib,
                                     timestamp_first_packet=True, min_range=0.05,
                                     max_range=200.0))
    parts = []

    def take(res):
        if res is None:
            return
        tp, pts = res
        parts.append((tp.host, tp.device, pts))

    n = 0
    for d in PcapReader(Path(capture_dir) / CAPTURE_FILE):
        if d.dst_port != v.DATA_PORT or len(d.payload) != v.DATA_PACKET_SIZE:
            continue
        take(dec.decode(d.t_ns * 1e-9, d.payload))
        n += 1
        if max_packets is not None and n >= max_packets:
            break
    take(dec.finish())
    xyz, host, ring, rt, inten, toh = [], [], [], [], [], []
    off = cfg.lidar.clock_offset_ns
    for host_s, dev_s, pts in parts:
        rel_ns = np.round(pts[:, 4].astype(np.float64) * 1e9).astype(np.int64)
        if dev_s < 3600.0:  # seconds past the hour: put the hour back using the host stamp
            ref = int(round(host_s * 1e9)) + off
            stamp_ns = toh_ns_to_unix_ns(int(round(dev_s * 1e9)), ref)
        else:  # velodyne-decoder 3 already resolved the hour: UNIX time on the lidar clock
            stamp_ns = int(round(dev_s * 1e9))
        lidar_ns = stamp_ns + rel_ns
        dev_us = (lidar_ns % HOUR_NS) / 1e3
        xyz.append(pts[:, :3].astype(np.float64))
        host.append(lidar_ns - off)
        ring.append(pts[:, 6].astype(np.int64))
        rt.append(pts[:, 7].astype(np.int64))
        inten.append(pts[:, 3])
        toh.append(dev_us)
    cat = (lambda a, dt: np.concatenate(a).astype(dt) if a else np.zeros(0, dt))
    return DecodedPoints(np.concatenate(xyz) if xyz else np.zeros((0, 3)), cat(host, np.int64),
                         cat(ring, np.int64), cat(rt, np.int64), cat(inten, np.float32),
                         cat(toh, np.float64))


def join_labels(points: DecodedPoints, labels_npz: str | Path) -> np.ndarray:
    """Class id of every decoded point from ``labels.npz`` (255 where it cannot be joined)."""
    laser = _LASER_OF_RING[np.clip(points.ring, 0, 15)]
    return lookup_labels(points.toh_us, laser, points.return_type, labels_npz)


def lookup_labels(device_time, laser: np.ndarray, return_type: np.ndarray,
                  labels_npz: str | Path) -> np.ndarray:
    """Class ids of decoded points, from any decoder's per-point fields.

    Parameters
    ----------
    device_time : (N,) firing time on the lidar clock: float microseconds past the hour, or
        int64 nanoseconds (UNIX time on the lidar clock, as ``tripod decode`` stamps points:
        ``stamp_device_ns + time_offset_ns``)
    laser : (N,) laser id in firing order (0..15; velodyne-decoder's ring is *not* this)
    return_type : (N,) 1 strongest, 2 last, 3 both (velodyne-decoder's ReturnMode)
    labels_npz : the capture's ``labels.npz``

    The packet is found by device time (``packet_toh_us``), the firing sequence inside it by
    the time offset, the block by the return type (dual: even blocks hold the last return, odd
    blocks the strongest), the channel by sequence and laser. Returns (N,) uint8, 255 where
    the point falls outside the capture's packets.
    """
    z = np.load(labels_npz)
    labels, toh = z["labels"], z["packet_toh_us"].astype(np.int64)
    mode = str(z["return_mode"])
    spp = sequences_per_packet(mode)
    toh_u = np.asarray(unwrap_toh_us(toh.tolist()), dtype=np.float64)
    t = np.asarray(device_time)
    if t.dtype.kind in "iu":  # ns on the lidar clock -> us past the hour
        t = (t % HOUR_NS) / 1e3
    t = t.astype(np.float64)
    # unwrap the points' times like the packets' (captures shorter than an hour)
    t = t + np.where(t < toh[0] - 1.8e9, 3.6e9, 0.0)
    p = np.clip(np.searchsorted(toh_u, t + 0.5, side="right") - 1, 0, len(toh_u) - 1)
    laser = np.clip(np.asarray(laser, dtype=np.int64), 0, 15)
    off_ns = (t - toh_u[p]) * 1e3 - laser * FIRING_NS
    k = np.round(off_ns / SEQUENCE_NS).astype(np.int64)
    ok = (k >= 0) & (k < spp) & (np.abs(off_ns - k * SEQUENCE_NS) < 2000)
    k = np.clip(k, 0, spp - 1)
    if mode == "dual":
        block = 2 * (k // 2) + np.where(np.asarray(return_type) == DEC_STRONGEST, 1, 0)
    else:
        block = k // 2
    ch = (k % 2) * 16 + laser
    out = labels[p, block, ch]
    return np.where(ok, out, 255).astype(np.uint8)


def labeled_points(capture_dir: str | Path, max_packets: int | None = None,
                   world: bool = True) -> tuple[np.ndarray, np.ndarray, DecodedPoints]:
    """Decoded points of a capture with their true class: ``(xyz (N, 3), labels (N,), points)``.

    ``world=True`` places every point with the true pose at its firing time (a perfectly
    registered, labelled cloud: training and test data for segmentation); ``False`` keeps the
    lidar frame. Labels are class ids (``CLASS_NAMES``), 255 where no join was possible.
    """
    _meta, cfg = load_meta(capture_dir)
    pts = decode_capture(capture_dir, max_packets)
    lab = join_labels(pts, Path(capture_dir) / LABELS_FILE)
    if not world:
        return pts.xyz, lab, pts
    _scene, xyz, _origin = place_points(pts, cfg)
    return xyz, lab, pts


@dataclass
class Fidelity:
    """Results of :func:`evaluate`; distances in metres."""

    n_points: int = 0
    dist_median_m: float = float("nan")
    dist_p99_m: float = float("nan")
    range_err_std_m: float = float("nan")
    range_err_robust_std_m: float = float("nan")
    configured_sigma_m: float = 0.0
    label_agreement: float = float("nan")
    label_joined: float = float("nan")  # fraction of points the label join found
    off_mesh_frac: float = float("nan")  # fraction of points farther than 5 mm from the mesh


def place_points(points: DecodedPoints, cfg: SimConfig):
    """World points (N, 3) and lidar origins (N, 3) with the true pose at each firing time."""
    scene, traj = build_rig(cfg)
    t_s = (points.host_ns - cfg.start_unix_ns) * 1e-9
    R, p = traj.T_world_lidar(t_s)
    return scene, np.einsum("nij,nj->ni", R, points.xyz) + p, p


def _laser_offsets_world(points: DecodedPoints, cfg: SimConfig) -> np.ndarray:
    """(N, 3) world offset of each point's laser origin from the lidar origin."""
    _scene, traj = build_rig(cfg)
    R, _ = traj.T_world_lidar((points.host_ns - cfg.start_unix_ns) * 1e-9)
    laser = _LASER_OF_RING[np.clip(points.ring, 0, 15)]
    offsets = LASER_VERT_OFFSET_M if cfg.lidar.vertical_offsets else np.zeros(16)
    return R[:, :, 2] * offsets[laser][:, None]


def geometry_check(capture_dir: str | Path, max_packets: int | None = None,
                   sample: int = 400_000, seed: int = 0) -> Fidelity:
    """Decode, place with the true pose, measure distance to the mesh and range error."""
    import open3d as o3d

    meta, cfg = load_meta(capture_dir)
    pts = decode_capture(capture_dir, max_packets)
    res = Fidelity(configured_sigma_m=cfg.lidar.range_noise_m)
    if len(pts.host_ns) == 0:
        return res
    if len(pts.host_ns) > sample:
        idx = np.sort(np.random.default_rng(seed).choice(len(pts.host_ns), sample, replace=False))
        pts = DecodedPoints(pts.xyz[idx], pts.host_ns[idx], pts.ring[idx], pts.return_type[idx],
                            pts.intensity[idx], pts.toh_us[idx])
    scene, world, origin = place_points(pts, cfg)
    origin = origin + _laser_offsets_world(pts, cfg)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    q = o3d.core.Tensor(world.astype(np.float32))
    dist = rc.compute_distance(q).numpy().astype(np.float64)
    closest = rc.compute_closest_points(q)["primitive_ids"].numpy()
    # range error along the ray: measured range minus the true range to the mesh
    vec = world - origin
    rng_meas = np.linalg.norm(vec, axis=1)
    d = vec / rng_meas[:, None]
    hit = rc.cast_rays(o3d.core.Tensor(np.concatenate([origin, d], 1).astype(np.float32)))
    t_true = hit["t_hit"].numpy().astype(np.float64)
    fin = np.isfinite(t_true)
    err = rng_meas[fin] - t_true[fin]
    if cfg.lidar.return_mode != "strongest":
        # last returns of a split footprint lie on a surface behind the centre ray's hit
        keep = max(0.5 * cfg.lidar.dual_min_separation_m, 6 * cfg.lidar.range_noise_m)
        err = err[np.abs(err) < keep]
    res.n_points = int(len(dist))
    res.dist_median_m = float(np.median(dist))
    res.dist_p99_m = float(np.percentile(dist, 99))
    res.off_mesh_frac = float(np.mean(dist > 0.005))
    res.range_err_std_m = float(np.std(err))
    res.range_err_robust_std_m = float(1.4826 * np.median(np.abs(err - np.median(err))))
    lab = join_labels(pts, Path(capture_dir) / LABELS_FILE)
    truth = scene.classes[closest]
    ok = lab != 255
    res.label_agreement = float(np.mean(lab[ok] == truth[ok])) if ok.any() else float("nan")
    res.label_joined = float(np.mean(ok))
    return res


def packet_check(capture_dir: str | Path) -> dict:
    """Sizes, factory bytes, block flags, timestamps, azimuth steps and rates of the pcap."""
    meta, cfg = load_meta(capture_dir)
    data_t, toh, az_step, bad, pos, pos_bad, nmea = [], [], [], 0, 0, 0, set()
    modes, products = set(), set()
    prev_az = None
    for d in PcapReader(Path(capture_dir) / CAPTURE_FILE):
        if d.dst_port == v.DATA_PORT:
            if v.check_data_packet(d.payload) != v.PacketKind.DATA:
                bad += 1
                continue
            data_t.append(d.t_ns)
            toh.append(v.data_timestamp_us(d.payload))
            modes.add(d.payload[v.RETURN_MODE_OFFSET])
            products.add(d.payload[v.PRODUCT_ID_OFFSET])
            az = int.from_bytes(d.payload[2:4], "little")
            if prev_az is not None:
                az_step.append((az - prev_az) % 36000)
            prev_az = az
        elif d.dst_port == v.POSITION_PORT:
            if v.check_position_packet(d.payload) != v.PacketKind.POSITION:
                pos_bad += 1
                continue
            pos += 1
            s = v.position_nmea(d.payload)
            nmea.add(s.split(",")[0] if s else "")
    data_t = np.asarray(data_t, dtype=np.int64)
    dtoh = np.diff(np.asarray(unwrap_toh_us(toh), dtype=np.int64))
    dur = (data_t[-1] - data_t[0]) * 1e-9 if len(data_t) > 1 else float("nan")
    return {
        "data_packets": int(len(data_t)),
        "malformed": bad,
        "packets_per_s": (len(data_t) - 1) / dur if len(data_t) > 1 else float("nan"),
        "toh_step_us": sorted({int(x) for x in np.unique(dtoh)}) if len(dtoh) else [],
        "azimuth_step_centideg": float(np.median(az_step)) if az_step else float("nan"),
        "return_modes": sorted(modes),
        "products": sorted(products),
        "position_packets": pos,
        "position_malformed": pos_bad,
        "nmea": sorted(nmea),
        "expected_period_us": meta["derived"]["packet_period_ns"] / 1e3,
    }


def read_imu_truth(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(host_ns (N,) int64, sample_ns (N,) int64, q (N, 4) w, x, y, z) of gt/imu_truth.csv."""
    ints = np.loadtxt(path, delimiter=",", comments="#", usecols=(0, 1), dtype=np.int64, ndmin=2)
    q = np.loadtxt(path, delimiter=",", comments="#", usecols=(2, 3, 4, 5), ndmin=2)
    return ints[:, 0], ints[:, 1], q


def imu_check(capture_dir: str | Path) -> dict:
    """Parse the IMU log like live data; compare its quaternions with gt/imu_truth.csv."""
    meta, cfg = load_meta(capture_dir)
    log = ImuLogReader(Path(capture_dir) / IMU_FILE)
    host, q = log.parse_quaternions()
    th, _sample_ns, qt = read_imu_truth(Path(capture_dir) / "gt" / "imu_truth.csv")
    n = min(len(host), len(th))
    same_time = bool(n == len(th) and np.array_equal(host[:n], th[:n]))
    dot = np.abs(np.einsum("ij,ij->i", q[:n], qt[:n]))
    ang = 2 * np.arccos(np.clip(dot, -1.0, 1.0))  # rad
    # for white noise sigma per axis, the error angle has E[ang^2] = 3 sigma^2
    sigma_est = float(np.degrees(np.sqrt(np.mean(ang**2) / 3))) if n else float("nan")
    parser_garbage = 0
    if log.protocol == "tfp":
        p = tfp.TfpStreamParser(uid=tfp.base58_decode(cfg.imu.uid))
        for rec in log:
            p.feed(rec.data)
        parser_garbage = p.garbage_bytes
    rate = (n - 1) / ((host[n - 1] - host[0]) * 1e-9) if n > 1 else float("nan")
    return {"samples": int(len(host)), "truth_samples": int(len(th)), "times_match": same_time,
            "sigma_est_deg": sigma_est, "configured_sigma_deg": cfg.imu.noise_deg,
            "max_err_deg": float(np.degrees(ang.max())) if n else float("nan"),
            "rate_hz": rate, "garbage_bytes": parser_garbage, "protocol": log.protocol}
