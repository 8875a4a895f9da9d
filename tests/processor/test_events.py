# SPDX-License-Identifier: BSD-3-Clause
"""tripod_processor.io.events: the one reader API over pcap, MCAP, IMU logs and simulator
folders, and the one data/position rule."""

import numpy as np
from tripod_shared import messages as m
from tripod_shared import topics as t
from tripod_shared import velodyne as vl
from tripod_shared.recording import RecordingWriter

from tripod_processor.io import events as ev
from tripod_processor.io.imu_log import write_imu_log
from tripod_processor.io.pcap import PcapReader, PcapWriter

T0 = 1_780_000_000_000_000_000


def test_one_data_position_rule():
    assert ev.lidar_kind(vl.DATA_PORT, 1206) == ev.LIDAR
    assert ev.lidar_kind(vl.POSITION_PORT, 512) == ev.POSITION
    # the port decides over the size: what was sent to a port is replayed to it
    assert ev.lidar_kind(vl.DATA_PORT, 512) == ev.LIDAR
    assert ev.lidar_kind(vl.POSITION_PORT, 1206) == ev.POSITION
    # elsewhere the size decides
    assert ev.lidar_kind(5000, 1206) == ev.LIDAR
    assert ev.lidar_kind(5000, 512) == ev.POSITION
    assert ev.lidar_kind(5000, 100) is None
    assert ev.lidar_kind(2000, 1206, data_port=2000, position_port=2001) == ev.LIDAR


def test_pcap_events_kinds_order_and_skips(tmp_path):
    p = tmp_path / "c.pcap"
    sent = [(vl.DATA_PORT, 1206), (vl.POSITION_PORT, 512), (5000, 1206), (5000, 512), (53, 60)]
    with PcapWriter(p) as w:
        for i, (port, size) in enumerate(sent):
            w.write_udp(T0 + i * 1000, bytes([i]) * size, port, port)
    skipped = {}
    got = list(ev.pcap_events(PcapReader(p), skipped=skipped))
    assert [(e.host_ns, e.kind, len(e.data)) for e in got] == [
        (T0, ev.LIDAR, 1206), (T0 + 1000, ev.POSITION, 512), (T0 + 2000, ev.LIDAR, 1206),
        (T0 + 3000, ev.POSITION, 512)]
    assert skipped == {"other_datagram": 1}


def test_mcap_events_every_kind_and_a_corrupt_message(tmp_path):
    p = tmp_path / "r.mcap"
    with RecordingWriter(p) as w:
        w.write_lidar_packet(T0, b"\x01" * 1206)
        w.write_position_packet(T0 + 10, b"\x02" * 512)
        w.write_imu(m.ImuSample(T0 + 20, 1.0, 0.0, 0.0, 0.0, raw=b"abc"))
        w.write_imu(m.ImuSample(T0 + 30, 0.0, 1.0, 0.0, 0.0))  # no raw bytes
        w.write_event(m.Event(T0 + 40, "mark", "station 1"))
        w.write_event(m.Event(T0 + 45, "start", ""))
        w.write_encoded(t.TOPIC_LIDAR_PACKETS, T0 + 50, b"\x00\x01")  # does not decode
    every = ev.McapEvents(p, (ev.LIDAR, ev.POSITION, ev.IMU, ev.IMU_SAMPLE, ev.MARK))
    got = list(every)
    assert [(e.host_ns, e.kind) for e in got] == [
        (T0, ev.LIDAR), (T0 + 10, ev.POSITION), (T0 + 20, ev.IMU), (T0 + 20, ev.IMU_SAMPLE),
        (T0 + 30, ev.IMU_SAMPLE), (T0 + 40, ev.MARK)]
    assert got[0].data == b"\x01" * 1206 and got[2].data == b"abc"
    assert got[4].data.x == 1.0 and got[5].data == "station 1"
    assert every.skipped == {f"bad_message:{t.TOPIC_LIDAR_PACKETS}": 1}
    assert not every.truncated
    # the default reads the lidar only
    assert [e.kind for e in ev.McapEvents(p)] == [ev.LIDAR, ev.POSITION]


def test_folder_events_merge_pcap_and_imu_log_by_time(tmp_path):
    with PcapWriter(tmp_path / "capture.pcap") as w:
        for i in range(4):
            w.write_udp(T0 + i * 1000, b"\x00" * 1206, vl.DATA_PORT, vl.DATA_PORT)
    write_imu_log(tmp_path / "imu.tripimu", "tfp", np.array([T0 + 500, T0 + 2500], np.int64),
                  [b"x", b"y"])
    got = list(ev.folder_events(tmp_path))
    assert [e.host_ns - T0 for e in got] == [0, 500, 1000, 2000, 2500, 3000]
    assert [e.kind for e in got] == [ev.LIDAR, ev.IMU, ev.LIDAR, ev.LIDAR, ev.IMU, ev.LIDAR]


def test_mcap_events_read_a_format1_recording(tmp_path):
    """Older recordings (format 1: events as a JSON channel) give the same events."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "shared"))
    from recording_v1 import write_v1

    items = [(T0, (b"\x01" * 1206, t.TOPIC_LIDAR_PACKETS)),
             (T0 + 10, (b"\x02" * 512, t.TOPIC_LIDAR_POSITION)),
             (T0 + 20, m.ImuSample(T0 + 20, 1.0, 0.0, 0.0, 0.0, raw=b"abc")),
             (T0 + 30, m.Status(T0 + 30, counts={"lidar_data": 1})),
             (T0 + 40, m.Event(T0 + 40, "mark", "station 1")),
             (T0 + 45, m.Event(T0 + 45, "stop", "control"))]
    old, new = tmp_path / "v1.mcap", tmp_path / "v2.mcap"
    write_v1(old, items)
    with RecordingWriter(new) as w:
        w.write_lidar_packet(T0, b"\x01" * 1206)
        w.write_position_packet(T0 + 10, b"\x02" * 512)
        w.write_imu(items[2][1])
        w.write_status(items[3][1])
        w.write_event(items[4][1])
        w.write_event(items[5][1])
    kinds = (ev.LIDAR, ev.POSITION, ev.IMU, ev.IMU_SAMPLE, ev.MARK)
    got_old = ev.McapEvents(old, kinds)
    got = [(e.host_ns, e.kind, e.data) for e in got_old]
    assert got == [(e.host_ns, e.kind, e.data) for e in ev.McapEvents(new, kinds)]
    assert (T0 + 40, ev.MARK, "station 1") in got and len(got) == 5
    assert got_old.skipped == {} and not got_old.truncated
