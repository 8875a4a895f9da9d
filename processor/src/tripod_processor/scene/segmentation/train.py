# SPDX-License-Identifier: BSD-3-Clause
"""Training of the segmenter on labelled clouds, with the augmentations that carry it to real
scans: range noise, density, tilt, yaw and position; simulated scenes add room sizes, shapes and
clutter. Deterministic for a given seed (single-threaded sampling, seeded torch).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from .context import context_features
from .features import voxel_features
from .model import NUM_CLASSES, Stacked, build_model


@dataclass
class TrainReport:
    seconds: float
    points: int
    steps: int
    final_loss: float
    class_counts: list


def augment(points: np.ndarray, labels: np.ndarray, rng: np.random.Generator,
            max_tilt_deg: float = 2.0, max_noise_m: float = 0.01,
            min_keep: float = 0.35) -> tuple[np.ndarray, np.ndarray]:
    """A randomly perturbed copy of a labelled cloud: subsampled, jittered, tilted, turned, moved.

    points : (N, 3) [m]; labels : (N,). Returns float32 points and the matching labels.
    """
    keep = rng.random(len(points)) < rng.uniform(min_keep, 1.0)
    p = np.asarray(points, np.float64)[keep]
    lab = np.asarray(labels)[keep]
    p = p + rng.normal(0, rng.uniform(0, max_noise_m), p.shape)
    yaw = rng.uniform(-np.pi, np.pi)
    tilt = np.deg2rad(rng.uniform(0, max_tilt_deg))
    axis = rng.normal(size=3)
    axis[2] = 0
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R_tilt = np.eye(3) + np.sin(tilt) * K + (1 - np.cos(tilt)) * K @ K
    c, s = np.cos(yaw), np.sin(yaw)
    R = R_tilt @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    centre = np.nanmean(p, 0)
    p = (p - centre) @ R.T + centre + rng.uniform(-20, 20, 3) * [1, 1, 0.1]
    return p.astype(np.float32), lab


@dataclass
class CopyRows:
    """One augmented copy of a labelled cloud, whole: what the second stage's context needs.

    features : (M, F) float32 of all its voxels; segment : (M, 3) int64 and centroids : (M, 3)
    float32 [m] of them (``voxel_features(..., return_segments=True, return_centroids=True)``);
    rows : (K,) int64 voxel of each sampled point; labels : (K,) int64 the point's label.
    """
    features: np.ndarray
    segment: np.ndarray
    centroids: np.ndarray
    rows: np.ndarray
    labels: np.ndarray


class CopyStore:
    """:class:`CopyRows` kept on disk (one ``.npz`` each, uncompressed, in ``directory``) and
    read back one at a time on every iteration: the copies of 140 buildings are ~6 GB whole,
    the second stage needs them twice (stage 1's rows, then its probabilities over each)."""

    def __init__(self, directory) -> None:
        from pathlib import Path

        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.files = sorted(self.directory.glob("copy_*.npz"))

    def add(self, c: CopyRows) -> None:
        fn = self.directory / f"copy_{len(self.files):05d}.npz"
        np.savez(fn, features=c.features, segment=c.segment.astype(np.int32),
                 centroids=c.centroids, rows=c.rows, labels=c.labels)
        self.files.append(fn)

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self):
        for fn in self.files:
            with np.load(fn) as z:
                yield CopyRows(z["features"], z["segment"].astype(np.int64), z["centroids"],
                               z["rows"], z["labels"])


def copies_of(clouds: Iterable[tuple[np.ndarray, np.ndarray]], copies: int, seed: int,
              progress: Callable | None = None, keep_per_copy: int = 400_000):
    """Yield a :class:`CopyRows` for each of ``copies`` augmented copies of every labelled cloud
    (the first copy unperturbed). Features are computed on the whole copy (context needs the
    full density), then at most ``keep_per_copy`` random points of it are sampled for
    training (the same draws as :func:`features_of`)."""
    rng = np.random.default_rng(seed)
    for points, labels in clouds:
        for k in range(copies):
            p, lab = (np.asarray(points, np.float32), np.asarray(labels)) if k == 0 else augment(
                points, labels, rng)
            f, point_voxel, segment, centroids = voxel_features(p, return_segments=True,
                                                                return_centroids=True)
            ok = np.flatnonzero((lab >= 0) & (lab < NUM_CLASSES) & (point_voxel >= 0))
            if len(ok) > keep_per_copy:
                ok = np.sort(rng.choice(ok, keep_per_copy, replace=False))
            # each sampled point: its voxel, its own label (voxels count by points)
            yield CopyRows(f, segment, centroids, point_voxel[ok].astype(np.int64),
                           lab[ok].astype(np.int64))
            if progress:
                progress()


