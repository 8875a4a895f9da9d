# SPDX-License-Identifier: BSD-3-Clause
"""Scene understanding, part 1: label every point ceiling / floor / wall / other.

``segment(points)`` computes :mod:`.features` in the C++ core and runs the small per-point
network of :mod:`.model` (PyTorch, CPU); a second stage makes the points of one planar segment
(:mod:`.segments`) agree. A two-stage weight file (:class:`.model.Stacked`) runs a second network
on the features and the first one's probabilities aggregated over context (:mod:`.context`)
before that. :mod:`.train` trains it on labelled clouds (simulated
scenes, S3DIS via :mod:`.s3dis`); :mod:`.metrics` scores it.
Labels: 0 ceiling, 1 floor, 2 wall, 3 other.
"""

from __future__ import annotations

import numpy as np

from .features import FEATURE_NAMES, point_features, voxel_features
from .context import context_features
from .model import CLASS_NAMES, DEFAULT_WEIGHTS, NUM_CLASSES, Stacked, load_model
from .segments import segment_consistent

#: a voxel this far [m] off its segment's least-squares plane (a board or radiator on a wall,
#: whose voxels join the wall's segment) keeps its own label in the second stage
FINE_GATE = 0.02
COARSE_GATE = 0.03
#: the wall planes' mean enters the third pass squared: a plane joins segments metres apart,
#: its evidence outweighs a voxel's own more than a segment's does (dev buildings, issue 18:
#: wall IoU +0.001, other +0.003 summed on two draws of 3 buildings a family; ceiling and
#: floor unchanged)
PLANE_POWER = 2.0
#: two-stage models: voxels whose first-stage probability of one class is at least this keep it,
#: the second network runs on the others only (1.0: on every voxel). Dev buildings (issue 18,
#: 3 a family, shipped two-stage weights): 0.99 gives the IoU of 1.0 (summed within 0.0001)
#: at 2.23 instead of 3.20 us CPU a voxel for the networks and the context
STAGE2_GATE = 0.99


def plane_consistent(probabilities: np.ndarray, features: np.ndarray,
                     segment: np.ndarray) -> np.ndarray:
    """Second stage: the voxels of one planar segment agree, first on the 10 cm segments, then
    on the 25 cm ones (far and grazing walls, scanned by a few sparse lines, are one plane only
    at that scale), each leaving out the voxels that lie off the segment's plane
    (:data:`FINE_GATE`, :data:`COARSE_GATE`: boards and radiators on walls), then on the wall
    planes (:func:`.segments.wall_planes`: coplanar segments apart, a pier beside a door and
    the wall beyond it, and the sparse voxels on them; the plane's mean squared,
    :data:`PLANE_POWER`).

    probabilities : (M, 4); features : (M, F) of :func:`.features.voxel_features`;
    segment : (M, 3) segments of the two grids and wall planes, (M, 2) the two grids only, or
    (M,) the 10 cm grid only (then one pass).
    """
    seg = np.asarray(segment)
    if seg.ndim == 1:
        return segment_consistent(probabilities, seg)
    res = features[:, FEATURE_NAMES.index("segment_residual")]
    cres = features[:, FEATURE_NAMES.index("coarse_residual")]
    out = segment_consistent(probabilities, np.where(res > FINE_GATE, -1, seg[:, 0]))
    out = segment_consistent(out, np.where(cres > COARSE_GATE, -1, seg[:, 1]))
    return segment_consistent(out, seg[:, 2], PLANE_POWER) if seg.shape[1] > 2 else out

__all__ = ["segment", "Segmenter", "plane_consistent", "CLASS_NAMES", "NUM_CLASSES", "DEFAULT_WEIGHTS",
           "point_features"]


