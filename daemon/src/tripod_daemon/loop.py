# SPDX-License-Identifier: BSD-3-Clause
"""The daemon: one ``selectors`` loop over the UDP sockets, the IMU port, a self-pipe for
signals and commands, and a tick (status, health, watchdog, IMU reconnect).

Light on the CPU: the lidar sends a datagram every 0.66 ms (dual return); waking for each one
costs more than handling it. So the UDP sockets are drained at most every
``lidar.wake_interval_ms`` (50 ms): after a drain the loop waits only on the IMU port and the
self-pipe until the interval is over, while the kernel queues the datagrams with their receive
stamps (SO_TIMESTAMPNS), so stamps are unchanged and nothing is lost (the receive buffer holds
seconds). Each wake-up hands one batch to the recorder and one to the publisher. The IMU's
serial port has no kernel stamps, so it is read as soon as it is readable.

Data flows one way: sockets/port -> encoded batch -> recorder queue (MCAP thread) and publisher
queue (Zenoh thread). The loop itself never writes files or sends to the network, so nothing
downstream can stall reception; its only blocking call is ``select``.

Signals: SIGTERM/SIGINT finish the file and exit 0; SIGHUP re-reads the config and starts a
new file. Signals and commands from other threads (Zenoh control queries) reach the loop through
the self-pipe, so ``main()`` can also run in a thread (tests) and be stopped with :meth:`signal`.
"""

from __future__ import annotations

import logging
import os
import queue
import selectors
import signal
import sys
import threading
import time
from collections.abc import Callable

from tripod_shared import messages, topics
from tripod_shared.config_io import ConfigError, dump_config

from .clock import LidarClock
from .config import DaemonConfig
from .imu_serial import ImuInput
from .lidar_udp import LidarInput
from .recorder import Recorder, free_bytes
from .stats import Counters, RateMeter, status_line
from .systemd import Notifier

log = logging.getLogger(__name__)

_CMD_BYTE = b"\xff"  # a command waits in the queue; other bytes are signal numbers

#: daemons whose loop is running in this process (tests stop a ``main()`` thread through it)
RUNNING: "list[Daemon]" = []


class _Command:
    def __init__(self, name: str, label: str):
        self.name, self.label = name, label
        self.done = threading.Event()
        self.result: dict = {}


