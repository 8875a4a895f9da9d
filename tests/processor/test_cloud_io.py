# SPDX-License-Identifier: BSD-3-Clause
"""cloud_io: PLY/PCD round trips and the real files of ../shared/data/registration."""

import numpy as np
import pytest

from tripod_processor.io import clouds as cloud_io


def _cloud(n=1000, seed=0):
    rng = np.random.default_rng(seed)
    return cloud_io.make_cloud(
        rng.normal(size=(n, 3)), intensity=rng.random(n).astype(np.float32),
        ring=rng.integers(0, 16, n).astype(np.uint16), time=rng.random(n),
        label=rng.integers(0, 4, n).astype(np.int32),
    )


@pytest.mark.parametrize("ext", [".ply", ".pcd"])
def test_round_trip(tmp_path, ext):
    c = _cloud()
    p = tmp_path / f"c{ext}"
    cloud_io.write_cloud(p, c)
    back = cloud_io.read_cloud(p)
    assert back.dtype.names == c.dtype.names
    for name in c.dtype.names:
        np.testing.assert_array_equal(back[name], c[name])


def test_real_files_match_open3d(registration_dir):
    import open3d as o3d  # a runtime dependency of the processor: the independent reader
    for rel, n in [("pcl/room_scan1.pcd", 112586), ("pcl/bun0.pcd", 397), ("bunny/bun000.ply", 40256)]:
        path = registration_dir / rel
        c = cloud_io.read_cloud(path)
        assert len(c) == n
        ref = np.asarray(o3d.io.read_point_cloud(str(path)).points)
        np.testing.assert_allclose(cloud_io.xyz(c), ref, atol=1e-6)


def test_bad_files(tmp_path):
    bad = tmp_path / "x.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00\x00")
    with pytest.raises(cloud_io.CloudFormatError, match="truncated"):
        cloud_io.read_cloud(bad)
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x01\x02garbage")
    with pytest.raises(cloud_io.CloudFormatError):
        cloud_io.read_cloud(junk)
    with pytest.raises(FileNotFoundError):
        cloud_io.read_cloud(tmp_path / "missing.pcd")


def test_read_matrix4(registration_dir):
    m = cloud_io.read_matrix4(registration_dir / "pcl" / "bun0_to_bun4_groundtruth.txt")
    assert m.shape == (4, 4)
    np.testing.assert_allclose(m[3], [0, 0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-4)
