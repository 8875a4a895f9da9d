# SPDX-License-Identifier: BSD-3-Clause
"""The native batch VLP-16 decoder (``tripod_processor.decode.native``) against its oracle,
velodyne-decoder 3.1: the same points, bit for bit, on every real VLP-16 capture in
``../shared/data/velodyne/``, with every calibration kind, in strongest, last and dual return,
with range and angle filters, and on malformed packets."""

from __future__ import annotations

import json

import numpy as np
import pytest
import velodyne_decoder as vd
from tripod_processor.decode import DecodeConfig, DecodeError, FrameDecoder, identify_sensor
from tripod_processor.decode.native import (
    POINT_DTYPE,
    STATUS_BAD_BLOCK_HEADER,
    STATUS_OK,
    CalibrationError,
    NativeVlp16Decoder,
    calibration_table,
)
from tripod_processor.io.packets import open_source
from vd_oracle import VelodyneDecoderOracle

_PRODUCT = {vd.Model.VLP16: 0x22, vd.Model.PuckHiRes: 0x24}


def _packets(path):
    """(N, 1206) uint8 data packets and (N,) int64 host stamps [ns] of any supported input."""
    pk = [(t, p) for t, p in open_source(path) if len(p) == 1206]
    return (np.frombuffer(b"".join(p for _, p in pk), np.uint8).reshape(-1, 1206).copy(),
            np.array([t for t, _ in pk], np.int64))


def _vd_decode(packets, stamps_ns, calibration, model=vd.Model.VLP16, min_range=0.001,
               max_range=200.0, min_angle=0.0, max_angle=360.0):
    """velodyne-decoder's ScanDecoder on the same packets (product byte set to the model's:
    it refuses others), stamped with the same host seconds."""
    cfg = vd.Config(model=model, calibration=calibration, min_range=min_range,
                    max_range=max_range, timestamp_first_packet=True)
    cfg.min_angle, cfg.max_angle = min_angle, max_angle
    pv = vd.PacketVector()
    tail = bytes([_PRODUCT[model]])
    for t, p in zip(stamps_ns.tolist(), packets):
        pv.append(vd.VelodynePacket(t * 1e-9, p.tobytes()[:-1] + tail))
    return vd.ScanDecoder(cfg).decode(pv, as_pcl_structs=True)[1]


def _native_decode(packets, stamps_ns, calibration, model=vd.Model.VLP16, min_range=0.001,
                   max_range=200.0, min_angle=0.0, max_angle=360.0, num_threads=1):
    dec = NativeVlp16Decoder(calibration, model=model, min_range_m=min_range,
                             max_range_m=max_range, min_angle_deg=min_angle,
                             max_angle_deg=max_angle, num_threads=num_threads)
    return dec.decode(packets, stamps_ns, with_time_s=True)


def _assert_same(batch, ref):
    """Bit-equal points in the same order; intensity as POINT_DTYPE's uint8 of the float."""
    ours = batch.points
    assert ours.dtype == POINT_DTYPE
    assert len(ours) == len(ref)
    for k in ("x", "y", "z", "ring", "return_type"):
        np.testing.assert_array_equal(ours[k], ref[k], err_msg=k)
    np.testing.assert_array_equal(batch.time_s, ref["time"], err_msg="time")
    np.testing.assert_array_equal(ours["intensity"], ref["intensity"].astype(np.uint8))
    # the channel: a VLP-16 packet's 32 returns per block are two firings of lasers 0..15
    assert ours["laser"].max(initial=0) < 16


def _assert_equal(packets, stamps_ns, calibration, **kw):
    ref = _vd_decode(packets, stamps_ns, calibration, **kw)
    batch = _native_decode(packets, stamps_ns, calibration, **kw)
    _assert_same(batch, ref)
    return batch, ref


def _is_vlp16(packets, stamps_ns):
    products = packets[:, 1205].tolist()
    product = max(set(products), key=products.count)
    toh = packets[:, 1200:1204].copy().view("<u4").ravel().astype(np.int64)
    d = np.diff(toh)
    d = d[(d > 0) & (d < 100_000)]
    try:
        identify_sensor(product, int(packets[0, 1204]), float(np.median(d)) if len(d) else None)
    except DecodeError:
        return False
    return True


