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


# ---- hand-turned pans (issue 12: two test rigs went metre-level with the fit) ---------------
AXIS = np.array([0.1, 0.2, 0.97]) / np.linalg.norm([0.1, 0.2, 0.97])


def _hand_pan(t_s: np.ndarray, base_dps: float, jerk_dps: float = 0.0,
              reversal_at_s: float | None = None) -> Rotation:
    """A hand-turned head on a fine grid: a 0.4 s ramp to ``base_dps`` [°/s], speed levels
    changing every ~1.3 s through a smooth blend (±40 %), an optional 0.8 s reversal, and a
    hand's 6 Hz jerks of ±``jerk_dps``."""
    ramp = np.clip(t_s / 0.4, 0, 1)
    level = 1.0 + 0.4 * np.sin(2 * np.pi * t_s / 2.6) * np.sin(2 * np.pi * t_s / 7.1)
    rate = base_dps * ramp * level + jerk_dps * np.sin(2 * np.pi * 6.0 * t_s + 0.3 * np.sin(t_s))
    if reversal_at_s is not None:
        u = np.clip((t_s - reversal_at_s) / 0.8, 0, 1)
        rate = rate * np.where((u > 0) & (u < 1), np.cos(2 * np.pi * u), 1.0)
    ang = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_s))])
    return Rotation.from_rotvec(np.outer(np.radians(ang), AXIS)) * R_BASE


def _station_errors(R_fine: Rotation, dur_s: float, anchors_s, trials: int,
                    extra=None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(slerped, fitted) attitude errors [deg] against the truth and the fit's outcomes, the
    fine truth (0.5 ms) sampled at 100 Hz with 0.05°/axis white noise; ``extra``: a rotation
    per sample applied in the world (the walk at a station's edge) on top of the head's."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, dur_s, 0.01)
    t_ns = (t * 1e9).astype(np.int64)
    R_true = R_fine[::20][:len(t)]
    if extra is not None:
        R_true = extra * R_true
    raw, fit, outcomes = [], [], []
    for _ in range(trials):
        noisy = R_true * Rotation.from_rotvec(rng.normal(0, np.radians(0.05), (len(t), 3)))
        o = ImuOrientation(ImuTrack(t_ns, _wxyz(noisy)), 0)
        for a_s in anchors_s:
            k = int(round(a_s / 0.01))
            a = int(t_ns[k])
            info: dict = {}
            R_fit = station_anchor_rotation(o, int(t_ns[0]), int(t_ns[-1]) + 1, a, info=info)
            R_raw = o.rotation_at(np.array([a]))[0]
            raw.append(np.degrees((R_true[k].inv() * Rotation.from_matrix(R_raw)).magnitude()))
            fit.append(np.degrees((R_true[k].inv() * Rotation.from_matrix(R_fit)).magnitude()))
            outcomes.append(info["outcome"])
    return np.array(raw), np.array(fit), outcomes


def test_short_and_long_hand_turned_stations_are_fitted():
    # a 4-s station of a fast hand pan (~90°/s) and a 57-s slow one (~7°/s) with a reversal at
    # its middle: the fit keeps its gain and the guard never fires on a sound station
    for dur, dps, rev, anchors in ((4.0, 90.0, None, (2.0, 1.5, 2.7)),
                                   (57.0, 6.6, 28.3, (28.5, 28.7, 12.0, 40.0))):
        fine = _hand_pan(np.arange(0.0, dur + 0.01, 0.0005), dps, reversal_at_s=rev)
        raw, fit, outcomes = _station_errors(fine, dur, anchors, 15)
        assert all(o.startswith("fit") for o in outcomes), set(outcomes)
        assert np.sqrt(np.mean(fit**2)) < 0.6 * np.sqrt(np.mean(raw**2))
        assert fit.max() < 0.15


def test_hand_jerks_keep_the_pan_angle_of_the_samples():
    # 6 Hz jerks of ±20°/s move the head by ±0.5° about the pan axis: no quadratic window
    # follows them (residuals far above the noise and correlated), so the pan angle is the
    # slerped sample's (the tilt still averaged), not the last window's smoothed value, which
    # was 0.4° off on every anchor
    fine = _hand_pan(np.arange(0.0, 8.01, 0.0005), 90.0, jerk_dps=20.0)
    raw, fit, outcomes = _station_errors(fine, 8.0, (2.0, 3.333, 4.0, 5.5), 10)
    assert set(outcomes) == {"fit, pan slerped"}
    assert np.sqrt(np.mean(fit**2)) <= np.sqrt(np.mean(raw**2))
    assert fit.max() < 0.2


def test_a_fit_far_from_the_slerped_attitude_is_not_used():
    # the first 2 s of a 6-s station are the tripod still settling from the walk (an 8° tilt
    # fading out): one pan axis no longer holds, the averaged tilt is 0.4-1.4° off, and the
    # guard keeps the slerped attitude
    t = np.arange(0.0, 6.0, 0.01)
    fine = _hand_pan(np.arange(0.0, 6.01, 0.0005), 60.0)
    settle = Rotation.from_rotvec(np.outer(np.radians(8.0) * np.clip(1 - t / 2.0, 0, 1),
                                           [1.0, 0.0, 0.0]))
    raw, fit, outcomes = _station_errors(fine, 6.0, (3.0, 4.0), 5, extra=settle)
    assert all(o.startswith("off by") for o in outcomes), set(outcomes)
    assert np.array_equal(raw, fit)
    assert raw.max() < 0.25
