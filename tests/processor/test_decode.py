# SPDX-License-Identifier: BSD-3-Clause
"""Golden tests of ``tripod_processor.decode`` and ``tripod decode`` on real VLP-16 captures
(``../shared/data/velodyne/``, read in place) and on cut / junk input."""

from __future__ import annotations

import json
import re
import struct
import tracemalloc

import numpy as np
import pytest
import velodyne_decoder as vd
from tripod_processor.cli import main
from tripod_processor.io.clouds import read_ply
from tripod_processor.decode import (
    POINT_DTYPE,
    DecodeConfig,
    DecodeError,
    FrameDecoder,
    NativeVlp16Decoder,
    decode_file,
    identify_sensor,
    to_veloview_xyz,
)
from tripod_processor.io.pcap import PcapReader, PcapWriter
from vd_oracle import VelodyneDecoderOracle

ISSUE_KEYS = ["frames", "points_per_frame", "sensor", "return_mode", "packets", "skipped"]


def _parse_veloview_expected(path):
    """frame_count, {frame: point_count}, {frame: [(index, x, y, z, intensity, last)]}."""
    counts, points, frame, total = {}, {}, None, None
    for line in path.read_text().splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "frame_count":
            total = int(tok[1])
        elif tok[0] == "frame":
            frame = int(tok[1])
        elif tok[0] == "point_count":
            counts[frame] = int(tok[1])
        elif tok[0] == "point_values":
            points.setdefault(frame, []).append(
                (int(tok[1]), *map(float, tok[2:5]), int(tok[5]), int(tok[6])))
    return total, counts, points


def _data_payloads(path):
    return [(t, p) for t, _port, p in PcapReader(path).payloads() if len(p) == 1206]


def _block_azimuths(payloads):
    a = np.frombuffer(b"".join(p[:1200] for _, p in payloads), np.uint8).reshape(-1, 12, 100)
    return (a[:, :, 2].astype(np.int64) | (a[:, :, 3].astype(np.int64) << 8)).ravel()


