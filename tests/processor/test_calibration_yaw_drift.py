# SPDX-License-Identifier: BSD-3-Clause
"""The IMU's heading drift in the surfaces' lever-arm fit (issue 12).

A fused attitude without magnetometer turns slowly about the world's vertical (the simulator's
``imu.yaw_drift_deg_per_min``). Within a station's pan that turns the later sightings against the
earlier ones by a shift that grows with the range. On a lidar on its side the lever arm along the
spin axis shifts opposite pan angles' scan planes against each other too, so with the drift held
at zero the fit takes part of it up there (here 1.8 mm; on the dev halls 8399, 455 and 383, which
end 4-7 mm off, it is a part only: see the README). Fitted as one more parameter
(``self_calibrate(fit_yaw_drift=True)``, opt-in ``calibration.fit_yaw_drift``) it comes out
near the truth here, and the lever arm is left alone.
"""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.calibration import self_calibrate
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map

DRIFT_DEG_PER_MIN = 4.0  # over a 6-s pan: 0.4°, as 0.5°/min over a 48-s one


@pytest.fixture(scope="module")
def side_hall(tmp_path_factory):
    """A lidar on its side (85°) in the 12 x 10 m hall, the IMU drifting; its stations, the
    orientation at the true time offset and the true extrinsic."""
    cap = make_rig_capture(tmp_path_factory.mktemp("drift"), "drift", motion={"tilt_deg": 85.0},
                           imu={"yaw_drift_deg_per_min": DRIFT_DEG_PER_MIN})
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), ev.true_time_offset_ns(cap, rec))
    return truth, rec, orient, true_stations(rec, truth), truth_extrinsic(truth)


def _lever_error_mm(cal, truth) -> float:
    axis = np.asarray(truth["pan_axis_imu"])
    d = cal.lever_arm_m - np.asarray(truth["lever_arm_imu_m"])
    return 1000 * float(np.linalg.norm(d - axis * (axis @ d)))


def _fit(side_hall, fit_yaw_drift: bool):
    truth, rec, orient, stations, ext = side_hall
    start = Extrinsic(ext.R_imu_lidar, ext.lever_arm_m, "test")  # from the true lever arm
    return self_calibrate(rec.lidar, stations, orient, start, fit_time=False,
                          fit_rotation=False, num_threads=2, fit_yaw_drift=fit_yaw_drift)


def test_the_drift_is_fitted_and_the_lever_arm_left_alone(side_hall):
    """From the true lever arm: with the drift fitted it stays (within 0.6 mm) and the drift
    comes out within 25 % of the truth; with it held at zero the lever arm is pulled off."""
    truth = side_hall[0]
    cal = _fit(side_hall, True)
    held = _fit(side_hall, False)
    assert abs(cal.yaw_drift_deg_per_min - DRIFT_DEG_PER_MIN) < 0.25 * DRIFT_DEG_PER_MIN, (
        cal.yaw_drift_deg_per_min)
    assert np.isnan(held.yaw_drift_deg_per_min)
    # measured: 0.1 mm fitted, 1.8 mm held
    assert _lever_error_mm(cal, truth) < 0.6, (_lever_error_mm(cal, truth), cal.lever_arm_sigma_m)
    assert _lever_error_mm(held, truth) > _lever_error_mm(cal, truth) + 1.0, (
        _lever_error_mm(held, truth), _lever_error_mm(cal, truth))
    assert cal.to_dict()["imu_yaw_drift_deg_per_min"] == cal.yaw_drift_deg_per_min

