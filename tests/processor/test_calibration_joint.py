# SPDX-License-Identifier: BSD-3-Clause
"""The IMU time offset from every station's turns, and the lever arm fitted jointly with it
(issue 12: any tripod, no calibration file).

Small captures of the digital twin with a known lever arm and IMU latency, on a hand-turned pan
(uneven speed, no pause, no reversal: the offset shows only in the hand's rate changes) and on a
motor pan at a constant rate (only its ramps show it). The offset comes from sweeps registered
against each other (``calibration.time_offset_from_turns``: pairs far apart when the mount's
sweeps overlap, the IMU's yaw drift fitted with it), then joins the stations' surfaces as a prior
(``self_calibrate(time_prior_ns=...)``): both within 1 ms, the lever arm across the pan axis
within 5 mm, the offset's sigma honest (the error within 3 sigma).
"""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.calibration import (max_pair_turn_deg, self_calibrate,
                                                         time_offset_from_turns)
from tripod_processor.reconstruction.config import CalibrationConfig
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map

PANS = {
    # a hand-turned head: speed changes only (the turns' pairs are the hand's rate changes)
    "hand": {"pan_profile": "hand", "pan_pause_s": 0.0, "pan_reversal_deg": 0.0,
             "pan_speed_variation": 0.4, "tilt_deg": 20.0, "pan_s": 10.0,
             "lever_arm_m": [0.09, -0.06, 0.03]},
    # a motor at a constant rate: the ramps at each end of the pan only
    "constant": {"pan_profile": "constant", "pan_pause_s": 0.0, "pan_reversal_deg": 0.0,
                 "tilt_deg": 50.0, "pan_s": 8.0, "lever_arm_m": [-0.05, 0.11, 0.02]},
}


def _truth_rotation(truth):
    from scipy.spatial.transform import Rotation

    q = truth["q_imu_lidar_wxyz"]
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


@pytest.fixture(scope="module", params=sorted(PANS))
def capture(request, tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp(request.param), request.param,
                           stations=3, motion=PANS[request.param],
                           imu={"latency_ms": 7.0, "latency_jitter_ms": 0.5})
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    return request.param, cap, truth, rec, orient, true_stations(rec, truth)


def test_max_pair_turn_follows_the_mount():
    """A spin axis on the pan axis pairs any turn; a lidar on its side keeps the floor."""
    assert max_pair_turn_deg(np.array([0.0, 0.0, 1.0])) == 180.0
    t = lambda deg: np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])  # noqa
    assert 75.0 < max_pair_turn_deg(t(18.0)) < 90.0
    assert max_pair_turn_deg(t(45.0)) < max_pair_turn_deg(t(30.0)) < max_pair_turn_deg(t(18.0))
    assert max_pair_turn_deg(t(89.0)) == 20.0


def test_time_offset_from_every_stations_turns(capture):
    """From the prior 0, with the mount known and the lever arm not: within 1 ms, sigma
    honest (error within 3 sigma) and small enough to be applied."""
    name, cap, truth, rec, orient, stations = capture
    t_true = ev.true_time_offset_ns(cap, rec)
    assert t_true < -4e6  # far from the prior 0
    ext = Extrinsic(_truth_rotation(truth), np.zeros(3), "test")
    est = time_offset_from_turns(rec.lidar, stations, orient, ext, 2)
    err_ms = (est.offset_ns - t_true) * 1e-6
    assert est.pairs >= 6, est
    assert abs(err_ms) < 1.0, (name, est, err_ms)
    assert abs(err_ms) < 3 * est.sigma_ms + 0.1, (name, est, err_ms)
    assert est.sigma_ms < CalibrationConfig().max_turns_time_offset_sigma_ms  # applied


def test_lever_arm_and_offset_jointly(capture):
    """The turns' offset as the surfaces' prior: the lever arm across the pan axis within
    5 mm (from 0) and the offset within 1 ms, with their sigmas."""
    name, cap, truth, rec, orient, stations = capture
    t_true = ev.true_time_offset_ns(cap, rec)
    ext = Extrinsic(_truth_rotation(truth), np.zeros(3), "test")
    turn = time_offset_from_turns(rec.lidar, stations, orient, ext, 2)
    cal = self_calibrate(rec.lidar, stations, orient.with_offset(turn.offset_ns), ext,
                         fit_rotation=False, num_threads=2, time_prior_ns=turn.offset_ns,
                         time_prior_sigma_ms=turn.sigma_ms)
    axis = np.asarray(truth["pan_axis_imu"])
    d = cal.lever_arm_m - np.asarray(truth["lever_arm_imu_m"])
    lever_err = float(np.linalg.norm(d - axis * (axis @ d)))
    assert lever_err < 0.005, (name, lever_err, cal.lever_arm_sigma_m)
    err_ms = (cal.time_offset_ns - t_true) * 1e-6
    assert abs(err_ms) < 1.0, (name, err_ms, cal.time_offset_sigma_ms)
    # the prior is information: the joint sigma is no larger than the turns' own
    assert cal.time_offset_sigma_ms <= turn.sigma_ms + 1e-9


def test_a_tight_prior_holds_the_offset(capture):
    """A prior of 0.01 ms holds the surfaces' offset there (it is a residual of the fit)."""
    name, cap, truth, rec, orient, stations = capture
    ext = Extrinsic(_truth_rotation(truth), np.zeros(3), "test")
    target = ev.true_time_offset_ns(cap, rec) + 3_000_000  # 3 ms off the truth
    cal = self_calibrate(rec.lidar, stations[:2], orient.with_offset(target), ext,
                         fit_rotation=False, num_threads=2, iterations=4,
                         time_prior_ns=target, time_prior_sigma_ms=0.01)
    assert abs(cal.time_offset_ns - target) < 0.05e6, (name, (cal.time_offset_ns - target) * 1e-6)
