# SPDX-License-Identifier: BSD-3-Clause
"""Write one simulated capture directory (the output of ``tripod simulate``).

Steps: scene -> trajectory -> lidar packets in chunks (ray cast, encode, write pcap, keep
labels) -> IMU stream -> ground truth, mesh, meta. See the README section "Digital twin" for
every file.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tripod_shared import velodyne as v
from tripod_shared.timebase import HOUR_NS

from ..io.imu_log import write_imu_log
from ..io.pcap import PcapWriter
from .beams import LASER_ELEVATION_DEG
from .config import SimConfig
from .imu import R_lidar_imu, simulate_imu, wxyz
from .lidar import (SEQUENCE_NS, Vlp16, gprmc, packet_period_ns, position_packet,
                    position_schedule)
from .motion import Trajectory
from .scenes import (CLASS_NAMES, NO_RETURN, Scene, check_route, load_scene_file, make_scene,
                     write_mesh_ply)

FORMAT_VERSION = 1
CAPTURE_FILE = "capture.pcap"
IMU_FILE = "imu.tripimu"
LABELS_FILE = "labels.npz"
MESH_FILE = "mesh.ply"
META_FILE = "meta.json"
MCAP_FILE = "recording.mcap"
OVERVIEW_FILE = "overview.png"
CONFIG_FILE = "config.yaml"
GT_DIR = "gt"


@dataclass
class SimSummary:
    out_dir: Path
    duration_s: float
    data_packets: int
    position_packets: int
    imu_samples: int
    stations: int
    wall_s: float

    @property
    def realtime_factor(self) -> float:
        """Sensor time per wall time (> 1: faster than real time)."""
        return self.duration_s / max(self.wall_s, 1e-9)


def build_scene(cfg: SimConfig) -> Scene:
    if cfg.scene_file:
        return load_scene_file(cfg.scene_file, cfg.seed)
    if cfg.scene_size is not None:
        return make_scene(cfg.scene, cfg.seed, cfg.scene_size.model_dump())
    return make_scene(cfg.scene, cfg.seed)


def build_rig(cfg: SimConfig, scene: Scene | None = None) -> tuple[Scene, Trajectory]:
    """The scene and the trajectory of a config (deterministic per seed)."""
    scene = scene or build_scene(cfg)
    route, closed = route_of(cfg, scene)
    traj = Trajectory(route, closed, cfg.stations, cfg.motion,
                      np.random.default_rng([cfg.seed, 0x7A3]), floor_z=scene.floor_z,
                      pan_rng=np.random.default_rng([cfg.seed, 0x9A4]))
    return scene, traj


def route_of(cfg: SimConfig, scene: Scene) -> tuple[np.ndarray, bool]:
    """The route of a capture: ``route_xy`` from the config, else the scene's own."""
    if cfg.route_xy is not None:
        return np.asarray(cfg.route_xy, dtype=np.float64), cfg.route_closed
    return scene.route, scene.closed_route


def _tum_line(t_ns: int, p, q_wxyz) -> str:
    s, ns = divmod(int(t_ns), 1_000_000_000)
    return (f"{s}.{ns:09d} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} "
            f"{q_wxyz[1]:.9f} {q_wxyz[2]:.9f} {q_wxyz[3]:.9f} {q_wxyz[0]:.9f}\n")


def _T(R: np.ndarray, p) -> list[list[float]]:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return [[round(float(x), 12) for x in row] for row in T]


