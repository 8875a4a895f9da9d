# SPDX-License-Identifier: BSD-3-Clause
"""Standard ROS 2 messages tripod writes (``ros2msg`` definitions + CDR encoders/decoders).

Used by ``tripod export rosbag2`` (VelodyneScan, Imu, TFMessage) and by recordings (MCAP
``ros2`` profile, every channel CDR, format version 2), where status becomes
``diagnostic_msgs/msg/DiagnosticArray`` (the ROS convention for health) and events
``tripod_msgs/msg/Event``:

* :func:`encode_status_diagnostics` / :func:`decode_status_diagnostics`: a
  :class:`~tripod_shared.messages.Status` as one ``DiagnosticStatus`` named
  :data:`DIAGNOSTIC_NAME`; its fields as key/value strings (JSON values), lossless.
* :func:`encode_event_cdr` / :func:`decode_event_cdr`: an
  :class:`~tripod_shared.messages.Event` as ``tripod_msgs/msg/Event``.

Definitions are the concatenated form ROS 2 writes into MCAP schemas and rosbag2 (each
dependency after a ``=====`` line and ``MSG: pkg/Type``).
"""

from __future__ import annotations

import json

from . import messages as m
from .cdr import CdrReader, CdrWriter
from .timebase import ns_to_sec_nsec, sec_nsec_to_ns
from .velodyne import DATA_PACKET_SIZE

_SEP = "=" * 80 + "\n"


def _dep(name: str, text: str) -> str:
    return f"{_SEP}MSG: {name}\n{text}"


TIME_DEF = "int32 sec\nuint32 nanosec\n"
HEADER_DEF = "builtin_interfaces/Time stamp\nstring frame_id\n"
QUATERNION_DEF = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
VECTOR3_DEF = "float64 x\nfloat64 y\nfloat64 z\n"
TRANSFORM_DEF = "Vector3 translation\nQuaternion rotation\n"
TRANSFORM_STAMPED_DEF = "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"
VELODYNE_PACKET_DEF = f"builtin_interfaces/Time stamp\nuint8[{DATA_PACKET_SIZE}] data\n"

VELODYNE_SCAN_TYPE = "velodyne_msgs/msg/VelodyneScan"
VELODYNE_SCAN_MSGDEF = (
    "# Velodyne LIDAR scan packets (one rotation), as the ROS velodyne driver publishes.\n"
    "std_msgs/Header header\nVelodynePacket[] packets\n"
    + _dep("std_msgs/Header", HEADER_DEF) + _dep("builtin_interfaces/Time", TIME_DEF)
    + _dep("velodyne_msgs/VelodynePacket", VELODYNE_PACKET_DEF))

IMU_TYPE = "sensor_msgs/msg/Imu"
IMU_MSGDEF = (
    "std_msgs/Header header\n"
    "geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n"
    "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
    "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n"
    + _dep("std_msgs/Header", HEADER_DEF) + _dep("builtin_interfaces/Time", TIME_DEF)
    + _dep("geometry_msgs/Quaternion", QUATERNION_DEF)
    + _dep("geometry_msgs/Vector3", VECTOR3_DEF))

TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"
TF_MESSAGE_MSGDEF = (
    "geometry_msgs/TransformStamped[] transforms\n"
    + _dep("geometry_msgs/TransformStamped", TRANSFORM_STAMPED_DEF)
    + _dep("std_msgs/Header", HEADER_DEF) + _dep("builtin_interfaces/Time", TIME_DEF)
    + _dep("geometry_msgs/Transform", TRANSFORM_DEF)
    + _dep("geometry_msgs/Vector3", VECTOR3_DEF)
    + _dep("geometry_msgs/Quaternion", QUATERNION_DEF))

DIAGNOSTIC_ARRAY_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTIC_STATUS_DEF = (
    "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n"
    "byte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n")
DIAGNOSTIC_ARRAY_MSGDEF = (
    "std_msgs/Header header\nDiagnosticStatus[] status\n"
    + _dep("std_msgs/Header", HEADER_DEF) + _dep("builtin_interfaces/Time", TIME_DEF)
    + _dep("diagnostic_msgs/DiagnosticStatus", DIAGNOSTIC_STATUS_DEF)
    + _dep("diagnostic_msgs/KeyValue", "string key\nstring value\n"))

EVENT_TYPE = "tripod_msgs/msg/Event"
EVENT_MSGDEF = (
    "# A recording event of the tripod daemon.\n"
    "# stamp: host time of the event (CLOCK_REALTIME).\n"
    "builtin_interfaces/Time stamp\n"
    "# start | stop | mark\nstring kind\n"
    "# mark: the operator's station label; start/stop: the reason\nstring label\n"
    + _dep("builtin_interfaces/Time", TIME_DEF))

#: name of the one DiagnosticStatus a daemon status becomes
DIAGNOSTIC_NAME = "tripod: daemon"
DIAG_OK, DIAG_WARN, DIAG_ERROR, DIAG_STALE = 0, 1, 2, 3
# daemon states (shared/README.md) -> DiagnosticStatus level; unknown states: WARN
_LEVELS = {"recording": DIAG_OK, "idle": DIAG_OK, "running": DIAG_OK, "ok": DIAG_OK,
           "stopped": DIAG_WARN, "degraded": DIAG_WARN, "warn": DIAG_WARN,
           "error": DIAG_ERROR}


_GROUPS = ("counts", "rates", "clocks", "disk")  # Status dict fields, one key/value each


def _time(w: CdrWriter, t_ns: int) -> None:
    sec, nsec = ns_to_sec_nsec(int(t_ns))
    w.int32(sec)
    w.uint32(nsec)


