# SPDX-License-Identifier: BSD-3-Clause
"""MCAP recording in a writer thread behind a bounded queue (Klipper ``queuelogger`` style).

The receive loop hands over *batches* of already-encoded messages (one ``put`` per readiness
event, not per packet) and never waits: when the queue holds ``queue_messages`` the batch is
counted in ``record_dropped`` and the loop goes on. The thread owns the
:class:`tripod_shared.recording.RecordingWriter`, closes a chunk at least every
``flush_interval_s`` (so a ``kill -9`` loses at most that much, see ``recover``), fsyncs by
policy, splits files by size and duration, names them by UTC start time, and stops cleanly
with a status saying why when free space falls below ``min_free_bytes`` or a write fails.
"""

from __future__ import annotations

import logging
import os
import queue
import socket
import threading
import time
from collections.abc import Callable
from datetime import datetime, timezone

from tripod_shared import messages
from tripod_shared.recording import RecordingWriter

from .config import RecordingConfig
from .stats import Counters

log = logging.getLogger(__name__)

Item = tuple[str, int, bytes]

_STOP = object()
_FREE_CHECK_BYTES = 1 << 20  # look at free space at least every MiB written


class _Cmd:
    def __init__(self, name: str, arg=None):
        self.name = name
        self.arg = arg
        self.done = threading.Event()
        self.result = None


def free_bytes(path: str) -> int:
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