def _cli(capsys, *args):
    code = main(["decode", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------------------------------------
# issue 2, item 6: the golden tests
# ---------------------------------------------------------------------------------------------
def test_veloview_vlp16_reproduces_veloview_oracle(velodyne_dir):
    total, counts, points = _parse_veloview_expected(
        velodyne_dir / "veloview-vlp16-20hz.expected.txt")
    frames = list(decode_file(velodyne_dir / "veloview-vlp16-20hz.pcap"))
    assert total == 52 and len(frames) == total
    for f, n in counts.items():
        assert len(frames[f]) == n, f"frame {f}"
    # VeloView's axes and firing-level azimuth (see to_veloview_xyz): the block azimuth step
    # of the capture, measured from the packets themselves
    az = _block_azimuths(_data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap"))
    d = np.diff(az)
    step_deg = float(np.median(d[d > 0])) / 100
    assert points
    for f, rows in points.items():
        xyz = to_veloview_xyz(frames[f].points, step_deg)
        for idx, x, y, z, intensity, _last in rows:
            assert np.linalg.norm(xyz[idx] - (x, y, z)) < 1e-3, (f, idx, xyz[idx])
            assert frames[f].points["intensity"][idx] == intensity
            # (the oracle's last column is not compared: it reads 0 for both points, but the
            # last one is the +15° laser by its z and intensity, i.e. laser 15 in firing order)


def test_veloview_vlp16_points_are_velodyne_decoders(velodyne_dir):
    """Frame splitting loses, adds and moves no point: the frames hold exactly the points of
    velodyne-decoder's own decode of the same packets, in the same order."""
    path = velodyne_dir / "veloview-vlp16-20hz.pcap"
    frames = list(decode_file(path, DecodeConfig(chunk_packets=100)))
    ours = np.concatenate([f.points for f in frames])
    sd = vd.ScanDecoder(vd.Config(model=vd.Model.VLP16, min_range=0.001,
                                  calibration=vd.calibrations.get_bundled_calibration(
                                      "VLP-16.yml")))
    pv = vd.PacketVector()
    for t, p in _data_payloads(path):
        pv.append(vd.VelodynePacket(t * 1e-9, p[:-1] + b"\x22"))
    ref = sd.decode(pv, as_pcl_structs=True)[1]
    assert len(ours) == len(ref) == 700400
    for k in ("x", "y", "z", "ring"):
        np.testing.assert_array_equal(ours[k], ref[k])
    # per-point time: offsets grow within a frame and follow the 2.304 µs firing pitch
    for f in frames[1:-1]:
        t = f.points["time_offset_ns"].astype(np.int64)
        assert t.min() >= -1000 and np.all(np.diff(t) > 0)
        assert 0.045e9 < t.max() < 0.055e9  # 20 Hz rotation


def test_mrpt_vlp16_gps_four_rotations_and_position_packets(velodyne_dir):
    run = decode_file(velodyne_dir / "mrpt-vlp16-gps.pcap")
    frames = list(run)
    rep = run.report
    assert rep.rotations == 4  # MRPT's test expects 4 scans (rotations closed by a wrap)
    assert len(frames) == 5  # plus the partial rotation at the end
    assert rep.sensor == "VLP-16" and rep.product_id == 0x22 and rep.packets == 293
    pos = rep.position
    assert pos.packets == 57 and pos.nmea == {"GPRMC": 57}  # every checksum valid
    assert pos.pps == {"locked": 57}
    assert pos.fixes == 57
    assert pos.first_utc.startswith("2016-01-21T08:18:")
    lon, lat, _alt = pos.first_position
    assert lat == pytest.approx(36.8291309, abs=1e-6)
    assert lon == pytest.approx(-2.4075715, abs=1e-6)


def test_rustlidar_vlp16_id0x21_decodes_as_vlp16(velodyne_dir):
    run = decode_file(velodyne_dir / "rustlidar-vlp16-id0x21.pcap")
    frames = list(run)
    assert run.report.sensor == "VLP-16" and run.report.product_id == 0x21
    assert run.report.packet_period_us == pytest.approx(1327, abs=2)
    assert run.report.packets == 84 and len(frames) >= 1
    pts = np.concatenate([f.points for f in frames])
    assert len(pts) > 15000 and np.isfinite(pts["x"]).all()
    assert set(np.unique(pts["ring"])) == set(range(16))
    r = np.hypot(pts["x"], pts["y"])
    assert (np.abs(np.degrees(np.arctan2(pts["z"], r))) < 15.5).all()  # VLP-16 ±15° fan


def test_mrpt_hdl32e_refused_naming_the_sensor(velodyne_dir, capsys):
    with pytest.raises(DecodeError, match="HDL-32E"):
        list(decode_file(velodyne_dir / "mrpt-hdl32e.pcap"))
    code, out, err = _cli(capsys, velodyne_dir / "mrpt-hdl32e.pcap", "--summary")
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "HDL-32E" in err and "Traceback" not in err


def test_identify_sensor_by_product_and_period():
    assert identify_sensor(0x22, 0x37, None) == "VLP-16"
    assert identify_sensor(0x21, 0x37, 1327.1) == "VLP-16"
    assert identify_sensor(0x21, 0x39, 663.6) == "VLP-16"  # dual return
    with pytest.raises(DecodeError, match="HDL-32E"):
        identify_sensor(0x21, 0x37, 553.0)
    with pytest.raises(DecodeError, match="VLP-32C"):
        identify_sensor(0x28, 0x37, 553.0)


def test_scanparser_vlp16_gaps_reported(velodyne_dir, capsys):
    code, out, err = _cli(capsys, velodyne_dir / "scanparser-vlp16-gaps.pcap", "--summary")
    assert code == 0
    s = json.loads(out)
    assert s["packets"] == 41 and s["gaps"]["count"] == 2
    assert s["gaps"]["max_s"] == pytest.approx(0.157, abs=0.002)
    for g in s["gaps"]["list"]:
        assert g["duration_s"] > 0.1 and g["missing_packets"] > 100
    assert s["position"]["nmea"] == {"GPRMC": 36}
    assert s["truncated"] and "warning" in err  # this capture itself ends mid-record


def test_cut_pcap_keeps_every_whole_packet_and_warns(velodyne_dir, tmp_path, capsys):
    data = (velodyne_dir / "veloview-vlp16-20hz.pcap").read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) // 3 + 700])  # ends inside a record
    whole = sum(1 for _, p in _data_payloads(cut))
    r = PcapReader(cut)
    list(r)
    assert r.stats.truncated and whole > 600
    code, out, err = _cli(capsys, cut, "--summary")
    assert code == 0
    s = json.loads(out)
    assert s["packets"] == whole and s["truncated"]
    assert sum(s["points_per_frame"]) == s["points"] > 0
    assert re.search(r"tripod: warning: .*cut short", err)


@pytest.mark.parametrize("content", [b"", bytes(np.random.default_rng(7).integers(
    0, 256, 50_000, dtype=np.uint8)), b"\xd4\xc3\xb2\xa1" + b"\x00" * 10])
def test_junk_or_empty_file_one_line_error(tmp_path, capsys, content):
    p = tmp_path / "input.pcap"
    p.write_bytes(content)
    code, out, err = _cli(capsys, p, "--summary")
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tripod: error:") and "Traceback" not in err


def test_missing_file_and_bad_option_one_line_error(tmp_path, capsys):
    code, _out, err = _cli(capsys, tmp_path / "nope.pcap", "--summary")
    assert code == 2 and err.strip().count("\n") == 0 and "no such file" in err
    code, _out, err = _cli(capsys, tmp_path / "nope.pcap", "--summary", "--sensor", "HDL-64")
    assert code == 2 and err.strip().count("\n") == 0 and "sensor" in err


# ---------------------------------------------------------------------------------------------
# item 5: inputs, outputs, summary, streaming
# ---------------------------------------------------------------------------------------------
def test_summary_json_has_the_issue_keys(velodyne_dir, capsys):
    code, out, _err = _cli(capsys, velodyne_dir / "veloview-vlp16-20hz.pcap", "--summary")
    assert code == 0 and out.count("\n") == 1
    s = json.loads(out)
    assert list(s)[: len(ISSUE_KEYS)] == ISSUE_KEYS
    assert s["frames"] == 52 == len(s["points_per_frame"])
    assert s["sensor"] == "VLP-16" and s["return_mode"] == "strongest"
    assert s["packets"] == 1902 and s["skipped"] == {}
    assert s["rotations"] == 51 and s["position"]["packets"] == 367


def test_payload_file_pcap_and_mcap_decode_alike(velodyne_dir, tmp_path):
    """The three kinds of input give the same frames from the same packets."""
    from tripod_shared.recording import RecordingWriter

    raw = (velodyne_dir / "vlp16go-1000-payloads.bin").read_bytes()
    payloads = [raw[i : i + 1206] for i in range(0, len(raw), 1206)]
    t0 = 1_700_000_000_000_000_000
    pcap, mcap = tmp_path / "p.pcap", tmp_path / "p.mcap"
    with PcapWriter(pcap) as w, RecordingWriter(mcap) as m:
        for i, p in enumerate(payloads):
            w.write_udp(t0 + i * 1_327_104, p, 2368, 2368)
            m.write_lidar_packet(t0 + i * 1_327_104, p)
    results = []
    for path in (velodyne_dir / "vlp16go-1000-payloads.bin", pcap, mcap):
        run = decode_file(path)
        frames = list(run)
        assert run.report.packets == 1000 and run.report.rotations == 13
        results.append(frames)
    kinds = [decode_file(p).source.kind for p in (velodyne_dir / "vlp16go-1000-payloads.bin",
                                                   pcap, mcap)]
    assert kinds == ["payloads", "pcap", "mcap"]
    for a, b in zip(results[0], results[1]):
        np.testing.assert_array_equal(a.points, b.points)
    for b, c in zip(results[1], results[2]):
        np.testing.assert_array_equal(b.points, c.points)
        assert b.stamp_host_ns == c.stamp_host_ns and b.stamp_device_ns == c.stamp_device_ns


def test_ply_frames_written_and_readable(velodyne_dir, tmp_path, capsys):
    out = tmp_path / "out"
    code, _o, _e = _cli(capsys, velodyne_dir / "rustlidar-vlp16.pcap", "-o", out, "-q")
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    files = sorted(out.glob("frame_*.ply"))
    assert len(files) == s["frames"] == 2
    for f, n in zip(files, s["points_per_frame"]):
        cloud = read_ply(f)
        assert cloud.dtype.names == POINT_DTYPE.names and len(cloud) == n
        assert b"stamp_device_ns" in f.read_bytes()[:600]
    assert "calibration" in (out / "decode_config.yaml").read_text()


def _repeat_capture(payloads, times):
    """The capture's packets ``times`` over, device time running on: a long stream."""
    toh0 = struct.unpack_from("<I", payloads[0][1], 1200)[0]
    toh1 = struct.unpack_from("<I", payloads[-1][1], 1200)[0]
    span_us = toh1 - toh0 + 1327
    for r in range(times):
        for t, p in payloads:
            toh = (struct.unpack_from("<I", p, 1200)[0] + r * span_us) % 3_600_000_000
            yield t + r * span_us * 1000, p[:1200] + struct.pack("<I", toh) + p[1204:]


def test_constant_memory_on_a_long_stream(velodyne_dir):
    payloads = _data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap")
    dec = FrameDecoder(DecodeConfig())
    tracemalloc.start()
    n_points = n_frames = 0
    for frame in dec.decode(_repeat_capture(payloads, 8)):
        n_points += len(frame)
        n_frames += 1
    _cur, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert dec.report.packets == 8 * len(payloads) and n_frames > 8 * 50
    held_if_buffered = n_points * POINT_DTYPE.itemsize
    assert n_points > 5_000_000
    assert peak < 40e6 < held_if_buffered  # a few frames and one chunk, whatever the length


def test_dual_return_frames(velodyne_dir):
    """Dual-return packets (block pairs share an azimuth; 664 µs period) split like single."""
    single = _data_payloads(velodyne_dir / "mrpt-vlp16-gps.pcap")

    def dualize(i, t, p):
        out = bytearray()
        for k in range(6):  # blocks 2k, 2k+1 of a pair: same azimuth, last + strongest
            blk = p[(2 * k) * 100 : (2 * k + 1) * 100]
            second = bytearray(blk)
            second[4::3] = bytes((b + 1) % 256 for b in blk[4::3])  # other distances
            out += blk + bytes(second)
        toh = struct.unpack_from("<I", single[0][1], 1200)[0] + round(i * 663.552)
        return t, bytes(out) + struct.pack("<I", toh) + b"\x39\x22"

    packets = [dualize(i, t, p) for i, (t, p) in enumerate(single)]
    dec = FrameDecoder()
    frames = list(dec.decode(packets))
    rep = dec.report
    assert rep.return_mode == "dual" and rep.sensor == "VLP-16"
    assert rep.packet_period_us == pytest.approx(663.5, abs=1)
    pts = np.concatenate([f.points for f in frames])
    assert set(np.unique(pts["return_type"])) <= {1, 2, 3} and len(pts) > 0
    # every block azimuth wrap is one rotation; with half the blocks per packet kept
    az = _block_azimuths(packets)
    assert rep.rotations == int((np.diff(az) < 0).sum()) and len(frames) == rep.rotations + 1
    for f in frames:
        t = f.points["time_offset_ns"].astype(np.int64)
        assert t.min() >= -1000 and np.all(np.diff(t) >= 0)


def test_long_silence_starts_a_new_frame(velodyne_dir):
    payloads = _data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap")
    cut_from, cut_to = 500, 700  # 200 packets = 0.27 s of silence, mid-rotation
    kept = payloads[:cut_from] + payloads[cut_to:]
    dec = FrameDecoder()
    frames = list(dec.decode(kept))
    az = _block_azimuths(kept)
    splits = set(np.flatnonzero(np.diff(az) < 0) + 1) | {cut_from * 12}
    assert len(frames) == len(splits) + 1
    assert dec.report.gap_count == 1 and dec.report.missing_packets == cut_to - cut_from
    assert sum(len(f) for f in frames) == dec.report.points


def test_out_of_order_packets_decode_packet_by_packet(velodyne_dir):
    payloads = _data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap")
    shuffled = list(payloads)
    shuffled[300], shuffled[301] = shuffled[301], shuffled[300]
    ref = FrameDecoder()
    n_ref = sum(len(f) for f in ref.decode(payloads))
    dec = FrameDecoder()
    frames = list(dec.decode(shuffled))
    assert sum(len(f) for f in frames) == n_ref == 700400
    assert any("backwards" in w for w in dec.report.warnings)
    pts = np.concatenate([f.points for f in frames])
    assert np.isfinite(pts["x"]).all() and np.abs(pts["time_offset_ns"]).max() < 0.2e9


def test_mcap_cut_short_keeps_whole_packets(velodyne_dir, tmp_path, capsys):
    from tripod_shared.recording import RecordingWriter

    payloads = _data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap")
    rec = tmp_path / "r.mcap"
    with RecordingWriter(rec, chunk_size=64 * 1024) as w:
        for t, p in payloads:
            w.write_lidar_packet(t, p)
    data = rec.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    code, out, err = _cli(capsys, cut, "--summary")
    assert code == 0
    s = json.loads(out)
    assert s["truncated"] and 0 < s["packets"] < len(payloads) and "cut short" in err
    assert s["input_format"] == "mcap"


def test_device_clock_unwraps_at_the_top_of_the_hour(velodyne_dir):
    """Shift the lidar clock so the hour rolls over mid-capture: same frames, time running on."""
    payloads = _data_payloads(velodyne_dir / "veloview-vlp16-20hz.pcap")
    toh0 = struct.unpack_from("<I", payloads[0][1], 1200)[0]
    shift = 3_600_000_000 - 1_000_000 - toh0  # the hour ends 1 s into the capture
    rolled = [(t, p[:1200] + struct.pack("<I", (struct.unpack_from("<I", p, 1200)[0] + shift)
                                          % 3_600_000_000) + p[1204:]) for t, p in payloads]
    ref = list(FrameDecoder().decode(payloads))
    dec = FrameDecoder()
    got = list(dec.decode(rolled))
    assert [len(f) for f in got] == [len(f) for f in ref]
    stamps = np.array([f.stamp_device_ns for f in got])
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(stamps) < 0.06e9)
    for a, b in zip(ref, got):
        np.testing.assert_array_equal(a.points["time_offset_ns"], b.points["time_offset_ns"])
    assert dec.report.gap_count == 0 and not dec.report.warnings


def _write_pcapng(path, frames_ns):
    """Minimal little-endian pcapng: section header, one Ethernet interface (ns resolution),
    one enhanced packet block per (t_ns, ethernet frame)."""
    def block(btype, body):
        body += b"\x00" * (-len(body) % 4)
        n = len(body) + 12
        return struct.pack("<II", btype, n) + body + struct.pack("<I", n)

    with open(path, "wb") as fh:
        fh.write(block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)))
        tsresol = struct.pack("<HHB3x", 9, 1, 9) + struct.pack("<HH", 0, 0)
        fh.write(block(1, struct.pack("<HHI", 1, 0, 65535) + tsresol))
        for t, frame in frames_ns:
            fh.write(block(6, struct.pack("<IIIII", 0, t >> 32, t & 0xFFFFFFFF, len(frame),
                                          len(frame)) + frame))


