# SPDX-License-Identifier: BSD-3-Clause
"""Range smoothing along a laser's scan line (decode.scanline): less noise, edges kept, no
curvature bias for the quadratic fit; off gives the decoder's points as they are."""

import numpy as np
import pytest

from tripod_processor.decode.native import POINT_DTYPE
from tripod_processor.decode.scanline import FIRING_PERIOD_NS, smooth_scanline_ranges

STEP_RAD = np.deg2rad(0.2)  # azimuth per firing at 600 rpm


def _scan(true_range, n=720, rings=(0, 5), noise_m=0.03, seed=0):
    """Points of ``rings`` (one return) in firing order over ``n`` firings, each laser's range
    ``true_range(azimuth [rad])`` plus Gaussian noise; returns (points, true xyz)."""
    rng = np.random.default_rng(seed)
    az = np.arange(n) * STEP_RAD
    pts, truth = [], []
    for k in range(n):
        for ring in rings:
            el = np.deg2rad(-15 + 2 * ring)
            d = np.array([np.cos(el) * np.cos(az[k]), np.cos(el) * np.sin(az[k]), np.sin(el)])
            r0 = true_range(az[k])
            p = np.zeros((), POINT_DTYPE)
            p["x"], p["y"], p["z"] = d * (r0 + rng.normal(0, noise_m))
            p["ring"], p["return_type"] = ring, 1
            p["time_offset_ns"] = k * FIRING_PERIOD_NS
            pts.append(p)
            truth.append(d * r0)
    return np.array(pts, POINT_DTYPE), np.array(truth)


def _plane(az):  # a wall 2 m away seen from 0 to 80° incidence (azimuth 0 to 80°)
    return 2.0 / np.cos(np.clip(az, 0, np.deg2rad(80)))


def _err(xyz, truth):
    return np.linalg.norm(xyz.astype(np.float64), axis=1) - np.linalg.norm(truth, axis=1)


@pytest.mark.parametrize("fit", ["mean", "linear", "quadratic"])
def test_smoothing_reduces_noise_on_a_plane(fit):
    pts, truth = _scan(_plane, n=250)  # incidence 0-50°, the range 2-3.1 m
    raw = _err(smooth_scanline_ranges(pts, 0), truth)
    out = smooth_scanline_ranges(pts, 5, 0.15, fit=fit)  # 0.15 m: 5 sigma of the noise
    assert out.dtype == np.float32 and out.shape == (len(pts), 3)
    err = _err(out, truth)
    # on a full window of 11: 1/sqrt(11) of the noise (mean, linear), sqrt(0.21) (quadratic)
    assert np.std(err) < (0.55 if fit == "quadratic" else 0.35) * np.std(raw)
    # the beam's direction is kept
    d_in = truth / np.linalg.norm(truth, axis=1)[:, None]
    d_out = out / np.linalg.norm(out, axis=1)[:, None]
    assert np.max(np.linalg.norm(d_in - d_out, axis=1)) < 1e-5


def test_linear_fit_on_an_oblique_plane():
    # incidence 60-70°: the range climbs ~4 cm a firing, so the 10-cm step test cuts the
    # window short on one side at random; the mean then follows the slope, the line does not
    pts, truth = _scan(_plane, n=350, seed=1)
    far = slice(2 * 300, None)
    raw = _err(smooth_scanline_ranges(pts, 0), truth)[far]
    lin = _err(smooth_scanline_ranges(pts, 5, fit="linear"), truth)[far]
    mean = _err(smooth_scanline_ranges(pts, 5, fit="mean"), truth)[far]
    assert np.std(lin) < 0.8 * np.std(raw)
    assert np.std(lin) < 0.8 * np.std(mean)


def test_quadratic_has_no_curvature_bias():
    # no noise, strong curvature: a wall seen at 60-75° incidence, 3 m away
    def wall(az):
        return 3.0 / np.cos(np.deg2rad(60) + az * 0.25)

    pts, truth = _scan(wall, n=300, noise_m=0.0)
    inner = slice(2 * 20, -2 * 20)  # away from the scan's ends (windows cut short)
    mean = _err(smooth_scanline_ranges(pts, 8, fit="mean"), truth)[inner]
    quad = _err(smooth_scanline_ranges(pts, 8, fit="quadratic"), truth)[inner]
    assert np.median(mean) > 1e-4  # the mean is biased outward (range convex in azimuth)
    assert np.max(np.abs(quad)) < 0.2 * np.median(mean)


def test_depth_edge_is_kept():
    # a step of 0.5 m in range at azimuth 36° (firing 180): no point moves across it
    def step(az):
        return np.where(az < np.deg2rad(36), 2.0, 2.5)

    pts, truth = _scan(step, n=360, noise_m=0.01)
    for fit in ("mean", "linear", "quadratic"):
        err = _err(smooth_scanline_ranges(pts, 5, fit=fit), truth)
        assert np.max(np.abs(err)) < 0.05, fit


def test_off_and_lasers_apart():
    pts, _ = _scan(_plane, n=50)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    assert np.array_equal(smooth_scanline_ranges(pts, 0), xyz)
    # each laser is smoothed on its own: a laser alone gives the same points
    both = smooth_scanline_ranges(pts, 3)
    one = pts[pts["ring"] == 5]
    assert np.allclose(smooth_scanline_ranges(one, 3), both[pts["ring"] == 5], atol=1e-6)
    with pytest.raises(ValueError, match="scan-line fit"):
        smooth_scanline_ranges(pts, 3, fit="cubic")
