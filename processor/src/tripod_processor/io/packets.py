# SPDX-License-Identifier: BSD-3-Clause
"""Where Velodyne UDP payloads come from: pcap/pcapng captures, raw payload files, our MCAP.

Every source iterates ``(host_ns, payload)`` in file order, data (1206 B) and position (512 B)
packets interleaved, and keeps a :class:`SourceReport` (what it skipped, whether the file was cut
short). :meth:`PacketSource.batches` gives the same packets as :class:`PacketBatch` es, the data
packets of a batch as one (n, 1206) array: the decoder's fast path (the pcap and payload-file
sources fill them without a Python step per packet). Reading streams through the file: constant
memory whatever its length.

``host_ns`` is host_realtime [ns] as the capturer stamped it (pcap record time, MCAP
``log_time``). A raw payload file carries no host time: its source synthesises ``host_ns`` from
the packets' own device time (µs past the hour, unwrapped across hour rollovers), starting at 0.
"""

from __future__ import annotations

import abc

import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from tripod_shared import velodyne as vl
from tripod_shared.timebase import TohChunkUnwrapper

from .pcap import PcapFormatError, PcapReader, sniff_format


class SourceError(ValueError):
    """The input cannot be read as a packet source (one-line message)."""


@dataclass
class SourceReport:
    """What a source met while reading."""

    skipped: dict[str, int] = field(default_factory=dict)  # reason -> count
    truncated: bool = False  # the file ends inside a record / packet / MCAP chunk
    detail: str = ""  # reader's own words on a truncation

    def skip(self, reason: str, n: int = 1) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + n


@dataclass
class PacketBatch:
    """Consecutive packets of a source: the data packets as one array, the rest beside.

    Attributes
    ----------
    host_ns : np.ndarray, shape (n,), int64
        host_realtime [ns] of each data packet.
    data : np.ndarray, shape (n, 1206), uint8
        The data packets (1206-byte payloads), in source order.
    others : list of (host_ns, payload)
        The other payloads (position packets, wrong sizes) of the same stretch.
    """

    host_ns: np.ndarray
    data: np.ndarray
    others: list[tuple[int, bytes]]


def group_packets(packets, max_data: int = 1024) -> Iterator[PacketBatch]:
    """:class:`PacketBatch` es of an iterable of ``(host_ns, payload)``, ``max_data`` data
    packets each (the last one fewer)."""
    size = vl.DATA_PACKET_SIZE
    data: list[bytes] = []
    host: list[int] = []
    others: list[tuple[int, bytes]] = []
    for host_ns, payload in packets:
        if len(payload) == size:
            data.append(payload)
            host.append(host_ns)
            if len(data) >= max_data:
                yield PacketBatch(np.array(host, np.int64), np.frombuffer(
                    b"".join(data), np.uint8).reshape(-1, size), others)
                data, host, others = [], [], []
        else:
            others.append((host_ns, payload))
    if data or others:
        yield PacketBatch(np.array(host, np.int64),
                          np.frombuffer(b"".join(data), np.uint8).reshape(-1, size), others)


class PacketSource(abc.ABC):
    """Base of the sources: ``iter(source)`` yields ``(host_ns, payload)``."""

    kind = ""

    def batches(self, max_data: int = 1024) -> Iterator[PacketBatch]:
        """The packets of ``iter(self)`` as :class:`PacketBatch` es (subclasses read faster)."""
        yield from group_packets(self, max_data)

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self.report = SourceReport()

    @abc.abstractmethod
    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        """(host_ns, payload) of every packet in file order."""

    @property
    def size_bytes(self) -> int:
        return os.path.getsize(self.path)


