# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon ctl``: status, start, stop and mark from scripts, over Zenoh.

::

    tripod-daemon ctl status [--json]   [--connect ENDPOINT] [--credentials FILE] [--ca PEM]
    tripod-daemon ctl start | stop      [...]                [--cert PEM --key PEM]
    tripod-daemon ctl mark [LABEL]      [...]

``--connect`` defaults to ``tcp/127.0.0.1:7447`` (the daemon on this machine).

Exit codes: 0 done; 1 refused or failed (the daemon said no, e.g. a label too long, a mark
while not recording, or this login may not control); 2 usage or connection error (bad
arguments, no session: unreachable, wrong user/password or certificate, daemon not answering).
Errors are one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from tripod_shared import topics

from .client import (
    ClientError,
    ClientOptions,
    ControlRefused,
    control,
    open_session,
    query_status,
    read_credentials,
)

EXIT_OK, EXIT_REFUSED, EXIT_USAGE = 0, 1, 2


def add_client_arguments(p: argparse.ArgumentParser, default_connect: str | None) -> None:
    """The connection and credential options shared by ``ctl`` and ``panel``."""
    p.add_argument("--connect", metavar="ENDPOINT", default=default_connect,
                   help="zenoh endpoint of the daemon, e.g. tcp/192.168.1.20:7447 or "
                   "tls/tripod.local:7447" + (f" (default {default_connect})"
                                              if default_connect else ""))
    p.add_argument("--device-id", default=topics.DEFAULT_DEVICE_ID,
                   help=f"the daemon's device_id (default {topics.DEFAULT_DEVICE_ID})")
    p.add_argument("--credentials", metavar="FILE",
                   default=os.environ.get("TRIPOD_CREDENTIALS") or None,
                   help="file with one line 'user:password' (a login of the daemon's "
                   "zenoh.auth.users_file); default $TRIPOD_CREDENTIALS")
    p.add_argument("--ca", metavar="PEM", default="",
                   help="CA certificate that signed the device's certificate (tls/ endpoints)")
    p.add_argument("--cert", metavar="PEM", default="",
                   help="this client's certificate, for mutual TLS (with --key)")
    p.add_argument("--key", metavar="PEM", default="", help="its private key")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the connection and each reply (default 5)")


def client_options(a: argparse.Namespace) -> ClientOptions:
    """ClientOptions from parsed arguments; ValueError naming the problem."""
    creds = read_credentials(a.credentials) if a.credentials else None
    return ClientOptions(endpoint=a.connect, device_id=a.device_id, credentials=creds,
                         ca=a.ca, certificate=a.cert, private_key=a.key, timeout_s=a.timeout)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tripod-daemon ctl",
        description="Control a tripod-daemon over Zenoh. Exit codes: 0 done, 1 refused or "
        "failed, 2 usage or connection error (unreachable, wrong credentials, no answer).")
    p.add_argument("command", choices=["status", *topics.CONTROL_COMMANDS])
    p.add_argument("label", nargs="?", default="", help="mark: the station's label (optional)")
    p.add_argument("--json", action="store_true", help="print the daemon's reply as JSON")
    add_client_arguments(p, "tcp/127.0.0.1:7447")
    return p


def _fmt_bytes(n: float | None) -> str:
    if n is None:
        return "?"
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def status_lines(st: dict) -> list[str]:
    """A few readable lines of a status dict."""
    rates, counts = st.get("rates", {}), st.get("counts", {})
    disk = st.get("disk", {})
    state = st.get("state", "?")
    lines = [f"state     {state}" + (f" ({st['file']})" if st.get("file") else "")]
    if disk.get("file_started_ns") and st.get("recording"):
        el = max(0, st.get("host_time_ns", time.time_ns()) - disk["file_started_ns"]) // 10**9
        lines.append(f"file      {_fmt_bytes(disk.get('file_bytes'))}, {el // 60}:{el % 60:02d}")
    if "free_bytes" in disk:
        lines.append(f"disk      {_fmt_bytes(disk['free_bytes'])} free")
    drops = sum(counts.get(k, 0) for k in ("lidar_kernel_drops", "record_dropped",
                                           "zenoh_dropped"))
    pps = st.get("clocks", {}).get("lidar", {}).get("pps", "?")
    lines.append(f"lidar     {rates.get('lidar_data', 0):.0f} packets/s, drops {drops}, "
                 f"PPS {pps}")
    if "imu" in st.get("clocks", {}):
        conn = "connected" if counts.get("imu_connected") else "disconnected"
        lines.append(f"imu       {rates.get('imu_samples', 0):.0f} samples/s, {conn}")
    if st.get("message"):
        lines.append(f"warnings  {st['message']}")
    return lines


def run(a: argparse.Namespace) -> int:
    try:
        opts = client_options(a)
    except ValueError as exc:
        print(f"tripod-daemon ctl: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        session = open_session(opts)
    except ClientError as exc:
        print(f"tripod-daemon ctl: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if a.command == "status":
            st = query_status(session, opts)
            print(json.dumps(st, sort_keys=True) if a.json else "\n".join(status_lines(st)))
            return EXIT_OK
        reply = control(session, opts, a.command, a.label if a.command == "mark" else "")
        if a.json:
            print(json.dumps(reply, sort_keys=True))
        elif a.command == "start":
            print(f"recording to {reply.get('file')}")
        elif a.command == "stop":
            print("stopped")
        else:
            label = f" {reply.get('label')!r}" if reply.get("label") else ""
            print(f"marked{label} in {reply.get('file')}")
        return EXIT_OK
    except ControlRefused as exc:
        print(f"tripod-daemon ctl: {a.command}: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except ClientError as exc:
        print(f"tripod-daemon ctl: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    p = _parser()
    try:
        a = p.parse_args(argv)
    except SystemExit as exc:  # argparse: 2 on usage errors, 0 for --help
        return int(exc.code or 0)
    if a.label and a.command != "mark":
        p.print_usage(sys.stderr)
        print(f"tripod-daemon ctl: error: {a.command} takes no label", file=sys.stderr)
        return EXIT_USAGE
    return run(a)


if __name__ == "__main__":
    sys.exit(main())