def features_of(clouds: Iterable[tuple[np.ndarray, np.ndarray]], copies: int, seed: int,
                progress: Callable | None = None,
                keep_per_copy: int = 400_000) -> tuple[np.ndarray, np.ndarray]:
    """Features and labels of the sampled points of :func:`copies_of` (each point: its voxel's
    features, its own label)."""
    F, L = [], []
    for c in copies_of(clouds, copies, seed, progress, keep_per_copy):
        F.append(c.features[c.rows])
        L.append(c.labels)
    return np.concatenate(F), np.concatenate(L)


def stage2_rows(stage1, copies: Iterable[CopyRows]) -> tuple[np.ndarray, np.ndarray]:
    """Second-stage rows of the sampled points: the voxel's features and the context
    (:func:`.context.context_features`) of ``stage1``'s probabilities over its whole copy,
    computed as at inference (:class:`..Segmenter`, single-threaded). Stage 1's probabilities
    of its own training voxels are in-sample: it underfits (wall IoU on its training rows
    within 0.01 of unseen buildings), so they are close to what it gives on new clouds."""
    from . import Segmenter

    seg = Segmenter(model=stage1, num_threads=1, plane_consistency=False)
    X, L = [], []
    for c in copies:
        prob = seg._voxel_probabilities(c.features, c.segment)[:-1]
        ctx = context_features(prob, c.segment, c.centroids)
        X.append(np.hstack([c.features[c.rows], ctx[c.rows]]))
        L.append(c.labels)
    return np.concatenate(X), np.concatenate(L)


def train_stacked(copies, *, seed: int = 0, steps: int = 3000, steps2: int | None = None,
                  batch: int = 8192, lr: float = 3e-3, hidden=(128, 128), hidden2=(128, 128),
                  num_threads: int = 0, class_power: float = 0.5, stage1=None,
                  progress: Callable | None = None):
    """Two-stage (auto-context) segmenter: :func:`train` on the sampled rows of ``copies``
    (:class:`CopyRows`, a list or a :class:`CopyStore`: iterated twice; or the given
    ``stage1``), then a second network (``steps2`` steps, default ``steps``) on
    :func:`stage2_rows`. Returns (:class:`.model.Stacked`, [TrainReport of each stage
    trained])."""
    reports = []
    if stage1 is None:
        F = np.concatenate([c.features[c.rows] for c in copies])
        L = np.concatenate([c.labels for c in copies])
        stage1, r = train(F, L, seed=seed, steps=steps, batch=batch, lr=lr, hidden=hidden,
                          num_threads=num_threads, class_power=class_power, progress=progress)
        reports.append(r)
        del F, L
    X, L = stage2_rows(stage1, copies)
    stage2, r = train(X, L, seed=seed, steps=steps2 or steps, batch=batch, lr=lr, hidden=hidden2,
                      num_threads=num_threads, class_power=class_power, progress=progress)
    reports.append(r)
    return Stacked(stage1, stage2), reports


