# SPDX-License-Identifier: BSD-3-Clause
"""IMU log: the raw byte stream of a serial/TCP IMU with the host time of every read.

It is what the host saw on the IMU line, so the same parsers as for live data
(``tripod_shared.tfp.TfpStreamParser``, ``tripod_shared.witmotion.WitStreamParser``) read it,
and ``tripod replay`` can send it out again with its original timing. The simulator writes one
beside its ``capture.pcap``.

Layout (little-endian)::

    header, 16 bytes:  magic b"TRIPIMU1" | uint16 version (1) | uint16 protocol
                       (1 = TFP / Tinkerforge, 2 = WitMotion 0x55 frames) | uint32 reserved (0)
    records, repeated: int64 host_ns | uint16 length | length bytes

``host_ns`` is host_realtime [ns] at which those bytes were read by the host (for a simulated
capture: when they arrive; the replayer writes them at that time, scaled by its rate). Records
are in non-decreasing time order. A file cut inside a record yields every whole record.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

MAGIC = b"TRIPIMU1"
VERSION = 1
PROTOCOL_TFP = 1
PROTOCOL_WITMOTION = 2
PROTOCOLS = {PROTOCOL_TFP: "tfp", PROTOCOL_WITMOTION: "witmotion"}
_HEADER = struct.Struct("<8sHHI")
_REC = struct.Struct("<qH")


class ImuLogError(ValueError):
    """Not an IMU log, or a damaged header (one-line message)."""


@dataclass(frozen=True, slots=True)
class ImuRecord:
    host_ns: int  # host_realtime
    data: bytes


def write_imu_log(path: str | os.PathLike, protocol: str, host_ns: np.ndarray,
                  chunks: list[bytes]) -> None:
    """Write records (``host_ns[i]``, ``chunks[i]``); ``protocol`` is 'tfp' or 'witmotion'."""
    code = {name: c for c, name in PROTOCOLS.items()}.get(protocol)
    if code is None:
        raise ValueError(f"unknown IMU protocol {protocol!r}")
    if len(host_ns) != len(chunks):
        raise ValueError("one host time per chunk")
    with open(path, "wb") as fh:
        fh.write(_HEADER.pack(MAGIC, VERSION, code, 0))
        fh.write(b"".join(_REC.pack(int(t), len(c)) + c for t, c in zip(host_ns, chunks)))


class ImuLogReader:
    """Stream the records of an IMU log.

    >>> log = ImuLogReader("imu.tripimu")
    >>> log.protocol                      # 'tfp' or 'witmotion'
    >>> for rec in log: rec.host_ns, rec.data
    """

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        if not os.path.isfile(self.path):
            raise FileNotFoundError(f"no such IMU log: {self.path}")
        with open(self.path, "rb") as fh:
            head = fh.read(_HEADER.size)
        if len(head) < _HEADER.size or head[:8] != MAGIC:
            raise ImuLogError(f"{self.path}: not a tripod IMU log (magic {MAGIC!r} expected)")
        _magic, version, code, _res = _HEADER.unpack(head)
        if version != VERSION:
            raise ImuLogError(f"{self.path}: IMU log version {version} is not supported")
        if code not in PROTOCOLS:
            raise ImuLogError(f"{self.path}: unknown IMU protocol code {code}")
        self.protocol = PROTOCOLS[code]
        self.truncated = False

    def __iter__(self) -> Iterator[ImuRecord]:
        self.truncated = False
        with open(self.path, "rb") as fh:
            fh.seek(_HEADER.size)
            while True:
                h = fh.read(_REC.size)
                if not h:
                    return
                if len(h) < _REC.size:
                    self.truncated = True
                    return
                t, n = _REC.unpack(h)
                data = fh.read(n)
                if len(data) < n:
                    self.truncated = True
                    return
                yield ImuRecord(t, data)

    def parse_quaternions(self) -> tuple[np.ndarray, np.ndarray]:
        """(host_ns (N,) int64, q (N, 4) float64 w, x, y, z normalised) of every quaternion."""
        from tripod_shared import tfp, witmotion

        ts: list[int] = []
        qs: list[tuple[float, float, float, float]] = []
        if self.protocol == "tfp":
            parser = tfp.TfpStreamParser()
            for rec in self:
                for pk in parser.feed(rec.data):
                    if pk.function_id == tfp.FID_CALLBACK_QUATERNION:
                        ts.append(rec.host_ns)
                        qs.append(tfp.decode_quaternion(pk.payload))
        else:
            wp = witmotion.WitStreamParser()
            for rec in self:
                for fr in wp.feed(rec.data):
                    if fr.ftype == witmotion.TYPE_QUATERNION:
                        ts.append(rec.host_ns)
                        qs.append(witmotion.decode_quaternion(fr.data))
        return np.asarray(ts, dtype=np.int64), np.asarray(qs, dtype=np.float64).reshape(-1, 4)
