# SPDX-License-Identifier: BSD-3-Clause
"""Segmentation: native features, the shipped model on unseen rooms, training, metrics, CLI."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_processor import _ext
from tripod_processor.cli import main
from tripod_processor.cloud_io import make_cloud, read_cloud, write_ply
from tripod_processor.segmentation import DEFAULT_WEIGHTS, Segmenter, point_features
from tripod_processor.segmentation.features import FEATURE_NAMES, floor_and_ceiling
from tripod_processor.segmentation.metrics import confusion, iou, overall_accuracy

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
    assert ious[0] > 0.95 and ious[1] > 0.95, ious
    assert ious[2] > 0.85, ious
    assert ious[3] > 0.6, ious


def test_segmenter_is_invariant_to_yaw_and_position():
    p, lab, _, _ = room_scan(9003, head_steps=8)
    seg = Segmenter()
    a = seg(p)
    c, s = np.cos(1.1), np.sin(1.1)
    q = p @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32).T + np.float32([40, -7, 3])
    b = seg(q)
    assert (a == b).mean() > 0.97


def test_training_learns_and_is_seeded(tmp_path):
    from tripod_processor.segmentation.model import load_model, save_weights
    from tripod_processor.segmentation.train import features_of, train

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
    assert acc > 0.85, acc  # chance is ~0.35


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
    assert (tmp_path / "out.config.yaml").is_file()


def test_cli_segment_bad_input_is_one_line(tmp_path, capsys):
    assert main(["segment", str(tmp_path / "missing.ply"), "-o", str(tmp_path / "o.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such file" in err[0]
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    assert main(["segment", str(bad), "-o", str(tmp_path / "o.ply")]) == 2
    assert main(["segment", str(bad), "-o", str(tmp_path / "o.txt")]) == 2
