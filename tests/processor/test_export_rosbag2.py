# SPDX-License-Identifier: BSD-3-Clause
"""``tripod export rosbag2``: a recording as a rosbag2 folder, read back with ``rosbags`` (an
independent rosbag2/MCAP reader and CDR deserialiser): every packet byte-exact, one
VelodyneScan per rotation, every IMU sample, the mount on /tf_static."""

from __future__ import annotations

import numpy as np
import pytest
from recon_synth import synth_capture
from rosbags.highlevel import AnyReader
from tripod_processor.cli import main
from tripod_processor.export.rosbag2 import packet_azimuth_cdeg
from tripod_shared import messages as m
from tripod_shared import topics as t
from tripod_shared.recording import RecordingReader


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    path = tmp_path_factory.mktemp("rb") / "rec.mcap"
    truth = synth_capture(path, stations=((2.0, 1.5, 0.0), (3.5, 1.5, 30.0)), station_s=1.5,
                          carry_s=1.0)
    return path, truth


def _recorded(path):
    """Packets and IMU samples straight from the recording (tripod's reader)."""
    reader = RecordingReader(path)
    pk, imu = [], []
    for msg in reader.messages([t.TOPIC_LIDAR_PACKETS, t.TOPIC_IMU]):
        if msg.topic == t.TOPIC_LIDAR_PACKETS:
            pk.append(m.decode_velodyne_packet(msg.data))
        else:
            imu.append(m.decode_imu(msg.data))
    return pk, imu


def _stamp(s) -> int:
    return s.sec * 10**9 + s.nanosec


def test_rosbag2_folder_reads_back_byte_exact(capture, tmp_path):
    path, truth = capture
    out = tmp_path / "bag"
    calib = tmp_path / "calib.yaml"
    calib.write_text("q_imu_lidar: [0.9659258, 0.2588190, 0.0, 0.0]\n"
                     "lever_arm_m: [0.0, 0.05, 0.12]\n")
    assert main(["export", "rosbag2", str(path), "-o", str(out), "--calibration",
                 str(calib)]) == 0
    assert (out / "metadata.yaml").is_file() and len(list(out.glob("*.mcap"))) == 1
    packets, imu = _recorded(path)
    assert len(packets) > 1000 and len(imu) > 100
    scans, got_imu, tf = [], [], []
    with AnyReader([out]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {"/velodyne_packets": "velodyne_msgs/msg/VelodyneScan",
                         "/imu/data": "sensor_msgs/msg/Imu",
                         "/tf_static": "tf2_msgs/msg/TFMessage"}
        last = -1
        for conn, log_ns, raw in reader.messages():
            assert log_ns >= last  # time-ordered
            last = log_ns
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/velodyne_packets":
                scans.append(msg)
                # stamped and logged at its last packet, as the ROS 2 driver publishes
                assert log_ns == _stamp(msg.packets[-1].stamp) == _stamp(msg.header.stamp)
            elif conn.topic == "/imu/data":
                got_imu.append(msg)
            else:
                tf.append(msg)
    # every packet, in order, byte-exact, with its host stamp
    flat = [(_stamp(p.stamp), bytes(p.data)) for s in scans for p in s.packets]
    assert len(flat) == len(packets)
    assert flat == packets
    # one scan per rotation: azimuth increases inside a scan and wraps between scans
    rpm_packets = []
    for s in scans:
        az = packet_azimuth_cdeg(np.stack([np.frombuffer(bytes(p.data), np.uint8)
                                           for p in s.packets]))
        assert np.all(np.diff(az) >= 0)
        rpm_packets.append(len(s.packets))
        assert s.header.frame_id == "velodyne"
    # 600 rpm, 754 packets/s: ~75 packets a rotation (the first and last may be partial)
    assert 74 <= np.median(rpm_packets) <= 77
    assert len(scans) == pytest.approx(len(packets) / 75.4, abs=2)
    # every IMU sample, its stamp and orientation
    assert len(got_imu) == len(imu)
    for g, s in zip(got_imu, imu):
        assert _stamp(g.header.stamp) == s.host_ns and g.header.frame_id == "imu"
        q = np.array([g.orientation.w, g.orientation.x, g.orientation.y, g.orientation.z])
        np.testing.assert_allclose(q, np.array(s.q_world_imu) / np.linalg.norm(s.q_world_imu),
                                   atol=1e-12)
    # the mount, latched
    assert len(tf) == 1 and len(tf[0].transforms) == 1
    tr = tf[0].transforms[0]
    assert (tr.header.frame_id, tr.child_frame_id) == ("imu", "velodyne")
    assert tr.transform.translation.z == pytest.approx(0.12)
    assert tr.transform.rotation.x == pytest.approx(0.2588190, abs=1e-6)
    with AnyReader([out]) as reader:
        qos = [c.ext.offered_qos_profiles for c in reader.connections
               if c.topic == "/tf_static"][0]
        assert qos and qos[0].durability.name == "TRANSIENT_LOCAL"


def test_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"garbage" * 10)
    assert main(["export", "rosbag2", str(bad), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tripod: error:")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "f").write_text("x")
    assert main(["export", "rosbag2", str(bad), "-o", str(tmp_path / "full")]) == 2
