# SPDX-License-Identifier: BSD-3-Clause
"""Streaming pcap / pcapng reader and a pcap writer for UDP datagrams (VeloView-style captures).

Reading never loads the file: records are yielded one at a time (constant memory). Link types:
Ethernet (with 802.1Q VLAN tags), Linux cooked (SLL, SLL2), raw IP and BSD loopback; IPv4 and
IPv6; UDP only. IPv4 fragments are counted and skipped (Velodyne packets are never fragmented).
A file cut mid-record yields every whole record and sets ``stats.truncated``.
"""

from __future__ import annotations

import os
import socket
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BOM = 0x1A2B3C4D

LINKTYPE_NULL = 0
LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_RAW_ALT = (12, 14)
LINKTYPE_LINUX_SLL = 113
LINKTYPE_LINUX_SLL2 = 276


class PcapFormatError(ValueError):
    """Not a pcap/pcapng file, or a header too damaged to go on (one-line message)."""


@dataclass(frozen=True, slots=True)
class UdpDatagram:
    """One UDP datagram of a capture. ``t_ns``: capture time (host_realtime of the capturer)."""

    t_ns: int
    src: str
    src_port: int
    dst: str
    dst_port: int
    payload: bytes


@dataclass
class PcapStats:
    records: int = 0
    udp: int = 0
    skipped: dict = field(default_factory=dict)  # reason -> count
    truncated: bool = False  # the file ends inside a record
    format: str = ""

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1


def _parse_ip(frame: memoryview, off: int, stats: PcapStats, t_ns: int) -> UdpDatagram | None:
    if len(frame) - off < 1:
        stats.skip("short_frame")
        return None
    version = frame[off] >> 4
    if version == 4:
        if len(frame) - off < 20:
            stats.skip("short_frame")
            return None
        ihl = (frame[off] & 0x0F) * 4
        total_len = struct.unpack_from(">H", frame, off + 2)[0]
        frag = struct.unpack_from(">H", frame, off + 6)[0]
        proto = frame[off + 9]
        if proto != 17:
            stats.skip("not_udp")
            return None
        if frag & 0x3FFF:  # more-fragments flag or a fragment offset
            stats.skip("ip_fragment")
            return None
        src = socket.inet_ntoa(bytes(frame[off + 12 : off + 16]))
        dst = socket.inet_ntoa(bytes(frame[off + 16 : off + 20]))
        udp = off + ihl
        ip_end = off + total_len if total_len else len(frame)
    elif version == 6:
        if len(frame) - off < 40:
            stats.skip("short_frame")
            return None
        if frame[off + 6] != 17:
            stats.skip("not_udp")
            return None
        src = socket.inet_ntop(socket.AF_INET6, bytes(frame[off + 8 : off + 24]))
        dst = socket.inet_ntop(socket.AF_INET6, bytes(frame[off + 24 : off + 40]))
        udp = off + 40
        ip_end = udp + struct.unpack_from(">H", frame, off + 4)[0]
    else:
        stats.skip("not_ip")
        return None
    if len(frame) - udp < 8:
        stats.skip("short_frame")
        return None
    sport, dport, ulen = struct.unpack_from(">HHH", frame, udp)
    end = udp + ulen if ulen >= 8 else ip_end
    if end > len(frame):
        stats.skip("snapped_payload")  # captured with a short snaplen
        return None
    stats.udp += 1
    return UdpDatagram(t_ns, src, sport, dst, dport, bytes(frame[udp + 8 : end]))


def _parse_frame(linktype: int, data: bytes, stats: PcapStats, t_ns: int) -> UdpDatagram | None:
    frame = memoryview(data)
    if linktype == LINKTYPE_ETHERNET:
        off, ethertype = 14, struct.unpack_from(">H", frame, 12)[0] if len(frame) >= 14 else 0
        while ethertype in (0x8100, 0x88A8) and len(frame) >= off + 4:
            ethertype = struct.unpack_from(">H", frame, off + 2)[0]
            off += 4
        if ethertype not in (0x0800, 0x86DD):
            stats.skip("not_ip")
            return None
    elif linktype == LINKTYPE_LINUX_SLL:
        off = 16
    elif linktype == LINKTYPE_LINUX_SLL2:
        off = 20
    elif linktype == LINKTYPE_NULL:
        off = 4
    elif linktype == LINKTYPE_RAW or linktype in LINKTYPE_RAW_ALT:
        off = 0
    else:
        stats.skip(f"linktype_{linktype}")
        return None
    return _parse_ip(frame, off, stats, t_ns)


