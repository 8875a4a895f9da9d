# SPDX-License-Identifier: BSD-3-Clause
"""MCAP recording in a writer thread behind a bounded queue (Klipper ``queuelogger`` style).

The receive loop hands over *batches* of already-encoded messages (one ``put`` per wake-up,
not per packet; lidar packets as one :class:`tripod_shared.mcap_writer.MessageBlock` written
without per-packet Python work) and never waits. The backlog is bounded in memory
(``queue_bytes``) and in time (``queue_max_age_s``): when the disk cannot keep up, batches are
dropped and counted (``record_dropped``), the recorder says so (``overload``: status message, an
``overload`` event, a log line every 10 s) and memory stays bounded. The thread owns the
:class:`tripod_shared.recording.RecordingWriter`, closes a chunk at least every
``flush_interval_s`` (see ``recover``), so a ``kill -9`` loses at most about
``queue_max_age_s`` + ``flush_interval_s`` (0.75 s by default) of what the kernel had handed
over; fsync (by policy) runs in a thread of its own so a slow disk never holds up the writer.
It splits files by size and duration and names them by UTC start time.

Self-healing: when the directory cannot be used, a write fails or free space falls below
``min_free_bytes``, the file is finished and, as long as recording is wanted (started and not
stopped), the thread tries again every ``retry_interval_s`` and resumes into a new file by
itself (``record_resumes``); what arrives meanwhile is counted in ``record_unrecorded``.
"""

from __future__ import annotations

import collections
import logging
import os
import queue
import socket
import threading
import time
from collections.abc import Callable
from datetime import datetime, timezone

from tripod_shared import messages
from tripod_shared.mcap_writer import MessageBlock
from tripod_shared.recording import RecordingWriter

from .config import RecordingConfig
from .osutil import set_thread_name
from .stats import Counters

log = logging.getLogger(__name__)

Item = tuple[str, int, bytes]


def batch_size(batch: list) -> tuple[int, int]:
    """(messages, message bytes) of a batch of items and MessageBlocks."""
    n = nbytes = 0
    for it in batch:
        if isinstance(it, MessageBlock):
            n += len(it)
            nbytes += it.nbytes
        else:
            n += 1
            nbytes += len(it[2])
    return n, nbytes

_STOP = object()
_FREE_CHECK_BYTES = 1 << 20  # look at free space at least every MiB written