class Daemon:
    """Runs until SIGTERM/SIGINT (or :meth:`signal`). Build, then :meth:`run` (returns 0 on a
    clean stop, 1 when start-up failed)."""

    def __init__(
        self,
        cfg: DaemonConfig,
        *,
        reload_config: Callable[[], DaemonConfig] | None = None,
        notifier: Notifier | None = None,
        free_space: Callable[[str], int] = free_bytes,
        install_signal_handlers: bool = True,
    ):
        self.cfg = cfg
        self.reload_config = reload_config
        self.notifier = notifier or Notifier()
        self.free_space = free_space
        self.install_signal_handlers = install_signal_handlers
        self.counts = Counters()
        self.rates = RateMeter()
        self.lidar_clock = LidarClock()
        self.lidar: LidarInput | None = None
        self.imu: ImuInput | None = None
        self.recorder: Recorder | None = None
        self.publisher = None
        self.ready = threading.Event()  # set once sockets are open (tests wait on it)
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._rpipe, self._wpipe = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._sel = selectors.DefaultSelector()  # everything
        self._sel_quiet = selectors.DefaultSelector()  # all but the lidar sockets
        self._running = False
        self.health: dict[str, str] = {}  # problem name -> message (stalls, not recording)
        self._seen: dict[str, tuple[int, float]] = {}  # counter -> (value, when it last moved)
        self._unhealthy_since: float | None = None
        self._watchdog_stopped = False
        self._last_status: messages.Status | None = None
        self._status_text = messages.encode_status(messages.Status(time.time_ns(), "starting"))
        self._last_status_mono = time.monotonic()
        self.zenoh_error = ""
        self._zenoh_retry_mono = 0.0

    # ---- called from any thread -------------------------------------------------------------
    def signal(self, signum: int) -> None:
        """Deliver a signal number to the loop (what the real handlers do)."""
        try:
            os.write(self._wpipe, bytes([signum]))
        except OSError:
            pass

    def control(self, name: str, label: str = "", timeout: float = 10.0) -> dict:
        """Run a control command (start, stop, mark) on the loop and return its result."""
        cmd = _Command(name, label)
        self._commands.put(cmd)
        try:
            os.write(self._wpipe, _CMD_BYTE)
        except OSError:
            return {"ok": False, "error": "daemon not running"}
        if not cmd.done.wait(timeout):
            return {"ok": False, "error": "timed out"}
        waiting = cmd.result.get("_wait")
        if waiting is not None:  # a start: wait (here, not on the loop) for the file to open
            waiting.wait(timeout)
            rec = self.recorder
            return {"ok": rec.active, "recording": rec.active, "file": rec.file,
                    "message": rec.message}
        return cmd.result

    def status_json(self) -> bytes:
        return self._status_text

    # ---- set-up -----------------------------------------------------------------------------
    def _open_lidar(self) -> None:
        self.lidar = LidarInput(self.cfg.lidar, self.counts, self.lidar_clock)
        for s in self.lidar.sockets():
            self._sel.register(s, selectors.EVENT_READ, "lidar")  # not in the quiet selector
        log.info("lidar: data on %s:%d, position on %s (receive buffer %d B)",
                 self.cfg.lidar.bind_address, self.lidar.data_port,
                 self.lidar.position_port, self.lidar.data_rcvbuf)

    def _close_lidar(self) -> None:
        if self.lidar is not None:
            for s in self.lidar.sockets():
                self._sel.unregister(s)
            self.lidar.close()
            self.lidar = None

    def _open_imu(self) -> None:
        self.imu = ImuInput(self.cfg.imu, self.counts) if self.cfg.imu.url else None
        self._imu_check()

    def _close_imu(self) -> None:
        if self.imu is not None:
            if self.imu.connected:
                self._unregister_both(self.imu.fileno())
            self.imu.close()
            self.imu = None

    def _imu_check(self) -> None:
        if self.imu is not None and self.imu.try_open():
            self._register_both(self.imu.fileno(), "imu")
            self._seen.pop("imu_samples", None)  # a stall is timed from the connection

    def _register_both(self, fileobj, data: str) -> None:
        self._sel.register(fileobj, selectors.EVENT_READ, data)
        self._sel_quiet.register(fileobj, selectors.EVENT_READ, data)

    def _unregister_both(self, fileobj) -> None:
        for sel in (self._sel, self._sel_quiet):
            try:
                sel.unregister(fileobj)
            except (KeyError, ValueError):
                pass

    def _open_publisher(self) -> None:
        """Open the Zenoh session. A failure (endpoint in use, bad zenoh config file) leaves
        the daemon recording without the live path; the tick retries every 10 s."""
        self.publisher = None
        self.zenoh_error = ""
        if not self.cfg.zenoh.enabled:
            return
        self._zenoh_retry_mono = time.monotonic() + 10.0
        try:
            from .publisher import LivePublisher  # zenoh loads a Rust runtime: only when used

            self.publisher = LivePublisher(
                self.cfg.zenoh, self.cfg.device_id, self.counts, self.status_json, self.control)
        except Exception as exc:  # noqa: BLE001 - zenoh.ZError and the like
            self.zenoh_error = f"zenoh unavailable: {exc}"
            self.counts.add("zenoh_open_failures")
            log.error("%s (recording goes on; retrying every 10 s)", self.zenoh_error)

    def _close_publisher(self) -> None:
        if self.publisher is not None:
            self.publisher.close()
            self.publisher = None

    def _recorder_metadata(self) -> dict[str, str]:
        return {"config": dump_config(self.cfg), "device_id": self.cfg.device_id}

    def _open_recorder(self) -> None:
        self.recorder = Recorder(self.cfg.recording, self.counts, self._recorder_metadata(),
                                 self.free_space)

    # ---- the loop ---------------------------------------------------------------------------
    def run(self) -> int:
        old_handlers = {}
        old_switch = sys.getswitchinterval()
        sys.setswitchinterval(self.cfg.lidar.switch_interval_ms / 1000.0)
        if self.install_signal_handlers and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
                old_handlers[sig] = signal.signal(sig, lambda s, _f: self.signal(s))
        try:
            try:
                self._register_both(self._rpipe, "pipe")
                self._open_lidar()
                self._open_recorder()
                self._open_publisher()
                self._open_imu()
            except (OSError, ConfigError, ValueError, RuntimeError) as exc:
                log.error("start-up failed: %s", exc)
                self.notifier.stopping(f"start-up failed: {exc}")
                self._shutdown()
                return 1
            except Exception as exc:  # noqa: BLE001 - zenoh.ZError and the like
                log.error("start-up failed: %s: %s", type(exc).__name__, exc)
                self.notifier.stopping(f"start-up failed: {exc}")
                self._shutdown()
                return 1
            if self.cfg.recording.enabled:
                self._start_recording("startup")
            self._publish_status(notify=False)  # the first status goes with READY=1
            self.notifier.ready(self._status_line())
            self.ready.set()
            self._running = True
            RUNNING.append(self)
            try:
                self._loop()
            finally:
                RUNNING.remove(self)
            self.notifier.stopping("stopping: finishing the recording")
            self._final_drain()
            self._shutdown()
            log.info("stopped; %s", self._status_line())
            return 0
        finally:
            sys.setswitchinterval(old_switch)
            for sig, h in old_handlers.items():
                signal.signal(sig, h)

    def _tick_interval(self) -> float:
        iv = self.cfg.status.interval_s
        if self.notifier.watchdog_interval_s:
            iv = min(iv, self.notifier.watchdog_interval_s)
        if self.imu is not None:
            iv = min(iv, self.cfg.imu.reconnect_interval_s)
        return iv

    def _loop(self) -> None:
        monotonic = time.monotonic
        next_tick = monotonic() + self._tick_interval()
        lidar_due = 0.0  # host_monotonic [s] before which the lidar sockets are left to fill
        imu_check = 0.0  # when to look for an IMU frame held at the end of the stream
        while self._running:
            now = monotonic()
            if self.imu is not None and now >= imu_check:
                imu_check = now + 0.05
                held: list = []
                self.imu.flush_if_quiet(held)
                self._submit(held)
            if now >= next_tick:
                try:
                    self._tick()
                except Exception:  # noqa: BLE001 - a status problem must not end the service
                    self.counts.add("internal_errors")
                    log.exception("error in the periodic tick (counted, continuing)")
                next_tick = monotonic() + self._tick_interval()
                continue
            if now < lidar_due:
                sel, until = self._sel_quiet, min(next_tick, lidar_due)
            else:
                sel, until = self._sel, next_tick
            if self.imu is not None:
                until = min(until, imu_check)
            batch: list = []
            drained = False
            behind = False
            for key, _ev in sel.select(until - now):
                what = key.data
                try:
                    if what == "lidar":
                        behind |= self.lidar.drain(key.fileobj, batch) >= self.lidar.cfg.max_batch
                        drained = True
                    elif what == "imu":
                        if not self.imu.on_readable(batch):
                            self._unregister_both(key.fileobj)
                    else:
                        self._submit(batch)
                        batch = []
                        self._on_pipe()
                        # a reload may have replaced sockets: the rest of this event list is
                        # stale (level-triggered, so anything pending is reported again)
                        break
                except Exception:  # noqa: BLE001 - bad input must never end the service
                    self.counts.add("internal_errors")
                    log.exception("error handling %s (counted, continuing)", what)
            if drained:
                wake_s = self.cfg.lidar.wake_interval_ms / 1000.0  # (SIGHUP may change it)
                # a socket still had data after max_batch datagrams: the loop is behind, so no
                # pause (the pause is for the light load it was made for, not for catching up)
                lidar_due = now if behind else now + wake_s
            self._submit(batch)

    def _submit(self, batch: list) -> None:
        if batch:
            self.recorder.submit(batch)
            if self.publisher is not None:
                self.publisher.submit(batch)

    def _on_pipe(self) -> None:
        try:
            data = os.read(self._rpipe, 512)
        except BlockingIOError:
            return
        for b in data:
            if b == _CMD_BYTE[0]:
                self._run_commands()
            elif b in (signal.SIGTERM, signal.SIGINT):
                log.info("signal %s: stopping", signal.Signals(b).name)
                self._running = False
            elif b == signal.SIGHUP:
                self._reload()

    def _run_commands(self) -> None:
        while True:
            try:
                cmd: _Command = self._commands.get_nowait()
            except queue.Empty:
                return
            try:
                cmd.result = self._do_command(cmd.name, cmd.label)
            except Exception as exc:  # noqa: BLE001 - a command must never kill the loop
                cmd.result = {"ok": False, "error": str(exc)}
            cmd.done.set()

    def _do_command(self, name: str, label: str) -> dict:
        rec = self.recorder
        if name == "start":
            if not rec.active:
                # never wait for the writer here (the loop must keep reading the sockets): the
                # caller's thread waits for the file in control()
                cmd_done = rec.start_async(label or "control")
                self._event("start", label or "control")
                return {"_wait": cmd_done}
            return {"ok": True, "recording": True, "file": rec.file, "message": rec.message}
        if name == "stop":
            if rec.active or rec.wanted:  # (wanted: failed and retrying -- stop retrying too)
                self._event("stop", label or "control")
                rec.stop(label or "control")
            return {"ok": True, "recording": False, "file": None}
        if name == "mark":
            ok = self._event("mark", label)
            return {"ok": ok, "recording": rec.active, "file": rec.file, "label": label}
        return {"ok": False, "error": f"unknown command {name!r}"}

    def _event(self, kind: str, label: str) -> bool:
        """Publish an event; marks also go into the recording (start/stop events are written
        by the recorder itself)."""
        ev = messages.Event(time.time_ns(), kind, label)
        item = (topics.TOPIC_EVENTS, ev.host_ns, messages.encode_event(ev))
        if self.publisher is not None:
            self.publisher.submit([item])
        if kind == "mark":
            if not self.recorder.active:
                return False
            self.recorder.submit([item])
        return True

    def _start_recording(self, reason: str) -> bool:
        ok = self.recorder.start(reason)
        self._event("start", reason)
        if not ok:
            log.error("not recording: %s", self.recorder.message)
        return ok

    def _reload(self) -> None:
        if self.reload_config is None:
            log.info("SIGHUP: no config to re-read; starting a new file")
            if self.recorder.active:
                self.recorder.rotate("sighup")
            return
        self.notifier.reloading()
        try:
            new = self.reload_config()
        except ConfigError as exc:
            log.error("SIGHUP: config not reloaded, keeping the old one: %s", exc)
            self.notifier.status(f"config error: {exc}")
            return
        old, self.cfg = self.cfg, new
        logging.getLogger("tripod_daemon").setLevel(new.log_level.upper())
        log.info("SIGHUP: config re-read")
        try:
            if new.lidar != old.lidar:
                self._close_lidar()
                self._open_lidar()
            if new.zenoh != old.zenoh or new.device_id != old.device_id:
                self._close_publisher()
                self._open_publisher()
            if new.imu != old.imu:
                self._close_imu()
                self._open_imu()
        except Exception as exc:  # noqa: BLE001
            log.error("SIGHUP: applying the new config failed: %s", exc)
        record = self.recorder.active or new.recording.enabled
        # the same writer thread finishes the file and starts the next with the new config,
        # in queue order: nothing received before or after the reload is lost
        self.recorder.reconfigure(new.recording, self._recorder_metadata(), record, "sighup")
        if record:
            self._event("start", "sighup")
        self.notifier.ready(self._status_line())

    # ---- status, watchdog, reconnect --------------------------------------------------------
    def _tick(self, force: bool = False) -> None:
        self._imu_check()
        if self.imu is not None:
            batch: list = []
            self.imu.poll(batch)
            self._submit(batch)
        now_mono = time.monotonic()
        if self.zenoh_error and now_mono >= self._zenoh_retry_mono:
            self._open_publisher()
        problems_before = set(self.health)
        self._check_health(now_mono)
        # a problem raised or cleared shows at once (not a stall's growing seconds: the interval)
        force = force or set(self.health) != problems_before
        if force or now_mono - self._last_status_mono >= self.cfg.status.interval_s * 0.95:
            self._last_status_mono = now_mono
            self._publish_status()
        if not self._watchdog_stopped:
            self.notifier.watchdog()

    def _stalled(self, counter: str, now: float, limit_s: float) -> float | None:
        """Seconds ``counter`` has not moved when that is over ``limit_s``, else None."""
        value = self.counts.get(counter, 0)
        last = self._seen.get(counter)
        if last is None or value != last[0]:
            self._seen[counter] = (value, now)
            return None
        idle = now - last[1]
        return idle if limit_s and idle >= limit_s else None

    def _flag(self, name: str, message: str | None) -> None:
        """Raise or clear a health problem: logged, an event, and in status and STATUS=."""
        old = self.health.get(name)
        if message is None:
            if old is not None:
                del self.health[name]
                log.warning("%s: resolved", name)
                self._event("health", f"{name} resolved")
            return
        if old is None:
            log.warning("%s", message)
            self._event("health", message)
            self.counts.add(f"health_{name}")
        self.health[name] = message

    def _check_health(self, now: float) -> None:
        h = self.cfg.health
        idle = self._stalled("lidar_data", now, h.lidar_stall_s)
        self._flag("lidar_stalled", None if idle is None else f"lidar stalled: no data for "
                   f"{idle:.0f} s")
        imu = self.imu
        if imu is not None and imu.connected:
            idle = self._stalled("imu_samples", now, h.imu_stall_s)
            self._flag("imu_stalled", None if idle is None else f"IMU stalled: connected but no "
                       f"samples for {idle:.0f} s")
        else:
            self._seen.pop("imu_samples", None)
            self._flag("imu_stalled", None)
        rec = self.recorder
        self._flag("record_overload", rec.overload or None)
        if rec.wanted and not rec.active:
            if self._unhealthy_since is None:
                self._unhealthy_since = now
            down = now - self._unhealthy_since
            if (h.unhealthy_restart_s and down >= h.unhealthy_restart_s
                    and self.notifier.watchdog_interval_s and not self._watchdog_stopped):
                self._watchdog_stopped = True
                log.error("not recording for %.0f s although asked to (%s): no more WATCHDOG=1, "
                          "so systemd restarts the service", down, rec.message)
                self.notifier.status(f"unhealthy: not recording for {down:.0f} s; waiting for "
                                     "the watchdog restart")
        else:
            self._unhealthy_since = None
            if self._watchdog_stopped:
                log.warning("recording again: watchdog resumed")
            self._watchdog_stopped = False

    def _publish_status(self, notify: bool = True) -> None:
        rec = self.recorder
        counts = dict(self.counts)
        counts["record_queue"] = rec.pending
        rates = self.rates.update({k: v for k, v in counts.items()
                                   if k in ("lidar_data", "lidar_position", "imu_samples",
                                            "lidar_bytes", "record_written", "zenoh_published")})
        clocks = {"lidar": self.lidar_clock.summary()}
        if self.imu is not None:
            clocks["imu"] = self.imu.clock_summary()
            counts["imu_connected"] = int(self.imu.connected)
        counts["record_queue_bytes"] = rec.pending_bytes
        msg = "; ".join(m for m in (
            rec.message, self.imu.last_error if self.imu is not None else "", self.zenoh_error,
            *self.health.values(),
        ) if m)
        st = messages.Status(
            time.time_ns(), state=rec.state, recording=rec.active, file=rec.file, counts=counts,
            rates=rates, message=msg, clocks=clocks, disk=self._disk_status())
        self._last_status = st
        data = messages.encode_status(st)
        self._status_text = data
        item = [(topics.TOPIC_STATUS, st.host_ns, data)]
        if self.cfg.status.record:
            rec.submit(item)
        if self.publisher is not None:
            self.publisher.submit(item)
        if notify:
            self.notifier.status(self._status_line())

    def _disk_status(self) -> dict:
        """Free space of the recording directory and the current file's size and start, for
        the operator's panel (free space: a statvfs once a status period)."""
        rec = self.recorder
        d: dict = {"min_free_bytes": self.cfg.recording.min_free_bytes}
        try:
            d["free_bytes"] = self.free_space(self.cfg.recording.directory)
        except OSError:
            pass
        if rec.file:
            d["file_bytes"] = self.counts.get("record_bytes", 0)
            d["file_started_ns"] = rec.file_started_ns
        return d

    def _status_line(self) -> str:
        rec = self.recorder
        state = rec.state if rec else "starting"
        if rec and rec.message:
            state += f" ({rec.message})"
        if self.health:
            state += "; " + "; ".join(self.health.values())
        return status_line(state, self.rates.rates, self.counts, rec.file if rec else None)

    # ---- shutdown ---------------------------------------------------------------------------
    def _final_drain(self) -> None:
        """Take what the kernel already holds for us before closing the sockets."""
        if self.imu is not None:
            batch: list = []
            self.imu.flush(batch)
            self.recorder.submit(batch)
        if self.lidar is None:
            return
        for sock in self.lidar.sockets():
            for _ in range(10_000):
                batch: list = []
                if self.lidar.drain(sock, batch) == 0:
                    break
                self.recorder.submit(batch)

    def _shutdown(self) -> None:
        if self.recorder is not None:
            self.recorder.close("shutdown")
        self._close_publisher()
        self._close_imu()
        self._close_lidar()
        self._sel.close()
        self._sel_quiet.close()
        for fd in (self._rpipe, self._wpipe):
            try:
                os.close(fd)
            except OSError:
                pass
