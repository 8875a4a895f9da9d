# SPDX-License-Identifier: BSD-3-Clause
"""WitMotion-style serial IMU framing (a common 0x55-framed protocol).

Each frame is 11 bytes: ``0x55 | type | 8 data bytes | checksum`` where checksum is the low byte
of the sum of the first 10 bytes. Types used here: 0x59 quaternion (int16 q0..q3 = w, x, y, z,
scale 1/32768) and 0x50 time (YY MM DD hh mm ss, uint16 ms).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

FRAME_SIZE = 11
HEAD = 0x55
TYPE_TIME = 0x50
TYPE_QUATERNION = 0x59
QUATERNION_SCALE = 32768.0
_Q = struct.Struct("<hhhh")


def checksum(frame10: bytes) -> int:
    return sum(frame10) & 0xFF


def encode_frame(ftype: int, data8: bytes) -> bytes:
    if len(data8) != 8:
        raise ValueError("WitMotion frame data must be 8 bytes")
    body = bytes([HEAD, ftype]) + bytes(data8)
    return body + bytes([checksum(body)])


def encode_quaternion(w: float, x: float, y: float, z: float) -> bytes:
    vals = [max(-32768, min(32767, int(round(c * QUATERNION_SCALE)))) for c in (w, x, y, z)]
    return encode_frame(TYPE_QUATERNION, _Q.pack(*vals))


def encode_time(year: int, month: int, day: int, hour: int, minute: int, second: int, ms: int) -> bytes:
    return encode_frame(TYPE_TIME, struct.pack("<6BH", year % 100, month, day, hour, minute, second, ms))


def decode_quaternion(data8: bytes) -> tuple[float, float, float, float]:
    w, x, y, z = _Q.unpack_from(data8)
    n = (w * w + x * x + y * y + z * z) ** 0.5
    if n == 0:
        raise ValueError("zero quaternion")
    return (w / n, x / n, y / n, z / n)


@dataclass(frozen=True, slots=True)
class WitFrame:
    ftype: int
    data: bytes

    @property
    def raw(self) -> bytes:
        return encode_frame(self.ftype, self.data)


class WitStreamParser:
    """Incremental 0x55-frame parser with checksum resync; counts skipped bytes."""

    def __init__(self):
        self._buf = bytearray()
        self.packets = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[WitFrame]:
        self._buf += data
        buf = self._buf
        out: list[WitFrame] = []
        i = 0
        while len(buf) - i >= FRAME_SIZE:
            if buf[i] == HEAD and checksum(buf[i : i + 10]) == buf[i + 10]:
                out.append(WitFrame(buf[i + 1], bytes(buf[i + 2 : i + 10])))
                self.packets += 1
                i += FRAME_SIZE
            else:
                i += 1
                self.garbage_bytes += 1
        del buf[:i]
        return out
