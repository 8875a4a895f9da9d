# SPDX-License-Identifier: BSD-3-Clause
"""Minimal little-endian CDR (XCDR1, as ROS 2 writes it) for the few types tripod records.

Alignment is relative to the byte after the 4-byte encapsulation header, as in ROS 2.
"""

from __future__ import annotations

import struct

ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"


class CdrWriter:
    __slots__ = ("_parts", "_size")

    def __init__(self):
        self._parts: list[bytes] = [ENCAPSULATION_CDR_LE]
        self._size = 0  # bytes after the encapsulation header

    def _align(self, n: int) -> None:
        pad = (-self._size) % n
        if pad:
            self._parts.append(b"\x00" * pad)
            self._size += pad

    def _put(self, fmt: str, align: int, *values) -> None:
        self._align(align)
        b = struct.pack("<" + fmt, *values)
        self._parts.append(b)
        self._size += len(b)

    def int32(self, v: int) -> None:
        self._put("i", 4, v)

    def uint32(self, v: int) -> None:
        self._put("I", 4, v)

    def int64(self, v: int) -> None:
        self._put("q", 8, v)

    def uint64(self, v: int) -> None:
        self._put("Q", 8, v)

    def uint8(self, v: int) -> None:
        self._put("B", 1, v)

    def float64(self, v: float) -> None:
        self._put("d", 8, v)

    def string(self, s: str) -> None:
        b = s.encode("utf-8") + b"\x00"
        self.uint32(len(b))
        self._parts.append(b)
        self._size += len(b)

    def fixed_bytes(self, b: bytes) -> None:
        self._parts.append(bytes(b))
        self._size += len(b)

    def byte_sequence(self, b: bytes) -> None:
        self.uint32(len(b))
        self.fixed_bytes(b)

    def getvalue(self) -> bytes:
        return b"".join(self._parts)


class CdrReader:
    __slots__ = ("_buf", "_pos")

    def __init__(self, data: bytes):
        if len(data) < 4 or data[1] != 0x01:
            raise ValueError("not little-endian CDR data")
        self._buf = memoryview(data)[4:]
        self._pos = 0

    def _get(self, fmt: str, size: int):
        self._pos += (-self._pos) % size
        v = struct.unpack_from("<" + fmt, self._buf, self._pos)[0]
        self._pos += size
        return v

    def int32(self) -> int:
        return self._get("i", 4)

    def uint32(self) -> int:
        return self._get("I", 4)

    def int64(self) -> int:
        return self._get("q", 8)

    def uint64(self) -> int:
        return self._get("Q", 8)

    def uint8(self) -> int:
        return self._get("B", 1)

    def float64(self) -> float:
        return self._get("d", 8)

    def string(self) -> str:
        n = self.uint32()
        b = bytes(self._buf[self._pos : self._pos + n])
        if len(b) != n:
            raise ValueError("truncated CDR string")
        self._pos += n
        return b.rstrip(b"\x00").decode("utf-8")

    def fixed_bytes(self, n: int) -> bytes:
        b = bytes(self._buf[self._pos : self._pos + n])
        if len(b) != n:
            raise ValueError("truncated CDR byte array")
        self._pos += n
        return b

    def byte_sequence(self) -> bytes:
        return self.fixed_bytes(self.uint32())
