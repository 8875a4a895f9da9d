# SPDX-License-Identifier: BSD-3-Clause
"""IMU input through pyserial: a serial device, a pseudo-terminal or brickd's TCP port.

Drivers frame the byte stream and resynchronise on garbage (the parsers live in
``tripod_shared``): ``tfp`` for the Tinkerforge IMU Brick 2.0 (asks for the quaternion callback
period, parses CALLBACK_QUATERNION fid 39) and ``witmotion`` for 0x55-framed IMUs (quaternion
0x59, time 0x50). Each sample is stamped right after the read that completed it
(host_realtime), as Klipper does ("time post read()"). When the device disappears (unplugged,
brickd restarted) the port is closed and reopened every ``reconnect_interval_s`` by the loop's
tick, without restarting the service.
"""

from __future__ import annotations

import calendar
import logging
import struct
import time

import serial

from tripod_shared import messages, tfp, topics, witmotion
from tripod_shared.timebase import NO_DEVICE_TIME, NS_PER_MS, NS_PER_S

from .clock import ClockMapper, RateClock
from .config import ImuConfig
from .stats import Counters

log = logging.getLogger(__name__)

Item = tuple[str, int, bytes]


class TfpDriver:
    """Tinkerforge IMU Brick 2.0 over TFP (serial/USB through brickd, or brickd's TCP port).

    Samples are taken only from the brick identified by UID: the configured ``tfp_uid``, or,
    when that is empty, the IMU Brick 2.0 that answers our enumerate request. Until one is
    known, quaternion frames are counted (``imu_unverified``) and dropped, and enumerate is
    asked again every ``reconnect_interval_s``; with a UID the parser also refuses frames run
    into each other (see ``TfpStreamParser``), so a cut-off frame never becomes a sample.
    """

    name = "tfp"

    def __init__(self, cfg: ImuConfig, counts: Counters):
        self.cfg = cfg
        self.counts = counts
        counts.setdefault("imu_unverified", 0)
        self.configured_uid = tfp.base58_decode(cfg.tfp_uid) if cfg.tfp_uid else None
        self.uid = self.configured_uid
        self.parser = tfp.TfpStreamParser(self.uid)
        self.clock = RateClock()
        self._prev_host_ns = 0
        self._samples_since_connect = 0

    def reset(self) -> None:
        # keep a learned UID over a reconnect (the same brick plugged back in streams at once);
        # a different brick is taken if it answers enumerate before any sample of the old one
        self.parser = tfp.TfpStreamParser(self.uid)
        self._samples_since_connect = 0

    def on_connect(self, port) -> None:
        """Ask who is there, and (when the UID is known) for the quaternion callback period."""
        port.write(tfp.encode_enumerate())
        if self.uid is not None:
            port.write(tfp.encode_set_quaternion_period(self.uid, self.cfg.quaternion_period_ms))

    def poll(self, port, out: list[Item]) -> None:
        """Called from the loop's tick while connected: enumerate until identified, and decide
        a frame held at the end of the stream once the line has been quiet (>= 50 ms)."""
        if self.uid is None:
            port.write(tfp.encode_enumerate())
        if time.time_ns() - self._prev_host_ns >= 50 * NS_PER_MS:
            self._take(self.parser.flush_held(), self._prev_host_ns, self._prev_host_ns, port,
                       out)

    def feed(self, data: bytes, host_ns: int, port, out: list[Item]) -> None:
        before = self.parser.garbage_bytes
        prev_ns, self._prev_host_ns = self._prev_host_ns, host_ns
        self._take(self.parser.feed(data), host_ns, prev_ns, port, out)
        self.counts.add("imu_garbage_bytes", self.parser.garbage_bytes - before)

    def _take(self, packets, host_ns: int, prev_ns: int, port, out: list[Item]) -> None:
        for pkt in packets:
            if pkt.function_id == tfp.FID_CALLBACK_QUATERNION:
                if self.uid is None or pkt.uid != self.uid:
                    self.counts.add("imu_unverified")
                    continue
                try:
                    w, x, y, z = tfp.decode_quaternion(pkt.payload)
                except ValueError:
                    self.counts.add("imu_bad")
                    continue
                ns = prev_ns if pkt.held and prev_ns else host_ns  # the read that completed it
                s = messages.ImuSample(ns, w, x, y, z, NO_DEVICE_TIME, "tfp", pkt.sequence,
                                       pkt.raw)
                out.append((topics.TOPIC_IMU, ns, messages.encode_imu(s)))
                self.counts.add("imu_samples")
                self._samples_since_connect += 1
                self.clock.add(ns)
            elif pkt.function_id == tfp.FID_CALLBACK_ENUMERATE:
                self.counts.add("imu_other_frames")
                try:
                    uid, dev = tfp.decode_enumerate_callback(pkt.payload)
                except (ValueError, struct.error, UnicodeDecodeError):
                    self.counts.add("imu_bad")
                    continue
                if uid != pkt.uid:
                    self.counts.add("imu_bad")  # header and payload disagree: not a real answer
                    continue
                if (dev == tfp.DEVICE_IDENTIFIER_IMU_V2 and uid != self.uid
                        and self.configured_uid is None and not self._samples_since_connect):
                    self.uid = uid
                    self.parser.uid = uid  # from now on, frames of this brick only
                if dev == tfp.DEVICE_IDENTIFIER_IMU_V2 and uid == self.uid:
                    log.info("IMU Brick 2.0 %s found; quaternion period %d ms",
                             tfp.base58_encode(uid), self.cfg.quaternion_period_ms)
                    try:
                        port.write(tfp.encode_set_quaternion_period(
                            uid, self.cfg.quaternion_period_ms))
                    except (OSError, serial.SerialException):
                        pass  # the read path notices a dead port
            else:
                self.counts.add("imu_other_frames")