def _read_exact(fh: BinaryIO, n: int) -> bytes:
    return fh.read(n)


def _iter_pcap(fh: BinaryIO, head: bytes, stats: PcapStats) -> Iterator[UdpDatagram]:
    magic_le = struct.unpack_from("<I", head)[0]
    if magic_le in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
        e = "<"
    else:
        e = ">"
    magic = struct.unpack_from(e + "I", head)[0]
    scale = 1 if magic == PCAP_MAGIC_NS else 1000
    rest = _read_exact(fh, 20)
    if len(rest) < 20:
        raise PcapFormatError("pcap global header is truncated")
    linktype = struct.unpack_from(e + "I", rest, 16)[0] & 0x0FFFFFFF
    stats.format = "pcap"
    rec = struct.Struct(e + "IIII")
    while True:
        h = _read_exact(fh, 16)
        if not h:
            return
        if len(h) < 16:
            stats.truncated = True
            return
        sec, frac, incl, _orig = rec.unpack(h)
        if incl > 262144 * 4:
            raise PcapFormatError(
                f"pcap record {stats.records} claims {incl} bytes: file is corrupt")
        data = _read_exact(fh, incl)
        if len(data) < incl:
            stats.truncated = True
            return
        stats.records += 1
        d = _parse_frame(linktype, data, stats, sec * 1_000_000_000 + frac * scale)
        if d is not None:
            yield d


def _iter_pcapng(fh: BinaryIO, head: bytes, stats: PcapStats) -> Iterator[UdpDatagram]:
    stats.format = "pcapng"
    e = "<"
    interfaces: list[tuple[int, int]] = []  # (linktype, ticks per second)
    first = True
    buf = head
    while True:
        h = buf if first else _read_exact(fh, 8)
        if not h:
            return
        if len(h) < 8:
            stats.truncated = True
            return
        if first:
            bom = _read_exact(fh, 4)
            if len(bom) < 4:
                raise PcapFormatError("pcapng section header is truncated")
            e = "<" if struct.unpack("<I", bom)[0] == PCAPNG_BOM else ">"
            if struct.unpack(e + "I", bom)[0] != PCAPNG_BOM:
                raise PcapFormatError("pcapng byte-order magic is wrong")
            btype, blen = struct.unpack(e + "II", h)
            body = bom + _read_exact(fh, blen - 12)
            first = False
        else:
            btype, blen = struct.unpack(e + "II", h)
            if blen < 12 or blen % 4 or blen > 1 << 24:
                raise PcapFormatError(f"pcapng block of length {blen}: file is corrupt")
            body = _read_exact(fh, blen - 8)
            if len(body) < blen - 8:
                stats.truncated = True
                return
        body = body[:-4]  # trailing block length
        if btype == PCAPNG_SHB:
            interfaces = []
        elif btype == 1:  # interface description
            linktype = struct.unpack_from(e + "H", body, 0)[0]
            tps = 1_000_000
            opt = 8
            while opt + 4 <= len(body):
                code, olen = struct.unpack_from(e + "HH", body, opt)
                if code == 0:
                    break
                if code == 9 and olen >= 1:  # if_tsresol
                    r = body[opt + 4]
                    tps = 2 ** (r & 0x7F) if r & 0x80 else 10 ** r
                opt += 4 + ((olen + 3) & ~3)
            interfaces.append((linktype, tps))
        elif btype in (6, 2):  # enhanced packet / obsolete packet
            if btype == 6:
                iface, th, tl, caplen = struct.unpack_from(e + "IIII", body, 0)
                off = 20
            else:
                iface, _drops, th, tl, caplen = struct.unpack_from(e + "HHIII", body, 0)
                off = 20
            stats.records += 1
            if iface >= len(interfaces):
                stats.skip("unknown_interface")
                continue
            linktype, tps = interfaces[iface]
            ticks = (th << 32) | tl
            t_ns = ticks * 1_000_000_000 // tps
            d = _parse_frame(linktype, body[off : off + caplen], stats, t_ns)
            if d is not None:
                yield d
        elif btype == 3:  # simple packet: no timestamp
            stats.records += 1
            if not interfaces:
                stats.skip("unknown_interface")
                continue
            d = _parse_frame(interfaces[0][0], body[4:], stats, 0)
            if d is not None:
                yield d


