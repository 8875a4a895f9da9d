# SPDX-License-Identifier: BSD-3-Clause
"""The learned occupancy-context model and its exact integer probability table.

A small MLP maps the 22-bit octree context (see ``cpp/tripod_core/octree_codec.hpp``: 7 causal
child-level neighbours, 7 parent-level neighbours towards the octant, the octant, the level
bucket, the density of the coded neighbourhood, whether the node has an occupied child yet) to
P(child occupied). The codec never runs the float network: the shipped weights are
integers (fixed point, ``FRAC_BITS`` fractional bits) and :func:`probability_table` evaluates
them for all 2^22 contexts with integer arithmetic (float64 matmuls of integers below 2^53 are
exact, whatever the BLAS summation order), then maps the logit through a shipped integer sigmoid
table. The encoder and the decoder therefore get bit-identical tables on every machine; the
table's SHA-256 (the *model id*) is stored in each file and checked before decoding.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CONTEXT_BITS = 22
N_CONTEXTS = 1 << CONTEXT_BITS
N_FEATURES = 7 + 7 + 8 + 4 + 4 + 1  # causal, parent bits; octant, level, density one-hots; any
FRAC_BITS = 12  # fixed point of weights and activations
LOGIT_STEPS_PER_UNIT = 64  # sigmoid table resolution: 1/64 of a logit unit
LOGIT_RANGE = 16  # table covers logits in [-16, 16)
P_MIN, P_MAX = 16, 65520  # probabilities are P(bit = 0) * 65536, clamped to this range

WEIGHTS_DIR = Path(__file__).with_name("weights")
DEFAULT_WEIGHTS = WEIGHTS_DIR / "octree_context_v3.npz"


def context_features(contexts: np.ndarray) -> np.ndarray:
    """Binary features (N, N_FEATURES) uint8 of packed 22-bit contexts (N,) uint32."""
    c = np.asarray(contexts, dtype=np.uint32)
    f = np.zeros((len(c), N_FEATURES), np.uint8)
    for k in range(14):
        f[:, k] = (c >> k) & 1
    f[np.arange(len(c)), 14 + ((c >> 14) & 7)] = 1
    f[np.arange(len(c)), 22 + ((c >> 17) & 3)] = 1
    f[np.arange(len(c)), 26 + ((c >> 19) & 3)] = 1
    f[:, 30] = (c >> 21) & 1
    return f


def sigmoid_lut() -> np.ndarray:
    """P(bit = 0) * 65536 for logits (of P(bit = 1)) in [-16, 16) at 1/64 steps, uint16."""
    z = np.arange(-LOGIT_RANGE * LOGIT_STEPS_PER_UNIT, LOGIT_RANGE * LOGIT_STEPS_PER_UNIT) / float(
        LOGIT_STEPS_PER_UNIT)
    p0 = 65536.0 / (1.0 + np.exp(z))
    return np.clip(np.rint(p0), P_MIN, P_MAX).astype(np.uint16)


@dataclass(frozen=True)
class ContextModel:
    """Integer weights of the MLP and the integer sigmoid table, as shipped."""

    weights: tuple[np.ndarray, ...]  # w1 (F,H) b1 (H) w2 (H,H) b2 (H) w3 (H,1) b3 (1), int64
    lut: np.ndarray  # sigmoid table, uint16
    meta: dict  # training provenance (seed, data, command)

    def save(self, path: str | Path) -> None:
        names = ("w1", "b1", "w2", "b2", "w3", "b3")
        arrays = {n: w.astype(np.int32) for n, w in zip(names, self.weights)}
        np.savez_compressed(path, lut=self.lut, meta=np.array(json.dumps(self.meta)), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "ContextModel":
        with np.load(path, allow_pickle=False) as z:
            weights = tuple(z[n].astype(np.int64) for n in ("w1", "b1", "w2", "b2", "w3", "b3"))
            return cls(weights, z["lut"].astype(np.uint16), json.loads(str(z["meta"])))

    @classmethod
    def from_float(cls, float_weights: list[np.ndarray], meta: dict) -> "ContextModel":
        """Quantise float weights (w1, b1, w2, b2, w3, b3; w as (in, out)) to fixed point."""
        q = tuple(np.rint(np.asarray(w, np.float64) * (1 << FRAC_BITS)).astype(np.int64)
                  for w in float_weights)
        return cls(q, sigmoid_lut(), meta)

    def logits(self, contexts: np.ndarray) -> np.ndarray:
        """Fixed-point logits (scale 2^FRAC_BITS) of P(bit = 1), int64, exact.

        The first layer of a binary input is a sum of weight rows; it is evaluated per context
        field (7 causal bits, 7 parent bits, octant, level, density, any) from small tables,
        which is exact in integers and much faster than the dense product.
        """
        w1, b1, w2, b2, w3, b3 = self.weights
        c = np.asarray(contexts, dtype=np.int64)
        low, high = self._first_layer_tables()
        h = low[c & 16383]
        h += high[c >> 14]
        np.maximum(h, 0, out=h)
        # every operand and partial sum is an integer < 2^53: float64 products/sums are exact
        h = np.maximum(((h.astype(np.float64) @ w2.astype(np.float64)).astype(np.int64)
                        >> FRAC_BITS) + b2, 0)
        z = ((h.astype(np.float64) @ w3.astype(np.float64)).astype(np.int64) >> FRAC_BITS)[:, 0]
        return z + b3[0]

    def _first_layer_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Pre-activations of the first layer for the low 14 context bits and the high 8."""
        w1, b1 = self.weights[0], self.weights[1]
        bits14 = ((np.arange(1 << 14)[:, None] >> np.arange(14)) & 1).astype(np.int64)
        low = bits14 @ w1[0:14] + b1
        hi = np.arange(1 << (CONTEXT_BITS - 14))
        high = (w1[14:22][hi & 7] + w1[22:26][(hi >> 3) & 3] + w1[26:30][(hi >> 5) & 3]
                + w1[30][None, :] * ((hi >> 7) & 1)[:, None])
        return low, high

    def table(self) -> np.ndarray:
        """P(bit = 0) * 65536 for every context, (2^22,) uint16."""
        out = np.empty(N_CONTEXTS, np.uint16)
        chunk = 1 << 18
        n_lut = len(self.lut)
        for s in range(0, N_CONTEXTS, chunk):
            z = self.logits(np.arange(s, s + chunk, dtype=np.int64))
            i = (z * LOGIT_STEPS_PER_UNIT) >> FRAC_BITS  # floor to the table's step
            i = np.clip(i + LOGIT_RANGE * LOGIT_STEPS_PER_UNIT, 0, n_lut - 1)
            out[s:s + chunk] = self.lut[i]
        return out