def test_pcapng_decodes_like_pcap(velodyne_dir, tmp_path):
    src = velodyne_dir / "rustlidar-vlp16.pcap"
    raw = src.read_bytes()
    frames, off = [], 24  # the Ethernet frames of the classic pcap, with their times
    while off + 16 <= len(raw):
        sec, usec, incl, _ = struct.unpack_from("<IIII", raw, off)
        frames.append((sec * 10**9 + usec * 1000, raw[off + 16 : off + 16 + incl]))
        off += 16 + incl
    ng = tmp_path / "c.pcapng"
    _write_pcapng(ng, frames)
    a, b = decode_file(src), decode_file(ng)
    fa, fb = list(a), list(b)
    assert b.source.kind == "pcapng" and len(fa) == len(fb) == 2
    for x, y in zip(fa, fb):
        np.testing.assert_array_equal(x.points, y.points)
        assert x.stamp_host_ns == y.stamp_host_ns


# ---------------------------------------------------------------------------------------------
# issue 15, item 6: bugs found by trying it
# ---------------------------------------------------------------------------------------------
def _pcap_records(raw):
    """(offset, length) of each record of a little-endian classic pcap."""
    out, off = [], 24
    while off + 16 <= len(raw):
        incl = struct.unpack_from("<I", raw, off + 8)[0]
        out.append((off, 16 + incl))
        off += 16 + incl
    return out


