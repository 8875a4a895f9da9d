# SPDX-License-Identifier: BSD-3-Clause
"""The lever arm's fit on a lidar mounted on its side (issue 12), on generated points.

A box room (6 x 5 x 3 m) with a pillar, the head panning one turn about the vertical at two
stations, the lidar's spin axis 85° off the pan axis (a near-vertical scan fan) and 9 cm off
the axis. Ray-cast points (1 cm range noise), no simulator: a few seconds.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tripod_processor.reconstruction import calibration as cal_mod
from tripod_processor.reconstruction.calibration import self_calibrate_samples
from tripod_processor.reconstruction.inputs import ImuTrack
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation
from tripod_processor.reconstruction.stations import Station

ROOM = (np.array([0.0, 0.0, 0.0]), np.array([6.0, 5.0, 3.0]))
PILLAR = (np.array([4.0, 1.0, 0.0]), np.array([4.5, 1.6, 3.0]))
R_IL = Rotation.from_euler("xz", [85.0, 20.0], degrees=True).as_matrix()
LEVER = np.array([0.07, -0.055, 0.02])  # [m] pivot → lidar, IMU frame (pan axis: IMU z)
PAN_S = 8.0
STATIONS = [np.array([2.0, 2.5, 1.3]), np.array([3.2, 3.4, 1.4])]


def _ray_box(o, d, lo, hi, inside):
    """Distance along unit rays d (N,3) from o (N,3) to an axis-aligned box (inf: missed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / d, (hi - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    if inside:
        return tmax
    return np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)


def _capture(seed=0):
    """(IMU orientation, stations, per-station (xyz lidar frame, time_ns))."""
    rng = np.random.default_rng(seed)
    elev = np.radians(np.linspace(-15.0, 15.0, 16))
    t0, gap = 1_000_000_000, 2_000_000_000
    q_t, q_all, data, stations = [], [], [], []
    for k, pivot in enumerate(STATIONS):
        start = t0 + k * (int(PAN_S * 1e9) + gap)
        # IMU at 100 Hz over the station; the pan: one turn with smooth ramps (rate changes)
        ti = np.arange(start - 200_000_000, start + int(PAN_S * 1e9) + 200_000_000, 10_000_000)
        s = np.clip((ti - start) / (PAN_S * 1e9), 0, 1)
        yaw = 2 * np.pi * 1.05 * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
        q_t.append(ti)
        q_all.append(Rotation.from_euler("z", yaw[:, None]).as_quat()[:, [3, 0, 1, 2]])
        # lidar: 10 rotations a second, 16 beams, ~6000 firings a station
        n = 6000
        t = np.sort(rng.integers(start, start + int(PAN_S * 1e9), n))
        az = 2 * np.pi * 10 * (t - start) * 1e-9 % (2 * np.pi)
        tt = np.repeat(t, 16)
        a, e = np.repeat(az, 16), np.tile(elev, n)
        d_l = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1)
        sp = np.clip((tt - start) / (PAN_S * 1e9), 0, 1)
        R_wi = Rotation.from_euler("z", (2 * np.pi * 1.05 * (sp - np.sin(2 * np.pi * sp)
                                                             / (2 * np.pi)))[:, None]).as_matrix()
        o = pivot + np.einsum("nij,j->ni", R_wi, LEVER)
        d_w = np.einsum("nij,nj->ni", R_wi, d_l @ R_IL.T)
        r = np.minimum(_ray_box(o, d_w, *ROOM, True), _ray_box(o, d_w, *PILLAR, False))
        r = r + rng.normal(0, 0.01, len(r))
        keep = np.isfinite(r) & (r > 1.0)
        data.append(((d_l * r[:, None])[keep], tt[keep].astype(np.int64)))
        stations.append(Station(k, start, start + int(PAN_S * 1e9), 0, 0))
    imu = ImuTrack(np.concatenate(q_t).astype(np.int64), np.concatenate(q_all))
    return ImuOrientation(imu, 0), stations, data


@pytest.fixture(scope="module")
def capture():
    return _capture()


def _across_err_mm(cal):
    b = cal.pan_axis_imu
    d = cal.lever_arm_m - LEVER
    return 1000 * float(np.linalg.norm(d - b * (b @ d)))


@pytest.mark.parametrize("start", [np.zeros(3), np.array([-0.01, -0.28, -0.07])])
def test_lever_arm_on_its_side_from_any_start(capture, start):
    """From the prior (0) or from a hand-eye lever arm 25 cm off (as on a slow pan of a mount
    on its side), the lever arm across the pan axis comes back within 5 mm, and both starts
    are reported."""
    orient, stations, data = capture
    cal = self_calibrate_samples(data, stations, orient, Extrinsic(R_IL, start, "guess"),
                                 fit_time=False, fit_rotation=False, num_threads=1)
    assert _across_err_mm(cal) < 5.0, cal.lever_starts
    assert cal.lever_arm_observable
    assert abs(cal.pan_axis_imu[2]) > 0.999
    names = [r["start"] for r in cal.lever_starts]
    assert names == (["given"] if not start.any() else ["given", "prior"])


def _cal(ell, sigma_mm, residual_m):
    return cal_mod.SelfCalibration(
        np.eye(3), np.asarray(ell, float), np.full(2, sigma_mm * 1e-3), np.array([0, 0, 1.0]),
        0, 0.1, 0.01, 0.0, True, True, True, [0], residual_m, 1000)


def test_pick_start_rules():
    """The same answer from both starts: the lower residual, observable. Different answers:
    the lower residual (the prior's when no residual is lower by ``same_cost_rel``), marked
    unobservable, with a sigma covering the gap."""
    U = cal_mod._perp_basis(np.array([0.0, 0.0, 1.0]))
    a, b = _cal([0.050, 0.0, 0.0], 1.0, 0.0101), _cal([0.052, 0.0, 0.0], 1.0, 0.0100)
    got = cal_mod._pick_start(a, b, U, 0.005, 0.0)
    assert got is b and got.lever_arm_observable
    for given_res, prior_res, rel, want in [(0.0100, 0.0102, 0.0, "given"),
                                            (0.0102, 0.0100, 0.0, "prior"),
                                            (0.0100, 0.01002, 0.01, "prior")]:
        far, near = _cal([0.25, 0.0, 0.0], 1.0, given_res), _cal([0.06, 0.0, 0.0], 1.0, prior_res)
        got = cal_mod._pick_start(far, near, U, 0.005, rel)
        assert got is (far if want == "given" else near)
        assert not got.lever_arm_observable
        assert np.max(got.lever_arm_sigma_m) >= 0.19 - 1e-9
        assert [r["start"] for r in got.lever_starts] == ["given", "prior"]
