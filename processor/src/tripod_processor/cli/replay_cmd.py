# SPDX-License-Identifier: BSD-3-Clause
"""``tripod replay``: send a capture back out over UDP and an IMU line, with its timing."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Optional

import typer

from . import app
from ._common import console, fail


def _parse_rate(text: str) -> float:
    if text.lower() in ("max", "inf"):
        return float("inf")
    try:
        r = float(text.rstrip("xX"))
    except ValueError:
        fail(f"bad --rate {text!r}: a number (1, 10, 0.5) or max")
    if not r > 0:
        fail("--rate must be > 0")
    if r != r:
        fail("--rate must be a number")
    return r


@app.command("replay", rich_help_panel="Test bed")
def replay_cmd(
    input: Path = typer.Argument(..., help="Capture directory (tripod simulate), pcap/pcapng, or "
                                           "MCAP recording."),
    rate: str = typer.Option("1", "--rate", help="Speed: 1 real time, 10, ..., or max."),
    lidar: str = typer.Option("127.0.0.1:2368", "--lidar", help="UDP HOST:PORT for data packets."),
    position: str = typer.Option("127.0.0.1:8308", "--position",
                                 help="UDP HOST:PORT for position packets."),
    imu: str = typer.Option(
        "pty", "--imu", help="IMU bytes to: pty, tcp (brickd-like on 4223), tcp:PORT (0 = any "
                             "free port), "
                             "serial:DEV, serial:DEV@BAUD or none."),
    imu_log: Optional[Path] = typer.Option(None, "--imu-log",
                                           help="IMU log to send (default: imu.tripimu beside "
                                                "the input)."),
    wait_imu_client: float = typer.Option(0.0, "--wait-imu-client",
                                          help="tcp: wait up to this many seconds for a client."),
    start_delay: float = typer.Option(0.0, "--start-delay",
                                      help="Seconds to wait before sending (time to open the "
                                           "pty or connect)."),
    limit: Optional[float] = typer.Option(None, "--limit",
                                          help="Replay only this many seconds of capture time."),
    loop: int = typer.Option(1, "--loop", help="Play the capture this many times back to back "
                                              "(0: until stopped)."),
    realtime: int = typer.Option(10, "--realtime",
                                 help="SCHED_FIFO priority of the sender (1..99; needs "
                                      "CAP_SYS_NICE, else normal scheduling); 0 = normal."),
    spin_us: Optional[float] = typer.Option(None, "--spin-us",
                                            help="Busy-wait before each send in us (default 100 "
                                                 "under SCHED_FIFO, else 300)."),
) -> None:
    """Replay packets and IMU bytes with the original timing; print counts, rate and jitter."""
    import time

    from tripod_shared import tfp

    from ..io.imu_log import ImuLogError
    from ..io.pcap import PcapFormatError
    from ..io.replay import ReplayInputError, Replayer, ReplaySource, open_imu_sink, parse_addr

    r = _parse_rate(rate)
    if loop < 0:
        fail("--loop must be >= 0 (0: until stopped)")
    if not 0 <= realtime <= 99:
        fail("--realtime must be 0 (off) or a SCHED_FIFO priority 1..99")
    sink = None
    try:
        src = ReplaySource.open(input, imu_log)
        lidar_addr = parse_addr(lidar, 2368)
        pos_addr = parse_addr(position, 8308)
        uid = None
        meta = (input / "meta.json") if input.is_dir() else input.parent / "meta.json"
        if meta.is_file():
            import json

            try:
                uid = tfp.base58_decode(json.loads(meta.read_text())["config"]["imu"]["uid"])
            except (KeyError, ValueError):
                uid = None
        sink = open_imu_sink(imu if src.imu_log or src.mcap else "none", uid=uid)
    except (ReplayInputError, ImuLogError, PcapFormatError, OSError) as exc:
        fail(str(exc))
    if sink is not None:
        # the path/port is what the device under test needs: print it first, on stdout
        print(f"imu: {sink.description}", flush=True)
        if wait_imu_client > 0 and hasattr(sink, "wait_for_client"):
            if not sink.wait_for_client(wait_imu_client):
                console.print("[yellow]no IMU client connected; sending anyway[/]")
    if start_delay > 0:
        time.sleep(start_delay)
    rp = Replayer(src, rate=r, lidar_addr=lidar_addr, position_addr=pos_addr, imu_sink=sink,
                  limit_s=limit, spin_us=spin_us, realtime_priority=realtime, loops=loop)
    signal.signal(signal.SIGTERM, lambda *_: rp.stop_event.set())
    try:
        stats = rp.run()
    except (PcapFormatError, ImuLogError, ValueError) as exc:
        fail(str(exc).splitlines()[0])
    finally:
        if sink is not None:
            sink.close()
    _print_stats(stats, str(input), sink is not None)


def _print_stats(stats, source: str, with_imu: bool) -> None:
    """The replay's results table, on stdout."""
    from rich.table import Table

    t = Table(title=f"tripod replay {source}")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, n in stats.sent.items():
        t.add_row(f"{k} sent", str(n))
    if stats.send_errors:
        t.add_row("send errors", str(stats.send_errors))
    if with_imu:
        t.add_row("IMU bytes sent / dropped", f"{stats.imu_bytes_sent} / {stats.imu_bytes_dropped}")
    t.add_row("capture span (s)", f"{stats.capture_span_s:.3f}")
    t.add_row("wall time (s)", f"{stats.wall_s:.3f}")
    t.add_row("achieved rate", f"{stats.achieved_rate:.2f}x")
    t.add_row("lidar packets/s", f"{stats.packets_per_s:.0f}")
    if len(stats.lateness_ns):
        t.add_row("jitter p50 / p99 / max (us)",
                  f"{stats.jitter_us(50):.0f} / {stats.jitter_us(99):.0f} / "
                  f"{stats.jitter_us(100):.0f}")
    t.add_row("scheduling", stats.scheduling)
    if stats.stopped_early:
        t.add_row("stopped early", "yes")
    Console = type(console)
    Console(file=sys.stdout).print(t)
