# SPDX-License-Identifier: BSD-3-Clause
"""The IMU time offset from the carries between stations (issue 12).

A slow or constant-rate pan changes its rate by a few °/s at most, which shows a 1 ms time
offset as a few thousandths of a degree; while the tripod is carried to the next station its
head turns about every axis with rate changes of tens of °/s.
``calibration.time_offset_from_turns`` registers sweeps of the carries
(``calibration.carry_spans``) as well as the stations'.
"""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.calibration import carry_spans, time_offset_from_turns
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import ImuOrientation, fit_clock_map
from tripod_processor.reconstruction.stations import Station


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("carry"), "carry", imu={"latency_ms": 8.0})
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    return rec, truth, truth_extrinsic(truth), ev.true_time_offset_ns(cap, rec)


def test_carry_spans_are_the_gaps_between_stations():
    st = [Station(1, 20_000_000_000, 30_000_000_000, 0, 0),
          Station(0, 0, 10_000_000_000, 0, 0),
          Station(2, 30_500_000_000, 40_000_000_000, 0, 0)]
    # sorted by time; a gap shorter than min_s (a station cut in two) is no carry
    assert carry_spans(st) == [(10_000_000_000, 20_000_000_000)]
    assert carry_spans(st, min_s=0.4) == [(10_000_000_000, 20_000_000_000),
                                          (30_000_000_000, 30_500_000_000)]
    assert carry_spans(st[:1]) == []


def test_time_offset_from_the_carries_alone(rig):
    """No station pair at all: the carries alone find an 8-ms latency from a start at 0."""
    rec, truth, ext, t_true = rig
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    assert t_true < -5e6  # the offset to find is far from the prior 0
    stations = true_stations(rec, truth)
    spans = carry_spans(stations)
    assert len(spans) == 2  # 3 stations
    est = time_offset_from_turns(rec.lidar, stations, orient, ext, 2, pairs_per_station=0,
                                 carries=spans)
    assert est.carry_pairs >= 6 and est.carry_pairs == est.pairs
    assert abs(est.offset_ns - t_true) < 1e6, (est, t_true)
    assert 0 < est.sigma_ms < 1.5
    # without the carries nothing is measured: the offset stays at the prior, sigma inf
    none = time_offset_from_turns(rec.lidar, stations, orient, ext, 2, pairs_per_station=0)
    assert none.pairs == 0 and none.offset_ns == 0 and not np.isfinite(none.sigma_ms)


def test_carries_join_the_stations_pairs(rig):
    """Stations' and carries' pairs pooled (each kind weighed by its own scale): within 1 ms."""
    rec, truth, ext, t_true = rig
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    stations = true_stations(rec, truth)
    est = time_offset_from_turns(rec.lidar, stations, orient, ext, 2,
                                 carries=carry_spans(stations))
    assert est.carry_pairs >= 6 and est.pairs > est.carry_pairs
    assert abs(est.offset_ns - t_true) < 1e6, (est, t_true)
    assert est.to_dict()["carry_pairs"] == est.carry_pairs


def test_turns_offset_with_more_pairs_and_passes(rig):
    """``calibration.turn_pairs_per_station`` / ``_per_carry`` / ``turn_passes`` reach the turns'
    offset: 12 pairs a station and a carry register twice the pairs of the defaults' 6 and the
    passes go on until the offset stops moving; within 0.5 ms from a start 8 ms off."""
    from tripod_processor.reconstruction.config import CalibrationConfig

    rec, truth, ext, t_true = rig
    cc = CalibrationConfig(turn_pairs_per_station=12, turn_pairs_per_carry=12, turn_passes=4)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    stations = true_stations(rec, truth)
    est = time_offset_from_turns(rec.lidar, stations, orient, ext, 2,
                                 carries=carry_spans(stations), passes=cc.turn_passes,
                                 pairs_per_station=cc.turn_pairs_per_station,
                                 pairs_per_carry=cc.turn_pairs_per_carry)
    assert est.pairs >= 50 and est.carry_pairs >= 20, est
    assert abs(est.offset_ns - t_true) < 0.5e6, (est, t_true)
    with pytest.raises(ValueError):
        CalibrationConfig(turn_passes=0)


def test_axis_information_marginalises_the_other_turns_and_the_shift():
    """A registration's information about its turn about one axis: the diagonal entry when
    nothing correlates with it, less when another turn or the shift shares its effect."""
    from tripod_processor.reconstruction.calibration import _axis_information_sqrt

    a = np.array([0.0, 0.0, 1.0])
    info = np.diag([4.0, 9.0, 16.0, 1.0, 1.0, 1.0])
    assert _axis_information_sqrt(info, a) == pytest.approx(4.0)
    # the turn about z correlated with the turn about x: what is left of it is its Schur
    # complement, 16 - 3² / 4 = 13.75
    info[0, 2] = info[2, 0] = 3.0
    assert _axis_information_sqrt(info, a) == pytest.approx(np.sqrt(13.75))
    # ... and with the shift along x (a fan's turn mistaken for its shift): less again
    info[2, 3] = info[3, 2] = 0.5
    assert _axis_information_sqrt(info, a) < np.sqrt(13.75)