_VELOVIEW = vd.calibrations.get_bundled_calibration("VLP-16.yml")


# ---------------------------------------------------------------------------------------------
def test_equal_to_velodyne_decoder_on_every_real_vlp16_capture(velodyne_dir):
    compared = []
    for path in sorted(velodyne_dir.iterdir()):
        if path.suffix not in (".pcap", ".pcapng", ".bin"):
            continue
        packets, stamps = _packets(path)
        if not len(packets) or not _is_vlp16(packets, stamps):
            continue  # the HDL-32E capture: not a 16-laser sensor
        batch, ref = _assert_equal(packets, stamps, _VELOVIEW)
        assert (batch.status == STATUS_OK).all()
        compared.append((path.name, len(ref)))
    names = [n for n, _ in compared]
    assert "veloview-vlp16-20hz.pcap" in names and "vlp16go-1000-payloads.bin" in names
    assert len(compared) >= 6 and all(n > 10_000 for _, n in compared)
    assert dict(compared)["veloview-vlp16-20hz.pcap"] == 700400


@pytest.mark.parametrize("model", [vd.Model.VLP16, vd.Model.PuckHiRes])
@pytest.mark.parametrize("kind", ["bundled", "builtin"])
def test_equal_with_each_calibration(velodyne_dir, model, kind):
    """Bundled VeloView angles (the simple model) and velodyne-decoder's built-in tables (with
    per-laser vertical offsets: the full correction model)."""
    packets, stamps = _packets(velodyne_dir / "mrpt-vlp16-gps.pcap")
    name = {vd.Model.VLP16: "VLP-16.yml", vd.Model.PuckHiRes: "Puck Hi-Res.yml"}[model]
    cal = (vd.calibrations.get_bundled_calibration(name) if kind == "bundled"
           else vd.Calibration.default_calibs[model])
    _assert_equal(packets, stamps, cal, model=model)


def test_equal_with_a_full_correction_calibration(velodyne_dir):
    """Distance, two-point, offset and intensity corrections: the whole 'advanced' branch of
    velodyne-decoder's unpackPoint, intensity clamped to [min, max]. The two-point correction
    (lasers with both dist_correction_x and _y set) agrees to one float32 ulp (<= 2 µm here)
    on a few points in a thousand and exactly on the rest; everything else is bit-equal."""
    lasers = []
    for i, vert in enumerate(calibration_table(_VELOVIEW)[0][:, 1]):
        two_pt = i % 2 == 1
        lasers.append(
            f"  - laser_id: {i}\n    rot_correction: {0.001 * (i - 8)}\n"
            f"    vert_correction: {vert}\n    dist_correction: {0.01 + 0.002 * i}\n"
            f"    dist_correction_x: {0.02 - 0.001 * i if two_pt else 0}\n"
            f"    dist_correction_y: {0.015 if two_pt else 0}\n"
            f"    vert_offset_correction: {0.004 * (i % 3)}\n"
            f"    horiz_offset_correction: {0.03 if i % 4 == 0 else -0.02}\n"
            f"    max_intensity: {200 + i}\n    min_intensity: {i}\n"
            f"    focal_distance: {10 + 3 * i}\n    focal_slope: {0.5 + 0.1 * i}\n")
    cal = vd.Calibration.from_string(
        "distance_resolution: 0.002\nnum_lasers: 16\nlasers:\n" + "".join(lasers))
    packets, stamps = _packets(velodyne_dir / "rustlidar-vlp16.pcap")
    ref = _vd_decode(packets, stamps, cal)
    batch = _native_decode(packets, stamps, cal)
    ours = batch.points
    assert len(ours) == len(ref) > 10_000
    two_pt = ours["laser"] % 2 == 1
    for k in ("x", "y", "z"):
        np.testing.assert_array_equal(ours[k][~two_pt], ref[k][~two_pt], err_msg=k)
        np.testing.assert_allclose(ours[k], ref[k], rtol=0, atol=2e-6, err_msg=k)
        assert (ours[k] != ref[k]).mean() < 0.005
    for k in ("ring", "return_type"):
        np.testing.assert_array_equal(ours[k], ref[k])
    np.testing.assert_array_equal(batch.time_s, ref["time"])
    np.testing.assert_array_equal(ours["intensity"], ref["intensity"].astype(np.uint8))
    assert (ref["intensity"] != np.floor(ref["intensity"])).any()  # fractions: truncated
    assert ref["intensity"].max() > 200 and ref["intensity"].min() >= 0


