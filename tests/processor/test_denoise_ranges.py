"""Range smoothing along the scan line (decode.timed.denoise_ranges)."""

import numpy as np

from tripod_processor.decode.scanline import FIRING_PERIOD_NS
from tripod_processor.decode.timed import TIMED_POINT_DTYPE, denoise_ranges


def _scan(ranges_true: np.ndarray, az_deg: np.ndarray, elev_deg: float, ring: int,
          t0_ns: int, noise_m: float, rng, return_type: int = 0) -> np.ndarray:
    """One laser's consecutive firings: points along beams at the given azimuths, with
    Gaussian noise along each beam."""
    r = ranges_true + rng.normal(0.0, noise_m, len(ranges_true))
    az, el = np.radians(az_deg), np.radians(elev_deg)
    p = np.empty(len(r), TIMED_POINT_DTYPE)
    p["x"] = r * np.cos(el) * np.cos(az)
    p["y"] = r * np.cos(el) * np.sin(az)
    p["z"] = r * np.sin(el)
    p["intensity"] = 10
    p["ring"] = ring
    p["return_type"] = return_type
    p["time_ns"] = t0_ns + FIRING_PERIOD_NS * np.arange(len(r))
    return p


def _wall_ranges(az_deg, dist_m):
    """Ranges to the plane x = dist_m seen at these azimuths (elevation 0)."""
    return dist_m / np.cos(np.radians(az_deg))


def test_noise_along_the_beam_is_averaged_and_the_direction_kept():
    rng = np.random.default_rng(0)
    az = np.arange(-30, 30, 0.2)
    truth = _wall_ranges(az, 3.0)
    pts = _scan(truth, az, 0.0, ring=7, t0_ns=10**18, noise_m=0.03, rng=rng)
    xyz = denoise_ranges(pts, firings=5)
    r = np.linalg.norm(xyz, axis=1)
    raw = np.linalg.norm(np.stack([pts["x"], pts["y"], pts["z"]], 1).astype(np.float64), axis=1)
    inner = slice(10, -10)
    err_raw = np.std(raw[inner] - truth[inner])
    err = np.std(r[inner] - truth[inner])
    assert err < err_raw / 2.5  # 11 firings: about 1/sqrt(11)
    assert abs(np.mean(r[inner] - truth[inner])) < 0.003  # no bias on the plane [m]
    # only the range changes: each point stays on its own beam
    d_raw = np.stack([pts["x"], pts["y"], pts["z"]], 1) / raw[:, None]
    np.testing.assert_allclose(xyz / r[:, None], d_raw, atol=1e-6)


def test_a_depth_edge_is_not_smoothed_across():
    rng = np.random.default_rng(1)
    az = np.arange(0, 20, 0.2)
    truth = np.where(az < 10, 3.0, 4.0)  # a door frame: 1 m step in range
    pts = _scan(truth, az, 0.0, ring=3, t0_ns=10**18, noise_m=0.01, rng=rng)
    r = np.linalg.norm(denoise_ranges(pts, firings=5), axis=1)
    assert np.max(np.abs(r - truth)) < 0.03


def test_lasers_returns_and_gaps_are_kept_apart():
    rng = np.random.default_rng(2)
    az = np.arange(0, 10, 0.2)
    t0 = 10**18
    a = _scan(np.full(len(az), 3.0), az, -15.0, ring=0, t0_ns=t0, noise_m=0.0, rng=rng)
    # another laser and the other return at the same firings, 5 cm further: never averaged in
    b = _scan(np.full(len(az), 3.05), az, 1.0, ring=1, t0_ns=t0, noise_m=0.0, rng=rng)
    c = _scan(np.full(len(az), 3.05), az, -15.0, ring=0, t0_ns=t0, noise_m=0.0, rng=rng,
              return_type=1)
    # the same laser a rotation later (0.1 s), 5 cm further: not a neighbour in time
    d = _scan(np.full(len(az), 3.05), az, -15.0, ring=0, t0_ns=t0 + 100_000_000,
              noise_m=0.0, rng=rng)
    pts = np.concatenate([a, b, c, d])
    r = np.linalg.norm(denoise_ranges(pts, firings=5), axis=1)
    np.testing.assert_allclose(r[: len(a)], 3.0, atol=1e-5)
    np.testing.assert_allclose(r[len(a):], 3.05, atol=1e-5)


def test_zero_firings_gives_the_points_as_decoded():
    rng = np.random.default_rng(3)
    az = np.arange(0, 5, 0.2)
    pts = _scan(np.full(len(az), 2.0), az, 3.0, ring=5, t0_ns=10**18, noise_m=0.03, rng=rng)
    xyz = denoise_ranges(pts, firings=0)
    np.testing.assert_array_equal(xyz, np.stack([pts["x"], pts["y"], pts["z"]], 1))


def _lexsort_denoise(pts: np.ndarray, firings: int, max_step_m: float, fit: str) -> np.ndarray:
    """denoise_ranges as it was (a lexicographic sort, every point fitted): the reference."""
    from tripod_processor.decode.scanline import fit_ranges

    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    r = np.linalg.norm(xyz, axis=1)
    key = pts["ring"].astype(np.int64) * 256 + pts["return_type"].astype(np.int64)
    order = np.lexsort((pts["time_ns"], key))
    sm = fit_ranges(r[order], key[order], pts["time_ns"][order], firings, max_step_m, fit)
    scale = np.empty(len(r))
    scale[order] = sm / np.maximum(r[order], 1e-9)
    return xyz * scale[:, None]


def test_smoothing_some_points_gives_their_values_to_the_bit():
    """``at``: the kept points' xyz smoothed over all points, equal to the bit to smoothing all
    then keeping (the calibration's stations keep a tenth of the points they decode), in
    firing order and shuffled (the sorting fallback), with depth edges, two returns and gaps."""
    rng = np.random.default_rng(3)
    scans = []
    for ring in range(16):
        for rt in (0, 1):
            az = np.arange(-60, 60, 0.2)
            truth = np.where(az < 10, _wall_ranges(az, 3.0), _wall_ranges(az, 3.5))  # an edge
            s = _scan(truth, az, ring - 7.5, ring, 10**18 + 2300 * ring, 0.03, rng, rt)
            scans.append(s[rng.random(len(s)) > 0.05])  # missing returns
    fired = np.concatenate(scans)
    fired = fired[np.argsort(fired["time_ns"], kind="stable")]  # the decoder's order
    shuffled = fired[rng.permutation(len(fired))]
    for pts in (fired, shuffled):
        at = np.sort(rng.choice(len(pts), len(pts) // 10, replace=False))
        for fit in ("mean", "linear"):
            ref = _lexsort_denoise(pts, 5, 0.1, fit)
            assert denoise_ranges(pts, 5, fit=fit).tobytes() == ref.tobytes()
            assert denoise_ranges(pts, 5, fit=fit, at=at).tobytes() == ref[at].tobytes()
        assert np.array_equal(denoise_ranges(pts, 0, at=at), _lexsort_denoise(pts, 0, 0.1, "mean")[at])