def simulate(cfg: SimConfig, out_dir: str | os.PathLike, *, nthreads: int = 0,
             progress: Callable[[int, int], None] | None = None,
             chunk_packets: int = 754) -> SimSummary:
    """Simulate the capture described by ``cfg`` into ``out_dir`` (created if needed).

    ``progress(done, total)`` is called after each chunk of data packets.
    """
    wall0 = time.perf_counter()
    out = Path(out_dir)
    scene = build_scene(cfg)
    check_route(scene, *route_of(cfg, scene))  # fail early, in one line, on a blocked route
    (out / GT_DIR).mkdir(parents=True, exist_ok=True)
    scene, traj = build_rig(cfg, scene)
    lc = cfg.lidar
    start = cfg.start_unix_ns
    duration_ns = int(round(traj.duration_s * 1e9))
    period = packet_period_ns(lc.return_mode)
    n_packets = duration_ns // period
    lidar = Vlp16(lc, scene, traj, start, cfg.seed, nthreads=nthreads)

    # position packets: send times, then payloads (toh on the lidar clock)
    pos_rng = np.random.default_rng([cfg.seed, 0x905])
    pos_t = position_schedule(duration_ns, cfg.seed) if lc.position_packets else np.zeros(0, int)
    pos_recv = start + pos_t + np.round(lc.network_latency_us * 1e3 + pos_rng.exponential(
        max(lc.network_jitter_us, 1e-9) * 1e3, len(pos_t))).astype(np.int64)
    pos_recv = np.maximum.accumulate(pos_recv) if len(pos_recv) else pos_recv
    pps = 2 if lc.gps else 0

    labels = np.empty((n_packets, 12, 32), dtype=np.uint8)
    toh = np.empty(n_packets, dtype=np.uint32)
    recv = np.empty(n_packets, dtype=np.int64)
    first_fire = np.empty(n_packets, dtype=np.int64)
    pi = 0  # next position packet
    with PcapWriter(out / CAPTURE_FILE, src_ip=lc.src_ip, dst_ip=lc.dst_ip) as pw:
        def write_positions(until_ns: int) -> None:
            nonlocal pi
            while pi < len(pos_t) and pos_recv[pi] <= until_ns:
                dev_ns = start + int(pos_t[pi]) + lc.clock_offset_ns
                nmea = gprmc(dev_ns, lc.gps_lat_deg, lc.gps_lon_deg) if lc.gps else ""
                pw.write_udp(int(pos_recv[pi]), position_packet((dev_ns % HOUR_NS) // 1000, pps,
                                                                nmea),
                             v.POSITION_PORT, v.POSITION_PORT)
                pi += 1

        for first in range(0, n_packets, chunk_packets):
            count = min(chunk_packets, n_packets - first)
            batch = lidar.packets(first, count)
            sl = slice(first, first + count)
            labels[sl] = batch.labels
            toh[sl] = batch.payloads[:, v.TIMESTAMP_OFFSET:v.TIMESTAMP_OFFSET + 4].copy().view(
                "<u4")[:, 0]
            rv = batch.recv_ns
            if first > 0:  # never earlier than the previous packet (one NIC queue)
                rv = np.maximum(rv, recv[first - 1])
            rv = np.maximum.accumulate(rv)
            recv[sl] = rv
            first_fire[sl] = start + batch.first_firing_ns
            for i in range(count):
                write_positions(int(rv[i]))
                pw.write_udp(int(rv[i]), batch.payloads[i].tobytes(), v.DATA_PORT, v.DATA_PORT)
            if progress:
                progress(first + count, n_packets)
        write_positions(start + duration_ns + 10**9)
        n_pos = pi

    np.savez_compressed(out / LABELS_FILE, labels=labels, packet_toh_us=toh,
                        packet_recv_ns=recv, packet_first_firing_ns=first_fire,
                        class_names=np.array(CLASS_NAMES), no_return=np.uint8(NO_RETURN),
                        return_mode=np.array(lc.return_mode))

    # IMU
    imu = simulate_imu(cfg.imu, traj, duration_ns, start, cfg.seed)
    write_imu_log(out / IMU_FILE, cfg.imu.protocol, imu.host_ns, imu.chunks)
    with open(out / GT_DIR / "imu_truth.csv", "w") as fh:
        fh.write("# host_ns,sample_ns,qw,qx,qy,qz  (host_realtime ns; R_ref_imu without noise)\n")
        for h, s_, q in zip(imu.host_ns.tolist(), (start + imu.sample_ns).tolist(),
                            imu.q_true.tolist()):
            fh.write(f"{h},{s_},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}\n")

    _write_ground_truth(out, cfg, scene, traj, duration_ns)
    if cfg.mcap:
        write_recording(out, cfg)
    write_mesh_ply(out / MESH_FILE, scene)
    from .plot import plot_overview

    plot_overview(out / OVERVIEW_FILE, scene, traj, route_of(cfg, scene)[0])
    wall = time.perf_counter() - wall0
    summary = SimSummary(out, duration_ns * 1e-9, int(n_packets), int(n_pos), len(imu.host_ns),
                         cfg.stations, wall)
    _write_meta(out, cfg, scene, traj, lidar, summary, duration_ns)
    with open(out / CONFIG_FILE, "w") as fh:
        fh.write("# effective config of this capture: tripod simulate --config config.yaml\n")
        yaml.safe_dump(cfg.model_dump(mode="json"), fh, sort_keys=False)
    return summary


