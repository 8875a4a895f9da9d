# SPDX-License-Identifier: BSD-3-Clause
"""velodyne-decoder 3.1 as a batch decoder (:class:`tripod_processor.decode.batch.BatchDecoder`):
the tests' oracle for the native decoder, handed to the frame decoder as

    FrameDecoder(config, batch_decoder=VelodyneDecoderOracle)

It feeds velodyne-decoder's ``ScanDecoder`` the chunk's packets (the lidar clock as their
stamps, the product byte set to the model's, which it insists on) and turns its points into the
native decoder's :class:`~tripod_processor.decode.native.NativeBatch`: ``POINT_DTYPE`` points
(``laser`` from ``ring``; ``time_offset_ns`` from velodyne-decoder's float32 seconds, so good to
about ±30 ns in a 0.1 s chunk) and the first point of each block, found from the points' times.
This was the product's ``decoder: velodyne_decoder`` path (slower; its azimuth filter cannot
cross 0).
"""

from __future__ import annotations

import numpy as np
import velodyne_decoder as vd
from tripod_processor.decode.native import POINT_DTYPE, STATUS_OK, NativeBatch
from tripod_shared import velodyne as vl

#: VLP-16 firing order of each ring: lasers alternate -15°, +1°, -13°, +3°, ...
LASER_OF_RING = np.array([0, 2, 4, 6, 8, 10, 12, 14, 1, 3, 5, 7, 9, 11, 13, 15], np.uint8)
_PRODUCT = {vd.Model.VLP16: vl.PRODUCT_VLP16, vd.Model.PuckHiRes: vl.PRODUCT_PUCK_HIRES}
_BLOCK_NS = 110_592  # one data block: two firing sequences of 55.296 µs
#: time from a packet's first to its last firing [ns]: 24 sequences (12 in dual return, where
#: two blocks carry the two returns of the same firings), the last one's 16th laser
_PACKET_SPAN_NS = {False: 23 * 55_296 + 15 * 2_304, True: 11 * 55_296 + 15 * 2_304}
_I32_MAX = 2**31 - 1


