# SPDX-License-Identifier: BSD-3-Clause
"""The ``.tpc`` container: versioned, checksummed, self-describing.

Layout (little endian)::

    0      8 B   magic b"TRIPODPC"
    8      u16   format version: the oldest reader version that can decode the file (1: the
                 octree codec; 2: adds the predictive codec); readers take every version up to
                 their FORMAT_VERSION, so octree files stay readable by version-1 readers
    10     u16   flags (0)
    12     u32   H: header length
    16     H B   header: UTF-8 JSON object (codec, model id, grid, counts, section sizes)
    16+H   u32   CRC-32 of bytes [0, 16+H)
    20+H   P B   payload: the sections, back to back, P = header["payload_bytes"]
    20+H+P u32   CRC-32 of the payload

Anything else (wrong magic, newer version, cut short, trailing bytes, a flipped bit anywhere)
raises :class:`ContainerError` with a one-line message before any geometry is decoded.
"""

from __future__ import annotations

import json
import struct
import zlib

MAGIC = b"TRIPODPC"
FORMAT_VERSION = 2
_FIXED = struct.Struct("<8sHHI")


class ContainerError(ValueError):
    """Not a readable .tpc file: foreign, corrupt, truncated or from a newer version."""


def pack(header: dict, sections: list[bytes], version: int = FORMAT_VERSION) -> bytes:
    """Serialise a header dict and payload sections (their sizes are added to the header);
    ``version``: the format version the file needs (see the layout above)."""
    if not 1 <= version <= FORMAT_VERSION:
        raise ValueError(f"format version {version} is not in [1, {FORMAT_VERSION}]")
    header = dict(header, section_bytes=[len(s) for s in sections],
                  payload_bytes=sum(len(s) for s in sections))
    head = json.dumps(header, separators=(",", ":"), sort_keys=True).encode()
    fixed = _FIXED.pack(MAGIC, version, 0, len(head)) + head
    payload = b"".join(sections)
    return b"".join([fixed, struct.pack("<I", zlib.crc32(fixed)), payload,
                     struct.pack("<I", zlib.crc32(payload))])


def read_header(data: bytes) -> tuple[dict, int]:
    """Parse and verify the header; returns (header, offset of the payload)."""
    if len(data) < _FIXED.size:
        if MAGIC.startswith(bytes(data[:8])) and len(data) > 0:
            raise ContainerError(f"truncated .tpc file: {len(data)} bytes, header incomplete")
        raise ContainerError("not a tripod .tpc file (too short, no TRIPODPC magic)")
    magic, version, _flags, hlen = _FIXED.unpack_from(data, 0)
    if magic != MAGIC:
        raise ContainerError("not a tripod .tpc file (no TRIPODPC magic)")
    if version == 0:
        raise ContainerError("corrupt .tpc file: format version 0")
    if version > FORMAT_VERSION:
        raise ContainerError(f".tpc format version {version} is newer than this tripod reads "
                             f"({FORMAT_VERSION}); upgrade tripod")
    end = _FIXED.size + hlen
    if len(data) < end + 4:
        raise ContainerError(f"truncated .tpc file: {len(data)} bytes, header needs {end + 4}")
    (crc,) = struct.unpack_from("<I", data, end)
    if zlib.crc32(bytes(data[:end])) != crc:
        raise ContainerError("corrupt .tpc file: header checksum mismatch")
    try:
        header = json.loads(bytes(data[_FIXED.size:end]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:  # only if the CRC collided
        raise ContainerError(f"corrupt .tpc file: unreadable header ({exc})") from None
    return header, end + 4


def unpack(data: bytes) -> tuple[dict, list[bytes]]:
    """Verify a whole file; returns (header, sections)."""
    header, start = read_header(data)
    size = int(header.get("payload_bytes", -1))
    expected = start + size + 4
    if size < 0 or len(data) < expected:
        raise ContainerError(f"truncated .tpc file: {len(data)} bytes of {expected}")
    if len(data) > expected:
        raise ContainerError(f"corrupt .tpc file: {len(data) - expected} unexpected trailing bytes")
    payload = bytes(data[start:start + size])
    (crc,) = struct.unpack_from("<I", data, start + size)
    if zlib.crc32(payload) != crc:
        raise ContainerError("corrupt .tpc file: payload checksum mismatch")
    sections, pos = [], 0
    for n in header.get("section_bytes", []):
        sections.append(payload[pos:pos + n])
        pos += n
    if pos != size:
        raise ContainerError("corrupt .tpc file: section sizes do not add up")
    return header, sections
