# SPDX-License-Identifier: BSD-3-Clause
"""The mount's turn about the pan axis from the carries (issue 12).

At a station the head turns about the pan axis only: hand-eye and the surfaces see the mount's
two tilts, not its turn about that axis, which keeps whatever hand-eye's noise left (dev seeds
83, 87, 40, 609: 1.2-2.2°). The lever arm, read in the IMU frame, turns with it (dev 87, 20-cm
lever: 5.9 mm off, 0.9 mm in the lidar frame). While carried the tripod turns about every axis:
``calibration.mount_yaw_from_carries`` fits that turn to the carries' sweep pairs, and the
pipeline (``calibration.mount_yaw_from_carries``, the config switch) turns the mount and the
lever arm together by it.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import calibration as C
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction import pipeline
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("yaw"), "yaw")
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), ev.true_time_offset_ns(cap, rec))
    return rec, truth, truth_extrinsic(truth), orient


def _turned(ext: Extrinsic, b: np.ndarray, deg: float) -> Extrinsic:
    Rb = Rotation.from_rotvec(np.radians(deg) * b).as_matrix()
    return Extrinsic(Rb @ ext.R_imu_lidar, Rb @ ext.lever_arm_m, ext.source)


def test_mount_turn_about_the_pan_axis_from_the_carries(rig):
    """The true mount turned 2° about the pan axis (the lever arm with it: every station the
    same): the carries find -2° within 0.6°; from the true mount, 0 within 0.6°."""
    rec, truth, ext, orient = rig
    stations = true_stations(rec, truth)
    b = np.asarray(truth["pan_axis_imu"], float)
    off = C.mount_yaw_from_carries(rec.lidar, stations, orient, _turned(ext, b, 2.0), 2,
                                   pan_axis_imu=b)
    assert off is not None and off.pairs >= 6 and off.carries == 2
    assert abs(np.degrees(off.angle_rad) + 2.0) < 0.6, off.to_dict()
    assert 0 < np.degrees(off.sigma_rad) < 1.0
    true = C.mount_yaw_from_carries(rec.lidar, stations, orient, ext, 2, pan_axis_imu=b)
    assert abs(np.degrees(true.angle_rad)) < 0.6, true.to_dict()
    # no carry (one station): nothing to measure
    assert C.mount_yaw_from_carries(rec.lidar, stations[:1], orient, ext, 2) is None


def test_pipeline_turns_mount_and_lever_together(monkeypatch):
    """The pipeline's step (registrations stubbed): mount and estimated lever arm turned by the
    carries' angle, the lever arm in the lidar frame unchanged; a given lever arm stays; a
    sigma over ``mount_yaw_max_sigma_deg`` leaves both."""
    b = np.array([0.0, 0.1, 1.0])
    b /= np.linalg.norm(b)
    R = Rotation.from_euler("xyz", [80.0, 5.0, 20.0], degrees=True).as_matrix()
    ell = np.array([0.12, -0.05, 0.03])
    ext = Extrinsic(R, ell, "calibrated")
    got = {"sigma": 0.3}
    monkeypatch.setattr(C, "mount_yaw_from_carries", lambda *a, **k: C.MountYaw(
        np.radians(1.5), np.radians(got["sigma"]), 20, 2, b))

    def cal():
        return SimpleNamespace(pan_axis_imu=b, R_imu_lidar=R.copy(), lever_arm_m=ell.copy(),
                               lever_basis_imu=C._perp_basis(b), mount_yaw=None)

    cfg = ReconstructConfig()
    assert cfg.calibration.mount_yaw_from_carries is True  # default; false: hand-eye's turn
    rec, seg = SimpleNamespace(lidar=None), SimpleNamespace(stations=[])
    c = cal()
    notes: list[str] = []
    out = pipeline._mount_yaw_from_carries(rec, seg, None, ext, cfg, c, True, notes)
    Rb = Rotation.from_rotvec(np.radians(1.5) * b).as_matrix()
    assert np.allclose(out.R_imu_lidar, Rb @ R) and np.allclose(out.lever_arm_m, Rb @ ell)
    assert np.allclose(out.R_imu_lidar.T @ out.lever_arm_m, R.T @ ell)  # lidar frame: same
    assert np.allclose(c.R_imu_lidar, out.R_imu_lidar) and np.allclose(c.lever_arm_m,
                                                                       out.lever_arm_m)
    assert c.mount_yaw["applied"] and abs(c.mount_yaw["angle_deg"] - 1.5) < 1e-9
    assert "applied" in notes[-1]
    # a lever arm given in the config stays where it was measured
    out = pipeline._mount_yaw_from_carries(rec, seg, None, ext, cfg, cal(), False, [])
    assert np.allclose(out.R_imu_lidar, Rb @ R) and np.allclose(out.lever_arm_m, ell)
    # too uncertain: hand-eye's turn kept
    got["sigma"] = 2.0
    c = cal()
    out = pipeline._mount_yaw_from_carries(rec, seg, None, ext, cfg, c, True, [])
    assert out is ext and c.mount_yaw["applied"] is False
