# SPDX-License-Identifier: BSD-3-Clause
"""Control plane security over loopback: who may query control/*, TLS and user/password
logins, label and rate limits. The data keys stay readable by every peer that may connect."""

from __future__ import annotations

import json
import logging
import os
import threading
import time

import zenoh

from daemon_helpers import (
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    make_data_packet,
    mutual_tls_setup,
    udp_sender,
)
from tripod_daemon.config import ZenohConfig
from tripod_daemon.publisher import build_zenoh_config


def _client(endpoint: str, **zenoh_kw) -> zenoh.Session:
    return zenoh.open(build_zenoh_config(ZenohConfig(listen=[], connect=[endpoint], **zenoh_kw)))


def _control(session, device_id: str, command: str, label: bytes | str | None = None,
             timeout: float = 3.0) -> dict | None:
    """The JSON reply (ok or error), or None when no reply came (refused by access control)."""
    replies = list(session.get(f"tripod/{device_id}/control/{command}", payload=label,
                               timeout=timeout))
    for r in replies:
        if r.ok is not None:
            return json.loads(r.ok.payload.to_bytes())
        err = r.err.payload.to_bytes()
        if err.startswith(b"{"):
            return json.loads(err)
    return None  # no reply, or zenoh's own "Timeout"


def _wait_status(session, device_id: str) -> None:
    """A status sample proves the session reached the daemon and may read the data keys."""
    seen = threading.Event()
    sub = session.declare_subscriber(f"tripod/{device_id}/status", lambda _s: seen.set())
    assert seen.wait(15), "no status sample: the data keys are not open to this peer"
    sub.undeclare()


def _recording_goes_on(d) -> None:
    c = d.daemon.counts
    before = c["record_written"]
    s = udp_sender()
    for k in range(50):
        s.sendto(make_data_packet(k), d.data_addr)
    assert d.wait_for(lambda: c["record_written"] >= before + 50, timeout=10)
    assert d.daemon.recorder.active


def test_default_control_only_from_loopback_and_logged_with_the_peer(tmp_path, caplog):
    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    caplog.set_level(logging.INFO, logger="tripod_daemon")
    with RunningDaemon(cfg) as d, _client(f"tcp/127.0.0.1:{port}") as z:
        _wait_status(z, cfg.device_id)
        r = _control(z, cfg.device_id, "mark", "station 1")
        assert r and r["ok"] and r["label"] == "station 1"
        d.stop()
    assert "control accepted only from this machine (loopback)" in caplog.text
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("control/mark"))
    assert "'station 1'" in line and "via lo" in line and "tcp/127.0.0.1:" in line


def _users(tmp_path):
    users = tmp_path / "zenoh-users"
    users.write_text("operator:op-secret\nviewer:view-secret\n")
    pw = {}
    for name, secret in (("operator", "op-secret"), ("viewer", "view-secret"),
                         ("intruder", "guess")):
        pw[name] = tmp_path / f"{name}.pw"
        pw[name].write_text(secret + "\n")
    return users, pw


def test_user_password_only_operator_may_control_and_recording_goes_on(tmp_path):
    users, pw = _users(tmp_path)
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={
        "enabled": True, "listen": [ep], "auth": {"users_file": str(users)},
        "control": {"allow_loopback": False, "users": ["operator"]}})
    with RunningDaemon(cfg) as d:
        # a viewer logs in and reads the data, but control/stop never reaches the daemon
        with _client(ep, auth={"user": "viewer", "password_file": str(pw["viewer"])}) as z:
            _wait_status(z, cfg.device_id)
            assert _control(z, cfg.device_id, "stop", timeout=1.5) is None
        assert d.daemon.counts["control_requests"] == 0
        _recording_goes_on(d)
        # a wrong password gets no session with the daemon at all
        with _client(ep, auth={"user": "intruder", "password_file": str(pw["intruder"])}) as z:
            assert _control(z, cfg.device_id, "stop", timeout=1.0) is None
        _recording_goes_on(d)
        # the operator may
        with _client(ep, auth={"user": "operator", "password_file": str(pw["operator"])}) as z:
            _wait_status(z, cfg.device_id)
            r = _control(z, cfg.device_id, "stop")
            assert r == {"ok": True, "recording": False, "file": None}
        assert d.wait_for(lambda: not d.daemon.recorder.active)
        d.stop()


