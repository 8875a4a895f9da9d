# SPDX-License-Identifier: BSD-3-Clause
"""Segmentation scores: a confusion matrix summed over scenes, per-class IoU from it."""

from __future__ import annotations

import numpy as np


def confusion(truth, pred, num_classes: int = 4) -> np.ndarray:
    """(C, C) int64 counts, rows = truth, columns = prediction; labels outside [0, C) ignored."""
    t = np.asarray(truth).astype(np.int64).ravel()
    p = np.asarray(pred).astype(np.int64).ravel()
    ok = (t >= 0) & (t < num_classes) & (p >= 0) & (p < num_classes)
    return np.bincount(t[ok] * num_classes + p[ok], minlength=num_classes ** 2).reshape(
        num_classes, num_classes)


def iou(conf: np.ndarray) -> np.ndarray:
    """(C,) IoU per class = TP / (TP + FP + FN); NaN for a class absent from truth and prediction."""
    conf = np.asarray(conf, dtype=np.float64)
    tp = np.diag(conf)
    denom = conf.sum(0) + conf.sum(1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denom > 0, tp / denom, np.nan)


def overall_accuracy(conf: np.ndarray) -> float:
    conf = np.asarray(conf, dtype=np.float64)
    return float(np.trace(conf) / max(conf.sum(), 1))