class VelodyneDecoderOracle:
    """velodyne-decoder's ``ScanDecoder`` behind the native decoder's interface (see the
    module notes); the arguments are :class:`~tripod_processor.decode.native.NativeVlp16Decoder`'s
    (``num_threads`` is ignored)."""

    def __init__(self, calibration: vd.Calibration | None = None, *,
                 model: vd.Model = vd.Model.VLP16, min_range_m: float = 0.1,
                 max_range_m: float = 200.0, min_angle_deg: float = 0.0,
                 max_angle_deg: float = 360.0, num_threads: int = 1):
        if min_angle_deg % 360 > max_angle_deg % 360:  # 360 is 0 to it
            raise ValueError("velodyne-decoder cannot keep an azimuth range across 0 (or ending "
                             "at 360): it keeps [max, min] instead")
        self._product = _PRODUCT[model]
        self._scan = vd.ScanDecoder(vd.Config(
            model=model, calibration=calibration, min_range=min_range_m,
            max_range=max_range_m, min_angle=min_angle_deg, max_angle=max_angle_deg,
            timestamp_first_packet=True))

    def decode(self, packets: np.ndarray, stamps_ns: np.ndarray,
               seg_first_block: np.ndarray | None = None,
               seg_ref_ns: np.ndarray | None = None) -> NativeBatch:
        k = len(packets)
        if seg_first_block is None:
            seg_first_block = np.zeros(1, np.int64)
            seg_ref_ns = stamps_ns[:1]
        arr = packets
        if (arr[:, vl.PRODUCT_ID_OFFSET] != self._product).any():
            arr = arr.copy()
            arr[:, vl.PRODUCT_ID_OFFSET] = self._product
        rel_ns = np.asarray(stamps_ns, np.int64) - int(stamps_ns[0])
        batch = [p.tobytes() for p in arr]
        # stamps: seconds since the chunk's first packet (small doubles: no rounding)
        stamps_s = (rel_ns * 1e-9).tolist()
        dual = bool(k) and int(arr[0, vl.RETURN_MODE_OFFSET]) == vl.RETURN_DUAL
        ordered = k == 1 or bool((np.diff(rel_ns) >= _PACKET_SPAN_NS[dual] + 2000).all())
        if ordered:
            # firings of different packets never overlap: each point's block is the last one
            # whose first firing is not after the point (float32 times: 1 µs of slack)
            raw = self._decode(batch, stamps_s)
            t_s = raw["time"]  # float32 [s] since packet 0 of the chunk
            unit_blocks = np.arange(0, 12, 2) if dual else np.arange(12)
            unit_ns = (rel_ns[:, None] + (unit_blocks // 2 if dual else unit_blocks)[None, :]
                       * _BLOCK_NS).ravel()
            unit_of = np.searchsorted(unit_ns, (t_s.astype(np.float64) * 1e9) + 1000,
                                      side="right") - 1
            block = (unit_of // len(unit_blocks)) * 12 + unit_blocks[unit_of % len(unit_blocks)]
            point_ns = None
        else:
            # out of order or overlapping: packet by packet, each point placed by its packet
            # and its firing time inside the packet (exact, slower)
            raw, owner = self._decode_each(batch, stamps_s)
            within_ns = np.rint(raw["time"].astype(np.float64) * 1e9).astype(np.int64)
            unit = (within_ns + 1000) // _BLOCK_NS  # block, or block pair in dual return
            block = owner * 12 + (np.clip(unit, 0, 5) * 2 if dual else np.clip(unit, 0, 11))
            point_ns = rel_ns[owner] + within_ns
            t_s = None
        points = np.empty(len(raw), POINT_DTYPE)
        for f in ("x", "y", "z", "intensity", "ring", "return_type"):
            points[f] = raw[f]  # (intensity 0..255: velodyne-decoder clamps it)
        points["laser"] = LASER_OF_RING[raw["ring"]]
        seg = np.searchsorted(seg_first_block, block, side="right") - 1
        ref_rel_ns = np.asarray(seg_ref_ns, np.int64) - int(stamps_ns[0])
        if point_ns is None:  # float32 seconds, as velodyne-decoder gives them
            off = (t_s - (ref_rel_ns * 1e-9).astype(np.float32)[seg]) * np.float32(1e9)
        else:
            off = (point_ns - ref_rel_ns[seg]).astype(np.float64)
        off = np.rint(off)
        clipped = bool(len(off)) and (off.max() > _I32_MAX or off.min() < -_I32_MAX)
        points["time_offset_ns"] = np.clip(off, -_I32_MAX, _I32_MAX)
        first = np.searchsorted(block, np.arange(k * 12 + 1), side="left")
        return NativeBatch(points, np.asarray(raw["time"], np.float32), first.astype(np.int64),
                           np.full(k, STATUS_OK, np.uint8), clipped)

    def _decode(self, batch: list[bytes], stamps_s: list[float]) -> np.ndarray:
        """All points of the packets in one velodyne-decoder call (time [s] since packet 0)."""
        pv = vd.PacketVector()
        for p, st in zip(batch, stamps_s):
            pv.append(vd.VelodynePacket(st, p))
        return self._scan.decode(pv, as_pcl_structs=True)[1]

    def _decode_each(self, batch, stamps_s) -> tuple[np.ndarray, np.ndarray]:
        """Packet by packet: points (time [s] since their own packet) and their packet index."""
        parts, owners = [], []
        for i in range(len(batch)):
            raw = self._decode(batch[i : i + 1], stamps_s[i : i + 1])
            parts.append(raw)
            owners.append(np.full(len(raw), i, np.int64))
        return np.concatenate(parts), np.concatenate(owners)
