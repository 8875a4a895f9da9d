# SPDX-License-Identifier: BSD-3-Clause
"""The surfaces' fit's station sample points kept across its fits (``points_cache`` of
``calibration.self_calibrate``, config ``calibration.station_points_cache_mb``): a fit again on
the same stations at the same time offset (after the mount tilt is weighed) takes the kept
points, the same result to the bit; another offset (other slow-turn weights) draws anew."""

import json

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import calibration as cal
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import ImuOrientation, fit_clock_map


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("stations"), "hand")
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    return rec, true_stations(rec, truth), orient, truth_extrinsic(truth)


def test_station_points_from_the_cache_are_the_drawn_ones(rig):
    rec, stations, orient, _ = rig
    st = stations[0]
    plain = cal._station_points(rec.lidar, st, 20_000, 11, 60.0, orient)
    cache = cal.SweepCache(64)
    first = cal._station_points(rec.lidar, st, 20_000, 11, 60.0, orient, cache=cache)
    again = cal._station_points(rec.lidar, st, 20_000, 11, 60.0, orient, cache=cache)
    assert cache.misses == 1 and cache.hits == 1
    assert again[0] is first[0]  # the kept arrays, read-only
    assert not again[0].flags.writeable
    for a, b in zip(plain, first):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    # another time offset: other slow-turn weights, so its own draw (a miss)
    cal._station_points(rec.lidar, st, 20_000, 11, 60.0, orient.with_offset(-20_000_000),
                        cache=cache)
    # another seed or sample size: its own draw
    cal._station_points(rec.lidar, st, 20_000, 12, 60.0, orient, cache=cache)
    cal._station_points(rec.lidar, st, 10_000, 11, 60.0, orient, cache=cache)
    assert cache.misses == 4 and cache.hits == 1


def test_self_calibrate_with_the_cache_the_same_to_the_bit(rig):
    rec, stations, orient, ext = rig
    kw = dict(points_per_station=20_000, iterations=3, num_threads=2)
    plain = cal.self_calibrate(rec.lidar, stations, orient, ext, **kw)
    cache = cal.SweepCache(64)
    first = cal.self_calibrate(rec.lidar, stations, orient, ext, points_cache=cache, **kw)
    n = cache.misses
    assert n >= 1 and cache.hits == 0
    again = cal.self_calibrate(rec.lidar, stations, orient, ext, points_cache=cache, **kw)
    assert cache.hits == n and cache.misses == n  # every station from the cache
    for r in (first, again):
        assert np.array_equal(r.lever_arm_m, plain.lever_arm_m)
        assert np.array_equal(r.R_imu_lidar, plain.R_imu_lidar)
        assert r.time_offset_ns == plain.time_offset_ns
        assert r.pairs == plain.pairs and r.residual_m == plain.residual_m