def test_mutual_tls_only_the_operator_certificate_may_control(tmp_path, caplog):
    cfg, ep, certs, ca = mutual_tls_setup(tmp_path)

    def tls(name):
        return {"certificate": str(certs / f"{name}.pem"),
                "private_key": str(certs / f"{name}.key"), "client_ca": ca}

    with RunningDaemon(cfg) as d:
        with _client(ep, tls=tls("viewer")) as z:
            _wait_status(z, cfg.device_id)
            assert _control(z, cfg.device_id, "stop", timeout=1.5) is None
        _recording_goes_on(d)
        caplog.set_level(logging.INFO, logger="tripod_daemon")
        with _client(ep, tls=tls("operator")) as z:
            _wait_status(z, cfg.device_id)
            r = _control(z, cfg.device_id, "stop")
            assert r and r["ok"] and r["recording"] is False
        assert d.wait_for(lambda: not d.daemon.recorder.active)
        d.stop()
    # the log names the peer by the certificate zenoh authenticated
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("control/stop"))
    assert line.endswith("via lo as operator") and "tls/127.0.0.1:" in line


def _rss_kib() -> int:
    with open(f"/proc/{os.getpid()}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def test_huge_and_bad_labels_refused_and_counted(tmp_path):
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [ep]})
    with RunningDaemon(cfg) as d, _client(ep) as z:
        _wait_status(z, cfg.device_id)
        c = d.daemon.counts
        rss0 = _rss_kib()
        # 100 MB: over zenoh.max_message_bytes, refused before it is reassembled
        for _ in range(2):
            assert _control(z, cfg.device_id, "mark", b"x" * (100 << 20), timeout=1.5) is None
        assert _rss_kib() - rss0 < 400 << 10  # the test's own 100 MB payload, not 2 x 100 MB more
        # over max_label_bytes, not UTF-8, control characters: refused with the reason
        r = _control(z, cfg.device_id, "mark", b"y" * 300_000)
        assert r == {"ok": False, "error": "label too long: 300000 bytes > 256"}
        r = _control(z, cfg.device_id, "mark", b"\xff\xfe")
        assert r["ok"] is False and "UTF-8" in r["error"]
        r = _control(z, cfg.device_id, "mark", "a\x1b[2Jb")
        assert r["ok"] is False and "control characters" in r["error"]
        assert c["control_refused_label"] == 3 == c["control_refused"]
        assert _control(z, cfg.device_id, "mark", "ok label")["ok"] is True
        _recording_goes_on(d)
        d.stop()
    from tripod_shared.recording import RecordingReader

    labels = [e.label for e in RecordingReader(d.daemon.recorder.files[0]).events()
              if e.kind == "mark"]
    assert labels == ["ok label"]


def test_start_stop_flood_is_rate_limited_and_counted(tmp_path):
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [ep],
                                           "control": {"burst": 6, "rate_per_s": 1.0}})
    with RunningDaemon(cfg) as d, _client(ep) as z:
        _wait_status(z, cfg.device_id)
        t0 = time.monotonic()
        results = [_control(z, cfg.device_id, cmd) for _ in range(100) for cmd in ("stop", "start")]
        elapsed = time.monotonic() - t0
        c = d.daemon.counts
        ok = sum(1 for r in results if r and r["ok"])
        refused = [r for r in results if r and not r["ok"]]
        assert ok <= 6 + int(elapsed) + 1
        assert len(refused) == c["control_refused_rate"] == 200 - ok
        assert all("too many control requests" in r["error"] for r in refused)
        d.stop()
    assert len(d.daemon.recorder.files) <= 1 + ok // 2 + 1
