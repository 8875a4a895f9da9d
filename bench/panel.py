# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark of ``tripod-daemon panel``: CPU of the panel process with one page open, while the
daemon receives the VLP-16 dual-return rate (1508 packets/s) over loopback UDP.

The daemon (recording zstd MCAP, Zenoh on) and the panel run as their own processes, exactly
as on the device; this script replays real VLP-16 payloads (VeloView's capture from the shared
data, looped) paced at the dual-return rate and plays the phone: it logs in and fetches
``/api/state`` once a second like the page does (with the range image whenever it changed).
CPU is each process's own (utime + stime from /proc); the sender's and the client's excluded.

Two phases of ``--seconds`` each at the same rate: the daemon alone (no panel process), then
with the panel and one client, so the daemon's own figure can be compared.

    python bench/panel.py                 # 2 x 20 s
    python bench/panel.py --seconds 10
"""

from __future__ import annotations

import argparse
import http.cookiejar
import importlib.util
import json
import os
import socket
import ssl
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
CLK_TCK = os.sysconf("SC_CLK_TCK")
PASSWORD = "bench-password"

_spec = importlib.util.spec_from_file_location("bench_daemon", HERE / "daemon.py")
bench_daemon = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_daemon)


def cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        f = fh.read().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / CLK_TCK


def payloads() -> list[bytes]:
    sys.path.insert(0, str(REPO / "tests" / "daemon"))
    from daemon_helpers import read_pcap_udp

    pcap = REPO.parent / "shared" / "data" / "velodyne" / "veloview-vlp16-20hz.pcap"
    if pcap.exists():
        return [p for _port, p in read_pcap_udp(pcap) if len(p) == 1206]
    return [bench_daemon.packet(i) for i in range(2000)]  # synthetic when the data is absent


class Replay(threading.Thread):
    """Paced sender (bursts of 32) until stopped."""

    def __init__(self, addr, pk: list[bytes], rate: float):
        super().__init__(daemon=True)
        self.addr, self.pk, self.rate = addr, pk, rate
        self.stop = threading.Event()
        self.sent = 0

    def run(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        t0 = time.perf_counter()
        n = 0
        while not self.stop.is_set():
            s.sendto(self.pk[n % len(self.pk)], self.addr)
            n += 1
            if n % 32 == 0:
                ahead = n / self.rate - (time.perf_counter() - t0)
                if ahead > 0:
                    time.sleep(ahead)
        self.sent = n
        s.close()


class PanelProcess:
    def __init__(self, work: Path, zport: int):
        from tripod_daemon.certs import gen_certs

        certs = work / "certs"
        gen_certs(str(certs), ["localhost", "127.0.0.1"], [])
        cred = work / "panel-credentials"
        cred.write_text(f"operator:{PASSWORD}\n")
        self.port = bench_daemon.free_port()
        self.url = f"https://127.0.0.1:{self.port}"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tripod_daemon", "panel", "--no-system-config",
             "--listen", f"127.0.0.1:{self.port}", "--credentials", str(cred),
             "--certificate", str(certs / "device.pem"), "--private-key",
             str(certs / "device.key"), "--connect", f"tcp/127.0.0.1:{zport}"],
            stderr=subprocess.DEVNULL)
        ctx = ssl.create_default_context(cafile=str(certs / "ca.pem"))
        self.opener = urllib.request.build_opener(
            urllib.request.HTTPSHandler(context=ctx),
            urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
        end = time.monotonic() + 60
        while True:
            try:
                self.opener.open(urllib.request.Request(
                    self.url + "/login", data=f"password={PASSWORD}".encode()), timeout=5)
                break
            except OSError:
                if time.monotonic() > end or self.proc.poll() is not None:
                    raise RuntimeError("panel did not start") from None
                time.sleep(0.2)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(30)


class Phone(threading.Thread):
    """Fetches /api/state once a second, as the page does."""

    def __init__(self, panel: PanelProcess):
        super().__init__(daemon=True)
        self.panel = panel
        self.stop = threading.Event()
        self.last: dict = {}
        self.requests = 0
        self.images = 0

    def run(self) -> None:
        have = -1
        while not self.stop.wait(1.0):
            with self.panel.opener.open(f"{self.panel.url}/api/state?have={have}",
                                        timeout=5) as r:
                st = json.loads(r.read())
            self.requests += 1
            if "grey_b64" in st["image"]:
                self.images += 1
            have = st["image"]["seq"]
            self.last = st


def measure(pids: dict[str, int], seconds: float) -> dict[str, float]:
    c0 = {k: cpu_s(p) for k, p in pids.items()}
    t0 = time.monotonic()
    time.sleep(seconds)
    wall = time.monotonic() - t0
    return {k: 100.0 * (cpu_s(p) - c0[k]) / wall for k, p in pids.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=bench_daemon.DUAL_RATE)
    a = ap.parse_args()
    pk = payloads()
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="tripod-bench-panel-") as tmp:
        work = Path(tmp)
        d = bench_daemon.DaemonProcess(work)
        replay = Replay(("127.0.0.1", d.port), pk, a.rate)
        panel = phone = None
        try:
            replay.start()
            time.sleep(3.0)  # settle
            cpu = measure({"daemon": d.proc.pid}, a.seconds)
            rows.append(("daemon alone", cpu["daemon"], None, os.getloadavg()[0]))
            panel = PanelProcess(work, d.zport)
            phone = Phone(panel)
            phone.start()
            time.sleep(3.0)
            cpu = measure({"daemon": d.proc.pid, "panel": panel.proc.pid}, a.seconds)
            rows.append(("daemon + panel, one client", cpu["daemon"], cpu["panel"],
                         os.getloadavg()[0]))
        finally:
            replay.stop.set()
            replay.join(10)
            if phone is not None:
                phone.stop.set()
                phone.join(10)
            if panel is not None:
                panel.stop()
            st = d.status()
            d.stop()
    counts = st["counts"]
    drops = sum(counts.get(k, 0) for k in ("lidar_kernel_drops", "record_dropped",
                                           "zenoh_dropped"))
    print(f"\nrate {a.rate:.0f} packets/s (real VLP-16 payloads), {a.seconds:g} s per phase; "
          f"received {counts['lidar_data']}, drops {drops}")
    if phone is not None and phone.last:
        print(f"client: {phone.requests} requests, {phone.images} new range images; the page "
              f"saw {phone.last['lidar']['rate']:.0f} packets/s, image of "
              f"{phone.last['image']['packets']} packets")
    print("\n| phase | daemon CPU [% of a core] | panel CPU [% of a core] | load avg (1 min) |")
    print("|---|---|---|---|")
    for name, dc, pc, la in rows:
        print(f"| {name} | {dc:.1f} | {'–' if pc is None else f'{pc:.1f}'} | {la:.2f} |")
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