def _header(w: CdrWriter, t_ns: int, frame_id: str) -> None:
    _time(w, t_ns)
    w.string(frame_id)


def _read_time(r: CdrReader) -> int:
    return sec_nsec_to_ns(r.int32(), r.uint32())


# ---- velodyne_msgs/msg/VelodyneScan -----------------------------------------------------------
def encode_velodyne_scan(stamp_ns: int, frame_id: str,
                         packets: list[tuple[int, bytes]]) -> bytes:
    """CDR of a VelodyneScan: header + (stamp_ns, 1206-byte payload) packets."""
    w = CdrWriter()
    _header(w, stamp_ns, frame_id)
    w.uint32(len(packets))
    for t_ns, payload in packets:
        if len(payload) != DATA_PACKET_SIZE:
            raise ValueError(f"data packet must be {DATA_PACKET_SIZE} bytes, got {len(payload)}")
        _time(w, t_ns)
        w.fixed_bytes(payload)
    return w.getvalue()


def decode_velodyne_scan(data: bytes) -> tuple[int, str, list[tuple[int, bytes]]]:
    r = CdrReader(data)
    stamp = _read_time(r)
    frame = r.string()
    n = r.uint32()
    pk = [(_read_time(r), r.fixed_bytes(DATA_PACKET_SIZE)) for _ in range(n)]
    return stamp, frame, pk


# ---- sensor_msgs/msg/Imu ----------------------------------------------------------------------
def encode_imu_orientation(stamp_ns: int, frame_id: str, q_wxyz, orientation_var: float = -1.0
                           ) -> bytes:
    """CDR of a sensor_msgs/Imu carrying only the orientation (q_world_imu, w, x, y, z).

    Angular velocity and linear acceleration are absent: their covariance[0] is -1 (REP 145).
    ``orientation_var`` [rad²] on the covariance diagonal; < 0: unknown (all zero).
    """
    w = CdrWriter()
    _header(w, stamp_ns, frame_id)
    qw, qx, qy, qz = (float(v) for v in q_wxyz)
    for v in (qx, qy, qz, qw):
        w.float64(v)
    cov = [0.0] * 9
    if orientation_var >= 0:
        cov[0] = cov[4] = cov[8] = float(orientation_var)
    for v in cov:
        w.float64(v)
    for _ in range(2):  # angular_velocity, linear_acceleration: absent
        for _ in range(3):
            w.float64(0.0)
        w.float64(-1.0)
        for _ in range(8):
            w.float64(0.0)
    return w.getvalue()


# ---- tf2_msgs/msg/TFMessage ---------------------------------------------------------------------
def encode_tf_message(transforms: list[tuple[int, str, str, tuple, tuple]]) -> bytes:
    """CDR of a TFMessage of (stamp_ns, parent, child, translation xyz [m], rotation wxyz)."""
    w = CdrWriter()
    w.uint32(len(transforms))
    for t_ns, parent, child, xyz, q_wxyz in transforms:
        _header(w, t_ns, parent)
        w.string(child)
        for v in xyz:
            w.float64(float(v))
        qw, qx, qy, qz = (float(v) for v in q_wxyz)
        for v in (qx, qy, qz, qw):
            w.float64(v)
    return w.getvalue()


# ---- diagnostic_msgs/msg/DiagnosticArray (daemon status) -----------------------------------------
def encode_status_diagnostics(s: m.Status, hardware_id: str = "tripod") -> bytes:
    """CDR of a DiagnosticArray holding the status as one DiagnosticStatus.

    level from ``state`` (recording/idle: OK; stopped, e.g. disk full: WARN; error: ERROR;
    anything else WARN); values: ``state``, ``recording``, ``file`` and ``counts.<name>``,
    ``rates.<name>``, ``clocks.<device>``, ``disk.<name>`` with JSON-encoded values.
    """
    values = [("state", json.dumps(s.state)), ("recording", json.dumps(s.recording)),
              ("file", json.dumps(s.file))]
    for group in _GROUPS:
        for k, v in sorted(getattr(s, group).items()):
            values.append((f"{group}.{k}", json.dumps(v, sort_keys=True)))
    w = CdrWriter()
    _header(w, s.host_ns, "")
    w.uint32(1)
    w.uint8(_LEVELS.get(s.state, DIAG_WARN))
    w.string(DIAGNOSTIC_NAME)
    w.string(s.message)
    w.string(hardware_id)
    w.uint32(len(values))
    for k, v in values:
        w.string(k)
        w.string(v)
    return w.getvalue()


def decode_status_diagnostics(data: bytes) -> m.Status:
    """The :class:`Status` of :func:`encode_status_diagnostics` (other statuses ignored)."""
    r = CdrReader(data)
    host_ns = _read_time(r)
    r.string()
    out = m.Status(host_ns, state="")
    for _ in range(r.uint32()):
        r.uint8()
        name, message, _hw = r.string(), r.string(), r.string()
        kv = [(r.string(), r.string()) for _ in range(r.uint32())]
        if name != DIAGNOSTIC_NAME:
            continue
        out.message = message
        for k, v in kv:
            val = json.loads(v)
            group, _, key = k.partition(".")
            if group in _GROUPS and key:
                getattr(out, group)[key] = val
            elif k in ("state", "recording", "file"):
                setattr(out, k, val)
    return out


# ---- tripod_msgs/msg/Event --------------------------------------------------------------------
def encode_event_cdr(e: m.Event) -> bytes:
    w = CdrWriter()
    _time(w, e.host_ns)
    w.string(e.kind)
    w.string(e.label)
    return w.getvalue()


def decode_event_cdr(data: bytes) -> m.Event:
    r = CdrReader(data)
    return m.Event(_read_time(r), r.string(), r.string())
