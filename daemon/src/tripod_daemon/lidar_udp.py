# SPDX-License-Identifier: BSD-3-Clause
"""VLP-16 UDP input: non-blocking sockets, kernel receive stamps, cheap header checks.

The loop calls :meth:`LidarInput.drain` when a socket is readable. Each datagram is read with
``recvmsg`` and stamped by the kernel at the wire (``SO_TIMESTAMPNS``, host_realtime), checked
(size, block flags, return mode, product; position packets: ``input_check``), counted
by kind and, when good, encoded once into the CDR bytes that both MCAP and Zenoh carry. Nothing is
decoded. The receive buffer is made large (``SO_RCVBUFFORCE`` when permitted) so that the kernel
holds bursts while Python does other work.
"""

from __future__ import annotations

import logging
import socket
import struct
import time

from tripod_shared import topics
from tripod_shared.timebase import NS_PER_S
from tripod_shared.velodyne import (
    DATA_PACKET_SIZE,
    POS_PPS_OFFSET,
    POSITION_PACKET_SIZE,
    PPS_STATES,
    TIMESTAMP_OFFSET,
    PacketKind,
    check_data_packet,
    position_nmea,
    position_timestamp_us,
)

from .clock import LidarClock
from .config import LidarConfig
from .input_check import POSITION_REJECT_REASONS, position_reject_reason
from .stats import Counters

log = logging.getLogger(__name__)

# Linux socket options the socket module does not name
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
_TIMESPEC = struct.Struct("@qq")  # struct timespec on 64-bit Linux: tv_sec, tv_nsec
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
_ANC_SIZE = socket.CMSG_SPACE(_TIMESPEC.size) + socket.CMSG_SPACE(4)
_U32 = struct.Struct("<I")
_CDR_TIME = struct.Struct("<4siI")  # encapsulation header + builtin_interfaces/Time
_CDR_LE = b"\x00\x01\x00\x00"
_CLOCK_EVERY = 8  # feed every 8th data packet to the clock estimator (enough for the envelope)

#: a batch item: (MCAP topic, host_realtime ns, encoded message bytes)
Item = tuple[str, int, bytes]


