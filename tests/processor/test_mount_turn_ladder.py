# SPDX-License-Identifier: BSD-3-Clause
"""Hand-eye's mount tilt on a lidar a little off the pan axis in a big hall (issue 12).

A lidar 24° off the pan axis scans a band tilted 24° that moves up and down the walls as the
head turns: in a 34 x 24 m hall two 0.1-s sweeps 45° apart register to 0.1° but share only
38-49 % of their points, under hand-eye's 0.5 fitness gate, and half the 22.5° pairs fail it
too. Hand-eye then fell back to consecutive windows (~2-3° of turn), whose turn axis, hence the
mount tilt, the registrations' noise sets: 3-11° off per station on dev seed 5621 (56-s hand
pan, back 18°), 1.5° here. With ``calibration.mount_turn_ladder`` (3: 45, 22.5, 11.25, 5.6°,
then consecutive windows; the pairs registered at a level given up are kept) its pairs turn
~14° and the tilt comes within 0.5°; a tilt hand-eye measures poorly (σ over
``mount_tilt_warn_deg``) is warned about.
"""

import numpy as np
import pytest
from sim_fixtures import segmented_rig

from tripod_processor.reconstruction import pipeline as pl
from tripod_processor.reconstruction.calibration import pan_axis_in_imu
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.placement import Extrinsic


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    # one 20-s hand pan of half a turn (a pause, 20° back) in a 34 x 24 m hall, 24° mount
    rec, seg, orient, _, R_true = segmented_rig(
        tmp_path_factory.mktemp("tilted_hall"), "cap", 1, seed=5,
        scene_size={"width_m": 34.0, "depth_m": 24.0, "height_m": 6.0},
        motion={"tilt_deg": 24.0, "lever_arm_m": [0.1, -0.08, 0.05], "pan_s": 20.0,
                "pan_turns": 0.5})
    return rec, seg, orient, R_true, pan_axis_in_imu(orient, seg.stations)


def _hand_eye(hall, ladder: int):
    rec, seg, orient, R_true, b = hall
    rc = ReconstructConfig(num_threads=2, calibration={"mount_turn_ladder": ladder})
    notes: list[str] = []
    ext, _, sigma = pl._calibrate_mount(rec, seg, orient, Extrinsic.from_config(None, None),
                                        rc, 2, {}, True, notes)
    a, t = ext.R_imu_lidar.T @ b, R_true.T @ b  # the pan axis in the lidar frame
    return float(np.degrees(np.arccos(np.clip(a @ t, -1.0, 1.0)))), sigma, notes


def test_mount_tilt_from_halved_turns(hall):
    err, sigma, notes = _hand_eye(hall, ReconstructConfig().calibration.mount_turn_ladder)
    assert err < 0.5, f"hand-eye's mount tilt {err:.2f}° off (σ {sigma:.2f}°)"
    assert "median turn" in notes[0]
    turn = float(notes[0].split("median turn ")[1].split("°")[0])
    assert turn > 8.0, notes[0]


def test_old_ladder_small_turns_are_warned(hall):
    """The old ladder: consecutive windows, their axis scatter makes hand-eye's σ degrees and
    the run says so."""
    err, sigma, notes = _hand_eye(hall, 0)
    assert sigma > ReconstructConfig().calibration.mount_tilt_warn_deg
    assert any(n.startswith("WARNING: hand-eye's mount tilt poorly observable") for n in notes)
