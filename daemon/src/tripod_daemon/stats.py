# SPDX-License-Identifier: BSD-3-Clause
"""Counters and per-second rates for STATUS= and the status topic.

Each counter is written by exactly one thread (receive loop, writer, publisher), so plain ``int``
increments under the GIL are enough; the status tick only reads them.
"""

from __future__ import annotations

import time


class Counters(dict):
    """Name -> cumulative count. ``add(name, n)`` creates on first use."""

    def add(self, name: str, n: int = 1) -> None:
        self[name] = self.get(name, 0) + n


class RateMeter:
    """Per-second rates of chosen counters between two ``update`` calls (host_monotonic)."""

    def __init__(self):
        self._last: dict[str, int] = {}
        self._last_t = time.monotonic()
        self.rates: dict[str, float] = {}

    def update(self, counts: dict[str, int]) -> dict[str, float]:
        now = time.monotonic()
        dt = now - self._last_t
        if dt > 0:
            self.rates = {k: round((v - self._last.get(k, 0)) / dt, 1) for k, v in counts.items()}
        self._last = dict(counts)
        self._last_t = now
        return self.rates


def status_line(state: str, rates: dict, counts: dict, file: str | None) -> str:
    """One short line for systemd STATUS= (shown by ``systemctl status``)."""
    drops = (
        counts.get("lidar_kernel_drops", 0) + counts.get("record_dropped", 0)
        + counts.get("zenoh_dropped", 0)
    )
    bad = counts.get("lidar_malformed", 0) + counts.get("lidar_foreign", 0)
    return (
        f"{state}; lidar {rates.get('lidar_data', 0):.0f}/s pos {rates.get('lidar_position', 0):.0f}/s"
        f" imu {rates.get('imu_samples', 0):.0f}/s; bad {bad}; drops {drops}"
        + (f"; file {file}" if file else "")
    )
