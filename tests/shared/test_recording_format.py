# SPDX-License-Identifier: BSD-3-Clause
"""Recording format 2 (MCAP profile ros2, every channel CDR) and reading format 1 files."""

from __future__ import annotations

import sys
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from tripod_shared import messages as m
from tripod_shared import ros2_msgs as r2
from tripod_shared import topics as t
from tripod_shared.recording import FORMAT_VERSION, RecordingReader, RecordingWriter
from tripod_shared.velodyne import DATA_PACKET_SIZE, POSITION_PACKET_SIZE

sys.path.insert(0, str(Path(__file__).resolve().parent))
from recording_v1 import write_v1  # noqa: E402

T0 = 1_780_000_000_000_000_000
STATUS = m.Status(T0 + 300, state="recording", recording=True, file="/data/a.mcap",
                  counts={"lidar_data": 50, "imu_samples": 2}, rates={"lidar_pps": 754.2},
                  message="imu: reconnecting", clocks={"lidar": {"offset_ns": 12, "ok": True}},
                  disk={"free_bytes": 1 << 30, "min_free_bytes": 1 << 20})
EVENTS = [m.Event(T0 + 100, "start", "control"), m.Event(T0 + 200, "mark", "station 1"),
          m.Event(T0 + 400, "stop", "disk full")]


def _payload(n, seed):
    return bytes((i * 7 + seed) % 256 for i in range(n))


def test_format2_is_ros2_profile_with_every_channel_cdr(tmp_path):
    path = tmp_path / "rec.mcap"
    with RecordingWriter(path, chunk_size=4096) as w:
        w.write_lidar_packet(T0, _payload(DATA_PACKET_SIZE, 1))
        w.write_position_packet(T0 + 10, _payload(POSITION_PACKET_SIZE, 2))
        w.write_imu(m.ImuSample(T0 + 20, 1.0, 0.0, 0.0, 0.0, raw=b"\x01"))
        w.write_event(EVENTS[0])
        # status and marks arrive from the daemon as their Zenoh JSON: written as CDR
        w.write_encoded(t.TOPIC_EVENTS, EVENTS[1].host_ns, m.encode_event(EVENTS[1]))
        w.write_encoded(t.TOPIC_STATUS, STATUS.host_ns, m.encode_status(STATUS))
        w.write_status(STATUS)
        w.write_event(EVENTS[2])
    with open(path, "rb") as fh:
        r = make_reader(fh)
        assert r.get_header().profile == "ros2"
        summary = r.get_summary()
        assert {c.topic for c in summary.channels.values()} == set(t.ALL_TOPICS)
        for c in summary.channels.values():
            assert c.message_encoding == "cdr"
            assert summary.schemas[c.schema_id].encoding == "ros2msg"
        meta = {md.name: md.metadata for md in r.iter_metadata()}
        assert meta["tripod"]["format_version"] == FORMAT_VERSION == "2"
    # an independent ROS 2 CDR decoder reads status and events from the definitions in the file
    with open(path, "rb") as fh:
        dec = {}
        for _s, ch, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages(topics=[t.TOPIC_STATUS, t.TOPIC_EVENTS]):
            dec.setdefault(ch.topic, []).append(msg)
    assert [(e.kind, e.label) for e in dec[t.TOPIC_EVENTS]] == [(e.kind, e.label) for e in EVENTS]
    st = dec[t.TOPIC_STATUS][0].status[0]
    assert (st.name, st.level, st.message) == (r2.DIAGNOSTIC_NAME, r2.DIAG_OK, STATUS.message)
    assert dec[t.TOPIC_STATUS][0].header.stamp.nanosec == STATUS.host_ns % 10**9
    # and ours, losslessly
    rd = RecordingReader(path)
    assert list(rd.events()) == EVENTS
    assert list(rd.statuses()) == [STATUS, STATUS]
    assert not rd.report.truncated


def test_format1_recording_still_reads(tmp_path):
    """A recording in the old layout (JSON status/events, profile "") reads as before."""
    path = tmp_path / "v1.mcap"
    pk = [_payload(DATA_PACKET_SIZE, i) for i in range(5)]
    pos = _payload(POSITION_PACKET_SIZE, 9)
    imu = m.ImuSample(T0 + 50, 0.0, 1.0, 0.0, 0.0, 7, "tfp", 1, b"\x02")
    items = [(EVENTS[0].host_ns, EVENTS[0])]
    items += [(T0 + 110 + i, (p, t.TOPIC_LIDAR_PACKETS)) for i, p in enumerate(pk)]
    items += [(T0 + 150, (pos, t.TOPIC_LIDAR_POSITION)), (imu.host_ns, imu),
              (EVENTS[1].host_ns, EVENTS[1]), (STATUS.host_ns, STATUS),
              (EVENTS[2].host_ns, EVENTS[2])]
    write_v1(path, sorted(items, key=lambda x: x[0]))
    with open(path, "rb") as fh:
        assert make_reader(fh).get_header().profile == ""
    rd = RecordingReader(path)
    assert list(rd.lidar_packets()) == [(T0 + 110 + i, p) for i, p in enumerate(pk)]
    assert list(rd.position_packets()) == [(T0 + 150, pos)]
    assert list(rd.imu_samples()) == [imu]
    assert list(rd.events()) == EVENTS
    assert list(rd.statuses()) == [STATUS]
    assert rd.report.metadata["tripod"]["format_version"] == "1"
