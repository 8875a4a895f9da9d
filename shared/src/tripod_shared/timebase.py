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
    return toh_ns_to_unix_ns(int(toh_us) * NS_PER_US, reference_unix_ns)


def toh_ns_to_unix_ns(toh_ns: int, reference_unix_ns: int) -> int:
    """:func:`toh_us_to_unix_ns` for a time past the hour given in ns."""
    ref = int(reference_unix_ns)
    hour_start = ref - ref % HOUR_NS
    t = hour_start + int(toh_ns)
    if t - ref > HOUR_NS // 2:
        t -= HOUR_NS
    elif ref - t > HOUR_NS // 2:
        t += HOUR_NS
    return t


def toh_us_to_unix_ns_array(toh_us, reference_unix_ns):
    """Vectorised :func:`toh_us_to_unix_ns`: each stamp on the hour nearest its reference.

    Parameters
    ----------
    toh_us : (N,) array_like of int [µs past the hour, lidar_toh]
    reference_unix_ns : (N,) array_like of int, or one int [ns, host_realtime or GPS]

    Returns
    -------
    (N,) int64 ndarray [ns, UNIX]
    """
    import numpy as np  # numpy only for the array forms: the scalar API stays dependency-free

    ref = np.asarray(reference_unix_ns, dtype=np.int64)
    t = ref - ref % HOUR_NS + np.asarray(toh_us).astype(np.int64) * NS_PER_US
    t = np.where(t - ref > HOUR_NS // 2, t - HOUR_NS, t)
    return np.where(ref - t > HOUR_NS // 2, t + HOUR_NS, t)


def nearest_hour_ns(toh_us: int, reference_unix_ns: int) -> int:
    """Start [ns, UNIX] of the hour that puts ``toh_us`` nearest to ``reference_unix_ns``."""
    return toh_us_to_unix_ns(toh_us, reference_unix_ns) - int(toh_us) * NS_PER_US


def same_hour_shift_ns(t_ns: int, reference_ns: int) -> int:
    """The whole number of hours [ns] that moves ``t_ns`` nearest to ``reference_ns``.

    For two time lines that agree on the µs past the hour but not on the hour (a capture replayed
    later keeps its lidar stamps but gets the replay's hour).
    """
    return round((int(reference_ns) - int(t_ns)) / HOUR_NS) * HOUR_NS


class TohChunkUnwrapper:
    """Streaming unwrap of µs-past-the-hour chunks (arrays) into one continuous ns time line.

    A backward jump of more than half an hour between consecutive stamps is an hour rollover.
    The first stamp is placed on the hour ``base_ns`` (0: device time since the top of the first
    hour; :func:`nearest_hour_ns` of a host stamp: UNIX time). State carries across chunks.
    """

    def __init__(self, base_ns: int = 0) -> None:
        self.base_ns = int(base_ns)
        self._prev_toh_ns: int | None = None

    def __call__(self, toh_us):
        """(N,) µs past the hour (array_like of int) → (N,) int64 ndarray [ns]."""
        import numpy as np

        toh_ns = np.asarray(toh_us).astype(np.int64) * NS_PER_US
        if len(toh_ns) == 0:
            return toh_ns
        prev = np.empty(len(toh_ns), np.int64)
        prev[0] = toh_ns[0] if self._prev_toh_ns is None else self._prev_toh_ns
        prev[1:] = toh_ns[:-1]
        base = self.base_ns + np.cumsum(toh_ns < prev - HOUR_NS // 2) * HOUR_NS
        self.base_ns, self._prev_toh_ns = int(base[-1]), int(toh_ns[-1])
        return base + toh_ns


class TohUnwrapper:
    """µs-past-the-hour stamps, one at a time -> a continuous device time [ns] (lidar_toh,
    unwrapped).

    A backward step of more than half an hour is a rollover (+1 h); a forward step of more than
    half an hour right after a rollover is a late packet from the previous hour (-1 h for it).
    """

    def __init__(self):
        self.hours = 0
        self.rollovers = 0
        self._prev: int | None = None

    def __call__(self, toh_us: int) -> int:
        prev = self._prev
        hours = self.hours
        if prev is not None:
            if prev - toh_us > HOUR_US // 2:
                self.hours = hours = hours + 1
                self.rollovers += 1
            elif toh_us - prev > HOUR_US // 2:
                # reordered packet from before the rollover: place it in the previous hour,
                # but keep the current hour for what follows
                return ((hours - 1) * HOUR_US + toh_us) * NS_PER_US
        self._prev = toh_us
        return (hours * HOUR_US + toh_us) * NS_PER_US


def unwrap_toh_us_array(toh_us, start_hour_us: int = 0):
    """Vectorised :func:`unwrap_toh_us`: (N,) µs past the hour → (N,) int64 monotonic µs."""
    import numpy as np

    t = np.asarray(toh_us).astype(np.int64)
    if len(t) == 0:
        return t
    d = np.diff(t)
    wraps = np.where(d < -(HOUR_US // 2), 1, 0) - np.where(d > HOUR_US // 2, 1, 0)
    return t + start_hour_us + np.concatenate([[0], np.cumsum(wraps)]) * HOUR_US


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
