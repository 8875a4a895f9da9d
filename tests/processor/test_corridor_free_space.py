# SPDX-License-Identifier: BSD-3-Clause
"""Stations round the corner of an L-shaped corridor (issue 12's metre-level station errors).

A 2 m wide L corridor; stations 6 m apart in its first leg and one 5-6 m into the second leg.
The pair across the corner overlaps little (~30 %), and a wrong pose that slides one station's
leg along the other's fits *more* points (both long walls on each other): odometry took it and
put the station metres off. The free-space check (``registration.free_space``) ranks the
candidates that put no point where the other station saw through first. Scans: the
simulator's corridor and beam model ray-cast from static stations (``sim.station_scan``; a
second of CPU each).
"""

import numpy as np
import pytest

from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.config import OdometryConfig, SlamConfig
from tripod_processor.reconstruction.fragments import Fragment
from tripod_processor.registration.free_space import range_image, violation
from tripod_processor.reconstruction.odometry import register_fragments
from tripod_processor.reconstruction.slam import inv, run_odometry, run_slam
from tripod_processor.reconstruction.stations import Station
from tripod_processor.sim.scenes import make_scene
from tripod_processor.sim.station_scan import pose, station_scan

L, LEG2, W = 22.8, 12.7, 2.0  # first leg, second leg, width [m]
TILTS = tuple(range(-30, 31, 3))  # head tilts of the scans [deg]: a dense fragment


@pytest.fixture(scope="module")
def corridor():
    return make_scene("corridor", 3, {"length_m": L, "leg2_m": LEG2, "width_m": W})


def _scan(scene, T, seed):
    return station_scan(scene, T, TILTS, seed=seed).astype(np.float32)


@pytest.mark.parametrize("x_leg1, y_leg2", [(L - 3.0, 5.5), (L - 4.0, 6.0), (L - 5.0, 4.0)])
def test_pair_round_the_corner(corridor, x_leg1, y_leg2):
    """The pair across the corner lands within 5 cm; without the check it slides metres (the
    failure this guards against; if the scene ever stops showing it, the test says so)."""
    c = W / 2
    Ta = pose(30.0, (x_leg1, c + 0.1, 1.4))
    Tb = pose(-70.0, (L - c - 0.1, y_leg2, 1.45))
    A, B = _scan(corridor, Ta, 1), _scan(corridor, Tb, 2)
    T_true = inv(Ta) @ Tb
    errs = {}
    for check in (False, True):
        r = register_fragments(B, A, Tb[:3, :3], Ta[:3, :3], OdometryConfig(free_space_check=check),
                               2)
        errs[check] = (r.ok, float(np.linalg.norm(r.T_target_source[:3, 3] - T_true[:3, 3])))
    assert errs[True][0] and errs[True][1] < 0.05, errs
    assert not errs[False][0] or errs[False][1] > 1.0, errs  # the unchecked failure


def test_free_space_violation_separates_right_from_slid(corridor):
    """A right pose puts (almost) nothing in the other station's free space; the same pair slid
    2 m along the corridor puts its end wall and its far leg there."""
    c = W / 2
    Ta, Tb = pose(10.0, (L - 9.0, c, 1.4)), pose(-40.0, (L - 3.0, c, 1.45))
    A, B = _scan(corridor, Ta, 3), _scan(corridor, Tb, 4)
    img = range_image(A)
    T = inv(Ta) @ Tb
    slid = T.copy()
    slid[:3, 3] += Ta[:3, :3].T @ np.array([2.0, 0.0, 0.0])  # 2 m along the corridor's axis
    assert violation(B, T, img) < 0.002
    assert violation(B, slid, img) > 0.01


def test_station_chain_round_the_corner(corridor):
    """Three stations (two in the first leg 6 m apart, one round the corner): odometry and the
    pose graph place them within 2 cm (station ATE, the benchmark's measure)."""
    c = W / 2
    T_true = np.array([pose(-20.0, (L - 9.0, c - 0.1, 1.5)), pose(30.0, (L - 3.0, c + 0.1, 1.4)),
                       pose(-70.0, (L - c - 0.1, 5.5, 1.45))])
    frags = []
    for k, T in enumerate(T_true):
        st = Station(k, int(k * 20e9), int(k * 20e9 + 10e9), 0, 0)
        P = _scan(corridor, T, 10 + k)
        frags.append(Fragment(st, P, T[:3, :3].copy(), len(P)))
    ocfg, scfg = OdometryConfig(), SlamConfig()
    T_odom, edges, comp, notes = run_odometry(frags, ocfg, 2)
    slam = run_slam(frags, T_odom, edges, comp, ocfg, scfg, 2)
    assert not slam.disconnected, notes + slam.notes
    err = ev.pose_errors(slam.T_optimized, T_true)
    assert err.ate_m * 100 < 2.0, (err.ate_m * 100, notes)
