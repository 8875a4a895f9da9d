# SPDX-License-Identifier: BSD-3-Clause
"""A format version 1 recording, written here with the old layout (test helper).

Format 1 (before issue 14): MCAP profile ``""``; lidar and IMU channels CDR as today; status and
events JSON channels (``jsonschema`` schemas ``tripod.Status`` / ``tripod.Event``, the same JSON
the daemon publishes over Zenoh); metadata ``tripod`` with ``format_version`` ``1``.
"""

from __future__ import annotations

import json

from mcap.writer import Writer
from tripod_shared import messages as m
from tripod_shared import topics as t

V1_SCHEMAS = {
    t.TOPIC_LIDAR_PACKETS: (m.VELODYNE_PACKET_TYPE, "ros2msg", m.VELODYNE_PACKET_MSGDEF, "cdr"),
    t.TOPIC_LIDAR_POSITION: (m.POSITION_PACKET_TYPE, "ros2msg", m.POSITION_PACKET_MSGDEF, "cdr"),
    t.TOPIC_IMU: (m.IMU_QUATERNION_TYPE, "ros2msg", m.IMU_QUATERNION_MSGDEF, "cdr"),
    t.TOPIC_STATUS: ("tripod.Status", "jsonschema", json.dumps(m.STATUS_JSON_SCHEMA), "json"),
    t.TOPIC_EVENTS: ("tripod.Event", "jsonschema", json.dumps(m.EVENT_JSON_SCHEMA), "json"),
}


def write_v1(path, items) -> None:
    """Write ``items``: (host_ns, obj) with obj a ``(payload bytes, topic)`` lidar packet,
    an :class:`ImuSample`, an :class:`Event` or a :class:`Status`, in the version 1 layout."""
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=4096)
        w.start(profile="", library="tripod (format 1, test)")
        w.add_metadata("tripod", {"format_version": "1", "library": "tripod"})
        chans: dict[str, int] = {}
        seq: dict[str, int] = {}
        for ns, obj in items:
            if isinstance(obj, m.ImuSample):
                topic, data = t.TOPIC_IMU, m.encode_imu(obj)
            elif isinstance(obj, m.Event):
                topic, data = t.TOPIC_EVENTS, m.encode_event(obj)
            elif isinstance(obj, m.Status):
                topic, data = t.TOPIC_STATUS, m.encode_status(obj)
            else:
                payload, topic = obj
                enc = (m.encode_velodyne_packet if topic == t.TOPIC_LIDAR_PACKETS
                       else m.encode_position_packet)
                data = enc(ns, payload)
            if topic not in chans:
                name, sch_enc, text, msg_enc = V1_SCHEMAS[topic]
                sid = w.register_schema(name, sch_enc, text.encode())
                chans[topic] = w.register_channel(topic, msg_enc, sid)
            n = seq.get(topic, 0)
            seq[topic] = n + 1
            w.add_message(chans[topic], ns, data, ns, n)
        w.finish()
