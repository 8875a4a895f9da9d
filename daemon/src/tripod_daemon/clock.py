# SPDX-License-Identifier: BSD-3-Clause
"""Device clock -> host clock mapping, robust to receive jitter and the lidar's hour rollover.

Model: ``host_ns = device_ns + offset_ns + drift * (device_ns - ref_ns) + delay`` where the
delay (network, kernel, USB, scheduling) is never negative and mostly small. The lower envelope
of ``host - device`` is the delay-free offset, so each window keeps the *minimum*; a line
through the last window minima gives offset and drift (ppm). Jitter is the mean excess of the
samples over that envelope. Nothing here changes what is recorded: every message keeps its
host receive stamp, and the device stamp stays inside the payload (lidar) or in
``device_time_ns`` (IMU). The estimate goes into the status so a bad clock shows live.

Clocks: ``host_realtime`` (ns, UNIX), ``lidar_toh`` (µs past the hour, wraps every 3600 s),
``imu_device`` (the IMU's own time where it gives one).
"""

from __future__ import annotations

from collections import deque

from tripod_shared.timebase import (HOUR_US, NS_PER_S, NS_PER_US, TohUnwrapper,
                                    toh_us_to_unix_ns)


class ClockMapper:
    """Lower-envelope estimate of ``host_ns - device_ns`` with drift.

    Parameters
    ----------
    window_s : float
        Length of one minimum window [s of device time].
    windows : int
        Window minima kept for the drift fit.
    """

    def __init__(self, window_s: float = 1.0, windows: int = 30):
        self.window_ns = int(window_s * NS_PER_S)
        self._minima: deque[tuple[int, int]] = deque(maxlen=windows)  # (device_ns, offset_ns)
        self._win_start: int | None = None
        self._win_min: tuple[int, int] | None = None
        self._excess_sum = 0
        self._excess_n = 0
        self.samples = 0
        self.offset_ns: int | None = None  # at ref_device_ns
        self.ref_device_ns = 0
        self.drift_ppm = 0.0
        self.jitter_ns = 0  # mean delay above the envelope in the last closed window
        self.resets = 0

    def add(self, device_ns: int, host_ns: int) -> None:
        off = host_ns - device_ns
        self.samples += 1
        if self._win_start is None or device_ns < self._win_start - self.window_ns:
            if self._win_start is not None:  # device clock jumped back: start over
                self._minima.clear()
                self.resets += 1
            self._win_start = device_ns
            self._win_min = (device_ns, off)
            self._excess_sum = self._excess_n = 0
        if off < self._win_min[1]:
            self._win_min = (device_ns, off)
        if self.offset_ns is not None:
            self._excess_sum += max(0, host_ns - self.to_host(device_ns))
            self._excess_n += 1
        if device_ns - self._win_start >= self.window_ns:
            self._close_window(device_ns)
        elif self.offset_ns is None:
            self.offset_ns, self.ref_device_ns = self._win_min[1], self._win_min[0]

    def _close_window(self, device_ns: int) -> None:
        if self._minima and abs(self._win_min[1] - self._minima[-1][1]) > NS_PER_S:
            self._minima.clear()  # a step of over a second: host clock set, or device reset
            self.resets += 1
        self._minima.append(self._win_min)
        if self._excess_n:
            self.jitter_ns = self._excess_sum // self._excess_n
        self._excess_sum = self._excess_n = 0
        self._fit()
        self._win_start = device_ns
        self._win_min = (device_ns, 1 << 62)

    def _fit(self) -> None:
        pts = list(self._minima)
        n = len(pts)
        x0, y0 = pts[-1]
        if n >= 3:
            mx = sum(p[0] - x0 for p in pts) / n
            my = sum(p[1] - y0 for p in pts) / n
            sxx = sum((p[0] - x0 - mx) ** 2 for p in pts)
            sxy = sum((p[0] - x0 - mx) * (p[1] - y0 - my) for p in pts)
            slope = sxy / sxx if sxx > 0 else 0.0
            # the envelope's line, anchored at the newest minimum's time
            self.offset_ns = int(y0 + my + slope * (0 - mx))
            self.drift_ppm = slope * 1e6
        else:
            self.offset_ns = y0
            self.drift_ppm = 0.0
        self.ref_device_ns = x0

    def to_host(self, device_ns: int) -> int | None:
        """host_realtime [ns] of a device time, or None before the first sample."""
        if self.offset_ns is None:
            return None
        return device_ns + self.offset_ns + int((device_ns - self.ref_device_ns) * self.drift_ppm * 1e-6)

    def summary(self) -> dict:
        return {
            "offset_ns": self.offset_ns,
            "drift_ppm": round(self.drift_ppm, 3),
            "jitter_ns": self.jitter_ns,
            "samples": self.samples,
            "resets": self.resets,
        }


class LidarClock:
    """The lidar's clock: unwrap µs past the hour, map to host time, watch PPS."""

    def __init__(self, window_s: float = 1.0):
        self.unwrap = TohUnwrapper()
        self.mapper = ClockMapper(window_s)
        self.pps_state = "unknown"
        self.nmea = ""
        self.hour_aligned_error_ns: int | None = None  # lidar (as UTC when PPS locked) - host

    def add_data(self, toh_us: int, host_ns: int) -> None:
        if toh_us >= HOUR_US:
            return  # not a valid µs-past-the-hour: counted as bad elsewhere, not used here
        self.mapper.add(self.unwrap(toh_us), host_ns)

    def add_position(self, toh_us: int, host_ns: int, pps_state: str, nmea: str) -> None:
        self.pps_state = pps_state
        if nmea:
            self.nmea = nmea
        if pps_state == "locked" and toh_us < HOUR_US:
            # with PPS the lidar's hour is the UTC hour: how far is the host from it (minus the
            # receive delay)?
            self.hour_aligned_error_ns = toh_us_to_unix_ns(toh_us, host_ns) - host_ns

    def summary(self) -> dict:
        d = self.mapper.summary()
        d.update(
            rollovers=self.unwrap.rollovers, pps=self.pps_state,
            pps_host_error_ns=self.hour_aligned_error_ns,
        )
        return d


class RateClock:
    """An IMU without its own clock (TFP callbacks): measured sample period and jitter."""

    def __init__(self, keep: int = 200):
        self._dts: deque[int] = deque(maxlen=keep)
        self._prev: int | None = None
        self.samples = 0

    def add(self, host_ns: int) -> None:
        if self._prev is not None:
            self._dts.append(host_ns - self._prev)
        self._prev = host_ns
        self.samples += 1

    def summary(self) -> dict:
        if len(self._dts) < 2:
            return {"samples": self.samples, "period_ns": None, "jitter_ns": None}
        s = sorted(self._dts)
        med = s[len(s) // 2]
        mad = sorted(abs(d - med) for d in s)[len(s) // 2]
        return {"samples": self.samples, "period_ns": med, "jitter_ns": mad}