def test_refused_input_leaves_no_output_folder(velodyne_dir, tmp_path, capsys):
    out = tmp_path / "out"
    code, _out, err = _cli(capsys, velodyne_dir / "mrpt-hdl32e.pcap", "-o", out)
    assert code == 2 and "HDL-32E" in err
    assert not out.exists()  # no decode_config.yaml left behind in a fresh folder


def test_reused_output_folder_describes_the_new_run(velodyne_dir, tmp_path, capsys):
    out = tmp_path / "out"
    assert _cli(capsys, velodyne_dir / "mrpt-vlp16-gps.pcap", "-o", out, "-q")[0] == 0
    first = sorted(p.name for p in out.glob("frame_*.ply"))
    assert len(first) == json.loads((out / "summary.json").read_text())["frames"] == 5
    (out / "notes.txt").write_text("mine")
    code, _out, err = _cli(capsys, velodyne_dir / "rustlidar-vlp16.pcap", "-o", out, "-q")
    assert code == 0 and "removed 5 frame files" in err
    s = json.loads((out / "summary.json").read_text())
    assert sorted(p.name for p in out.glob("frame_*")) == [
        f"frame_{i:06d}.ply" for i in range(s["frames"])] and s["frames"] == 2
    assert (out / "notes.txt").read_text() == "mine"  # not the decoder's: kept
    # a refused input keeps the earlier run's output whole
    assert _cli(capsys, velodyne_dir / "mrpt-hdl32e.pcap", "-o", out)[0] == 2
    assert json.loads((out / "summary.json").read_text()) == s


