# SPDX-License-Identifier: BSD-3-Clause
"""A daemon recording read by ``rosbags`` (an independent ROS 2 bag reader and CDR deserialiser).

Recordings are MCAP profile ``ros2`` (format 2, issue 14): every channel CDR with a ``ros2msg``
schema, status as ``diagnostic_msgs/msg/DiagnosticArray`` and events as
``tripod_msgs/msg/Event``. rosbags' MCAP storage reader opens the daemon's file as written and
gets every packet byte-exact; deserialised from the definitions in the file, every IMU sample,
the status and the events (start, the station mark, stop) are there."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.storage_mcap import McapReader
from tripod_shared import messages as m
from tripod_shared import ros2_msgs as r2
from tripod_shared import tfp
from tripod_shared import topics as t
from tripod_shared.recording import RecordingReader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from daemon_helpers import (  # noqa: E402
    FakePty,
    RunningDaemon,
    loopback_config,
    make_data_packet,
    send_paced,
    udp_sender,
)

N_PACKETS = 600
N_IMU = 40


@pytest.fixture(scope="module")
def daemon_recording(tmp_path_factory):
    """A recording made by a running daemon on loopback: data packets, IMU samples over a
    pty, a station mark, start/stop events and status."""
    tmp = tmp_path_factory.mktemp("daemon_rec")
    dev = FakePty(tmp / "tripod-imu")
    cfg = loopback_config(tmp, imu={"url": str(dev.link), "reconnect_interval_s": 0.2})
    uid = 0x2B3C4D
    try:
        with RunningDaemon(cfg) as d:
            c = d.daemon.counts
            assert d.wait_for(lambda: d.daemon.imu.connected)
            dev.read_available(0.3)
            dev.write(tfp.encode_enumerate_callback(uid))
            for k in range(N_IMU):
                a = 0.01 * k
                dev.write(tfp.encode_quaternion_callback(uid, 1.0 - a * a / 2, a, 0.0, 0.0))
            assert d.wait_for(lambda: c["imu_samples"] == N_IMU)
            send_paced(udp_sender(), d.data_addr, [make_data_packet(i) for i in range(N_PACKETS)],
                       3000.0)
            assert d.wait_for(lambda: c["lidar_data"] >= N_PACKETS)
            assert d.daemon.control("mark", "station A")["ok"] is not False
            assert d.stop() == 0
    finally:
        dev.close()
    files = d.daemon.recorder.files
    assert len(files) == 1
    return Path(files[0])


def test_rosbags_reads_a_daemon_recording(daemon_recording, tmp_path):
    from tripod_processor.io.rosbag2 import Rosbag2Writer

    ros2 = daemon_recording
    # 1. the bare MCAP through rosbags' MCAP storage reader (it refuses any profile but ros2)
    reader = McapReader(ros2)
    reader.open()
    try:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            t.TOPIC_LIDAR_PACKETS: m.VELODYNE_PACKET_TYPE, t.TOPIC_IMU: m.IMU_QUATERNION_TYPE,
            t.TOPIC_STATUS: r2.DIAGNOSTIC_ARRAY_TYPE, t.TOPIC_EVENTS: r2.EVENT_TYPE}
        by_topic: dict[str, list[bytes]] = {}
        for conn, _ns, raw in reader.messages(reader.connections):
            by_topic.setdefault(conn.topic, []).append(raw)
    finally:
        reader.close()
    pk = [m.decode_velodyne_packet(x)[1] for x in by_topic[t.TOPIC_LIDAR_PACKETS]]
    assert pk == [make_data_packet(i) for i in range(N_PACKETS)]  # every packet, byte-exact
    # 2. as a rosbag2 folder (the same MCAP messages and schemas), deserialised by rosbags from
    # the definitions in the file
    bag = tmp_path / "bag"
    with open(ros2, "rb") as fh, Rosbag2Writer(bag) as w:
        for schema, channel, msg in make_reader(fh).iter_messages():
            if channel.topic not in w._topics:
                w.add_topic(channel.topic, schema.name, schema.data.decode())
            w.write(channel.topic, msg.log_time, msg.data)
    ours = list(RecordingReader(daemon_recording).imu_samples())
    assert len(ours) == N_IMU
    imu, status, events, packets = [], [], [], []
    with AnyReader([bag]) as ar:
        for conn, _ns, raw in ar.messages():
            msg = ar.deserialize(raw, conn.msgtype)
            if conn.topic == t.TOPIC_IMU:
                imu.append(msg)
            elif conn.topic == t.TOPIC_STATUS:
                status.append(msg)
            elif conn.topic == t.TOPIC_EVENTS:
                events.append(msg)
            elif conn.topic == t.TOPIC_LIDAR_PACKETS:
                packets.append(bytes(msg.data))
    assert packets == [make_data_packet(i) for i in range(N_PACKETS)]
    assert len(imu) == N_IMU  # every IMU sample
    for g, s in zip(imu, ours):
        assert (g.w, g.x, g.y, g.z) == (s.w, s.x, s.y, s.z) and bytes(g.raw) == s.raw
        assert g.stamp.sec * 10**9 + g.stamp.nanosec == s.host_ns
    assert status and status[-1].status[0].name == r2.DIAGNOSTIC_NAME
    values = {kv.key: kv.value for kv in status[-1].status[0].values}
    assert values["state"] in ('"recording"', '"idle"') and "counts.lidar_data" in values
    kinds = [(e.kind, e.label) for e in events]
    assert kinds[0][0] == "start" and ("mark", "station A") in kinds and kinds[-1][0] == "stop"
