# SPDX-License-Identifier: BSD-3-Clause
"""NMEA 0183 sentences as the VLP-16 forwards them in its position packets (GPRMC).

The one NMEA parser of the project: the daemon (PPS/NMEA health), the processor (the hour of
the lidar clock from GPRMC) and the simulator (writing GPRMC) all use these functions.
Pure Python, no dependencies.
"""

from __future__ import annotations

import datetime as _dt

NS_PER_S = 1_000_000_000


def checksum(body: str) -> str:
    """Two upper-case hex digits: the XOR of the characters between ``$`` and ``*``."""
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"{c:02X}"


def with_checksum(body: str) -> str:
    """``$<body>*<checksum>``."""
    return f"${body}*{checksum(body)}"


def checksum_ok(sentence: str) -> bool:
    """True when ``sentence`` is ``$...*hh`` and ``hh`` matches its body."""
    if not sentence.startswith("$") or "*" not in sentence:
        return False
    body, _, cs = sentence[1:].partition("*")
    try:
        return int(cs[:2], 16) == int(checksum(body), 16)
    except ValueError:
        return False


def sentence_type(sentence: str) -> str:
    """The talker + type field (``GPRMC``), or ``"unknown"`` when it is not a ``$`` sentence."""
    return sentence[1:6] if sentence.startswith("$") else "unknown"


def rmc_unix_ns(sentence: str) -> int | None:
    """UNIX time [ns] of an RMC sentence, to the whole second (host_realtime's epoch), or None.

    The checksum is not required (the lidar forwards what the receiver sent); a sentence that is
    not RMC or whose time or date fields do not parse gives None.
    """
    if "RMC" not in sentence[:6]:
        return None
    f = sentence.split(",")
    try:
        if len(f) < 10 or len(f[1]) < 6 or len(f[9]) != 6:
            return None
        hh, mm, ss = int(f[1][0:2]), int(f[1][2:4]), int(float(f[1][4:]))
        d, mo, y = int(f[9][0:2]), int(f[9][2:4]), 2000 + int(f[9][4:6])
        t = _dt.datetime(y, mo, d, hh, mm, ss, tzinfo=_dt.timezone.utc)
    except ValueError:
        return None
    return int(t.timestamp()) * NS_PER_S


def format_rmc(unix_ns: int, lat_deg: float, lon_deg: float) -> str:
    """A GPRMC sentence (with checksum) for UTC time ``unix_ns`` at a fixed position, speed 0."""
    t = _dt.datetime.fromtimestamp(unix_ns / 1e9, tz=_dt.timezone.utc)
    la, lo = abs(lat_deg), abs(lon_deg)
    lat = f"{int(la):02d}{(la - int(la)) * 60:010.7f}"
    lon = f"{int(lo):03d}{(lo - int(lo)) * 60:010.7f}"
    body = (f"GPRMC,{t:%H%M%S}.{t.microsecond // 10000:02d},A,{lat},{'N' if lat_deg >= 0 else 'S'},"
            f"{lon},{'E' if lon_deg >= 0 else 'W'},0.000,0.0,{t:%d%m%y},0.0,E,A")
    return with_checksum(body)
