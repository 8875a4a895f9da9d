# SPDX-License-Identifier: BSD-3-Clause
"""The calibration's decoded sweeps kept across its registrations (``calibration.SweepCache``,
config ``calibration.sweep_cache_mb``): hand-eye, the turns' lever arm and each pass of the
turns' time offset de-skew the same windows again; with the cache each window is decoded once,
and every result is the same to the bit as without it."""

import numpy as np
import pytest

from sim_fixtures import make_rig_capture, true_stations, truth_extrinsic
from tripod_processor.reconstruction import calibration as cal
from tripod_processor.reconstruction.inputs import read_recording
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    import json

    cap = make_rig_capture(tmp_path_factory.mktemp("sweeps"), "hand")  # a pause, a reversal
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    return rec, true_stations(rec, truth), orient, truth_extrinsic(truth)


def _counting(monkeypatch):
    """The windows decoded (either decoder path of ``_sweep_points``), in call order."""
    calls = []

    def counting(real):
        def counted(payload, lidar_ns, a, b, **kw):
            calls.append((a, b))
            return real(payload, lidar_ns, a, b, **kw)
        return counted

    for name in ("decode_timed_points", "decode_xyz_time"):
        monkeypatch.setattr(cal, name, counting(getattr(cal, name)))
    return calls


def _same_turns(a, b):
    assert a.offset_ns == b.offset_ns
    assert a.sigma_ms == b.sigma_ms or (np.isnan(a.sigma_ms) and np.isnan(b.sigma_ms))
    assert a.pairs == b.pairs and a.rate_change_deg_s == b.rate_change_deg_s


def test_turns_and_hand_eye_the_same_to_the_bit_each_window_decoded_once(rig, monkeypatch):
    rec, stations, orient, ext = rig
    kw = dict(pairs_per_station=12, uses_per_sweep=2, passes=1)
    o2 = orient.with_offset(-3_000_000)  # a second pass: another offset, the same windows
    ext2 = Extrinsic(ext.R_imu_lidar, ext.lever_arm_m + 0.01, "moved")

    calls = _counting(monkeypatch)
    plain = [cal.time_offset_from_turns(rec.lidar, stations, orient, ext, 2, **kw),
             cal.time_offset_from_turns(rec.lidar, stations, o2, ext2, 2, **kw)]
    he_plain = cal.calibrate_mount(rec.lidar, stations, orient, 2, turn_ladder=3)
    n_plain = len(calls)
    assert len(set(calls)) < n_plain  # the same windows decoded again without the cache

    calls.clear()
    cache = cal.SweepCache(256)
    kept = [cal.time_offset_from_turns(rec.lidar, stations, orient, ext, 2, sweep_cache=cache,
                                       **kw),
            cal.time_offset_from_turns(rec.lidar, stations, o2, ext2, 2, sweep_cache=cache,
                                       **kw)]
    he_kept = cal.calibrate_mount(rec.lidar, stations, orient, 2, turn_ladder=3,
                                  sweep_cache=cache)
    assert len(calls) == len(set(calls))  # each window decoded once
    assert len(calls) < n_plain and cache.hits == n_plain - len(calls)
    assert 0 < cache.nbytes <= 256 * 2**20
    for a, b in zip(plain, kept):
        _same_turns(a, b)
    assert np.array_equal(he_plain[0].R_imu_lidar, he_kept[0].R_imu_lidar)
    assert np.array_equal(he_plain[0].lever_arm_m, he_kept[0].lever_arm_m)
    assert he_plain[1] == he_kept[1]
    cache.clear()
    assert cache.nbytes == 0


def test_sweep_from_the_cache_is_the_decoded_one_and_a_zero_cap_keeps_nothing(rig):
    rec, stations, orient, ext = rig
    st = stations[0]
    t0, win = st.start_ns + int(1e9), int(0.1e9)
    ref, ref_t = cal._sweep(rec.lidar, orient, ext, t0, win, 2, with_times=True)
    cache = cal.SweepCache(64)
    for _ in range(2):  # kept, then taken from the cache
        got, got_t = cal._sweep(rec.lidar, orient, ext, t0, win, 2, with_times=True,
                                cache=cache)
        assert np.array_equal(got, ref) and np.array_equal(got_t, ref_t)
        got_t[:] = 0  # the caller's copy: the kept times stay as they were
    assert cache.hits == 1 and cache.misses == 1
    # another range cut is another window's points
    far = cal._sweep(rec.lidar, orient, ext, t0, win, 2, min_range=1.5, cache=cache)
    assert cache.misses == 2 and len(far) < len(ref)
    off = cal.SweepCache(0)
    for _ in range(2):
        assert np.array_equal(cal._sweep(rec.lidar, orient, ext, t0, win, 2, cache=off), ref)
    assert off.hits == 0 and off.misses == 2 and off.nbytes == 0


def test_lever_arm_from_turns_stations_side_by_side_the_same_to_the_bit(rig, monkeypatch):
    """The turns' lever arm runs its stations on threads (each registration on one): every
    station's pairs and the result are those of the stations one after another, each
    registration on two threads (the old order)."""
    rec, stations, orient, ext = rig
    seq = {st.index: cal._turn_pairs(rec.lidar, st, orient, ext.R_imu_lidar, 2, 0.3, 0.1, 16,
                                     45.0) for st in stations}
    seen = {}
    real = cal._turn_pairs

    def recorded(lidar, st, *a, **kw):
        seen[st.index] = out = real(lidar, st, *a, **kw)
        return out

    monkeypatch.setattr(cal, "_turn_pairs", recorded)
    cache = cal.SweepCache(256)
    two = cal.lever_arm_from_turns(rec.lidar, stations, orient, ext, 2, sweep_cache=cache)
    assert set(seen) == set(seq)
    for k, (A, B) in seq.items():
        A2, B2 = seen[k]
        assert len(A) == len(A2) and all(np.array_equal(x, y) for x, y in zip(A, A2))
        assert all(np.array_equal(x, y) for x, y in zip(B, B2))
    assert two is None or two.pairs == sum(len(A) for A, _ in seq.values())


@pytest.mark.parametrize("firings,min_range", [(5, 0.5), (0, 0.5), (3, 1.5)])
def test_sweep_points_one_call_equal_to_the_records_smoothed(rig, firings, min_range):
    """A sweep decoded and smoothed in one decoder call (``decode_xyz_time``) is the records'
    ``denoise_ranges`` to the bit: the same points, order, xyz and times."""
    from tripod_processor.decode.timed import decode_timed_points, denoise_ranges

    rec, stations, _, _ = rig
    lidar = rec.lidar
    for st in stations[:2]:
        for a in range(st.packet_start, st.packet_stop - 80, 450):
            b = a + 75
            xyz, t = cal._sweep_points(lidar, a, b, min_range, firings)
            pts = decode_timed_points(lidar.payload, lidar.lidar_ns, a, b,
                                      min_range=min_range, max_range=40.0)
            ref = denoise_ranges(pts, firings).astype(np.float32)
            assert xyz.dtype == np.float32 and t.dtype == np.int64
            assert np.array_equal(xyz, ref)
            assert np.array_equal(t, pts["time_ns"].astype(np.int64))
