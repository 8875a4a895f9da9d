# SPDX-License-Identifier: BSD-3-Clause
"""Where Velodyne UDP payloads come from: pcap/pcapng captures, raw payload files, our MCAP.

Every source iterates ``(host_ns, payload)`` in file order, data (1206 B) and position (512 B)
packets interleaved, and keeps a :class:`SourceReport` (what it skipped, whether the file was cut
short). Reading streams through the file: constant memory whatever its length.

``host_ns`` is host_realtime [ns] as the capturer stamped it (pcap record time, MCAP
``log_time``). A raw payload file carries no host time: its source synthesises ``host_ns`` from
the packets' own device time (µs past the hour, unwrapped across hour rollovers), starting at 0.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field

from tripod_shared import velodyne as vl

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


class PacketSource:
    """Base of the sources: ``iter(source)`` yields ``(host_ns, payload)``."""

    kind = ""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self.report = SourceReport()

    def __iter__(self) -> Iterator[tuple[int, bytes]]:  # pragma: no cover - abstract
        raise NotImplementedError

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
            st = self._reader.stats
            for reason, n in st.skipped.items():
                self.report.skip(reason, n)
            if st.truncated:
                self.report.truncated = True
                self.report.detail = "the file ends inside a pcap record"


class PayloadFileSource(PacketSource):
    """A file of back-to-back 1206-byte data payloads (no framing, no host time)."""

    kind = "payloads"
    _BATCH = 512  # packets per read

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        self.report = SourceReport()
        size = vl.DATA_PACKET_SIZE
        hour_ns = 3_600_000_000_000
        base_ns = 0
        last_toh_ns = None
        with open(self.path, "rb") as fh:
            while True:
                block = fh.read(size * self._BATCH)
                n = len(block) // size
                for k in range(n):
                    payload = block[k * size : (k + 1) * size]
                    toh_ns = vl.data_timestamp_us(payload) * 1000
                    if last_toh_ns is not None and toh_ns < last_toh_ns - hour_ns // 2:
                        base_ns += hour_ns  # top of the hour passed
                    last_toh_ns = toh_ns
                    yield base_ns + toh_ns, payload
                if len(block) % size:
                    self.report.truncated = True
                    self.report.detail = (
                        f"{len(block) % size} trailing bytes do not make a whole packet")
                if len(block) < size * self._BATCH:
                    return


class McapSource(PacketSource):
    """Lidar data and position packets of a tripod MCAP recording (``tripod_shared.recording``)."""

    kind = "mcap"

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        from tripod_shared import messages as m
        from tripod_shared import topics as t
        from tripod_shared.recording import RecordingReader

        self.report = SourceReport()
        reader = RecordingReader(self.path)
        decoders = {t.TOPIC_LIDAR_PACKETS: m.decode_velodyne_packet,
                    t.TOPIC_LIDAR_POSITION: m.decode_position_packet}
        for msg in reader.messages(list(decoders)):
            try:
                host_ns, payload = decoders[msg.topic](msg.data)
            except Exception:  # noqa: BLE001 - a corrupt message is counted, never fatal
                self.report.skip("bad_message")
                continue
            yield host_ns, payload
        if reader.report.truncated:
            self.report.truncated = True
            self.report.detail = reader.report.error or "the recording ends early"


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
