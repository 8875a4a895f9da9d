# SPDX-License-Identifier: BSD-3-Clause
"""Scene understanding, part 1: label every point ceiling / floor / wall / other.

``segment(points)`` computes :mod:`.features` in the C++ core and runs the small per-point
network of :mod:`.model` (PyTorch, CPU). :mod:`.train` trains it on labelled clouds (simulated
scenes, S3DIS via :mod:`.s3dis`); :mod:`.metrics` scores it.
Labels: 0 ceiling, 1 floor, 2 wall, 3 other.
"""

from __future__ import annotations

import numpy as np

from .features import point_features
from .model import CLASS_NAMES, DEFAULT_WEIGHTS, NUM_CLASSES, load_model

__all__ = ["segment", "Segmenter", "CLASS_NAMES", "NUM_CLASSES", "DEFAULT_WEIGHTS",
           "point_features"]


class Segmenter:
    """A loaded segmenter (keeps the model between clouds).

    Parameters
    ----------
    weights : path of a ``.npz`` weight file; None = the shipped weights
    num_threads : CPU threads for features and inference, 0 = all
    chunk : points per inference batch
    """

    def __init__(self, weights=None, num_threads: int = 0, chunk: int = 1 << 18) -> None:
        self.model, self.meta = load_model(weights)
        self.num_threads = int(num_threads)
        self.chunk = int(chunk)

    def probabilities(self, points) -> np.ndarray:
        """(N, 4) float32 class probabilities of (N, 3) points [m], z up."""
        import torch

        if self.num_threads > 0:
            torch.set_num_threads(self.num_threads)
        f = point_features(points, self.num_threads)
        out = np.empty((len(f), NUM_CLASSES), np.float32)
        with torch.inference_mode():
            for s in range(0, len(f), self.chunk):
                logits = self.model(torch.from_numpy(f[s:s + self.chunk]))
                out[s:s + self.chunk] = torch.softmax(logits, 1).numpy()
        return out

    def __call__(self, points) -> np.ndarray:
        """(N,) int32 labels (0 ceiling, 1 floor, 2 wall, 3 other), in the input's order."""
        return self.probabilities(points).argmax(1).astype(np.int32)


def segment(points, weights=None, num_threads: int = 0) -> np.ndarray:
    """Label (N, 3) points [m] (z up): (N,) int32, 0 ceiling, 1 floor, 2 wall, 3 other."""
    return Segmenter(weights, num_threads)(points)
