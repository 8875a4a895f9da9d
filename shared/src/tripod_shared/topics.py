# SPDX-License-Identifier: BSD-3-Clause
"""MCAP topic names and Zenoh key expressions: defined here once, used by daemon and processor.

Lidar and IMU Zenoh payloads are the same CDR bytes as the MCAP message data of the matching
topic (see ``messages``), so a live subscriber and a recording reader decode them with the same
code. Status and events are JSON on Zenoh (``messages.decode_status`` / ``decode_event``) and CDR
in recordings (``diagnostic_msgs/msg/DiagnosticArray``, ``tripod_msgs/msg/Event``): the recorder
converts them (``recording.RecordingWriter.write_encoded``).
"""

from __future__ import annotations

# --- MCAP topics ----------------------------------------------------------------------------
TOPIC_LIDAR_PACKETS = "/velodyne/packets"  # velodyne_msgs/msg/VelodynePacket (1206 B data)
TOPIC_LIDAR_POSITION = "/velodyne/position"  # tripod_msgs/msg/VelodynePositionPacket (512 B)
TOPIC_IMU = "/imu/quaternion"  # tripod_msgs/msg/ImuQuaternion
TOPIC_STATUS = "/tripod/status"  # once a second; diagnostic_msgs/msg/DiagnosticArray (Zenoh: JSON)
TOPIC_EVENTS = "/tripod/events"  # start/stop, station marks; tripod_msgs/msg/Event (Zenoh: JSON)

ALL_TOPICS = (TOPIC_LIDAR_PACKETS, TOPIC_LIDAR_POSITION, TOPIC_IMU, TOPIC_STATUS, TOPIC_EVENTS)

# --- Zenoh key expressions --------------------------------------------------------------------
KEY_ROOT = "tripod"
DEFAULT_DEVICE_ID = "tripod0"


def _key(device_id: str, leaf: str) -> str:
    if not device_id or any(c in device_id for c in "/*$?#"):
        raise ValueError(f"invalid device id for a Zenoh key: {device_id!r}")
    return f"{KEY_ROOT}/{device_id}/{leaf}"


def key_lidar_packets(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """Raw 1206-byte data packets, one CDR VelodynePacket per sample. Published only while
    someone subscribes to it; live consumers should take :func:`key_lidar_blocks`."""
    return _key(device_id, "lidar/packets")


def key_lidar_blocks(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """The data packets in blocks, many per sample (``tripod_shared.lidar_block``): the live
    lidar stream, at a per-sample cost a consumer can afford at any packet rate."""
    return _key(device_id, "lidar/blocks")


def key_lidar_position(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """Raw 512-byte position packets (CDR VelodynePositionPacket)."""
    return _key(device_id, "lidar/position")


def key_imu(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """IMU quaternion samples (CDR ImuQuaternion)."""
    return _key(device_id, "imu/quaternion")


def key_status(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """Status (JSON): published once a second, and a queryable answering on demand."""
    return _key(device_id, "status")


def key_events(device_id: str = DEFAULT_DEVICE_ID) -> str:
    """Recording events (JSON): start, stop, mark."""
    return _key(device_id, "events")


def key_control(device_id: str = DEFAULT_DEVICE_ID, command: str = "*") -> str:
    """Control queryables: ``control/start``, ``control/stop``, ``control/mark`` (label in the
    query parameters or payload)."""
    return _key(device_id, f"control/{command}")


CONTROL_COMMANDS = ("start", "stop", "mark")


def topic_for_key(key: str) -> str | None:
    """The MCAP topic a Zenoh key expression carries, or None."""
    parts = key.split("/", 2)
    if len(parts) < 3 or parts[0] != KEY_ROOT:
        return None
    return {
        "lidar/packets": TOPIC_LIDAR_PACKETS,
        "lidar/position": TOPIC_LIDAR_POSITION,
        "imu/quaternion": TOPIC_IMU,
        "status": TOPIC_STATUS,
        "events": TOPIC_EVENTS,
    }.get(parts[2])