def test_forced_sensor_warns_when_the_packet_period_says_otherwise(velodyne_dir, capsys):
    code, out, err = _cli(capsys, velodyne_dir / "mrpt-hdl32e.pcap", "--summary",
                          "--sensor", "VLP-16")
    assert code == 0 and json.loads(out)["sensor"] == "VLP-16"
    assert re.search(r"tripod: warning: .*'VLP-16' was forced.* every 55\d µs", err)
    code, out, err = _cli(capsys, velodyne_dir / "mrpt-vlp16-gps.pcap", "--summary",
                          "--sensor", "VLP-16")
    assert code == 0 and "forced" not in err  # a VLP-16 forced as VLP-16: no doubt


def test_folder_as_input_is_named_a_folder(tmp_path, capsys):
    code, out, err = _cli(capsys, tmp_path, "--summary")
    assert code == 2 and out == ""
    assert err.strip() == f"tripod: error: {tmp_path}: a folder, not a capture file"


def test_corrupt_record_error_names_the_file_once(velodyne_dir, tmp_path, capsys):
    raw = bytearray((velodyne_dir / "veloview-vlp16-20hz.pcap").read_bytes())
    off, _n = _pcap_records(raw)[1500]  # past the sensor detection and the first batch
    struct.pack_into("<I", raw, off + 8, 10**8)  # a record that claims 100 MB
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(bytes(raw))
    out = tmp_path / "out"
    code, _out, err = _cli(capsys, bad, "-o", out, "-q")
    assert code == 2 and err.count(str(bad)) == 1, err
    assert "claims 100000000 bytes" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()  # the frames written before the corrupt record went again


