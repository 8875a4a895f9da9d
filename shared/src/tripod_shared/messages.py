# SPDX-License-Identifier: BSD-3-Clause
"""Message types recorded to MCAP and published over Zenoh, with their encodings.

Binary messages are ROS 2 messages in CDR with their ``ros2msg`` definitions embedded in the
MCAP schema records, so Foxglove and ``ros2 bag`` read a recording without tripod's code:

* ``velodyne_msgs/msg/VelodynePacket`` (ROS 2 velodyne driver's type) — a 1206-byte data packet,
  verbatim; ``stamp`` is the host receive time. The lidar's own time is inside the payload
  (``data[1200:1204]``, uint32 µs past the hour; ``tripod_shared.velodyne.data_timestamp_us``).
* ``tripod_msgs/msg/VelodynePositionPacket`` — a 512-byte position packet, verbatim.
* ``tripod_msgs/msg/ImuQuaternion`` — one IMU orientation sample (q_world_imu), host stamp at the
  read, the device's own time where it gives one, and the raw frame bytes as read.

Status and events are JSON (``json`` message encoding with a JSON Schema).
"""

from __future__ import annotations

import json
import struct
from dataclasses import asdict, dataclass, field

from .cdr import ENCAPSULATION_CDR_LE, CdrReader, CdrWriter
from .timebase import NO_DEVICE_TIME, ns_to_sec_nsec, sec_nsec_to_ns
from .velodyne import DATA_PACKET_SIZE, POSITION_PACKET_SIZE

# ---- definitions (ros2msg text, as embedded in MCAP schemas) -------------------------------
TIME_MSGDEF = "================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"

VELODYNE_PACKET_TYPE = "velodyne_msgs/msg/VelodynePacket"
VELODYNE_PACKET_MSGDEF = (
    "# Raw Velodyne data packet (UDP payload of port 2368), verbatim.\n"
    "# stamp: host receive time (CLOCK_REALTIME, kernel SO_TIMESTAMPNS).\n"
    "builtin_interfaces/Time stamp\n"
    f"uint8[{DATA_PACKET_SIZE}] data\n" + TIME_MSGDEF
)

POSITION_PACKET_TYPE = "tripod_msgs/msg/VelodynePositionPacket"
POSITION_PACKET_MSGDEF = (
    "# Raw Velodyne position packet (UDP payload of port 8308), verbatim.\n"
    "# stamp: host receive time (CLOCK_REALTIME, kernel SO_TIMESTAMPNS).\n"
    "builtin_interfaces/Time stamp\n"
    f"uint8[{POSITION_PACKET_SIZE}] data\n" + TIME_MSGDEF
)

IMU_QUATERNION_TYPE = "tripod_msgs/msg/ImuQuaternion"
IMU_QUATERNION_MSGDEF = (
    "# One IMU orientation sample, q_world_imu (normalised, Hamilton, w first).\n"
    "# stamp: host time right after the read that completed the frame (CLOCK_REALTIME).\n"
    "builtin_interfaces/Time stamp\n"
    "# the IMU's own clock [ns]; -1 when the device gives none (TFP callbacks carry none)\n"
    "int64 device_time_ns\n"
    "float64 w\nfloat64 x\nfloat64 y\nfloat64 z\n"
    "# driver that framed it: 'tfp' (Tinkerforge IMU Brick 2.0) or 'witmotion'\n"
    "string driver\n"
    "# TFP sequence number (0 for callbacks), or 0\n"
    "uint8 sequence\n"
    "# the frame bytes exactly as read from the line\n"
    "uint8[] raw\n" + TIME_MSGDEF
)

STATUS_SCHEMA_NAME = "tripod.Status"
EVENT_SCHEMA_NAME = "tripod.Event"
STATUS_JSON_SCHEMA = {
    "type": "object",
    "title": "tripod daemon status (once a second)",
    "properties": {
        "host_time_ns": {"type": "integer", "description": "host_realtime"},
        "recording": {"type": "boolean"},
        "file": {"type": ["string", "null"]},
        "counts": {"type": "object", "description": "cumulative counters by name"},
        "rates": {"type": "object", "description": "per-second rates by name"},
        "state": {"type": "string"},
        "message": {"type": "string"},
        "clocks": {"type": "object", "description": "device clock estimates by device"},
        "disk": {"type": "object", "description": "recording disk: free_bytes, min_free_bytes, "
                 "file_bytes, file_started_ns (host_realtime)"},
    },
}
EVENT_JSON_SCHEMA = {
    "type": "object",
    "title": "tripod recording event",
    "properties": {
        "host_time_ns": {"type": "integer", "description": "host_realtime"},
        "kind": {"type": "string", "enum": ["start", "stop", "mark"]},
        "label": {"type": "string"},
    },
    "required": ["host_time_ns", "kind"],
}

