# SPDX-License-Identifier: BSD-3-Clause
"""Live lidar blocks: many VLP-16 data packets in one Zenoh sample (``tripod/<id>/lidar/blocks``).

Why: a subscriber pays per sample (zenoh builds a Sample, takes the GIL and calls Python), about
as much as it pays per packet for the work it actually wants. At 50,000 packets/s that per-sample
cost alone starves a consumer on a small machine. The daemon reads its socket in batches (one
``recvmmsg`` per wake-up) and publishes each batch as blocks of at most ``max_packets`` packets,
so a consumer pays per block; the packets inside are a numpy array it can hand on as is.
A block adds no latency: its packets were read together (the daemon drains every
``lidar.wake_interval_ms``); at the sensor's rate a block is one wake-up's packets.

Layout of a block (little-endian, version 1)::

    offset  size      field
    0       4         magic b"TLB1"
    4       2         version (u16) = 1
    6       2         header_size (u16): offset of the stamps (24 in version 1; a reader skips
                      whatever a later version adds before them)
    8       4         count n (u32) >= 1
    12      4         packet_size (u32): bytes of every payload in the block (1206 for VLP-16
                      data packets; the daemon publishes only well-formed ones)
    16      8         first_index (u64): the block's first packet's number among all data packets
                      the daemon handed to its live path since it started: a gap between blocks
                      is exactly the packets this subscriber lost (zenoh drops a slow
                      subscriber's samples without telling anyone); a smaller number than before
                      is a daemon restart
    24      8 n       host_ns (i64 x n): each packet's host_realtime receive stamp [ns] (the
                      kernel's SO_TIMESTAMPNS, as in the recording's log_time)
    24+8n   size n    the n payloads back to back, in arrival order

The payloads and stamps are the ones the recording holds (``/velodyne/packets``: the same stamp
in the CDR header and as log_time). The per-packet key ``tripod/<id>/lidar/packets`` (one CDR
message per packet) is still published, but only while someone subscribes to it.

Bad input never crashes a reader: :class:`LidarBlockDecoder` rejects a truncated or inconsistent
block whole (counted per reason in ``rejected``) and goes on with the next.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"TLB1"
VERSION = 1
HEADER = struct.Struct("<4sHHIIQ")  # magic, version, header_size, count, packet_size, first_index
HEADER_SIZE = HEADER.size  # 24
STAMP_SIZE = 8  # i64 host_ns per packet

#: reasons a block is rejected (``LidarBlockDecoder.rejected`` keys)
REJECT_REASONS = ("short", "magic", "version", "header", "count", "size", "length")


class BlockError(ValueError):
    """A block that cannot be read; ``reason`` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass
class LidarBlock:
    """One decoded block (arrays are read-only views of the sample's bytes: no copy).

    Attributes
    ----------
    first_index : int
        Number of the first packet (see the module docstring).
    host_ns : np.ndarray, shape (n,), int64
        host_realtime receive stamps [ns].
    payloads : np.ndarray, shape (n, packet_size), uint8
    """

    first_index: int
    host_ns: np.ndarray
    payloads: np.ndarray

    def __len__(self) -> int:
        return self.host_ns.shape[0]

    def packets(self) -> list[tuple[int, bytes]]:
        """(host_ns, payload bytes) of each packet, for per-packet code."""
        size = self.payloads.shape[1]
        buf = self.payloads.tobytes()
        return list(zip(self.host_ns.tolist(),
                        [buf[o:o + size] for o in range(0, len(buf), size)]))


def block_size(count: int, packet_size: int) -> int:
    """Bytes of a block of ``count`` packets of ``packet_size`` bytes."""
    return HEADER_SIZE + count * (STAMP_SIZE + packet_size)