class Segmenter:
    """A loaded segmenter (keeps the model between clouds).

    Parameters
    ----------
    weights : path of a ``.npz`` weight file; None = the shipped weights
    num_threads : CPU threads for features and inference, 0 = all
    chunk : voxels per network batch (its activations, 128 floats a voxel, stay in cache)
    plane_consistency : second stage, the points of one planar segment agree
        (:func:`plane_consistent`)
    model : a torch model from :func:`.train.train` (or a :class:`.model.Stacked` from
        :func:`.train.train_stacked`) to use instead of a weight file
    stage2_gate : two-stage models: the second network runs on the voxels whose largest
        first-stage probability is below this (:data:`STAGE2_GATE`)
    """

    def __init__(self, weights=None, num_threads: int = 0, chunk: int = 1 << 15,
                 plane_consistency: bool = True, model=None,
                 stage2_gate: float = STAGE2_GATE) -> None:
        if model is not None:  # a freshly trained network (evaluation protocols)
            self.model, self.meta = model.eval(), {}
        else:
            self.model, self.meta = load_model(weights)
        self.num_threads = int(num_threads)
        self.chunk = int(chunk)
        self.plane_consistency = bool(plane_consistency)
        #: two networks: the second needs the voxel centroids (:mod:`.context`)
        self.stacked = isinstance(self.model, Stacked)
        self.stage2_gate = float(stage2_gate)

    def probabilities(self, points) -> np.ndarray:
        """(N, 4) float32 class probabilities of (N, 3) points [m], z up; the network runs once
        per occupied 4 cm voxel. Non-finite points get 1/4 each (and label "other")."""
        if self.num_threads > 0:
            import torch

            torch.set_num_threads(self.num_threads)
        return self.probabilities_of(*voxel_features(points, self.num_threads,
                                                     return_segments=True,
                                                     return_centroids=self.stacked))

    def probabilities_of(self, f: np.ndarray, point_voxel: np.ndarray,
                         segment: np.ndarray, centroids: np.ndarray | None = None) -> np.ndarray:
        """:meth:`probabilities` from precomputed ``voxel_features(points,
        return_segments=True, return_centroids=True)`` (evaluations that score several models
        on one cloud; the centroids are needed by two-stage models only)."""
        return self._voxel_probabilities(f, segment, centroids)[point_voxel]

    def _voxel_probabilities(self, f: np.ndarray, segment: np.ndarray,
                             centroids: np.ndarray | None = None) -> np.ndarray:
        """(M + 1, 4) probabilities of the voxels, the last row for non-finite points (index
        -1 of ``point_voxel``)."""
        vox = np.empty((len(f) + 1, NUM_CLASSES), np.float32)
        vox[-1] = [0.25, 0.25, 0.25, 0.25 + 1e-6]  # index -1: non-finite points
        if self.stacked:
            if centroids is None:
                raise ValueError("a two-stage segmenter needs the voxel centroids "
                                 "(voxel_features(..., return_centroids=True))")
            self._network(f, vox[:-1], self.model.stage1)
            if self.stage2_gate >= 1.0:
                ctx = context_features(vox[:-1], segment, centroids)
                self._network(np.hstack([f, ctx]), vox[:-1], self.model.stage2)
            else:  # the doubtful voxels only (the context's means still over all voxels)
                idx = np.flatnonzero(vox[:-1].max(1) < self.stage2_gate)
                ctx = context_features(vox[:-1], segment, centroids, idx)
                out = np.empty((len(idx), NUM_CLASSES), np.float32)
                self._network(np.hstack([f[idx], ctx]), out, self.model.stage2)
                vox[idx] = out
        else:
            self._network(f, vox[:-1], self.model)
        if self.plane_consistency:
            vox[:-1] = plane_consistent(vox[:-1], f, segment)
        return vox

    def _network(self, f: np.ndarray, out: np.ndarray, model) -> None:
        """Softmax of the network on the rows of ``f`` into ``out``, chunk by chunk: the same
        arithmetic as ``model(x)`` (addmm per layer) with the activations of a chunk small
        enough to stay in cache and ReLU in place. With more than one thread the chunks are
        shared by Python threads, each running torch single-threaded (torch releases the GIL):
        no intra-op barriers per layer, which on a loaded machine cost more CPU than they save."""
        import torch
        from torch import nn

        chunk = self.chunk
        layers = list(model)
        lin = [(m.weight.detach(), m.bias.detach()) for m in layers if isinstance(m, nn.Linear)]
        plain = (len(layers) == 2 * len(lin) and hasattr(layers[0], "inv_std")
                 and all(isinstance(m, nn.ReLU) for m in layers[2:-1:2]))

        def run(s: int) -> None:
            with torch.inference_mode():
                if not plain:  # another architecture: its own forward
                    out[s:s + chunk] = torch.softmax(model(torch.from_numpy(f[s:s + chunk])),
                                                     1).numpy()
                    return
                x = (torch.from_numpy(f[s:s + chunk]) - layers[0].mean) * layers[0].inv_std
                for i, (w, b) in enumerate(lin):
                    x = torch.addmm(b, x, w.t())
                    if i < len(lin) - 1:
                        x.relu_()
                torch.softmax(x, 1, out=torch.from_numpy(out[s:s + chunk]))

        starts = range(0, len(f), chunk)
        workers = min(self.num_threads or torch.get_num_threads(), len(starts))
        if workers <= 1:
            for s in starts:
                run(s)
            return
        from concurrent.futures import ThreadPoolExecutor

        before = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(run, starts))
        finally:
            torch.set_num_threads(before)

    def __call__(self, points) -> np.ndarray:
        """(N,) int32 labels (0 ceiling, 1 floor, 2 wall, 3 other), in the input's order."""
        if self.num_threads > 0:
            import torch

            torch.set_num_threads(self.num_threads)
        f, point_voxel, segment, *centroids = voxel_features(
            points, self.num_threads, return_segments=True, return_centroids=self.stacked)
        # argmax per voxel, then one int per point (not 4 floats per point)
        return self._voxel_probabilities(f, segment, *centroids).argmax(1).astype(
            np.int32)[point_voxel]


def segment(points, weights=None, num_threads: int = 0) -> np.ndarray:
    """Label (N, 3) points [m] (z up): (N,) int32, 0 ceiling, 1 floor, 2 wall, 3 other."""
    return Segmenter(weights, num_threads)(points)