def write_recording(out: Path, cfg: SimConfig) -> Path:
    """``recording.mcap``: the capture as the daemon would record it (every packet and IMU
    sample at its host receive time, IMU samples decoded with their raw bytes)."""
    from tripod_shared import tfp, witmotion
    from tripod_shared.messages import Event, ImuSample
    from tripod_shared.recording import RecordingWriter

    from ..io.events import IMU, LIDAR, POSITION, folder_events

    first = last = None
    with RecordingWriter(out / MCAP_FILE, metadata={"source": "tripod simulate",
                                                    "seed": str(cfg.seed)}) as w:
        tp = tfp.TfpStreamParser()
        wp = witmotion.WitStreamParser()
        for t_ns, kind, data in folder_events(out):
            if first is None:
                first = t_ns
                w.write_event(Event(t_ns, "start", "simulated capture"))
            last = t_ns
            if kind == LIDAR:
                w.write_lidar_packet(t_ns, data)
            elif kind == POSITION:
                w.write_position_packet(t_ns, data)
            elif kind == IMU and cfg.imu.protocol == "tfp":
                for pk in tp.feed(data):
                    if pk.function_id == tfp.FID_CALLBACK_QUATERNION:
                        q = tfp.decode_quaternion(pk.payload)
                        w.write_imu(ImuSample(t_ns, *q, driver="tfp", sequence=pk.sequence,
                                              raw=pk.raw))
            elif kind == IMU:
                for fr in wp.feed(data):
                    if fr.ftype == witmotion.TYPE_QUATERNION:
                        q = witmotion.decode_quaternion(fr.data)
                        w.write_imu(ImuSample(t_ns, *q, driver="witmotion", raw=fr.raw))
        if last is not None:
            w.write_event(Event(last, "stop", "simulated capture"))
    return out / MCAP_FILE