class Recorder:
    """Owns the recording thread. Thread-safe entry points: ``submit``, ``start``, ``stop``,
    ``mark``, ``rotate``, ``close``; state is read through ``state``/``file``/``message``.

    Parameters
    ----------
    cfg : RecordingConfig
    counts : Counters
        ``record_written``, ``record_dropped``, ``record_files``, ``record_bytes`` are added.
    metadata : dict
        Written as the ``tripod_daemon`` metadata record of every file (e.g. the config).
    free_space : callable(path) -> int
        Free bytes for the recording directory; a test hook, ``os.statvfs`` by default.
    """

    def __init__(
        self,
        cfg: RecordingConfig,
        counts: Counters,
        metadata: dict[str, str] | None = None,
        free_space: Callable[[str], int] = free_bytes,
        on_file_closed: Callable[[str], None] | None = None,
    ):
        self.cfg = cfg
        self.counts = counts
        for k in ("record_written", "record_dropped", "record_files", "record_bytes"):
            counts.setdefault(k, 0)
        self.metadata = dict(metadata or {})
        self.free_space = free_space
        self.on_file_closed = on_file_closed
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._enqueued = 0  # written by producers (loop thread) only
        self._dequeued = 0  # written by the writer thread only
        self.active = False  # accepting data (set by the loop's start/stop, read by submit)
        self.state = "idle"
        self.message = ""
        self.file: str | None = None
        self.files: list[str] = []
        self._writer: RecordingWriter | None = None
        self._fh = None
        self._opened_mono = 0.0
        self._last_flush = 0.0
        self._last_fsync = 0.0
        self._bytes_at_check = 0
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    # ---- producer side (loop thread) --------------------------------------------------------
    @property
    def pending(self) -> int:
        return self._enqueued - self._dequeued

    def submit(self, batch: list[Item]) -> None:
        """Queue a batch for writing; never blocks. Ignored while not recording."""
        if not self.active or not batch:
            return
        n = len(batch)
        if self._enqueued - self._dequeued + n > self.cfg.queue_messages:
            self.counts["record_dropped"] += n
            return
        self._enqueued += n
        self._q.put(batch)

    def _command(self, name: str, arg=None, wait: float | None = 10.0):
        cmd = _Cmd(name, arg)
        self._q.put(cmd)
        if wait:
            cmd.done.wait(wait)
        return cmd.result

    def start(self, reason: str = "start") -> bool:
        """Open a new file (if not recording) and wait for it; True when recording."""
        done = self.start_async(reason)
        done.wait(10.0)
        return self.active

    def start_async(self, reason: str = "start") -> threading.Event:
        """Ask for a new file without waiting (the writer may still be busy with a backlog);
        data submitted from now on goes into it. The event is set once the file is open, or
        opening failed (then ``active`` is False again and ``state``/``message`` say why)."""
        if self.active:
            done = threading.Event()
            done.set()
            return done
        self.active = True
        cmd = _Cmd("start", reason)
        self._q.put(cmd)
        return cmd.done

    # The calls below never wait for the writer: under load its queue may hold seconds of
    # data, and the receive loop must not stop reading the sockets meanwhile.
    def stop(self, reason: str = "stop") -> None:
        """Finish the current file after what is queued before this call."""
        self.active = False
        self._command("stop", reason, wait=None)

    def rotate(self, reason: str = "rotate") -> None:
        """Finish the current file and start the next one (split on demand)."""
        self._command("rotate", reason, wait=None)

    def reconfigure(self, cfg: RecordingConfig, metadata: dict[str, str] | None = None,
                    record: bool = True, reason: str = "reload") -> None:
        """Finish the current file, take the new config, and (``record``) start a new file."""
        self._command("reconfigure", (cfg, dict(metadata or self.metadata), record, reason),
                      wait=None)
        self.active = record

    def mark(self, label: str, host_ns: int | None = None) -> bool:
        """Write a station mark into the recording; False when not recording."""
        if not self.active:
            return False
        self._command("mark", (label, host_ns or time.time_ns()), wait=None)
        return True

    def close(self, reason: str = "shutdown", timeout: float = 30.0) -> None:
        """Write everything queued, finish the file, end the thread."""
        self.active = False
        self._q.put(_STOP)
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.error("recorder did not finish within %.0f s", timeout)

    # ---- writer thread ----------------------------------------------------------------------
    def _run(self) -> None:
        cfg = self.cfg
        while True:
            timeout = max(0.01, cfg.flush_interval_s - (time.monotonic() - self._last_flush))
            try:
                item = self._q.get(timeout=timeout if self._writer else None)
            except queue.Empty:
                item = None
            try:
                if item is _STOP:
                    self._drain_and_finish("shutdown")
                    return
                if isinstance(item, list):
                    self._dequeued += len(item)
                    if self._writer is not None:
                        self._write_batch(item)
                    else:
                        self.counts["record_dropped"] += len(item)
                elif isinstance(item, _Cmd):
                    self._do(item)
                if self._writer is not None:
                    self._housekeeping()
            except Exception as exc:  # noqa: BLE001 - the writer must never die silently
                self._fail(f"recording error: {type(exc).__name__}: {exc}")

    def _drain_and_finish(self, reason: str) -> None:
        while True:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, list):
                self._dequeued += len(item)
                if self._writer is not None:
                    try:
                        self._write_batch(item)
                    except Exception as exc:  # noqa: BLE001
                        self._fail(f"recording error: {type(exc).__name__}: {exc}")
            elif isinstance(item, _Cmd):
                item.done.set()
        self._close_file(reason)
        if self.state == "recording":
            self.state = "idle"

    def _write_batch(self, batch: list[Item]) -> None:
        write = self._writer.write_encoded
        for topic, ns, data in batch:
            write(topic, ns, data)
        self.counts["record_written"] += len(batch)

    def _do(self, cmd: _Cmd) -> None:
        try:
            if cmd.name == "start":
                if self._writer is None:
                    self._open_file(cmd.arg)
                cmd.result = self._writer is not None
                if not cmd.result:
                    self.active = False
            elif cmd.name == "stop":
                self._close_file(cmd.arg)
                self.state, self.message = "idle", f"stopped ({cmd.arg})"
            elif cmd.name == "rotate":
                if self._writer is not None:
                    self._close_file(cmd.arg)
                    self._open_file(cmd.arg)
            elif cmd.name == "reconfigure":
                cfg, meta, record, reason = cmd.arg
                self._close_file(reason)
                self.cfg, self.metadata = cfg, meta
                self.state, self.message = "idle", ""
                if record:
                    self._open_file(reason)
            elif cmd.name == "mark":
                label, ns = cmd.arg
                if self._writer is not None:
                    self._writer.write_event(messages.Event(ns, "mark", label))
                    cmd.result = True
        finally:
            cmd.done.set()

    def _new_path(self) -> str:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S")
        base = os.path.join(self.cfg.directory, f"{self.cfg.prefix}_{stamp}Z")
        path, k = base + ".mcap", 1
        while os.path.exists(path):
            path, k = f"{base}_{k}.mcap", k + 1
        return path

    def _open_file(self, reason: str) -> None:
        cfg = self.cfg
        try:
            os.makedirs(cfg.directory, exist_ok=True)
            free = self.free_space(cfg.directory)
        except OSError as exc:
            self._fail(f"cannot use {cfg.directory}: {exc}")
            return
        if free < cfg.min_free_bytes:
            self._fail(f"disk full: {free >> 20} MiB free < min_free_bytes "
                       f"{cfg.min_free_bytes >> 20} MiB in {cfg.directory}", state="stopped")
            return
        path = self._new_path()
        try:
            self._fh = open(path, "xb")
            meta = {"host": socket.gethostname(), **self.metadata}
            self._writer = RecordingWriter(
                self._fh, chunk_size=cfg.chunk_size_bytes, compression=cfg.compression,
                metadata={"writer": "tripod-daemon"}, library="tripod-daemon")
            self._writer.add_metadata("tripod_daemon", meta)
            self._writer.write_event(messages.Event(time.time_ns(), "start", reason))
            self._writer.flush_chunk()
        except OSError as exc:
            self._fail(f"cannot write {path}: {exc}")
            return
        now = time.monotonic()
        self._opened_mono = self._last_flush = self._last_fsync = now
        self._bytes_at_check = 0
        self.file = path
        self.files.append(path)
        self.counts["record_files"] += 1
        self.state, self.message = "recording", ""
        log.info("recording to %s", path)

    def _close_file(self, reason: str) -> None:
        w, fh, path = self._writer, self._fh, self.file
        if w is None:
            return
        self._writer = self._fh = None
        try:
            w.write_event(messages.Event(time.time_ns(), "stop", reason))
            w.add_metadata("tripod_daemon_counts", {k: str(v) for k, v in self.counts.items()})
            w.close()
            fh.flush()
            if self.cfg.fsync != "never":
                os.fsync(fh.fileno())
            log.info("finished %s (%s)", path, reason)
        except (OSError, ValueError) as exc:
            log.error("finishing %s failed: %s; `tripod-daemon recover %s` rebuilds it",
                      path, exc, path)
        finally:
            try:
                fh.close()
            except OSError:
                pass
        self.file = None
        if self.on_file_closed and path:
            self.on_file_closed(path)

    def _housekeeping(self) -> None:
        cfg = self.cfg
        now = time.monotonic()
        size = self._fh.tell()
        self.counts["record_bytes"] = size
        flushed = False
        if now - self._last_flush >= cfg.flush_interval_s:
            self._writer.flush_chunk()
            self._last_flush = now
            flushed = True
            if cfg.fsync == "chunk" or (
                cfg.fsync == "interval" and now - self._last_fsync >= cfg.fsync_interval_s
            ):
                os.fsync(self._fh.fileno())
                self._last_fsync = now
        if flushed or size - self._bytes_at_check >= _FREE_CHECK_BYTES:
            self._bytes_at_check = size
            free = self.free_space(cfg.directory)
            if free < cfg.min_free_bytes:
                msg = (f"disk full: {free >> 20} MiB free < min_free_bytes "
                       f"{cfg.min_free_bytes >> 20} MiB in {cfg.directory}")
                self._close_file("disk full")
                self._fail(msg, state="stopped")
                return
        if (cfg.max_file_bytes and size >= cfg.max_file_bytes) or (
            cfg.max_file_duration_s and now - self._opened_mono >= cfg.max_file_duration_s
        ):
            self._close_file("split")
            self._open_file("split")

    def _fail(self, msg: str, state: str = "error") -> None:
        log.error("recording stopped: %s", msg)
        self.active = False
        if self._writer is not None:
            self._close_file(state)
        self.state, self.message = state, msg
