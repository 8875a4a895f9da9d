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
from tripod_processor.compression.synthetic import ordered_scan


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
    assert info.mode == "predictive" and len(auto) < 0.8 * len(octree)
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
    assert len(at_origin) < 0.7 * len(at_zero)  # about the wrong point nothing is regular
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
    from tripod_processor.cloud_io import make_cloud, pcd_viewpoint, read_cloud, write_cloud, xyz

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
