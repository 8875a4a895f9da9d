# SPDX-License-Identifier: BSD-3-Clause
"""The segmenter network: a per-point MLP over :mod:`.features`, and its weight file.

Weights are a small ``.npz`` (a few 10 kB): layer matrices, the feature normalisation, and the
provenance (seed, data, command) as JSON. torch is imported only when a model is built.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .features import FEATURE_NAMES

CLASS_NAMES = ("ceiling", "floor", "wall", "other")
NUM_CLASSES = len(CLASS_NAMES)
HIDDEN = (128, 128)
DEFAULT_WEIGHTS = Path(__file__).with_name("weights") / "segmenter.npz"


def build_model(num_features: int = len(FEATURE_NAMES), hidden=HIDDEN):
    """torch ``nn.Sequential``: standardise -> [Linear, ReLU] x len(hidden) -> Linear (logits)."""
    import torch
    from torch import nn

    class Standardise(nn.Module):
        def __init__(self, n: int) -> None:
            super().__init__()
            self.register_buffer("mean", torch.zeros(n))
            self.register_buffer("inv_std", torch.ones(n))

        def forward(self, x):
            return (x - self.mean) * self.inv_std

    layers: list = [Standardise(num_features)]
    n = num_features
    for h in hidden:
        layers += [nn.Linear(n, h), nn.ReLU()]
        n = h
    layers.append(nn.Linear(n, NUM_CLASSES))
    return nn.Sequential(*layers)


def save_weights(model, path, meta: dict) -> None:
    """Write the model's parameters and ``meta`` (provenance) to ``path`` (.npz)."""
    arrays = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in model.state_dict().items()}
    meta = dict(meta, feature_names=list(FEATURE_NAMES), hidden=list(_hidden_of(model)),
                class_names=list(CLASS_NAMES))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, __meta__=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)


def _hidden_of(model) -> list[int]:
    from torch import nn

    return [m.out_features for m in model if isinstance(m, nn.Linear)][:-1]


def load_model(path=None):
    """Model from a weight file (default: the shipped weights); returns (model, meta)."""
    import torch

    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise FileNotFoundError(f"no segmenter weights at {path}")
    with np.load(path) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        state = {k: torch.from_numpy(z[k]) for k in z.files if k != "__meta__"}
    if tuple(meta["feature_names"]) != FEATURE_NAMES:
        raise ValueError(f"{path}: weights were trained on other features; retrain them")
    model = build_model(len(FEATURE_NAMES), meta["hidden"])
    model.load_state_dict(state)
    model.eval()
    return model, meta
