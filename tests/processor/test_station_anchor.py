# SPDX-License-Identifier: BSD-3-Clause
"""A station's anchor attitude fitted over its IMU samples (``placement.station_anchor_rotation``):
the IMU's white noise at the station's middle time no longer turns the whole station (issue 12's
station angle error); a pan's ramps, speed change and reversal near the anchor are kept, a still
head is averaged, and a fragment built on the fitted anchor is the slerped one moved rigidly."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation
from test_imu_smoothing import _pan, _wxyz

from tripod_processor.reconstruction.inputs import ImuTrack
from tripod_processor.reconstruction.placement import ImuOrientation, station_anchor_rotation

R_BASE = Rotation.from_rotvec([0.01, -0.02, 0.3])  # the tripod's stand: level error and heading


@lru_cache(maxsize=1)
def _fine_pan() -> Rotation:
    return _pan(np.arange(0.0, 20.0, 0.0005))


def _truth(t_s: float) -> Rotation:
    """The noise-free attitude at t_s (the pan integrated on a fine grid)."""
    return _fine_pan()[int(round(t_s / 0.0005))] * R_BASE


def _errors(R_true: Rotation, anchors_s, trials: int, still: bool = False):
    """(slerped, fitted) per-axis errors [deg] at ``anchors_s`` over noisy draws (0.05°/axis)."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 20.0, 0.01)  # 100 Hz
    t_ns = (t * 1e9).astype(np.int64)
    raw, fit = [], []
    for _ in range(trials):
        noisy = R_true * Rotation.from_rotvec(rng.normal(0, np.radians(0.05), (len(t), 3)))
        o = ImuOrientation(ImuTrack(t_ns, _wxyz(noisy)), 0)
        for a_s in anchors_s:
            a = int(round(a_s * 1e9))
            tru = R_true[0] if still else _truth(a_s)
            R_raw = Rotation.from_matrix(o.rotation_at(np.array([a]))[0])
            R_fit = Rotation.from_matrix(station_anchor_rotation(o, int(0.5e9), int(19.5e9), a))
            raw.append(np.degrees((tru.inv() * R_raw).as_rotvec()))
            fit.append(np.degrees((tru.inv() * R_fit).as_rotvec()))
    return np.array(raw), np.array(fit)


def test_fitted_anchor_is_the_attitude_without_noise():
    t = np.arange(0.0, 20.0, 0.01)
    o = ImuOrientation(ImuTrack((t * 1e9).astype(np.int64), _wxyz(_pan(t) * R_BASE)), 0)
    for a_s in (3.0, 5.555, 10.3, 15.5):  # a steady pan, between samples, reversal, speed change
        a = int(round(a_s * 1e9))
        R = station_anchor_rotation(o, int(0.5e9), int(19.5e9), a)
        # a quadratic over 0.25 s through the reversal: a model error far below the noise
        assert np.degrees((_truth(a_s).inv() * Rotation.from_matrix(R)).magnitude()) < 0.01


def test_fitted_anchor_removes_most_of_the_white_noise():
    # anchors on a steady pan, between samples, in the reversal (10-10.6 s), at the speed change
    raw, fit = _errors(_pan(np.arange(0.0, 20.0, 0.01)) * R_BASE, (3.0, 5.555, 10.3, 15.5), 30)
    rms_raw = np.sqrt(np.mean(raw**2, axis=0))
    rms_fit = np.sqrt(np.mean(fit**2, axis=0))
    assert np.all((0.04 < rms_raw) & (rms_raw < 0.06))
    # the pan axis is [0.1, 0.2, 0.97] (mostly z): x and y are the tilt, averaged over the
    # station; z is mostly the pan angle, fitted over at most a second around the anchor
    assert np.all(rms_fit[:2] < 0.15 * rms_raw[:2])
    assert rms_fit[2] < 0.4 * rms_raw[2]
    assert np.abs(fit).max() < 0.5 * np.abs(raw).max()  # the reversal's worst draw too


def test_fitted_anchor_of_a_still_head_is_the_mean():
    R_true = Rotation.from_rotvec(np.tile(R_BASE.as_rotvec(), (2000, 1)))
    raw, fit = _errors(R_true, (2.0, 10.0), 20, still=True)
    assert np.sqrt(np.mean(fit**2)) < 0.2 * np.sqrt(np.mean(raw**2))


def test_too_few_samples_keep_the_slerped_attitude():
    t = np.arange(0.0, 20.0, 0.01)
    o = ImuOrientation(ImuTrack((t * 1e9).astype(np.int64), _wxyz(_pan(t) * R_BASE)), 0)
    a = int(5.004e9)
    assert np.array_equal(station_anchor_rotation(o, int(5.0e9), int(5.05e9), a),
                          o.rotation_at(np.array([a]))[0])
