# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark of tripod-daemon: loss and CPU under load, over loopback UDP, printed as a table.

The daemon runs as its own process (``python -m tripod_daemon``) with recording (zstd MCAP)
and Zenoh on, exactly as on the device; this script sends numbered 1206-byte VLP-16 data
packets at a paced rate and reads the daemon's counters through its Zenoh ``status``
queryable. CPU is the daemon process's own (utime + stime from /proc), the sender's excluded.

The sender paces packets evenly, as the sensor sends them (not in bursts: bursts let the
daemon handle many packets per wake-up and under-state its CPU use).

Rows:
  * 754 and 1508 packets/s (VLP-16 single and dual return): CPU use (goal <= 5 % of a core)
  * 1508/s with a live Zenoh subscriber (a separate process)
  * 20x the dual-return rate (30,140 packets/s) for 30 s, without and with a subscriber
  * rising rates with a subscriber until the first loss: the highest zero-loss rate
At the end the recordings are read back: every received packet must be there exactly once.
Then kill -9 at 20x and at the zero-loss rate: what the recovered file lacks of what was sent
before the kill, in seconds.

    python bench/daemon.py            # the full run (~5 minutes)
    python bench/daemon.py --quick    # shorter runs, for a smoke test
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from tripod_shared import topics
from tripod_shared.recording import RecordingReader
from tripod_shared.velodyne import VLP16_PACKET_PERIOD_US

DUAL_RATE = 1e6 / VLP16_PACKET_PERIOD_US["dual"]  # packets/s
CLK_TCK = os.sysconf("SC_CLK_TCK")


def packet(seq: int) -> bytes:
    body = struct.pack("<I", seq) * 24 + bytes(2)
    return b"".join(b"\xff\xee" + body for _ in range(12)) + struct.pack(
        "<I", (seq * 664) % 3_600_000_000) + b"\x39\x22"


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


class DaemonProcess:
    def __init__(self, workdir: Path, lidar_yaml: str = ""):
        self.zport = free_port()
        self.workdir = workdir
        cfg = workdir / "daemon.yaml"
        cfg.write_text(
            "lidar:\n  bind_address: 127.0.0.1\n  data_port: 0\n  position_port: 0\n"
            "  receive_buffer_bytes: 67108864\n" + lidar_yaml +
            f"recording:\n  directory: {workdir / 'rec'}\n  min_free_bytes: 0\n"
            f"zenoh:\n  listen: [tcp/127.0.0.1:{self.zport}]\n")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tripod_daemon", "--no-system-config", "--config", str(cfg)],
            stderr=subprocess.PIPE, text=True)
        self.port = None
        self.log: list[str] = []
        ready = threading.Event()

        def pump():
            for line in self.proc.stderr:
                self.log.append(line.rstrip())
                m = re.search(r"data on [\d.]+:(\d+)", line)
                if m:
                    self.port = int(m.group(1))
                if "recording to" in line:
                    ready.set()

        threading.Thread(target=pump, daemon=True).start()
        if not ready.wait(30):
            raise RuntimeError("daemon did not start:\n" + "\n".join(self.log))
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{self.zport}"]')
        self.session = zenoh.open(conf)

    def rss_mib(self) -> tuple[float, float]:
        """(current, peak) resident memory of the daemon process [MiB]."""
        vals = {}
        with open(f"/proc/{self.proc.pid}/status") as fh:
            for line in fh:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    vals[line.split(":")[0]] = int(line.split()[1]) / 1024
        return vals.get("VmRSS", 0.0), vals.get("VmHWM", 0.0)

    def cpu_s(self) -> float:
        with open(f"/proc/{self.proc.pid}/stat") as fh:
            f = fh.read().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / CLK_TCK

    def status(self) -> dict:
        for _ in range(50):
            for reply in self.session.get(topics.key_status(), timeout=2.0):
                if reply.ok is not None:
                    st = json.loads(reply.ok.payload.to_bytes())
                    if st.get("state") != "starting":
                        return st
            time.sleep(0.1)
        raise RuntimeError("no status reply")

    def stop(self) -> None:
        self.session.close()
        self.proc.terminate()
        self.proc.wait(60)