class WitMotionDriver:
    """0x55-framed serial IMU: quaternion frames (0x59); time frames (0x50) give device time."""

    name = "witmotion"

    def __init__(self, cfg: ImuConfig, counts: Counters):
        self.cfg = cfg
        self.counts = counts
        self.parser = witmotion.WitStreamParser()
        self.clock = ClockMapper()
        self._device_ns = NO_DEVICE_TIME  # from the last time frame, until the next quaternion

    def reset(self) -> None:
        self.parser = witmotion.WitStreamParser()
        self._device_ns = NO_DEVICE_TIME

    def on_connect(self, port) -> None:
        pass  # streams on its own

    def poll(self, port, out: list[Item]) -> None:
        pass

    @staticmethod
    def _time_frame_ns(data8: bytes) -> int:
        yy, mo, dd, hh, mi, ss, ms = struct.unpack("<6BH", data8)
        return (calendar.timegm((2000 + yy, mo, dd, hh, mi, ss)) * NS_PER_S) + ms * NS_PER_MS

    def feed(self, data: bytes, host_ns: int, port, out: list[Item]) -> None:
        before = self.parser.garbage_bytes
        for fr in self.parser.feed(data):
            if fr.ftype == witmotion.TYPE_QUATERNION:
                try:
                    w, x, y, z = witmotion.decode_quaternion(fr.data)
                except ValueError:
                    self.counts.add("imu_bad")
                    continue
                s = messages.ImuSample(host_ns, w, x, y, z, self._device_ns, "witmotion", 0,
                                       fr.raw)
                self._device_ns = NO_DEVICE_TIME
                out.append((topics.TOPIC_IMU, host_ns, messages.encode_imu(s)))
                self.counts.add("imu_samples")
            elif fr.ftype == witmotion.TYPE_TIME:
                try:
                    self._device_ns = self._time_frame_ns(fr.data)
                    self.clock.add(self._device_ns, host_ns)
                except (ValueError, OverflowError, struct.error):
                    self.counts.add("imu_bad")
                self.counts.add("imu_other_frames")
            else:
                self.counts.add("imu_other_frames")
        self.counts.add("imu_garbage_bytes", self.parser.garbage_bytes - before)


