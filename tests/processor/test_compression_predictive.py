# SPDX-License-Identifier: BSD-3-Clause
"""tripod_processor.compression, predictive mode: round trip, lattices, fall-back, integrity."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from tripod_processor.compression import (CodecError, ContainerError, compress,
                                          compress_with_info, decompress, read_info)
from tripod_processor.compression import container, predictive
from tripod_processor.compression.codec import decode_cloud, encode
from tripod_processor.compression.synthetic import VLP16_FIRING_ORDER_DEG, ordered_scan


@pytest.fixture(scope="module")
def scan() -> np.ndarray:
    """About 27 k points: one VLP-16 revolution in firing order, ranges on a 2 mm lattice."""
    return ordered_scan(11)


@pytest.mark.parametrize("error", [0.0005, 0.003, 0.02])
def test_round_trip_keeps_order_and_error_bound(scan, error):
    data, info = compress_with_info(scan, error=error, mode="predictive")
    out = decompress(data)
    assert info.mode == "predictive" and read_info(data)["codec"] == predictive.CODEC_NAME
    # every point comes back, in input order, within the bound (row by row, no matching)
    assert out.dtype == np.float32 and out.shape == scan.shape
    err = np.linalg.norm(out.astype(np.float64) - scan, axis=1)
    assert err.max() <= error * (1 + 1e-6)
    assert read_info(data)["max_error"] == pytest.approx(err.max(), abs=1e-7)


def test_lattices_are_detected_and_ranges_are_exact(scan):
    data = compress(scan, error=0.001, mode="predictive")
    header = read_info(data)
    assert header["range_lattice"] == pytest.approx(0.002, rel=1e-6)
    assert header["el_table_len"] == 16  # the 16 lasers, coded as indices
    start, step = header["el_uniform"]  # -15 .. 15 deg in 2 deg steps: stored as two numbers
    assert math.degrees(start) == pytest.approx(-15, abs=1e-6)
    assert math.degrees(step) == pytest.approx(2, abs=1e-6)
    out = decompress(data).astype(np.float64)
    r_in, r_out = np.linalg.norm(scan, axis=1), np.linalg.norm(out, axis=1)
    assert np.abs(r_out - r_in).max() < 2e-6  # range lossless up to float32 storage
    # a range step coarser than the lattice is a multiple of it
    coarse = read_info(compress(scan, error=0.02, mode="predictive"))
    steps = coarse["range_step"] / coarse["range_lattice"]
    assert steps == pytest.approx(round(steps), abs=1e-6) and round(steps) > 1


def test_plain_grid_without_lattices():
    rng = np.random.default_rng(3)
    pts = ordered_scan(5, range_lattice_m=None)
    pts = pts + rng.normal(0, 1e-3, pts.shape).astype(np.float32)  # no elevation lattice either
    data = compress(pts, error=0.004, mode="predictive")
    header = read_info(data)
    assert header["range_lattice"] == 0.0 and header["el_table_len"] == 0
    out = decompress(data)
    assert np.linalg.norm(out.astype(np.float64) - pts, axis=1).max() <= 0.004 * (1 + 1e-6)


def test_auto_prefers_the_scan_structure_and_falls_back_on_unordered_clouds(scan):
    step = 0.004
    auto, info = encode(scan, step)
    octree, octree_info = encode(scan, step, mode="octree")
    assert info.mode == "predictive" and len(auto) < 0.57 * len(octree)  # measured 0.523
    # the same points, shuffled: no scan order left, the octree is kept (never a larger file)
    shuffled = scan[np.random.default_rng(0).permutation(len(scan))]
    auto, info = encode(shuffled, step)
    octree, _ = encode(shuffled, step, mode="octree")
    assert info.mode == "octree" and auto == octree
    # forcing the predictive mode on it still works, only bigger
    forced, forced_info = encode(shuffled, step, mode="predictive")
    assert forced_info.mode == "predictive" and len(forced) > len(octree)
    out = decompress(forced)
    assert np.linalg.norm(out.astype(np.float64) - shuffled, axis=1).max() <= step * 0.8661
    with pytest.raises(CodecError, match="unknown mode"):
        encode(scan, step, mode="zip")


def test_origin_moves_with_the_sensor(scan):
    shift = np.array([12.5, -3.0, 1.25])
    moved = (scan + shift).astype(np.float32)
    at_origin = compress(moved, error=0.002, mode="predictive", origin=shift)
    at_zero = compress(moved, error=0.002, mode="predictive")
    assert read_info(at_origin)["origin"] == pytest.approx(shift.tolist())
    # about the wrong point nothing is regular (measured 0.464)
    assert len(at_origin) < 0.51 * len(at_zero)
    out = decompress(at_origin)
    assert np.linalg.norm(out.astype(np.float64) - moved, axis=1).max() <= 0.002 * (1 + 1e-6)


def test_intensity_per_point_and_edge_clouds(scan):
    inten = (np.arange(len(scan)) % 200).astype(np.float32)
    out, attrs, header = decode_cloud(compress(scan, error=0.002, mode="predictive",
                                               intensity=inten))
    assert header["codec"] == predictive.CODEC_NAME
    np.testing.assert_array_equal(attrs["intensity"], inten.astype(np.uint8))
    empty = decompress(compress(np.zeros((0, 3), np.float32), error=0.01, mode="predictive"))
    assert empty.shape == (0, 3)
    one = np.array([[1.0, -2.0, 0.5]], np.float32)
    back = decompress(compress(one, error=0.001, mode="predictive"))
    assert back.shape == (1, 3) and np.abs(back - one).max() <= 0.001


def test_detectors():
    rng = np.random.default_rng(1)
    r = np.round(rng.uniform(0.5, 20, 5000) / 0.01) * 0.01
    step, dev = predictive.range_lattice(r.astype(np.float32).astype(np.float64))
    assert step == pytest.approx(0.01, rel=1e-6) and dev < 2e-5
    assert predictive.range_lattice(rng.uniform(0.5, 20, 5000)) is None
    lasers = np.deg2rad([-10.0, -3.5, 0.0, 2.0, 9.0])  # an irregular table stays a table
    el = lasers[rng.integers(0, 5, 4000)] + rng.normal(0, 1e-7, 4000)
    table, dev, uniform = predictive.elevation_table(el, 1e-5)
    np.testing.assert_allclose(table, lasers, atol=1e-6)
    assert uniform is None and dev < 1e-6
    assert predictive.elevation_table(rng.uniform(-1, 1, 4000), 1e-5) is None


# ---- container integrity of the new mode ----------------------------------------------------
@pytest.fixture(scope="module")
def small_file(scan) -> bytes:
    return compress(scan[:8000], error=0.005, mode="predictive",
                    intensity=np.full(8000, 7.0, np.float32))


def test_versions(small_file, scan):
    assert struct.unpack_from("<H", small_file, 8)[0] == 2  # needs a version-2 reader
    octree = compress(scan[:2000], error=0.005, mode="octree")
    assert struct.unpack_from("<H", octree, 8)[0] == 1  # still readable by version-1 readers


def test_truncation_and_bit_flips_are_one_line_errors(small_file):
    for n in sorted(set(np.linspace(0, len(small_file) - 1, 60).astype(int)) | {1, 8, 19}):
        with pytest.raises(ContainerError) as exc:
            decompress(small_file[:n])
        assert "\n" not in str(exc.value)
    rng = np.random.default_rng(2)
    for pos in rng.choice(len(small_file), 150, replace=False):
        corrupt = bytearray(small_file)
        corrupt[pos] ^= 1 << int(rng.integers(8))
        with pytest.raises((ContainerError, CodecError)) as exc:
            decompress(bytes(corrupt))
        assert "\n" not in str(exc.value)


def test_damaged_stream_with_fresh_checksums_is_rejected(small_file):
    header, sections = container.unpack(small_file)
    header = {k: v for k, v in header.items() if k not in ("section_bytes", "payload_bytes")}
    for where in (0.2, 0.5, 0.9):
        stream = bytearray(sections[0])
        stream[int(len(stream) * where)] ^= 0x24
        with pytest.raises(CodecError, match="corrupt predictive stream"):
            decompress(container.pack(header, [bytes(stream), *sections[1:]]))
    for bad in (dict(header, el_table_len=3), dict(header, el_uniform=[0.1, -0.01]),
                {k: v for k, v in header.items() if k != "el_uniform"}):
        with pytest.raises((ContainerError, CodecError), match="corrupt"):
            decompress(container.pack(bad, sections))


def test_cli_modes_and_pcd_viewpoint(tmp_path, scan, capsys):
    from tripod_processor.cli import main
    from tripod_processor.io.clouds import make_cloud, pcd_viewpoint, read_cloud, write_cloud, xyz

    shift = np.array([2.0, -1.5, 0.75])
    src = tmp_path / "scan.pcd"
    write_cloud(src, make_cloud((scan + shift).astype(np.float32)))
    raw = src.read_bytes().replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 2 -1.5 0.75 1 0 0 0")
    src.write_bytes(raw)
    assert pcd_viewpoint(src).tolist() == shift.tolist()
    tpc, out = tmp_path / "scan.tpc", tmp_path / "out.ply"
    assert main(["compress", str(src), "-o", str(tpc), "--error", "2mm"]) == 0
    info = read_info(tpc.read_bytes())
    assert info["codec"] == predictive.CODEC_NAME and info["origin"] == shift.tolist()
    assert main(["decompress", str(tpc), "-o", str(out)]) == 0
    back = xyz(read_cloud(out))
    assert back.shape == scan.shape
    assert np.linalg.norm(back - (scan + shift), axis=1).max() <= 0.002 * (1 + 1e-5)
    assert main(["compress", str(src), "-o", str(tpc), "--error", "2mm", "--mode", "octree"]) == 0
    assert read_info(tpc.read_bytes())["codec"] == "octree-ctx22"
    capsys.readouterr()
    assert main(["compress", str(src), "-o", str(tpc), "--mode", "zip"]) == 2
    assert main(["compress", str(src), "-o", str(tpc), "--origin", "1,x,2"]) == 2
    err = capsys.readouterr().err
    assert "--mode must be one of" in err and "--origin must be x,y,z" in err


# ---- per-laser model (lasers with vertical offsets: G-PCC's angular mode) --------------------
#: the VLP-16 manual's vertical offsets [m], in firing order (-15, 1, -13, 3, ... deg)
VLP16_LASER_Z_M = [0.0112, -0.0007, 0.0097, -0.0022, 0.0081, -0.0037, 0.0066, -0.0051,
                   0.0051, -0.0066, 0.0037, -0.0081, 0.0022, -0.0097, 0.0007, -0.0112]


@pytest.fixture(scope="module")
def offset_scan() -> np.ndarray:
    """A VLP-16 revolution whose lasers sit at their own heights: no elevation table fits."""
    return ordered_scan(12, laser_z_m=VLP16_LASER_Z_M)


@pytest.mark.parametrize("error,ratio", [(0.0005, 0.42), (0.004, 0.62)])  # measured 0.379, 0.565
def test_per_laser_model_round_trip(offset_scan, error, ratio):
    data, info = compress_with_info(offset_scan, error=error, mode="predictive")
    header = read_info(data)
    assert header["codec"] == predictive.CODEC_NAME and header["laser_z"]
    assert header["el_table_len"] == 16 and header["range_lattice"] == pytest.approx(0.002)
    out = decompress(data)
    assert out.shape == offset_scan.shape  # all points, in input order
    err = np.linalg.norm(out.astype(np.float64) - offset_scan, axis=1)
    assert err.max() <= error * (1 + 1e-6)
    # without the laser model this scan has no elevation table: the model must pay off
    auto, _ = encode(offset_scan, 2 * error / math.sqrt(3))
    octree, _ = encode(offset_scan, 2 * error / math.sqrt(3), mode="octree")
    assert len(auto) == len(data) and len(data) < ratio * len(octree)


def test_laser_table_detection(offset_scan):
    p = offset_scan.astype(np.float64)
    h, z = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
    assert predictive.elevation_table(np.arctan2(z, h), 2e-5) is None
    el, z0, dev = predictive.laser_table(h, z, 2e-5)
    order = np.argsort(VLP16_FIRING_ORDER_DEG)
    np.testing.assert_allclose(np.degrees(el), np.sort(VLP16_FIRING_ORDER_DEG), atol=1e-4)
    np.testing.assert_allclose(z0, np.asarray(VLP16_LASER_Z_M)[order], atol=2e-5)
    assert dev < 2e-5
    # unstructured points: no model
    rng = np.random.default_rng(4)
    assert predictive.laser_table(rng.uniform(0.5, 9, 5000), rng.uniform(-2, 2, 5000),
                                  2e-5) is None


def test_azimuth_lattice_detection():
    rng = np.random.default_rng(5)
    az = (rng.integers(0, 36000, 20000) * (2 * math.pi / 36000) + rng.normal(0, 2e-7, 20000))
    az = np.where(az > math.pi, az - 2 * math.pi, az)
    m, dev = predictive.angle_lattice(az)
    assert m == 36000 and dev < 1e-6
    assert predictive.angle_lattice(rng.uniform(-math.pi, math.pi, 20000)) is None


@pytest.mark.parametrize("calibration", ["veloview", "manual"])
def test_real_decoded_rotation(calibration, velodyne_dir):
    """A rotation as ``tripod decode`` writes it (sensor frame, firing order), with the nominal
    angles and with the manual's per-laser vertical offsets: predictive, within the bound,
    smaller than the octree at q12."""
    from tripod_processor.decode import DecodeConfig, decode_file

    path = velodyne_dir / "veloview-vlp16-20hz.pcap"
    frames = iter(decode_file(path, DecodeConfig(calibration=calibration)))
    next(frames)  # the first frame is a partial rotation
    rec = next(frames).points
    pts = np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float32)
    step = float(np.ptp(pts, 0).max()) / (2**12 - 1)
    data, info = encode(pts, step)
    octree, _ = encode(pts, step, mode="octree")
    header = read_info(data)
    assert info.mode == "predictive" and len(data) < 0.66 * len(octree)  # measured 0.60, 0.61
    assert header["el_table_len"] == 16 and header["laser_z"] == (calibration == "manual")
    assert header["az_lattice"] == 36000 and header["range_lattice"] == pytest.approx(0.002)
    out = decompress(data)
    assert out.shape == pts.shape
    assert np.linalg.norm(out.astype(np.float64) - pts, axis=1).max() <= step * 0.8661


def test_old_sph1_file_still_decodes():
    """A ``predictive-sph1`` file written by the code that wrote sph1 (commit c8984a8; see
    tests/processor/data/sph1/README.md) decodes to what that code's decoder gave."""
    import hashlib
    from pathlib import Path

    d = Path(__file__).parent / "data" / "sph1"
    data = (d / "ordered_scan_2000.tpc").read_bytes()
    header = read_info(data)
    assert header["codec"] == "predictive-sph1" and header["n_points"] == 2000
    out = decompress(data)
    assert hashlib.sha256(out.tobytes()).hexdigest() == (
        "9558233937587ef59a805a52a67dd2d10c6e6edaa491fe20c862d6c96971d150")
    with np.load(d / "ordered_scan_2000_input.npz") as z:
        points = z["points"]
    err = np.linalg.norm(out.astype(np.float64) - points, axis=1)
    assert err.max() <= 0.003 and err.max() == pytest.approx(header["max_error"], abs=1e-7)
    damaged = bytearray(data)
    damaged[-100] ^= 0x40  # inside the stream: the sph1 checksum still guards it
    with pytest.raises((CodecError, ContainerError)):
        decompress(bytes(damaged))