_REC_LE = struct.Struct("<IIII")
_REC_BE = struct.Struct(">IIII")
_BUF_SIZE = 1 << 20


def _iter_pcap_payloads(fh: BinaryIO, head: bytes, stats: PcapStats
                        ) -> Iterator[tuple[int, int, bytes]]:
    """Fast path of :func:`_iter_pcap`: ``(t_ns, dst_port, payload)``, no address strings.

    Reads the file in 1 MiB blocks and slices records out of them; plain Ethernet/IPv4/UDP
    frames (every Velodyne capture) are parsed inline, anything else goes through
    :func:`_parse_frame`, so the results are the same as :class:`PcapReader` iteration.
    """
    e = "<" if struct.unpack_from("<I", head)[0] in (PCAP_MAGIC_US, PCAP_MAGIC_NS) else ">"
    magic = struct.unpack_from(e + "I", head)[0]
    scale = 1 if magic == PCAP_MAGIC_NS else 1000
    rest = fh.read(20)
    if len(rest) < 20:
        raise PcapFormatError("pcap global header is truncated")
    linktype = struct.unpack_from(e + "I", rest, 16)[0] & 0x0FFFFFFF
    stats.format = "pcap"
    rec_unpack = (_REC_LE if e == "<" else _REC_BE).unpack_from
    u16 = struct.Struct(">H").unpack_from
    buf = b""
    pos = 0
    eof = False
    while True:
        avail = len(buf) - pos
        if avail >= 16:
            sec, frac, incl, _orig = rec_unpack(buf, pos)
            if incl > 262144 * 4:
                raise PcapFormatError(
                    f"pcap record {stats.records} claims {incl} bytes: file is corrupt")
        if avail < 16 or avail < 16 + incl:
            if eof:
                if avail:
                    stats.truncated = True
                return
            chunk = fh.read(_BUF_SIZE)
            eof = len(chunk) < _BUF_SIZE
            buf = buf[pos:] + chunk
            pos = 0
            continue
        start = pos + 16
        pos = start + incl
        stats.records += 1
        t_ns = sec * 1_000_000_000 + frac * scale
        # inline Ethernet + IPv4 (no options, not fragmented) + UDP
        if (linktype == LINKTYPE_ETHERNET and incl >= 42 and buf[start + 12] == 8
                and buf[start + 13] == 0 and buf[start + 14] == 0x45 and buf[start + 23] == 17
                and not (u16(buf, start + 20)[0] & 0x3FFF)):
            ulen = u16(buf, start + 38)[0]
            end = start + 34 + ulen if ulen >= 8 else start + 14 + u16(buf, start + 16)[0]
            if end <= pos:
                stats.udp += 1
                yield t_ns, u16(buf, start + 36)[0], buf[start + 42 : end]
                continue
        d = _parse_frame(linktype, buf[start:pos], stats, t_ns)
        if d is not None:
            yield d.t_ns, d.dst_port, d.payload


_MAX_RECORD_BYTES = 262144 * 4


@dataclass
class PayloadBatch:
    """The UDP payloads of consecutive records: those of ``data_size`` bytes as one array.

    Attributes
    ----------
    data : np.ndarray, shape (n, data_size), uint8
        Payloads of the given size, in file order.
    data_t_ns : np.ndarray, shape (n,), int64
        Their capture times [ns] (host_realtime of the capturer).
    data_port : np.ndarray, shape (n,), uint16
        Their UDP destination ports.
    others : list of (t_ns, dst_port, payload)
        Every other UDP payload of the same records.
    """

    data: np.ndarray
    data_t_ns: np.ndarray
    data_port: np.ndarray
    others: list[tuple[int, int, bytes]]


