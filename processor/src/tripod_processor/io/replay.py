# SPDX-License-Identifier: BSD-3-Clause
"""Hardware-in-the-loop replayer: send a capture back out as the devices would.

Sources (all on the host_realtime clock, merged in time order):

- a simulated capture directory (``capture.pcap`` + ``imu.tripimu``),
- any pcap/pcapng (data packets by UDP port 2368, position packets by 8308), with the IMU log
  ``imu.tripimu`` beside it or given with ``imu_log``,
- one of our MCAP recordings (``/velodyne/packets``, ``/velodyne/position``, and the raw IMU
  bytes of ``/imu/quaternion``).

Sinks: UDP datagrams to the lidar and position addresses; the IMU bytes to a pseudo-terminal
(the daemon opens its slave as a serial port), to a TCP port that behaves like brickd (answers
enumerate and quaternion-period requests, streams the callbacks to every connected client), or
to a real serial device through pyserial.

Timing: event ``i`` is sent at ``start + (t_i - t_0) / rate`` on CLOCK_MONOTONIC (sleep, then
spin for the last ``spin_us``); ``rate=inf`` sends as fast as possible. The jitter reported is
the lateness of each send's completion (after ``sendto`` / the IMU write returned) against its
target.
"""

from __future__ import annotations

import abc

import errno
import gc
import os
import selectors
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tripod_shared import tfp
from tripod_shared import velodyne as v

from .events import IMU, LIDAR, POSITION, Event, McapEvents, imu_log_events, merge, pcap_events
from .imu_log import ImuLogReader
from .pcap import PcapReader

KIND_NAMES = ("lidar", "position", "imu")


class ReplayInputError(ValueError):
    """The input cannot be replayed (one-line message)."""


# ----------------------------------------------------------------------------- sources


@dataclass
class ReplaySource:
    """What will be replayed: the lidar/position pcap and/or MCAP, and an IMU log."""

    pcap: Path | None = None
    mcap: Path | None = None
    imu_log: Path | None = None
    lidar_port: int = v.DATA_PORT
    position_port: int = v.POSITION_PORT

    @classmethod
    def open(cls, path: str | os.PathLike,
             imu_log: str | os.PathLike | None = None) -> "ReplaySource":
        """Recognise a capture directory, a pcap/pcapng or an MCAP recording."""
        from .pcap import sniff_format

        p = Path(path)
        if not p.exists():
            raise ReplayInputError(f"no such file or directory: {p}")
        src = cls()
        if p.is_dir():
            if not (p / "capture.pcap").is_file():
                raise ReplayInputError(f"{p}: no capture.pcap in this directory")
            src.pcap = p / "capture.pcap"
            if (p / "imu.tripimu").is_file():
                src.imu_log = p / "imu.tripimu"
        else:
            with open(p, "rb") as fh:
                head = fh.read(8)
            if head == b"\x89MCAP0\r\n":
                src.mcap = p
            elif sniff_format(p):
                src.pcap = p
                if (p.parent / "imu.tripimu").is_file():
                    src.imu_log = p.parent / "imu.tripimu"
            else:
                raise ReplayInputError(f"{p}: neither a pcap/pcapng, an MCAP recording nor a "
                                       "capture directory")
        if imu_log is not None:
            if not Path(imu_log).is_file():
                raise ReplayInputError(f"no such IMU log: {imu_log}")
            ImuLogReader(imu_log)  # header check: one-line error now, not mid-replay
            src.imu_log = Path(imu_log)
        return src

    def events(self) -> Iterator[Event]:
        """(host_ns, kind, bytes) of every event, in time order (streams merged lazily)."""
        streams = []
        if self.pcap is not None:
            streams.append(pcap_events(PcapReader(self.pcap), self.lidar_port, self.position_port))
        if self.mcap is not None:
            streams.append(McapEvents(self.mcap, (LIDAR, POSITION, IMU)))
        if self.imu_log is not None:
            streams.append(imu_log_events(self.imu_log))
        return merge(*streams)


