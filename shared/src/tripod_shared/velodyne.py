# SPDX-License-Identifier: BSD-3-Clause
"""Velodyne VLP-16 UDP payload layouts (the bytes after the UDP header).

Only layout and cheap header checks live here: the daemon never decodes points, it checks size
and header and records the payload verbatim; the processor decodes with velodyne-decoder.

Data packet (1206 B, UDP port 2368)::

    12 x data block (100 B): bytes FF EE | uint16 azimuth [0.01 deg]
                             | 32 x (uint16 distance [2 mm], uint8 reflectivity)
    uint32 timestamp [us past the top of the hour, lidar_toh clock]
    uint8  return mode   0x37 strongest, 0x38 last, 0x39 dual
    uint8  product id    0x22 VLP-16 (early VLP-16 firmware: 0x21, like the HDL-32E)

Position (telemetry) packet (512 B, UDP port 8308)::

    187..197  temperatures and ADC calibration state
    198..201  uint32 timestamp [us past the hour]
    202       PPS status 0 absent, 1 synchronising, 2 locked, 3 error
    206..333  NMEA sentence (GPRMC or GPGGA), NUL padded
"""

from __future__ import annotations

import struct

DATA_PORT = 2368
POSITION_PORT = 8308

DATA_PACKET_SIZE = 1206
POSITION_PACKET_SIZE = 512

BLOCKS_PER_PACKET = 12
BLOCK_SIZE = 100
CHANNELS_PER_BLOCK = 32
LASERS = 16
BLOCK_FLAG_BYTES = b"\xff\xee"  # on the wire, first two bytes of each block
TIMESTAMP_OFFSET = 1200
RETURN_MODE_OFFSET = 1204
PRODUCT_ID_OFFSET = 1205

DISTANCE_UNIT_M = 0.002  # VLP-16 distance LSB [m]
AZIMUTH_UNIT_DEG = 0.01

#: VLP-16 firing timing [us]
FIRING_PERIOD_US = 2.304  # between lasers
SEQUENCE_PERIOD_US = 55.296  # between firing sequences (16 lasers + recharge)

RETURN_STRONGEST = 0x37
RETURN_LAST = 0x38
RETURN_DUAL = 0x39
RETURN_MODES = {RETURN_STRONGEST: "strongest", RETURN_LAST: "last", RETURN_DUAL: "dual"}

PRODUCT_HDL32E = 0x21
PRODUCT_VLP16 = 0x22
PRODUCT_PUCK_HIRES = 0x24
PRODUCT_VLP32C = 0x28
PRODUCT_VELARRAY = 0x31
PRODUCT_VLS128 = 0xA1
PRODUCTS = {
    PRODUCT_HDL32E: "HDL-32E",
    PRODUCT_VLP16: "VLP-16",
    PRODUCT_PUCK_HIRES: "Puck Hi-Res",
    PRODUCT_VLP32C: "VLP-32C",
    PRODUCT_VELARRAY: "Velarray",
    PRODUCT_VLS128: "VLS-128",
}

#: Packet period [us] by sensor and return mode; the way to tell a VLP-16 reporting 0x21 from
#: an HDL-32E (which sends a data packet every ~553 us).
VLP16_PACKET_PERIOD_US = {"single": 1327.104, "dual": 663.552}
HDL32E_PACKET_PERIOD_US = 552.96

# position packet
POS_TIMESTAMP_OFFSET = 198
POS_PPS_OFFSET = 202
POS_NMEA_OFFSET = 206
POS_NMEA_SIZE = 128
PPS_STATES = {0: "absent", 1: "synchronizing", 2: "locked", 3: "error"}

_u32 = struct.Struct("<I")
_FLAGS_FF = b"\xff" * BLOCKS_PER_PACKET
_FLAGS_EE = b"\xee" * BLOCKS_PER_PACKET


class PacketKind:
    """Classification of a UDP payload by cheap header checks (no decoding)."""

    DATA = "data"
    POSITION = "position"
    MALFORMED = "malformed"  # wrong size or bad block flags
    FOREIGN = "foreign"  # well-formed Velodyne packet of a sensor we do not record


