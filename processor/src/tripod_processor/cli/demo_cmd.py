# SPDX-License-Identifier: BSD-3-Clause
"""``tripod demo``: the whole system on bundled defaults, end to end, on this machine.

1. ``tripod simulate``: a multi-room capture with ground truth (the digital twin);
2. ``tripod-daemon``: started as its own process on free loopback ports, recording MCAP;
3. ``tripod replay``: the capture sent into it over UDP and a pseudo-terminal (the IMU);
4. the daemon stopped with SIGTERM (it finishes its file);
5. ``tripod reconstruct`` on the daemon's recording, checked against the simulator's truth;
   a results table, and where the report is. The processor is not told the rig's calibration:
   the simulated rig has a lever arm of 10 cm across the pan axis, a 60° mount and a 5 ms IMU
   latency (``DEMO_RIG``), which the reconstruction finds from the data.

Nothing is downloaded; the network is loopback only.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import typer

from . import app
from ._common import console, fail


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _daemon_exe() -> list[str]:
    exe = shutil.which("tripod-daemon")
    if exe is None:
        cand = Path(sys.executable).with_name("tripod-daemon")
        if cand.exists():
            exe = str(cand)
    if exe is not None:
        return [exe]
    return [sys.executable, "-m", "tripod_daemon"]


class _Daemon:
    """``tripod-daemon`` as a child process; READY=1 is awaited on a private NOTIFY_SOCKET."""

    def __init__(self, record_dir: Path, data_port: int, position_port: int, imu_url: str,
                 log_path: Path):
        self.sock_dir = Path(tempfile.mkdtemp(prefix="tripod-demo-"))
        self.sock_path = self.sock_dir / "notify"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.sock_path))
        self.sock.settimeout(0.5)
        env = dict(os.environ, NOTIFY_SOCKET=str(self.sock_path))
        self.log = open(log_path, "w")
        # a desktop is no tripod computer: lz4 chunks and no fsync per chunk keep the writer
        # ahead on a busy machine (the daemon's defaults are zstd and fsync per chunk)
        conf = self.sock_dir / "daemon.yaml"
        conf.write_text("recording:\n  compression: lz4\n  fsync: never\n")
        cmd = _daemon_exe() + ["--no-system-config", "--config", str(conf),
                               "--lidar-port", str(data_port),
                               "--position-port", str(position_port), "--imu", imu_url,
                               "--imu-driver", "tfp", "--record-dir", str(record_dir),
                               "--no-zenoh"]
        self.proc = subprocess.Popen(cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT)

    def wait_ready(self, timeout: float = 30.0) -> bool:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if self.proc.poll() is not None:
                return False
            try:
                msg = self.sock.recv(4096).decode(errors="replace")
            except socket.timeout:
                continue
            if "READY=1" in msg.split("\n"):
                # keep reading WATCHDOG/STATUS as systemd would: a full socket blocks the sender
                self._drain = threading.Thread(target=self._drain_notify, daemon=True)
                self._drain.start()
                return True
        return False

    def _drain_notify(self) -> None:
        self.last_status = ""
        while True:
            try:
                msg = self.sock.recv(4096).decode(errors="replace")
            except socket.timeout:
                continue
            except OSError:
                return
            for line in msg.split("\n"):
                if line.startswith("STATUS="):
                    self.last_status = line[7:]

    def stop(self, timeout: float = 300.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.sock.close()
        self.log.close()
        shutil.rmtree(self.sock_dir, ignore_errors=True)
        return int(self.proc.returncode)


#: the demo's rig: what the processor must find from the data (lidar origin in the pan frame,
#: spin axis tilted 60° from the pan axis, IMU read 5 ms late)
DEMO_RIG = {"motion": {"lever_arm_m": [0.08, 0.06, 0.10], "tilt_deg": 60.0},
            "imu": {"latency_ms": 5.0}}


@app.command("demo", rich_help_panel="Run")
def demo_command(
    output: Path = typer.Option(Path("demo-output"), "-o", "--output",
                                help="folder for the demo's outputs"),
    scene: str = typer.Option("two_rooms", "--scene", help="simulated scene"),
    stations: int = typer.Option(6, "--stations", help="stations of the simulated capture"),
    seed: int = typer.Option(7, "--seed", help="simulation seed"),
    rate: float = typer.Option(2.0, "--rate", help="replay speed into the daemon (1 = real "
                                                  "time)"),
) -> None:
    """Simulate a capture, record it with the daemon over loopback, reconstruct it, check it."""
    from ..reconstruction.config import ReconstructConfig
    from ..reconstruction.evaluation import evaluate_run, load_sim_truth
    from ..reconstruction.inputs import RecordingError
    from ..reconstruction.pipeline import reconstruct, summary
    from ..io.replay import PtyImuSink, Replayer, ReplaySource
    from ..sim import SimConfig, simulate

    output.mkdir(parents=True, exist_ok=True)
    capture = output / "capture"
    record_dir = output / "recording"
    recon_dir = output / "reconstruction"
    for d in (capture, record_dir, recon_dir):
        shutil.rmtree(d, ignore_errors=True)
    record_dir.mkdir(parents=True)
    t_all = time.perf_counter()
    steps: list[tuple[str, str, float]] = []

    # 1. simulate
    t0 = time.perf_counter()
    console.print(f"[bold]1/5[/] simulating a '{scene}' capture with {stations} stations")
    try:
        sim = simulate(SimConfig.model_validate({"scene": scene, "stations": stations,
                                                 "seed": seed, **DEMO_RIG}), capture)
    except ValueError as exc:
        fail(f"simulate: {exc}")
    steps.append(("simulate", f"{sim.duration_s:.0f} s of sensor time, {sim.data_packets} "
                              "packets", time.perf_counter() - t0))

    # 2. daemon
    console.print("[bold]2/5[/] starting tripod-daemon on loopback (UDP + pseudo-terminal IMU)")
    t0 = time.perf_counter()
    sink = PtyImuSink()
    data_port, pos_port = _free_udp_port(), _free_udp_port()
    daemon = _Daemon(record_dir, data_port, pos_port, sink.path, output / "daemon.log")
    try:
        if not daemon.wait_ready():
            daemon.stop()
            fail(f"tripod-daemon did not become ready (see {output / 'daemon.log'})")
        time.sleep(0.5)  # let it open the IMU line
        steps.append(("daemon", f"ready, ports {data_port}/{pos_port}, IMU {sink.path}",
                      time.perf_counter() - t0))

        # 3. replay
        console.print(f"[bold]3/5[/] replaying the capture into the daemon at {rate:g}x")
        t0 = time.perf_counter()
        stats = Replayer(ReplaySource.open(capture), rate=rate,
                         lidar_addr=("127.0.0.1", data_port),
                         position_addr=("127.0.0.1", pos_port), imu_sink=sink).run()
        time.sleep(1.0)  # the last packets through the daemon's queue
        steps.append(("replay", f"{stats.sent.get('lidar', 0)} data packets, "
                                f"{stats.imu_bytes_sent} IMU bytes", time.perf_counter() - t0))
    finally:
        # 4. stop
        rc = daemon.stop()
        sink.close()
    console.print(f"[bold]4/5[/] daemon stopped (exit {rc})")
    files = sorted(record_dir.rglob("*.mcap"))
    if rc != 0 or not files:
        fail(f"the daemon left no recording (exit {rc}; see {output / 'daemon.log'})")
    steps.append(("record", f"{len(files)} MCAP file(s), "
                            f"{sum(f.stat().st_size for f in files) / 1e6:.1f} MB", 0.0))

    # 5. reconstruct the daemon's recording; the rig's calibration is not given: it is found
    # from the data (and checked against the simulator's below)
    console.print("[bold]5/5[/] reconstructing the daemon's recording (calibration from the data)")
    t0 = time.perf_counter()
    cfg = ReconstructConfig()
    try:
        res = reconstruct([str(f) for f in files], recon_dir, cfg)
    except RecordingError as exc:
        fail(str(exc))
    steps.append(("reconstruct", f"{len(res.fragments)} stations", time.perf_counter() - t0))
    t_truth, T_truth = load_sim_truth(capture)
    acc = evaluate_run(recon_dir, t_truth, T_truth, capture / "mesh.ply")
    s = summary(res)
    s.update(acc)
    acc.update(_calibration_errors(res, capture))
    (recon_dir / "accuracy.json").write_text(json.dumps(acc, indent=2) + "\n")

    _print_results(steps, time.perf_counter() - t_all, s, acc, res, recon_dir)


def _calibration_errors(res, capture: Path) -> dict:
    """The recovered lever arm (across the pan axis, where it is observable) against the
    simulator's, and the mount's tilt error (the pan axis in the lidar frame)."""
    import numpy as np

    truth = json.loads((capture / "meta.json").read_text()).get("truth")
    if not truth:
        return {}
    b = np.asarray(truth["pan_axis_imu"])
    ell_t = np.asarray(truth["lever_arm_imu_m"])
    ell = res.extrinsic.lever_arm_m

    def across(v):
        return v - b * (b @ v)

    from scipy.spatial.transform import Rotation

    qt = truth["q_imu_lidar_wxyz"]
    R_t = Rotation.from_quat([qt[1], qt[2], qt[3], qt[0]]).as_matrix()
    a_t, a = R_t.T @ b, res.extrinsic.R_imu_lidar.T @ b
    return {"lever_arm_error_mm": float(1000 * np.linalg.norm(across(ell) - across(ell_t))),
            "lever_arm_across_true_cm": float(100 * np.linalg.norm(across(ell_t))),
            "lever_arm_across_cm": float(100 * np.linalg.norm(across(ell))),
            "mount_tilt_error_deg": float(np.degrees(np.arccos(np.clip(a @ a_t, -1, 1)))),
            "imu_time_offset_ms": res.time_offset_ns * 1e-6,
            "imu_latency_true_ms": float(truth["imu_latency_ms"])}


def _print_results(steps, total_s: float, s: dict, acc: dict, res, recon_dir: Path) -> None:
    """The demo's tables: steps and times, the run's results, accuracy against the truth."""
    from rich.console import Console
    from rich.table import Table

    from .reconstruct_cmd import results_table

    out = Console()
    t = Table(title="tripod demo: simulate → daemon → replay → reconstruct")
    t.add_column("step")
    t.add_column("what")
    t.add_column("wall [s]", justify="right")
    for name, what, dt in steps:
        t.add_row(name, what, f"{dt:.1f}")
    t.add_row("total", "", f"{total_s:.1f}")
    out.print(t)
    out.print(results_table(s, "reconstruction of the daemon's recording"))
    a = Table(title="accuracy against the simulator's truth")
    a.add_column("quantity")
    a.add_column("value", justify="right")
    a.add_column("goal", justify="right")
    a.add_row("station ATE", f"{acc['ate_cm']:.2f} cm / {acc['ate_deg']:.3f}°", "≤ 2 cm / 0.2°")
    a.add_row("odometry-only ATE", f"{acc['ate_odometry_cm']:.2f} cm / "
                                   f"{acc['ate_odometry_deg']:.3f}°", "")
    a.add_row("odometry drift", f"{acc['odometry_drift_pct']:.3f} % of {acc['path_m']:.1f} m",
              "≤ 0.5 %")
    a.add_row("map to mesh", f"median {acc['map_to_mesh_median_cm']:.2f} cm, p95 "
                             f"{acc['map_to_mesh_p95_cm']:.2f} cm", "median ≤ 1.5 cm")
    if "lever_arm_error_mm" in acc:
        a.add_row("lever arm across the pan axis (from the data)",
                  f"{acc['lever_arm_across_cm']:.2f} cm (true {acc['lever_arm_across_true_cm']:.2f}"
                  f" cm, error {acc['lever_arm_error_mm']:.1f} mm)", "≤ 5 mm")
        a.add_row("mount tilt (pan axis in the lidar frame)",
                  f"error {acc['mount_tilt_error_deg']:.3f}°", "")
        a.add_row("IMU time offset (from the data)",
                  f"{acc['imu_time_offset_ms']:.2f} ms (IMU latency "
                  f"{acc['imu_latency_true_ms']:.1f} ms, less the lidar packets' own receive delay and the replay's)", "")
    out.print(a)
    for n in res.notes:
        out.print(f"[yellow]note:[/] {n}")
    out.print(f"report: [bold]{res.files.get('report', recon_dir)}[/]")
