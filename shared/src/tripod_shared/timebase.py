# SPDX-License-Identifier: BSD-3-Clause
"""Time conventions: every time is an ``int`` of nanoseconds named ``*_ns`` with its clock stated.

Clocks
------
``host_realtime``  CLOCK_REALTIME of the capture computer (UNIX epoch). Kernel receive
                   timestamps (SO_TIMESTAMPNS) and ``time.time_ns()`` read it. MCAP ``log_time``
                   of every recorded message is on this clock.
``host_monotonic`` CLOCK_MONOTONIC of the capture computer (never used in files; only for rates).
``lidar_toh``      the VLP-16's own clock: microseconds past the top of the hour, wraps every
                   3600 s. Synchronised to GPS when PPS is locked.
``imu_device``     the IMU's own clock, where a driver gives one (TFP callbacks carry none).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

NS_PER_US = 1_000
NS_PER_MS = 1_000_000
NS_PER_S = 1_000_000_000
HOUR_NS = 3600 * NS_PER_S
HOUR_US = 3600 * 1_000_000

CLOCK_HOST_REALTIME = "host_realtime"
CLOCK_HOST_MONOTONIC = "host_monotonic"
CLOCK_LIDAR_TOH = "lidar_toh"
CLOCK_IMU_DEVICE = "imu_device"

#: device time not given by this device
NO_DEVICE_TIME = -1


@dataclass(frozen=True, slots=True)
class TimePair:
    """One event seen on two clocks: the host at the read and the device's own stamp."""

    host_ns: int  # host_realtime
    device_ns: int  # device clock, or NO_DEVICE_TIME


def host_now_ns() -> int:
    """Current CLOCK_REALTIME in ns."""
    return time.time_ns()


def ns_to_sec_nsec(t_ns: int) -> tuple[int, int]:
    """Split ns into ROS ``builtin_interfaces/Time`` (sec: int32, nanosec: uint32)."""
    sec, nsec = divmod(int(t_ns), NS_PER_S)
    return sec, nsec


def sec_nsec_to_ns(sec: int, nsec: int) -> int:
    return int(sec) * NS_PER_S + int(nsec)


def toh_us_to_unix_ns(toh_us: int, reference_unix_ns: int) -> int:
    """Place a lidar µs-past-the-hour stamp on the UNIX time line.

    The hour is taken from ``reference_unix_ns`` (the host receive time, or GPRMC time), choosing
    the candidate hour that puts the result nearest to the reference: this is robust to the hour
    rollover as long as the two clocks agree to better than 30 minutes.
    """
    ref = int(reference_unix_ns)
    hour_start = ref - ref % HOUR_NS
    t = hour_start + int(toh_us) * NS_PER_US
    if t - ref > HOUR_NS // 2:
        t -= HOUR_NS
    elif ref - t > HOUR_NS // 2:
        t += HOUR_NS
    return t


def unwrap_toh_us(toh_us_seq, start_hour_us: int = 0) -> list[int]:
    """Unwrap a sequence of µs-past-the-hour stamps into a monotonic µs count.

    A backward jump of more than half an hour is taken as an hour rollover.
    """
    out: list[int] = []
    offset = start_hour_us
    prev = None
    for t in toh_us_seq:
        t = int(t)
        if prev is not None and prev - t > HOUR_US // 2:
            offset += HOUR_US
        elif prev is not None and t - prev > HOUR_US // 2:
            offset -= HOUR_US
        out.append(t + offset)
        prev = t
    return out
