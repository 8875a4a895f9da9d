# SPDX-License-Identifier: BSD-3-Clause
"""tripod_shared.timebase: the array forms agree with the scalar rule, the unwrapper with
unwrap_toh_us, over hour rollovers and chunk boundaries."""

import numpy as np

from tripod_shared import timebase as tb

H_US = tb.HOUR_US


def test_array_placement_matches_scalar():
    rng = np.random.default_rng(7)
    ref = 1_780_000_000 * tb.NS_PER_S + rng.integers(0, 4 * tb.HOUR_NS, 500)
    toh = rng.integers(0, H_US, 500)
    got = tb.toh_us_to_unix_ns_array(toh, ref)
    want = [tb.toh_us_to_unix_ns(int(a), int(r)) for a, r in zip(toh, ref)]
    assert got.dtype == np.int64 and got.tolist() == want
    assert (np.abs(got - ref) <= tb.HOUR_NS // 2).all()


def test_nearest_hour():
    ref = 1_780_000_000 * tb.NS_PER_S
    base = tb.nearest_hour_ns(H_US - 5, ref)
    assert base % tb.HOUR_NS == 0
    assert abs(base + (H_US - 5) * tb.NS_PER_US - ref) <= tb.HOUR_NS // 2


def test_unwrapper_over_rollover_and_chunks():
    toh = [H_US - 300, 50, 1000, H_US // 2, H_US - 10, 20]  # two rollovers, forward only
    want = [t * tb.NS_PER_US for t in tb.unwrap_toh_us(toh)]
    u = tb.TohChunkUnwrapper()
    got = np.concatenate([u(np.array(toh[:3])), u(np.array(toh[3:5])), u(np.array([])),
                          u(np.array(toh[5:]))])
    assert got.tolist() == want
    u2 = tb.TohChunkUnwrapper(base_ns=5 * tb.HOUR_NS)
    assert u2(np.array(toh))[0] == 5 * tb.HOUR_NS + toh[0] * tb.NS_PER_US


def test_same_hour_shift():
    t = 1_780_000_000 * tb.NS_PER_S
    assert tb.same_hour_shift_ns(t, t + 3 * tb.HOUR_NS + 7) == 3 * tb.HOUR_NS
    assert tb.same_hour_shift_ns(t, t - 2 * tb.HOUR_NS - 7) == -2 * tb.HOUR_NS
    assert tb.same_hour_shift_ns(t, t + 5) == 0


def test_unwrap_array_matches_list_form_both_directions():
    rng = np.random.default_rng(3)
    toh = rng.integers(0, H_US, 300)  # random stamps: backward and forward hour jumps alike
    assert tb.unwrap_toh_us_array(toh).tolist() == tb.unwrap_toh_us(toh.tolist())
    assert tb.unwrap_toh_us_array(toh, H_US).tolist() == tb.unwrap_toh_us(toh.tolist(), H_US)
    assert len(tb.unwrap_toh_us_array(np.array([], np.int64))) == 0


def test_ns_placement_keeps_sub_microsecond():
    ref = 1_780_000_000 * tb.NS_PER_S
    t = tb.toh_ns_to_unix_ns(1_234_567_891, ref)
    assert t % tb.HOUR_NS == 1_234_567_891 and abs(t - ref) <= tb.HOUR_NS // 2
