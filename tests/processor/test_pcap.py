# SPDX-License-Identifier: BSD-3-Clause
"""pcap reader/writer: real captures, round trip, cut files, junk."""

import pytest

from tripod_processor.io.pcap import PcapFormatError, PcapReader, PcapWriter


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


@pytest.mark.parametrize("name", ["veloview-vlp16-20hz.pcap", "mrpt-vlp16-gps.pcap",
                                  "scanparser-vlp16-gaps.pcap", "mrpt-hdl32e.pcap"])
def test_payloads_fast_path_matches_iteration(velodyne_dir, name):
    r = PcapReader(velodyne_dir / name)
    slow = [(d.t_ns, d.dst_port, d.payload) for d in r]
    slow_stats = (r.stats.records, r.stats.udp, dict(r.stats.skipped), r.stats.truncated)
    fast = list(r.payloads())
    assert fast == slow and len(fast) > 0
    assert (r.stats.records, r.stats.udp, dict(r.stats.skipped), r.stats.truncated) == slow_stats


def test_payloads_fast_path_on_cut_and_corrupt_files(tmp_path):
    p = tmp_path / "w.pcap"
    with PcapWriter(p) as w:
        for i in range(3000):  # > 1 MiB: crosses the reader's block boundary
            w.write_udp(1_000 + i, bytes([i % 256]) * 1206, 2368, 2368)
    data = p.read_bytes()
    r = PcapReader(p)
    assert [len(x[2]) for x in r.payloads()] == [1206] * 3000 and not r.stats.truncated
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[:-500])
    r = PcapReader(cut)
    assert len(list(r.payloads())) == 2999 and r.stats.truncated
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(data[:24] + b"\x00" * 8 + b"\xff\xff\xff\x7f" * 2 + data[40:])
    with pytest.raises(PcapFormatError, match="corrupt"):
        list(PcapReader(bad).payloads())
