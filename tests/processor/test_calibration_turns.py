# SPDX-License-Identifier: BSD-3-Clause
"""The IMU time offset from the head's turns, and a lidar on its side far off the pan axis
(issue 12's failure kinds found on development rigs).

* A motor pan turns at a constant rate between its ramps: the stations' surfaces hardly see a
  time offset there (it only turns the fragment), so the offset comes from sweeps registered
  against each other across the ramps (``calibration.time_offset_from_turns``).
* A lidar on its side (87° mount) 16 cm off the pan axis in a hall, a hand-turned head that turns
  back (development rig 3's kind): the surfaces' time offset came out ~10 ms off (σ claimed
  1.9 ms, applied), which cut a station at its reversal. Now: every station whole, the time
  offset within 1 ms, the lever arm within 5 mm, station ATE within 1 cm / 0.1°.
"""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.calibration import time_offset_from_turns
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.pipeline import reconstruct
from tripod_processor.reconstruction.placement import ImuOrientation, fit_clock_map
from tripod_processor.sim.truth import score_stations


def test_time_offset_from_turns_on_a_motor_pan(tmp_path):
    """A constant-rate motor pan (ramps only), 4 stations, 8 ms IMU latency: within 1 ms from 0."""
    cap = make_rig_capture(tmp_path, "motor", stations=4, motion={
        "pan_profile": "constant", "pan_pause_s": 0.0, "pan_reversal_deg": 0.0,
        "tilt_deg": 45.0, "pan_s": 8.0}, imu={"latency_ms": 8.0})
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    t_true = ev.true_time_offset_ns(cap, rec)
    assert t_true < -5e6  # the offset to find is far from the prior 0
    est = time_offset_from_turns(rec.lidar, true_stations(rec, truth), orient,
                                 truth_extrinsic(truth), 2)
    assert est.pairs >= 3 and est.rate_change_deg_s > 10.0
    assert abs(est.offset_ns - t_true) < 1e6, (est, t_true)
    assert 0 < est.sigma_ms < 1.0


@pytest.fixture(scope="module")
def side(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("side"), "side", motion={
        "tilt_deg": 87.0, "lever_arm_m": [0.05, 0.0, 0.16], "pan_s": 10.0,
        "pan_reversal_deg": 35.0, "pan_pause_s": 0.0}, imu={"latency_ms": 2.0})
    out = tmp_path_factory.mktemp("side-out")
    cfg = ReconstructConfig()
    cfg.output.write_mcap = False
    cfg.output.report = False
    res = reconstruct(cap, out, cfg, quiet=True)
    return cap, out, res


def test_lidar_on_its_side_with_a_reversal_uncalibrated(side):
    cap, out, res = side
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    sc = score_stations(truth, [[s.start_ns, s.end_ns] for s in res.segmentation.stations])
    assert sc["recall"] == 1.0 and sc["precision"] == 1.0, sc  # no station cut at its reversal
    cal = json.loads((out / "calibration.json").read_text())
    t_true_ms = ev.true_time_offset_ns(cap, res.recording) * 1e-6
    assert abs(cal["imu_time_offset_s"] * 1e3 - t_true_ms) < 1.0
    assert cal["estimate"]["imu_time_offset_method"].startswith("turns")
    axis = np.asarray(truth["pan_axis_imu"])
    d = np.asarray(cal["lever_arm_m"]) - np.asarray(truth["lever_arm_imu_m"])
    assert np.linalg.norm(d - axis * (axis @ d)) < 0.005
    t, T = ev.load_sim_truth(cap)
    acc = ev.evaluate_run(out, t, T)
    assert acc["ate_cm"] < 1.0 and acc["ate_deg"] < 0.1, acc