def _iter_pcap_batches(fh: BinaryIO, head: bytes, stats: PcapStats, data_size: int
                       ) -> Iterator[PayloadBatch]:
    """Batch path of :func:`_iter_pcap_payloads`: 1 MiB of records at a time, scanned in C++
    (``tripod_core/pcap_scan``: the same plain Ethernet/IPv4/UDP rules), data payloads copied
    out into one array; records off the plain path go through :func:`_parse_frame`."""
    from .. import _ext

    e = "<" if struct.unpack_from("<I", head)[0] in (PCAP_MAGIC_US, PCAP_MAGIC_NS) else ">"
    magic = struct.unpack_from(e + "I", head)[0]
    rest = fh.read(20)
    if len(rest) < 20:
        raise PcapFormatError("pcap global header is truncated")
    linktype = struct.unpack_from(e + "I", rest, 16)[0] & 0x0FFFFFFF
    stats.format = "pcap"
    layout = _ext._PcapLayout()
    layout.big_endian, layout.nanosecond = e == ">", magic == PCAP_MAGIC_NS
    layout.linktype = linktype
    buf = b""
    eof = False
    while True:
        if not eof:
            chunk = fh.read(_BUF_SIZE)
            eof = len(chunk) < _BUF_SIZE
            buf = buf + chunk if buf else chunk
        scan = _ext._scan_pcap_records(np.frombuffer(buf, np.uint8), layout, data_size,
                                       _MAX_RECORD_BYTES)
        consumed, records, oversize = scan.consumed, scan.records, scan.oversize_bytes
        data, data_t_ns, data_port, data_rec = (scan.data, scan.data_t_ns, scan.data_port,
                                                scan.data_record)
        other, slow = scan.other, scan.slow
        stats.udp += len(data_t_ns) + len(other)
        others = [(t, port, buf[off : off + n]) for t, off, n, port in other.tolist()]
        slow_data = []  # data payloads of records off the plain path: put in file order
        for t, off, n, rec in slow.tolist():
            d = _parse_frame(linktype, buf[off : off + n], stats, t)
            if d is None:
                continue
            if len(d.payload) == data_size:
                slow_data.append((rec, d))
            else:
                others.append((d.t_ns, d.dst_port, d.payload))
        if slow_data:
            at = np.searchsorted(data_rec, [rec for rec, _ in slow_data])
            data = np.insert(data, at, np.frombuffer(b"".join(d.payload for _, d in slow_data),
                                                    np.uint8).reshape(-1, data_size), axis=0)
            data_t_ns = np.insert(data_t_ns, at, [d.t_ns for _, d in slow_data])
            data_port = np.insert(data_port, at, [d.dst_port for _, d in slow_data])
        stats.records += records
        if records:
            yield PayloadBatch(data, data_t_ns, data_port, others)
        if oversize:
            raise PcapFormatError(
                f"pcap record {stats.records} claims {oversize} bytes: file is corrupt")
        buf = buf[consumed:]
        if eof and (not records or not buf):
            if buf:
                stats.truncated = True
            return


def sniff_format(path: str | os.PathLike) -> str:
    """'pcap', 'pcapng' or '' from the first bytes of a file."""
    with open(path, "rb") as fh:
        head = fh.read(4)
    if len(head) < 4:
        return ""
    m_le = struct.unpack("<I", head)[0]
    m_be = struct.unpack(">I", head)[0]
    if PCAP_MAGIC_US in (m_le, m_be) or PCAP_MAGIC_NS in (m_le, m_be):
        return "pcap"
    if m_le == PCAPNG_SHB:
        return "pcapng"
    return ""


