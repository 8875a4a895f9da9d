# SPDX-License-Identifier: BSD-3-Clause
"""Tinkerforge TFP framing and the IMU Brick 2.0 quaternion callback.

Every TFP packet is an 8-byte little-endian header then the payload::

    uint32 uid | uint8 length (header+payload) | uint8 function_id
    | uint8 (seq << 4 | response_expected << 3 | options) | uint8 flags (error code in bits 6-7)

IMU Brick 2.0 (device identifier 18): CALLBACK_QUATERNION (fid 39) carries int16 w, x, y, z
scaled by 1/16383 (bindings) or 1/16384 (firmware): we divide and normalise. Callbacks use
sequence number 0 and carry no device timestamp; the host stamps them at the read.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

HEADER = struct.Struct("<IBBBB")
HEADER_SIZE = 8
MAX_PACKET_SIZE = 80
BRICKD_PORT = 4223

DEVICE_IDENTIFIER_IMU_V2 = 18
FID_GET_QUATERNION = 8
FID_SET_QUATERNION_PERIOD = 28
FID_GET_QUATERNION_PERIOD = 29
FID_CALLBACK_QUATERNION = 39
FID_ENUMERATE = 254
FID_CALLBACK_ENUMERATE = 253
QUATERNION_SCALE = 16383.0
QUATERNION_PACKET_SIZE = HEADER_SIZE + 8
ENUMERATE_CALLBACK_SIZE = HEADER_SIZE + 26

_Q = struct.Struct("<hhhh")
_U32 = struct.Struct("<I")
_ENUM = struct.Struct("<8s8sc3B3BHB")

BASE58_ALPHABET = "123456789abcdefghijkmnopqrstuvwxyzABCDEFGHJKLMNPQRSTUVWXYZ"


def base58_encode(value: int) -> str:
    if value == 0:
        return BASE58_ALPHABET[0]
    out = ""
    while value:
        value, r = divmod(value, 58)
        out = BASE58_ALPHABET[r] + out
    return out


def base58_decode(text: str) -> int:
    value = 0
    for ch in text:
        idx = BASE58_ALPHABET.find(ch)
        if idx < 0:
            raise ValueError(f"not a Tinkerforge UID: {text!r}")
        value = value * 58 + idx
    return value


@dataclass(frozen=True, slots=True)
class TfpPacket:
    uid: int
    function_id: int
    sequence: int
    response_expected: bool
    error_code: int
    payload: bytes
    #: completed by an earlier ``feed`` but held back until the bytes after it showed it is
    #: not a cut-off frame run into the next one (the caller stamps it with that earlier read)
    held: bool = False

    @property
    def raw(self) -> bytes:
        return encode_packet(
            self.uid, self.function_id, self.payload, self.sequence, self.response_expected,
            self.error_code,
        )


def encode_packet(
    uid: int, function_id: int, payload: bytes = b"", sequence: int = 0,
    response_expected: bool = False, error_code: int = 0,
) -> bytes:
    length = HEADER_SIZE + len(payload)
    if length > MAX_PACKET_SIZE:
        raise ValueError(f"TFP packet too long: {length} > {MAX_PACKET_SIZE}")
    opts = ((sequence & 0x0F) << 4) | (0x08 if response_expected else 0)
    return HEADER.pack(uid, length, function_id, opts, (error_code & 0x03) << 6) + bytes(payload)


def encode_quaternion_callback(uid: int, w: float, x: float, y: float, z: float) -> bytes:
    """A CALLBACK_QUATERNION packet as the brick sends it (int16, scale 16383)."""
    vals = [max(-32768, min(32767, int(round(c * QUATERNION_SCALE)))) for c in (w, x, y, z)]
    return encode_packet(uid, FID_CALLBACK_QUATERNION, _Q.pack(*vals))


def encode_set_quaternion_period(uid: int, period_ms: int, sequence: int = 1) -> bytes:
    return encode_packet(uid, FID_SET_QUATERNION_PERIOD, _U32.pack(period_ms), sequence, True)


def encode_enumerate(sequence: int = 1) -> bytes:
    return encode_packet(0, FID_ENUMERATE, b"", sequence, False)


def encode_enumerate_callback(
    uid: int, device_identifier: int = DEVICE_IDENTIFIER_IMU_V2, connected_uid: str = "0",
    position: bytes = b"0", enumeration_type: int = 0,
) -> bytes:
    payload = _ENUM.pack(
        base58_encode(uid).encode(), connected_uid.encode(), position, 1, 0, 0, 2, 0, 10,
        device_identifier, enumeration_type,
    )
    return encode_packet(uid, FID_CALLBACK_ENUMERATE, payload)


def decode_enumerate_callback(payload: bytes) -> tuple[int, int]:
    """(uid, device_identifier) of a CALLBACK_ENUMERATE payload."""
    uid_s, _c, _p, *_hwfw, dev_id, _t = _ENUM.unpack_from(payload)
    return base58_decode(uid_s.split(b"\x00", 1)[0].decode("ascii")), dev_id


def decode_quaternion(payload: bytes) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a quaternion payload, normalised (q_world_imu)."""
    w, x, y, z = _Q.unpack_from(payload)
    n = (w * w + x * x + y * y + z * z) ** 0.5
    if n == 0:
        raise ValueError("zero quaternion")
    return (w / n, x / n, y / n, z / n)


