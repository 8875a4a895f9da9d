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