def max_packets_for(message_bytes: int, packet_size: int) -> int:
    """The most packets a block of at most ``message_bytes`` bytes holds (at least 1)."""
    return max(1, (message_bytes - HEADER_SIZE) // (STAMP_SIZE + packet_size))


def encode_block(first_index: int, host_ns, payloads) -> bytes:
    """One block.

    Parameters
    ----------
    first_index : int
    host_ns : array-like, shape (n,), integer [ns]
    payloads : np.ndarray, shape (n, size), uint8 (any strides: e.g. a column range of the
        recorder's rows), or a list of n equal-length ``bytes``
    """
    if not isinstance(payloads, np.ndarray):
        sizes = {len(p) for p in payloads}
        if len(sizes) != 1:
            raise ValueError("a block's payloads must all have the same size (and n >= 1)")
        payloads = np.frombuffer(b"".join(payloads), np.uint8).reshape(len(payloads), -1)
    n, size = payloads.shape
    stamps = np.asarray(host_ns, dtype="<i8")
    if n == 0 or stamps.shape != (n,):
        raise ValueError("one stamp per payload, n >= 1")
    out = np.empty(block_size(n, size), np.uint8)
    out[:HEADER_SIZE] = np.frombuffer(
        HEADER.pack(MAGIC, VERSION, HEADER_SIZE, n, size, first_index), np.uint8)
    end = HEADER_SIZE + STAMP_SIZE * n
    out[HEADER_SIZE:end] = stamps.view(np.uint8)
    out[end:].reshape(n, size)[:] = payloads
    return out.tobytes()


def decode_block(buf) -> LidarBlock:
    """Parse one block (``bytes``, ``bytearray`` or ``memoryview``); raises :class:`BlockError`
    when it is truncated or inconsistent. The arrays are views of ``buf``."""
    total = len(buf)
    if total < HEADER_SIZE:
        raise BlockError("short", f"block of {total} B is shorter than its {HEADER_SIZE} B header")
    magic, version, hsize, n, size, first = HEADER.unpack_from(buf)
    if magic != MAGIC:
        raise BlockError("magic", f"not a lidar block (magic {magic!r})")
    if version != VERSION:
        raise BlockError("version", f"lidar block version {version} (this reader knows {VERSION})")
    if hsize < HEADER_SIZE:
        raise BlockError("header", f"header size {hsize} < {HEADER_SIZE}")
    if n == 0:
        raise BlockError("count", "a block of 0 packets")
    if size == 0:
        raise BlockError("size", "packet size 0")
    want = hsize + n * (STAMP_SIZE + size)
    if total != want:
        raise BlockError("length", f"block of {total} B; its header ({n} x {size} B) says {want}")
    host_ns = np.frombuffer(buf, dtype="<i8", count=n, offset=hsize)
    payloads = np.frombuffer(buf, dtype=np.uint8, offset=hsize + STAMP_SIZE * n).reshape(n, size)
    return LidarBlock(first, host_ns, payloads)


@dataclass
class LidarBlockDecoder:
    """Decodes the blocks of one stream and counts what it gets, rejects and misses.

    Attributes
    ----------
    blocks, packets : int
        Blocks and packets decoded.
    missing : int
        Packets lost between the daemon and this subscriber: the gaps in ``first_index``.
    restarts : int
        Times ``first_index`` went back (the daemon restarted): not counted as missing.
    rejected : dict[str, int]
        Blocks rejected, per reason (:data:`REJECT_REASONS`).
    packet_size : int | None
        When set, blocks of another packet size are rejected ("size").
    """

    packet_size: int | None = 1206
    blocks: int = 0
    packets: int = 0
    missing: int = 0
    restarts: int = 0
    rejected: dict = field(default_factory=lambda: dict.fromkeys(REJECT_REASONS, 0))
    _next: int | None = None

    def decode(self, buf) -> LidarBlock | None:
        """The block, or None (counted in ``rejected``) when it cannot be read."""
        try:
            blk = decode_block(buf)
            if self.packet_size is not None and blk.payloads.shape[1] != self.packet_size:
                raise BlockError("size", f"packets of {blk.payloads.shape[1]} B, not "
                                         f"{self.packet_size}")
        except BlockError as exc:
            self.rejected[exc.reason] += 1
            return None
        if self._next is not None:
            if blk.first_index >= self._next:
                self.missing += blk.first_index - self._next
            else:
                self.restarts += 1
        self._next = blk.first_index + len(blk)
        self.blocks += 1
        self.packets += len(blk)
        return blk

    @property
    def next_index(self) -> int | None:
        """The number the next packet should have (None before the first block): ``packets +
        missing`` equals it since the first block, less that block's ``first_index``."""
        return self._next

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())
