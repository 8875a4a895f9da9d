# SPDX-License-Identifier: BSD-3-Clause
"""The daemon's live Zenoh stream, cut into rotations, behind a bounded queue.

A :class:`LiveStream` is a plain Zenoh subscriber on the daemon's lidar blocks, IMU, status and
events keys (``tripod_shared.topics``; not ``tripod/<device>/**``, which would also match the
per-packet lidar key and make the daemon publish every packet a second time, one sample each):
it never talks back to the daemon, so it cannot slow it (the daemon publishes with congestion
control "drop": a slow link loses its own samples only, counted here in ``missing`` from the
blocks' packet numbers). On Zenoh's callback thread it only decodes blocks, appends packets
and cuts rotations where the azimuth of a packet's first block wraps; each finished rotation
goes into a queue of ``queue_rotations`` entries. When the consumer is behind, the oldest
waiting rotation is dropped (counted in ``rotations_dropped``, with a log line at most once a
second) so what is shown stays current.
IMU quaternions are kept in a short ring; status and events (JSON) are kept / queued as they are.
"""

from __future__ import annotations

import collections
import json
import logging
import queue
import threading
import time
from dataclasses import dataclass

import numpy as np

from tripod_shared import messages, topics
from tripod_shared import velodyne as vl
from tripod_shared.lidar_block import LidarBlockDecoder

log = logging.getLogger(__name__)

PACKET_SIZE = vl.DATA_PACKET_SIZE


@dataclass
class Rotation:
    """Data packets of one sensor rotation, as received.

    Attributes
    ----------
    packets : np.ndarray, shape (N, 1206), uint8
    host_ns : np.ndarray, shape (N,), int64
        The daemon's host_realtime stamps at the read [ns].
    received_ns : int
        host_realtime [ns] when the rotation's last packet reached this process.
    index : int
        Rotation number since the start of this stream (gaps where rotations were dropped).
    """

    packets: np.ndarray
    host_ns: np.ndarray
    received_ns: int
    index: int


@dataclass
class StreamCounters:
    packets: int = 0
    malformed: int = 0  # samples that could not be decoded (a bad lidar block counts once)
    missing: int = 0  # lidar packets lost between the daemon and here (gaps in block numbers)
    rotations: int = 0
    rotations_dropped: int = 0
    imu_samples: int = 0
    events: int = 0
    status: int = 0


def first_block_azimuth(payload: bytes) -> int:
    """Azimuth of a data packet's first block [0.01 deg]."""
    return payload[2] | (payload[3] << 8)


class RotationCutter:
    """Groups data packets into rotations: a rotation ends before the packet whose first block's
    azimuth is smaller than the previous packet's (the wrap through 0), or after a silence of
    ``max_gap_ns``."""

    def __init__(self, max_gap_ns: int = 200_000_000):
        self.max_gap_ns = max_gap_ns
        self._payloads: list[bytes] = []
        self._stamps: list[int] = []
        self._last_az = -1

    def feed(self, host_ns: int, payload: bytes) -> tuple[list[bytes], list[int]] | None:
        """Add one packet; returns the finished rotation's (payloads, stamps) when this packet
        starts a new one."""
        az = first_block_azimuth(payload)
        done = None
        if self._payloads and (az < self._last_az
                               or host_ns - self._stamps[-1] > self.max_gap_ns):
            done = (self._payloads, self._stamps)
            self._payloads, self._stamps = [], []
        self._payloads.append(payload)
        self._stamps.append(host_ns)
        self._last_az = az
        return done

    def flush(self) -> tuple[list[bytes], list[int]] | None:
        if not self._payloads:
            return None
        done = (self._payloads, self._stamps)
        self._payloads, self._stamps = [], []
        self._last_az = -1
        return done