@dataclass(frozen=True)
class ProbabilityTable:
    """The codec's probability table and its id (first 16 hex digits of its SHA-256)."""

    p0: np.ndarray  # (2^22,) uint16
    model_id: str


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "tripod" / "compression"


@functools.lru_cache(maxsize=4)
def load_table(path: str | Path = DEFAULT_WEIGHTS) -> ProbabilityTable:
    """The probability table of a weights file, built once per process (and cached on disk).

    The disk cache ($XDG_CACHE_HOME/tripod/compression/<sha256 of the weights file>.npz) only
    saves the build time: a cached table is used when its SHA-256 and range check out, and the
    model id written into each file is always the hash of the table actually used.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"compressor weights not found: {path}")
    key = hashlib.sha256(path.read_bytes()).hexdigest()
    cache = _cache_dir() / f"{key}.npz"
    p0 = None
    try:
        with np.load(cache, allow_pickle=False) as z:
            cand, digest = z["p0"], str(z["sha256"])
        if (cand.dtype == np.uint16 and cand.shape == (N_CONTEXTS,)
                and hashlib.sha256(cand.tobytes()).hexdigest() == digest
                and cand.min() >= P_MIN and cand.max() <= P_MAX):
            p0 = cand
    except (OSError, ValueError, KeyError):
        pass
    if p0 is None:
        p0 = ContextModel.load(path).table()
        try:
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_suffix(f".{os.getpid()}.tmp.npz")
            np.savez(tmp, p0=p0, sha256=np.array(hashlib.sha256(p0.tobytes()).hexdigest()))
            os.replace(tmp, cache)
        except OSError:
            pass  # a read-only home only costs the build time next run
    p0.setflags(write=False)
    return ProbabilityTable(p0, hashlib.sha256(p0.tobytes()).hexdigest()[:16])