def data_timestamp_us(payload: bytes) -> int:
    """Device time of a data packet: us past the top of the hour (lidar_toh clock)."""
    return _u32.unpack_from(payload, TIMESTAMP_OFFSET)[0]


def position_timestamp_us(payload: bytes) -> int:
    return _u32.unpack_from(payload, POS_TIMESTAMP_OFFSET)[0]


def return_mode_name(payload: bytes) -> str:
    return RETURN_MODES.get(payload[RETURN_MODE_OFFSET], f"unknown(0x{payload[RETURN_MODE_OFFSET]:02x})")


def product_name(product_id: int) -> str:
    return PRODUCTS.get(product_id, f"unknown(0x{product_id:02x})")


def check_data_packet(payload: bytes, accept_products=(PRODUCT_VLP16, PRODUCT_HDL32E)) -> str:
    """Classify a payload that arrived on the data port.

    Checks the size, the 12 block flags, the return-mode byte and the product byte. 0x21 is
    accepted by default because early VLP-16 firmware reports it; the processor tells the two
    apart by the packet period.
    """
    if len(payload) != DATA_PACKET_SIZE:
        return PacketKind.MALFORMED
    # the 12 block flags by two strided slices: one C-level compare each, not 24 Python ones
    # (this runs per packet in the daemon's receive path, ~30,000 times a second)
    if (
        payload[0:TIMESTAMP_OFFSET:BLOCK_SIZE] != _FLAGS_FF
        or payload[1:TIMESTAMP_OFFSET:BLOCK_SIZE] != _FLAGS_EE
    ):
        return PacketKind.MALFORMED
    if payload[RETURN_MODE_OFFSET] not in RETURN_MODES:
        return PacketKind.MALFORMED
    if payload[PRODUCT_ID_OFFSET] not in accept_products:
        return PacketKind.FOREIGN
    return PacketKind.DATA


def check_position_packet(payload: bytes) -> str:
    """Classify a payload that arrived on the position port (size and timestamp range)."""
    if len(payload) != POSITION_PACKET_SIZE:
        return PacketKind.MALFORMED
    if position_timestamp_us(payload) >= 3600 * 1_000_000:
        return PacketKind.MALFORMED
    return PacketKind.POSITION


def position_nmea(payload: bytes) -> str:
    """The NMEA sentence of a position packet ('' when none)."""
    raw = payload[POS_NMEA_OFFSET : POS_NMEA_OFFSET + POS_NMEA_SIZE]
    return raw.split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()


def position_pps_state(payload: bytes) -> str:
    return PPS_STATES.get(payload[POS_PPS_OFFSET], f"unknown({payload[POS_PPS_OFFSET]})")


class PacketGapCounter:
    """VLP-16 data packets missing from a stream, counted from the gaps in their device
    timestamps: what a live subscriber can count itself (Zenoh drops a slow subscriber's
    samples without telling the publisher). A gap of k packet periods (663.552 µs dual return,
    1327.104 µs single) is k - 1 missing packets; gaps over a second (a sensor restart, a
    pause) are not counted; the hour wrap of the µs-past-the-hour clock is handled."""

    _HOUR_US = 3600 * 1_000_000

    def __init__(self) -> None:
        self.packets = 0
        self.missing = 0
        self._last_us: int | None = None

    def add(self, payload: bytes) -> int:
        """Take the next packet's 1206-byte payload; returns the packets missing before it."""
        t_us = _u32.unpack_from(payload, TIMESTAMP_OFFSET)[0]
        period = VLP16_PACKET_PERIOD_US[
            "dual" if payload[RETURN_MODE_OFFSET] == RETURN_DUAL else "single"]
        last, self._last_us = self._last_us, t_us
        self.packets += 1
        if last is None:
            return 0
        dt = (t_us - last) % self._HOUR_US
        k = round(dt / period) - 1 if dt < 1_000_000 else 0
        if k > 0:
            self.missing += k
            return k
        return 0
