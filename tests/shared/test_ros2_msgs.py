# SPDX-License-Identifier: BSD-3-Clause
"""ROS 2 message encoders of ``tripod_shared.ros2_msgs`` checked by an independent CDR
deserialiser: rosbags' typestore (standard types from its ROS 2 Humble store; our own types from
the ``ros2msg`` text we embed) and mcap-ros2-support on the embedded definitions."""

from __future__ import annotations

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from tripod_shared import ros2_msgs as r2
from tripod_shared.messages import Event, Status


def _packet(k: int) -> bytes:
    return bytes((k * 7 + i) & 0xFF for i in range(1206))


@pytest.fixture(scope="module")
def store():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    types.update(get_types_from_msg(r2.VELODYNE_SCAN_MSGDEF, r2.VELODYNE_SCAN_TYPE))
    types.update(get_types_from_msg(r2.EVENT_MSGDEF, r2.EVENT_TYPE))
    ts.register(types)
    return ts


def test_velodyne_scan_byte_exact(store):
    pk = [(1_700_000_000_000_000_000 + 1327_000 * k, _packet(k)) for k in range(5)]
    data = r2.encode_velodyne_scan(1_700_000_000_002_000_000, "velodyne", pk)
    msg = store.deserialize_cdr(data, r2.VELODYNE_SCAN_TYPE)
    assert msg.header.frame_id == "velodyne"
    assert msg.header.stamp.sec == 1_700_000_000 and msg.header.stamp.nanosec == 2_000_000
    assert len(msg.packets) == 5
    for (t, p), m in zip(pk, msg.packets):
        assert m.stamp.sec * 10**9 + m.stamp.nanosec == t
        assert bytes(m.data) == p
    assert r2.decode_velodyne_scan(data) == (1_700_000_000_002_000_000, "velodyne", pk)
    # the serialiser of the typestore writes the same bytes
    assert bytes(store.serialize_cdr(msg, r2.VELODYNE_SCAN_TYPE)) == data


def test_imu_and_tf_match_the_standard_definitions(store):
    data = r2.encode_imu_orientation(1_234_567_890_123_456_789, "imu", (0.5, 0.5, -0.5, 0.5))
    m = store.deserialize_cdr(data, r2.IMU_TYPE)  # the store's own sensor_msgs/Imu
    assert (m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z) == \
        (0.5, 0.5, -0.5, 0.5)
    assert m.angular_velocity_covariance[0] == -1 and m.linear_acceleration_covariance[0] == -1
    assert m.header.frame_id == "imu" and m.header.stamp.nanosec == 123_456_789
    tf = r2.encode_tf_message([(5 * 10**9, "imu", "velodyne", (0.0, 0.05, 0.12),
                                (0.9, 0.1, 0.2, 0.3))])
    t = store.deserialize_cdr(tf, r2.TF_MESSAGE_TYPE).transforms[0]
    assert t.header.frame_id == "imu" and t.child_frame_id == "velodyne"
    assert (t.transform.translation.y, t.transform.rotation.w) == (0.05, 0.9)


def test_status_as_diagnostic_array_round_trip(store):
    s = Status(1_700_000_000_500_000_000, state="running", recording=True,
               file="/data/tripod_20261126T060000Z.mcap",
               counts={"lidar_packets": 75412, "imu_samples": 9000, "lidar_drops": 0},
               rates={"lidar_packets": 753.9, "imu_samples": 100.0}, message="ok",
               clocks={"lidar": {"offset_ms": 0.3, "drift_ppm": -1.5}})
    data = r2.encode_status_diagnostics(s, hardware_id="tripod0")
    m = store.deserialize_cdr(data, r2.DIAGNOSTIC_ARRAY_TYPE)  # the standard type
    st = m.status[0]
    assert st.name == r2.DIAGNOSTIC_NAME and st.level == r2.DIAG_OK
    assert st.hardware_id == "tripod0" and st.message == "ok"
    kv = {v.key: v.value for v in st.values}
    assert kv["counts.lidar_packets"] == "75412" and kv["recording"] == "true"
    assert r2.decode_status_diagnostics(data) == s
    warn = r2.encode_status_diagnostics(Status(1, state="degraded"))
    assert store.deserialize_cdr(warn, r2.DIAGNOSTIC_ARRAY_TYPE).status[0].level == r2.DIAG_WARN


def test_event_round_trip(store):
    e = Event(1_700_000_001_000_000_001, "mark", "station 3 — hall")
    data = r2.encode_event_cdr(e)
    m = store.deserialize_cdr(data, r2.EVENT_TYPE)
    assert (m.kind, m.label, m.stamp.nanosec) == ("mark", "station 3 — hall", 1)
    assert r2.decode_event_cdr(data) == e


def test_definitions_parse_with_mcap_ros2_support():
    from mcap_ros2._dynamic import generate_dynamic

    for name, text in ((r2.VELODYNE_SCAN_TYPE, r2.VELODYNE_SCAN_MSGDEF),
                       (r2.IMU_TYPE, r2.IMU_MSGDEF), (r2.TF_MESSAGE_TYPE, r2.TF_MESSAGE_MSGDEF),
                       (r2.DIAGNOSTIC_ARRAY_TYPE, r2.DIAGNOSTIC_ARRAY_MSGDEF),
                       (r2.EVENT_TYPE, r2.EVENT_MSGDEF)):
        assert generate_dynamic(name, text)
    dec = generate_dynamic(r2.VELODYNE_SCAN_TYPE, r2.VELODYNE_SCAN_MSGDEF)[r2.VELODYNE_SCAN_TYPE]
    msg = dec(r2.encode_velodyne_scan(7, "velodyne", [(8, _packet(1))]))
    assert bytes(msg.packets[0].data) == _packet(1)
    assert msg.header.frame_id == "velodyne" and msg.packets[0].stamp.nanosec == 8
