# SPDX-License-Identifier: BSD-3-Clause
"""Hand-eye's mount rotation when the head turns back (a hand pan's reversal).

Dev rig 383 (a 38 x 15 m hall, lidar 75° off the pan axis, hand pans that turn back 33°):
hand-eye's sweep pairs there are consecutive 0.1-s windows (big turns of a lidar on its side
share too little view), fifteen of ~3° forward and one of 13° inside the reversal. With every
turn about one axis the mount is the shortest rotation taking the IMU's mean turn axis onto the
lidar's; summed as signed rotation vectors the reversed pair cancelled the forward ones (the sum
2 % of its terms), the registrations' noise set the mean axis, and the mount tilt came out 6.4°
off (then 1.6° after the surfaces' fit, the lever arm 136 mm off, station ATE 14 cm). The axis
has no sign: each pair is now signed along the principal axis first.
"""

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction import calibration as cal


def _pairs(R_il: np.ndarray, pan_axis_imu: np.ndarray, turns_deg: list[float], seed: int):
    """(A_list, B_list) as ``calibration._turn_pairs`` gives them for turns about one pan axis:
    B the IMU's turn (exact), A the lidar's as a registration measures it (axis noise ~1°)."""
    rng = np.random.default_rng(seed)
    A_list, B_list = [], []
    for th in turns_deg:
        B = Rotation.from_rotvec(np.radians(th) * pan_axis_imu).as_matrix()
        noise = Rotation.from_rotvec(rng.normal(0.0, np.radians(0.05), 3)).as_matrix()
        A = np.eye(4)
        A[:3, :3] = noise @ R_il.T @ B @ R_il
        A_list.append(A)
        B_list.append(B)
    return A_list, B_list


def _tilt_error_deg(R_est: np.ndarray, R_true: np.ndarray, b: np.ndarray) -> float:
    """Angle [deg] between the pan axis in the lidar frame, estimated and true (what hand-eye
    can see: its turn about the pan axis is set to zero)."""
    return float(np.degrees(np.arccos(np.clip((R_est.T @ b) @ (R_true.T @ b), -1.0, 1.0))))


def _mount(monkeypatch, turns_deg, seed=3):
    b = np.array([0.1, -0.2, 1.0])
    b /= np.linalg.norm(b)
    R_il = Rotation.from_euler("xyz", [75.0, 10.0, 30.0], degrees=True).as_matrix()
    A_list, B_list = _pairs(R_il, b, turns_deg, seed)
    monkeypatch.setattr(cal, "most_turning_station", lambda stations, orient: stations[0])
    monkeypatch.setattr(cal, "_turn_pairs", lambda *a, **k: (A_list, B_list))
    ext, info = cal.calibrate_mount(None, [SimpleNamespace(index=0)], None)
    return _tilt_error_deg(ext.R_imu_lidar, R_il, b), info


def test_hand_eye_mount_with_a_pair_turned_back(monkeypatch):
    """Fifteen 3° pairs forward, one 11.6° back (the rotation vectors' weighted sum nearly
    cancels): the mount tilt within 0.2° (17.5° off summed as signed)."""
    turns = [3.0] * 15 + [-11.6]
    err, info = _mount(monkeypatch, turns)
    assert info["pairs"] == 16
    assert err < 0.2, f"mount tilt {err:.2f}° off"


def test_hand_eye_mount_forward_pairs_unchanged(monkeypatch):
    """Pairs all turned one way, or all the other (no pair flipped): the mount as before."""
    turns = [3.0, 2.5, 4.0, 3.3, 13.0, 2.8]
    err_f, _ = _mount(monkeypatch, turns)
    err_b, _ = _mount(monkeypatch, [-t for t in turns])
    assert err_f < 0.2 and err_b < 0.2
