# SPDX-License-Identifier: BSD-3-Clause
"""Checks that a VLP-16 position packet is one before it reaches the recording or the clock.

A 512-byte datagram on the position port is accepted only when every field we can check says
"Velodyne": the timestamp is a µs-past-the-hour (< 3600 s), the PPS status byte is one of the four
states, and the 128-byte NMEA field is either all NUL (no GPS receiver attached: what a VLP-16
without GPS sends) or one NMEA 0183 sentence -- ``$`` talker + type, comma-separated printable
fields, ``*`` and the two hex digits of the XOR checksum, optional CR LF -- followed only by NUL
padding. A random datagram passes with a probability of about 256^-100, so junk never becomes
position data or a clock sample.

Rejected packets are counted per reason (``position_rejected_<reason>``, plus the total in
``lidar_malformed``) and not recorded: they are not the sensor's output, and keeping them would
hand every reader of the position channel junk to filter.
"""

from __future__ import annotations

import re

from tripod_shared.velodyne import (
    POS_NMEA_OFFSET,
    POS_NMEA_SIZE,
    POS_PPS_OFFSET,
    POS_TIMESTAMP_OFFSET,
    POSITION_PACKET_SIZE,
    PPS_STATES,
)

HOUR_US = 3600 * 1_000_000

#: reasons a position datagram is refused, in the order they are checked
POSITION_REJECT_REASONS = ("size", "time", "pps", "nmea_structure", "nmea_checksum")

# $ + talker (2 letters, or P for proprietary) + type, then fields of printable ASCII without
# the delimiters $ * and the checksum; NMEA 0183 limits a sentence to 82 characters
_NMEA = re.compile(rb"^\$([A-Z]{2}[A-Z0-9]{3}|P[A-Z0-9]{2,6})((?:,[\x20-\x23\x25-\x29\x2b-\x7e]*)*)"
                   rb"\*([0-9A-F]{2})(\r\n)?$")
_NUL_FIELD = bytes(POS_NMEA_SIZE)
_MAX_SENTENCE = 82


def nmea_reject_reason(field: bytes) -> str | None:
    """None when ``field`` (the NUL-padded NMEA bytes) is empty or one valid sentence;
    otherwise ``nmea_structure`` or ``nmea_checksum``."""
    if field == _NUL_FIELD[: len(field)]:
        return None
    sentence, _nul, padding = field.partition(b"\x00")
    if padding.strip(b"\x00") or len(sentence) > _MAX_SENTENCE:
        return "nmea_structure"
    m = _NMEA.match(sentence)
    if m is None:
        return "nmea_structure"
    body = sentence[1 : sentence.index(b"*")]
    x = 0
    for b in body:
        x ^= b
    return None if x == int(m.group(3), 16) else "nmea_checksum"


def position_reject_reason(payload: bytes) -> str | None:
    """None for a well-formed VLP-16 position packet, else the first reason it is not one
    (one of :data:`POSITION_REJECT_REASONS`)."""
    if len(payload) != POSITION_PACKET_SIZE:
        return "size"
    toh_us = int.from_bytes(payload[POS_TIMESTAMP_OFFSET : POS_TIMESTAMP_OFFSET + 4], "little")
    if toh_us >= HOUR_US:
        return "time"
    if payload[POS_PPS_OFFSET] not in PPS_STATES:
        return "pps"
    return nmea_reject_reason(payload[POS_NMEA_OFFSET : POS_NMEA_OFFSET + POS_NMEA_SIZE])