DRIVERS = {"tfp": TfpDriver, "witmotion": WitMotionDriver}


class ImuInput:
    """One IMU port: open/reopen, read with a post-read stamp, frame, encode.

    Counters: ``imu_samples``, ``imu_garbage_bytes``, ``imu_other_frames``, ``imu_bad``,
    ``imu_connects``, ``imu_disconnects``, ``imu_bytes``, ``imu_unverified`` (TFP quaternions
    before the brick was identified, or of another brick).
    """

    def __init__(self, cfg: ImuConfig, counts: Counters):
        self.cfg = cfg
        self.counts = counts
        for k in ("imu_samples", "imu_garbage_bytes", "imu_other_frames", "imu_bad",
                  "imu_connects", "imu_disconnects", "imu_bytes"):
            counts.setdefault(k, 0)
        self.driver = DRIVERS[cfg.driver](cfg, counts)
        self.port = None
        self._next_try = 0.0  # host_monotonic [s]
        self.last_error = ""

    @property
    def connected(self) -> bool:
        return self.port is not None

    def try_open(self) -> bool:
        """Open the port if it is time to try; True when newly connected."""
        if self.port is not None or not self.cfg.url:
            return False
        now = time.monotonic()
        if now < self._next_try:
            return False
        self._next_try = now + self.cfg.reconnect_interval_s
        try:
            # reads never wait (the loop calls us when readable); the few-byte TFP requests
            # wait at most 0.1 s for room, so a stuck device cannot hold up the loop
            port = serial.serial_for_url(self.cfg.url, baudrate=self.cfg.baudrate, timeout=0,
                                         write_timeout=0.1)
            port.fileno()  # every URL we support has one; refuse handlers that do not
        except (OSError, serial.SerialException, ValueError, AttributeError) as exc:
            msg = f"IMU {self.cfg.url}: {exc}"
            if msg != self.last_error:
                log.warning("%s (retrying every %.1f s)", msg, self.cfg.reconnect_interval_s)
                self.last_error = msg
            return False
        self.port = port
        self.last_error = ""
        self.driver.reset()
        self.counts.add("imu_connects")
        log.info("IMU connected: %s (%s)", self.cfg.url, self.driver.name)
        try:
            self.driver.on_connect(port)
        except (OSError, serial.SerialException) as exc:
            log.warning("IMU %s: setup write failed: %s", self.cfg.url, exc)
        return True

    def fileno(self) -> int:
        return self.port.fileno()

    def poll(self, out: list[Item]) -> None:
        """Periodic work while connected (the TFP driver re-asks who is there and decides a
        frame held at the end of the stream)."""
        if self.port is None:
            return
        try:
            self.driver.poll(self.port, out)
        except (OSError, serial.SerialException) as exc:
            log.debug("IMU poll write failed: %s", exc)

    def on_readable(self, out: list[Item]) -> bool:
        """Read what is waiting; False when the device is gone (the caller unregisters it)."""
        try:
            data = self.port.read(self.cfg.read_size)
            host_ns = time.time_ns()  # post-read stamp (host_realtime)
            if not data:
                raise serial.SerialException("no data although readable (device disconnected?)")
        except (OSError, serial.SerialException, TypeError) as exc:
            self._lost(str(exc))
            return False
        self.counts.add("imu_bytes", len(data))
        self.driver.feed(data, host_ns, self.port, out)
        return True

    def _lost(self, why: str) -> None:
        log.warning("IMU %s lost: %s; reconnecting", self.cfg.url, why)
        self.counts.add("imu_disconnects")
        self.close()
        self._next_try = time.monotonic() + min(0.2, self.cfg.reconnect_interval_s)

    def close(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except (OSError, serial.SerialException):
                pass
            self.port = None

    def clock_summary(self) -> dict:
        return self.driver.clock.summary()
