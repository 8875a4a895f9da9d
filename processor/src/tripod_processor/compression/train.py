# SPDX-License-Identifier: BSD-3-Clause
"""Train the occupancy-context model (``tripod train-compressor``).

Steps: 1. make training clouds: fragments of the digital twin (``tripod simulate``, one station
per capture, scenes cycling through room/office/corridor/two_rooms/hall, seeds from the training
seed), or PLY/PCD files given, or the quick synthetic rooms of :mod:`.synthetic`; 2. quantise each at the voxel
sizes of Draco's 8..13-bit range and count, per 22-bit context, how often the coded bit was 0 or
1; 3. fit the MLP to those counts (count-weighted binary cross-entropy, full batch, CPU, fixed
seed, single thread for reproducibility); 4. quantise to fixed point and save.
The whole run takes a few minutes on 2 cores.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from .model import CONTEXT_BITS, N_CONTEXTS, ContextModel, context_features

DEFAULT_SEED = 8
DEFAULT_FRAGMENTS = 5
HELD_OUT_SEEDS = range(900, 1000)  # simulator seeds the benchmark uses: never trained on
HIDDEN = 32


def count_contexts(clouds: Iterable[np.ndarray], quant_bits=(8, 9, 10, 11, 12),
                   log: Callable[[str], None] = print) -> np.ndarray:
    """(2^22, 2) int64 counts of coded bits 0 / 1 per context over all clouds and voxel sizes."""
    from .. import _ext
    from .codec import voxel_codes

    counts = np.zeros((N_CONTEXTS, 2), np.int64)
    for k, pts in enumerate(clouds):
        pts = np.ascontiguousarray(pts, np.float32)
        ext = float((pts.max(0) - pts.min(0)).max())
        for q in quant_bits:
            codes, _, depth = voxel_codes(pts, ext / (2**q - 1))
            ctx, bits = _ext.octree_contexts(codes, depth)
            counts[:, 1] += np.bincount(ctx[bits == 1], minlength=N_CONTEXTS)
            counts[:, 0] += np.bincount(ctx[bits == 0], minlength=N_CONTEXTS)
        log(f"  cloud {k}: {len(pts)} points, {counts.sum()} coded bits so far")
    return counts


def fit(counts: np.ndarray, seed: int = DEFAULT_SEED, epochs: int = 400,
        log: Callable[[str], None] = print) -> list[np.ndarray]:
    """Fit the MLP to per-context counts; returns float weights (w1, b1, w2, b2, w3, b3)."""
    import torch

    torch.manual_seed(seed)
    torch.set_num_threads(1)  # reproducible float sums
    seen = np.flatnonzero(counts.sum(1) > 0)
    x = torch.tensor(context_features(seen.astype(np.uint32)), dtype=torch.float32)
    n0 = torch.tensor(counts[seen, 0], dtype=torch.float32)
    n1 = torch.tensor(counts[seen, 1], dtype=torch.float32)
    total = float((n0 + n1).sum())
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], HIDDEN), torch.nn.ReLU(),
                              torch.nn.Linear(HIDDEN, HIDDEN), torch.nn.ReLU(),
                              torch.nn.Linear(HIDDEN, 1))
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    for epoch in range(epochs):
        opt.zero_grad()
        z = net(x)[:, 0]
        # bits: n1 * -log sigmoid(z) + n0 * -log sigmoid(-z)
        loss = (n1 * torch.nn.functional.softplus(-z) + n0 * torch.nn.functional.softplus(z)).sum()
        loss = loss / total / np.log(2.0)
        loss.backward()
        opt.step()
        sched.step()
        if epoch % 100 == 0 or epoch == epochs - 1:
            log(f"  epoch {epoch}: {loss.item():.4f} bits per coded decision")
    l1, l2, l3 = net[0], net[2], net[4]
    return [l1.weight.detach().numpy().T.copy(), l1.bias.detach().numpy().copy(),
            l2.weight.detach().numpy().T.copy(), l2.bias.detach().numpy().copy(),
            l3.weight.detach().numpy().T.copy(), l3.bias.detach().numpy().copy()]


def table_bits(counts: np.ndarray, p0_table: np.ndarray) -> float:
    """Ideal code length [bits] of the counted decisions under a static table."""
    p0 = p0_table.astype(np.float64) / 65536.0
    return float(-(counts[:, 0] * np.log2(p0) + counts[:, 1] * np.log2(1 - p0)).sum())


def _git_commit() -> str | None:
    """The repository commit the training ran on (the simulator's version matters), if known."""
    import subprocess

    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                              capture_output=True, text=True, timeout=5,
                              check=True).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def train(out: Path, clouds: list[Path] | None = None, n_fragments: int = DEFAULT_FRAGMENTS,
          seed: int = DEFAULT_SEED, epochs: int = 400, source_kind: str = "sim",
          log: Callable[[str], None] = print) -> ContextModel:
    """Train and save the context model; returns it.

    ``clouds``: PLY/PCD training files; else ``n_fragments`` fragments of ``source_kind``
    ("sim": the digital twin, "synthetic": the quick built-in rooms).
    """
    t0 = time.time()
    if clouds:
        from ..io.clouds import read_cloud, xyz

        data = (xyz(read_cloud(p), np.float32) for p in clouds)
        source = [str(p) for p in clouds]
    elif source_kind == "sim":
        from .simdata import SCENES, simulated_fragments

        runs = [(SCENES[k % len(SCENES)], seed * 100 + k) for k in range(n_fragments)]
        assert not any(s in HELD_OUT_SEEDS for _, s in runs)
        data = (f for scene, s in runs for f in simulated_fragments(scene, s, stations=1))
        source = {"tripod_simulate_scene_seed": runs, "stations": 1}
    else:
        from .synthetic import random_fragment

        rng = np.random.default_rng(seed)
        frag_seeds = [int(s) for s in rng.integers(0, 2**31 - 1, n_fragments)]
        data = (random_fragment(s, n_revolutions=int(12 + s % 25)) for s in frag_seeds)
        source = {"synthetic_fragment_seeds": frag_seeds}
    log("1. counting contexts")
    counts = count_contexts(data, log=log)
    log("2. fitting the context MLP")
    weights = fit(counts, seed=seed, epochs=epochs, log=log)
    meta = {"seed": seed, "epochs": epochs, "hidden": HIDDEN, "context_bits": CONTEXT_BITS,
            "training_data": source, "coded_bits": int(counts.sum()), "git_commit": _git_commit(),
            "command": f"tripod train-compressor --seed {seed} --fragments {n_fragments} "
                       f"--epochs {epochs} --source {source_kind}"}
    model = ContextModel.from_float(weights, meta)
    table = model.table()
    n = counts.sum()
    emp = counts / np.maximum(counts.sum(1, keepdims=True), 1)
    h_emp = -np.nansum(counts * np.log2(np.where(emp > 0, emp, 1)))
    log(f"3. training set: {table_bits(counts, table) / n:.4f} bits/decision with the integer "
        f"table (empirical entropy {h_emp / n:.4f}); {time.time() - t0:.0f} s")
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(out)
    return model