def test_equal_with_range_and_angle_filters(velodyne_dir):
    packets, stamps = _packets(velodyne_dir / "veloview-vlp16-20hz.pcap")
    packets, stamps = packets[:400], stamps[:400]
    full = _native_decode(packets, stamps, _VELOVIEW)
    for kw in ({"min_range": 1.5, "max_range": 8.0},  # indoor walls at a few metres
               {"min_angle": 90.0, "max_angle": 270.0},
               {"min_angle": 300.0, "max_angle": 359.99}, {"min_angle": 0.0, "max_angle": 60.0}):
        batch, _ref = _assert_equal(packets, stamps, _VELOVIEW, **kw)
        assert 0 < len(batch.points) < len(full.points)
    # a sector across 0 deg: the ROS driver's rule (300..359.99 and 0..60; velodyne-decoder
    # cannot give: it keeps [60, 300] for min > max)
    across = _native_decode(packets, stamps, _VELOVIEW, min_angle=300.0, max_angle=60.0)
    parts = [_native_decode(packets, stamps, _VELOVIEW, min_angle=a, max_angle=b)
             for a, b in ((300.0, 359.99), (0.0, 60.0))]

    def rows(*batches):
        p = np.concatenate([b.points for b in batches])
        return np.sort(p[["x", "y", "z", "time_offset_ns"]])

    np.testing.assert_array_equal(rows(across), rows(*parts))
    inverse = _vd_decode(packets, stamps, _VELOVIEW, min_angle=300.0, max_angle=60.0)
    assert len(inverse) + len(across.points) > len(full.points)  # [60, 300]: the other side


