# SPDX-License-Identifier: BSD-3-Clause
"""Preprocessing on the native core, checked against Open3D on the same clouds."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from tripod_processor import preprocess


def _o3d_voxel(points: np.ndarray, voxel: float) -> np.ndarray:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    return np.asarray(pcd.voxel_down_sample(voxel).points)


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.fixture(scope="module")
def bunny(registration_dir) -> np.ndarray:
    pcd = o3d.io.read_point_cloud(str(registration_dir / "bunny" / "bun000.ply"))
    pts = np.asarray(pcd.points, dtype=np.float32)
    assert len(pts) > 30000
    return pts


@pytest.mark.parametrize("voxel", [0.002, 0.005, 0.0137])
def test_voxel_min_bound_equals_open3d_exactly(bunny, voxel):
    ours = preprocess.voxel_downsample(bunny, voxel, align="min_bound")
    ref = _o3d_voxel(bunny, voxel).astype(np.float32)
    assert ours.shape == ref.shape
    # same voxels, same centroids to the float32 bit (both sum in double in point order)
    np.testing.assert_array_equal(_sorted_rows(ours), _sorted_rows(ref))


def test_voxel_min_bound_equals_open3d_on_random_cloud():
    rng = np.random.default_rng(3)
    pts = (rng.normal(size=(50000, 3)) * [4.0, 3.0, 1.0] + [100.0, -20.0, 2.0]).astype(np.float32)
    ours = preprocess.voxel_downsample(pts, 0.1, align="min_bound", num_threads=2)
    ref = _o3d_voxel(pts, 0.1).astype(np.float32)
    assert ours.shape == ref.shape
    np.testing.assert_array_equal(_sorted_rows(ours), _sorted_rows(ref))


def test_voxel_origin_alignment_shares_the_lattice():
    # Two points on either side of x = 0.1 stay apart for voxel 0.1 in origin mode, whatever the
    # cloud's min bound; every centroid lies inside its origin-aligned voxel.
    pts = np.array([[0.09, 0.0, 0.0], [0.11, 0.0, 0.0], [0.05, 0.0, 0.0]], np.float32)
    out = preprocess.voxel_downsample(pts, 0.1)
    np.testing.assert_allclose(out, [[0.07, 0.0, 0.0], [0.11, 0.0, 0.0]], atol=1e-7)
    rng = np.random.default_rng(0)
    cloud = rng.uniform(-5, 5, size=(20000, 3)).astype(np.float32)
    out = preprocess.voxel_downsample(cloud, 0.5)
    idx = np.floor(cloud / 0.5).astype(int)
    assert len(out) == len(np.unique(idx, axis=0))


def test_voxel_deterministic_across_threads(bunny):
    a = preprocess.voxel_downsample(bunny, 0.003, num_threads=1)
    b = preprocess.voxel_downsample(bunny, 0.003, num_threads=2)
    np.testing.assert_array_equal(a, b)


def test_voxel_degenerate_input():
    assert preprocess.voxel_downsample(np.zeros((0, 3), np.float32), 0.1).shape == (0, 3)
    nan = np.full((5, 3), np.nan, np.float32)
    assert preprocess.voxel_downsample(nan, 0.1).shape == (0, 3)
    mixed = np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 1.0], [np.inf, 0, 0]], np.float32)
    np.testing.assert_array_equal(preprocess.voxel_downsample(mixed, 0.1), [[0, 0, 0]])
    with pytest.raises(ValueError, match="voxel_size"):
        preprocess.voxel_downsample(mixed, 0.0)
    with pytest.raises(ValueError, match="voxel_size"):
        preprocess.voxel_downsample(mixed, float("nan"))
    with pytest.raises(ValueError, match="align"):
        preprocess.voxel_downsample(mixed, 0.1, align="corner")
    with pytest.raises(ValueError, match="too many voxels"):
        preprocess.voxel_downsample(np.array([[0, 0, 0], [1e6, 0, 0]], np.float32), 0.01)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        preprocess.voxel_downsample(np.zeros((4, 2)), 0.1)
