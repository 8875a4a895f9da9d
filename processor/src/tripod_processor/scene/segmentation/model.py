# SPDX-License-Identifier: BSD-3-Clause
"""The segmenter network: a per-point MLP over :mod:`.features`, and its weight file.

Weights are a small ``.npz`` (a few 10 kB): layer matrices, the feature normalisation, and the
provenance (seed, data, command) as JSON. torch is imported only when a model is built.
A two-stage (auto-context) segmenter, :class:`Stacked`, keeps both networks in one file: the
first stage's arrays under their plain names (as a single-stage file), the second's prefixed
:data:`STAGE2_PREFIX`, and ``"stages": 2`` with the second stage's widths in the provenance.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .context import CONTEXT_NAMES
from .features import FEATURE_NAMES

CLASS_NAMES = ("ceiling", "floor", "wall", "other")
NUM_CLASSES = len(CLASS_NAMES)
HIDDEN = (128, 128)
DEFAULT_WEIGHTS = Path(__file__).with_name("weights") / "segmenter.npz"
STAGE2_PREFIX = "stage2."
#: inputs of the second stage: the voxel's features, then :func:`.context.context_features`
STAGE2_INPUTS = len(FEATURE_NAMES) + len(CONTEXT_NAMES)


class Stacked:
    """Two networks of :func:`build_model`: ``stage1`` on the features, ``stage2`` on the
    features and the context of stage 1's probabilities (:mod:`.context`)."""

    def __init__(self, stage1, stage2) -> None:
        self.stage1, self.stage2 = stage1, stage2

    def eval(self) -> "Stacked":
        self.stage1.eval()
        self.stage2.eval()
        return self


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
    """Write the model's parameters and ``meta`` (provenance) to ``path`` (.npz); a
    :class:`Stacked` model writes both stages."""
    first = model.stage1 if isinstance(model, Stacked) else model
    arrays = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in first.state_dict().items()}
    meta = dict(meta, feature_names=list(FEATURE_NAMES), hidden=list(_hidden_of(first)),
                class_names=list(CLASS_NAMES))
    if isinstance(model, Stacked):
        arrays.update({STAGE2_PREFIX + k: v.detach().cpu().numpy().astype(np.float32)
                       for k, v in model.stage2.state_dict().items()})
        meta.update(stages=2, hidden2=list(_hidden_of(model.stage2)),
                    context_names=list(CONTEXT_NAMES))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, __meta__=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)


def _hidden_of(model) -> list[int]:
    from torch import nn

    return [m.out_features for m in model if isinstance(m, nn.Linear)][:-1]


def load_model(path=None):
    """Model from a weight file (default: the shipped weights); returns (model, meta): a torch
    ``nn.Sequential`` for a single-stage file, a :class:`Stacked` for a two-stage one."""
    import torch

    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise FileNotFoundError(f"no segmenter weights at {path}")
    with np.load(path) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        state = {k: torch.from_numpy(z[k]) for k in z.files if k != "__meta__"}
    if tuple(meta["feature_names"]) != FEATURE_NAMES:
        raise ValueError(f"{path}: weights were trained on other features; retrain them")
    stages = int(meta.get("stages", 1))
    if stages not in (1, 2):
        raise ValueError(f"{path}: {stages} stages; this version reads 1 or 2")
    model = build_model(len(FEATURE_NAMES), meta["hidden"])
    model.load_state_dict({k: v for k, v in state.items() if not k.startswith(STAGE2_PREFIX)})
    model.eval()
    if stages == 1:
        return model, meta
    if tuple(meta.get("context_names", ())) != CONTEXT_NAMES:
        raise ValueError(f"{path}: second stage trained on another context; retrain it")
    stage2 = build_model(STAGE2_INPUTS, meta["hidden2"])
    stage2.load_state_dict({k[len(STAGE2_PREFIX):]: v for k, v in state.items()
                            if k.startswith(STAGE2_PREFIX)})
    return Stacked(model, stage2).eval(), meta
