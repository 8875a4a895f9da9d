# SPDX-License-Identifier: BSD-3-Clause
"""Zero-phase smoothing of the IMU's attitude samples (``placement.smooth_quaternions``): the
white noise per sample drops, a pan's ramps and reversal are kept, and no lag is added (an IMU
time offset estimated on the smoothed track is unbiased)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction.inputs import ImuTrack
from tripod_processor.reconstruction.placement import ImuOrientation, smooth_quaternions


def _pan(t_s: np.ndarray) -> Rotation:
    """A pan about a tilted axis: a 0.3 s ramp to 36°/s, a 0.6 s reversal at 10 s, a hand's
    speed change at 15 s (rate [rad/s] integrated exactly by the cumulative trapezoid)."""
    rate = np.radians(36.0) * np.clip(t_s / 0.3, 0, 1)
    rate = rate * np.where(t_s > 10, np.cos(np.clip((t_s - 10) / 0.6, 0, 1) * np.pi), 1.0)
    rate = rate * (1.0 + 0.4 * np.clip((t_s - 15) / 1.0, 0, 1))
    ang = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_s))])
    axis = np.array([0.1, 0.2, 0.97]) / np.linalg.norm([0.1, 0.2, 0.97])
    return Rotation.from_rotvec(np.outer(ang, axis))


def _wxyz(R: Rotation) -> np.ndarray:
    q = R.as_quat()[:, [3, 0, 1, 2]]
    for k in range(1, len(q)):
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q


def _err_deg(q_wxyz: np.ndarray, R_true: Rotation) -> np.ndarray:
    """(K, 3) per-axis attitude error [deg]."""
    return np.degrees((R_true.inv() * Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]])).as_rotvec())


def test_smoothing_keeps_a_clean_pan_and_adds_no_lag():
    t = np.arange(0.0, 20.0, 0.01)  # 100 Hz
    R = _pan(t)
    q = _wxyz(R)
    qs = smooth_quaternions((t * 1e9).astype(np.int64), q, 0.15)
    e = _err_deg(qs, R)
    # a quadratic fit over ±75 ms keeps the ramps, the reversal and the speed change
    assert np.abs(e).max() < 0.01
    # no lag: the error about the pan axis does not follow the turn rate's sign
    assert abs(float(np.mean(e[50:-50] @ np.array([0.1, 0.2, 0.97])))) < 1e-4


def test_smoothing_removes_most_of_the_white_noise():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 20.0, 0.01)
    R = _pan(t)
    noisy = R * Rotation.from_rotvec(rng.normal(0, np.radians(0.05), (len(t), 3)))
    q = _wxyz(noisy)
    t_ns = (t * 1e9).astype(np.int64)
    raw = np.sqrt(np.mean(_err_deg(q, R)[20:-20] ** 2))
    sm = np.sqrt(np.mean(_err_deg(smooth_quaternions(t_ns, q, 0.15), R)[20:-20] ** 2))
    assert 0.045 < raw < 0.055
    assert sm < 0.45 * raw  # 16 samples, quadratic: ~0.41x
    # through ImuOrientation: the slerped attitude between samples is as much better, and the
    # offset copy keeps the smoothed samples
    o = ImuOrientation(ImuTrack(t_ns, q), 0, smooth_s=0.15).with_offset(0)
    t_fine = np.arange(0.0, 20.0, 0.001)  # the truth between samples, every 1 ms
    k = np.arange(1000, 19000, 7)
    e = _err_deg(o.quat_at((t_fine[k] * 1e9).round().astype(np.int64)), _pan(t_fine)[k])
    assert np.sqrt(np.mean(e**2)) < 0.45 * raw
    # 0: the raw samples, exactly
    assert np.array_equal(ImuOrientation(ImuTrack(t_ns, q), 0)._q, q)


def test_smoothing_keeps_gaps_and_ends_sane():
    t = np.concatenate([np.arange(0.0, 5.0, 0.01), np.arange(7.0, 9.0, 0.01)])  # a 2 s gap
    R = _pan(t)
    q = _wxyz(R)
    qs = smooth_quaternions((t * 1e9).astype(np.int64), q, 0.15)
    assert np.abs(_err_deg(qs, R)).max() < 0.02  # no fit across the gap
    assert np.allclose(smooth_quaternions(np.arange(3) * 10_000_000, q[:3], 0.15), q[:3])
