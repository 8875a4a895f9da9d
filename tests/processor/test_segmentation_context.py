# SPDX-License-Identifier: BSD-3-Clause
"""The segmenter's second stage (auto-context, issue 18): context aggregation, the two-stage
weight file, training on whole copies."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_processor.scene.segmentation import DEFAULT_WEIGHTS, Segmenter
from tripod_processor.scene.segmentation.context import CONTEXT_NAMES, context_features
from tripod_processor.scene.segmentation.features import FEATURE_NAMES, voxel_features
from tripod_processor.scene.segmentation.model import (STAGE2_INPUTS, Stacked, build_model,
                                                       load_model, save_weights)

from scene_fixtures import room_scan


def _col(name: str) -> int:
    return CONTEXT_NAMES.index(name)


def test_context_means_over_segments_boxes_and_column():
    # five voxels: 0-2 one x-y column 0.3 m cell (z 0.1, 0.5, 0.9), 3 beside it in the same
    # 1 m box, 4 far away; segments: 0 and 1 share the 10 cm segment, 2 has none
    cen = np.array([[0.05, 0.05, 0.1], [0.05, 0.05, 0.5], [0.1, 0.1, 0.9],
                    [0.5, 0.5, 0.1], [5.0, 5.0, 0.1]], np.float32)
    p = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [.25, .25, .25, .25]],
                 np.float32)
    seg = np.array([[0, 0, -1], [0, 0, -1], [-1, 1, -1], [1, 0, 5], [2, 2, 5]])
    ctx = context_features(p, seg, cen)
    assert ctx.shape == (5, len(CONTEXT_NAMES))
    np.testing.assert_allclose(ctx[:, 0:4], p)
    # 10 cm segment: voxels 0, 1 share one (mean), voxel 2 has none (its own)
    np.testing.assert_allclose(ctx[0, 4:8], [.5, .5, 0, 0])
    np.testing.assert_allclose(ctx[2, 4:8], p[2])
    # 25 cm segment 0: voxels 0, 1, 3
    np.testing.assert_allclose(ctx[3, 8:12], [1 / 3, 1 / 3, 0, 1 / 3], rtol=1e-6)
    # wall plane 5: voxels 3, 4; voxels without a plane keep their own
    np.testing.assert_allclose(ctx[4, 12:16], [.125, .125, .125, .625])
    np.testing.assert_allclose(ctx[1, 12:16], p[1])
    # 0.3 m box: voxel 0 alone in its cube (1 is 0.4 m above it); 1 m box: voxels 0-3
    np.testing.assert_allclose(ctx[0, 16:20], p[0])
    np.testing.assert_allclose(ctx[0, 20:24], [.25, .25, .25, .25])
    np.testing.assert_allclose(ctx[4, 20:24], p[4])
    # column: voxel 1 has 0 below and 2 above; 0 has nothing below, 1 and 2 above
    np.testing.assert_allclose(ctx[1, 24:28], p[0])
    np.testing.assert_allclose(ctx[1, 28:32], p[2])
    np.testing.assert_allclose(ctx[0, 24:28], 0)
    np.testing.assert_allclose(ctx[0, 28:32], [0, .5, .5, 0])
    np.testing.assert_allclose(ctx[:, _col("ctx_log_below")], np.log1p([0, 1, 2, 0, 0]))
    np.testing.assert_allclose(ctx[:, _col("ctx_log_above")], np.log1p([2, 1, 0, 0, 0]))
    with pytest.raises(ValueError, match="segments and centroids"):
        context_features(p, seg[:, :2], cen)


def test_context_is_invariant_to_the_order_of_the_voxels():
    rng = np.random.default_rng(0)
    cen = rng.uniform(0, 3, (400, 3)).astype(np.float32)
    p = rng.dirichlet(np.ones(4), 400).astype(np.float32)
    seg = rng.integers(-1, 20, (400, 3))
    perm = rng.permutation(400)
    a = context_features(p, seg, cen)[perm]
    b = context_features(p[perm], seg[perm], cen[perm])
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def _stacked(seed: int) -> Stacked:
    import torch

    torch.manual_seed(seed)
    return Stacked(build_model(len(FEATURE_NAMES), (16,)), build_model(STAGE2_INPUTS, (8, 8)))


def test_two_stage_weight_file_round_trip(tmp_path):
    model = _stacked(1)
    save_weights(model, tmp_path / "w.npz", {"seed": 1})
    got, meta = load_model(tmp_path / "w.npz")
    assert isinstance(got, Stacked)
    assert meta["stages"] == 2 and meta["hidden"] == [16] and meta["hidden2"] == [8, 8]
    assert meta["context_names"] == list(CONTEXT_NAMES) and meta["seed"] == 1
    for a, b in ((model.stage1, got.stage1), (model.stage2, got.stage2)):
        sa, sb = a.state_dict(), b.state_dict()
        assert sa.keys() == sb.keys()
        for k in sa:
            assert np.array_equal(sa[k].numpy(), sb[k].numpy()), k
    p = room_scan(11, head_steps=6)[0]
    lab1 = Segmenter(model=model, num_threads=1)(p)
    lab2 = Segmenter(tmp_path / "w.npz", num_threads=1)(p)
    assert np.array_equal(lab1, lab2)
    # the second stage changes the answer: it is not the first network's alone
    f, pv, sg, cen = voxel_features(p, 1, return_segments=True, return_centroids=True)
    two = Segmenter(model=model, num_threads=1, plane_consistency=False)
    one = Segmenter(model=model.stage1, num_threads=1, plane_consistency=False)
    assert not np.allclose(two.probabilities_of(f, pv, sg, cen), one.probabilities_of(f, pv, sg))
    with pytest.raises(ValueError, match="centroids"):
        two.probabilities_of(f, pv, sg)


def test_single_stage_files_still_load(tmp_path):
    from torch import nn

    model, meta = load_model(DEFAULT_WEIGHTS)
    if meta.get("stages", 1) == 1:  # the shipped file may itself be two-stage
        assert isinstance(model, nn.Sequential) and not Segmenter(DEFAULT_WEIGHTS).stacked
    single = build_model(len(FEATURE_NAMES), (16,))
    save_weights(single, tmp_path / "s.npz", {"seed": 0})
    got, meta = load_model(tmp_path / "s.npz")
    assert isinstance(got, nn.Sequential) and "stages" not in meta
    p = room_scan(11, head_steps=6)[0]
    assert np.array_equal(Segmenter(model=single, num_threads=1)(p),
                          Segmenter(tmp_path / "s.npz", num_threads=1)(p))


def test_stacked_training_on_whole_copies_is_seeded_and_learns():
    from tripod_processor.scene.segmentation.train import copies_of, features_of, train_stacked

    clouds = [room_scan(s, head_steps=6)[:2] for s in (11, 12)]
    copies = list(copies_of(clouds, copies=1, seed=0, keep_per_copy=20_000))
    F, L = features_of(clouds, copies=1, seed=0, keep_per_copy=20_000)
    # the rows of the single-stage path are the copies' sampled voxels
    assert np.array_equal(F, np.concatenate([c.features[c.rows] for c in copies]))
    assert np.array_equal(L, np.concatenate([c.labels for c in copies]))
    assert all(len(c.features) == len(c.segment) == len(c.centroids) for c in copies)
    kw = dict(seed=3, steps=80, batch=1024, hidden=(32,), hidden2=(32,), num_threads=1)
    m1, r1 = train_stacked(copies, **kw)
    m2, r2 = train_stacked(copies, **kw)
    assert [r.final_loss for r in r1] == [r.final_loss for r in r2] and len(r1) == 2
    p, lab = clouds[0]
    acc = (Segmenter(model=m1, num_threads=1)(p) == lab).mean()
    assert acc > 0.9, acc


def test_cli_trains_two_stages(tmp_path):
    from tripod_processor.cli import main

    p, lab = room_scan(11, head_steps=6)[:2]
    np.savez(tmp_path / "room.npz", points=p, labels=lab)
    out = tmp_path / "w.npz"
    args = ["train-segmenter", "-o", str(out), "--data", str(tmp_path / "room.npz"), "--steps",
            "30", "--batch", "512", "--copies", "1", "--keep", "20000", "--threads", "1",
            "--hidden", "16", "--hidden2", "8"]
    assert main(args + ["--stages", "2", "--steps2", "20"]) == 0
    model, meta = load_model(out)
    assert isinstance(model, Stacked) and meta["steps2"] == 20 and meta["hidden2"] == [8]
    assert main(args + ["--stages", "3"]) == 2
