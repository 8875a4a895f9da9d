# SPDX-License-Identifier: BSD-3-Clause
"""pcap reader/writer: real captures, round trip, cut files, junk."""

import pytest

from tripod_processor.pcap import PcapFormatError, PcapReader, PcapWriter


def test_veloview_counts(velodyne_dir):
    r = PcapReader(velodyne_dir / "veloview-vlp16-20hz.pcap")
    ds = list(r)
    assert sum(1 for d in ds if d.dst_port == 2368 and len(d.payload) == 1206) == 1902
    assert sum(1 for d in ds if d.dst_port == 8308 and len(d.payload) == 512) == 367
    assert not r.stats.truncated
    assert all(b.t_ns >= a.t_ns for a, b in zip(ds, ds[1:]))


def test_round_trip_and_cut(tmp_path):
    p = tmp_path / "w.pcap"
    payloads = [bytes([i % 256]) * (1206 if i % 3 else 512) for i in range(100)]
    with PcapWriter(p) as w:
        for i, pl in enumerate(payloads):
            w.write_udp(1_600_000_000_000_000_000 + i * 1327, pl, 2368, 2368 if len(pl) == 1206 else 8308)
    got = list(PcapReader(p))
    assert [d.payload for d in got] == payloads
    assert got[5].t_ns == 1_600_000_000_000_000_000 + 5 * 1327
    assert got[0].src == "192.168.1.201"
    data = p.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) - 100])
    r = PcapReader(cut)
    kept = list(r)
    assert r.stats.truncated and [d.payload for d in kept] == payloads[: len(kept)] and len(kept) == 99


@pytest.mark.parametrize("content", [b"", b"\x13\x37" * 500])
def test_not_a_pcap(tmp_path, content):
    p = tmp_path / "junk.pcap"
    p.write_bytes(content)
    with pytest.raises(PcapFormatError):
        PcapReader(p)