def open_udp_socket(address: str, port: int, rcvbuf: int) -> tuple[socket.socket, int]:
    """A bound, non-blocking UDP socket with SO_TIMESTAMPNS; returns (socket, actual rcvbuf)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        # the kernel reports, with each datagram, how many it had to drop on this socket so far
        # (only once there were any): loss is counted, never silent
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, rcvbuf)
        except OSError:  # no CAP_NET_ADMIN: capped by net.core.rmem_max
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        sock.bind((address, port))
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    actual = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2  # kernel doubles it
    return sock, actual


class LidarInput:
    """The data and position sockets and their per-kind counters.

    Counters (``counts``): ``lidar_data``, ``lidar_position`` (good, recorded),
    ``lidar_malformed`` (wrong size, flags, mode, truncated), ``lidar_foreign`` (a Velodyne
    packet of a product not accepted), ``lidar_filtered`` (sender not in ``source_addresses``),
    ``lidar_bytes``, ``lidar_kernel_drops`` (datagrams the kernel dropped because the receive
    buffer was full: the loss no user-space counter could otherwise see), and per reason a
    position datagram was refused, ``position_rejected_<reason>`` (see ``input_check``).
    """

    def __init__(self, cfg: LidarConfig, counts: Counters, clock: LidarClock | None = None):
        self.cfg = cfg
        self.counts = counts
        self.clock = clock or LidarClock()
        for k in ("lidar_data", "lidar_position", "lidar_malformed", "lidar_foreign",
                  "lidar_filtered", "lidar_bytes", "lidar_kernel_drops"):
            counts.setdefault(k, 0)
        for why in POSITION_REJECT_REASONS:
            counts.setdefault("position_rejected_" + why, 0)
        self.data_sock, self.data_rcvbuf = open_udp_socket(
            cfg.bind_address, cfg.data_port, cfg.receive_buffer_bytes)
        self.position_sock = None
        self.position_rcvbuf = 0
        if cfg.position_enabled:
            try:
                self.position_sock, self.position_rcvbuf = open_udp_socket(
                    cfg.bind_address, cfg.position_port, cfg.receive_buffer_bytes)
            except OSError:
                self.data_sock.close()
                raise
        if self.data_rcvbuf < cfg.receive_buffer_bytes:
            log.warning(
                "receive buffer is %d B, not %d B: raise net.core.rmem_max (see deploy/sysctl)",
                self.data_rcvbuf, cfg.receive_buffer_bytes)
        self._sources = frozenset(cfg.source_addresses)
        self._products = frozenset(cfg.accept_products)
        self._n_data = 0
        self._drops = [0, 0]  # kernel drop counters of the data and position sockets

    @property
    def data_port(self) -> int:
        return self.data_sock.getsockname()[1]

    @property
    def position_port(self) -> int | None:
        return self.position_sock.getsockname()[1] if self.position_sock else None

    def sockets(self) -> list[socket.socket]:
        return [s for s in (self.data_sock, self.position_sock) if s is not None]

    def drain(self, sock: socket.socket, out: list[Item]) -> int:
        """Read up to ``max_batch`` datagrams from ``sock``; append good ones to ``out``."""
        if sock is self.data_sock:
            return self._drain_data(out)
        return self._drain_position(out)

    # The two drain loops are the hot path (~30,000 calls/s at 20x the dual-return rate):
    # locals only; the checks are tripod_shared's (one source of truth for the layout).
    def _drain_data(self, out: list[Item]) -> int:
        recvmsg = self.data_sock.recvmsg
        append = out.append
        pack = _CDR_TIME.pack
        check = check_data_packet
        DATA, FOREIGN, MSG_TRUNC = PacketKind.DATA, PacketKind.FOREIGN, socket.MSG_TRUNC  # noqa: N806
        sources = self._sources
        products = self._products
        clock = self.clock
        n_good = n_bad = n_foreign = n_filtered = n_bytes = 0
        n = 0
        topic = topics.TOPIC_LIDAR_PACKETS
        for n in range(1, self.cfg.max_batch + 1):  # noqa: B007
            try:
                data, anc, flags, addr = recvmsg(2048, _ANC_SIZE)
            except (BlockingIOError, InterruptedError):
                n -= 1
                break
            if anc:
                sec, nsec = _TIMESPEC.unpack_from(anc[0][2])
                host_ns = sec * NS_PER_S + nsec
                if len(anc) > 1:
                    self._kernel_drops(anc, 0)
            else:
                host_ns = time.time_ns()
            if sources and addr[0] not in sources:
                n_filtered += 1
                continue
            kind = check(data, products)  # size, 12 block flags, return mode, product
            if kind is not DATA or flags & MSG_TRUNC:
                if kind is FOREIGN and not flags & MSG_TRUNC:
                    n_foreign += 1
                else:
                    n_bad += 1
                continue
            n_good += 1
            n_bytes += DATA_PACKET_SIZE
            append((topic, host_ns, pack(_CDR_LE, *divmod(host_ns, NS_PER_S)) + data))
            if not (n_good + self._n_data) % _CLOCK_EVERY:
                clock.add_data(_U32.unpack_from(data, TIMESTAMP_OFFSET)[0], host_ns)
        c = self.counts
        self._n_data += n_good
        c["lidar_data"] += n_good
        c["lidar_malformed"] += n_bad
        c["lidar_foreign"] += n_foreign
        c["lidar_filtered"] += n_filtered
        c["lidar_bytes"] += n_bytes
        return n

    def _drain_position(self, out: list[Item]) -> int:
        sock = self.position_sock
        topic = topics.TOPIC_LIDAR_POSITION
        c = self.counts
        n = 0
        for n in range(1, self.cfg.max_batch + 1):  # noqa: B007
            try:
                data, anc, flags, addr = sock.recvmsg(2048, _ANC_SIZE)
            except (BlockingIOError, InterruptedError):
                n -= 1
                break
            if anc:
                sec, nsec = _TIMESPEC.unpack_from(anc[0][2])
                host_ns = sec * NS_PER_S + nsec
                if len(anc) > 1:
                    self._kernel_drops(anc, 1)
            else:
                host_ns = time.time_ns()
            if self._sources and addr[0] not in self._sources:
                c["lidar_filtered"] += 1
                continue
            why = "size" if flags & socket.MSG_TRUNC else position_reject_reason(data)
            if why is not None:
                # junk on the position port never reaches the recording or the clock
                c["lidar_malformed"] += 1
                c["position_rejected_" + why] += 1
                continue
            toh_us = position_timestamp_us(data)
            c["lidar_position"] += 1
            c["lidar_bytes"] += POSITION_PACKET_SIZE
            out.append((topic, host_ns, _CDR_TIME.pack(_CDR_LE, *divmod(host_ns, NS_PER_S)) + data))
            self.clock.add_position(
                toh_us, host_ns, PPS_STATES.get(data[POS_PPS_OFFSET], "unknown"),
                position_nmea(data))
        return n

    def _kernel_drops(self, anc, which: int) -> None:
        """Record the kernel's cumulative drop count of socket ``which`` (SO_RXQ_OVFL)."""
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(data) >= 4:
                self._drops[which] = _U32.unpack_from(data)[0]
                self.counts["lidar_kernel_drops"] = self._drops[0] + self._drops[1]

    def close(self) -> None:
        for s in self.sockets():
            s.close()
