# SPDX-License-Identifier: BSD-3-Clause
"""VLP-16 UDP input: non-blocking sockets, kernel receive stamps, cheap header checks.

The loop calls :meth:`LidarInput.drain` when a socket is readable. Every datagram is stamped by
the kernel at the wire (``SO_TIMESTAMPNS``, host_realtime), checked (size, block flags, return
mode, product; position packets: ``input_check``), counted by kind and, when good, encoded once
into the CDR bytes that both MCAP and Zenoh carry. Nothing is decoded. The receive buffer is
made large (``SO_RCVBUFFORCE`` when permitted) so that the kernel holds bursts while Python does
other work.

Data packets (``lidar.batch_receive``, the default on Linux): one ``recvmmsg`` reads up to
``max_batch`` datagrams straight into the rows of a :class:`tripod_shared.mcap_writer.
MessageBlock` (each row the MCAP Message record the packet is stored as: record header, CDR
header and stamp, payload), the checks run on the whole array at once, and the good rows go to
the recorder and the publisher as one block: no Python work per packet. Otherwise (and for the
rare position packets) one ``recvmsg`` per datagram, as (topic, ns, bytes) items.
"""

from __future__ import annotations

import logging
import socket
import struct
import time

import numpy as np

from tripod_shared import topics
from tripod_shared.mcap_writer import MESSAGE_HEADER_SIZE, MessageBlock
from tripod_shared.timebase import NS_PER_S
from tripod_shared.velodyne import (
    BLOCK_SIZE,
    DATA_PACKET_SIZE,
    POS_PPS_OFFSET,
    POSITION_PACKET_SIZE,
    PPS_STATES,
    PRODUCT_ID_OFFSET,
    RETURN_MODE_OFFSET,
    RETURN_MODES,
    TIMESTAMP_OFFSET,
    PacketKind,
    check_data_packet,
    position_nmea,
    position_timestamp_us,
)

from .clock import LidarClock
from .config import LidarConfig
from . import recvmmsg
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

# a data packet's row in a MessageBlock: MCAP record header, CDR header + stamp, payload
_CDR_SIZE = _CDR_TIME.size  # 12
_ROW_SIZE = MESSAGE_HEADER_SIZE + _CDR_SIZE + DATA_PACKET_SIZE
_PAYLOAD = MESSAGE_HEADER_SIZE + _CDR_SIZE  # column of the payload's first byte
_FLAG_COLS = _PAYLOAD + np.arange(0, TIMESTAMP_OFFSET, BLOCK_SIZE)  # 0xFF of the 12 block flags
_STAMP = np.dtype({"names": ["hdr", "sec", "nsec"], "formats": ["<u4", "<i4", "<u4"],
                   "offsets": [0, 4, 8], "itemsize": _CDR_SIZE})
_CDR_HDR_U32 = _U32.unpack(_CDR_LE)[0]


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
        self._batch = None
        if cfg.batch_receive and recvmmsg.available():
            self._batch = recvmmsg.BatchReceiver(
                self.data_sock, cfg.max_batch, _ROW_SIZE, _PAYLOAD, DATA_PACKET_SIZE)
            self._source_keys = np.array(
                [recvmmsg.ipv4_key(a) for a in cfg.source_addresses], dtype=np.uint32)
            # byte value -> accepted? (a table lookup per row: far cheaper than np.isin)
            self._product_ok = np.zeros(256, dtype=bool)
            self._product_ok[[p for p in self._products if 0 <= p < 256]] = True
            self._mode_ok = np.zeros(256, dtype=bool)
            self._mode_ok[list(RETURN_MODES)] = True

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
            if self._batch is not None:
                return self._drain_data_batch(out)
            return self._drain_data(out)
        return self._drain_position(out)

    def _drain_data_batch(self, out: list) -> int:
        """One ``recvmmsg``; the good packets appended to ``out`` as one MessageBlock."""
        br = self._batch
        n = br.receive()
        if n == 0:
            return 0
        if br.kernel_drops >= 0:
            self._drops[0] = br.kernel_drops
            self.counts["lidar_kernel_drops"] = self._drops[0] + self._drops[1]
        rows = br.rows[:n]
        stamps = br.stamps_ns
        if not stamps.all():  # no kernel stamp (should not happen): the read time
            stamps = np.where(stamps == 0, time.time_ns(), stamps)
        filtered = (~np.isin(br.addresses, self._source_keys) if len(self._source_keys)
                    else np.zeros(n, dtype=bool))
        well_formed = ((br.lengths == DATA_PACKET_SIZE) & ~br.truncated
                       & (rows[:, _FLAG_COLS] == 0xFF).all(axis=1)
                       & (rows[:, _FLAG_COLS + 1] == 0xEE).all(axis=1)
                       & self._mode_ok[rows[:, _PAYLOAD + RETURN_MODE_OFFSET]])
        ours = self._product_ok[rows[:, _PAYLOAD + PRODUCT_ID_OFFSET]]
        good = ~filtered & well_formed & ours
        n_good = int(np.count_nonzero(good))
        n_filtered = int(np.count_nonzero(filtered))
        c = self.counts
        c["lidar_filtered"] += n_filtered
        c["lidar_malformed"] += int(np.count_nonzero(~filtered & ~well_formed))
        c["lidar_foreign"] += int(np.count_nonzero(~filtered & well_formed & ~ours))
        if n_good == 0:
            return n
        if n_good == n:
            # a full read is handed over without a copy (the next receive reads into a new
            # array); a small one is copied, so a queued block never holds a mostly empty array
            block = br.take(n) if 2 * n >= br.capacity else rows.copy()
        else:
            block = rows[good]
            stamps = stamps[good]
        # the CDR header and stamp (builtin_interfaces/Time: sec int32, nanosec uint32)
        st = np.empty(n_good, dtype=_STAMP)
        st["hdr"] = _CDR_HDR_U32
        st["sec"], st["nsec"] = np.divmod(stamps, NS_PER_S)
        block[:, MESSAGE_HEADER_SIZE:_PAYLOAD] = st.view(np.uint8).reshape(n_good, _CDR_SIZE)
        log_times = stamps.astype(np.uint64)
        out.append(MessageBlock(topics.TOPIC_LIDAR_PACKETS, block, log_times))
        # every _CLOCK_EVERY-th data packet to the clock estimator (as the per-packet path)
        first = (-self._n_data - 1) % _CLOCK_EVERY
        if first < n_good:
            pick = np.arange(first, n_good, _CLOCK_EVERY)
            toh = block[pick, _PAYLOAD + TIMESTAMP_OFFSET:_PAYLOAD + TIMESTAMP_OFFSET + 4] \
                .copy().view("<u4")[:, 0]
            add = self.clock.add_data
            for t_us, ns in zip(toh.tolist(), stamps[pick].tolist()):
                add(t_us, ns)
        self._n_data += n_good
        c["lidar_data"] += n_good
        c["lidar_bytes"] += n_good * DATA_PACKET_SIZE
        return n

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