# (function_id -> expected total length) of packets we accept from an IMU Brick 2.0
_KNOWN_LENGTHS = {
    FID_CALLBACK_QUATERNION: QUATERNION_PACKET_SIZE,
    FID_GET_QUATERNION: QUATERNION_PACKET_SIZE,
    FID_CALLBACK_ENUMERATE: ENUMERATE_CALLBACK_SIZE,
    FID_SET_QUATERNION_PERIOD: HEADER_SIZE,
    FID_GET_QUATERNION_PERIOD: HEADER_SIZE + 4,
}


def _plausible_quaternion(payload: bytes) -> bool:
    w, x, y, z = _Q.unpack_from(payload)
    n2 = (w * w + x * x + y * y + z * z) / (QUATERNION_SCALE * QUATERNION_SCALE)
    return 0.9 < n2 < 1.1


def _unit_quaternion(payload: bytes) -> bool:
    """Unit norm to the int16 rounding of a real brick (|n^2 - 1| < 1e-3)."""
    w, x, y, z = _Q.unpack_from(payload)
    n2 = (w * w + x * x + y * y + z * z) / (QUATERNION_SCALE * QUATERNION_SCALE)
    return abs(n2 - 1.0) < 1e-3


class TfpStreamParser:
    """Incremental TFP parser for a byte stream (serial line or brickd TCP) with resync.

    ``feed(data)`` returns the whole packets found. A candidate header is accepted only when its
    (function id, length) pair is one an IMU Brick 2.0 sends, the flag bits are sane, the UID
    matches (when one is set) and, for quaternions, the norm is about 1; otherwise one byte is
    skipped and counted as garbage. Bytes are never silently lost: ``garbage_bytes`` counts them.

    With a UID set, frames of other UIDs are garbage, except enumerate answers (any brick may
    answer; the caller decides). A frame cut short on the line (a dropped byte, a reset brick)
    runs into the bytes after it and would otherwise read as one frame made of both -- a sample
    that never existed -- and lose the next one. So a candidate is refused (resync one byte on)
    when a header of ours starts inside it, and it must be followed by a header of ours; when
    followed by other bytes (line noise) it is taken only if it is a unit quaternion to the
    brick's rounding (|n^2 - 1| < 1e-3; a frame completed by foreign bytes passes that about
    once in 10^4). When the buffer ends before that can be told, the candidate is held until
    more bytes arrive (returned then with ``held=True``, so the caller can stamp it with the
    earlier read), or until the caller says the line went quiet (:meth:`flush_held`: then
    silence follows it, which no foreign byte completed).
    """

    def __init__(self, uid: int | None = None):
        self._buf = bytearray()
        self.packets = 0
        self.garbage_bytes = 0
        self._held_at: int | None = None  # buffer offset of a frame complete but held
        self._quiet = False
        self.uid = uid

    @property
    def uid(self) -> int | None:
        return self._uid

    @uid.setter
    def uid(self, uid: int | None) -> None:
        self._uid = uid
        self._uid_bytes = _U32.pack(uid) if uid is not None else b""

    def _header_at(self, j: int) -> int:
        """1 when a frame header of our UID (or any brick's enumerate answer) starts at j, 0
        when none does, -1 when the buffer ends before that is known."""
        head = bytes(self._buf[j : j + HEADER_SIZE])
        n = len(head)
        if n == 0 and self._quiet:
            return 0  # the line went quiet: nothing follows
        k = min(4, n)
        if head[:k] != self._uid_bytes[:k]:
            if n < 6:
                return -1  # (could still be an enumerate answer)
            if head[5] != FID_CALLBACK_ENUMERATE:
                return 0
        if n == 0:
            return -1
        if n >= 6 and _KNOWN_LENGTHS.get(head[5]) != head[4]:
            return 0
        if (n >= 7 and head[6] & 0x07) or (n >= 8 and head[7] & 0x3F):
            return 0
        return 1 if n == HEADER_SIZE else -1

    def _valid_at(self, i: int) -> int:
        """Length of a valid packet starting at i, 0 if none, -1 if more bytes needed."""
        buf = self._buf
        if len(buf) - i < HEADER_SIZE:
            return -1
        uid, length, fid, opts, flags = HEADER.unpack_from(buf, i)
        if self._uid is not None and uid != self._uid and fid != FID_CALLBACK_ENUMERATE:
            return 0  # (any brick may answer enumerate: the caller decides)
        if _KNOWN_LENGTHS.get(fid) != length or (opts & 0x07) or (flags & 0x3F):
            return 0
        if len(buf) - i < length:
            return -1
        if fid in (FID_CALLBACK_QUATERNION, FID_GET_QUATERNION):
            if not _plausible_quaternion(bytes(buf[i + HEADER_SIZE : i + length])):
                return 0
        if self._uid is not None:
            # A frame cut short runs into what follows. Refuse a candidate with a header of
            # ours inside it, and want one right after it; a candidate followed by other bytes
            # (noise) is taken only when it is a unit quaternion to the device's rounding,
            # which a frame completed by foreign bytes practically never is.
            first = self._uid_bytes[0]
            end = i + length
            for j in range(i + 1, end):
                if buf[j] == first:
                    h = self._header_at(j)
                    if h > 0 or (h < 0 and self._quiet):
                        return 0
                    if h < 0:
                        return -1  # the buffer ends inside a possible header: wait
            after = self._header_at(end)
            if after < 0:
                return -1  # wait for the next bytes to tell
            if (after == 0 and not self._quiet
                    and fid in (FID_CALLBACK_QUATERNION, FID_GET_QUATERNION)):
                if not _unit_quaternion(bytes(buf[i + HEADER_SIZE : end])):
                    return 0
        return length

    def feed(self, data: bytes) -> list[TfpPacket]:
        held = self._held_at
        self._held_at = None
        self._buf += data
        out: list[TfpPacket] = []
        i = 0
        buf = self._buf
        while True:
            n = self._valid_at(i)
            if n < 0:
                if len(buf) - i >= HEADER_SIZE and self._uid is not None:
                    _u, length, *_ = HEADER.unpack_from(buf, i)
                    if len(buf) - i >= length:
                        self._held_at = 0  # complete, held: at offset 0 after the trim below
                break
            if n == 0:
                i += 1
                self.garbage_bytes += 1
                continue
            uid, length, fid, opts, flags = HEADER.unpack_from(buf, i)
            out.append(
                TfpPacket(uid, fid, opts >> 4, bool(opts & 0x08), flags >> 6,
                          bytes(buf[i + HEADER_SIZE : i + length]), held=(i == held))
            )
            self.packets += 1
            i += n
        # keep at most one partial packet's worth of tail
        if len(buf) - i > MAX_PACKET_SIZE:
            drop = len(buf) - i - MAX_PACKET_SIZE
            self.garbage_bytes += drop
            i += drop
            self._held_at = None
        del buf[:i]
        return out

    def flush_held(self) -> list[TfpPacket]:
        """The line has been quiet for a while: decide a held frame as if noise followed it."""
        if self._held_at is None:
            return []
        self._quiet = True
        try:
            return self.feed(b"")
        finally:
            self._quiet = False

    @property
    def pending(self) -> int:
        return len(self._buf)
