# SPDX-License-Identifier: BSD-3-Clause
"""An odometry pair's information is honest about a direction its surfaces hardly constrain.

Two fragments of a corridor's corner seen by walls only (no floor, no ceiling): the vertical
translation is flat in the point-to-plane cost, yet the per-point information of the oriented
refine claims millimetres (the walls' noisy normals add vertical support that is not there),
within the 3-mm floor, so the pose graph trusts it. ``odometry.flat_probe_m`` probes the
direction with the least patch support and caps it by how far a start off it stays."""

from __future__ import annotations

import numpy as np

from tripod_processor.reconstruction import odometry as od
from tripod_processor.reconstruction.config import OdometryConfig


def _plane(rng, origin, u, v, nu, nv, step=0.03):
    a, b = np.meshgrid(np.arange(nu) * step, np.arange(nv) * step)
    return origin + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v


def _corner(rng, floor: bool, noise=0.01):
    """An L of walls 1.1 m either side of the origin (x walls, an end wall, a side leg),
    z in [-1.2, 1.2]; with a floor strip at z = -1.2 when ``floor``."""
    ex, ey, ez = np.eye(3)
    parts = [
        _plane(rng, np.array([-1.1, -4.0, -1.2]), ey, ez, 170, 80),  # x = -1.1
        _plane(rng, np.array([1.1, -4.0, -1.2]), ey, ez, 100, 80),   # x = 1.1, up to y = -1
        _plane(rng, np.array([-1.1, 1.1, -1.2]), ex, ez, 150, 80),   # end wall y = 1.1
        _plane(rng, np.array([1.1, -1.0, -1.2]), ex, ez, 100, 80),   # side leg wall y = -1
    ]
    if floor:
        parts.append(_plane(rng, np.array([-1.0, -3.5, -1.2]), ex, ey, 60, 150))
    p = np.concatenate(parts)
    return (p + rng.normal(0, noise, p.shape)).astype(np.float32)


def _sigma_z(info):
    return 1.0 / np.sqrt(info[2, 2] - info[2, 3:] @ np.linalg.solve(info[3:, 3:], info[3:, 2]))


def test_walls_only_vertical_sigma_is_honest():
    rng = np.random.default_rng(0)
    tgt, src = _corner(rng, floor=False), _corner(rng, floor=False)
    T0 = np.eye(4)
    T0[:3, 3] = [0.01, -0.01, 0.004]
    old = OdometryConfig()
    _, info_old, fit, _ = od.oriented_refine(src, tgt, T0, old)
    assert fit > 0.5
    info_old = od._cap_information(info_old, old)
    # the old information: the floor's cap, though nothing horizontal is in the overlap
    assert _sigma_z(info_old) < 0.01
    new = OdometryConfig(flat_probe_m=0.1)
    _, info_new, _, _ = od.oriented_refine(src, tgt, T0, new)
    info_new = od._cap_information(info_new, new)
    assert _sigma_z(info_new) > 0.03
    # the horizontal directions keep the floor's sigma
    assert 1 / np.sqrt(info_new[0, 0]) < 0.006 and 1 / np.sqrt(info_new[1, 1]) < 0.006


def test_floor_keeps_vertical_sigma():
    rng = np.random.default_rng(1)
    tgt, src = _corner(rng, floor=True), _corner(rng, floor=True)
    T0 = np.eye(4)
    T0[:3, 3] = [0.01, -0.01, 0.004]
    cfg = OdometryConfig(flat_probe_m=0.1)
    _, info, _, _ = od.oriented_refine(src, tgt, T0, cfg)
    assert _sigma_z(od._cap_information(info, cfg)) < 0.006


def test_patch_support_counts_patches_not_noisy_normals():
    rng = np.random.default_rng(2)
    for floor, lo, hi in ((False, 0.0, 0.5), (True, 10.0, 1e9)):
        tgt = _corner(rng, floor)
        cache = od.CloudCache(0.03)
        s = cache.oriented("s", tgt, 0.06)
        S = od.patch_support(s.points, s.normals, s.points, s.normals, np.eye(4), 0.15, 0.5, 0.06)
        assert lo <= S[2, 2] <= hi, (floor, S[2, 2])


def test_cap_flat_direction():
    cfg = OdometryConfig()
    info = np.diag([1e4] * 3 + [1e5] * 3)  # under the floor caps
    T = np.eye(4)
    d = np.array([0.0, 0.0, 1.0])
    flat = od.cap_flat_direction(info, T, d, 0.1, lambda T0: T0, cfg)
    assert abs(1 / np.sqrt(flat[2, 2]) - 0.1) < 1e-6
    assert np.isclose(flat[0, 0], 1e4) and np.isclose(flat[1, 1], 1e4)
    firm = od.cap_flat_direction(info, T, d, 0.1, lambda T0: T, cfg)
    assert np.allclose(firm, info, rtol=1e-6)