class PcapReader:
    """Iterate the UDP datagrams of a pcap/pcapng file.

    >>> r = PcapReader("capture.pcap")
    >>> for d in r: ...          # UdpDatagram(t_ns, src, src_port, dst, dst_port, payload)
    >>> r.stats.truncated, r.stats.skipped
    """

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        if os.path.isdir(self.path):
            raise PcapFormatError(f"{self.path}: a folder, not a capture file")
        if not os.path.isfile(self.path):
            raise FileNotFoundError(f"no such file: {self.path}")
        fmt = sniff_format(self.path)
        if not fmt:
            size = os.path.getsize(self.path)
            what = "an empty file" if size == 0 else "not a pcap or pcapng file"
            raise PcapFormatError(f"{self.path}: {what}")
        self.format = fmt
        self.stats = PcapStats()

    def __iter__(self) -> Iterator[UdpDatagram]:
        self.stats = PcapStats()
        with open(self.path, "rb") as fh:
            head = fh.read(8 if self.format == "pcapng" else 4)
            if self.format == "pcap":
                yield from _iter_pcap(fh, head, self.stats)
            else:
                yield from _iter_pcapng(fh, head, self.stats)


    def payloads(self) -> Iterator[tuple[int, int, bytes]]:
        """``(t_ns, dst_port, payload)`` of every UDP datagram, in file order.

        The same datagrams as iterating the reader, without building address strings: the
        decoder's hot path (a few times faster per record on classic pcap).
        """
        self.stats = PcapStats()
        with open(self.path, "rb") as fh:
            if self.format == "pcap":
                yield from _iter_pcap_payloads(fh, fh.read(4), self.stats)
            else:
                for d in _iter_pcapng(fh, fh.read(8), self.stats):
                    yield d.t_ns, d.dst_port, d.payload

    def payload_batches(self, data_size: int = 1206, batch_records: int = 1024
                        ) -> Iterator[PayloadBatch]:
        """The same datagrams as :meth:`payloads`, in :class:`PayloadBatch` es: payloads of
        ``data_size`` bytes as one (n, data_size) array per batch (file order), the others
        beside them. Classic pcap is scanned in C++ (1 MiB of records per batch); pcapng is
        grouped from :meth:`payloads` (``batch_records`` datagrams per batch).
        """
        if self.format == "pcap":
            self.stats = PcapStats()
            with open(self.path, "rb") as fh:
                yield from _iter_pcap_batches(fh, fh.read(4), self.stats, data_size)
            return
        data: list[bytes] = []
        t_ns: list[int] = []
        ports: list[int] = []
        others: list[tuple[int, int, bytes]] = []

        def batch() -> PayloadBatch:
            arr = np.frombuffer(b"".join(data), np.uint8).reshape(len(data), data_size)
            return PayloadBatch(arr, np.array(t_ns, np.int64), np.array(ports, np.uint16),
                                list(others))

        for t, port, payload in self.payloads():
            if len(payload) == data_size:
                data.append(payload)
                t_ns.append(t)
                ports.append(port)
            else:
                others.append((t, port, payload))
            if len(data) + len(others) >= batch_records:
                yield batch()
                data.clear(), t_ns.clear(), ports.clear(), others.clear()
        if data or others:
            yield batch()


def _ip_checksum(header: bytes) -> int:
    s = sum(struct.unpack(">10H", header))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


class PcapWriter:
    """Write UDP datagrams as a nanosecond pcap with Ethernet/IPv4/UDP framing.

    Defaults match a VLP-16: source 192.168.1.201, broadcast destination, the sensor's MAC OUI.
    """

    def __init__(self, path: str | os.PathLike, src_ip: str = "192.168.1.201",
                 dst_ip: str = "255.255.255.255", src_mac: bytes = bytes.fromhex("60769f000001"),
                 dst_mac: bytes = b"\xff" * 6):
        self._fh = open(path, "wb")
        self._fh.write(struct.pack("<IHHiIII", PCAP_MAGIC_NS, 2, 4, 0, 0, 65535, LINKTYPE_ETHERNET))
        self._eth = dst_mac + src_mac + b"\x08\x00"
        self._src = socket.inet_aton(src_ip)
        self._dst = socket.inet_aton(dst_ip)
        self._ident = 0
        self.count = 0

    def write_udp(self, t_ns: int, payload: bytes, src_port: int, dst_port: int) -> None:
        ulen = 8 + len(payload)
        self._ident = (self._ident + 1) & 0xFFFF
        ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + ulen, self._ident, 0x4000, 64, 17, 0,
                         self._src, self._dst)
        ip = ip[:10] + struct.pack(">H", _ip_checksum(ip)) + ip[12:]
        frame = self._eth + ip + struct.pack(">HHHH", src_port, dst_port, ulen, 0) + payload
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        self._fh.write(struct.pack("<IIII", sec, nsec, len(frame), len(frame)) + frame)
        self.count += 1

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "PcapWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
