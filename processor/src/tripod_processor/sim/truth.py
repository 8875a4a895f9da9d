# SPDX-License-Identifier: BSD-3-Clause
"""Scoring a processor's run against a simulated capture's truth (``meta.json["truth"]``):
station precision/recall by lidar-time overlap and the calibration errors. Pure numpy on
plain values, so ``bench/rigs.py`` and the processor's tests share one definition."""

from __future__ import annotations

import numpy as np

#: a found station matches a true one when it covers more than this share of it
MOST = 0.5


def true_station_spans(truth: dict, which: str = "still") -> np.ndarray:
    """(T, 2) int64 lidar-time spans [ns] of the true stations (``still``: carry to carry,
    the head may turn; ``pan``: while the head turns)."""
    return np.array([s[which]["lidar_ns"] for s in truth["stations"]],
                    dtype=np.int64).reshape(-1, 2)


def score_stations(truth: dict, found_spans_ns) -> dict:
    """:func:`match_stations` of a run's station spans (F, 2) [lidar ns] against the truth,
    the truth first moved by whole hours onto the run's time line (a replayed capture keeps
    the µs past the hour, not the hour). Adds ``true_spans_s`` / ``found_spans_s``: the spans
    in seconds from the first true station, for reading."""
    from tripod_shared.timebase import same_hour_shift_ns

    true_iv = true_station_spans(truth)
    found = np.asarray(found_spans_ns, dtype=np.int64).reshape(-1, 2)
    if len(found) and not true_iv[0, 0] <= found[0, 0] <= true_iv[-1, 1]:
        true_iv = true_iv + same_hour_shift_ns(int(true_iv[0, 0]), int(found[0, 0]))
    r = match_stations(true_iv, found)
    t0 = int(true_iv[0, 0]) if len(true_iv) else 0
    r["true_spans_s"] = np.round((true_iv - t0) * 1e-9, 2).tolist()
    r["found_spans_s"] = np.round((found - t0) * 1e-9, 2).tolist()
    return r


def match_stations(true_iv: np.ndarray, found_iv: np.ndarray) -> dict:
    """Match found station spans (F, 2) to true ones (T, 2) [ns, one time line].

    A true station is recalled when exactly one found station overlaps it significantly
    (more than min(1 s, 20 % of it)), that one covers more than ``MOST`` of it and overlaps no
    other true station significantly; a found station is precise when it recalls one.
    """
    T, F = len(true_iv), len(found_iv)
    if T == 0 or F == 0:
        return {"tp": 0, "true": T, "found": F, "recall": 0.0 if T else 1.0,
                "precision": 0.0 if F else 1.0, "splits": 0, "merges": 0}
    a = np.maximum(true_iv[:, None, 0], found_iv[None, :, 0])
    b = np.minimum(true_iv[:, None, 1], found_iv[None, :, 1])
    ov = np.maximum(b - a, 0).astype(np.float64)
    dur = (true_iv[:, 1] - true_iv[:, 0]).astype(np.float64)
    sig = (ov > 0) & (ov > np.minimum(1e9, 0.2 * dur)[:, None])
    one_t, one_f = sig.sum(axis=1) == 1, sig.sum(axis=0) == 1
    match = sig & (ov > MOST * dur[:, None]) & one_t[:, None] & one_f[None, :]
    tp = int(match.any(axis=1).sum())
    return {"tp": tp, "true": T, "found": F, "recall": tp / T, "precision": tp / F,
            "splits": int((sig.sum(axis=1) >= 2).sum()),
            "merges": int((sig.sum(axis=0) >= 2).sum())}


def _quat_angle_deg(q1, q2) -> float:
    d = abs(float(np.dot(np.asarray(q1, float), np.asarray(q2, float))))
    return float(np.degrees(2 * np.arccos(min(1.0, d))))


def calibration_errors(result: dict, truth: dict,
                       true_time_offset_ms: float | None = None) -> dict:
    """Errors of the calibration a run used against the truth (None: no estimate to judge).

    The lever arm is judged across the pan axis only (along it is unobservable) and only when
    the run estimated it (a ``calibration`` section with ``lever_arm_m`` in result.json); the
    time offset from ``calibration.imu_time_offset_ms`` or the run's ``imu_time_offset_ms``;
    the mount from the extrinsic's ``q_imu_lidar``. ``true_time_offset_ms``: the processor's
    own true value when it has one (its clock map), else ``truth["imu_time_offset_ms"]``.
    """
    cal = result.get("calibration") or {}
    out = {"lever_mm": None, "time_ms": None, "mount_deg": None}
    lever = cal.get("lever_arm_m")
    if lever is not None:
        axis = np.asarray(truth["pan_axis_imu"], float)
        d = np.asarray(lever, float) - np.asarray(truth["lever_arm_imu_m"], float)
        out["lever_mm"] = 1000 * float(np.linalg.norm(d - axis * (axis @ d)))
    off = cal.get("imu_time_offset_ms", result.get("imu_time_offset_ms"))
    if off is not None:
        want = truth["imu_time_offset_ms"] if true_time_offset_ms is None else true_time_offset_ms
        out["time_ms"] = abs(float(off) - want)
    q = (result.get("extrinsic") or {}).get("q_imu_lidar")
    if q is not None:
        out["mount_deg"] = _quat_angle_deg(q, truth["q_imu_lidar_wxyz"])
    return out