class LiveStream:
    """Subscribes to one daemon's stream; :meth:`get_rotation` hands out finished rotations.

    Parameters
    ----------
    session : zenoh.Session
        An open session that reaches the daemon (see :func:`open_session`).
    device_id : str
        The daemon's ``device_id``.
    queue_rotations : int
        Rotations that may wait for the consumer; older ones are dropped beyond that.
    """

    def __init__(self, session, device_id: str = topics.DEFAULT_DEVICE_ID,
                 queue_rotations: int = 2):
        self.counts = StreamCounters()
        self._q: queue.Queue[Rotation] = queue.Queue(maxsize=max(1, queue_rotations))
        self._cutter = RotationCutter()
        self._lock = threading.Lock()
        self._imu: collections.deque = collections.deque(maxlen=2048)  # (host_ns, w, x, y, z)
        self._events: collections.deque = collections.deque(maxlen=256)
        self.status: dict | None = None
        self._last_drop_log = 0.0
        self._drops_logged = 0
        self.last_packet_ns = 0  # host_realtime of the last packet's arrival here
        self._blocks = LidarBlockDecoder(packet_size=PACKET_SIZE)
        self._leaf = {
            "imu/quaternion": self._on_imu,
            "status": self._on_status,
            "events": self._on_event,
        }
        self._subs = [session.declare_subscriber(topics.key_lidar_blocks(device_id),
                                                 self._on_block_sample)]
        self._subs += [session.declare_subscriber(key, self._on_sample) for key in (
            topics.key_imu(device_id), topics.key_status(device_id), topics.key_events(device_id))]

    # ---- Zenoh's callback thread: short, never blocks ---------------------------------------
    def _on_sample(self, sample) -> None:
        leaf = str(sample.key_expr).split("/", 2)[-1]
        handler = self._leaf.get(leaf)
        if handler is None:
            return
        try:
            handler(sample.payload.to_bytes())
        except Exception as exc:  # noqa: BLE001 - bad input is counted, never fatal
            self.counts.malformed += 1
            log.debug("malformed %s sample: %s", leaf, exc)

    def _on_block_sample(self, sample) -> None:
        blk = self._blocks.decode(sample.payload.to_bytes())
        if blk is None:  # truncated or inconsistent: counted, the stream goes on
            self.counts.malformed += 1
            return
        self.counts.missing = self._blocks.missing
        self.counts.packets += len(blk)
        self.last_packet_ns = time.time_ns()
        finished = []
        with self._lock:
            feed = self._cutter.feed
            for host_ns, payload in blk.packets():
                done = feed(host_ns, payload)
                if done is not None:
                    finished.append(done)
        for done in finished:
            self._push(done)

    def _push(self, done: tuple[list[bytes], list[int]]) -> None:
        payloads, stamps = done
        rot = Rotation(np.frombuffer(b"".join(payloads), np.uint8).reshape(-1, PACKET_SIZE),
                       np.asarray(stamps, np.int64), time.time_ns(), self.counts.rotations)
        self.counts.rotations += 1
        while True:
            try:
                self._q.put_nowait(rot)
                return
            except queue.Full:
                try:
                    self._q.get_nowait()  # the oldest goes: show what is current
                    self.counts.rotations_dropped += 1
                    self._log_drop()
                except queue.Empty:
                    pass

    def _log_drop(self) -> None:
        now = time.monotonic()
        if now - self._last_drop_log >= 1.0:
            n = self.counts.rotations_dropped
            log.warning("live view behind the stream: %d rotation(s) dropped (%d in all)",
                        n - self._drops_logged, n)
            self._last_drop_log, self._drops_logged = now, n

    def _on_imu(self, data: bytes) -> None:
        s = messages.decode_imu(data)
        self.counts.imu_samples += 1
        self._imu.append((s.host_ns, s.w, s.x, s.y, s.z))

    def _on_status(self, data: bytes) -> None:
        self.status = json.loads(data)
        self.counts.status += 1

    def _on_event(self, data: bytes) -> None:
        self._events.append(messages.decode_event(data))
        self.counts.events += 1

    # ---- consumer side ----------------------------------------------------------------------
    def get_rotation(self, timeout_s: float) -> Rotation | None:
        """The next finished rotation, or None after ``timeout_s``. A stream silent for more
        than ``timeout_s`` gives its last, partial rotation."""
        try:
            return self._q.get(timeout=timeout_s)
        except queue.Empty:
            pass
        if self.last_packet_ns and time.time_ns() - self.last_packet_ns > timeout_s * 1e9:
            with self._lock:
                done = self._cutter.flush()
            if done is not None:
                self._push(done)
                try:
                    return self._q.get_nowait()
                except queue.Empty:
                    return None
        return None

    def imu_track(self) -> tuple[np.ndarray, np.ndarray]:
        """Recent IMU samples: host_ns (K,) int64 and q_world_imu (K, 4) float64 w, x, y, z."""
        snap = list(self._imu)
        if not snap:
            return np.zeros(0, np.int64), np.zeros((0, 4))
        a = np.asarray(snap, dtype=np.float64)
        return np.asarray([s[0] for s in snap], np.int64), a[:, 1:]

    def pop_events(self) -> list[messages.Event]:
        out = []
        while self._events:
            out.append(self._events.popleft())
        return out

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # noqa: BLE001 - closing twice, or the session is gone
                pass


def open_session(connect: list[str], config_file: str | None = None):
    """A Zenoh peer session connecting to ``connect`` endpoints (``tcp/HOST:7447``), no
    multicast scouting; ``config_file`` (zenoh JSON5: TLS, user/password) underneath."""
    import zenoh

    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps([]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)
