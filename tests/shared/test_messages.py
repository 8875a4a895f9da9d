# SPDX-License-Identifier: BSD-3-Clause
"""Encodings of tripod_shared.messages: round trips and an independent decoder as oracle."""

import os

import pytest
from mcap_ros2.decoder import DecoderFactory
from mcap.reader import make_reader

from tripod_shared import messages as m
from tripod_shared import topics as t
from tripod_shared.recording import RecordingReader, RecordingWriter
from tripod_shared.velodyne import DATA_PACKET_SIZE, POSITION_PACKET_SIZE


def _payload(n, seed):
    return bytes((i * 7 + seed) % 256 for i in range(n))


def test_imu_round_trip():
    s = m.ImuSample(1_700_000_000_123_456_789, 0.5, -0.5, 0.5, -0.5, -1, "tfp", 0, b"\x01\x02\x03")
    assert m.decode_imu(m.encode_imu(s)) == s


def test_packet_round_trip():
    p = _payload(DATA_PACKET_SIZE, 3)
    assert m.decode_velodyne_packet(m.encode_velodyne_packet(123_000_000_001, p)) == (123_000_000_001, p)
    with pytest.raises(ValueError):
        m.encode_velodyne_packet(0, p[:-1])


def test_recording_round_trip_and_ros2_oracle(tmp_path):
    path = tmp_path / "rec.mcap"
    data = [_payload(DATA_PACKET_SIZE, i) for i in range(50)]
    pos = _payload(POSITION_PACKET_SIZE, 9)
    imu = m.ImuSample(1_000_000_500, 1.0, 0.0, 0.0, 0.0, 42, "witmotion", 3, b"\x55\x59")
    with RecordingWriter(path, chunk_size=4096) as w:
        for i, d in enumerate(data):
            w.write_lidar_packet(1_000_000_000 + i * 1000, d)
        w.write_position_packet(1_000_000_100, pos)
        w.write_imu(imu)
        w.write_event(m.Event(1_000_000_200, "mark", "station 1"))
        w.write_status(m.Status(1_000_000_300, counts={"lidar_good": 50}))

    r = RecordingReader(path)
    assert list(r.lidar_packets()) == [(1_000_000_000 + i * 1000, d) for i, d in enumerate(data)]
    assert list(r.position_packets()) == [(1_000_000_100, pos)]
    assert list(r.imu_samples()) == [imu]
    assert [e.label for e in r.events()] == ["station 1"]
    assert not r.report.truncated

    # an independent ROS 2 CDR decoder reads our bytes through the embedded msg definitions
    with open(path, "rb") as fh:
        seen = {}
        for schema, channel, message, decoded in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=[t.TOPIC_LIDAR_PACKETS, t.TOPIC_IMU, t.TOPIC_LIDAR_POSITION]
        ):
            seen.setdefault(channel.topic, []).append(decoded)
    assert bytes(seen[t.TOPIC_LIDAR_PACKETS][7].data) == data[7]
    assert seen[t.TOPIC_LIDAR_PACKETS][7].stamp.sec == 1 and seen[t.TOPIC_LIDAR_PACKETS][7].stamp.nanosec == 7000
    q = seen[t.TOPIC_IMU][0]
    assert (q.w, q.x, q.device_time_ns, q.driver, q.sequence, bytes(q.raw)) == (1.0, 0.0, 42, "witmotion", 3, b"\x55\x59")
    assert bytes(seen[t.TOPIC_LIDAR_POSITION][0].data) == pos


def test_truncated_recording_keeps_whole_messages(tmp_path):
    path = tmp_path / "rec.mcap"
    with RecordingWriter(path, chunk_size=20_000) as w:
        for i in range(200):
            w.write_lidar_packet(i, _payload(DATA_PACKET_SIZE, i))
    size = os.path.getsize(path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: size * 2 // 3])
    r = RecordingReader(cut)
    got = list(r.lidar_packets())
    assert r.report.truncated and r.report.error
    assert 0 < len(got) < 200
    assert got == [(i, _payload(DATA_PACKET_SIZE, i)) for i in range(len(got))]
