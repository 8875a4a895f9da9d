# SPDX-License-Identifier: BSD-3-Clause
"""The turns' pair choice compares sweep-to-sweep angles with thresholds only
(``calibration._turn_angles_deg``: from the trace, scipy's exact angle near a threshold): every
comparison as with ``Rotation.from_matrix(...).magnitude()``."""

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction.calibration import _turn_angles_deg


def _scipy_deg(M):
    return np.degrees(Rotation.from_matrix(M).magnitude())


def test_threshold_comparisons_as_scipys_angles():
    rng = np.random.default_rng(0)
    ax = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])
    ang = np.cumsum(rng.uniform(0.0, 1.5, 1500))  # a pan with pauses, over several turns
    R = Rotation.from_rotvec(np.radians(ang)[:, None] * ax).as_matrix()
    R = R @ Rotation.from_rotvec(rng.normal(0.0, 1e-3, (len(R), 3))).as_matrix()
    for k in range(0, len(R) - 101, 5):
        ref = _scipy_deg(np.einsum("ji,njk->nik", R[k], R[k + 1:k + 101]))
        for th in [(3.0, 45.0), (2.8125,), (0.0,), (22.5, 179.0)]:
            got = _turn_angles_deg(R[k], R[k + 1:k + 101], th)
            assert np.max(np.abs(got - ref)) < 1e-8
            for x in th:
                assert np.array_equal(got >= x, ref >= x) and np.array_equal(got <= x, ref <= x)
    # a threshold exactly at a pair's angle: that angle is scipy's to the bit
    th = float(_scipy_deg(R[0].T @ R[5]))
    got = _turn_angles_deg(R[0], R[1:10], (th,))
    assert got[4] == th and np.array_equal(got >= th, _scipy_deg(
        np.einsum("ji,njk->nik", R[0], R[1:10])) >= th)
    # stacked first rotations (the carries' lags)
    k = np.arange(200)
    ref = _scipy_deg(np.einsum("nji,njk->nik", R[k], R[k + 3]))
    got = _turn_angles_deg(R[k], R[k + 3], (float(ref[10]),))
    assert np.max(np.abs(got - ref)) < 1e-8 and got[10] == ref[10]
