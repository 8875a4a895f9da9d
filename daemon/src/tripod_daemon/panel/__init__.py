# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon panel``: the operator's page, a small process beside the daemon.

::

    tripod-daemon panel [--config FILE] [--no-system-config] [--listen HOST:PORT]
                        [--credentials FILE] [--certificate PEM --private-key PEM]
                        [--connect ENDPOINT] [--device-id ID]

It reads the daemon's config (``/etc/tripod/daemon.yaml`` < ``--config`` < flags; its own keys
are in the ``panel`` section), talks to the daemon over Zenoh like any client, and serves one
page over HTTPS only (the device's certificate), behind the password of the credentials file.
Needs the ``panel`` extra (``pip install 'tripod-daemon[panel]'``: Starlette and uvicorn, pure
Python). Exit codes: 0 stopped by a signal, 2 config or start-up error (one line).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from ..config import SYSTEM_CONFIG, ConfigError, DaemonConfig, load

log = logging.getLogger("tripod_daemon.panel")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tripod-daemon panel",
        description="Serve the operator's page (HTTPS, password) for the daemon on this device.")
    p.add_argument("-c", "--config", help=f"YAML config (layered over {SYSTEM_CONFIG})")
    p.add_argument("--no-system-config", action="store_true",
                   help=f"do not read {SYSTEM_CONFIG}")
    p.add_argument("--listen", metavar="HOST:PORT", help="panel.listen, e.g. 0.0.0.0:8443")
    p.add_argument("--credentials", metavar="FILE",
                   help="panel.credentials_file: one line 'user:password'")
    p.add_argument("--certificate", metavar="PEM", help="panel.certificate (HTTPS)")
    p.add_argument("--private-key", metavar="PEM", help="panel.private_key")
    p.add_argument("--connect", metavar="ENDPOINT", help="panel.connect: the daemon's endpoint")
    p.add_argument("--device-id", help="device_id")
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    return p


def daemon_endpoint(cfg: DaemonConfig) -> str:
    """Where the panel reaches the daemon: ``panel.connect``, else the daemon's first ``tcp/``
    listen endpoint (else its first ``tls/`` one) on this machine."""
    if cfg.panel.connect:
        return cfg.panel.connect
    for want in ("tcp", "tls"):
        for ep in cfg.zenoh.listen:
            proto, _, addr = ep.partition("/")
            if proto != want:
                continue
            host, _, port = addr.split("?", 1)[0].split("#", 1)[0].rpartition(":")
            if host in ("0.0.0.0", "[::]", ""):
                host = "127.0.0.1"
            return f"{proto}/{host}:{port}"
    raise ConfigError("panel.connect is empty and zenoh.listen has no tcp/ or tls/ endpoint: "
                      "set panel.connect to the daemon's endpoint")


def main(argv: list[str] | None = None) -> int:
    a = _parser().parse_args(argv)
    o = {"panel.listen": a.listen, "panel.credentials_file": a.credentials,
         "panel.certificate": a.certificate, "panel.private_key": a.private_key,
         "panel.connect": a.connect, "device_id": a.device_id, "log_level": a.log_level}
    o = {k: v for k, v in o.items() if v is not None}
    try:
        cfg = load(a.config, o, system_config=None if a.no_system_config else SYSTEM_CONFIG)
        return serve(cfg)
    except (ConfigError, ValueError) as exc:
        print(f"tripod-daemon panel: {exc}", file=sys.stderr)
        return 2


def _expand(path: str) -> str:
    return os.path.expandvars(path) if path else ""


def settings(cfg: DaemonConfig):
    """(client options, HTTPS certificate, its key, the page's password) from the config;
    ValueError with one line naming what is missing."""
    from ..client import ClientOptions, read_credentials

    p, tls = cfg.panel, cfg.zenoh.tls
    try:
        creds = read_credentials(p.credentials_file)
    except ValueError as exc:
        raise ValueError(f"refusing to serve the page without a password: {exc}") from None
    if p.certificate:
        cert, key = _expand(p.certificate), _expand(p.private_key)
    elif tls.certificate:
        cert, key = tls.certificate, tls.private_key
    else:
        cert, key = (_expand(f"${{CREDENTIALS_DIRECTORY}}/tripod_device.{x}")
                     for x in ("pem", "key"))
        if "$" in cert:
            cert = key = ""
    if not cert or not key:
        raise ValueError("the page is served over HTTPS only: set panel.certificate and "
                         "panel.private_key (or zenoh.tls.certificate/private_key, or give the "
                         "unit the device's tripod_device.pem/.key: deploy/README.md)")
    for f in (cert, key):
        if not os.path.isfile(f):
            raise ValueError(f"HTTPS certificate: file not found: {f}")
    endpoint = daemon_endpoint(cfg)
    tls_ep = endpoint.startswith("tls/")
    opts = ClientOptions(
        endpoint=endpoint, device_id=cfg.device_id,
        # the daemon asks every peer to log in when it has a users file
        credentials=creds if cfg.zenoh.auth.users_file else None,
        ca=_expand(p.zenoh_ca) or (tls.client_ca if tls_ep else ""),
        certificate=_expand(p.zenoh_certificate) or (
            tls.certificate if tls_ep and tls.client_ca else ""),
        private_key=_expand(p.zenoh_private_key) or (
            tls.private_key if tls_ep and tls.client_ca else ""),
        # on this machine the certificate's names (the device's network names) are not
        # "localhost"; the chain is still checked against the CA
        verify_name=not (tls_ep and not p.connect))
    return opts, cert, key, creds.password


def serve(cfg: DaemonConfig) -> int:
    """Run the panel until SIGTERM/SIGINT (uvicorn's handlers)."""
    from ..systemd import setup_logging

    try:
        import uvicorn

        from .app import create_app
        from .live import LiveState
    except ImportError as exc:
        raise ValueError(f"the panel needs its extra: pip install 'tripod-daemon[panel]' "
                         f"({exc.name} missing)") from None
    opts, cert, key, password = settings(cfg)
    p = cfg.panel
    host, _, port = p.listen.rpartition(":")
    setup_logging(cfg.log_level)
    live = LiveState(opts, p.image_interval_s)
    app = create_app(live, password, p.session_hours)
    log.info("panel for tripod/%s at %s on https://%s:%s/", cfg.device_id, opts.endpoint,
             host, port)
    server = uvicorn.Server(uvicorn.Config(
        app, host=host.strip("[]"), port=int(port), ssl_certfile=cert, ssl_keyfile=key,
        log_level="warning", access_log=False, lifespan="on", proxy_headers=False,
        server_header=False, timeout_graceful_shutdown=2))
    server.run()
    return 0


__all__ = ["daemon_endpoint", "main", "serve", "settings"]