class _Syncer:
    """fsync in a thread of its own, so a slow disk never holds up the writer: it asks, and
    goes on writing into the page cache (a ``kill -9`` loses nothing written there; fsync is
    for power loss). Requests that pile up while one runs are merged into the newest (an older
    one is the same file, or one fsynced when it was closed)."""

    def __init__(self, counts: Counters):
        self.counts = counts
        counts.setdefault("record_fsync_errors", 0)
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="recorder-fsync", daemon=True)
        self._thread.start()

    def request(self, fd: int) -> None:
        self._q.put(os.dup(fd))

    def close(self, timeout: float = 30.0) -> None:
        self._q.put(None)
        self._thread.join(timeout)

    def _run(self) -> None:
        set_thread_name("tripod-fsync")
        while True:
            fd = self._q.get()
            while fd is not None:
                try:
                    nxt = self._q.get_nowait()
                except queue.Empty:
                    break
                os.close(fd)
                fd = nxt
            if fd is None:
                return
            try:
                os.fsync(fd)
            except OSError as exc:
                self.counts["record_fsync_errors"] += 1
                log.warning("fsync failed: %s", exc)
            finally:
                os.close(fd)


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
        ``record_written``, ``record_dropped`` (backlog over budget), ``record_unrecorded``
        (arrived while recording was wanted but impossible), ``record_files``,
        ``record_bytes``, ``record_resumes`` are added; ``record_queue_bytes`` is the backlog.
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
        for k in ("record_written", "record_dropped", "record_unrecorded", "record_files",
                  "record_bytes", "record_resumes"):
            counts.setdefault(k, 0)
        self.metadata = dict(metadata or {})
        self.free_space = free_space
        self.on_file_closed = on_file_closed
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._enqueued = 0  # written by producers (loop thread) only
        self._dequeued = 0  # written by the writer thread only
        self._enqueued_bytes = 0  # likewise, in message bytes
        self._dequeued_bytes = 0
        # host_monotonic when each queued batch was queued (producer appends, writer pops)
        self._queued_at: collections.deque[float] = collections.deque()
        self._syncer = _Syncer(counts)
        self.active = False  # accepting data (set by the loop's start/stop, read by submit)
        self.wanted = False  # recording asked for (start .. stop): failures are retried
        self.overload = ""  # set while the backlog is over budget (the disk cannot keep up)
        self._overload_log_mono = 0.0
        self._dropped_logged = 0
        self._retry_mono = 0.0
        self.state = "idle"
        self.message = ""
        self.file: str | None = None
        self.files: list[str] = []
        self._writer: RecordingWriter | None = None
        self._fh = None
        self.file_started_ns = 0  # host_realtime when the current file was opened; 0: none
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

    @property
    def pending_bytes(self) -> int:
        return self._enqueued_bytes - self._dequeued_bytes

    def submit(self, batch: list[Item], nbytes: int | None = None) -> None:
        """Queue a batch for writing; never blocks. Ignored while not recording (counted in
        ``record_unrecorded`` while recording is wanted). ``nbytes``: the batch's message
        bytes, when the caller knows them."""
        if not batch:
            return
        n, nb = batch_size(batch)
        if not self.active:
            if self.wanted:
                self.counts["record_unrecorded"] += n
            return
        if nbytes is None:
            nbytes = nb
        now = time.monotonic()
        if self._enqueued_bytes - self._dequeued_bytes + nbytes > self.cfg.queue_bytes:
            self._over_budget(n, f"backlog over {self.cfg.queue_bytes >> 20} MiB")
            return
        try:
            age = now - self._queued_at[0]  # the oldest batch still waiting (or being written)
        except IndexError:
            age = 0.0
        if age > self.cfg.queue_max_age_s:
            self._over_budget(n, f"backlog older than {self.cfg.queue_max_age_s:g} s")
            return
        backlog = self._enqueued_bytes - self._dequeued_bytes
        if self.overload and backlog < self.cfg.queue_bytes // 2 \
                and age < self.cfg.queue_max_age_s / 2:
            self.overload = ""
            log.warning("recording keeps up again (%d messages dropped in all)",
                        self.counts["record_dropped"])
        self._enqueued += n
        self._enqueued_bytes += nbytes
        self._queued_at.append(now)
        self._q.put(batch)

    def _over_budget(self, n: int, why: str) -> None:
        c = self.counts
        c["record_dropped"] += n
        now = time.monotonic()
        if not self.overload or now - self._overload_log_mono >= 10.0:
            self.overload = (f"disk cannot keep up: {why}, "
                             f"{c['record_dropped']} messages dropped")
            log.warning("%s (%d since the last report)", self.overload,
                        c["record_dropped"] - self._dropped_logged)
            self._dropped_logged = c["record_dropped"]
            self._overload_log_mono = now

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
        self.wanted = True
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
        self.active = self.wanted = False
        self._command("stop", reason, wait=None)

    def rotate(self, reason: str = "rotate") -> None:
        """Finish the current file and start the next one (split on demand)."""
        self._command("rotate", reason, wait=None)

    def reconfigure(self, cfg: RecordingConfig, metadata: dict[str, str] | None = None,
                    record: bool = True, reason: str = "reload") -> None:
        """Finish the current file, take the new config, and (``record``) start a new file."""
        self._command("reconfigure", (cfg, dict(metadata or self.metadata), record, reason),
                      wait=None)
        self.active = self.wanted = record

    def mark(self, label: str, host_ns: int | None = None) -> bool:
        """Write a station mark into the recording; False when not recording."""
        if not self.active:
            return False
        self._command("mark", (label, host_ns or time.time_ns()), wait=None)
        return True

    def close(self, reason: str = "shutdown", timeout: float = 30.0) -> None:
        """Write everything queued, finish the file, end the thread."""
        self.active = self.wanted = False
        self._q.put(_STOP)
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.error("recorder did not finish within %.0f s", timeout)
        self._syncer.close()

    # ---- writer thread ----------------------------------------------------------------------
    def _run(self) -> None:
        set_thread_name("tripod-recorder")
        while True:
            cfg = self.cfg
            now = time.monotonic()
            if self._writer is not None:
                timeout = max(0.01, cfg.flush_interval_s - (now - self._last_flush))
            elif self.wanted and self.state in ("error", "stopped"):
                timeout = max(0.01, self._retry_mono - now)
            else:
                timeout = None
            try:
                item = self._q.get(timeout=timeout)
            except queue.Empty:
                item = None
            try:
                if item is _STOP:
                    self._drain_and_finish("shutdown")
                    return
                if isinstance(item, list):
                    n, nbytes = batch_size(item)
                    try:
                        if self._writer is not None:
                            self._write_batch(item, n)
                        else:
                            self.counts["record_unrecorded"] += n
                    finally:
                        self._dequeued += n
                        self._dequeued_bytes += nbytes
                        self._queued_at.popleft()
                elif isinstance(item, _Cmd):
                    self._do(item)
                if self._writer is not None:
                    self._housekeeping()
                elif (self.wanted and self.state in ("error", "stopped")
                      and time.monotonic() >= self._retry_mono):
                    self._retry()
            except Exception as exc:  # noqa: BLE001 - the writer must never die silently
                self._fail(f"recording error: {type(exc).__name__}: {exc}")

    def _retry(self) -> None:
        """Try again to record after a failure (directory gone, unwritable, disk full)."""
        before = self.message
        self._open_file("retry")
        if self._writer is not None:
            self.counts["record_resumes"] += 1
            self.active = True
            log.warning("recording resumed into %s (after: %s)", self.file, before)

    def _drain_and_finish(self, reason: str) -> None:
        while True:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, list):
                n, nbytes = batch_size(item)
                self._dequeued += n
                self._dequeued_bytes += nbytes
                self._queued_at.popleft()
                if self._writer is not None:
                    try:
                        self._write_batch(item, n)
                    except Exception as exc:  # noqa: BLE001
                        self._fail(f"recording error: {type(exc).__name__}: {exc}")
            elif isinstance(item, _Cmd):
                item.done.set()
        self._close_file(reason)
        if self.state == "recording":
            self.state = "idle"

    def _write_batch(self, batch: list, n: int) -> None:
        w = self._writer
        write = w.write_encoded
        for it in batch:
            if isinstance(it, MessageBlock):
                w.write_block(it)
            else:
                write(*it)
        self.counts["record_written"] += n

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
                compression_level=cfg.compression_level,
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
        self.file_started_ns = time.time_ns()  # host_realtime
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
                self._syncer.request(self._fh.fileno())
                self._last_fsync = now
        if flushed and os.fstat(self._fh.fileno()).st_nlink == 0:
            # the file (or its directory) was deleted under us: writing on would fill an
            # invisible inode; finish it and let the retry make the directory and a new file
            path = self.file
            self._fail(f"{path} was deleted while recording")
            return
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
        retry = self.cfg.retry_interval_s
        if msg != self.message or self.state != state:
            log.error("recording stopped: %s%s", msg,
                      f" (retrying every {retry:g} s)" if self.wanted else "")
        self.active = False
        if self._writer is not None:
            self._close_file(state)
        self.state, self.message = state, msg
        self._retry_mono = time.monotonic() + retry
