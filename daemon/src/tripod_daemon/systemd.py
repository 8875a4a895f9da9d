# SPDX-License-Identifier: BSD-3-Clause
"""sd_notify without dependencies: READY=1, WATCHDOG=1, STATUS=..., STOPPING=1, RELOADING=1.

systemd passes ``NOTIFY_SOCKET`` (a path, or ``@name`` in the abstract namespace) and, with
``WatchdogSec=``, ``WATCHDOG_USEC`` (and ``WATCHDOG_PID``). Without ``NOTIFY_SOCKET`` every call
is a no-op, so the daemon runs the same in a terminal. Logging is plain lines on stderr; journald
adds the timestamps (``SyslogLevelPrefix``-style ``<N>`` prefixes are added when under journald).
"""

from __future__ import annotations

import logging
import os
import socket
import sys


class Notifier:
    """Send sd_notify datagrams to ``NOTIFY_SOCKET`` (read once, at construction)."""

    def __init__(self, environ: dict | None = None):
        env = os.environ if environ is None else environ
        addr = env.get("NOTIFY_SOCKET", "")
        self._sock: socket.socket | None = None
        self._addr: str | None = None
        if addr and addr[0] in "/@":
            self._addr = "\0" + addr[1:] if addr[0] == "@" else addr
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            # Never block the receive loop: a notify socket nobody reads fills up, and then a
            # message is dropped (and reported False) instead of stalling reception.
            self._sock.setblocking(False)
        self.watchdog_interval_s = self._watchdog(env)

    @staticmethod
    def _watchdog(env) -> float | None:
        """Half of systemd's WatchdogSec [s] (ping twice per period), or None when off."""
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        if not usec.isdigit() or int(usec) == 0:
            return None
        if pid and pid.isdigit() and int(pid) != os.getpid():
            return None
        return int(usec) / 2e6

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, state: str) -> bool:
        if self._sock is None:
            return False
        try:
            self._sock.sendto(state.encode("utf-8", "replace"), self._addr)
            return True
        except OSError:
            return False  # systemd gone or socket full (EAGAIN): never fatal, never blocks

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def reloading(self) -> bool:
        return self.notify("RELOADING=1")

    def stopping(self, status: str = "") -> bool:
        return self.notify("STOPPING=1" + (f"\nSTATUS={status}" if status else ""))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


_JOURNAL_PRIORITY = {
    logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2,
}


class _JournalPrefix(logging.Formatter):
    """``<priority>`` prefixes that journald turns into log levels."""

    def format(self, record: logging.LogRecord) -> str:
        return f"<{_JOURNAL_PRIORITY.get(record.levelno, 6)}>" + super().format(record)


def _stderr_is_journal(stream) -> bool:
    """True when ``stream`` is the journald stream systemd connected (JOURNAL_STREAM=dev:ino)."""
    want = os.environ.get("JOURNAL_STREAM", "")
    try:
        st = os.fstat(stream.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return want == f"{st.st_dev}:{st.st_ino}"


def setup_logging(level: str = "info", stream=None) -> None:
    """Plain lines on stderr; under journald (JOURNAL_STREAM set) with priority prefixes."""
    stream = stream or sys.stderr
    handler = logging.StreamHandler(stream)
    fmt = "%(name)s: %(message)s"
    if _stderr_is_journal(stream):
        handler.setFormatter(_JournalPrefix(fmt))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s " + fmt))
    root = logging.getLogger("tripod_daemon")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
