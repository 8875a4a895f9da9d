# SPDX-License-Identifier: BSD-3-Clause
"""A Zenoh client of the daemon, for ``ctl`` and ``panel``: connect with the daemon's
authentication (user/password from a credentials file, TLS certificates), query the status and
send control commands, each failure as one clear line.

Credentials file: one line ``user:password`` (the format of a line of the daemon's
``zenoh.auth.users_file``); blank lines and ``#`` comments are ignored.
"""

from __future__ import annotations

import json
import os
import socket
from dataclasses import dataclass

from tripod_shared import topics

from .config import ZenohConfig, ZenohTlsConfig, check_endpoint


class ClientError(Exception):
    """Could not talk to the daemon (no session, no answer): exit code 2 in ``ctl``."""


class ControlRefused(Exception):
    """The daemon (or its access control) refused the command: exit code 1 in ``ctl``."""


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str


def read_credentials(path: str) -> Credentials:
    """The first ``user:password`` line of ``path``; ValueError naming the problem."""
    path = os.path.expandvars(path)
    try:
        with open(path, encoding="utf-8") as fh:
            lines = [ln.strip() for ln in fh]
    except OSError as exc:
        raise ValueError(f"credentials file {path}: {exc.strerror or exc}") from None
    for ln in lines:
        if not ln or ln.startswith("#"):
            continue
        user, sep, password = ln.partition(":")
        if not sep or not user or not password:
            raise ValueError(f"credentials file {path}: expected one line 'user:password'")
        return Credentials(user, password)
    raise ValueError(f"credentials file {path}: empty (expected one line 'user:password')")


@dataclass
class ClientOptions:
    """How to reach the daemon. ``ca``: the CA that signed the device's certificate (for
    ``tls/`` endpoints); ``certificate``/``private_key``: this client's own certificate when the
    daemon asks for mutual TLS."""

    endpoint: str = "tcp/127.0.0.1:7447"
    device_id: str = topics.DEFAULT_DEVICE_ID
    credentials: Credentials | None = None
    ca: str = ""
    certificate: str = ""
    private_key: str = ""
    timeout_s: float = 5.0
    verify_name: bool = True  # check the device certificate's name against the endpoint's host


def build_client_config(opts: ClientOptions):
    """A zenoh Config for a peer that connects to ``opts.endpoint`` only (no listening, no
    scouting) and fails at open when the connection or the login fails."""
    from .publisher import build_zenoh_config

    check_endpoint(opts.endpoint)
    for what, path in (("--ca", opts.ca), ("--cert", opts.certificate),
                       ("--key", opts.private_key)):
        if path and not os.path.isfile(path):
            raise ValueError(f"{what}: file not found: {path}")
    if bool(opts.certificate) != bool(opts.private_key):
        raise ValueError("--cert and --key go together")
    conf = build_zenoh_config(ZenohConfig(
        listen=[], connect=[opts.endpoint],
        tls=ZenohTlsConfig(certificate=opts.certificate, private_key=opts.private_key,
                           verify_name_on_connect=opts.verify_name)))
    if opts.ca:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(opts.ca))
    if opts.certificate:
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    if opts.credentials is not None:
        conf.insert_json5("transport/auth/usrpwd", json.dumps(
            {"user": opts.credentials.user, "password": opts.credentials.password}))
    conf.insert_json5("connect/timeout_ms", json.dumps(int(opts.timeout_s * 1000)))
    conf.insert_json5("connect/exit_on_failure", "true")
    return conf


def _tcp_answers(endpoint: str, timeout_s: float) -> bool:
    """Whether something accepts a TCP connection at the endpoint's host:port."""
    addr = endpoint.split("/", 1)[1].split("?", 1)[0].split("#", 1)[0]
    host, _, port = addr.rpartition(":")
    host = host.strip("[]")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


def open_session(opts: ClientOptions):
    """An open zenoh session to the daemon, or :class:`ClientError` with one line saying why."""
    import zenoh

    try:
        conf = build_client_config(opts)
    except (ValueError, OSError) as exc:
        raise ClientError(str(exc)) from None
    try:
        return zenoh.open(conf)
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError
        ep = opts.endpoint
        if ep.split("/", 1)[0] in ("tcp", "tls") and _tcp_answers(ep, min(opts.timeout_s, 2.0)):
            how = []
            if opts.credentials is not None:
                how.append(f"user {opts.credentials.user!r}: wrong user or password?")
            else:
                how.append("it may ask for a login (--credentials FILE)")
            if ep.startswith("tls/"):
                how.append("or the certificates do not match (--ca, --cert/--key)")
            raise ClientError(f"{ep} answers but refused the session: {' '.join(how)}") from None
        first = str(exc).split(" at /", 1)[0].strip()
        raise ClientError(f"cannot connect to {ep}: {first}") from None


def query_status(session, opts: ClientOptions) -> dict:
    """The daemon's status (JSON as a dict), or :class:`ClientError`."""
    for r in session.get(topics.key_status(opts.device_id), timeout=opts.timeout_s):
        if r.ok is not None:
            return json.loads(r.ok.payload.to_bytes())
    raise ClientError(f"no status from tripod/{opts.device_id} at {opts.endpoint} within "
                      f"{opts.timeout_s:g} s (daemon not running, or another device_id?)")


def control(session, opts: ClientOptions, command: str, label: str = "") -> dict:
    """Run ``command`` (start, stop, mark) with ``label``; the daemon's reply as a dict.

    Raises :class:`ControlRefused` when the daemon refuses it, or when no reply comes although
    the status answers (zenoh's access control drops control queries from peers that
    ``zenoh.control`` does not list), and :class:`ClientError` when the daemon does not answer
    at all.
    """
    if command not in topics.CONTROL_COMMANDS:
        raise ValueError(f"unknown command {command!r} ({', '.join(topics.CONTROL_COMMANDS)})")
    key = topics.key_control(opts.device_id, command)
    payload = label.encode("utf-8") if label else None
    for r in session.get(key, payload=payload, timeout=opts.timeout_s):
        if r.ok is not None:
            reply = json.loads(r.ok.payload.to_bytes())
            if not reply.get("ok", False):
                if reply.get("error"):
                    raise ControlRefused(reply["error"])
                if command == "mark" and not reply.get("recording", True):
                    raise ControlRefused("not recording: the mark was not written (start first)")
                raise ControlRefused(json.dumps(reply))
            return reply
        err = r.err.payload.to_bytes()
        if err.startswith(b"{"):
            raise ControlRefused(json.loads(err).get("error", err.decode("utf-8", "replace")))
    query_status(session, opts)  # raises ClientError when the daemon is not there at all
    who = f"user {opts.credentials.user!r}" if opts.credentials else "this client"
    raise ControlRefused(f"control/{command} refused: {who} is not allowed to control "
                         f"tripod/{opts.device_id} (the daemon's zenoh.control)")