def test_cut_pcapng_is_called_a_pcapng_block(velodyne_dir, tmp_path, capsys):
    raw = (velodyne_dir / "rustlidar-vlp16.pcap").read_bytes()
    ng = tmp_path / "c.pcapng"
    _write_pcapng(ng, [(struct.unpack_from("<I", raw, o)[0] * 10**9, raw[o + 16 : o + n])
                       for o, n in _pcap_records(raw)])
    data = ng.read_bytes()
    ng.write_bytes(data[: len(data) - 500])
    code, out, err = _cli(capsys, ng, "--summary")
    assert code == 0 and json.loads(out)["truncated"]
    assert "ends inside a pcapng block" in err and "pcap record" not in err


def test_azimuth_filter_keeps_the_view_width(velodyne_dir, capsys):
    path = velodyne_dir / "mrpt-vlp16-gps.pcap"
    full = np.concatenate([f.points for f in decode_file(path)])

    def points(lo, hi, batch_decoder=NativeVlp16Decoder):
        cfg = DecodeConfig(azimuth_min_deg=lo, azimuth_max_deg=hi)
        return np.concatenate([f.points for f in decode_file(path, cfg,
                                                             batch_decoder=batch_decoder)])

    def azimuth_deg(p):  # the sensor's azimuth: 0 along +x, clockwise seen from above
        return np.degrees(np.arctan2(-p["y"], p["x"])) % 360

    # a range within one turn: velodyne-decoder's filter, point for point
    a, b = points(0, 180), points(0, 180, VelodyneDecoderOracle)
    np.testing.assert_array_equal(a[["x", "y", "z", "intensity", "ring"]],
                                  b[["x", "y", "z", "intensity", "ring"]])
    # (a laser's own azimuth offset puts a few returns up to ~1.5 deg past the block's)
    assert 0.3 * len(full) < len(a) < 0.7 * len(full)
    az = azimuth_deg(a)
    assert ((az <= 182) | (az >= 358)).all()
    # across 0: the front half (x >= 0), which velodyne-decoder cannot give
    front = points(270, 90)
    az = azimuth_deg(front)
    assert ((az <= 92) | (az >= 268)).all() and (front["x"] > -0.1).all()
    assert 0.3 * len(full) < len(front) < 0.7 * len(full)
    with pytest.raises(DecodeError, match="cannot keep an azimuth range across 0"):
        points(270, 90, VelodyneDecoderOracle)
    code, out, _err = _cli(capsys, path, "--summary", "--azimuth-min", "270",
                           "--azimuth-max", "90")
    assert code == 0 and json.loads(out)["points"] == len(front)
    code, _out, err = _cli(capsys, path, "--summary", "--azimuth-min", "-5")
    assert code == 2 and "azimuth_min_deg" in err
