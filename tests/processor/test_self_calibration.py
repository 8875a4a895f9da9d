# SPDX-License-Identifier: BSD-3-Clause
"""Calibration from the data and station splitting on an uncalibrated rig (issue 12).

One small capture of the digital twin (``sim.rigs.small_rig``): a 12 x 10 m hall, the lidar
10 cm off the pan axis on a 60° mount, a hand-turned head with a pause and a reversal inside
every pan, a 4 ms IMU latency, 3 stations. The processor is told none of it.
"""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.config import ReconstructConfig, StationConfig
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.pipeline import reconstruct
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map
from tripod_shared.config_io import load_config


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    cap = make_rig_capture(root)
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    return cap, truth


@pytest.fixture(scope="module")
def run(rig, tmp_path_factory):
    cap, truth = rig
    out = tmp_path_factory.mktemp("rig-out")
    cfg = ReconstructConfig()
    cfg.output.write_mcap = False
    res = reconstruct(cap, out, cfg, quiet=True)
    return res, out


def _across(v, axis):
    v, axis = np.asarray(v), np.asarray(axis)
    return v - axis * (axis @ v)


def _matched(stations, truth):
    """Found stations whose middle lies in a true still period (each period used once)."""
    spans = [s["still"]["lidar_ns"] for s in truth["stations"]]
    used, hits = set(), 0
    for st in stations:
        m = [i for i, (a, b) in enumerate(spans) if a <= st.mid_ns <= b and i not in used]
        if m:
            used.add(m[0])
            hits += 1
    return hits


def test_stations_found_without_calibration(rig, run):
    """With the lever arm and the mount unknown (0, identity) the first pass finds stations to
    calibrate on and no false ones; with the calibration it found, the second finds every
    station once and whole, its pause and reversal included."""
    from tripod_processor.reconstruction.stations import segment_stations

    cap, truth = rig
    rec = read_recording(cap)
    o = ImuOrientation(rec.imu, fit_clock_map(rec.lidar))
    seg = segment_stations(rec.lidar, o, Extrinsic.identity(), StationConfig())
    assert len(seg.stations) >= 2 and _matched(seg.stations, truth) == len(seg.stations)
    res, _ = run
    final = res.segmentation.stations
    assert len(final) == len(truth["stations"]) == 3 and _matched(final, truth) == 3
    for st, tr in zip(final, truth["stations"]):
        p0, p1 = tr["pan"]["lidar_ns"]
        assert st.start_ns <= p0 + 0.6e9 and st.end_ns >= p1 - 0.6e9


def test_calibration_recovered_from_the_data(run, rig):
    res, out = run
    cap, truth = rig
    cal = json.loads((out / "calibration.json").read_text())
    axis = truth["pan_axis_imu"]
    err = np.linalg.norm(_across(cal["lever_arm_m"], axis)
                         - _across(truth["lever_arm_imu_m"], axis))
    assert err < 0.005  # the goal; measured 0.4 mm
    est = cal["estimate"]
    assert est["observable"]["lever_arm"] and max(est["lever_arm_sigma_m"]) < 0.003
    assert np.degrees(np.arccos(np.clip(np.dot(est["pan_axis_imu"], axis), -1, 1))) < 0.2
    # the time offset in the processor's terms (not simply −latency: the clock map absorbs the
    # lidar packets' receive delay)
    t_true_ms = ev.true_time_offset_ns(cap, res.recording) * 1e-6
    assert abs(cal["imu_time_offset_s"] * 1e3 - t_true_ms) < 1.0  # measured 0.03 ms
    assert est["observable"]["time_offset"]  # a hand-turned head changes its rate
    assert cal["source"] == {"q_imu_lidar": "data (hand-eye, tilts refined)",
                             "lever_arm_m": "data", "imu_time_offset_s": "data"}
    # the mount: the pan axis seen in the lidar frame (the turn about it changes nothing)
    from scipy.spatial.transform import Rotation

    def pan_in_lidar(q):
        return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix().T @ np.asarray(axis)

    tilt_err = np.degrees(np.arccos(np.clip(
        pan_in_lidar(cal["q_imu_lidar"]) @ pan_in_lidar(truth["q_imu_lidar_wxyz"]), -1, 1)))
    assert tilt_err < 0.1


def test_accuracy_without_calibration(run, rig):
    res, out = run
    cap, truth = rig
    t, T = ev.load_sim_truth(cap)
    acc = ev.evaluate_run(out, t, T, cap / "mesh.ply")
    assert acc["stations"] == 3 and _matched([f.station for f in res.fragments], truth) == 3
    # the goals: 1 cm / 0.1° time-matched, map median 1 cm (measured 0.10 cm /
    # 0.040°, 0.33 cm)
    assert acc["ate_cm"] < 1.0 and acc["ate_deg"] < 0.1
    assert acc["map_to_mesh_median_cm"] < 1.0


def test_report_calibration_section_and_timeline(run):
    res, out = run
    text = (out / "report.md").read_text()
    assert "## Calibration" in text
    assert "lever arm along the pan axis" in text and "unobservable" in text
    assert "| IMU time offset |" in text
    cal = json.loads((out / "calibration.json").read_text())["estimate"]
    turns = cal["imu_time_offset_turns"]
    assert turns["carry_pairs"] > 0  # 3 stations: 2 carries
    assert (f"{turns['pairs']} pairs of sweeps registered against each other "
            f"({turns['carry_pairs']} while the tripod was carried)") in text
    png = out / "report_stations.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    s = json.loads((out / "result.json").read_text())
    assert s["calibration"]["source"]["lever_arm_m"] == "data"


def test_given_calibration_wins(run, rig, tmp_path):
    """--set / --calibration values are used as given, not estimated, and say so."""
    res, out = run
    cap, truth = rig
    lever = [0.01, 0.02, 0.03]
    cfg = load_config(ReconstructConfig, overrides={
        "placement.extrinsic.lever_arm_m": lever, "placement.imu_time_offset_s": -0.002,
        "output.report": False, "output.write_mcap": False, "output.write_fragments": False})
    r2 = reconstruct(cap, tmp_path / "given", cfg, quiet=True)
    cal = json.loads((tmp_path / "given" / "calibration.json").read_text())
    assert cal["lever_arm_m"] == pytest.approx(lever)
    assert cal["imu_time_offset_s"] == pytest.approx(-0.002)
    assert cal["source"]["lever_arm_m"] == "config"
    assert cal["source"]["imu_time_offset_s"] == "config"
    assert r2.time_offset_ns == -2_000_000
    # the effective calibration of the first run loads back as a calibration file
    from tripod_processor.reconstruction.placement import load_extrinsic_file

    q, ell = load_extrinsic_file(out / "calibration.json")
    assert ell == pytest.approx(res.extrinsic.lever_arm_m.tolist())


def test_marks_split_and_short_periods():
    """Two operator marks in one still run split it; runs are found as [first, last]."""
    from tripod_processor.reconstruction.stations import _runs, _split_by_marks

    still = np.array([0, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 1, 1, 0], dtype=bool)
    assert _runs(still) == [(1, 8), (11, 12)]
    times = np.arange(len(still), dtype=np.int64) * 500_000_000
    marks = [(int(1.2e9), "a"), (int(3.2e9), "b")]
    parts = _split_by_marks(_runs(still), marks, times, 100_000_000)
    assert len(parts) == 3 and parts[0][0] == 1 and parts[1][1] == 8
    assert parts[0][1] < parts[1][0]
