# SPDX-License-Identifier: BSD-3-Clause
"""S3DIS loader on a fixture written in the dataset's layout, with its known defects; class map;
Area-5 and 6-fold evaluation; training from it through the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_processor.cli import main
from tripod_processor.scene.segmentation.s3dis import (S3DIS_CLASSES, S3DIS_TO_TRIPOD, S3DISError,
                                                 area5_split, evaluate, iter_rooms, load_room,
                                                 parse_annotation, room_dirs, six_fold_splits)


def _box_room(rng, w, d, h, n=1500):
    """Annotations of a small box room: {name: (N, 6) x y z r g b}."""
    out = {}
    xy = rng.uniform([0, 0], [w, d], (n, 2))
    out["floor_1"] = np.c_[xy, np.zeros(n)]
    out["ceiling_1"] = np.c_[rng.uniform([0, 0], [w, d], (n, 2)), np.full(n, h)]
    walls = []
    for k, (x0, y0, x1, y1) in enumerate([(0, 0, w, 0), (w, 0, w, d), (w, d, 0, d), (0, d, 0, 0)]):
        t = rng.uniform(0, 1, n // 2)
        walls.append(np.c_[x0 + t * (x1 - x0), y0 + t * (y1 - y0), rng.uniform(0, h, n // 2)])
        out[f"wall_{k + 1}"] = walls[-1]
    out["table_1"] = np.c_[rng.uniform([1, 1], [2, 1.8], (400, 2)), np.full(400, 0.75)]
    out["chair_1"] = np.c_[rng.uniform([2.5, 1], [2.9, 1.4], (200, 2)), rng.uniform(0, 0.9, 200)]
    out["door_1"] = np.c_[np.full(200, 0.02), rng.uniform(0.5, 1.4, 200), rng.uniform(0, 2, 200)]
    for k, v in out.items():
        out[k] = np.c_[v + rng.normal(0, 0.003, v.shape), rng.integers(0, 256, (len(v), 3))]
    return out


def _write_room(room_dir, ann):
    (room_dir / "Annotations").mkdir(parents=True)
    whole = []
    for name, arr in ann.items():
        lines = "\n".join(f"{x:.6f} {y:.6f} {z:.6f} {int(r)} {int(g)} {int(b)}" for x, y, z, r, g, b in arr)
        (room_dir / "Annotations" / f"{name}.txt").write_text(lines + "\n")
        whole.append(lines)
    (room_dir / f"{room_dir.name}.txt").write_text("\n".join(whole) + "\n")


@pytest.fixture(scope="module")
def s3dis_root(tmp_path_factory):
    """Six areas of two small rooms each, in the documented layout, with the known defects."""
    root = tmp_path_factory.mktemp("Stanford3dDataset_v1.2_Aligned_Version")
    rng = np.random.default_rng(0)
    for a in range(1, 7):
        names = ["office_1", "hallway_6" if a == 5 else "hallway_1"]
        if a == 5:
            names.append("office_36")
        for name in names:
            _write_room(root / f"Area_{a}" / name, _box_room(rng, *rng.uniform([3, 3, 2.5], [6, 5, 3.2])))
    # defect 1: a stray non-numeric byte inside a line of hallway_6's ceiling_1.txt
    f = root / "Area_5" / "hallway_6" / "Annotations" / "ceiling_1.txt"
    lines = f.read_text().splitlines()
    x, y, z, r, g, b = lines[179].split()
    lines[179] = f"{x} {y} {z} {r} {g}\x10 {b}"
    f.write_text("\n".join(lines) + "\n")
    # defect 2: a duplicated file "wall_3 (1).txt" in office_36
    ann = root / "Area_5" / "office_36" / "Annotations"
    (ann / "wall_3 (1).txt").write_bytes((ann / "wall_3.txt").read_bytes())
    # and an unknown class name, as in some real rooms
    (ann / "stairs_1.txt").write_text("0.5 0.5 0.1 10 10 10\n0.6 0.5 0.2 10 10 10\n")
    return root


def test_layout_and_counts(s3dis_root):
    dirs = room_dirs(s3dis_root)
    assert len(dirs) == 13 and {a for a, _ in dirs} == set(range(1, 7))
    rooms = list(iter_rooms(s3dis_root, [1]))
    assert [r.name for r in rooms] == ["hallway_1", "office_1"]
    r = rooms[0]
    assert r.points.dtype == np.float32 and r.points.shape[1] == 3 and r.rgb.dtype == np.uint8
    assert len(r.points) == 1500 * 2 + 4 * 750 + 400 + 200 + 200
    assert r.issues == []


def test_stray_byte_is_repaired_and_reported(s3dis_root):
    room = load_room(s3dis_root / "Area_5" / "hallway_6", 5)
    ceiling = room.labels13 == S3DIS_CLASSES.index("ceiling")
    assert ceiling.sum() == 1500  # no line lost
    assert any("stray byte" in s and "line 180" in s for s in room.issues), room.issues
    assert np.isfinite(room.points).all()


def test_duplicate_file_is_skipped_and_unknown_class_mapped(s3dis_root):
    room = load_room(s3dis_root / "Area_5" / "office_36", 5)
    assert any("wall_3 (1).txt" in s and "duplicate" in s for s in room.issues)
    assert (room.labels13 == S3DIS_CLASSES.index("wall")).sum() == 4 * 750  # not 5 x
    assert any("stairs" in s for s in room.issues)
    assert (room.labels13 == S3DIS_CLASSES.index("clutter")).sum() == 2


def test_unparseable_lines_are_skipped():
    arr, issues = parse_annotation(b"1 2 3 4 5 6\n1 2 3\n7 8 9 10 11 12\n", "x.txt")
    assert arr.shape == (2, 6) and "skipped 1" in issues[0]
    arr, issues = parse_annotation(b"1 2 3 4 5 6\n1 2 3 4 5x 6\n", "y.txt")
    assert arr.shape == (2, 6) and arr[1, 4] == 5 and "stray byte" in issues[0]
    arr, issues = parse_annotation(b"1 2 3 4 5 6\n1 2 3 4 5 6e\n", "z.txt")  # not a number
    assert arr.shape == (1, 6) and "skipped 1" in issues[0]


def test_class_map():
    assert len(S3DIS_CLASSES) == 13 and len(S3DIS_TO_TRIPOD) == 13
    m = dict(zip(S3DIS_CLASSES, S3DIS_TO_TRIPOD))
    assert (m["ceiling"], m["floor"], m["wall"]) == (0, 1, 2)
    # the one convention (sim.procedural.CONVENTION): windows and doors lie in the wall
    assert m["window"] == 2 and m["door"] == 2
    assert all(m[c] == 3 for c in S3DIS_CLASSES[3:] if c not in ("window", "door"))
    from tripod_processor.sim.procedural import CONVENTION

    for s3dis_class, part in (("ceiling", "ceiling"), ("floor", "floor"), ("wall", "wall"),
                              ("window", "window"), ("door", "door_closed"), ("beam", "beam"),
                              ("column", "column"), ("board", "wall_item"), ("table", "furniture"),
                              ("clutter", "clutter")):
        assert m[s3dis_class] == CONVENTION[part][0], s3dis_class


def test_missing_layout_is_an_error(tmp_path):
    with pytest.raises(S3DISError):
        room_dirs(tmp_path / "nope")
    (tmp_path / "Area_1").mkdir()
    with pytest.raises(S3DISError, match="Area_2"):
        room_dirs(tmp_path, [1, 2])


def test_splits():
    assert area5_split() == [((1, 2, 3, 4, 6), 5)]
    folds = six_fold_splits()
    assert sorted(t for _, t in folds) == [1, 2, 3, 4, 5, 6]
    assert all(t not in tr and len(tr) == 5 for tr, t in folds)


def test_area5_and_six_fold_evaluation(s3dis_root):
    """Train the real model per fold (few steps) and score the held-out area; the confusion is
    summed over rooms and folds."""
    from tripod_processor.scene.segmentation import Segmenter
    from tripod_processor.scene.segmentation.metrics import iou
    from tripod_processor.scene.segmentation.train import features_of, train

    trained_on = []

    def train_fn(rooms):
        trained_on.append(sorted({r.area for r in rooms}))
        F, L = features_of([(r.points, r.labels4) for r in rooms], copies=1, seed=0)
        model, _ = train(F, L, steps=150, batch=1024, num_threads=1)
        return model

    def predict_fn(model, points):
        import torch

        from tripod_processor.scene.segmentation.features import voxel_features

        f, point_voxel = voxel_features(points)
        with torch.inference_mode():
            return model(torch.from_numpy(f)).argmax(1).numpy()[point_voxel]

    conf5, per5 = evaluate(s3dis_root, area5_split(), train_fn, predict_fn)
    n5 = sum(len(r.points) for r in iter_rooms(s3dis_root, [5]))
    assert conf5.sum() == n5 and trained_on == [[1, 2, 3, 4, 6]]
    ious = iou(conf5)
    assert ious[0] > 0.9 and ious[1] > 0.9, ious
    conf6, per6 = evaluate(s3dis_root, six_fold_splits(), train_fn, predict_fn)
    assert len(per6) == 6 and conf6.sum() == sum(len(r.points) for r in iter_rooms(s3dis_root))
    np.testing.assert_array_equal(conf6, sum(per6))
    assert Segmenter is not None


def test_cli_train_segmenter_on_s3dis(s3dis_root, tmp_path):
    out = tmp_path / "w.npz"
    assert main(["train-segmenter", "-o", str(out), "--s3dis", str(s3dis_root), "--steps", "40",
                 "--batch", "512", "--copies", "1", "--threads", "1"]) == 0
    from tripod_processor.scene.segmentation.model import load_model

    _, meta = load_model(out)
    assert meta["s3dis_areas"] == "1,2,3,4,6" and meta["steps"] == 40
    assert main(["train-segmenter", "-o", str(out), "--s3dis", str(tmp_path / "none")]) == 2


def test_cli_s3dis_eval(s3dis_root, capsys):
    assert main(["s3dis-eval", str(s3dis_root), "--protocol", "area5", "--steps", "40",
                 "--threads", "1"]) == 0
    err = capsys.readouterr().err
    assert "IoU" in err and "ceiling" in err and "overall accuracy" in err
    assert main(["s3dis-eval", str(s3dis_root), "--protocol", "7fold"]) == 2
    assert main(["s3dis-eval", str(s3dis_root.parent / "missing")]) == 2
