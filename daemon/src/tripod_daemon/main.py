# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon``: run the capture service, or ``recover`` a cut-off file, or ``watch`` the
live stream.

::

    tripod-daemon [--config FILE] [--lidar-port N] [--position-port N] [--imu URL]
                  [--record-dir DIR] [--zenoh-listen EP] [--zenoh-connect EP] [--no-record]
    tripod-daemon --print-default-config
    tripod-daemon recover FILE [-o OUT]
    tripod-daemon watch [--connect EP] [--device-id ID] [--seconds S]
    tripod-daemon gen-certs DIR [--name HOST] [--client CN]
    tripod-daemon ctl status|start|stop|mark [LABEL] [--connect EP] [--credentials FILE] ...
    tripod-daemon panel [--config FILE] [--listen HOST:PORT] [--credentials FILE] ...
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from . import __version__
from .config import SYSTEM_CONFIG, ConfigError, default_config_text, load

log = logging.getLogger("tripod_daemon")


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tripod-daemon",
        description="Receive VLP-16 packets and IMU samples, publish them over Zenoh and record "
        "them to MCAP. Subcommands: 'recover FILE' rebuilds a cut-off recording; 'watch' "
        "prints the live stream's rates; 'gen-certs DIR' makes TLS certificates; 'ctl' "
        "controls a running daemon (status, start, stop, mark); 'panel' serves the "
        "operator's page.",
    )
    p.add_argument("--version", action="version", version=f"tripod-daemon {__version__}")
    p.add_argument("-c", "--config", help=f"YAML config (layered over {SYSTEM_CONFIG})")
    p.add_argument("--no-system-config", action="store_true",
                   help=f"do not read {SYSTEM_CONFIG}")
    p.add_argument("--print-default-config", action="store_true",
                   help="print the commented default config and exit")
    p.add_argument("--lidar-port", type=int, help="UDP port of data packets (lidar.data_port)")
    p.add_argument("--position-port", type=int,
                   help="UDP port of position packets (lidar.position_port)")
    p.add_argument("--imu", metavar="URL",
                   help="IMU pyserial URL (imu.url): /dev/ttyUSB0, /dev/pts/N, socket://host:4223")
    p.add_argument("--imu-driver", choices=["tfp", "witmotion"], help="imu.driver")
    p.add_argument("--record-dir", metavar="DIR", help="recording.directory")
    p.add_argument("--no-record", action="store_true",
                   help="do not record at start-up (recording.enabled: false)")
    p.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help="zenoh.listen endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)")
    p.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="zenoh.connect endpoint (repeatable)")
    p.add_argument("--no-zenoh", action="store_true", help="zenoh.enabled: false")
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    return p


def _overrides(a: argparse.Namespace) -> dict:
    o = {
        "lidar.data_port": a.lidar_port,
        "lidar.position_port": a.position_port,
        "imu.url": a.imu,
        "imu.driver": a.imu_driver,
        "recording.directory": a.record_dir,
        "zenoh.listen": a.zenoh_listen,
        "zenoh.connect": a.zenoh_connect,
        "log_level": a.log_level,
    }
    if a.no_record:
        o["recording.enabled"] = False
    if a.no_zenoh:
        o["zenoh.enabled"] = False
    return {k: v for k, v in o.items() if v is not None}


def run(argv: list[str]) -> int:
    from .loop import Daemon
    from .systemd import setup_logging

    args = _run_parser().parse_args(argv)
    if args.print_default_config:
        sys.stdout.write(default_config_text())
        return 0
    system = None if args.no_system_config else SYSTEM_CONFIG

    def _load():
        return load(args.config, _overrides(args), system_config=system)

    try:
        cfg = _load()
    except ConfigError as exc:
        print(f"tripod-daemon: {exc}", file=sys.stderr)
        return 2
    setup_logging(cfg.log_level)
    log.info("tripod-daemon %s (pid %d)", __version__, os.getpid())
    return Daemon(cfg, reload_config=_load).run()


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "recover":
        from .recover import main as recover_main

        return recover_main(argv[1:])
    if argv and argv[0] == "gen-certs":
        from .certs import main as certs_main

        return certs_main(argv[1:])
    if argv and argv[0] == "ctl":
        from .ctl import main as ctl_main

        return ctl_main(argv[1:])
    if argv and argv[0] == "panel":
        from .panel import main as panel_main

        return panel_main(argv[1:])
    if argv and argv[0] == "watch":
        from .watch import main as watch_main

        return watch_main(argv[1:])
    return run(argv)


if __name__ == "__main__":
    sys.exit(main())
