# SPDX-License-Identifier: BSD-3-Clause
"""4 x 4 rigid transforms for the pose-graph tests: built from a rotation vector [rad] and a
translation [m], and inverted."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def T_from(rotvec, t) -> np.ndarray:
    """(4, 4) with rotation ``rotvec`` (axis x angle [rad]) and translation ``t`` [m]."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4)."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
