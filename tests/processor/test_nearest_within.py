# SPDX-License-Identifier: BSD-3-Clause
"""The station splitter's direction matches: the native grid search against scipy's cKDTree
(``tripod_processor._ext.nearest_within`` and ``stations.matched_directions``), bit for bit,
with and without exact ties (dual returns give the same direction twice)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tripod_processor import _ext
from tripod_processor.reconstruction.stations import matched_directions

RADIUS = float(np.radians(0.3))


def _sweep(n: int, pan_rad: float, seed: int) -> np.ndarray:
    """Unit vectors of a VLP-16 sweep (16 cones) with the lidar on its side, panned about z."""
    rng = np.random.default_rng(seed)
    el = np.radians(-15.0 + 2.0 * (np.arange(n) % 16))
    az = rng.uniform(0.0, 2 * np.pi, n)
    v = np.stack([np.sin(el), np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az)], axis=1)
    c, s = np.cos(pan_rad), np.sin(pan_rad)
    v = v @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    # ranges 0.5-40 m, then back to directions as pivot_shift_fit makes them
    p = v * rng.uniform(0.5, 40.0, n)[:, None]
    return p / np.linalg.norm(p, axis=1)[:, None]


def _scipy(u_ref, u_q):
    tree = cKDTree(u_ref, balanced_tree=False, compact_nodes=False)
    return tree.query(u_q, k=1, distance_upper_bound=RADIUS)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("pan_deg", [0.5, 18.0, 90.0])
def test_native_matches_ckdtree_bit_for_bit_without_ties(pan_deg):
    u_ref, u_q = _sweep(12000, 0.0, 1), _sweep(4000, np.radians(pan_deg), 2)
    dist, idx, ties = _ext.nearest_within(u_ref, u_q, RADIUS)
    want_d, want_i = _scipy(u_ref, u_q)
    assert ties == 0
    assert np.isfinite(want_d).sum() > 100  # the test compares matches, not only misses
    assert _same(dist, want_d) and _same(idx, want_i)


def test_float32_directions_as_the_splitter_has_them():
    # placed clouds are float32: their directions reach cKDTree as float32, converted to float64
    u_ref = _sweep(12000, 0.0, 6).astype(np.float32)
    u_q = _sweep(4000, np.radians(3.0), 7).astype(np.float32)
    dist, idx = matched_directions(u_ref, u_q, RADIUS)
    want_d, want_i = _scipy(u_ref, u_q)
    assert np.isfinite(want_d).sum() > 100
    assert _same(dist, want_d) and _same(idx, want_i)


def test_ties_are_counted_and_answered_by_ckdtree():
    u_ref = _sweep(12000, 0.0, 3)
    # dual returns: every 5th direction twice, and queries right on some of them
    u_ref = np.concatenate([u_ref, u_ref[::5]])
    u_q = np.concatenate([_sweep(4000, np.radians(10.0), 4), u_ref[:50:5]])
    _, idx, ties = _ext.nearest_within(u_ref, u_q, RADIUS)
    assert ties >= 10
    # the native answer in a tie is the lowest index of the tied references
    assert idx[-10:].tolist() == list(range(0, 50, 5))
    dist, idx = matched_directions(u_ref, u_q, RADIUS)
    want_d, want_i = _scipy(u_ref, u_q)
    assert _same(dist, want_d) and _same(idx, want_i)


def test_empty_and_far_queries():
    u_ref = _sweep(100, 0.0, 5)
    dist, idx, ties = _ext.nearest_within(u_ref, np.zeros((0, 3)), RADIUS)
    assert dist.shape == (0,) and idx.shape == (0,) and ties == 0
    dist, idx, _ = _ext.nearest_within(np.zeros((0, 3)), u_ref, RADIUS)
    assert np.isinf(dist).all() and (idx == 0).all()
    dist, idx, _ = _ext.nearest_within(u_ref, u_ref * 100.0, RADIUS)
    assert np.isinf(dist).all() and (idx == len(u_ref)).all()
    with pytest.raises(ValueError):
        _ext.nearest_within(u_ref, u_ref, 0.0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ranges_round_as_linalg_norm(dtype):
    from tripod_processor.reconstruction.stations import _beyond, _ranges

    rng = np.random.default_rng(8)
    for n in [0, 1, 2, 3, 7, 8, 9, 33, 1000, 4000, 12000]:
        p = (rng.normal(size=(n, 3)) * rng.uniform(0.01, 50.0, (n, 1))).astype(dtype)
        assert _same(_ranges(p), np.linalg.norm(p, axis=1))
        kept, r = _beyond(p, 0.3)
        ok = np.linalg.norm(p, axis=1) > 0.3
        assert _same(kept, p[ok]) and _same(r, np.linalg.norm(p, axis=1)[ok])
