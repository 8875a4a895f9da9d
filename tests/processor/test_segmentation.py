# SPDX-License-Identifier: BSD-3-Clause
"""Segmentation: native features, the shipped model on unseen rooms, training, metrics, CLI."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_processor import _ext
from tripod_processor.cli import main
from tripod_processor.io.clouds import make_cloud, read_cloud, write_ply
from tripod_processor.scene.segmentation import DEFAULT_WEIGHTS, Segmenter, point_features
from tripod_processor.scene.segmentation.features import FEATURE_NAMES, floor_and_ceiling
from tripod_processor.scene.segmentation.metrics import confusion, iou, overall_accuracy
from tripod_processor.scene.segmentation.segments import planar_segments, segment_consistent

from scene_fixtures import room_scan


def test_local_shape_matches_numpy_pca():
    rng = np.random.default_rng(0)
    # a tilted plane with 1 mm noise, 30 x 30 cm
    n_true = np.array([0.2, -0.3, 0.93])
    n_true /= np.linalg.norm(n_true)
    u = np.cross(n_true, [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n_true, u)
    ab = rng.uniform(-0.15, 0.15, (20000, 2))
    p = (ab[:, :1] * u + ab[:, 1:] * v + rng.normal(0, 0.001, (20000, 1)) * n_true).astype(np.float32)
    out = _ext.voxel_local_shape(p, 0.5, 1)  # one neighbourhood holds everything
    assert out.shape == (20000, 7)
    q = p.astype(np.float64) - p.mean(0)
    evals, evecs = np.linalg.eigh(q.T @ q / len(q))
    np.testing.assert_allclose(out[0, 3:6], evals, rtol=1e-3, atol=1e-8)
    assert abs(abs(out[0, :3] @ evecs[:, 0]) - 1) < 1e-5
    assert out[0, 2] >= 0 and out[0, 6] == 20000
    assert abs(out[0, :3] @ n_true) > 0.9999


def test_local_shape_skips_non_finite_points():
    p = np.array([[0, 0, 0], [np.nan, 0, 0], [0.01, 0, 0]], np.float32)
    out = _ext.voxel_local_shape(p, 0.1, 1)
    assert np.all(out[1] == 0) and out[0, 6] == 2


def test_column_context_walls_are_open_furniture_is_not():
    p, lab, scene, _ = room_scan(3, kind="box", head_steps=8)
    feats = point_features(p)
    open_frac = feats[:, FEATURE_NAMES.index("open_fraction")]
    assert np.median(open_frac[lab == 2]) > 0.25
    assert np.median(open_frac[lab == 3]) < 0.15


def test_column_context_is_the_same_on_every_side_of_the_grid():
    """Rays leaving past the low edge of the grid are open too (a truncating cast once kept them
    in cell 0, so walls on the -x and -y sides looked closed, like furniture)."""
    t = np.linspace(0.0, 4.0, 400)
    z = np.full_like(t, 1.0)
    walls = [np.c_[t, 0 * t, z], np.c_[t, 0 * t + 4, z], np.c_[0 * t, t, z], np.c_[0 * t + 4, t, z]]
    p = np.concatenate(walls).astype(np.float32)
    opt = _ext._ColumnContextOptions()
    opt.cell_size, opt.z_low, opt.z_high, opt.max_range, opt.num_threads = 0.1, 0.2, 2.5, 100.0, 1
    cc = _ext.column_context(p, np.ones(len(p), np.uint8), opt)
    mid = [200, 600, 1000, 1400]  # the middle of each wall
    assert np.ptp(cc[mid, 0]) == 0.0, cc[mid, 0]
    assert 0.3 < cc[mid[0], 0] < 0.6  # about half of the rays leave the room outward


def _grid(u, v):
    uu, vv = np.meshgrid(u, v)
    return uu.ravel(), vv.ravel()


def test_planar_segments_long_wall_vs_box_in_front_of_it():
    rng = np.random.default_rng(0)
    # a 6 m x 2.5 m wall at y = 0, and a 1.0 x 0.6 m box (a radiator) 10 cm in front of it
    x, z = _grid(np.arange(0, 6, 0.02), np.arange(0, 2.5, 0.02))
    wall = np.c_[x, np.zeros_like(x), z]
    x, z = _grid(np.arange(2, 3, 0.02), np.arange(0.15, 0.75, 0.02))
    front = np.c_[x, np.full_like(x, 0.12), z]
    p = np.concatenate([wall, front]).astype(np.float32)
    p += rng.normal(0, 0.003, p.shape).astype(np.float32)
    stats, nz, seg = planar_segments(p, num_threads=1)
    w, f = slice(0, len(wall)), slice(len(wall), len(p))
    # most of the wall is one segment spanning it, the radiator front is not part of it
    main = np.bincount(seg[w]).argmax()
    assert (seg[w] == main).mean() > 0.9
    assert not np.isin(seg[f], [main]).any()
    wall_stats = stats[w][seg[w] == main][0]
    assert 5.7 < wall_stats[0] < 6.1 and 2.2 < wall_stats[1] < 2.6  # horizontal, vertical span
    assert wall_stats[4] > 10  # [m^2]
    assert np.median(stats[f][:, 0]) < 1.2 and np.median(stats[f][:, 1]) < 0.7
    assert nz[w][seg[w] == main].max() < 0.05  # the segment is upright


def test_planar_segments_residual_finds_a_board_on_the_wall():
    rng = np.random.default_rng(1)
    # a 6 m x 2.5 m wall at y = 0 and a 1.2 x 0.9 m board 4 cm in front of it: the board's
    # voxels straddle both and join the wall's segment, but the board lies off its plane
    x, z = _grid(np.arange(0, 6, 0.02), np.arange(0, 2.5, 0.02))
    keep = ~((x > 2) & (x < 3.2) & (z > 1.0) & (z < 1.9))  # the wall hidden behind the board
    wall = np.c_[x, np.zeros_like(x), z][keep]
    x, z = _grid(np.arange(2, 3.2, 0.02), np.arange(1.0, 1.9, 0.02))
    board = np.c_[x, np.full_like(x, 0.04), z]
    p = np.concatenate([wall, board]).astype(np.float32)
    p += rng.normal(0, 0.003, p.shape).astype(np.float32)
    _, _, seg, res = planar_segments(p, num_threads=1, residual=True)
    w, b = slice(0, len(wall)), slice(len(wall), len(p))
    main = np.bincount(seg[w]).argmax()
    assert (seg[b] == main).mean() > 0.5  # the board is (mostly) in the wall's segment ...
    assert np.median(res[w]) < 0.01  # ... but the wall is on the segment's plane
    inner = (board[:, 0] > 2.1) & (board[:, 0] < 3.1) & (board[:, 2] > 1.1) & (board[:, 2] < 1.8)
    assert np.median(res[b][inner]) > 0.025  # [m] and the board is off it
    # without residual=True: the three arrays of before
    assert len(planar_segments(p, num_threads=1)) == 3


def test_wall_planes_join_wall_pieces_apart_and_leave_a_box_out():
    from tripod_processor.scene.segmentation.segments import planar_segments, wall_planes

    rng = np.random.default_rng(2)
    # a wall at y = 0 cut by a 1 m doorway (x 3-4 m) into a 3 m piece and a 0.5 m pier; a box
    # face 0.6 m in front of the long piece; a sparse patch (a few scan lines) on the wall's
    # plane above the doorway
    x, z = _grid(np.arange(0, 3, 0.02), np.arange(0, 2.5, 0.02))
    piece = np.c_[x, np.zeros_like(x), z]
    x, z = _grid(np.arange(4, 4.5, 0.02), np.arange(0, 2.5, 0.02))
    pier = np.c_[x, np.zeros_like(x), z]
    x, z = _grid(np.arange(0.5, 1.5, 0.02), np.arange(0, 1.0, 0.02))
    box = np.c_[x, np.full_like(x, 0.6), z]
    x, z = _grid(np.arange(3.1, 3.9, 0.08), np.array([2.2, 2.4]))
    sparse = np.c_[x, np.zeros_like(x), z]
    p = np.concatenate([piece, pier, box, sparse]).astype(np.float32)
    p += rng.normal(0, 0.002, p.shape).astype(np.float32)
    cen, pv, _ = voxel_assign_4cm(p)
    _, _, seg = planar_segments(cen, num_threads=1)
    plane = wall_planes(cen, seg)[pv]
    n1, n2, n3 = len(piece), len(pier), len(box)
    a, b, c, d = plane[:n1], plane[n1:n1 + n2], plane[n1 + n2:n1 + n2 + n3], plane[n1 + n2 + n3:]
    main = np.bincount(a[a >= 0]).argmax()
    assert (a == main).mean() > 0.9 and (b == main).mean() > 0.9  # the pier is on the wall
    assert (c == main).mean() < 0.01  # the box face in front is not
    assert (d == main).mean() > 0.5  # the sparse lines above the doorway join the wall
    assert np.all(wall_planes(cen[:3], seg[:3]) == -1)  # too few segments: no planes


def voxel_assign_4cm(p):
    from tripod_processor.preprocess import voxel_assign

    return voxel_assign(p, 0.04, 1)


def test_plane_consistency_leaves_voxels_off_the_plane_alone():
    from tripod_processor.scene.segmentation import COARSE_GATE, FINE_GATE, plane_consistent

    # one segment on both grids: 8 voxels say wall, 2 doubt (other 0.6); one of them lies
    # 3 cm off the segment's plane (a board) and keeps "other", the other is outvoted
    probs = np.tile(np.float32([0.0, 0.0, 0.9, 0.1]), (10, 1))
    probs[8] = probs[9] = [0.0, 0.0, 0.4, 0.6]
    f = np.zeros((10, len(FEATURE_NAMES)), np.float32)
    f[9, FEATURE_NAMES.index("segment_residual")] = FINE_GATE + 0.01
    f[9, FEATURE_NAMES.index("coarse_residual")] = COARSE_GATE + 0.01
    out = plane_consistent(probs, f, np.zeros((10, 2), np.int64))
    assert out[8].argmax() == 2 and out[9].argmax() == 3
    assert (out[:8].argmax(1) == 2).all()
    # (M,) segments: the 10 cm pass only, as segment_consistent
    np.testing.assert_array_equal(plane_consistent(probs, f, np.zeros(10, np.int64)),
                                  segment_consistent(probs, np.zeros(10, np.int64)))


def test_segment_consistency_outvotes_doubtful_points_only():
    # one segment: 8 points say wall, 1 doubts (other 0.6), 1 is sure it is other (0.99)
    p = np.tile(np.float32([0.0, 0.0, 0.9, 0.1]), (10, 1))
    p[8] = [0.0, 0.0, 0.4, 0.6]
    p[9] = [0.0, 0.0, 0.01, 0.99]
    single = np.float32([[0.3, 0.0, 0.3, 0.4]])  # a segment of its own keeps its label
    probs = np.concatenate([p, single])
    seg = np.r_[np.zeros(10, np.int64), 1]
    out = segment_consistent(probs, seg)
    np.testing.assert_allclose(out.sum(1), 1, rtol=1e-5)
    assert out[8].argmax() == 2 and out[9].argmax() == 3 and out[10].argmax() == 3
    assert (out[:8].argmax(1) == 2).all()
    # no segment (-1): unchanged
    np.testing.assert_array_equal(segment_consistent(probs, np.full(11, -1)), probs)


def test_segment_consistency_power_weighs_the_segment_more():
    # the wall-plane pass squares the plane's mean: a point fairly sure it is other (0.85) on a
    # plane that says wall is outvoted, one that is very sure (0.99) still is not
    p = np.tile(np.float32([0.0, 0.0, 0.9, 0.1]), (10, 1))
    p[8] = [0.0, 0.0, 0.15, 0.85]
    p[9] = [0.0, 0.0, 0.01, 0.99]
    seg = np.zeros(10, np.int64)
    once, twice = segment_consistent(p, seg), segment_consistent(p, seg, power=2.0)
    np.testing.assert_allclose(twice.sum(1), 1, rtol=1e-5)
    assert once[8].argmax() == 3 and twice[8].argmax() == 2
    assert once[9].argmax() == 3 and twice[9].argmax() == 3
    np.testing.assert_array_equal(segment_consistent(p, seg, power=1.0), once)


def test_floor_and_ceiling_heights():
    p, lab, scene, _ = room_scan(4, head_steps=8)
    nz = np.abs(_ext.voxel_local_shape(p, 0.05, 1)[:, 2])
    zf, zc = floor_and_ceiling(p[:, 2], nz)
    assert abs(zf - 0.0) < 0.03 and abs(zc - scene.height) < 0.03


def test_metrics_on_a_known_confusion():
    truth = np.array([0, 0, 1, 1, 2, 2, 3, 3, 7])  # 7: outside the classes, ignored
    pred = np.array([0, 0, 1, 2, 2, 2, 3, 0, 0])
    c = confusion(truth, pred)
    assert c.sum() == 8 and c[1, 2] == 1 and c[3, 0] == 1
    np.testing.assert_allclose(iou(c), [2 / 3, 1 / 2, 2 / 3, 1 / 2])
    assert overall_accuracy(c) == pytest.approx(6 / 8)


def test_shipped_model_on_unseen_rooms():
    """Rooms from seeds the shipped weights never saw, 3 cm range noise; IoU from the confusion
    summed over the rooms (one room can hold only a few thousand "other" points)."""
    assert DEFAULT_WEIGHTS.is_file()
    seg = Segmenter()
    total = np.zeros((4, 4), np.int64)
    for seed in (9001, 9002):
        p, lab, _, _ = room_scan(seed, head_steps=12)
        pred = seg(p)
        assert pred.shape == lab.shape and pred.dtype == np.int32
        total += confusion(lab, pred)
    ious = iou(total)
    # measured 0.991 / 0.990 / 0.942 / 0.783
    assert ious[0] > 0.98 and ious[1] > 0.98, ious
    assert ious[2] > 0.92, ious
    assert ious[3] > 0.74, ious


def test_partition_walls_are_walls():
    """Two rooms split by a partition with a door, from unseen seeds: the partition does not
    bound the scanned space (the other room is behind it), so only its plane - metres long,
    floor to ceiling - tells it from furniture. It was the largest error of the first model
    (13 % of a held-out capture's partition called "other"). The plane-consistency stage must
    remove wall -> other errors, not add them."""
    seg, seg_1 = Segmenter(), Segmenter(plane_consistency=False)
    total = np.zeros((4, 4), np.int64)
    part_ok = part_n = wall_as_other = wall_as_other_1 = 0
    for seed in (9011, 9012):
        p, lab, scene, _ = room_scan(seed, kind="two_rooms", head_steps=10)
        pred = seg(p)
        total += confusion(lab, pred)
        lo, hi = scene.vertices.min(0), scene.vertices.max(0)
        # wall points away from the outer walls: the partition (and its door lintel)
        inner = ((lab == 2) & (p[:, 0] > lo[0] + 0.3) & (p[:, 0] < hi[0] - 0.3)
                 & (p[:, 1] > lo[1] + 0.3) & (p[:, 1] < hi[1] - 0.3))
        part_ok += int((pred[inner] == 2).sum())
        part_n += int(inner.sum())
        wall_as_other += int(((lab == 2) & (pred == 3)).sum())
        wall_as_other_1 += int(((lab == 2) & (seg_1(p) == 3)).sum())
    assert part_n > 10_000
    # measured with the weights of issue 15: 0.989 of the partition, 704 wall -> other against
    # 1094 without the stage; with the weights trained on generated buildings (issue 18) the
    # network alone makes few such errors (75, and 76 with the stage): the stage must not add
    # more than a handful, and the errors stay under 1 % of the partition
    assert part_ok / part_n > 0.98, part_ok / part_n
    assert wall_as_other <= wall_as_other_1 + 0.002 * part_n, (wall_as_other, wall_as_other_1)
    assert wall_as_other < 0.01 * part_n, (wall_as_other, part_n)
    ious = iou(total)
    assert ious[2] > 0.96 and ious[3] > 0.71, ious


def test_segmenter_is_invariant_to_yaw_and_position():
    p, lab, _, _ = room_scan(9003, head_steps=8)
    seg = Segmenter()
    a = seg(p)
    c, s = np.cos(1.1), np.sin(1.1)
    q = p @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32).T + np.float32([40, -7, 3])
    b = seg(q)
    assert (a == b).mean() > 0.985  # measured 0.9935


def test_training_learns_and_is_seeded(tmp_path):
    from tripod_processor.scene.segmentation.model import load_model, save_weights
    from tripod_processor.scene.segmentation.train import features_of, train

    clouds = [room_scan(s, head_steps=6)[:2] for s in (11, 12)]
    F, L = features_of(clouds, copies=1, seed=0, keep_per_copy=40_000)
    m1, r1 = train(F, L, seed=3, steps=120, batch=1024, num_threads=1)
    m2, r2 = train(F, L, seed=3, steps=120, batch=1024, num_threads=1)
    assert r1.final_loss == r2.final_loss
    save_weights(m1, tmp_path / "w.npz", {"seed": 3})
    model, meta = load_model(tmp_path / "w.npz")
    assert meta["seed"] == 3 and meta["feature_names"] == list(FEATURE_NAMES)
    import torch

    with torch.inference_mode():
        acc = (model(torch.from_numpy(F)).argmax(1).numpy() == L).mean()
    assert acc > 0.97, acc  # measured 0.993; chance is ~0.35


def test_cli_segment_keeps_points_and_order(tmp_path, capsys):
    p, lab, _, _ = room_scan(9004, head_steps=6)
    src = tmp_path / "in.ply"
    write_ply(src, make_cloud(p, truth=lab.astype(np.int32), intensity=np.arange(len(p), dtype=np.float32)))
    out = tmp_path / "out.pcd"
    assert main(["segment", str(src), "-o", str(out), "--truth-field", "truth"]) == 0
    c = read_cloud(out)
    assert set(c.dtype.names) >= {"x", "y", "z", "intensity", "truth", "label"}
    np.testing.assert_array_equal(c["x"], p[:, 0])
    np.testing.assert_array_equal(c["intensity"], np.arange(len(p), dtype=np.float32))
    assert set(np.unique(c["label"])) <= {0, 1, 2, 3}
    assert "IoU" in capsys.readouterr().err
    assert "plane_consistency: true" in (tmp_path / "out.config.yaml").read_text()
    # the second stage can be turned off; labels stay in the contract
    assert main(["segment", str(src), "-o", str(tmp_path / "raw.ply"), "--no-plane-consistency"]) == 0
    assert "plane_consistency: false" in (tmp_path / "raw.config.yaml").read_text()
    assert set(np.unique(read_cloud(tmp_path / "raw.ply")["label"])) <= {0, 1, 2, 3}


def test_cli_segment_bad_input_is_one_line(tmp_path, capsys):
    assert main(["segment", str(tmp_path / "missing.ply"), "-o", str(tmp_path / "o.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such file" in err[0]
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    assert main(["segment", str(bad), "-o", str(tmp_path / "o.ply")]) == 2
    assert main(["segment", str(bad), "-o", str(tmp_path / "o.txt")]) == 2


def test_fast_inference_path_is_the_model_bitwise():
    """``Segmenter.__call__`` (network in chunks with addmm and in-place ReLU, argmax per voxel,
    planar segments on a second thread) gives exactly what the plain model, the unthreaded
    features and the per-point probabilities give."""
    import torch

    from tripod_processor.preprocess import voxel_assign
    from tripod_processor.scene.segmentation import plane_consistent
    from tripod_processor.scene.segmentation.features import voxel_features

    p, _, _, _ = room_scan(9004, head_steps=8)
    p = np.concatenate([p, np.full((3, 3), np.nan, np.float32)])  # non-finite points too
    seg = Segmenter()
    f, pv, sg, cen = voxel_features(p, return_segments=True, return_centroids=True)
    with torch.inference_mode():
        if seg.stacked:  # two stages: the second on the voxels the first doubts
            from tripod_processor.scene.segmentation import STAGE2_GATE
            from tripod_processor.scene.segmentation.context import context_features

            p1 = torch.softmax(seg.model.stage1(torch.from_numpy(f)), 1).numpy()
            x = np.hstack([f, context_features(p1, sg, cen)])
            p2 = torch.softmax(seg.model.stage2(torch.from_numpy(x)), 1).numpy()
            prob = np.where((p1.max(1) < STAGE2_GATE)[:, None], p2, p1)
        else:
            prob = torch.softmax(seg.model(torch.from_numpy(f)), 1).numpy()
    prob = plane_consistent(prob, f, sg)
    want = np.where(pv >= 0, prob.argmax(1)[pv], 3)
    np.testing.assert_array_equal(seg(p), want)
    np.testing.assert_array_equal(Segmenter(chunk=1000)(p), want)
    np.testing.assert_array_equal(Segmenter(num_threads=1)(p), want)  # no second thread
    np.testing.assert_array_equal(seg.probabilities(p)[pv >= 0], prob[pv[pv >= 0]])
    # voxel grids of more points than one thread sorts alone: the same voxels as numpy's
    q = np.random.default_rng(1).uniform(-3, 3, (300_000, 3)).astype(np.float32)
    cen, qv, counts = voxel_assign(q, 0.25, 2)
    keys, inv, cnt = np.unique(np.floor(q / np.float32(0.25)).astype(np.int64), axis=0,
                               return_inverse=True, return_counts=True)
    assert len(cen) == len(keys) and np.array_equal(np.sort(counts), np.sort(cnt))
    np.testing.assert_array_equal(np.bincount(qv, minlength=len(cen)), counts)


def test_coplanar_pairs_are_those_of_the_full_matrix():
    """``wall_planes``' pairs found by one sort on the offsets are exactly the pairs of the k x k
    test (angles near 0 and near pi wrap, the offset's sign flips), in the same order."""
    from tripod_processor.scene.segmentation.segments import (PLANE_MAX_ANGLE_DEG,
                                                              PLANE_MAX_OFFSET, _coplanar_pairs)

    rng = np.random.default_rng(5)
    for k in (2, 40, 900):
        # a few wall directions (one of them just below pi: wraps to 0) and offset lines
        th = (rng.choice([0.0, 0.7, np.pi / 2, np.pi - 0.01], k) + rng.normal(0, 0.03, k)) % np.pi
        off = rng.choice(np.arange(-3, 3.01, 0.5), k) + rng.normal(0, 0.02, k)
        dth = np.abs(th[:, None] - th[None, :])
        wrap = dth > np.pi / 2
        dth = np.where(wrap, np.pi - dth, dth)
        doff = np.abs(off[:, None] - np.where(wrap, -off[None, :], off[None, :]))
        a, b = np.nonzero(np.triu((dth < np.deg2rad(PLANE_MAX_ANGLE_DEG))
                                  & (doff < PLANE_MAX_OFFSET), 1))
        got = _coplanar_pairs(th, off)
        assert len(a) > 0 or k == 2
        np.testing.assert_array_equal(got[0], a)
        np.testing.assert_array_equal(got[1], b)


def test_wall_planes_cost_grows_with_the_building_not_its_square():
    """Regression guard (issue 18's throughput): on a tall building (dev seed, 7.8 m; 9.6 m in
    generator 3) twice over, ``wall_planes`` costs under half the CPU time of the 10 cm
    ``planar_segments`` it follows (0.23-0.31 measured; the all-pairs matrix and a pass over
    every candidate voxel per plane gave 0.67-1.04, growing with the building). CPU time of this
    process, best of 3: valid on a loaded machine, unlike wall time."""
    import os
    import time

    from tripod_processor.preprocess import voxel_assign
    from tripod_processor.scene.segmentation.segments import wall_planes
    from tripod_processor.sim.procedural import labelled_scan

    p = labelled_scan("rooms", 500_001, n_stations=2, head_steps=12)[0]
    ext = p.max(0) - p.min(0)  # a second copy beside the first: a building twice as large
    q = np.concatenate([p, p + np.array([ext[0] + 3, ext[1] + 3, 0], np.float32)])
    cen, _, _ = voxel_assign(q, 0.04, 1)

    def cpu(f, *args):
        best = np.inf
        for _ in range(3):
            t0 = time.process_time()
            out = f(*args)
            best = min(best, time.process_time() - t0)
        return best, out

    t_seg, (_, _, seg, _) = cpu(lambda: planar_segments(cen, 1, residual=True))
    t_planes, planes = cpu(wall_planes, cen, seg)
    assert planes.max() > 50  # the walls of both copies are planes
    assert t_planes < 0.5 * t_seg, (t_planes, t_seg, os.getloadavg())