# ----------------------------------------------------------------------------- IMU sinks


class ImuSink(abc.ABC):
    """Where IMU bytes go. ``write`` never blocks for long; undeliverable bytes are counted."""

    description = ""

    def __init__(self) -> None:
        self.bytes_sent = 0
        self.bytes_dropped = 0

    @abc.abstractmethod
    def write(self, data: bytes) -> None:
        """Send ``data`` (or count it in ``bytes_dropped``)."""

    def close(self) -> None:
        pass


class PtyImuSink(ImuSink):
    """A pseudo-terminal in raw mode; ``path`` is the slave to open as a serial port.

    While nobody reads the slave, the kernel buffer fills and further bytes are dropped and
    counted, as a real serial line would lose them.
    """

    def __init__(self) -> None:
        import tty

        super().__init__()
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.description = f"pty {self.path}"

    def write(self, data: bytes) -> None:
        try:
            n = os.write(self.master, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EAGAIN):
                raise
            n = 0
        self.bytes_sent += n
        self.bytes_dropped += len(data) - n

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class SerialImuSink(ImuSink):
    """A real serial device (or any pyserial URL)."""

    def __init__(self, device: str, baudrate: int = 115200) -> None:
        super().__init__()
        try:
            import serial
        except ImportError:  # pragma: no cover - pyserial ships with the daemon
            raise ReplayInputError("serial output needs pyserial (pip install pyserial)") from None
        try:
            self.port = serial.serial_for_url(device, baudrate=baudrate, write_timeout=0.05)
        except (serial.SerialException, ValueError) as exc:
            raise ReplayInputError(f"cannot open serial device {device}: {exc}") from None
        self.description = f"serial {device} @ {baudrate}"

    def write(self, data: bytes) -> None:
        import serial

        try:
            n = self.port.write(data) or 0
        except serial.SerialTimeoutException:
            n = 0
        self.bytes_sent += n
        self.bytes_dropped += len(data) - n

    def close(self) -> None:
        self.port.close()


