# SPDX-License-Identifier: BSD-3-Clause
"""Clock mapping: lower envelope under jitter, drift, the lidar's hour rollover."""

from __future__ import annotations

import random

from tripod_shared.timebase import HOUR_US, NS_PER_S

from tripod_daemon.clock import ClockMapper, LidarClock, RateClock, TohUnwrapper


def test_unwrap_across_the_hour_and_a_late_packet():
    u = TohUnwrapper()
    a = u(HOUR_US - 500)
    b = u(100)  # rollover
    late = u(HOUR_US - 300)  # reordered packet from before the rollover
    c = u(800)
    assert b - a == 600_000  # 600 us later, in ns
    assert late - a == 200_000
    assert c - b == 700_000 and u.rollovers == 1


def test_mapper_finds_offset_and_drift_under_one_sided_jitter():
    rng = random.Random(1)
    offset = 1_700_000_000 * NS_PER_S + 123_456_789
    drift = 20e-6  # the device clock runs 20 ppm slow
    m = ClockMapper(window_s=0.5)
    dev = 0
    for _ in range(20_000):  # 10 s at 2 kHz
        dev += 500_000
        true_host = offset + dev + int(dev * drift)
        delay = int(rng.expovariate(1 / 200_000))  # mean 200 us, never negative
        m.add(dev, true_host + delay)
    assert abs(m.drift_ppm - 20.0) < 2.0
    pred = m.to_host(dev)
    truth = offset + dev + int(dev * drift)
    assert abs(pred - truth) < 50_000  # within 50 us although the mean delay is 200 us
    assert 100_000 < m.jitter_ns < 400_000


def test_lidar_clock_through_a_rollover_keeps_one_offset():
    c = LidarClock(window_s=0.2)
    host0 = 1_800_000_000 * NS_PER_S
    toh0 = HOUR_US - 1_000_000  # 1 s before the lidar's hour wraps
    for k in range(4000):  # 2.65 s at the dual-return rate
        us = toh0 + int(k * 663.552)
        c.add_data(us % HOUR_US, host0 + int(k * 663_552) + 50_000)
    s = c.summary()
    assert s["rollovers"] == 1 and s["resets"] == 0
    assert abs(s["offset_ns"] - (host0 + 50_000 - toh0 * 1000)) < 5_000
    c.add_data(HOUR_US + 5, host0)  # not a valid stamp: ignored
    assert c.summary()["samples"] == s["samples"]


def test_host_clock_step_restarts_the_estimate():
    m = ClockMapper(window_s=0.1)
    for k in range(100):
        m.add(k * 10_000_000, 5 * NS_PER_S + k * 10_000_000)
    for k in range(100, 200):  # host clock set forward by 10 s (NTP step)
        m.add(k * 10_000_000, 15 * NS_PER_S + k * 10_000_000)
    assert m.resets >= 1
    assert abs(m.offset_ns - 15 * NS_PER_S) < 1_000


def test_rate_clock_reports_period_and_jitter():
    rng = random.Random(3)
    r = RateClock()
    t = 0
    for _ in range(201):
        t += 10_000_000 + rng.randint(-200_000, 200_000)  # 100 Hz, +-0.2 ms uniform
        r.add(t)
    s = r.summary()
    assert abs(s["period_ns"] - 10_000_000) < 40_000
    assert 70_000 < s["jitter_ns"] < 130_000  # median absolute deviation of U(-0.2, 0.2) ms
