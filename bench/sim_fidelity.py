#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Fidelity of the digital twin, and how fast it generates.

For each scene: a noise-free capture (decoded points placed with the true pose: distance to the
mesh, label agreement), a capture with the default noise (range sigma, IMU sigma), packet
rates and timing fields in single and dual return; then a 12-station capture (about 3 minutes
of sensor time) timed on 2 ray-casting threads, and the replayer at 1x and at max rate.

    python bench/sim_fidelity.py            # everything (a few minutes on 2 cores)
    python bench/sim_fidelity.py --quick    # one scene, no 12-station run
"""

from __future__ import annotations

import argparse
import os
import resource
import socket
import sys
import tempfile
from pathlib import Path

from rich.console import Console
from rich.table import Table

from tripod_processor.io.replay import Replayer, ReplaySource
from tripod_processor.sim import SCENE_NAMES, SimConfig, simulate
from tripod_processor.sim import fidelity as F

SHORT = {"pan_s": 4.0, "settle_s": 0.3, "transit_s": 2.0}


def cfg(**kw) -> SimConfig:
    base = {"stations": 2, "motion": dict(SHORT)}
    for k, v in kw.items():
        base[k] = {**base.get(k, {}), **v} if isinstance(v, dict) else v
    return SimConfig.model_validate(base)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one scene, skip the 12-station run")
    ap.add_argument("--stations", type=int, default=12, help="stations of the speed run")
    ap.add_argument("--keep", type=Path, help="keep the captures in this directory")
    args = ap.parse_args(argv)
    con = Console(width=170)
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        return run(args, con, args.keep)
    with tempfile.TemporaryDirectory(prefix="sim_fidelity_") as tmp:
        return run(args, con, Path(tmp))


def run(args, con: Console, root: Path) -> int:
    scenes = SCENE_NAMES[:1] if args.quick else SCENE_NAMES

    geo = Table(title="Geometry: decoded with velodyne-decoder, placed with the true pose")
    for c in ("scene", "points", "noise-free median", "noise-free p99", "labels agree",
              "sigma set", "range sigma (robust)", "range std"):
        geo.add_column(c, justify="right")
    for i, sc in enumerate(scenes):
        clean = root / f"{sc}_clean"
        simulate(cfg(scene=sc, seed=i, lidar={"range_noise_m": 0.0, "dropout": 0.0},
                     imu={"noise_deg": 0.0}), clean, nthreads=2)
        noisy = root / f"{sc}_noisy"
        simulate(cfg(scene=sc, seed=i), noisy, nthreads=2)
        a, b = F.geometry_check(clean), F.geometry_check(noisy)
        geo.add_row(sc, f"{a.n_points}", f"{a.dist_median_m * 1e3:.2f} mm",
                    f"{a.dist_p99_m * 1e3:.2f} mm", f"{a.label_agreement * 100:.2f} %",
                    f"{b.configured_sigma_m * 100:.1f} cm",
                    f"{b.range_err_robust_std_m * 100:.2f} cm", f"{b.range_err_std_m * 100:.2f} cm")
    con.print(geo)

    pk = Table(title="Packets and IMU (VLP-16 reference: 754 packets/s single, 1508 dual at "
                     "600 rpm)")
    for c in ("capture", "packets/s", "timestamp steps us", "azimuth step", "factory bytes",
              "position pkts", "NMEA", "IMU rate", "IMU sigma set", "IMU sigma measured"):
        pk.add_column(c, justify="right")
    dual = root / "dual_gps_wit"
    simulate(cfg(scene="two_rooms", seed=5, lidar={"return_mode": "dual", "gps": True},
                 imu={"protocol": "witmotion"}), dual, nthreads=2)
    last = root / "last_1200rpm"
    simulate(cfg(scene="corridor", seed=6, lidar={"return_mode": "last", "rpm": 1200}), last,
             nthreads=2)
    for name, d in ((f"{scenes[0]} strongest", root / f"{scenes[0]}_noisy"),
                    ("two_rooms dual+GPS+WitMotion", dual), ("corridor last 1200 rpm", last)):
        p, m = F.packet_check(d), F.imu_check(d)
        pk.add_row(name, f"{p['packets_per_s']:.1f}", ",".join(map(str, p["toh_step_us"])),
                   f"{p['azimuth_step_centideg'] / 100:.2f} deg",
                   "/".join(f"0x{x:02x}" for x in p["return_modes"] + p["products"]),
                   str(p["position_packets"]), ",".join(p["nmea"]) or "(none)",
                   f"{m['rate_hz']:.1f} Hz {m['protocol']}", f"{m['configured_sigma_deg']:.3f} deg",
                   f"{m['sigma_est_deg']:.3f} deg")
    con.print(pk)

    sp = Table(title="Generation speed and replay (this machine)")
    sp.add_column("run")
    sp.add_column("result", justify="right")
    if not args.quick:
        big = root / f"{args.stations}_stations"
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        s = simulate(SimConfig(stations=args.stations, seed=1), big, nthreads=2)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        sp.add_row(f"simulate room, {args.stations} stations, 2 threads",
                   f"{s.duration_s:.1f} s of sensor time in {s.wall_s:.1f} s wall "
                   f"({s.realtime_factor:.1f}x real time), {cpu:.1f} s CPU, "
                   f"{s.data_packets} packets")
    src = ReplaySource.open(root / f"{scenes[0]}_noisy")
    hole = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    hole.bind(("127.0.0.1", 0))
    st = Replayer(src, rate=1.0, lidar_addr=hole.getsockname(), position_addr=hole.getsockname(),
                  limit_s=5.0, realtime_priority=10).run()
    sp.add_row("replay 1x, 5 s, loopback",
               f"rate {st.achieved_rate:.3f}x, jitter p50 {st.jitter_us(50):.0f} us, "
               f"p99 {st.jitter_us(99):.0f} us, max {st.jitter_us(100):.0f} us ({st.scheduling})")
    st = Replayer(ReplaySource.open(dual), rate=float("inf"), lidar_addr=hole.getsockname(),
                  position_addr=hole.getsockname()).run()
    sp.add_row("replay max, dual capture",
               f"{st.packets_per_s:.0f} packets/s = {st.packets_per_s / 1507.5:.1f}x the dual "
               f"rate ({st.achieved_rate:.1f}x real time)")
    hole.close()
    con.print(sp)
    con.print(f"cores: {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}"
              + (f"; captures kept in {root}" if args.keep else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
