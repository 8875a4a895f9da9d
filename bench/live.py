# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark of ``tripod live``: does it keep up with the dual-return stream, and how far behind?

A simulated capture (VLP-16 dual return, 1507 packets/s, IMU) is replayed over loopback UDP and
a pseudo-terminal into a running daemon (its own process, Zenoh on); ``tripod live`` (its own
process) subscribes and serves Foxglove. Rows: replay at 1x (the sensor's rate) and faster, to
show the live view dropping rotations instead of falling behind. Columns: rotations the daemon's
stream carried (as cut by the live view), shown, dropped; lag = when a rotation was published to
Foxglove minus the daemon's host stamp of its last packet (both host_realtime on this machine),
median and 95th percentile; the live process's CPU (utime + stime over its life, including
start-up and its idle wait after the replay).

    python bench/live.py            # 1x, 2x, 4x of a 2-station capture (~1 minute)
    python bench/live.py --quick    # 1x only
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from tripod_processor.io.replay import PtyImuSink, Replayer, ReplaySource
from tripod_processor.sim import SimConfig, simulate


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


def start_daemon(workdir: Path, imu_path: str, uid: int):
    zport = free_port()
    cfg = workdir / "daemon.yaml"
    cfg.write_text(
        "lidar:\n  bind_address: 127.0.0.1\n  data_port: 0\n  position_port: 0\n"
        "  receive_buffer_bytes: 67108864\n"
        f"imu:\n  url: {imu_path}\n  driver: tfp\n  tfp_uid: {uid}\n"
        f"recording:\n  directory: {workdir / 'rec'}\n  min_free_bytes: 0\n"
        f"zenoh:\n  listen: [tcp/127.0.0.1:{zport}]\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "tripod_daemon", "--no-system-config", "--config", str(cfg)],
        stderr=subprocess.PIPE, text=True)
    ports: dict[str, int] = {}
    ready = threading.Event()

    def pump():
        for line in proc.stderr:
            m = re.search(r"data on [\d.]+:(\d+)", line)
            if m:
                ports["data"] = int(m.group(1))
            m = re.search(r"position on [\d.]+:(\d+)", line)
            if m:
                ports["position"] = int(m.group(1))
            if "recording to" in line:
                ready.set()

    threading.Thread(target=pump, daemon=True).start()
    if not ready.wait(30) or "data" not in ports:
        proc.kill()
        raise RuntimeError("daemon did not start")
    return proc, zport, ports


def run_row(capture: Path, rate: float, zport: int, ports: dict, sink) -> dict:
    wport = free_port()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    live = subprocess.Popen(
        [sys.executable, "-m", "tripod_processor", "live", "--connect",
         f"tcp/127.0.0.1:{zport}", "--port", str(wport), "--duration", "600"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)  # start-up: imports, the Foxglove server, the zenoh session
    t0 = time.monotonic()
    Replayer(ReplaySource.open(capture), rate=rate, lidar_addr=("127.0.0.1", ports["data"]),
             position_addr=("127.0.0.1", ports.get("position", 9)), imu_sink=sink).run()
    replay_s = time.monotonic() - t0
    time.sleep(2.0)
    live.send_signal(2)  # SIGINT: the live view stops and prints its counters
    out, err = live.communicate(timeout=30)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if live.returncode != 0:
        raise RuntimeError(f"tripod live failed:\n{err}")
    s = json.loads(out.strip().splitlines()[-1])
    s["cpu_s"] = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    s["replay_s"] = replay_s
    s["rate"] = rate
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1x only")
    args = ap.parse_args(argv)
    rates = [1.0] if args.quick else [1.0, 2.0, 4.0]
    with tempfile.TemporaryDirectory(prefix="tripod-bench-live-") as tmp:
        work = Path(tmp)
        cfg = SimConfig.model_validate({
            "stations": 2, "seed": 7, "lidar": {"return_mode": "dual"},
            "motion": {"pan_s": 4.0, "settle_s": 0.2, "pan_ramp_s": 0.3, "transit_s": 1.0}})
        capture = work / "capture"
        print("simulating a 2-station dual-return capture ...", file=sys.stderr)
        simulate(cfg, capture, nthreads=2)
        sink = PtyImuSink()
        daemon, zport, ports = start_daemon(work, sink.path, SimConfig().imu.uid)
        rows = []
        try:
            for rate in rates:
                rows.append(run_row(capture, rate, zport, ports, sink))
        finally:
            daemon.terminate()
            daemon.wait(30)
            sink.close()
    print(f"tripod live, dual return (1507 packets/s at 1x), on {os.cpu_count()} cores shared "
          "with the daemon and the replayer")
    hdr = (f"{'rate':>5} {'replay s':>8} {'rotations':>9} {'shown':>6} {'dropped':>7} "
           f"{'lag median s':>12} {'lag p95 s':>9} {'live CPU s':>10}  stations [s, ended by]")
    print(hdr)
    print("-" * len(hdr))
    for s in rows:
        print(f"{s['rate']:>4.0f}x {s['replay_s']:>8.1f} {s['rotations']:>9} "
              f"{s['rotations_shown']:>6} {s['rotations_dropped']:>7} "
              f"{s['lag_median_s']:>12.3f} {s['lag_p95_s']:>9.3f} {s['cpu_s']:>10.1f}  "
              + ", ".join(f"{t['duration_s']:.1f} {t['ended_by']}" for t in s["stations"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
