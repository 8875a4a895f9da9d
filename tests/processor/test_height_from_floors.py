# SPDX-License-Identifier: BSD-3-Clause
"""A pair whose overlap holds walls only takes its height from the two fragments' floors and
ceilings (``odometry.height_seed_gate_m``).

A near-vertical lidar sees a band of wall about its own height and the floor and ceiling only
far away; round a corridor's corner the two stations' far floors lie in different legs, so the
overlap does not hold the height (dev seed 722's pair 2->3: 5.4 cm off, claiming 3 mm). Each
fragment's own floor and ceiling still give its height above the floor."""

from __future__ import annotations

import numpy as np

from tripod_processor.reconstruction import odometry as od
from tripod_processor.reconstruction.config import OdometryConfig

CEILING_M = 2.6


def _rect(rng, origin, u, v, n):
    a, b = rng.uniform(0, 1, (2, n, 1))
    return origin + a * u + b * v


def _station(rng, pos, floor_xy, noise=0.005):
    """A station's fragment (its own frame, levelled: the world shifted by -pos): an L of walls
    (x = ±1.1 for y < 1.1, an end wall y = 1.1 and a side leg's wall y = -1 for x > 1.1) seen
    in a band ±0.4 m about the sensor's height (no horizontal surface there), and the floor
    and ceiling in the 2 x 2 m square at ``floor_xy`` (elsewhere for each station)."""
    ex, ey, ez = np.eye(3)
    z0 = pos[2] - 0.4
    parts = [
        _rect(rng, np.array([-1.1, -5.0, z0]), 6.1 * ey, 0.8 * ez, 12000),
        _rect(rng, np.array([1.1, -5.0, z0]), 4.0 * ey, 0.8 * ez, 8000),
        _rect(rng, np.array([-1.1, 1.1, z0]), 6.0 * ex, 0.8 * ez, 12000),
        _rect(rng, np.array([1.1, -1.0, z0]), 4.0 * ex, 0.8 * ez, 8000),
    ]
    fx, fy = floor_xy
    for z in (0.0, CEILING_M):
        parts.append(_rect(rng, np.array([fx, fy, z]), 2.0 * ex, 2.0 * ey, 3000))
    p = np.concatenate(parts) - pos
    return (p + rng.normal(0, noise, p.shape)).astype(np.float32)


def _pair():
    rng = np.random.default_rng(3)
    pos_t = np.array([0.0, -2.0, 1.33])
    pos_s = np.array([0.2, -0.5, 1.21])  # 12 cm lower: T_target_source's z is -0.12
    tgt = _station(rng, pos_t, (-1.0, -5.0))
    src = _station(rng, pos_s, (3.0, -1.0))
    return src, tgt, pos_s - pos_t


def test_horizontal_height_shift_reads_the_floors_not_the_walls():
    src, tgt, d = _pair()
    cache = od.CloudCache(0.03)
    dz = od.horizontal_height_shift(src, tgt, np.eye(3), np.eye(3), cache)
    assert dz is not None and abs(dz - d[2]) < 0.005
    # the whole clouds' histograms (the translation seeds') align the wall bands instead
    assert abs(od.height_shift(tgt, src) - d[2]) > 0.05
    # no floor or ceiling in a fragment: no height
    walls = src[src[:, 2] > -1.0]
    walls = walls[walls[:, 2] < 1.0]
    assert od.horizontal_height_shift(walls, tgt, np.eye(3), np.eye(3), od.CloudCache(0.03)) \
        is None


def test_weak_height_pair_takes_the_floors_height():
    src, tgt, d = _pair()
    guess = np.eye(4)
    guess[:3, 3] = d + [0.0, 0.0, 0.06]  # a start 6 cm off in height, right across
    old = od.register_fragments(src, tgt, np.eye(3), np.eye(3),
                                OdometryConfig(height_seed_gate_m=0.0),
                                T_guess=guess)
    new = od.register_fragments(src, tgt, np.eye(3), np.eye(3),
                                OdometryConfig(height_seed_gate_m=0.01), T_guess=guess)
    assert old.ok and new.ok
    # the walls alone do not hold the height: the old pair stays off
    assert abs(old.T_target_source[2, 3] - d[2]) > 0.02
    assert abs(new.T_target_source[2, 3] - d[2]) < 0.005
    assert np.linalg.norm(new.T_target_source[:2, 3] - d[:2]) < 0.01
    # and claims the floors' sigma along up, the registration's across
    up = np.array([0.0, 0.0, 1.0])
    assert abs(od.up_sigma_m(new.information, up) - 0.01) < 1e-6
    assert od.up_sigma_m(new.information, np.array([1.0, 0.0, 0.0])) < 0.005


def test_height_from_seed_leaves_a_held_height_alone():
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 0.3]
    firm = od.PairResult(T, 0.9, 0.01, np.diag([1e6] * 3 + [1e8] * 3), True)
    cfg = OdometryConfig(height_seed_gate_m=0.01)
    up = np.array([0.0, 0.0, 1.0])
    r, reset = od.height_from_seed(firm, 0.1, up, cfg)
    assert not reset and np.allclose(r.T_target_source, T)
    weak = od.PairResult(T, 0.9, 0.01, np.diag([1e6, 1e6, 1e2] + [1e8] * 3), True)
    r, reset = od.height_from_seed(weak, 0.1, up, cfg)
    assert reset and np.allclose(r.T_target_source[:3, 3], [1.0, 2.0, 0.1])
    # off (gate 0, the default before stop 40), or no floors: untouched
    assert not od.height_from_seed(weak, 0.1, up, OdometryConfig(height_seed_gate_m=0.0))[1]
    assert not od.height_from_seed(weak, None, up, cfg)[1]