_HDR = ENCAPSULATION_CDR_LE
_TIME = struct.Struct("<iI")
_PKT_OFFSET = 4 + _TIME.size  # payload starts after encapsulation + Time
PACKET_PAYLOAD_OFFSET = _PKT_OFFSET  # of a Velodyne(Position)Packet's CDR bytes [B]


# ---- lidar packets --------------------------------------------------------------------------
def encode_velodyne_packet(host_ns: int, payload: bytes) -> bytes:
    """CDR of a VelodynePacket (fixed 1206-byte array: no length prefix)."""
    if len(payload) != DATA_PACKET_SIZE:
        raise ValueError(f"data packet must be {DATA_PACKET_SIZE} bytes, got {len(payload)}")
    return _HDR + _TIME.pack(*ns_to_sec_nsec(host_ns)) + bytes(payload)


def encode_position_packet(host_ns: int, payload: bytes) -> bytes:
    if len(payload) != POSITION_PACKET_SIZE:
        raise ValueError(f"position packet must be {POSITION_PACKET_SIZE} bytes, got {len(payload)}")
    return _HDR + _TIME.pack(*ns_to_sec_nsec(host_ns)) + bytes(payload)


def decode_raw_packet(data: bytes, size: int) -> tuple[int, bytes]:
    """(host_ns, payload) of an encoded VelodynePacket / VelodynePositionPacket."""
    if len(data) < _PKT_OFFSET + size or data[1] != 0x01:
        raise ValueError("truncated or non-CDR packet message")
    sec, nsec = _TIME.unpack_from(data, 4)
    return sec_nsec_to_ns(sec, nsec), bytes(data[_PKT_OFFSET : _PKT_OFFSET + size])


def decode_velodyne_packet(data: bytes) -> tuple[int, bytes]:
    return decode_raw_packet(data, DATA_PACKET_SIZE)


def decode_position_packet(data: bytes) -> tuple[int, bytes]:
    return decode_raw_packet(data, POSITION_PACKET_SIZE)


# ---- IMU ------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ImuSample:
    """One orientation sample. ``host_ns``: host_realtime at the read; ``q_world_imu``: w,x,y,z."""

    host_ns: int
    w: float
    x: float
    y: float
    z: float
    device_time_ns: int = NO_DEVICE_TIME
    driver: str = "tfp"
    sequence: int = 0
    raw: bytes = b""

    @property
    def q_world_imu(self) -> tuple[float, float, float, float]:
        return (self.w, self.x, self.y, self.z)


def encode_imu(s: ImuSample) -> bytes:
    w = CdrWriter()
    sec, nsec = ns_to_sec_nsec(s.host_ns)
    w.int32(sec)
    w.uint32(nsec)
    w.int64(s.device_time_ns)
    for c in (s.w, s.x, s.y, s.z):
        w.float64(c)
    w.string(s.driver)
    w.uint8(s.sequence)
    w.byte_sequence(s.raw)
    return w.getvalue()


def decode_imu(data: bytes) -> ImuSample:
    r = CdrReader(data)
    host_ns = sec_nsec_to_ns(r.int32(), r.uint32())
    device_ns = r.int64()
    wq, xq, yq, zq = r.float64(), r.float64(), r.float64(), r.float64()
    driver = r.string()
    seq = r.uint8()
    raw = r.byte_sequence()
    return ImuSample(host_ns, wq, xq, yq, zq, device_ns, driver, seq, raw)


# ---- status / events (JSON) -----------------------------------------------------------------
@dataclass(slots=True)
class Event:
    host_ns: int
    kind: str  # start | stop | mark
    label: str = ""


def encode_event(e: Event) -> bytes:
    return json.dumps({"host_time_ns": e.host_ns, "kind": e.kind, "label": e.label}).encode()


def decode_event(data: bytes) -> Event:
    d = json.loads(data)
    return Event(int(d["host_time_ns"]), str(d["kind"]), str(d.get("label", "")))


@dataclass(slots=True)
class Status:
    host_ns: int
    state: str = "running"
    recording: bool = False
    file: str | None = None
    counts: dict = field(default_factory=dict)
    rates: dict = field(default_factory=dict)
    message: str = ""
    clocks: dict = field(default_factory=dict)  # device -> clock estimate (offset, drift, ...)
    disk: dict = field(default_factory=dict)  # free_bytes, min_free_bytes, file_bytes, ...

    def to_dict(self) -> dict:
        d = asdict(self)
        d["host_time_ns"] = d.pop("host_ns")
        return d


def encode_status(s: Status) -> bytes:
    return json.dumps(s.to_dict(), sort_keys=True).encode()


def decode_status(data: bytes) -> Status:
    d = json.loads(data)
    return Status(
        int(d["host_time_ns"]), d.get("state", ""), bool(d.get("recording", False)), d.get("file"),
        dict(d.get("counts", {})), dict(d.get("rates", {})), d.get("message", ""),
        dict(d.get("clocks", {})), dict(d.get("disk", {})),
    )
