# SPDX-License-Identifier: BSD-3-Clause
"""A loop closure's information is capped at its own floors (``slam.loop_sigma_floor_m`` /
``_deg``), not the odometry pairs': dev seed 722's loop round a corridor's corner (its overlap
one corner 4-5 m from both stations) was 1.9 cm and 0.27° off in yaw at the odometry's 3 mm /
0.03°, and pulled the chain (0.02° a pair) 0.1° off."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tripod_processor.reconstruction import slam
from tripod_processor.reconstruction.config import OdometryConfig, SlamConfig
from tripod_processor.reconstruction.odometry import PairResult


def _sigmas(info):
    cov = np.linalg.inv(info)
    return np.sqrt(np.diag(cov))


def _pair(info):
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.0]
    return PairResult(T, 0.5, 0.01, info, True, "guess")


def test_loop_capped_floors():
    ocfg = OdometryConfig()
    sure = np.diag([1 / 0.003**2] * 3 + [1 / np.radians(0.03) ** 2] * 3)
    r = _pair(sure)
    off = SlamConfig(loop_sigma_floor_m=0.0, loop_sigma_floor_deg=0.0)
    assert slam.loop_capped(r, ocfg, off) is r  # off at 0 (the default before stop 40)
    assert SlamConfig().loop_sigma_floor_deg == 0.1  # on by default since stop 40
    capped = slam.loop_capped(r, ocfg, SlamConfig(loop_sigma_floor_m=0.01,
                                                  loop_sigma_floor_deg=0.1)).information
    s = _sigmas(capped)
    assert np.allclose(s[:3], 0.01, rtol=1e-6)
    assert np.allclose(np.degrees(s[3:]), 0.1, rtol=1e-6)
    # a weaker loop stays as weak as it is
    weak = np.diag([1 / 0.05**2] * 3 + [1 / np.radians(0.5) ** 2] * 3)
    s = _sigmas(slam.loop_capped(_pair(weak), ocfg, SlamConfig(loop_sigma_floor_m=0.01,
                                                               loop_sigma_floor_deg=0.1)
                                 ).information)
    assert np.allclose(s[:3], 0.05) and np.allclose(np.degrees(s[3:]), 0.5)


def test_run_slam_caps_loops_not_odometry(monkeypatch):
    sure = np.diag([1 / 0.003**2] * 3 + [1 / np.radians(0.03) ** 2] * 3)

    def fake_register_pairs(engine, frags, pairs, cfg, num_threads, cache=None, guesses=None,
                            progress=None):
        out = []
        for (j, i), g in zip(pairs, guesses or [None] * len(pairs)):
            T = np.eye(4)
            T[:3, 3] = [3.0 * (j - i), 0.0, 0.0]
            out.append(PairResult(T, 0.5, 0.01, sure.copy(), True, "guess"))
        return out

    monkeypatch.setattr(slam, "register_pairs", fake_register_pairs)
    frags = [SimpleNamespace(R_world_lidar=np.eye(3), up_in_lidar=np.array([0.0, 0.0, 1.0]),
                             tilt_fitted=False) for _ in range(3)]
    T_odom = np.tile(np.eye(4), (3, 1, 1))
    T_odom[:, 0, 3] = [0.0, 3.0, 6.0]
    from tripod_processor.registration import pose_graph as pg
    odom = [pg.Edge(k, k + 1, fake_register_pairs(None, None, [(k + 1, k)], None, 0)[0]
                    .T_target_source, sure.copy(), "odometry", 0.5, 0.01) for k in range(2)]
    res = slam.run_slam(frags, T_odom, odom, np.zeros(3, int), OdometryConfig(),
                        SlamConfig(loop_sigma_floor_m=0.01, loop_sigma_floor_deg=0.1,
                                   tilt_from_imu=False))
    loops = [e for e in res.edges if e.kind == "loop"]
    assert len(loops) == 1
    assert np.allclose(_sigmas(loops[0].information)[:3], 0.01, rtol=1e-6)
    for e in res.edges:
        if e.kind == "odometry":
            assert np.allclose(_sigmas(e.information)[:3], 0.003, rtol=1e-6)
