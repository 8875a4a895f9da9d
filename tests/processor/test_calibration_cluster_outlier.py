# SPDX-License-Identifier: BSD-3-Clause
"""The turns' IMU time offset leaves out one cluster that disagrees with all the others
(issue 12, ``calibration.turn_cluster_outlier_z``).

A station's pairs (or a carry's) share its errors: one bad station (a small room's biased
registrations) or a span mis-taken for a carry moves all its pairs the same way, so trimming
pair by pair against the pooled fit (which that cluster already pulled) keeps them. Here a
synthetic carry-like motion and its IMU (as test_calibration_turn_anchor's) in four clusters,
one of whose "registrations" are the truth's turns 20 ms late: every cluster agrees but that
one, which pulls the pooled offset milliseconds off.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction.calibration import (TurnMeasurements, cluster_outlier,
                                                         fit_turn_offset)
from tripod_processor.reconstruction.inputs import ImuTrack
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation

T_TRUE_NS = -6_000_000  # the offset to find
RATE_HZ = 100.0
DUR_S = 40.0
N_CLUSTERS = 4
BAD = 2  # the cluster whose registrations are biased
BIAS_NS = 20_000_000  # ... as if its sweeps were 20 ms later than they are


def _truth(t_s: np.ndarray) -> Rotation:
    """A carried head's sways (0.9-1.8 Hz, 9-15°/s) about every axis on a slow turn."""
    t = np.asarray(t_s, dtype=np.float64)[:, None]
    f = np.array([0.9, 1.3, 1.8])
    amp = np.radians([15.0, 9.0, 11.0]) / (2 * np.pi * f)
    sway = amp * np.sin(2 * np.pi * f * t + np.array([0.3, 1.9, 4.0]))
    yaw = np.radians(10.0) * t[:, 0]
    return Rotation.from_euler("z", yaw[:, None]) * Rotation.from_rotvec(sway)


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(11)
    stamp_ns = np.round(np.arange(0.0, DUR_S, 1 / RATE_HZ) * 1e9).astype(np.int64)
    R_true = _truth((stamp_ns + T_TRUE_NS) * 1e-9)
    noise = Rotation.from_rotvec(rng.normal(0.0, np.radians(0.05), (len(stamp_ns), 3)))
    o = ImuOrientation(ImuTrack(stamp_ns, (R_true * noise).as_quat()[:, [3, 0, 1, 2]]), 0,
                       T_TRUE_NS)
    tk = np.arange(1_000_000_000, int((DUR_S - 2) * 1e9), 170_000_000, dtype=np.int64)
    tj = tk + 300_000_000
    n = len(tk)
    cluster = np.arange(n) * N_CLUSTERS // n
    late = np.where(cluster == BAD, BIAS_NS, 0)
    # registrations: the true turn with 0.02° of noise per axis (the bad cluster's, late)
    Rk, Rj = _truth((tk + late) * 1e-9), _truth((tj + late) * 1e-9)
    meas = []
    for m in range(n):
        A = np.eye(4)
        e = Rotation.from_rotvec(rng.normal(0.0, np.radians(0.02), 3))
        A[:3, :3] = (Rk[m].inv() * Rj[m] * e).as_matrix()
        meas.append((int(tk[m]), int(tj[m]), A, 30.0, np.eye(3)))
    tm = TurnMeasurements(meas, cluster.astype(np.int64), np.ones(n, dtype=bool),
                          np.array([0.0, 0.0, 1.0]))
    return tm, o, Extrinsic.identity()


def test_one_biased_cluster_is_left_out(setup):
    """The old fit (z 0) is pulled over 2 ms off by the late cluster; with z 3 that cluster is
    found (the only one over 3 combined sigmas from the rest) and left out: within 0.5 ms,
    its sigma still finite, the other clusters' pairs all in."""
    tm, o, ext = setup
    old = fit_turn_offset(tm, o, ext, anchor_smooth_s=0.1)
    assert abs(old.offset_ns - T_TRUE_NS) > 2e6, old
    assert old.dropped_cluster is None
    q, z, _ = cluster_outlier(tm, o, ext, 3.0, anchor_smooth_s=0.1)
    assert q == BAD and z > 3.0
    new = fit_turn_offset(tm, o, ext, anchor_smooth_s=0.1, cluster_outlier_z=3.0)
    assert new.dropped_cluster == BAD
    assert abs(new.offset_ns - T_TRUE_NS) < 0.5e6, new
    assert np.isfinite(new.sigma_ms) and new.pairs >= 0.9 * int((tm.cluster != BAD).sum())
    assert new.to_dict()["dropped_cluster"] == BAD


def test_consistent_clusters_are_all_kept(setup):
    """Without the bad cluster every cluster agrees: nothing is left out and the fit is the
    old one to the bit; with fewer than three clusters nothing is judged."""
    tm, o, ext = setup
    good = tm.subset(tm.cluster != BAD)
    assert cluster_outlier(good, o, ext, 3.0, anchor_smooth_s=0.1) is None
    old = fit_turn_offset(good, o, ext, anchor_smooth_s=0.1)
    new = fit_turn_offset(good, o, ext, anchor_smooth_s=0.1, cluster_outlier_z=3.0)
    assert new.offset_ns == old.offset_ns and new.sigma_ms == old.sigma_ms
    assert new.dropped_cluster is None and abs(new.offset_ns - T_TRUE_NS) < 0.5e6
    two = tm.subset(tm.cluster <= 1)
    assert cluster_outlier(two, o, ext, 0.0, anchor_smooth_s=0.1) is None