def test_pick_pairs_lets_a_sweep_join_several_pairs():
    """``uses_per_sweep``: the pairs whose rate changes most, a sweep in at most that many; 1
    is each sweep in one pair (the greedy order is kept: largest rate change first)."""
    from tripod_processor.reconstruction.calibration import _pick_pairs

    # candidates (k, j, rate change): sweep 0 has the largest changes with 1, 2 and 3
    k = np.array([0, 0, 0, 1, 2])
    j = np.array([1, 2, 3, 2, 3])
    dr = np.array([5.0, 4.0, 3.0, 2.0, 1.0])
    assert _pick_pairs(dr, k, j, 4, 10) == [(0, 1, 5.0), (2, 3, 1.0)]
    # sweep 0 joins two pairs, then (0, 3) is left out (0 used twice), (1, 2) joins, and
    # (2, 3) is left out (2 used twice)
    two = _pick_pairs(dr, k, j, 4, 10, uses_per_sweep=2)
    assert two == [(0, 1, 5.0), (0, 2, 4.0), (1, 2, 2.0)]
    assert _pick_pairs(dr, k, j, 4, 2, uses_per_sweep=2) == two[:2]


def test_default_turns_pair_each_station_sweep_twice(rig):
    """By default (``calibration.turn_sweep_uses`` 2, ``turn_pairs_per_station`` 12, pairs
    weighed by their registration's information about the pan-axis turn) a station registers
    more pairs than its sweeps could form one pair each (6 a station before), from the same
    sweeps; within 0.5 ms from a start 8 ms off."""
    from tripod_processor.reconstruction.config import CalibrationConfig

    rec, truth, ext, t_true = rig
    cc = CalibrationConfig()
    assert cc.turn_sweep_uses == 2 and cc.turn_pairs_per_station == 12
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    stations = true_stations(rec, truth)
    est = time_offset_from_turns(rec.lidar, stations, orient, ext, 2, passes=cc.turn_passes,
                                 pairs_per_station=cc.turn_pairs_per_station,
                                 uses_per_sweep=cc.turn_sweep_uses,
                                 station_information=cc.turn_station_information)
    assert est.carry_pairs == 0 and est.pairs > 6 * len(stations), est
    assert abs(est.offset_ns - t_true) < 0.5e6, (est, t_true)
    with pytest.raises(ValueError):
        CalibrationConfig(turn_sweep_uses=0)


def test_carries_fit_the_mount_error_that_leaks_into_the_offset(rig):
    """A mount rotation 1.5° off (hand-eye's is 1-2° off on hard dev rigs) turns a carried
    pair's predicted rotation by (I − Pᵀ)ε, which the carries' rows took for offset (1.8 ms
    here, with the carries alone); ``carry_mount`` fits that small correction in their rows
    (``calibration.turn_carry_mount``) and the offset comes back within 0.5 ms."""
    from scipy.spatial.transform import Rotation

    from tripod_processor.reconstruction.placement import Extrinsic

    rec, truth, ext, t_true = rig
    R_off = ext.R_imu_lidar @ Rotation.from_rotvec(np.radians([0.0, 0.0, 1.5])).as_matrix()
    ext_off = Extrinsic(R_off, ext.lever_arm_m, "test")
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), t_true)
    stations = true_stations(rec, truth)
    kw = dict(pairs_per_station=0, carries=carry_spans(stations), passes=1)
    old = time_offset_from_turns(rec.lidar, stations, orient, ext_off, 2, **kw)
    new = time_offset_from_turns(rec.lidar, stations, orient, ext_off, 2, carry_mount=True,
                                 **kw)
    assert abs(old.offset_ns - t_true) > 1.2e6, (old, t_true)
    assert abs(new.offset_ns - t_true) < 0.5e6, (new, t_true)
    assert new.carry_pairs >= 10


def test_split_combination_inflates_kinds_that_disagree():
    """``combine="split"``: each kind's offset fitted alone, joined by inverse variance with
    the carries' sigma floored; two kinds further apart than their sigmas allow get a sigma
    grown by the Birge ratio (honest), two that agree keep the plain inverse-variance one."""
    from tripod_processor.reconstruction.calibration import _join_kinds

    off, sig = _join_kinds((0.0, 0.5), (0.0, 0.5), carry_floor_ms=0.0)
    assert off == pytest.approx(0.0) and sig == pytest.approx(0.5 / np.sqrt(2))
    # the carries (second) floored at 1 ms: the stations weigh four times as much
    off, sig = _join_kinds((0.0, 0.5), (2.5, 0.1), carry_floor_ms=1.0)
    s_c = np.hypot(0.1, 1.0)
    w = np.array([1 / 0.25, 1 / s_c**2])
    mean = w[1] * 2.5 / w.sum()
    assert off == pytest.approx(mean)
    chi = np.sqrt(np.sum(w * (np.array([0.0, 2.5]) - mean) ** 2))
    assert chi > 1 and sig == pytest.approx(chi / np.sqrt(w.sum()))
    # one kind alone keeps its own offset and sigma (no floor)
    assert _join_kinds(None, (2.5, 0.1), carry_floor_ms=1.0) == (2.5, 0.1)
    assert _join_kinds((0.3, 0.4), None, carry_floor_ms=1.0) == (0.3, 0.4)