# ---------------------------------------------------------------------------------------------
# synthetic return modes and malformed packets
# ---------------------------------------------------------------------------------------------
def _dualize(packet: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A dual-return packet from a single-return one: each block pair shares block 2k's
    azimuth; block 2k (last return) and 2k+1 (strongest) have equal distances ("both"),
    different ones, or one of them zero."""
    p = packet.copy()
    blocks = p[:1200].reshape(12, 100)
    for k in range(6):
        last, strongest = blocks[2 * k], blocks[2 * k + 1]
        strongest[2:4] = last[2:4]
        d_last = last[4:].reshape(32, 3)
        d_str = strongest[4:].reshape(32, 3)
        d_str[:] = d_last
        choice = rng.integers(0, 4, 32)
        d_str[choice == 1, 0] = (d_str[choice == 1, 0].astype(int) + 37) % 256  # farther
        d_str[choice == 1, 2] = 255 - d_str[choice == 1, 2]
        d_str[choice == 2, :2] = 0  # no strongest return
        d_last[choice == 3, :2] = 0  # no last return
    p[1204] = 0x39
    return p


def test_equal_in_dual_return(velodyne_dir):
    packets, stamps = _packets(velodyne_dir / "rustlidar-vlp16.pcap")
    rng = np.random.default_rng(1)
    dual = np.stack([_dualize(p, rng) for p in packets])
    batch, ref = _assert_equal(dual, stamps, _VELOVIEW)
    assert set(np.unique(batch.points["return_type"])) == {1, 2, 3}  # strongest, last, both
    # points of a block pair belong to its even block
    first = batch.block_first_point.reshape(-1)[:-1].reshape(-1, 12)
    assert (np.diff(batch.block_first_point)[1::2] == 0).all() and first[:, 0].min() >= 0


def test_equal_in_last_return(velodyne_dir):
    packets, stamps = _packets(velodyne_dir / "scanparser-vlp16-gaps.pcap")
    last = packets.copy()
    last[:, 1204] = 0x38
    batch, _ref = _assert_equal(last, stamps, _VELOVIEW)
    assert (batch.points["return_type"] == 2).all()
    strongest = _native_decode(packets, stamps, _VELOVIEW)
    assert (strongest.points["return_type"] == 1).all()


def test_malformed_packets_in_a_batch_are_skipped_never_crash(velodyne_dir):
    packets, stamps = _packets(velodyne_dir / "rustlidar-vlp16.pcap")
    rng = np.random.default_rng(7)
    bad = packets.copy()
    bad[3, 5 * 100] = 0x00  # block 5's flag broken: blocks 0..4 decode, as velodyne-decoder
    bad[10, 0:2] = 0  # block 0's flag broken: nothing
    bad[20, :1200] = rng.integers(0, 256, 1200, dtype=np.uint8)  # garbage
    fuzz = bad[30:60]  # valid flags, anything else random (azimuths up to 65535 too)
    body = fuzz[:, :1200].reshape(-1, 12, 100)
    body[:, :, 2:] = rng.integers(0, 256, body[:, :, 2:].shape, dtype=np.uint8)
    fuzz[:, 1204] = rng.choice([0x37, 0x38, 0x39, 0x00, 0xFF], len(fuzz))
    body[:, :, 0], body[:, :, 1] = 0xFF, 0xEE
    batch, _ref = _assert_equal(bad, stamps, _VELOVIEW)
    assert batch.status[3] == batch.status[10] == STATUS_BAD_BLOCK_HEADER
    assert batch.status[20] == STATUS_BAD_BLOCK_HEADER
    first = batch.block_first_point
    assert first[3 * 12 + 5] == first[4 * 12] > first[3 * 12]  # blocks 0..4 of packet 3 only
    assert first[10 * 12] == first[11 * 12]
    assert np.isfinite(batch.points["x"]).all()
    assert np.count_nonzero(batch.status) == 3


def test_empty_batch_and_bad_shapes(velodyne_dir):
    dec = NativeVlp16Decoder(_VELOVIEW)
    out = dec.decode(np.zeros((0, 1206), np.uint8), np.zeros(0, np.int64))
    assert len(out.points) == 0 and out.block_first_point.tolist() == [0]
    with pytest.raises(ValueError, match="1206"):
        dec.decode(np.zeros((2, 1200), np.uint8), np.zeros(2, np.int64))
    with pytest.raises(ValueError, match="one entry per packet"):
        dec.decode(np.zeros((2, 1206), np.uint8), np.zeros(3, np.int64))


def test_a_calibration_of_another_sensor_is_refused():
    with pytest.raises(CalibrationError, match="32 lasers"):
        NativeVlp16Decoder(vd.calibrations.get_bundled_calibration("HDL-32E.yml"))


def test_threads_and_chunking_do_not_change_the_points(velodyne_dir):
    packets, stamps = _packets(velodyne_dir / "veloview-vlp16-20hz.pcap")
    one = _native_decode(packets, stamps, _VELOVIEW, num_threads=1)
    many = _native_decode(packets, stamps, _VELOVIEW, num_threads=4)
    np.testing.assert_array_equal(one.points, many.points)
    np.testing.assert_array_equal(one.block_first_point, many.block_first_point)
    # time offsets: exact integer ns since packet 0's stamp, whatever the chunk
    dec = NativeVlp16Decoder(_VELOVIEW, min_range_m=0.001)
    a = dec.decode(packets[100:200], stamps[100:200])
    b = dec.decode(packets[:300], stamps[:300])
    off = b.block_first_point[100 * 12]
    got = b.points[off : off + len(a.points)]
    np.testing.assert_array_equal(a.points[["x", "y", "z", "ring"]], got[["x", "y", "z", "ring"]])
    np.testing.assert_array_equal(
        a.points["time_offset_ns"].astype(np.int64),
        got["time_offset_ns"].astype(np.int64) - (stamps[100] - stamps[0]))


# ---------------------------------------------------------------------------------------------
# the frame decoder with either batch decoder
# ---------------------------------------------------------------------------------------------
_BATCH_DECODERS = {"native": NativeVlp16Decoder, "velodyne_decoder": VelodyneDecoderOracle}


def _frames(payloads, decoder, chunk=256):
    dec = FrameDecoder(DecodeConfig(chunk_packets=chunk), batch_decoder=_BATCH_DECODERS[decoder])
    return list(dec.decode(payloads)), dec.report


@pytest.mark.parametrize("shuffle", [False, True])
def test_frames_are_the_same_on_both_decoder_paths(velodyne_dir, shuffle):
    """The frame decoder gives the same frames with the native decoder and with the
    velodyne-decoder oracle; time offsets agree to velodyne-decoder's float32 rounding (the
    native ones are exact integer ns)."""
    payloads = [(t, p) for t, p in open_source(velodyne_dir / "veloview-vlp16-20hz.pcap")
                if len(p) == 1206]
    if shuffle:
        payloads[300], payloads[301] = payloads[301], payloads[300]
    nat, rep_n = _frames(payloads, "native", chunk=100)
    ref, rep_v = _frames(payloads, "velodyne_decoder", chunk=100)
    # (the swap makes one more azimuth wrap: one more frame, on both paths)
    assert rep_n.summary() == rep_v.summary() and len(nat) == 52 + shuffle
    for a, b in zip(nat, ref):
        assert (a.stamp_device_ns, a.packets, a.gaps) == (b.stamp_device_ns, b.packets, b.gaps)
        for k in ("x", "y", "z", "intensity", "ring", "laser", "return_type"):
            np.testing.assert_array_equal(a.points[k], b.points[k], err_msg=k)
        dt = a.points["time_offset_ns"].astype(np.int64) - b.points["time_offset_ns"]
        assert np.abs(dt).max(initial=0) <= 100


def test_native_time_offsets_are_exact(velodyne_dir):
    """Each point's offset is its packet's device time plus its firing time (55.296 µs per
    sequence, 2.304 µs per laser) minus the frame's first firing, in integer ns."""
    payloads = [(t, p) for t, p in open_source(velodyne_dir / "mrpt-vlp16-gps.pcap")
                if len(p) == 1206]
    frames, _rep = _frames(payloads, "native", chunk=64)
    # packet device times are whole µs: stamp + offset must be a whole µs plus the firing time
    # of one of the packet's 24 sequences for the point's laser, to the nanosecond (float32
    # seconds would miss by tens of ns)
    allowed = (55_296 * np.arange(24)[:, None] + 2_304 * np.arange(16)[None, :]) % 1000
    for f in frames:
        t = f.points["time_offset_ns"].astype(np.int64)
        assert t[0] >= 0 and np.all(np.diff(t) >= 0)
        r = (t + f.stamp_device_ns) % 1000
        assert (allowed[:, f.points["laser"].astype(np.int64)] == r).any(axis=0).all()


