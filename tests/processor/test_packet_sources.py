# SPDX-License-Identifier: BSD-3-Clause
"""The batch paths of the packet sources (``PacketSource.batches``, ``PcapReader.
payload_batches``) give exactly the packets of their per-packet iteration."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from tripod_processor.io.packets import PayloadFileSource, PcapSource, open_source
from tripod_processor.io.pcap import PcapFormatError, PcapReader, PcapWriter


def _flatten(batches):
    data = [(int(t), bytes(p)) for b in batches for t, p in zip(b.host_ns, b.data)]
    others = sorted((t, p) for b in batches for t, p in b.others)
    return data, others


def _split(packets):
    return ([(t, p) for t, p in packets if len(p) == 1206],
            sorted((t, p) for t, p in packets if len(p) != 1206))


def test_pcap_batches_equal_the_packets_on_every_capture(velodyne_dir):
    n = 0
    for path in sorted(velodyne_dir.glob("*.pcap")):
        reader = PcapReader(path)
        per_packet = list(reader.payloads())
        stats_a = (reader.stats.records, reader.stats.udp, reader.stats.skipped,
                   reader.stats.truncated)
        batches = list(reader.payload_batches())
        stats_b = (reader.stats.records, reader.stats.udp, reader.stats.skipped,
                   reader.stats.truncated)
        assert stats_a == stats_b, path.name
        data = [(int(t), int(port), bytes(p)) for b in batches
                for t, port, p in zip(b.data_t_ns, b.data_port, b.data)]
        assert data == [d for d in per_packet if len(d[2]) == 1206], path.name
        assert sorted(o for b in batches for o in b.others) == sorted(
            d for d in per_packet if len(d[2]) != 1206), path.name
        n += len(data)
    assert n > 2000


def test_pcap_batches_slow_path_ports_and_cut(tmp_path, velodyne_dir):
    """Records off the plain path (VLAN tag) parsed in Python, the port filter, a cut file."""
    src = [(t, p) for t, _port, p in PcapReader(velodyne_dir / "rustlidar-vlp16.pcap").payloads()]
    path = tmp_path / "mixed.pcap"
    with PcapWriter(path) as w:
        for i, (t, p) in enumerate(src):
            w.write_udp(t, p, 2368, 2368 if i % 5 else 2369)
    raw = bytearray(path.read_bytes())
    # tag the first record's Ethernet frame with an 802.1Q VLAN header (4 bytes more)
    incl = struct.unpack_from("<I", raw, 24 + 8)[0]
    frame = raw[24 + 16 : 24 + 16 + incl]
    tagged = frame[:12] + b"\x81\x00\x00\x05" + frame[12:]
    rec = struct.pack("<IIII", *struct.unpack_from("<II", raw, 24), len(tagged), len(tagged))
    raw = raw[:24] + rec + tagged + raw[24 + 16 + incl :]
    path.write_bytes(bytes(raw[:-100]))  # and cut inside the last record
    for ports in (None, {2368}):
        a, b = PcapSource(path, ports), PcapSource(path, ports)
        per_packet, batches = list(a), list(b.batches())
        assert _flatten(batches) == _split(per_packet)
        assert a.report.skipped == b.report.skipped and a.report.truncated and b.report.truncated
    assert b.report.skipped.get("other_port", 0) == len([i for i in range(len(src)) if i % 5 == 0])
    data, _ = _flatten(batches)
    assert data[0] == (src[1][0], src[1][1])  # the VLAN record went through the slow path


def test_pcap_batches_corrupt_record_length(tmp_path, velodyne_dir):
    path = tmp_path / "bad.pcap"
    raw = bytearray((velodyne_dir / "rustlidar-vlp16.pcap").read_bytes())
    off = 24
    for _ in range(10):  # the 11th record claims 16 MB
        off += 16 + struct.unpack_from("<I", raw, off + 8)[0]
    struct.pack_into("<I", raw, off + 8, 1 << 24)
    path.write_bytes(bytes(raw))
    reader = PcapReader(path)
    got = []
    with pytest.raises(PcapFormatError, match="record 10 claims 16777216 bytes"):
        for b in reader.payload_batches():
            got.append(len(b.data) + len(b.others))
    assert sum(got) == 10


def test_payload_file_batches_unwrap_the_hour_like_iteration(tmp_path, velodyne_dir):
    payloads = [p for _t, _port, p in PcapReader(velodyne_dir / "rustlidar-vlp16.pcap").payloads()
                if len(p) == 1206]
    toh0 = struct.unpack_from("<I", payloads[0], 1200)[0]
    shift = 3_600_000_000 - 30_000 - toh0  # the hour ends 30 ms in
    rolled = [p[:1200] + struct.pack("<I", (struct.unpack_from("<I", p, 1200)[0] + shift)
                                     % 3_600_000_000) + p[1204:] for p in payloads]
    path = tmp_path / "payloads.bin"
    path.write_bytes(b"".join(rolled * 3) + b"\x00" * 7)  # and 7 trailing bytes
    src = open_source(path)
    assert isinstance(src, PayloadFileSource)
    per_packet = list(src)
    rep_a = (src.report.truncated, src.report.detail)
    batches = list(src.batches(max_data=50))  # batch edges inside the stream
    assert _flatten(batches) == _split(per_packet)
    assert (src.report.truncated, src.report.detail) == rep_a and rep_a[0]
    t = np.concatenate([b.host_ns for b in batches])
    assert len(t) == 3 * len(payloads) and (np.diff(t[: len(payloads)]) > 0).all()
