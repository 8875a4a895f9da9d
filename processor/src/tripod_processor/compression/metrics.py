# SPDX-License-Identifier: BSD-3-Clause
"""Geometric distortion: symmetric D1 (point-to-point) MSE and PSNR.

D1 MSE of A against B is the mean squared distance from each point of A to its nearest point of
B; the symmetric value is the larger of the two directions (MPEG pc_error convention). Two peaks:
* ``psnr_diag``: peak = bounding-box diagonal of the original, PSNR = 10 log10(diag^2 / MSE);
* ``psnr_mpeg10``: the MPEG 10-bit convention: coordinates scaled so the largest bounding-box
  side spans 1023 units, PSNR = 10 log10(3 * 1023^2 / MSE) (pc_error with resolution 1023).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class D1:
    """Symmetric point-to-point distortion of a decoded cloud against its original."""

    mse_m2: float  # [m^2]
    rmse_m: float  # [m]
    psnr_diag_db: float
    psnr_mpeg10_db: float


def d1(original: np.ndarray, decoded: np.ndarray, workers: int = -1) -> D1:
    """D1 distortion of ``decoded`` (M, 3) against ``original`` (N, 3), both [m]."""
    from scipy.spatial import cKDTree

    a = np.asarray(original, np.float64)[:, :3]
    b = np.asarray(decoded, np.float64)[:, :3]
    a = a[np.isfinite(a).all(1)]
    if len(a) == 0 or len(b) == 0:
        raise ValueError("D1 needs two non-empty clouds")
    d_ab, _ = cKDTree(b).query(a, workers=workers)
    d_ba, _ = cKDTree(a).query(b, workers=workers)
    mse = max(float(np.mean(d_ab**2)), float(np.mean(d_ba**2)))
    lo, hi = a.min(0), a.max(0)
    diag = float(np.linalg.norm(hi - lo))
    unit = float((hi - lo).max()) / 1023.0  # [m] per MPEG 10-bit unit
    if mse == 0.0:
        return D1(0.0, 0.0, math.inf, math.inf)
    return D1(mse, math.sqrt(mse), 10 * math.log10(diag**2 / mse),
              10 * math.log10(3 * 1023.0**2 / (mse / unit**2)) if unit > 0 else math.inf)
