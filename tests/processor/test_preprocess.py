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


# ------------------------------------------------------------------ normals, SOR, MLS, NSS, FPFH
@pytest.fixture(scope="module")
def bunny_small(bunny) -> np.ndarray:
    return preprocess.voxel_downsample(bunny, 0.003)


def test_normals_match_open3d_and_face_the_viewpoint(bunny_small):
    vp = np.array([0.0, 0.0, 1.0])
    n, cov, curv, valid = preprocess.estimate_normals(bunny_small, 20, viewpoint=vp)
    assert valid.all() and n.shape == (len(bunny_small), 3) and cov.shape == (len(n), 3, 3)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(bunny_small.astype(np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    ref = np.asarray(pcd.normals)
    agree = np.abs(np.einsum("ij,ij->i", n, ref))
    assert np.median(agree) > 0.9999 and (agree > 0.99).mean() > 0.99
    assert (np.einsum("ij,ij->i", n, vp - bunny_small) >= 0).all()
    # covariance of point 0 is the (biased) sample covariance of its 20 nearest neighbours
    d = np.linalg.norm(bunny_small - bunny_small[0], axis=1)
    nb = bunny_small[np.argsort(d)[:20]].astype(np.float64)
    np.testing.assert_allclose(cov[0], np.cov(nb.T, bias=True), atol=1e-9)
    assert 0 <= curv.min() and curv.max() <= 1 / 3 + 1e-9
    # radius neighbourhoods
    n_r, _, _, valid_r = preprocess.estimate_normals(bunny_small, 30, radius=0.01, viewpoint=vp)
    both = valid_r
    assert np.median(np.abs(np.einsum("ij,ij->i", n_r[both], n[both]))) > 0.99


def test_statistical_outlier_removal_drops_far_points():
    rng = np.random.default_rng(4)
    dense = rng.normal(size=(5000, 3)).astype(np.float32)
    far = rng.uniform(20, 30, size=(20, 3)).astype(np.float32)
    pts = np.vstack([dense, far])
    kept = preprocess.statistical_outlier_removal(pts, 20, 2.0, num_threads=2)
    assert not np.isin(np.arange(5000, 5020), kept).any()
    assert len(kept) > 0.9 * 5000 and np.all(np.diff(kept) > 0)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    _, ref = pcd.remove_statistical_outlier(20, 2.0)
    overlap = len(np.intersect1d(kept, ref)) / max(len(ref), 1)
    assert overlap > 0.97


@pytest.mark.parametrize("fit_voxel", [0.0, 0.04])
def test_mls_smooths_a_noisy_plane_and_keeps_a_sphere(fit_voxel):
    # fit_voxel 0: a surface per point; 0.04: surfaces at voxel centroids, points projected
    # onto their nearest one's
    rng = np.random.default_rng(5)
    xy = rng.uniform(-1, 1, size=(20000, 2))
    noisy = np.c_[xy, rng.normal(0, 0.005, len(xy))].astype(np.float32)
    out = preprocess.mls_smooth(noisy, 0.08, num_threads=2, fit_voxel=fit_voxel)
    assert out.shape == noisy.shape
    inner = np.abs(xy).max(axis=1) < 0.9
    assert out[inner, 2].std() < 0.3 * noisy[inner, 2].std()
    # points keep their place along the surface (projection, not snapping to the centroids)
    assert np.abs(out[inner, :2] - noisy[inner, :2]).max() < 0.01
    d = rng.normal(size=(20000, 3))
    sphere = (d / np.linalg.norm(d, axis=1, keepdims=True) * (1 + rng.normal(0, 0.003, (20000, 1))))
    sm = preprocess.mls_smooth(sphere.astype(np.float32), 0.1, fit_voxel=fit_voxel)
    r = np.linalg.norm(sm, axis=1)
    assert abs(np.median(r) - 1.0) < 0.002 and r.std() < 0.5 * np.linalg.norm(sphere, axis=1).std()


def test_normal_space_sampling_keeps_rare_orientations():
    rng = np.random.default_rng(6)
    normals = np.tile([0.0, 0.0, 1.0], (10000, 1))  # a floor...
    normals[:100] = [1.0, 0.0, 0.0]  # ...and a thin wall strip
    idx = preprocess.normal_space_sampling(normals, 500, seed=1)
    assert len(idx) == 500 and len(np.unique(idx)) == 500 and np.all(np.diff(idx) > 0)
    assert (idx < 100).sum() == 100  # uniform sampling would keep about 5
    again = preprocess.normal_space_sampling(normals, 500, seed=1)
    np.testing.assert_array_equal(idx, again)
    assert len(preprocess.normal_space_sampling(normals[:10], 50)) == 10
    del rng


def test_fpfh_matches_open3d(bunny):
    pts = preprocess.voxel_downsample(bunny, 0.004)
    n, _, _, valid = preprocess.estimate_normals(pts, 20, viewpoint=(0, 0, 1))
    assert valid.all()
    ours = preprocess.compute_fpfh(pts, n, radius=0.02, max_neighbors=100, num_threads=2)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    pcd.normals = o3d.utility.Vector3dVector(n)
    ref = o3d.pipelines.registration.compute_fpfh_feature(
        pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=100)).data.T
    assert ours.shape == ref.shape == (len(pts), 33)
    # SPFH of the point (3 x 100) + the normalised sum of its neighbours' (3 x 100)
    np.testing.assert_allclose(ours.sum(axis=1), 600.0, rtol=1e-4)
    # identical except where a neighbour sits on the radius (float32 here, float64 in Open3D)
    close = np.abs(ours - ref).max(axis=1) < 0.05
    assert close.mean() > 0.9, close.mean()
    cos = np.einsum("ij,ij->i", ours, ref) / np.linalg.norm(ours, axis=1) / np.linalg.norm(ref, axis=1)
    assert np.quantile(cos, 0.01) > 0.99


def test_preprocess_degenerate_input():
    empty = np.zeros((0, 3), np.float32)
    n, c, k, v = preprocess.estimate_normals(empty)
    assert n.shape == (0, 3) and c.shape == (0, 3, 3) and v.shape == (0,)
    assert len(preprocess.statistical_outlier_removal(empty)) == 0
    assert preprocess.mls_smooth(empty, 0.1).shape == (0, 3)
    two = np.array([[0, 0, 0], [1, 0, 0]], np.float32)
    _, _, _, v = preprocess.estimate_normals(two, 5)
    assert not v.any()  # too few points: no normal, no crash
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)].astype(np.float32)
    _, _, _, v = preprocess.estimate_normals(line, 10)
    assert not v.any()  # collinear: normal undefined
    with pytest.raises(ValueError, match="NaN"):
        preprocess.estimate_normals(np.array([[np.nan, 0, 0]] * 5))
    with pytest.raises(ValueError, match="radius"):
        preprocess.mls_smooth(two, 0.0)
    with pytest.raises(ValueError, match="normals"):
        preprocess.compute_fpfh(two, np.zeros((3, 3)), 0.1)
