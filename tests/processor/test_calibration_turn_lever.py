# SPDX-License-Identifier: BSD-3-Clause
"""The turns' IMU time offset measured again with the turns' lever arm (issue 12, stop 37).

The turns' sweeps are de-skewed with hand-eye's lever arm, often 5-15 cm off on a lidar on its
side. Each 0.1-s sweep is then smeared by the head's swing, more the faster it pans, and the
pair's registration turns with the rate change as an offset error does: a lidar 75° off the pan
axis in a 5 x 4 m room, the lever arm 15 cm off, gives the turns' offset ~0.7 ms off, the true
lever arm ~0.0. Once the lever arm's start comes from the turns
(``pipeline._lever_start_from_turns``) the offset is measured again with it
(``calibration.turn_relever_mm``; 0, the default: not, as before; mixed end to end, see the
config).
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.pipeline import (_lever_start_from_turns,
                                                      _join_with_surfaces,
                                                      _surfaces_own_offset,
                                                      _turns_after_surfaces,
                                                      _turns_again_with_lever,
                                                      _turns_time_offset)
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("turn-lever"), "room", scene="room",
                           scene_size={"width_m": 5.0, "depth_m": 4.0, "height_m": 2.8},
                           motion={"tilt_deg": 75.0, "lever_arm_m": [0.02, 0.10, 0.14]},
                           imu={"latency_ms": 6.0})
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    return rec, truth, ev.true_time_offset_ns(cap, rec)


def test_turns_offset_measured_again_with_the_turns_lever_arm(room):
    rec, truth, t_true = room
    cfg = ReconstructConfig()
    cfg.num_threads = 2
    cfg.calibration.turn_relever_mm = 20.0  # opt-in (default 0)
    seg = SimpleNamespace(stations=true_stations(rec, truth))
    et = truth_extrinsic(truth)
    # hand-eye's kind of lever arm: 15 cm off
    ext_he = Extrinsic(et.R_imu_lidar, et.lever_arm_m + np.array([0.0, 0.0, 0.15]), "guess")
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    turn = _turns_time_offset(rec, seg, orient, ext_he, cfg)
    orient = orient.with_offset(turn.offset_ns)
    err_he_ms = abs(turn.offset_ns - t_true) * 1e-6
    assert err_he_ms > 0.4, err_he_ms  # the smear's bias
    notes = []
    ext, lt = _lever_start_from_turns(rec, seg, orient, ext_he, cfg, notes)
    assert lt is not None and np.linalg.norm(ext.lever_arm_m - et.lever_arm_m) < 0.05
    again, orient2 = _turns_again_with_lever(rec, seg, orient, ext_he, ext, turn, cfg, notes)
    err_ms = abs(again.offset_ns - t_true) * 1e-6
    assert err_ms < 0.3 and err_ms < err_he_ms - 0.2, (err_he_ms, err_ms)
    assert orient2.time_offset_ns == again.offset_ns
    assert any("measured again" in n for n in notes)
    # off (the default): the first measurement, untouched
    cfg.calibration.turn_relever_mm = 0.0
    same, orient3 = _turns_again_with_lever(rec, seg, orient, ext_he, ext, turn, cfg, [])
    assert same is turn and orient3 is orient


def test_surfaces_own_offset_takes_the_prior_out():
    # data 2.0 ± 0.5 ms and prior 1.0 ± 0.4 ms give the posterior below; taking the prior out
    # gives the data back; a posterior no sharper than the prior leaves nothing (None)
    i_d, i_p = 1 / 0.5**2, 1 / 0.4**2
    post_ms = (2.0 * i_d + 1.0 * i_p) / (i_d + i_p)
    cal = SimpleNamespace(time_offset_ns=post_ms * 1e6, time_offset_sigma_ms=(i_d + i_p) ** -0.5)
    prior = SimpleNamespace(offset_ns=1_000_000, sigma_ms=0.4)
    m, s = _surfaces_own_offset(cal, prior)
    assert abs(m - 2e6) < 1 and abs(s - 0.5) < 1e-9
    assert _surfaces_own_offset(cal, None) == (cal.time_offset_ns, cal.time_offset_sigma_ms)
    cal.time_offset_sigma_ms = 0.4
    assert _surfaces_own_offset(cal, prior) is None


def test_turns_measured_again_after_the_surfaces_fit(room):
    # the first turns' offset with hand-eye's kind of lever arm (15 cm off) is biased; measured
    # again with the surfaces' fit's lever arm (here the true one, the fit's is within ~5 mm)
    # it is the result, joined with the surfaces' own offset when that agrees
    rec, truth, t_true = room
    cfg = ReconstructConfig()
    cfg.num_threads = 2
    seg = SimpleNamespace(stations=true_stations(rec, truth))
    et = truth_extrinsic(truth)
    ext_he = Extrinsic(et.R_imu_lidar, et.lever_arm_m + np.array([0.0, 0.0, 0.15]), "guess")
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    turn = _turns_time_offset(rec, seg, orient, ext_he, cfg)
    err_he_ms = abs(turn.offset_ns - t_true) * 1e-6
    orient = orient.with_offset(turn.offset_ns)
    cal = SimpleNamespace(time_offset_ns=turn.offset_ns, time_offset_sigma_ms=turn.sigma_ms,
                          time_offset_method="turns", time_offset_observable=True, turns=None)
    notes = []
    off = _turns_after_surfaces(rec, seg, orient, et, cfg, cal, None, turn.offset_ns, notes)
    err_ms = abs(off - t_true) * 1e-6
    assert err_ms < 0.3 and err_ms < err_he_ms - 0.2, (err_he_ms, err_ms)
    assert cal.time_offset_ns == off and cal.time_offset_method == "turns (after surfaces)"
    assert "after_surfaces" in cal.turns and any("measured again" in n for n in notes)
    # a surfaces' own estimate that agrees joins by inverse variance; one that does not, not
    m, s, joined = _join_with_surfaces(1_000_000, 0.4, (1_600_000, 0.4), 1.0)
    assert joined and abs(m - 1_300_000) < 1 and abs(s - 0.4 / np.sqrt(2)) < 1e-9
    assert _join_with_surfaces(1_000_000, 0.4, (4_000_000, 0.4), 1.0)[2] is False
    assert _join_with_surfaces(1_000_000, 0.4, (1_600_000, 1.5), 1.0)[2] is False
    assert _join_with_surfaces(1_000_000, 0.4, None, 1.0) == (1e6, 0.4, False)
