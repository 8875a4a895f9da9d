# SPDX-License-Identifier: BSD-3-Clause
"""The sd_notify protocol against a fake NOTIFY_SOCKET: ``main()`` runs in a thread and is
stopped with SIGTERM through the daemon's self-pipe."""

from __future__ import annotations

import signal
import socket
import threading
import time

from tripod_daemon import loop
from tripod_daemon.main import main
from tripod_daemon.systemd import Notifier


def _listen(tmp_path):
    path = str(tmp_path / "notify.sock")
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(path)
    s.settimeout(0.1)
    return s, path


def _collect(sock, until, timeout=20.0):
    msgs = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            msgs.append(sock.recv(4096).decode())
        except TimeoutError:
            pass
        if until(msgs):
            break
    return msgs


def test_notify_protocol_order(tmp_path, monkeypatch):
    sock, path = _listen(tmp_path)
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # ping every 0.2 s
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    rc = []
    cfgfile = tmp_path / "daemon.yaml"
    cfgfile.write_text("lidar:\n  bind_address: 127.0.0.1\nstatus:\n  interval_s: 0.3\n")
    argv = ["--no-system-config", "--config", str(cfgfile), "--no-zenoh", "--lidar-port", "0", "--position-port", "0",
            "--record-dir", str(tmp_path / "rec")]
    t = threading.Thread(target=lambda: rc.append(main(argv)), daemon=True)
    t.start()
    msgs = _collect(sock, lambda m: sum("WATCHDOG=1" in x for x in m) >= 3
                    and any(x.startswith("STATUS=") for x in m))
    assert loop.RUNNING, "daemon loop not running"
    loop.RUNNING[0].signal(signal.SIGTERM)
    t.join(20)
    msgs += _collect(sock, lambda m: any("STOPPING=1" in x for x in m), timeout=2)
    assert rc == [0]
    kinds = [line.split("=", 1)[0] for m in msgs for line in m.splitlines()]
    # READY first (with a status), then status and watchdog pings, STOPPING last
    assert kinds[0] == "READY"
    assert "WATCHDOG" in kinds and "STATUS" in kinds[1:]
    assert kinds[-1] in ("STOPPING", "STATUS") and "STOPPING" in kinds
    assert kinds.index("STOPPING") > max(i for i, k in enumerate(kinds) if k == "WATCHDOG")
    ready = next(m for m in msgs if m.startswith("READY=1"))
    assert "STATUS=" in ready and "lidar" in ready
    status = [m for m in msgs if m.startswith("STATUS=")]
    assert any("drops 0" in m for m in status)
    sock.close()


def test_notifier_abstract_socket_and_watchdog_env():
    n = Notifier({"NOTIFY_SOCKET": "@tripod-test-abstract", "WATCHDOG_USEC": "2000000"})
    assert n.enabled and n.watchdog_interval_s == 1.0
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind("\0tripod-test-abstract")
    try:
        assert n.ready("up")
        assert s.recv(100) == b"READY=1\nSTATUS=up"
    finally:
        s.close()
        n.close()
    # no NOTIFY_SOCKET: everything is a harmless no-op
    off = Notifier({})
    assert not off.enabled and not off.watchdog() and off.watchdog_interval_s is None
    # a watchdog meant for another process is not ours
    assert Notifier({"WATCHDOG_USEC": "1000", "WATCHDOG_PID": "1"}).watchdog_interval_s is None


def test_notify_to_vanished_socket_is_not_fatal(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    assert n.notify("STATUS=x") is False


def test_journald_stream_gets_priority_prefixes(tmp_path, monkeypatch):
    import logging
    import os

    from tripod_daemon.systemd import setup_logging

    path = tmp_path / "journal"
    with open(path, "w") as fh:
        st = os.fstat(fh.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        setup_logging("info", stream=fh)
        logging.getLogger("tripod_daemon.test").warning("disk almost full")
        logging.getLogger("tripod_daemon.test").debug("not shown at info")
    assert path.read_text() == "<4>tripod_daemon.test: disk almost full\n"
    # a terminal (or any other stream) gets plain timestamped lines instead
    other = tmp_path / "other"
    with open(other, "w") as fh:
        setup_logging("info", stream=fh)
        logging.getLogger("tripod_daemon.test").error("boom")
    line = other.read_text()
    assert "ERROR tripod_daemon.test: boom" in line and not line.startswith("<")


def test_notify_never_blocks_when_nobody_reads(tmp_path):
    """A NOTIFY_SOCKET that is never read fills up; notify must drop, not stall the loop."""
    path = str(tmp_path / "notify.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    try:
        n = Notifier({"NOTIFY_SOCKET": path})
        t0 = time.monotonic()
        results = [n.status("x" * 200) for _ in range(5000)]
        assert time.monotonic() - t0 < 5.0
        assert results[0] is True and results[-1] is False  # the queue filled, then dropped
        n.close()
    finally:
        server.close()
