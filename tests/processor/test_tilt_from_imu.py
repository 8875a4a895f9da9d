# SPDX-License-Identifier: BSD-3-Clause
"""Station tilts from the IMU, yaw and position from the registrations (``slam.station_graph``).

In a small room the registrations between two stations' fragments come out 0.1-0.6° off in tilt
(dev seed 126, 4 x 4 m, 9° mount, with the whole true calibration: range noise; the fragments
themselves fit the scene mesh within 0.04° and the IMU anchors within 0.006°), and their
information, capped at 0.03°, outweighed the gravity priors (0.1°): the station tilts were
0.11° RMS off. Here a graph of such edges, built and solved as ``run_slam`` does.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction.config import SlamConfig
from tripod_processor.reconstruction.fragments import Fragment
from tripod_processor.reconstruction.slam import (optimize_graph, station_graph,
                                                  tilt_free_information)
from tripod_processor.reconstruction.stations import Station

from poses import T_from as _T, inv as _inv


def _room(n=8, seed=0):
    """n stations T_world_lidar in a 4 x 4 m room: any yaw, the lidar tilted 9° on the head."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        R = (Rotation.from_euler("z", rng.uniform(-np.pi, np.pi))
             * Rotation.from_rotvec(np.radians(9.0) * np.array([0.0, 1.0, 0.0])))
        out.append(_T(R.as_rotvec(), [*rng.uniform(-1.5, 1.5, 2), 1.4 + rng.uniform(-.1, .1)]))
    return np.array(out)


def _tilt_yaw_deg(T_est, T_true):
    """Per station (tilt, yaw) error [deg]: the world-frame rotation error split about the
    world's horizontal axes and its up axis."""
    W = T_true[:, :3, :3] @ np.transpose(T_est[:, :3, :3], (0, 2, 1))
    rv = np.degrees(Rotation.from_matrix(W).as_rotvec())
    return np.hypot(rv[:, 0], rv[:, 1]), np.abs(rv[:, 2])


def _fragments(truth, anchor="fit"):
    """Fragments whose IMU anchor is the true attitude (its tilt fitted over the station)."""
    return [Fragment(Station(k, 0, 1, 0, 1), np.zeros((0, 3), np.float32), T[:3, :3].copy(), 0,
                     anchor=anchor) for k, T in enumerate(truth)]


def _edges(truth, seed=1, tilt_deg=0.4):
    """Odometry and loop edges as a small room's registrations give them: each tilted by
    ``tilt_deg`` about a random horizontal axis through a point 1.5 m from the source station
    (so its translation is off along), yaw right, information at the odometry's caps (3 mm,
    0.03°)."""
    from tripod_processor.registration import pose_graph as pg

    rng = np.random.default_rng(seed)
    info = np.diag([1 / 0.003**2] * 3 + [1 / np.radians(0.03) ** 2] * 3)
    n = len(truth)
    pairs = [(k, k + 1) for k in range(n - 1)] + [(0, n - 1), (0, 2), (1, 3), (2, 5), (3, 6)]
    edges = []
    for i, j in pairs:
        a = rng.uniform(0, 2 * np.pi)
        axis_w = np.array([np.cos(a), np.sin(a), 0.0])
        axis_j = truth[j][:3, :3].T @ axis_w  # about a horizontal axis, in j's frame
        pivot = rng.normal(0, 1, 3)
        pivot *= 1.5 / np.linalg.norm(pivot)
        D = _T(np.radians(tilt_deg) * axis_j, np.zeros(3))
        D[:3, 3] = pivot - D[:3, :3] @ pivot  # the tilt about a point 1.5 m away
        meas = _inv(truth[i]) @ truth[j] @ D
        edges.append(pg.Edge(i, j, meas, info.copy(), "odometry" if j == i + 1 else "loop"))
    return edges


def _solve(truth, frags, edges, scfg):
    members = list(range(len(truth)))
    graph = station_graph(frags, members, truth.copy(), edges, scfg)
    return optimize_graph(graph, scfg, 1).T_world_node


def test_tilt_free_information_drops_tilt_only():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    info = A @ A.T + 6 * np.eye(6)
    up = np.array([0.1, -0.2, 0.97])
    up /= np.linalg.norm(up)
    out = tilt_free_information(info, up)
    h = np.cross(up, [1.0, 0.0, 0.0])
    h /= np.linalg.norm(h)
    for tilt in (h, np.cross(up, h)):
        e = np.concatenate([np.zeros(3), tilt])
        assert abs(e @ out @ e) < 1e-6 * np.trace(info)  # no information about a tilt
    # a translation or a yaw is known no better than with the tilt free (the Schur complement):
    # at most what the full information said, more than nothing
    for e in (np.r_[1.0, 0, 0, 0, 0, 0], np.r_[0, 0, 0, up]):
        assert 0 < e @ out @ e <= e @ info @ e + 1e-9
    assert np.allclose(out, out.T)
    assert np.linalg.eigvalsh(out).min() > -1e-9 * np.trace(info)