def _write_ground_truth(out: Path, cfg: SimConfig, scene: Scene, traj: Trajectory,
                        duration_ns: int) -> None:
    start = cfg.start_unix_ns
    gt = out / GT_DIR
    step = int(round(1e9 / cfg.gt_rate_hz))
    t_ns = np.arange(0, duration_ns + 1, step, dtype=np.int64)
    with open(gt / "trajectory.tum", "w") as fh:
        fh.write("# T_world_lidar: timestamp[s host_realtime] x y z qx qy qz qw\n")
        for c in range(0, len(t_ns), 20000):
            tt = t_ns[c:c + 20000]
            R, p = traj.T_world_lidar(tt * 1e-9)
            q = wxyz(R)
            fh.write("".join(_tum_line(start + a, b, qq) for a, b, qq in zip(tt, p, q)))
    with open(gt / "stations.tum", "w") as fh, open(gt / "stations.csv", "w") as fc:
        fh.write("# T_world_base of each station at its pan start: t x y z qx qy qz qw\n")
        fc.write("index,pan_start_ns,pan_end_ns,x,y,z,qw,qx,qy,qz\n")
        for st in traj.stations:
            q = wxyz(st.R_world_base[None])[0]
            t0 = start + int(round(st.t_pan_start_s * 1e9))
            t1 = start + int(round(st.t_pan_end_s * 1e9))
            fh.write(_tum_line(t0, st.position, q))
            x, y, z = st.position
            fc.write(f"{st.index},{t0},{t1},{x:.6f},{y:.6f},{z:.6f},"
                     f"{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}\n")
    ic = cfg.imu
    calib = {
        "frames": "world (z up), base (tripod head, station pose), pan = base turned Rz(phi), "
                  "lidar (velodyne-decoder output frame), imu; T_a_b maps points of b into a",
        "T_pan_lidar": _T(traj.R_pan_lidar, traj.t_pan_lidar),
        "T_lidar_imu": _T(R_lidar_imu(ic), ic.t_lidar_imu_m),
        "imu_reference": {
            "description": "the IMU reports "
                           "R_ref_imu = Rz(yaw_offset + yaw_drift * t) R_world_imu, "
                           "t = seconds since the capture start",
            "yaw_offset_deg": ic.yaw_offset_deg,
            "yaw_drift_deg_per_min": ic.yaw_drift_deg_per_min,
        },
        "laser_elevation_deg": LASER_ELEVATION_DEG.tolist(),
    }
    (gt / "calibration.json").write_text(json.dumps(calib, indent=2) + "\n")
    lc = cfg.lidar
    clocks = {
        "start_unix_ns": start,
        "duration_ns": duration_ns,
        "lidar_clock_offset_ns": lc.clock_offset_ns,
        "lidar_clock_description": "lidar_toh = (host_realtime + lidar_clock_offset_ns) mod 1 h, "
                                   "in us, truncated",
        "lidar_receive_latency_us": {"mean": lc.network_latency_us + lc.network_jitter_us,
                                     "after": "the last firing of the packet"},
        "imu_latency_ms": {"mean": cfg.imu.latency_ms + cfg.imu.latency_jitter_ms,
                           "after": "the instant the sample describes"},
        "imu_clock_drift_ppm": cfg.imu.clock_drift_ppm,
        "firing": {"sequence_ns": SEQUENCE_NS, "laser_ns": 2304,
                   "first_sequence_at_ns": start},
    }
    (gt / "clocks.json").write_text(json.dumps(clocks, indent=2) + "\n")


def truth_of(cfg: SimConfig, traj: Trajectory) -> dict:
    """What a processor should recover from the capture (meta.json ``truth``).

    Stations: ``still`` = the tripod stands (carry to carry; the head may turn), ``pan`` = the
    head turns; both in host_realtime ns and on the lidar time line (host + lidar clock offset,
    the time line of ``evaluation.load_sim_truth``). Calibration in the processor's terms:
    ``q_imu_lidar`` and the lever arm pivot -> lidar in the IMU frame (as
    ``placement.load_extrinsic_file`` reads gt/calibration.json), split into its component
    along the pan axis (unobservable: it moves every point of a station alike) and across it.
    ``imu_time_offset_ms``: what to add to the IMU's de-jittered host stamps = minus the
    latency floor ``latency_ms`` (the exponential jitter's 1st percentile is 1 % of
    ``latency_jitter_ms``).
    """
    start, off = cfg.start_unix_ns, int(cfg.lidar.clock_offset_ns)

    def host(t_s: float) -> int:
        return start + int(round(t_s * 1e9))

    def span(a: float, b: float) -> dict:
        return {"host_ns": [host(a), host(b)], "lidar_ns": [host(a) + off, host(b) + off]}

    still = traj.still_intervals_s()
    stations = []
    for st, (a, b) in zip(traj.stations, still):
        t0 = st.t_pan_start_s
        plan = traj.pans[st.index] if traj.pans is not None else None
        stations.append({
            "index": st.index, "still": span(a, b), "still_s": [round(a, 6), round(b, 6)],
            "pan": span(st.t_pan_start_s, st.t_pan_end_s),
            "net_turn_deg": round(float(np.degrees(traj.pan_net_rad(st.index))), 6),
            "pauses": [span(t0 + x, t0 + y) for x, y in (plan.pauses_s if plan else [])],
            "reversals": [span(t0 + x, t0 + y) for x, y in (plan.reversals_s if plan else [])],
        })
    R_il = R_lidar_imu(cfg.imu).T
    R_pl, t_pl = traj.R_pan_lidar, traj.t_pan_lidar
    ell = R_il @ R_pl.T @ t_pl
    axis = R_il @ R_pl.T @ np.array([0.0, 0.0, 1.0])
    along = float(ell @ axis)
    q = wxyz(R_il[None])[0]
    ic = cfg.imu
    return {
        "stations": stations,
        "carries_s": [round(float(x), 6) for x in traj.transit_s],
        "pan_profile": cfg.motion.pan_profile,
        "tilt_deg": cfg.motion.tilt_deg,
        "lever_arm_pan_m": [round(float(x), 9) for x in t_pl],
        "lever_arm_imu_m": [round(float(x), 9) for x in ell],
        "pan_axis_imu": [round(float(x), 9) for x in axis],
        "lever_arm_along_axis_m": round(along, 9),
        "lever_arm_across_axis_m": round(float(np.linalg.norm(ell - along * axis)), 9),
        "q_imu_lidar_wxyz": [round(float(x), 12) for x in q],
        "imu_latency_ms": ic.latency_ms,
        "imu_latency_jitter_ms": ic.latency_jitter_ms,
        "imu_time_offset_ms": -ic.latency_ms,
        "lidar_clock_offset_ns": off,
        "return_mode": cfg.lidar.return_mode,
    }