def test_the_decoder_key_is_deprecated(velodyne_dir, tmp_path, capsys):
    """The velodyne-decoder path left the product: an old config's ``decoder: native`` still
    loads (with a note, and is not written back), any other value and ``--decoder`` are one-line
    errors, and an unknown key stays one."""
    from tripod_processor.cli import main

    path = velodyne_dir / "mrpt-vlp16-gps.pcap"
    assert main(["decode", str(path), "--summary"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert plain["points"] > 70_000
    old = tmp_path / "old.yaml"
    old.write_text("decoder: native\nchunk_packets: 512\n")
    out_dir = tmp_path / "out"
    assert main(["decode", str(path), "--summary", "--config", str(old), "-o", str(out_dir)]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    for k in ("input", "input_format"):
        plain.pop(k), summary.pop(k)
    assert summary == plain
    assert "'decoder' is deprecated and ignored" in err
    written = (out_dir / "decode_config.yaml").read_text()
    assert "chunk_packets: 512" in written and "decoder" not in written
    for text, word in (("decoder: velodyne_decoder\n", "decoder"), ("bogus_key: 1\n", "bogus_key")):
        old.write_text(text)
        code = main(["decode", str(path), "--summary", "--config", str(old)])
        _out, err = capsys.readouterr()
        assert code == 2 and len(err.strip().splitlines()) == 1 and word in err, err
    code = main(["decode", str(path), "--summary", "--decoder", "native"])
    _out, err = capsys.readouterr()
    assert code == 2 and "--decoder" in err