def test_station_tilts_come_from_the_imu():
    truth = _room()
    frags = _fragments(truth)
    edges = _edges(truth)
    old = SlamConfig(gravity_sigma_fitted_deg=0.0, tilt_from_imu=False)  # before: 0.1° priors
    T_old = _solve(truth, frags, edges, old)
    tilt_old, _ = _tilt_yaw_deg(T_old, truth)
    assert np.sqrt(np.mean(tilt_old**2)) > 0.1  # the registrations' tilts won
    T_new = _solve(truth, frags, edges, SlamConfig())
    tilt_new, yaw_new = _tilt_yaw_deg(T_new, truth)
    assert tilt_new.max() < 0.02
    assert yaw_new.max() < 0.02  # the yaws were measured right and stay so


def test_slerped_anchors_keep_the_registrations_tilt():
    """A station whose anchor is one slerped sample (0.05° noise) keeps the 0.1° prior and its
    edges their tilt: the same result as before the change."""
    truth = _room()
    frags = _fragments(truth, anchor="slerped")
    edges = _edges(truth)
    old = SlamConfig(gravity_sigma_fitted_deg=0.0, tilt_from_imu=False)
    np.testing.assert_array_equal(_solve(truth, frags, edges, old),
                                  _solve(truth, frags, edges, SlamConfig()))


def _box_fragment(T_world_lidar, rng, noise_m=0.01, size=(4.0, 4.0, 2.6), n=60_000):
    """Points on the walls, floor and ceiling of a box room seen from a station, in its lidar
    frame, with range noise along the beams."""
    L = np.array(size)
    face = rng.integers(0, 6, n)
    p = rng.uniform(0, 1, (n, 3)) * L
    ax, hi = face // 2, face % 2
    p[np.arange(n), ax] = hi * L[ax]
    o = T_world_lidar[:3, 3]
    d = p - o
    r = np.linalg.norm(d, axis=1, keepdims=True)
    p = o + d * (1 + rng.normal(0, noise_m, (n, 1)) / r)
    return ((p - o) @ T_world_lidar[:3, :3]).astype(np.float32)


def test_tilt_refit_takes_the_imus_tilt_and_refits_the_shift():
    """A pair registered 0.4° off in tilt with its translation 1 cm off along: finished at the
    anchors' tilt (yaw kept) with the translation refitted."""
    from tripod_processor.reconstruction.config import OdometryConfig
    from tripod_processor.reconstruction.odometry import CloudCache, PairResult, tilt_refit

    rng = np.random.default_rng(5)
    Ta = _T((Rotation.from_euler("z", 0.3) * Rotation.from_euler("y", np.radians(9))).as_rotvec(),
            [1.5, 2.0, 1.4])
    Tb = _T((Rotation.from_euler("z", 1.9) * Rotation.from_euler("y", np.radians(9))).as_rotvec(),
            [2.4, 1.6, 1.5])
    A, B = _box_fragment(Ta, rng), _box_fragment(Tb, rng)
    T_true = _inv(Ta) @ Tb  # T_a_b: source b onto target a
    h = Tb[:3, :3].T @ np.array([0.6, 0.8, 0.0])  # a horizontal axis in b's frame
    D = _T(np.radians(0.4) * h, np.zeros(3))
    pivot = 1.5 * Tb[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # 1.5 m above b, across the axis
    D[:3, 3] = pivot - D[:3, :3] @ pivot
    wrong = T_true @ D
    cfg = OdometryConfig()
    r = PairResult(wrong, 0.9, 0.01, np.eye(6), True, "test")
    out = tilt_refit(B, A, r, Tb[:3, :3], Ta[:3, :3], cfg, 1, CloudCache(cfg.point_sigma_m, 1),
                     ("b", "a"))
    E = np.linalg.inv(T_true) @ out.T_target_source
    W = Tb[:3, :3] @ E[:3, :3] @ Tb[:3, :3].T  # the error in the world frame
    rv = np.degrees(Rotation.from_matrix(W).as_rotvec())
    assert np.hypot(rv[0], rv[1]) < 1e-6  # the IMU's relative tilt, exactly
    assert abs(rv[2]) < 0.01  # the yaw as registered (right here)
    shift_before = np.linalg.norm(wrong[:3, 3] - T_true[:3, 3])
    shift_after = np.linalg.norm(out.T_target_source[:3, 3] - T_true[:3, 3])
    assert shift_before > 0.008
    assert shift_after < 0.002
    assert out.ok and out.information is r.information