def send(addr, first_seq: int, rate: float, seconds: float, kill_at=None) -> tuple[int, float]:
    """Send numbered packets evenly paced at ``rate`` for ``seconds``, as the sensor does (one
    every 0.66 ms at the dual-return rate), not in bursts; returns (count, achieved rate).

    Up to 4,000 packets/s each packet waits for its own time slot; above that, packets go in
    groups of ceil(rate / 4000) every 0.25 ms (a Python sender cannot sleep 33 µs). ``kill_at``:
    (seconds, callable) called once that far into the run (the kill -9 case).
    """
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    n = int(rate * seconds)
    group = max(1, -(-int(rate) // 4000))
    pk = [packet(first_seq + i) for i in range(min(n, 8192))]
    sendto, perf, sleep = s.sendto, time.perf_counter, time.sleep
    t0 = perf()
    killed = kill_at is None
    for i in range(n):
        p = pk[i] if i < len(pk) else packet(first_seq + i)
        if i % group == 0:
            ahead = i / rate - (perf() - t0)
            if ahead > 0:
                sleep(ahead)
            if not killed and i / rate >= kill_at[0]:
                kill_at[1](i)
                killed = True
        sendto(p, addr)
    dt = perf() - t0
    # one more packet a little later: the kernel reports its drop count (SO_RXQ_OVFL) only with
    # the next datagram it queues, so this one carries the count of the run into the status
    if kill_at is None:
        time.sleep(0.2)
        s.sendto(packet(first_seq + n), addr)
        n += 1
    s.close()
    return n, (n - 1) / dt if kill_at is None else n / dt


class Subscriber:
    """A live subscriber in its own process (so its cost is not the daemon's): counts every
    lidar packet it receives and prints the total when done."""

    def __init__(self, zport: int, seconds: float):
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--subscriber", str(zport), str(seconds)],
            stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().strip() == "subscribed"

    def close(self) -> int:
        out, _ = self.proc.communicate(timeout=120)
        return int(out.split()[-1])


def subscriber_main(zport: int, seconds: float) -> int:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{zport}"]')
    n = [0]

    def on_sample(_s):
        n[0] += 1

    with zenoh.open(conf) as z:
        z.declare_subscriber(topics.key_lidar_packets(), on_sample)
        print("subscribed", flush=True)
        time.sleep(seconds)
    print(n[0], flush=True)
    return 0


def run_case(d: DaemonProcess, seq: int, rate: float, seconds: float, sub_seconds=None):
    before = d.status()["counts"]
    cpu0, t0 = d.cpu_s(), time.monotonic()
    sub = Subscriber(d.zport, seconds + 5) if sub_seconds else None
    if sub:
        time.sleep(1.5)
        cpu0, t0 = d.cpu_s(), time.monotonic()
    n, achieved = send(("127.0.0.1", d.port), seq, rate, seconds)
    # let the daemon catch up (bounded), then read its counters; CPU over the busy time only
    end = time.monotonic() + 15
    got_prev, wall, cpu = -1, None, None
    while True:
        after = d.status()["counts"]
        got = after["lidar_data"] - before["lidar_data"]
        if got >= n or time.monotonic() > end:
            break
        if got == got_prev and wall is None:  # stalled: packets were lost, not queued
            wall, cpu = time.monotonic() - t0, d.cpu_s() - cpu0
        got_prev = got
        time.sleep(0.2)
    if wall is None:
        wall, cpu = time.monotonic() - t0, d.cpu_s() - cpu0
    row = {
        "rate": rate, "achieved": achieved, "seconds": seconds, "sent": n, "received": got,
        "lost": n - got,
        "kernel_drops": after.get("lidar_kernel_drops", 0) - before.get("lidar_kernel_drops", 0),
        "rec_dropped": after["record_dropped"] - before["record_dropped"],
        "zenoh_dropped": after["zenoh_dropped"] - before["zenoh_dropped"],
        "cpu_pct": 100.0 * cpu / wall, "subscriber": None,
        "rss_mib": d.rss_mib()[0], "load": os.getloadavg()[0],
    }
    if sub:
        row["subscriber"] = sub.close()
    return row, seq + n


def kill_case(rate: float, seconds: float, kill_s: float, workdir: Path) -> dict:
    """kill -9 the daemon ``kill_s`` into an evenly paced run at ``rate``; recover the cut-off
    file with ``tripod-daemon recover`` and count what is missing of what was sent before
    the kill (the recovered file is then read with the plain ``mcap`` reader)."""
    from mcap.reader import make_reader

    d = DaemonProcess(workdir)
    d.session.close()
    sent_before = [0]

    def kill(i):
        sent_before[0] = i
        os.kill(d.proc.pid, 9)

    send(("127.0.0.1", d.port), 0, rate, seconds, kill_at=(kill_s, kill))
    d.proc.wait(30)
    rss = 0.0
    src = sorted((workdir / "rec").glob("*.mcap"))[-1]
    out = workdir / "recovered.mcap"
    subprocess.run([sys.executable, "-m", "tripod_daemon", "recover", str(src), "-o", str(out)],
                   check=True, capture_output=True)
    with open(out, "rb") as fh:  # the plain mcap reader, with the summary recover wrote
        reader = make_reader(fh)
        seqs = [struct.unpack_from("<I", m.data, 12 + 2)[0]
                for _s, _c, m in reader.iter_messages(topics=[topics.TOPIC_LIDAR_PACKETS])]
    kept = len(seqs)
    lost = sent_before[0] - kept
    return {"rate": rate, "sent_before_kill": sent_before[0], "recovered": kept, "lost": lost,
            "lost_s": lost / rate, "rss": rss}


def main() -> int:
    if len(sys.argv) == 4 and sys.argv[1] == "--subscriber":
        return subscriber_main(int(sys.argv[2]), float(sys.argv[3]))
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    ap.add_argument("--max-rate", type=float, default=200_000)
    ap.add_argument("--no-search", action="store_true", help="skip the zero-loss search")
    ap.add_argument("--no-kill", action="store_true", help="skip the kill -9 cases")
    a = ap.parse_args()
    low_s = 5 if a.quick else 20
    long_s = 5 if a.quick else 30
    step_s = 3 if a.quick else 5
    rows = []
    kills = []
    best = None
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        d = DaemonProcess(Path(tmp))
        seq = 0
        try:
            for name, rate, secs, sub in (
                ("754/s single return", DUAL_RATE / 2, low_s, False),
                ("1508/s dual return", DUAL_RATE, low_s, False),
                ("1508/s + subscriber", DUAL_RATE, low_s, True),
                ("20x dual return", 20 * DUAL_RATE, long_s, False),
                ("20x + subscriber", 20 * DUAL_RATE, long_s, True),
            ):
                r, seq = run_case(d, seq, rate, secs, sub_seconds=sub or None)
                rows.append((name, r))
            rate = 40_000.0
            bad = None
            while not a.no_search and rate <= a.max_rate:
                r, seq = run_case(d, seq, rate, step_s, sub_seconds=True)
                rows.append((f"search {rate:,.0f}/s + sub", r))
                if r["lost"] == 0 and r["rec_dropped"] == 0 and r["achieved"] >= 0.95 * rate:
                    best = rate
                    rate *= 1.25
                else:
                    bad = rate
                    break
            counts = d.status()["counts"]
            peak_rss = d.rss_mib()[1]
        finally:
            d.stop()
        # the recordings hold every received packet exactly once, in order
        seqs = []
        for f in sorted((Path(tmp) / "rec").glob("*.mcap")):
            for _ns, p in RecordingReader(f).lidar_packets():
                seqs.append(struct.unpack_from("<I", p, 2)[0])
        in_order = all(b > a_ for a_, b in zip(seqs, seqs[1:]))
    if not a.no_kill:
        for rate in (20 * DUAL_RATE,) + ((best,) if best else ()):
            with tempfile.TemporaryDirectory() as tmp:
                kills.append(kill_case(rate, 5 if a.quick else 8, 3 if a.quick else 6, Path(tmp)))
    print()
    print(f"tripod-daemon bench, loopback UDP, evenly paced sender in another process, "
          f"recording zstd MCAP + Zenoh on; {os.cpu_count()} CPUs, load average at start "
          f"{load0[0]:.1f} / {load0[1]:.1f} / {load0[2]:.1f} (1/5/15 min)")
    hdr = (f"{'case':<24}{'rate/s':>9}{'sent/s':>9}{'s':>4}{'sent':>9}{'lost':>7}"
           f"{'rec.drop':>9}{'zen.drop':>9}{'sub.got':>9}{'CPU %':>7}{'RSS MiB':>8}{'load':>6}")
    print(hdr)
    print("-" * len(hdr))
    for name, r in rows:
        print(f"{name:<24}{r['rate']:>9,.0f}{r['achieved']:>9,.0f}{r['seconds']:>4.0f}"
              f"{r['sent']:>9,}{r['lost']:>7,}{r['rec_dropped']:>9,}"
              f"{r['zenoh_dropped']:>9,}"
              f"{'' if r['subscriber'] is None else format(r['subscriber'], ','):>9}"
              f"{r['cpu_pct']:>7.1f}{r['rss_mib']:>8.0f}{r['load']:>6.1f}")
    print("-" * len(hdr))
    print("CPU %: the daemon process (all its threads, Zenoh's included) in % of one core over "
          "the run, from /proc/PID/stat; lost: sent - received by the daemon; rec.drop / "
          "zen.drop: dropped at the recorder / live-path queues; sub.got: packets a Zenoh "
          "subscriber process received; load: 1-min load average at the end of the row")
    print(f"highest zero-loss rate with a live subscriber: {best:,.0f} packets/s" if best else
          "highest zero-loss rate with a live subscriber: below 40,000 packets/s"
          if not a.no_search else "zero-loss search skipped")
    print(f"peak RSS of the daemon over all rows: {peak_rss:.0f} MiB")
    print(f"recording: {len(seqs):,} packets of {counts['lidar_data']:,} received; "
          f"in order, no duplicates: {in_order and len(seqs) == counts['lidar_data']}")
    for k in kills:
        print(f"kill -9 at {k['rate']:,.0f}/s: {k['sent_before_kill']:,} sent before the kill, "
              f"{k['recovered']:,} in the recovered file (read by the mcap reader): "
              f"{k['lost']:,} lost = {k['lost_s']:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
