# SPDX-License-Identifier: BSD-3-Clause
"""Gravity for scene understanding: the rotation that levels a cloud given its up direction.

The segmenter, the planes and the heightmap registration all assume z up. A cloud that carries
its up direction (``tripod reconstruct``'s fragments and map, or ``--up`` on the command line)
is turned by :func:`R_level_cloud` first: the smallest rotation taking ``up`` onto +z, so a cloud
that is already level is left as it is and the yaw of a tilted one changes as little as
possible.
"""

from __future__ import annotations

import numpy as np

from ..io.clouds import unit_up


def R_level_cloud(up) -> np.ndarray:
    """(3, 3) float64: the smallest rotation taking the unit of ``up`` (3,) onto +z
    (x_level = R @ x_cloud). ValueError for a zero or non-finite ``up``."""
    n = unit_up(up)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = float(np.linalg.norm(v)), float(n[2])
    if s < 1e-12:  # already up, or upside down: turn half a turn about x
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def level_points(points: np.ndarray, up) -> tuple[np.ndarray, np.ndarray]:
    """(levelled points (N, 3) in the dtype of ``points``, R_level_cloud (3, 3)): ``points``
    [m] turned so that ``up`` points along +z (about the cloud's origin, which stays put)."""
    R = R_level_cloud(up)
    P = np.asarray(points)
    dtype = P.dtype if P.dtype.kind == "f" else np.float64
    return (P @ R.T.astype(dtype)).astype(dtype, copy=False), R


def parse_up(text: str) -> np.ndarray:
    """``"X,Y,Z"`` → (3,) unit float64; ValueError with a one-line message otherwise."""
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise ValueError(f"--up: expected three numbers X,Y,Z, got {text!r}") from None
    if len(vals) != 3:
        raise ValueError(f"--up: expected three numbers X,Y,Z, got {text!r}")
    try:
        return unit_up(vals)
    except ValueError:
        raise ValueError(f"--up: {text!r} is not a direction (all zero or not finite)") from None