class BrickdImuSink(ImuSink):
    """A TCP server that talks like brickd to the Tinkerforge API on 127.0.0.1:``port``.

    Answers ``enumerate`` (fid 254) with an IMU Brick 2.0 CALLBACK_ENUMERATE, acknowledges
    ``set_quaternion_period`` (fid 28) and answers ``get_quaternion_period`` (fid 29); every
    replayed IMU chunk goes to every connected client. With no client connected the bytes are
    dropped (and counted), as brickd does with callbacks nobody listens to.
    """

    def __init__(self, port: int = tfp.BRICKD_PORT, host: str = "127.0.0.1",
                 uid: int | None = None, period_ms: int = 10) -> None:
        super().__init__()
        self.server = socket.create_server((host, port))
        self.server.setblocking(False)
        self.port = self.server.getsockname()[1]
        self.description = f"brickd tcp:{host}:{self.port}"
        self.uid = uid
        self.period_ms = period_ms
        self.clients: list[socket.socket] = []
        self._bufs: dict[socket.socket, bytearray] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._sel = selectors.DefaultSelector()
        self._sel.register(self.server, selectors.EVENT_READ)
        self.requests = 0
        self._thread = threading.Thread(target=self._serve, name="brickd", daemon=True)
        self._thread.start()

    def wait_for_client(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if self.clients:
                    return True
            time.sleep(0.005)
        return False

    def _reply(self, c: socket.socket, data: bytes) -> None:
        try:
            c.sendall(data)
        except OSError:
            self._drop(c)

    def _drop(self, c: socket.socket) -> None:
        with self._lock:
            if c in self.clients:
                self.clients.remove(c)
        self._bufs.pop(c, None)
        try:
            self._sel.unregister(c)
        except (KeyError, ValueError):
            pass
        c.close()

    def _handle(self, c: socket.socket, data: bytes) -> None:
        # requests from the API bindings: whole TFP packets, walked header by header
        raw = self._bufs.setdefault(c, bytearray())
        raw += data
        while len(raw) >= tfp.HEADER_SIZE:
            uid, length, fid, opts, _flags = tfp.HEADER.unpack_from(raw, 0)
            if length < tfp.HEADER_SIZE or length > tfp.MAX_PACKET_SIZE:
                del raw[:1]
                continue
            if len(raw) < length:
                break
            payload = bytes(raw[tfp.HEADER_SIZE:length])
            del raw[:length]
            self.requests += 1
            seq = opts >> 4
            want = bool(opts & 0x08)
            my_uid = self.uid if self.uid is not None else 0
            if fid == tfp.FID_ENUMERATE:
                self._reply(c, tfp.encode_enumerate_callback(my_uid))
            elif fid == tfp.FID_SET_QUATERNION_PERIOD:
                if len(payload) >= 4:
                    self.period_ms = int.from_bytes(payload[:4], "little")
                if want:
                    self._reply(c, tfp.encode_packet(uid, fid, b"", seq, True))
            elif fid == tfp.FID_GET_QUATERNION_PERIOD:
                self._reply(c, tfp.encode_packet(uid, fid, self.period_ms.to_bytes(4, "little"),
                                                 seq, True))
            elif want:  # anything else: "function not supported", as a device answers
                self._reply(c, tfp.encode_packet(uid, fid, b"", seq, True, error_code=2))

    def _serve(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._sel.select(timeout=0.05):
                s = key.fileobj
                if s is self.server:
                    try:
                        c, _addr = self.server.accept()
                    except OSError:
                        continue
                    c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    c.setblocking(False)
                    self._sel.register(c, selectors.EVENT_READ)
                    with self._lock:
                        self.clients.append(c)
                else:
                    try:
                        data = s.recv(4096)
                    except (BlockingIOError, InterruptedError):
                        continue
                    except OSError:
                        data = b""
                    if not data:
                        self._drop(s)
                    else:
                        self._handle(s, data)

    def write(self, data: bytes) -> None:
        with self._lock:
            clients = list(self.clients)
        if not clients:
            self.bytes_dropped += len(data)
            return
        for c in clients:
            try:
                n = c.send(data)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError:
                n = 0
            self.bytes_sent += n
            self.bytes_dropped += len(data) - n

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        with self._lock:
            clients, self.clients = self.clients, []
        for c in clients:
            c.close()
        self.server.close()
        self._sel.close()


def open_imu_sink(spec: str, uid: int | None = None) -> ImuSink | None:
    """``pty``, ``tcp[:PORT]`` (brickd's 4223 by default, 0 = any free port),
    ``serial:DEV[@BAUD]`` or ``none``."""
    if spec in ("none", ""):
        return None
    if spec == "pty":
        return PtyImuSink()
    if spec == "tcp":
        spec = f"tcp:{tfp.BRICKD_PORT}"
    if spec.startswith("tcp:"):
        try:
            port = int(spec[4:])
        except ValueError:
            raise ReplayInputError(f"bad IMU output {spec!r}: tcp:PORT expected") from None
        try:
            return BrickdImuSink(port, uid=uid)
        except OSError as exc:
            raise ReplayInputError(f"cannot listen on {spec}: {exc.strerror}") from None
    if spec.startswith("serial:"):
        dev, _, baud = spec[7:].partition("@")
        return SerialImuSink(dev, int(baud) if baud else 115200)
    raise ReplayInputError(f"bad IMU output {spec!r}: pty, tcp:PORT, serial:DEV or none")


def parse_addr(spec: str, default_port: int) -> tuple[str, int]:
    host, _, port = spec.rpartition(":")
    if not host:
        host, port = spec, str(default_port)
    try:
        return host, int(port)
    except ValueError:
        raise ReplayInputError(f"bad address {spec!r}: HOST:PORT expected") from None


# ----------------------------------------------------------------------------- replay


def _set_timer_slack(ns: int) -> int | None:
    """prctl(PR_SET_TIMERSLACK): returns the previous slack, None where unsupported."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        old = libc.prctl(30, 0, 0, 0, 0)  # PR_GET_TIMERSLACK
        if libc.prctl(29, ctypes.c_ulong(ns), 0, 0, 0) != 0:  # PR_SET_TIMERSLACK
            return None
        return int(old)
    except (OSError, AttributeError):
        return None


def _enter_realtime(priority: int):
    """Put the calling thread under SCHED_FIFO; returns a function restoring the old policy,
    or None when not permitted."""
    if not hasattr(os, "sched_setscheduler"):
        return None
    try:
        old_policy = os.sched_getscheduler(0)
        old_param = os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, PermissionError):
        return None
    old_slack = _set_timer_slack(1)

    def restore() -> None:
        try:
            os.sched_setscheduler(0, old_policy, old_param)
        except OSError:
            pass
        if old_slack is not None:
            _set_timer_slack(old_slack)

    return restore


@dataclass
class ReplayStats:
    sent: dict = field(default_factory=lambda: {k: 0 for k in KIND_NAMES})
    send_errors: int = 0
    capture_span_s: float = 0.0
    wall_s: float = 0.0
    lateness_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    imu_bytes_sent: int = 0
    imu_bytes_dropped: int = 0
    stopped_early: bool = False
    scheduling: str = "normal"

    @property
    def achieved_rate(self) -> float:
        """Capture time replayed per wall-clock time (1.0 = real time)."""
        return self.capture_span_s / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def packets_per_s(self) -> float:
        return self.sent["lidar"] / self.wall_s if self.wall_s > 0 else float("nan")

    def jitter_us(self, q: float) -> float:
        if len(self.lateness_ns) == 0:
            return float("nan")
        return float(np.percentile(np.abs(self.lateness_ns), q)) / 1e3


class Replayer:
    """Send the events of a :class:`ReplaySource` with their original timing / ``rate``.

    Parameters
    ----------
    source : ReplaySource
    rate : float
        1.0 real time, 10.0 ten times faster, ``float('inf')`` as fast as possible.
    lidar_addr, position_addr : (host, port) UDP destinations
    imu_sink : ImuSink or None
    limit_s : replay only the first ``limit_s`` seconds of capture time (None: all)
    spin_us : busy-wait this long before each send instead of sleeping (timing accuracy);
        default 100 us under SCHED_FIFO (wake-ups are prompt), 300 us otherwise
    loops : play the capture this many times back to back (0: until ``stop_event``), each
        pass shifted by the capture's span plus one millisecond (soak tests)
    realtime_priority : if > 0, run the sending thread under SCHED_FIFO at this priority (needs
        CAP_SYS_NICE; falls back to normal scheduling and says so in the stats) and with a 1 ns
        timer slack: a loaded machine then cannot delay a send by a scheduler time slice.
    """

    def __init__(self, source: ReplaySource, rate: float = 1.0,
                 lidar_addr: tuple[str, int] = ("127.0.0.1", v.DATA_PORT),
                 position_addr: tuple[str, int] = ("127.0.0.1", v.POSITION_PORT),
                 imu_sink: ImuSink | None = None, limit_s: float | None = None,
                 spin_us: float | None = None, realtime_priority: int = 0, loops: int = 1):
        if not rate > 0:
            raise ReplayInputError("rate must be > 0")
        self.source = source
        self.rate = rate
        self.lidar_addr = lidar_addr
        self.position_addr = position_addr
        self.imu_sink = imu_sink
        self.limit_ns = None if limit_s is None else int(limit_s * 1e9)
        self.spin_us = spin_us
        self.stop_event = threading.Event()
        self.realtime_priority = realtime_priority
        if loops < 0:
            raise ReplayInputError("loops must be >= 0 (0: until stopped)")
        self.loops = loops

    def _looped_events(self) -> Iterator[tuple[int, int, bytes]]:
        first = last = None
        i = 0
        while self.loops == 0 or i < self.loops:
            shift = 0 if i == 0 else i * (last - first + 1_000_000)
            n = 0
            for t_ns, kind, data in self.source.events():
                if i == 0:
                    first = t_ns if first is None else first
                    last = t_ns
                n += 1
                yield t_ns + shift, kind, data
            if n == 0:
                return
            i += 1

    def run(self, progress=None) -> ReplayStats:
        """Replay until the end (or ``stop_event``); returns the statistics."""
        stats = ReplayStats()
        # SCHED_FIFO only helps timed sends; flat out it would just starve the machine
        want_rt = self.realtime_priority > 0 and np.isfinite(self.rate)
        restore = _enter_realtime(self.realtime_priority) if want_rt else None
        if restore is not None:
            stats.scheduling = f"SCHED_FIFO {self.realtime_priority}"
        elif want_rt:
            stats.scheduling = "normal (SCHED_FIFO not permitted)"
        spin_us = self.spin_us if self.spin_us is not None else (100.0 if restore else 300.0)
        spin_ns = int(spin_us * 1e3)
        fam = socket.AF_INET6 if ":" in self.lidar_addr[0] else socket.AF_INET
        sock = socket.socket(fam, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        if self.lidar_addr[0].endswith(".255"):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        realtime = np.isfinite(self.rate)
        late = np.empty(1 << 16, dtype=np.int64)
        n_late = 0
        inv_rate = 1.0 / self.rate if realtime else 0.0
        sent = [0, 0, 0]
        t_first = None
        t_last = None
        wall0 = time.monotonic_ns()
        gc_was_enabled = gc.isenabled()
        gc.disable()  # a collection in the middle would be a multi-ms send delay
        sleep, mono, sendto = time.sleep, time.monotonic_ns, sock.sendto
        dest = (self.lidar_addr, self.position_addr)
        imu = self.imu_sink
        try:
            for t_ns, kind, data in self._looped_events():
                if self.stop_event.is_set():
                    stats.stopped_early = True
                    break
                if t_first is None:
                    t_first = t_ns
                    wall0 = mono()
                rel = t_ns - t_first
                if self.limit_ns is not None and rel > self.limit_ns:
                    break
                if realtime:
                    target = wall0 + int(rel * inv_rate)
                    now = mono()
                    if target - now > spin_ns:
                        sleep((target - now - spin_ns) * 1e-9)
                    while mono() < target:
                        pass
                if kind == IMU:
                    if imu is not None:
                        imu.write(data)
                        sent[IMU] += 1
                else:
                    try:
                        sendto(data, dest[kind])
                        sent[kind] += 1
                    except OSError:
                        stats.send_errors += 1
                if realtime:  # lateness of the send's completion against its target
                    if n_late == len(late):
                        late = np.concatenate([late, np.empty_like(late)])
                    late[n_late] = mono() - target
                    n_late += 1
                t_last = t_ns
                if progress is not None and (sent[LIDAR] & 0x3FF) == 0 and kind == LIDAR:
                    progress(rel)
        except KeyboardInterrupt:
            stats.stopped_early = True
        finally:
            stats.wall_s = (mono() - wall0) * 1e-9
            sock.close()
            if restore is not None:
                restore()
            if gc_was_enabled:
                gc.enable()
        stats.sent = dict(zip(KIND_NAMES, sent))
        stats.capture_span_s = (t_last - t_first) * 1e-9 if t_first is not None else 0.0
        stats.lateness_ns = late[:n_late].copy()
        if imu is not None:
            stats.imu_bytes_sent = imu.bytes_sent
            stats.imu_bytes_dropped = imu.bytes_dropped
        return stats
