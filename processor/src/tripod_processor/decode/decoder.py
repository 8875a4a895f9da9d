# SPDX-License-Identifier: BSD-3-Clause
"""Velodyne VLP-16 packets → frames (one rotation each) of points with per-point fields.

The points come from a batch decoder (:mod:`.batch`): by default tripod's own
(:mod:`.native`, C++, one call per chunk of packets, proven equal to velodyne-decoder 3.1 point
for point by the tests, where velodyne-decoder is the oracle); this module groups packets, tells
the sensor apart, splits rotations, stamps points and reports what it met.

Frames
    A frame is one rotation, split where the azimuth of a *data block* wraps (is smaller than
    the previous block's), exactly as VeloView splits: a frame may start or end inside a packet.
    Blocks with zero distance give no point. The first and last frame of a capture are partial.
    A gap longer than ``max_gap_in_frame_s`` (no packet for longer than one slow rotation) also
    starts a new frame, since the wrap may have been lost in it.

Frame convention (sensor frame ``lidar``)
    velodyne-decoder's: x forward (azimuth 0), y left, z up (ROS REP-103). VeloView's axes are
    this frame turned +90° about z: ``x_veloview = -y``, ``y_veloview = x``, ``z_veloview = z``
    (VeloView puts azimuth 0 on +y and azimuth grows clockwise towards +x). See
    :func:`to_veloview_xyz`.

Time
    Every frame has ``stamp_host_ns`` (host_realtime clock of the capturer, from the packet
    holding the frame's first block) and ``stamp_device_ns`` (lidar clock: the packets'
    µs-past-the-hour, put on the hour nearest the host time, unwrapped across hours; the time of
    the frame's first firing). Each point has ``time_offset_ns`` (int32, lidar clock) since
    ``stamp_device_ns``, from the firing timing of the VLP-16 manual (55.296 µs per firing
    sequence, 2.304 µs per laser) as velodyne-decoder computes it. The native decoder gives it
    exactly (integer ns from the packet's device time). Point times never depend on the host
    clock's jitter (the batch decoder is handed the lidar clock as its packet stamps).

Azimuth
    velodyne-decoder interpolates each laser's azimuth by its firing time; VeloView (the version
    that made its regression oracle) gives all 16 lasers of a firing sequence one azimuth.
    Points differ by up to 15 × 2.304 µs of rotation (0.25° at 20 Hz); :func:`to_veloview_xyz`
    undoes it. The default ``calibration="veloview"`` uses VeloView's nominal laser angles.

Sensor
    Product byte 0x22 is a VLP-16, 0x24 a Puck Hi-Res (VLP-16 Hi-Res). 0x21 is an HDL-32E *or*
    an early-firmware VLP-16: the data packet period decides (VLP-16 1327 µs, or 664 µs in dual
    return; HDL-32E 553 µs). Other sensors are refused with :class:`DecodeError`.

Memory stays constant: packets are decoded in chunks of ``chunk_packets`` (one decoder call
each), and at most one chunk of points plus the open frame is held. A frame wholly inside a
chunk is a slice of the batch decoder's output (no copy); any other point is copied once, from
the decoder's output into its frame.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import velodyne_decoder as vd
from pydantic import Field, field_validator
from tripod_shared import nmea as nmea_
from tripod_shared import velodyne as vl
from tripod_shared.timebase import TohChunkUnwrapper, nearest_hour_ns
from tripod_shared.config_io import StrictModel

from .batch import BatchDecoder, BatchDecoderFactory
from .native import POINT_DTYPE, NativeVlp16Decoder
from ..io.packets import PacketBatch, PacketSource, SourceError, group_packets, open_source

_FIRST_CAPACITY = 32_768  # points; a VLP-16 rotation holds up to 28,800 (5 Hz, single return)
_BLOCK_NS = 110_592  # one VLP-16 data block: two firing sequences of 55.296 µs
_MODELS = {"VLP-16": vd.Model.VLP16, "Puck Hi-Res": vd.Model.PuckHiRes}


class DecodeError(ValueError):
    """The input cannot be decoded (wrong sensor, no data packets); one-line message."""


class DecodeConfig(StrictModel):
    """Settings of the decoder (section ``decode`` of the processor config)."""

    sensor: Literal["auto", "VLP-16", "Puck Hi-Res"] = Field(
        "auto", description="auto: from the product byte and the packet period")
    min_range_m: float = Field(
        0.001, ge=0, description="drop returns nearer than this [m] (zero distance = no return "
        "is always dropped; the default keeps every other return, like VeloView)")
    max_range_m: float = Field(200.0, gt=0, description="drop returns farther than this [m]")
    azimuth_min_deg: float = Field(
        0.0, ge=0, le=360, description="keep only returns with azimuth in [azimuth_min_deg, azimuth_max_deg] "
        "[deg] (the view width; velodyne-decoder's min_angle). Azimuth is the sensor's own: "
        "0 along +x (forward), growing clockwise seen from above (90 = -y, right); a range "
        "that crosses 0 (e.g. 270 to 90) keeps the front half. Equal values keep everything")
    azimuth_max_deg: float = Field(
        360.0, ge=0, le=360, description="end of the kept azimuth range [deg] (velodyne-decoder's max_angle)")
    max_gap_in_frame_s: float = Field(
        0.2, gt=0, description="a silence longer than this [s] starts a new frame")
    gap_factor: float = Field(
        1.5, gt=1, description="a packet interval above this many packet periods is a gap")
    decoder: Literal["native"] | None = Field(
        None, exclude=True, description="deprecated, ignored: tripod always decodes with its "
        "native decoder (accepted so that the decode_config.yaml of an earlier run still "
        "loads; never written)")
    num_threads: int = Field(
        1, ge=0, description="threads of the native decoder per chunk (0: all cores); one "
        "is enough: it decodes ~3 µs a packet, the rest of the stream is the bottleneck")
    chunk_packets: int = Field(
        1024, ge=1, description="packets per decoder call (speed vs memory: a chunk's points "
        "take up to 7.9 MB at 1024)")
    detect_packets: int = Field(
        32, ge=2, description="data packets looked at to tell the sensor and its period")
    max_gaps_listed: int = Field(100, ge=0, description="gaps itemised in the report")
    calibration: str = Field(
        "veloview", description="veloview: nominal laser angles as VeloView/LidarView use "
        "them; manual: velodyne-decoder's built-in table with the VLP-16 manual's per-laser "
        "vertical offsets (up to 11.2 mm); or the path of a velodyne YAML calibration")

    @field_validator("decoder", mode="before")
    @classmethod
    def _decoder_gone(cls, value):
        if value is not None and value != "native":
            raise ValueError(
                f"{value!r} is no longer offered: the key is deprecated and tripod always "
                "decodes with its native decoder (velodyne-decoder is the tests' oracle); "
                "remove the key")
        return value


@dataclass
class Frame:
    """One rotation of points.

    Attributes
    ----------
    index : int
        0-based frame number in the stream.
    points : np.ndarray, shape (N,), dtype :data:`POINT_DTYPE`
    stamp_host_ns : int
        host_realtime [ns] of the packet holding the frame's first block.
    stamp_device_ns : int
        lidar clock [ns] of the frame's first firing (see the module notes).
    packets : int
        Data packets with at least one block in this frame.
    azimuth_start_deg, azimuth_end_deg : float
        Block azimuths of the first and last block [deg].
    gaps : int
        Gaps (missing packets) inside this frame.
    """

    index: int
    points: np.ndarray
    stamp_host_ns: int
    stamp_device_ns: int
    packets: int
    azimuth_start_deg: float
    azimuth_end_deg: float
    gaps: int = 0

    def __len__(self) -> int:
        return len(self.points)

    def xyz(self) -> np.ndarray:
        """(N, 3) float32 view-copy of the coordinates [m], lidar frame."""
        p = self.points
        return np.stack([p["x"], p["y"], p["z"]], axis=1)


@dataclass
class Gap:
    """Missing data packets: the device clock jumped by ``duration_ns`` between two packets."""

    after_packet: int  # index of the data packet before the gap
    device_ns: int  # lidar clock of that packet
    duration_ns: int
    missing_packets: int


@dataclass
class PositionReport:
    """What the position (telemetry) packets said."""

    packets: int = 0
    nmea: dict[str, int] = field(default_factory=dict)  # sentence type -> count
    pps: dict[str, int] = field(default_factory=dict)  # PPS state -> count
    fixes: int = 0  # sentences with a valid fix
    first_nmea: str = ""
    first_utc: str = ""  # ISO time of the first sentence with a time
    last_utc: str = ""
    first_position: tuple[float, float, float] | None = None  # lon, lat [deg], alt [m]

    def to_dict(self) -> dict:
        return {"packets": self.packets, "nmea": dict(self.nmea), "pps": dict(self.pps),
                "fixes": self.fixes, "first_nmea": self.first_nmea,
                "first_utc": self.first_utc, "last_utc": self.last_utc,
                "first_position": list(self.first_position) if self.first_position else None}


@dataclass
class DecodeReport:
    """Everything the decoder met; :meth:`summary` is the ``tripod decode --summary`` JSON."""

    sensor: str = ""
    product_id: int | None = None
    return_mode: str = ""
    packet_period_us: float | None = None
    packets: int = 0  # data packets decoded
    rotations: int = 0  # azimuth wraps seen = frames closed by a wrap (MRPT's scan count)
    points: int = 0
    points_per_frame: list[int] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)
    gaps: list[Gap] = field(default_factory=list)  # the first max_gaps_listed
    gap_count: int = 0
    missing_packets: int = 0
    max_gap_ns: int = 0
    position: PositionReport = field(default_factory=PositionReport)
    truncated: bool = False
    warnings: list[str] = field(default_factory=list)
    first_device_ns: int | None = None
    last_device_ns: int | None = None

    def skip(self, reason: str, n: int = 1) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + n

    def warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    @property
    def frames(self) -> int:
        return len(self.points_per_frame)

    def summary(self) -> dict:
        """JSON-ready summary: the keys of issue 2 first, then extras."""
        dur = None
        if self.first_device_ns is not None and self.last_device_ns is not None:
            dur = round((self.last_device_ns - self.first_device_ns) * 1e-9, 6)
        return {
            "frames": self.frames,
            "points_per_frame": list(self.points_per_frame),
            "sensor": self.sensor,
            "return_mode": self.return_mode,
            "packets": self.packets,
            "skipped": dict(sorted(self.skipped.items())),
            "rotations": self.rotations,
            "points": self.points,
            "product_id": f"0x{self.product_id:02x}" if self.product_id is not None else None,
            "packet_period_us": (round(self.packet_period_us, 3)
                                 if self.packet_period_us is not None else None),
            "duration_s": dur,
            "gaps": {
                "count": self.gap_count,
                "missing_packets": self.missing_packets,
                "max_s": round(self.max_gap_ns * 1e-9, 6),
                "list": [{"after_packet": g.after_packet, "device_ns": g.device_ns,
                          "duration_s": round(g.duration_ns * 1e-9, 6),
                          "missing_packets": g.missing_packets} for g in self.gaps],
            },
            "position": self.position.to_dict(),
            "truncated": self.truncated,
            "warnings": list(self.warnings),
        }


def to_veloview_xyz(points: np.ndarray, block_azimuth_step_deg: float | None = None
                    ) -> np.ndarray:
    """(N, 3) float64 coordinates of a frame's points in VeloView's convention.

    Two differences are undone: the axes (VeloView = ours turned +90° about z, see the module
    notes) and, when ``block_azimuth_step_deg`` (the azimuth advance per data block, 0.8° at
    20 Hz) is given, the per-laser azimuth: velodyne-decoder interpolates the azimuth of each
    laser by its firing time (2.304 µs per laser, VLP-16 manual), VeloView gives all 16 lasers of
    a firing sequence the sequence's azimuth.
    """
    x = points["x"].astype(np.float64)
    y = points["y"].astype(np.float64)
    if block_azimuth_step_deg:
        laser = points["laser"].astype(np.int64)  # firing order
        # azimuth grows clockwise seen from above: undoing an advance turns counter-clockwise
        a = np.deg2rad(block_azimuth_step_deg * laser * 2304 / _BLOCK_NS)
        c, s = np.cos(a), np.sin(a)
        x, y = c * x - s * y, s * x + c * y
    return np.stack([-y, x, points["z"].astype(np.float64)], axis=1)


def identify_sensor(product_id: int, return_byte: int, period_us: float | None) -> str:
    """Sensor name from the factory bytes and the data packet period [µs].

    Raises :class:`DecodeError` for a sensor tripod does not decode, naming it.
    """
    if product_id == vl.PRODUCT_VLP16:
        return "VLP-16"
    if product_id == vl.PRODUCT_PUCK_HIRES:
        return "Puck Hi-Res"
    if product_id == vl.PRODUCT_HDL32E:
        if period_us is None:
            raise DecodeError("product byte 0x21 (HDL-32E or early VLP-16) and too few "
                              "packets to tell them apart by the packet period")
        single, dual = vl.VLP16_PACKET_PERIOD_US["single"], vl.VLP16_PACKET_PERIOD_US["dual"]
        if abs(period_us - single) < 0.15 * single:
            return "VLP-16"
        if abs(period_us - dual) < 0.1 * dual and return_byte == vl.RETURN_DUAL:
            return "VLP-16"
        raise DecodeError(
            f"the sensor is an HDL-32E (product byte 0x21, one data packet every "
            f"{period_us:.0f} µs): tripod decodes VLP-16 captures only")
    raise DecodeError(f"the sensor is a {vl.product_name(product_id)} (product byte "
                      f"0x{product_id:02x}): tripod decodes VLP-16 captures only")


def forced_sensor_doubt(sensor: str, product_id: int, return_byte: int,
                        period_us: float | None) -> str:
    """Why the capture does not look like the ``sensor`` forced by the config ('' if it does):
    a VLP-16 or Puck Hi-Res sends a data packet every 1327 µs (664 µs in dual return); an
    HDL-32E every 553 µs."""
    if period_us is None:
        return ""
    single, dual = vl.VLP16_PACKET_PERIOD_US["single"], vl.VLP16_PACKET_PERIOD_US["dual"]
    if abs(period_us - single) < 0.15 * single or (
            abs(period_us - dual) < 0.1 * dual and return_byte == vl.RETURN_DUAL):
        return ""
    return (f"sensor {sensor!r} was forced (--sensor / config key sensor), but the data packets come every {period_us:.0f} µs "
            f"(a {sensor} sends one every {single:.0f} µs, {dual:.0f} µs in dual return; the "
            f"product byte 0x{product_id:02x} says {vl.product_name(product_id)}): the points "
            "are likely wrong")


_BUNDLED_CALIBRATION = {"VLP-16": "VLP-16.yml", "Puck Hi-Res": "Puck Hi-Res.yml"}


def _calibration(name: str, sensor: str):
    """velodyne-decoder Calibration for a :attr:`DecodeConfig.calibration` value."""
    if name == "manual":
        return None  # velodyne-decoder's built-in table for the model
    try:
        if name == "veloview":
            return vd.calibrations.get_bundled_calibration(_BUNDLED_CALIBRATION[sensor])
        return vd.Calibration.read(os.fspath(name))
    except RuntimeError as exc:
        raise DecodeError(f"cannot read the calibration {name!r}: {exc}") from None


class FrameDecoder:
    """Streaming decoder: feed ``(host_ns, payload)`` packets, get :class:`Frame` objects.

    >>> dec = FrameDecoder(DecodeConfig())
    >>> for frame in dec.decode(source):      # any iterable of (host_ns, payload)
    ...     frame.points["x"], frame.stamp_device_ns
    >>> dec.report.summary()

    ``batch_decoder`` makes the decoder of the points (:class:`.batch.BatchDecoderFactory`,
    called once per stream when the sensor is known); default :class:`.native.NativeVlp16Decoder`.
    """

    def __init__(self, config: DecodeConfig | None = None,
                 batch_decoder: BatchDecoderFactory = NativeVlp16Decoder):
        self.config = config or DecodeConfig()
        self.report = DecodeReport()
        self._factory = batch_decoder

    # ---------------------------------------------------------------------------------------
    def decode(self, packets: Iterable[tuple[int, bytes]]) -> Iterator[Frame]:
        """Frames of a packet stream, in order; the last (partial) frame comes at the end."""
        yield from self.decode_batches(group_packets(packets, self.config.chunk_packets))

    def decode_batches(self, batches: Iterable[PacketBatch]) -> Iterator[Frame]:
        """:meth:`decode` of a stream given as :class:`~.packet_sources.PacketBatch` es (the
        sources' fast path: data packets arrive as arrays, cut here into decoder chunks)."""
        cfg = self.config
        self.report = rep = DecodeReport()
        self._state_reset()
        pend_host: list[np.ndarray] = []  # data packets not decoded yet, in arrays
        pend_data: list[np.ndarray] = []
        n_pend = 0
        detecting = True
        pos_size = vl.POSITION_PACKET_SIZE
        chunk = cfg.chunk_packets
        for batch in batches:
            for _host_ns, payload in batch.others:
                if len(payload) == pos_size:
                    self._position(payload)
                else:
                    rep.skip("wrong_size")
            if not len(batch.host_ns):
                continue
            pend_host.append(batch.host_ns)
            pend_data.append(batch.data)
            n_pend += len(batch.host_ns)
            if detecting:
                if n_pend < cfg.detect_packets:
                    continue
                self._detect(np.concatenate(pend_data)[: cfg.detect_packets])
                detecting = False
            if n_pend < chunk:
                continue
            host = np.concatenate(pend_host) if len(pend_host) > 1 else pend_host[0]
            data = np.concatenate(pend_data) if len(pend_data) > 1 else pend_data[0]
            full = n_pend - n_pend % chunk
            for i in range(0, full, chunk):  # row slices of a C-contiguous array: no copy
                yield from self._process(host[i : i + chunk], data[i : i + chunk])
            pend_host, pend_data = [host[full:]], [data[full:]]
            n_pend -= full
        if detecting:
            if not n_pend:
                raise DecodeError("no Velodyne data packets (1206-byte UDP payloads) found")
            self._detect(np.concatenate(pend_data)[: cfg.detect_packets])
        if n_pend:
            yield from self._process(np.concatenate(pend_host), np.concatenate(pend_data))
        yield from self._finish()

    # ---------------------------------------------------------------------------------------
    def _state_reset(self) -> None:
        self._model = None
        self._sensor_product = None
        self._batch: BatchDecoder | None = None
        self._view: np.ndarray | None = None  # a frame wholly inside one decoded chunk
        self._prev_az = -1  # azimuth of the last block seen
        self._prev_dev_ns = None  # lidar clock of the last packet (unwrapped, absolute)
        self._unwrap: TohChunkUnwrapper | None = None  # lidar_toh -> host_realtime's hours
        self._packet_index = 0
        self._frame_index = 0
        self._buf = np.empty(_FIRST_CAPACITY, POINT_DTYPE)  # points of the open frame
        self._n = 0
        self._frame_open = False
        self._frame_host_ns = 0
        self._frame_dev_ns = 0
        self._frame_packets = 0
        self._frame_az0 = 0
        self._frame_az1 = 0
        self._frame_gaps = 0
        self._return_mode_byte = None
        self._last_nmea = ""
        self._last_parsed: tuple = ("", False, None, "")

    def _detect(self, first: np.ndarray) -> None:
        cfg, rep = self.config, self.report
        good = [p for p in map(bytes, first) if vl.check_data_packet(
            p, accept_products=tuple(vl.PRODUCTS)) == vl.PacketKind.DATA]
        if not good:
            raise DecodeError("no well-formed Velodyne data packets at the start of the input")
        products = [p[vl.PRODUCT_ID_OFFSET] for p in good]
        product = max(set(products), key=products.count)
        ret = good[0][vl.RETURN_MODE_OFFSET]
        toh = np.array([vl.data_timestamp_us(p) for p in good], dtype=np.int64)
        d = np.diff(toh)
        d = d[(d > 0) & (d < 100_000)]
        period = float(np.median(d)) if len(d) else None
        if cfg.sensor == "auto":
            sensor = identify_sensor(product, ret, period)
        else:
            sensor = cfg.sensor
            doubt = forced_sensor_doubt(sensor, product, ret, period)
            if doubt:
                rep.warn(doubt)
        rep.sensor, rep.product_id, rep.packet_period_us = sensor, product, period
        rep.return_mode = vl.RETURN_MODES.get(ret, f"unknown(0x{ret:02x})")
        self._return_mode_byte = ret
        self._model = _MODELS[sensor]
        self._sensor_product = product
        calibration = _calibration(cfg.calibration, sensor)
        try:  # (CalibrationError is a ValueError)
            self._batch = self._factory(
                calibration, model=self._model, min_range_m=cfg.min_range_m,
                max_range_m=cfg.max_range_m, min_angle_deg=cfg.azimuth_min_deg,
                max_angle_deg=cfg.azimuth_max_deg, num_threads=cfg.num_threads)
        except ValueError as exc:
            raise DecodeError(str(exc)) from None
        self._period_ns = int(round((period or vl.VLP16_PACKET_PERIOD_US["single"]) * 1000))

    def _position(self, payload: bytes) -> None:
        pr = self.report.position
        if vl.check_position_packet(payload) != vl.PacketKind.POSITION:
            self.report.skip("bad_position_packet")
            return
        pr.packets += 1
        state = vl.position_pps_state(payload)
        pr.pps[state] = pr.pps.get(state, 0) + 1
        nmea = vl.position_nmea(payload)
        if not nmea:
            return
        # the sensor repeats each (1 Hz) sentence in many position packets: parse it once
        if nmea != self._last_nmea:
            self._last_nmea = nmea
            self._last_parsed = self._parse_nmea(nmea, payload)
        kind, fix, position, utc = self._last_parsed
        pr.nmea[kind] = pr.nmea.get(kind, 0) + 1
        if not pr.first_nmea:
            pr.first_nmea = nmea
        if fix:
            pr.fixes += 1
            if pr.first_position is None:
                pr.first_position = position
        if utc:
            if not pr.first_utc:
                pr.first_utc = utc
            pr.last_utc = utc

    @staticmethod
    def _parse_nmea(nmea: str, payload: bytes) -> tuple[str, bool, tuple | None, str]:
        """(sentence type or 'bad_checksum', has a fix, (lon, lat, alt), ISO UTC time)."""
        kind = nmea_.sentence_type(nmea)
        if not nmea_.checksum_ok(nmea):
            return "bad_checksum", False, None, ""
        try:
            info = vd.TelemetryPacket(payload).parse_nmea()
        except Exception:  # noqa: BLE001 - a sentence velodyne-decoder cannot parse is counted
            info = None
        if info is None:
            return kind, False, None, ""
        date = (f"{info.utc_year:04d}-{info.utc_month:02d}-{info.utc_day:02d}T"
                if info.utc_year > 0 else "")
        utc = f"{date}{info.utc_hours:02d}:{info.utc_minutes:02d}:{info.utc_seconds:06.3f}Z"
        position = (info.longitude, info.latitude, info.altitude)
        return kind, bool(info.fix_available), position, utc

    # ---------------------------------------------------------------------------------------
    def _process(self, host_ns: np.ndarray, arr: np.ndarray) -> Iterator[Frame]:
        """Decode one chunk of data packets ((k,) int64 host_ns, (k, 1206) uint8) and emit the
        frames it completes."""
        kept = self._valid_packets(host_ns, arr)
        if kept is None:
            return
        host_ns, arr, blocks = kept
        k = len(arr)
        dev_ns = self._device_clock(host_ns, arr)
        dt, gap_idx = self._gaps(dev_ns)
        az_flat, split = self._frame_boundaries(blocks, dt)
        # ---- decode --------------------------------------------------------------------------
        dual = self._return_mode_byte == vl.RETURN_DUAL
        split_blocks = np.flatnonzero(split)
        starts = np.concatenate(([0], split_blocks))  # segments: [starts[s], ends[s]) blocks
        ends = np.concatenate((split_blocks, [k * 12]))
        continued = self._frame_open  # the first segment goes on with a frame of the last chunk
        raw, pstarts, pends = self._decode_points(arr, dev_ns, starts, ends, dual, continued)
        yield from self._cut_frames(host_ns, dev_ns, az_flat, gap_idx, starts, ends, pstarts,
                                    pends, raw, dual, continued)
        self._packet_index += k
        self.report.packets += k

    def _valid_packets(self, host_ns, arr):
        """The chunk without packets of a bad header, return mode or other product (counted as
        skipped): (host_ns, arr, blocks (k, 12, 100)), or None when nothing is left."""
        rep = self.report
        blocks = arr[:, :1200].reshape(-1, 12, 100)
        ok = (blocks[:, :, 0] == 0xFF).all(1) & (blocks[:, :, 1] == 0xEE).all(1)
        ret = arr[:, vl.RETURN_MODE_OFFSET]
        ok &= (ret >= vl.RETURN_STRONGEST) & (ret <= vl.RETURN_DUAL)
        if not ok.all():
            rep.skip("bad_header", int((~ok).sum()))
        prod_ok = arr[:, vl.PRODUCT_ID_OFFSET] == self._sensor_product
        if not (prod_ok | ~ok).all():
            rep.skip("other_product", int((ok & ~prod_ok).sum()))
        ok &= prod_ok
        if not ok.all():
            keep = np.flatnonzero(ok)
            host_ns = host_ns[keep]
            arr = arr[keep]
            blocks = blocks[keep]
            ret = ret[keep]
        if len(arr) == 0:
            return None
        if (ret != self._return_mode_byte).any():
            rep.warn("the return mode changes within the capture")
        return host_ns, arr, blocks

    def _device_clock(self, host_ns, arr) -> np.ndarray:
        """(k,) int64 lidar time [ns] of each packet: µs past the hour unwrapped over hours and
        put on the host's hour."""
        rep = self.report
        toh_us = arr[:, vl.TIMESTAMP_OFFSET : vl.TIMESTAMP_OFFSET + 4].copy().view("<u4").ravel()
        if self._unwrap is None:
            self._unwrap = TohChunkUnwrapper(nearest_hour_ns(int(toh_us[0]), int(host_ns[0])))
        dev_ns = self._unwrap(toh_us)
        if rep.first_device_ns is None:
            rep.first_device_ns = int(dev_ns[0])
            self._prev_dev_ns = int(dev_ns[0]) - self._period_ns
        rep.last_device_ns = int(dev_ns[-1])
        return dev_ns

    def _gaps(self, dev_ns):
        """(dt (k,) ns since the packet before, indices of the packets after a gap); the gaps
        are counted in the report."""
        rep, cfg = self.report, self.config
        dt = np.diff(dev_ns, prepend=self._prev_dev_ns)
        if self._packet_index == 0:
            dt[0] = self._period_ns
        gap_idx = np.flatnonzero(dt > cfg.gap_factor * self._period_ns)
        if (dt < 0).any():
            rep.warn("the device time goes backwards (reordered or replayed packets)")
        for g in gap_idx:
            missing = max(int(round(dt[g] / self._period_ns)) - 1, 1)
            rep.gap_count += 1
            rep.missing_packets += missing
            rep.max_gap_ns = max(rep.max_gap_ns, int(dt[g]))
            if len(rep.gaps) < cfg.max_gaps_listed:
                after_dev = int(dev_ns[g - 1]) if g > 0 else self._prev_dev_ns
                rep.gaps.append(Gap(self._packet_index + int(g) - 1, after_dev, int(dt[g]),
                                    missing))
        self._prev_dev_ns = int(dev_ns[-1])
        return dt, gap_idx

    def _frame_boundaries(self, blocks, dt):
        """(azimuth of every block (k * 12,), True where a block starts a new frame): at the
        azimuth wrap, and after a gap longer than ``max_gap_in_frame_s``."""
        rep, cfg = self.report, self.config
        az = blocks[:, :, 2].astype(np.int32) | (blocks[:, :, 3].astype(np.int32) << 8)
        az_flat = az.ravel()
        prev_az = np.empty_like(az_flat)
        prev_az[0] = self._prev_az
        prev_az[1:] = az_flat[:-1]
        split = az_flat < prev_az  # block starts a new frame
        split[0] = split[0] and self._prev_az >= 0
        rep.rotations += int(split.sum())
        long_gap = np.flatnonzero(dt > cfg.max_gap_in_frame_s * 1e9)
        split[long_gap * 12] = True  # (a no-op at the stream start: no frame is open)
        self._prev_az = int(az_flat[-1])
        return az_flat, split

    def _decode_points(self, arr, dev_ns, starts, ends, dual, continued):
        """The chunk through the batch decoder: (points, first point of each segment, end
        point of each segment)."""
        # one call for the chunk; every point is attributed to its block, so the frames
        # are cut at block boundaries exactly, whatever the packet order, and each point's
        # time offset comes out relative to its frame's first firing (exact integer ns)
        blk = starts % 12
        seg_ref_ns = dev_ns[starts // 12] + ((blk // 2) if dual else blk) * _BLOCK_NS
        if continued:
            seg_ref_ns[0] = self._frame_dev_ns
        out = self._batch.decode(arr, dev_ns, starts, seg_ref_ns)
        if out.time_offset_clipped:
            self.report.warn("a frame spans more than 2.1 s: its time offsets are clipped")
        return out.points, out.block_first_point[starts], out.block_first_point[ends]

    def _cut_frames(self, host_ns, dev_ns, az_flat, gap_idx, starts, ends, pstarts, pends, raw,
                    dual, continued) -> Iterator[Frame]:
        """Cut the decoded points into frames: emit each frame closed in this chunk, keep the
        open one's points."""
        # ---- cut into frames (points come in packet, block, firing order) --------------------
        last_seg = len(starts) - 1
        for seg, (b0, b1, q0, q1) in enumerate(zip(starts, ends, pstarts, pends)):
            if seg > 0:
                yield from self._close_frame()
            if b1 <= b0:
                continue
            if not self._frame_open:
                pk = b0 // 12
                blk = b0 % 12
                self._frame_open = True
                self._frame_host_ns = int(host_ns[pk])
                blk_time = (blk // 2) * _BLOCK_NS if dual else blk * _BLOCK_NS
                self._frame_dev_ns = int(dev_ns[pk]) + blk_time
                self._frame_packets = 0
                self._frame_gaps = 0
                self._frame_az0 = int(az_flat[b0])
            first_pk, last_pk = b0 // 12, (b1 - 1) // 12
            self._frame_packets += last_pk - first_pk + 1  # a packet cut by a wrap: in both
            lo = first_pk - 1 if (seg == 0 and continued and b0 == 0) else first_pk
            self._frame_gaps += int(((gap_idx > lo) & (gap_idx <= last_pk)).sum())
            self._frame_az1 = int(az_flat[b1 - 1])
            if self._n == 0 and seg < last_seg and not (seg == 0 and continued):
                # a whole frame inside this chunk: the decoder's output is the frame, no copy
                self._view = raw[q0:q1]
                continue
            if q1 > q0:
                self._append(raw[q0:q1])

    def _append(self, src) -> None:
        """Copy decoded points into the open frame's buffer (once per point)."""
        n, m = self._n, len(src)
        if n + m > len(self._buf):
            grown = np.empty(max(2 * len(self._buf), n + m), POINT_DTYPE)
            grown[:n] = self._buf[:n]
            self._buf = grown
        self._buf[n : n + m] = src
        self._n = n + m

    def _close_frame(self) -> Iterator[Frame]:
        if not self._frame_open:
            return
        if self._view is not None:  # a frame the batch decoder gave whole
            pts, self._view = self._view, None
        else:
            # the frame keeps its buffer; the next one gets a fresh buffer sized after this one
            pts = self._buf[: self._n]
            self._buf = np.empty(max(_FIRST_CAPACITY, self._n + self._n // 8), POINT_DTYPE)
            self._n = 0
        self._frame_open = False
        f = Frame(self._frame_index, pts, self._frame_host_ns, self._frame_dev_ns,
                  self._frame_packets, self._frame_az0 / 100.0, self._frame_az1 / 100.0,
                  self._frame_gaps)
        self._frame_index += 1
        self.report.points_per_frame.append(len(pts))
        self.report.points += len(pts)
        yield f

    def _finish(self) -> Iterator[Frame]:
        yield from self._close_frame()


class DecodeRun:
    """A lazy decode of one input: iterate it for frames; ``report`` fills as it goes.

    Once the iteration ends the report also holds what the source skipped and whether the
    input was cut short.
    """

    def __init__(self, source: PacketSource, decoder: FrameDecoder):
        self.source = source
        self.decoder = decoder

    @property
    def report(self) -> DecodeReport:
        return self.decoder.report

    def __iter__(self) -> Iterator[Frame]:
        try:
            yield from self.decoder.decode_batches(self.source.batches())
        finally:
            rep, src = self.decoder.report, self.source.report
            for reason, n in src.skipped.items():
                rep.skip(reason, n)
            if src.truncated:
                rep.truncated = True
                rep.warn(f"the input is cut short ({src.detail}); every whole packet before "
                         "the cut was decoded")


def decode_file(path: str | os.PathLike, config: DecodeConfig | None = None,
                ports: set[int] | None = None,
                batch_decoder: BatchDecoderFactory = NativeVlp16Decoder) -> DecodeRun:
    """Open any supported input (pcap, pcapng, raw payloads, tripod MCAP) for decoding.

    >>> run = decode_file("capture.pcap")
    >>> for frame in run: ...
    >>> run.report.summary()

    ``batch_decoder`` makes the decoder of the points (see :class:`FrameDecoder`).

    Raises
    ------
    FileNotFoundError, SourceError
        Missing or unreadable input (raised here, before any frame).
    DecodeError
        Wrong sensor or no data packets (raised while iterating).
    """
    return DecodeRun(open_source(path, ports), FrameDecoder(config, batch_decoder))


__all__ = [
    "POINT_DTYPE", "DecodeConfig", "DecodeError", "DecodeReport", "DecodeRun", "Frame",
    "FrameDecoder",
    "Gap", "PositionReport", "SourceError", "decode_file", "identify_sensor", "to_veloview_xyz",
]
