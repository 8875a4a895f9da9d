# SPDX-License-Identifier: BSD-3-Clause
"""``tripod live``: show a running daemon's capture in Foxglove while scanning."""

from __future__ import annotations

import json
import logging
import signal
import sys
from pathlib import Path
from typing import Optional

import typer

from . import app
from ._common import console, fail


@app.command("live", rich_help_panel="Test bed")
def live_cmd(
    connect: list[str] = typer.Option(..., "--connect",
                                      help="The daemon's Zenoh endpoint, e.g. tcp/HOST:7447 "
                                           "(repeatable)."),
    device_id: str = typer.Option("tripod0", "--device-id", help="The daemon's device_id."),
    host: str = typer.Option("127.0.0.1", "--host",
                             help="Address the Foxglove WebSocket server listens on "
                                  "(0.0.0.0: every interface)."),
    port: int = typer.Option(8765, "--port", help="Foxglove WebSocket port (0: any free one)."),
    voxel: float = typer.Option(0.10, "--voxel", help="Coverage map voxel [m]."),
    zenoh_config: Optional[Path] = typer.Option(
        None, "--zenoh-config", help="zenoh JSON5 config underneath (TLS, user/password)."),
    duration: Optional[float] = typer.Option(
        None, "--duration", help="Stop after this many seconds and print the counters "
                                 "(default: until Ctrl-C)."),
) -> None:
    """Subscribe to the daemon's stream and serve it to Foxglove (ws://HOST:PORT): the current
    rotation, the IMU orientation, a growing coverage map and each finished station. Writes
    no file; prints the counters (JSON) on exit."""
    from ..live import LiveConfig, LiveStream, LiveView, open_session

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    try:
        cfg = LiveConfig(voxel_m=voxel)
    except ValueError as exc:
        fail(f"bad option: {exc}")
    if zenoh_config is not None and not zenoh_config.is_file():
        fail(f"no such zenoh config: {zenoh_config}")
    try:
        session = open_session(connect, str(zenoh_config) if zenoh_config else None)
    except Exception as exc:  # noqa: BLE001 - zenoh raises ZError for bad endpoints
        fail(f"cannot open a zenoh session to {', '.join(connect)}: {exc}")
    stream = LiveStream(session, device_id, queue_rotations=cfg.queue_rotations)
    try:
        view = LiveView(stream, cfg, host=host, port=port)
    except Exception as exc:  # noqa: BLE001 - the port is taken, ...
        stream.close()
        session.close()
        fail(f"cannot start the Foxglove server on {host}:{port}: {exc}")
    console.print(f"tripod live: Foxglove → ws://{host}:{view.port}  "
                  f"(Open connection → Foxglove WebSocket), stream from {', '.join(connect)}")

    def _stop(_signum, _frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _stop)  # systemd / a test stops it like Ctrl-C
    try:
        view.run(duration_s=duration)
    except KeyboardInterrupt:
        pass
    finally:
        view.close()
        stream.close()
        session.close()
    st = view.stats()
    st.pop("daemon_status", None)
    print(json.dumps(st), flush=True)