def _write_meta(out: Path, cfg: SimConfig, scene: Scene, traj: Trajectory, lidar: Vlp16,
                s: SimSummary, duration_ns: int) -> None:
    import open3d

    meta = {
        "format_version": FORMAT_VERSION,
        "generator": "tripod simulate",
        "config": cfg.model_dump(mode="json"),
        "scene": {"name": scene.name, "params": scene.params, "triangles": len(scene.triangles),
                  "class_triangles": scene.class_counts(),
                  "bounds_m": [b.round(4).tolist() for b in scene.bounds],
                  "route_length_m": round(traj.route.length, 4),
                  "route_xy": np.round(route_of(cfg, scene)[0], 4).tolist(),
                  "route_closed": route_of(cfg, scene)[1]},
        "derived": {
            "duration_s": s.duration_s,
            "data_packets": s.data_packets,
            "position_packets": s.position_packets,
            "imu_samples": s.imu_samples,
            "packet_period_ns": packet_period_ns(cfg.lidar.return_mode),
            "packets_per_s": 1e9 / packet_period_ns(cfg.lidar.return_mode),
            "azimuth0_deg": lidar.azimuth0_deg,
            "transit_s": [round(float(x), 6) for x in traj.transit_s],
            "stations": [{"index": st.index, "pan_start_s": st.t_pan_start_s,
                          "pan_end_s": st.t_pan_end_s} for st in traj.stations],
        },
        "truth": truth_of(cfg, traj),
        "files": {
            CAPTURE_FILE: "VLP-16 data (2368) and position (8308) packets, Ethernet/IPv4/UDP, "
                          "ns pcap, host receive times",
            IMU_FILE: "IMU byte stream with host read times (tripod IMU log)",
            LABELS_FILE: "class of every block/channel of every data packet",
            MESH_FILE: "scene mesh with per-face class and reflectivity",
            "gt/trajectory.tum": "T_world_lidar at gt_rate_hz",
            "gt/stations.tum": "T_world_base per station", "gt/stations.csv": "stations, times",
            "gt/calibration.json": "extrinsics", "gt/clocks.json": "clock offsets, latencies",
            "gt/imu_truth.csv": "noise-free IMU quaternions",
            CONFIG_FILE: "effective config",
            OVERVIEW_FILE: "top view: scene, route, tripod path, stations",
            **({MCAP_FILE: "the capture as the daemon records it"} if cfg.mcap else {}),
        },
        "generation": {"wall_s": round(s.wall_s, 3), "realtime_factor": round(s.realtime_factor, 3),
                       "python": platform.python_version(), "open3d": open3d.__version__,
                       "cpus": os.cpu_count()},
    }
    (out / META_FILE).write_text(json.dumps(meta, indent=2) + "\n")
