# SPDX-License-Identifier: BSD-3-Clause
"""The surfaces' mount-tilt sigma from the spread of the stations' own fits (issue 12).

On a near-vertical lidar in a corridor (dev seed 722) the surfaces' joint fit landed 0.78° off
the true tilt while its model sigma said 0.03° (every voxel counted as independent), so it
replaced hand-eye's tilt (0.05° off); the stations fitted alone were 0.06-1.13° off. With
``calibration.tilt_spread_max_deg`` the sigma is at least the spread of the stations' own fits
(the sigma of their mean), the tilt counts as not observable, and it is weighed against
hand-eye's. Here the per-station fits are stand-ins with known tilts: the rule's arithmetic,
its gate (the spin axis's angle from the pan axis) and its off switch.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction import pipeline as pl
from tripod_processor.reconstruction.calibration import SelfCalibration
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.stations import Segmentation, Station


def _cal(R, stations, sigma_deg=0.03):
    return SelfCalibration(
        R, np.zeros(3), np.full(2, 1e-3), np.array([0.0, 0.0, 1.0]), 0, 0.5, sigma_deg, 0.0,
        True, True, sigma_deg < 0.05, stations, 0.01, 1000)


def _seg(n):
    st = [Station(k, k * 10**10, k * 10**10 + 5 * 10**9, 0, 1) for k in range(n)]
    return Segmentation(stations=st, t_ns=np.zeros(1), motion_m=np.zeros(1),
                        still=np.zeros(1, bool))


class _Orient:
    def with_offset(self, off):
        return self


def _run(monkeypatch, R_joint, tilts_deg, spread_max_deg=30.0):
    """_tilt_spread_sigma with stations fitted alone at the joint mount turned by
    ``tilts_deg`` (one (x, y) tilt [deg] about the lidar's x / y axes a station)."""
    seg = _seg(len(tilts_deg))
    alone = {k: R_joint @ Rotation.from_rotvec(np.radians([tx, ty, 0.0])).as_matrix()
             for k, (tx, ty) in enumerate(tilts_deg)}

    def fake_fit(rec, seg1, orient, ext, cfg, pps, **fit):
        assert fit["max_stations"] == 1 and len(seg1.stations) == 1
        assert np.allclose(ext.R_imu_lidar, R_joint)  # started from the joint result
        return _cal(alone[seg1.stations[0].index], [seg1.stations[0].index])

    monkeypatch.setattr(pl, "_fit_surfaces", fake_fit)
    cal = _cal(R_joint, list(range(len(tilts_deg))))
    cfg = ReconstructConfig(num_threads=2,
                            calibration={"tilt_spread_max_deg": spread_max_deg})
    pl._tilt_spread_sigma(None, seg, _Orient(), cfg, cal, 1000, True, True, {})
    return cal


def test_disagreeing_stations_raise_the_sigma(monkeypatch):
    """722's stations alone (tilt errors 1.13, 0.86, 0.06, 0.38° about one axis): the sigma of
    their mean, ~0.24°, not the model's 0.03°; the tilt is then not observable."""
    tilts = [(0.0, -1.13), (0.1, -0.86), (0.0, -0.06), (-0.1, -0.38)]
    cal = _run(monkeypatch, np.eye(3), tilts)
    want = np.std([t[1] for t in tilts], ddof=1) / 2.0
    assert cal.rotation_sigma_deg == pytest.approx(want, rel=1e-3)
    assert cal.tilt_spread_sigma_deg == pytest.approx(want, rel=1e-3)
    assert not cal.rotation_observable


def test_agreeing_stations_keep_the_model_sigma(monkeypatch):
    """Stations within a few hundredths of a degree (dev 721's): the model's sigma stays."""
    cal = _run(monkeypatch, np.eye(3), [(0.01, -0.02), (0.03, -0.04), (-0.01, -0.01),
                                        (0.02, 0.01)])
    assert cal.rotation_sigma_deg == pytest.approx(0.03)
    assert 0 < cal.tilt_spread_sigma_deg < 0.03
    assert cal.rotation_observable


def test_gate_and_switch(monkeypatch):
    """A lidar on its side (spin axis 90° from the pan axis) and the knob at 0: untouched."""
    tilts = [(0.0, -1.13), (0.1, -0.86), (0.0, -0.06), (-0.1, -0.38)]
    side = Rotation.from_rotvec([np.pi / 2, 0.0, 0.0]).as_matrix()
    cal = _run(monkeypatch, side, tilts)
    assert cal.rotation_sigma_deg == 0.03 and np.isnan(cal.tilt_spread_sigma_deg)
    cal = _run(monkeypatch, np.eye(3), tilts, spread_max_deg=0.0)
    assert cal.rotation_sigma_deg == 0.03 and cal.rotation_observable
    # under 3 stations: no spread to measure
    cal = _run(monkeypatch, np.eye(3), tilts[:2])
    assert cal.rotation_sigma_deg == 0.03