def train(features: np.ndarray, labels: np.ndarray, *, seed: int = 0, steps: int = 3000,
          batch: int = 8192, lr: float = 3e-3, hidden=(128, 128), num_threads: int = 0,
          class_power: float = 0.5, progress: Callable | None = None):
    """Train the per-point MLP; returns (model, TrainReport).

    features : (N, F) float32 from :func:`features_of`; labels : (N,) int in [0, 4)
    Classes are weighted by 1/frequency**class_power (0.5: 1/sqrt) so that the small "other"
    class is not drowned; the learning rate follows one cycle (warm-up, cosine decay) to ``lr``.
    """
    import torch

    t0 = time.perf_counter()
    torch.manual_seed(seed)
    if num_threads > 0:
        torch.set_num_threads(num_threads)
    rng = np.random.default_rng(seed)
    model = build_model(features.shape[1], hidden)
    X = torch.from_numpy(np.ascontiguousarray(features, np.float32))
    Y = torch.from_numpy(np.asarray(labels, np.int64))
    std = X.std(0)
    model[0].mean.copy_(X.mean(0))
    model[0].inv_std.copy_(1.0 / torch.clamp(std, min=1e-6))
    counts = np.bincount(labels, minlength=NUM_CLASSES).astype(np.float64)
    w = 1.0 / np.maximum(counts, 1) ** class_power
    w = w / (w * counts).sum() * counts.sum()
    loss_fn = torch.nn.CrossEntropyLoss(weight=torch.tensor(w, dtype=torch.float32))
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps)
    model.train()
    loss_avg = None
    for step in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(X), batch))
        loss = loss_fn(model(X[idx]), Y[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        li = float(loss.detach())
        loss_avg = li if loss_avg is None else 0.98 * loss_avg + 0.02 * li
        if progress:
            progress(step, loss_avg)
    model.eval()
    return model, TrainReport(time.perf_counter() - t0, len(X), steps, float(loss_avg or 0),
                              counts.astype(int).tolist())


# ----------------------------------------------------------------- procedural buildings
#: the recipe of the shipped weights (scripts/train_segmenter.sh): buildings per family of the
#: generator's train seeds, augmented copies, sampled points per copy, optimiser steps and batch,
#: widths, peak learning rate, class weights 1/frequency**class_power (fourth round of issue 18:
#: 9 000 steps instead of 3 000 and class_power 0.25 instead of 0.5, dev wall IoU +0.002)
#: Issue 18, fifth round: a second, auto-context stage (:mod:`.context`, :func:`train_stacked`) of
#: ``hidden2`` widths trained ``steps2`` steps on the same rows with stage 1's context
RECIPE = {"per_family": 20, "copies": 2, "keep_per_copy": 30_000, "steps": 9000, "batch": 4096,
          "hidden": (128, 128), "lr": 3e-3, "class_power": 0.25, "stages": 2,
          "hidden2": (128, 128), "steps2": 3000}


def procedural_clouds(family: str, split: str = "train", n: int = 20):
    """(points, labels) of ``n`` scans of generated buildings of ``family`` (``sim.procedural``:
    the split's seeds, one scan of 1-3 stations each)."""
    from ...sim.procedural import labelled_scan, split_seeds

    for s in split_seeds(split, n):
        yield labelled_scan(family, s)


def procedural_features(families, split: str = "train", per_family: int = RECIPE["per_family"],
                        copies: int = RECIPE["copies"], seed: int = 0,
                        keep_per_copy: int = RECIPE["keep_per_copy"],
                        progress: Callable | None = None) -> dict:
    """{family: (features, labels)} of :func:`procedural_clouds` with :func:`features_of`
    (augmentation drawn from ``seed`` and the family's index, so a family's rows do not depend
    on which other families are trained with it: leave-one-family-out reuses them)."""
    from ...sim.procedural import FAMILIES

    out = {}
    for fam in families:
        out[fam] = features_of(procedural_clouds(fam, split, per_family), copies,
                               seed=seed * 1000 + FAMILIES.index(fam), progress=progress,
                               keep_per_copy=keep_per_copy)
    return out


def procedural_copies(family: str, per_family: int = RECIPE["per_family"],
                      copies: int = RECIPE["copies"], seed: int = 0,
                      keep_per_copy: int = RECIPE["keep_per_copy"],
                      progress: Callable | None = None):
    """Yield the :class:`CopyRows` of ``family``'s train buildings (:func:`procedural_clouds`,
    :func:`copies_of`), drawn as :func:`procedural_features` draws them (the same sampled
    points); one at a time, since whole copies are large (~1 GB a family at the recipe)."""
    from ...sim.procedural import FAMILIES

    yield from copies_of(procedural_clouds(family, "train", per_family), copies,
                         seed=seed * 1000 + FAMILIES.index(family), progress=progress,
                         keep_per_copy=keep_per_copy)


def train_on_families(feats: dict, families, *, seed: int = 0, steps: int = RECIPE["steps"],
                      batch: int = RECIPE["batch"], hidden=RECIPE["hidden"], lr: float = RECIPE["lr"],
                      class_power: float = RECIPE["class_power"], num_threads: int = 0,
                      progress: Callable | None = None):
    """:func:`train` on the rows of ``families`` from :func:`procedural_features` (in the
    order given)."""
    F = np.concatenate([feats[f][0] for f in families])
    L = np.concatenate([feats[f][1] for f in families])
    return train(F, L, seed=seed, steps=steps, batch=batch, lr=lr, hidden=hidden,
                 num_threads=num_threads, class_power=class_power, progress=progress)
