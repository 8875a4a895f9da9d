# SPDX-License-Identifier: BSD-3-Clause
"""The packets the surfaces' fit decodes for a station's sample (``calibration._station_packets``,
config ``calibration.station_decode_oversample``): 0 is the old integer stride to the index;
> 0 spreads ceil(x * n / 300) packets evenly, and the fit from that sample lands near the
old one's (a small hand-turned 60° rig, lever arm 10 cm, from a zero start)."""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import calibration as cal
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map
from tripod_processor.reconstruction.stations import Station


def test_packets_old_stride_by_default_fractional_with_oversample():
    for n_pk, n in [(15_000, 160_000), (15_000, 80_000), (3_000, 160_000), (40_000, 80_000)]:
        st = Station(0, 0, 1, 1000, 1000 + n_pk)
        old = np.arange(1000, 1000 + n_pk, max(1, int(n_pk * 300 / (10 * n))))
        assert np.array_equal(cal._station_packets(st, n), old)
        idx = cal._station_packets(st, n, 10.0)
        m = min(n_pk, int(np.ceil(10.0 * n / 300)))
        assert abs(len(idx) - m) <= 1 and idx[0] == 1000 and idx[-1] == 1000 + n_pk - 1
        assert np.all(np.diff(idx) > 0) and len(idx) <= len(old)


@pytest.mark.parametrize("oversample", [10.0])
def test_fit_from_the_fractional_stride_near_the_old(tmp_path, oversample):
    cap = make_rig_capture(tmp_path, "hand")
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    stations = true_stations(rec, truth)
    tx = truth_extrinsic(truth)
    ext = Extrinsic(tx.R_imu_lidar, np.zeros(3), "test")
    kw = dict(fit_rotation=False, fit_time=False, num_threads=2, points_per_station=160_000)
    a = cal.self_calibrate(rec.lidar, stations, orient, ext, **kw)
    b = cal.self_calibrate(rec.lidar, stations, orient, ext, decode_oversample=oversample, **kw)
    axis = a.pan_axis_imu
    across = lambda d: float(np.linalg.norm(d - axis * (axis @ d)))  # noqa: E731
    assert across(b.lever_arm_m - a.lever_arm_m) < 0.002, (a.lever_arm_m, b.lever_arm_m)
    assert across(b.lever_arm_m - tx.lever_arm_m) < 0.005