class PcapSource(PacketSource):
    """UDP payloads of a pcap / pcapng capture (VeloView, Wireshark, tcpdump).

    Parameters
    ----------
    ports : set of int, optional
        Keep only datagrams sent to these UDP ports (default: all; the decoder tells data and
        position packets apart by size and header).
    """

    def __init__(self, path: str | os.PathLike, ports: set[int] | None = None):
        super().__init__(path)
        try:
            self._reader = PcapReader(self.path)
        except PcapFormatError as exc:
            raise SourceError(str(exc)) from None
        self.kind = self._reader.format
        self.ports = ports

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        self.report = SourceReport()
        ports = self.ports
        try:
            for t_ns, dst_port, payload in self._reader.payloads():
                if ports is not None and dst_port not in ports:
                    self.report.skip("other_port")
                    continue
                yield t_ns, payload
        except PcapFormatError as exc:
            raise SourceError(f"{self.path}: {exc}") from None
        finally:
            self._reader_report()

    def batches(self, max_data: int = 1024) -> Iterator[PacketBatch]:
        """Batches straight from the pcap reader's batch path (``max_data`` is for the other
        sources: a classic pcap batch is 1 MiB of records)."""
        self.report = SourceReport()
        ports = self.ports
        port_list = sorted(ports) if ports is not None else None
        try:
            for b in self._reader.payload_batches(vl.DATA_PACKET_SIZE):
                data, host_ns = b.data, b.data_t_ns
                others = b.others
                if port_list is not None:
                    keep = np.isin(b.data_port, port_list)
                    if not keep.all():
                        self.report.skip("other_port", int((~keep).sum()))
                        data, host_ns = data[keep], host_ns[keep]
                    kept = [o for o in others if o[1] in ports]
                    if len(kept) < len(others):
                        self.report.skip("other_port", len(others) - len(kept))
                    others = kept
                yield PacketBatch(host_ns, data, [(t, p) for t, _port, p in others])
        except PcapFormatError as exc:
            raise SourceError(f"{self.path}: {exc}") from None
        finally:
            self._reader_report()

    def _reader_report(self) -> None:
        st = self._reader.stats
        for reason, n in st.skipped.items():
            self.report.skip(reason, n)
        if st.truncated:
            self.report.truncated = True
            self.report.detail = ("the file ends inside a pcapng block" if self.kind == "pcapng"
                                  else "the file ends inside a pcap record")


class PayloadFileSource(PacketSource):
    """A file of back-to-back 1206-byte data payloads (no framing, no host time)."""

    kind = "payloads"
    _BATCH = 512  # packets per read

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        # one reading and hour-unwrapping path: the batch reader below
        for batch in self.batches(self._BATCH):
            for t_ns, row in zip(batch.host_ns.tolist(), batch.data):
                yield t_ns, row.tobytes()

    def batches(self, max_data: int = 1024) -> Iterator[PacketBatch]:
        """The file read ``max_data`` packets at a time, straight into arrays."""
        self.report = SourceReport()
        size = vl.DATA_PACKET_SIZE
        unwrap = TohChunkUnwrapper()  # no host time: device time since the first hour
        with open(self.path, "rb") as fh:
            while True:
                block = fh.read(size * max_data)
                n = len(block) // size
                if n:
                    arr = np.frombuffer(block, np.uint8, count=n * size).reshape(n, size)
                    toh_us = arr[:, vl.TIMESTAMP_OFFSET : vl.TIMESTAMP_OFFSET + 4].copy()
                    yield PacketBatch(unwrap(toh_us.view("<u4").ravel()), arr, [])
                if len(block) % size:
                    self.report.truncated = True
                    self.report.detail = (
                        f"{len(block) % size} trailing bytes do not make a whole packet")
                if len(block) < size * max_data:
                    return


class McapSource(PacketSource):
    """Lidar data and position packets of a tripod MCAP recording (``tripod_shared.recording``)."""

    kind = "mcap"

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        from .events import McapEvents

        self.report = SourceReport()
        events = McapEvents(self.path)  # lidar data and position packets
        for host_ns, _kind, payload in events:
            yield host_ns, payload
        for _key, n in events.skipped.items():  # a corrupt message is counted, never fatal
            self.report.skip("bad_message", n)
        if events.truncated:
            self.report.truncated = True
            self.report.detail = events.error or "the recording ends early"


def open_source(path: str | os.PathLike, ports: set[int] | None = None) -> PacketSource:
    """The right :class:`PacketSource` for a file, sniffed from its first bytes.

    Raises
    ------
    FileNotFoundError
        No such file.
    SourceError
        Empty, or not a pcap, pcapng, MCAP or raw payload file (one-line message).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise SourceError(f"{path}: a folder, not a capture file")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no such file: {path}")
    size = os.path.getsize(path)
    if size == 0:
        raise SourceError(f"{path}: an empty file")
    if sniff_format(path):
        return PcapSource(path, ports)
    with open(path, "rb") as fh:
        head = fh.read(vl.DATA_PACKET_SIZE)
    if head.startswith(b"\x89MCAP"):
        return McapSource(path)
    if len(head) == vl.DATA_PACKET_SIZE and vl.check_data_packet(
            head, accept_products=tuple(vl.PRODUCTS)) == vl.PacketKind.DATA:
        return PayloadFileSource(path)
    raise SourceError(
        f"{path}: not a pcap, pcapng, MCAP or raw 1206-byte Velodyne payload file")
