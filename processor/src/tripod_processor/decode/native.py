# SPDX-License-Identifier: BSD-3-Clause
"""The C++ core's batch VLP-16 decoder: a chunk of packets → points in one call.

It replicates velodyne-decoder 3.1's decoding of 16-laser packets (``PacketDecoder::unpack``:
per-laser azimuth interpolated by firing time, sin/cos tables in 0.01° steps, the calibration's
angles, offsets and distance corrections, the range and angle filters, the dual-return pairing)
operation for operation in float32, and is held equal to it by the tests
(``tests/processor/test_native_decoder.py``: bit-equal x, y, z, time, intensity, ring, return
type and point order on every real capture, and on synthetic dual/last-return and malformed
packets; the two-point distance correction of "advanced" calibrations, which no VLP-16 table
has, to one float32 ulp). It takes the calibration from a ``velodyne_decoder.Calibration``, so
both decoders read the same tables. velodyne-decoder's ``column`` field is not produced; the
per-point ``laser`` (channel) is.

Why: velodyne-decoder's own speed is high, but reaching it from Python costs a conversion of
each packet's payload in its binding (~9 µs a packet, three times the decoding). Here a whole
chunk crosses once, as an (N, 1206) uint8 array, decoded with the GIL released (OpenMP over
packets); the points come back already in :data:`POINT_DTYPE`, their time offsets exact
integer ns (the float32 seconds velodyne-decoder gives are ±30 ns in a 0.3 s chunk).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import velodyne_decoder as vd
import yaml

from .. import _ext

#: Per-point fields of a frame: packed little-endian, 20 bytes (4-byte fields aligned); the
#: layout of the C++ ``tripod::Vlp16Point``; a PLY/PCD body is this array's bytes.
POINT_DTYPE = np.dtype([
    ("x", "<f4"),  # [m], sensor frame "lidar" (x forward, y left, z up)
    ("y", "<f4"),
    ("z", "<f4"),
    ("time_offset_ns", "<i4"),  # since the frame's stamp_device_ns, lidar clock
    ("intensity", "u1"),  # calibrated reflectivity 0..255
    ("ring", "u1"),  # laser index ordered by elevation, 0 = lowest (-15° on a VLP-16)
    ("laser", "u1"),  # laser index in firing order (VeloView's laser_id, the packet's channel)
    ("return_type", "u1"),  # 1 strongest, 2 last, 3 both (velodyne_decoder.ReturnMode)
])

#: Columns of the calibration table handed to C++ (velodyne-decoder's ``LaserCorrection``).
CALIBRATION_COLUMNS = (
    "rot_correction", "vert_correction", "dist_correction", "two_pt_correction_available",
    "dist_correction_x", "dist_correction_y", "vert_offset_correction",
    "horiz_offset_correction", "max_intensity", "min_intensity", "focal_distance", "focal_slope")
_DEFAULTS = {"max_intensity": 255, "min_intensity": 0}
PACKET_SIZE = 1206

#: Return type of single-return points before any packet with a known return mode byte
#: (velodyne-decoder 3.1's value; a packet with an unknown byte gets the type of the last
#: known mode, so the decoder carries it from chunk to chunk)
RETURN_TYPE_UNKNOWN = 63
#: ``NativeBatch.status`` values
STATUS_OK, STATUS_BAD_BLOCK_HEADER = 0, 1


class CalibrationError(ValueError):
    """The calibration does not describe a 16-laser sensor (one-line message)."""


def calibration_table(calibration: vd.Calibration) -> tuple[np.ndarray, float, np.ndarray]:
    """The per-laser table, distance resolution and rings of a velodyne-decoder calibration.

    velodyne-decoder does not expose its ``LaserCorrection`` fields to Python; its own YAML
    serialisation writes every float with 9 significant digits, which gives back each float32
    exactly, so the table is read from there.

    Returns
    -------
    table : np.ndarray, shape (16, 12), float64
        :data:`CALIBRATION_COLUMNS` per laser in firing order (angles [rad], lengths [m]).
    distance_resolution_m : float
        [m] per distance unit of the packet.
    rings : np.ndarray, shape (16,), uint8
        Rank of each laser by vertical angle (velodyne-decoder's stable argsort).
    """
    doc = yaml.safe_load(calibration.to_string())
    lasers = sorted(doc.get("lasers") or [], key=lambda lz: int(lz["laser_id"]))
    if len(lasers) != 16 or [int(lz["laser_id"]) for lz in lasers] != list(range(16)):
        raise CalibrationError(
            f"the calibration has {len(lasers)} lasers: the native decoder takes a 16-laser "
            "(VLP-16 / Puck Hi-Res) calibration")
    table = np.array([[float(lz.get(c, _DEFAULTS.get(c, 0))) for c in CALIBRATION_COLUMNS]
                      for lz in lasers], dtype=np.float64)
    # velodyne-decoder 3.1 neither reads nor writes two_pt_correction_available: it applies
    # the two-point correction where both dist_correction_x and dist_correction_y are set
    table[:, 3] = (table[:, 4] != 0) & (table[:, 5] != 0)
    vert = table[:, 1].astype(np.float32)
    rings = np.empty(16, np.uint8)
    rings[np.argsort(vert, kind="stable")] = np.arange(16, dtype=np.uint8)
    resolution = float(np.float32(doc.get("distance_resolution", 0.002)))
    return table, resolution, rings


@functools.lru_cache(maxsize=None)
def _default_table(model: vd.Model) -> tuple[np.ndarray, float, np.ndarray]:
    """:func:`calibration_table` of velodyne-decoder's built-in table of ``model``, read once
    (it goes through YAML: milliseconds a call)."""
    table, resolution, rings = calibration_table(vd.Calibration.default_calibs[model])
    table.setflags(write=False)
    rings.setflags(write=False)
    return table, resolution, rings


@dataclass
class NativeBatch:
    """Points of a chunk of packets, in packet, block, firing order.

    Attributes
    ----------
    points : np.ndarray, shape (M,), dtype :data:`POINT_DTYPE`
    time_s : np.ndarray, shape (M,) or (0,), float32
        velodyne-decoder's point time [s] since packet 0's device time (when asked).
    block_first_point : np.ndarray, shape (N * 12 + 1,), int64
        First point of each data block (flat index packet * 12 + block); the points of a
        dual-return block pair belong to its even block.
    status : np.ndarray, shape (N,), uint8
        :data:`STATUS_OK`, or :data:`STATUS_BAD_BLOCK_HEADER` (a block without the 0xFFEE
        flag: the blocks before it were decoded, as velodyne-decoder does).
    time_offset_clipped : bool
        A time offset did not fit in int32 ns (2.1 s) and was clipped.
    """

    points: np.ndarray
    time_s: np.ndarray
    block_first_point: np.ndarray
    status: np.ndarray
    time_offset_clipped: bool


class NativeVlp16Decoder:
    """Batch decoder of VLP-16 / Puck Hi-Res data packets, equal to velodyne-decoder 3.1.

    Parameters
    ----------
    calibration : velodyne_decoder.Calibration, optional
        The sensor's calibration; default: velodyne-decoder's built-in table of ``model``.
    model : velodyne_decoder.Model
        ``Model.VLP16`` or ``Model.PuckHiRes`` (used for the built-in table only).
    min_range_m, max_range_m : float
        Drop returns nearer / farther than this [m] (velodyne-decoder's ``min_range``,
        ``max_range``).
    min_angle_deg, max_angle_deg : float
        Keep azimuths from min clockwise to max [deg] (0 = +x, 90 = -y), across 0 when min >
        max (the ROS velodyne driver's rule; velodyne-decoder's ``min_angle``, ``max_angle``
        keep [max, min] then).
    num_threads : int
        OpenMP threads per call; 0 = all cores.
    """

    def __init__(self, calibration: vd.Calibration | None = None, *,
                 model: vd.Model = vd.Model.VLP16, min_range_m: float = 0.1,
                 max_range_m: float = 200.0, min_angle_deg: float = 0.0,
                 max_angle_deg: float = 360.0, num_threads: int = 1):
        if calibration is None:
            table, resolution, rings = _default_table(model)
        else:
            table, resolution, rings = calibration_table(calibration)
        self.num_threads = int(num_threads)
        self._return_type = RETURN_TYPE_UNKNOWN  # velodyne-decoder's state across packets
        config = _ext._Vlp16DecoderConfig()
        config.min_range_m, config.max_range_m = float(min_range_m), float(max_range_m)
        config.min_angle_deg, config.max_angle_deg = float(min_angle_deg), float(max_angle_deg)
        self._dec = _ext._Vlp16Decoder(table, resolution, rings, config)

    def decode(self, packets: np.ndarray, stamps_ns: np.ndarray,
               seg_first_block: np.ndarray | None = None, seg_ref_ns: np.ndarray | None = None,
               with_time_s: bool = False) -> NativeBatch:
        """Decode a chunk of packets in one call (the next chunk of a stream goes on from it:
        velodyne-decoder's return-mode state is carried over).

        Parameters
        ----------
        packets : np.ndarray, shape (N, 1206), uint8
            Data packet payloads, C-contiguous.
        stamps_ns : np.ndarray, shape (N,), int64
            Packet stamps [ns]. ``time_offset_ns = stamp + firing offset - reference``; for
            ``time_s`` they are taken, as seconds, for the host stamps velodyne-decoder gets.
        seg_first_block, seg_ref_ns : np.ndarray, shape (S,), int64, optional
            Segments (frames) of the chunk: the flat block index (packet * 12 + block) where
            each starts, sorted, and its reference time [ns]. Default: one segment referenced
            to ``stamps_ns[0]``.
        with_time_s : bool
            Also return velodyne-decoder's float32 time [s] (for comparisons).
        """
        packets = np.ascontiguousarray(packets, dtype=np.uint8)
        if packets.ndim != 2 or packets.shape[1] != PACKET_SIZE:
            raise ValueError(f"packets must be (N, {PACKET_SIZE}) uint8, got {packets.shape}")
        stamps_ns = np.ascontiguousarray(stamps_ns, dtype=np.int64)
        if seg_first_block is not None:
            seg_first_block = np.ascontiguousarray(seg_first_block, dtype=np.int64)
            seg_ref_ns = np.ascontiguousarray(seg_ref_ns, dtype=np.int64)
        out = self._dec.decode(packets, stamps_ns, seg_first_block, seg_ref_ns, with_time_s,
                               self.num_threads, self._return_type)
        self._return_type = out.return_type_after
        return NativeBatch(out.points.view(POINT_DTYPE).reshape(-1), out.time_s,
                           out.block_first_point, out.status, bool(out.time_offset_clipped))


__all__ = ["CALIBRATION_COLUMNS", "POINT_DTYPE", "RETURN_TYPE_UNKNOWN", "STATUS_BAD_BLOCK_HEADER",
           "STATUS_OK",
           "CalibrationError", "NativeBatch", "NativeVlp16Decoder", "calibration_table"]
