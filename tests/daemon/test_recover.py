# SPDX-License-Identifier: BSD-3-Clause
"""recover: a recording cut at any byte, or with a corrupted chunk, gives back every whole
message before the damage, in a file the plain mcap reader opens."""

from __future__ import annotations

import time

from mcap.reader import make_reader

from tripod_shared import messages, topics
from tripod_shared.recording import RecordingWriter

from daemon_helpers import make_data_packet
from tripod_daemon.recover import recover


def _write(path, n=600, chunk=20_000):
    t0 = time.time_ns()
    with RecordingWriter(path, chunk_size=chunk) as w:
        w.add_metadata("tripod_daemon", {"device_id": "tripod0"})
        for k in range(n):
            w.write_encoded(topics.TOPIC_LIDAR_PACKETS, t0 + k * 1000,
                            messages.encode_velodyne_packet(t0 + k * 1000, make_data_packet(k)))
            if k % 50 == 0:
                w.write_imu(messages.ImuSample(t0 + k * 1000, 1.0, 0.0, 0.0, 0.0, raw=b"x"))
    return t0


def _read(path):
    with open(path, "rb") as fh:
        r = make_reader(fh)
        assert r.get_summary() is not None
        msgs = [(ch.topic, m.log_time, m.sequence, m.data) for _s, ch, m in r.iter_messages()]
        meta = {m.name: m.metadata for m in r.iter_metadata()}
    return msgs, meta


def test_cut_at_any_offset_recovers_a_prefix(tmp_path):
    full = tmp_path / "full.mcap"
    _write(full)
    blob = full.read_bytes()
    original, _ = _read(full)
    prev = -1
    for cut in list(range(8, len(blob), max(1, len(blob) // 40))) + [len(blob) - 1]:
        src = tmp_path / "cut.mcap"
        src.write_bytes(blob[:cut])
        out = tmp_path / "out.mcap"
        rep = recover(str(src), str(out))
        got, meta = _read(out)
        assert got == original[: len(got)]  # same topics, times, sequences, bytes; in order
        assert rep.total_messages == len(got) >= prev  # a longer file never gives less
        assert rep.kept_bytes + rep.lost_bytes == cut
        assert meta["tripod_recover"]["lost_bytes"] == str(rep.lost_bytes)
        if len(got) > 0:
            assert meta["tripod_daemon"] == {"device_id": "tripod0"}
        prev = len(got)
    assert prev > 0.9 * len(original)  # cut just before the end: almost everything back


def test_complete_file_is_copied_whole(tmp_path):
    full = tmp_path / "full.mcap"
    _write(full)
    rep = recover(str(full), str(tmp_path / "copy.mcap"))
    assert rep.complete and rep.lost_bytes == 0
    assert _read(tmp_path / "copy.mcap")[0] == _read(full)[0]


def test_corrupted_chunk_stops_at_the_damage(tmp_path):
    full = tmp_path / "full.mcap"
    _write(full, n=600, chunk=20_000)
    blob = bytearray(full.read_bytes())
    original, _ = _read(full)
    mid = len(blob) // 2
    blob[mid : mid + 64] = bytes(64)  # zeroes inside a compressed chunk: CRC or zstd fails
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(blob))
    rep = recover(str(bad), str(tmp_path / "fixed.mcap"))
    got, _ = _read(tmp_path / "fixed.mcap")
    assert rep.error and not rep.complete
    assert 0 < len(got) < len(original) and got == original[: len(got)]


def test_recover_keeps_the_profile_and_both_formats_read(tmp_path):
    """A format 2 file stays profile ros2 (status/events CDR); a format 1 file stays profile ""
    with its JSON channels; both read back through RecordingReader."""
    import sys
    from pathlib import Path

    from tripod_shared.recording import RecordingReader

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "shared"))
    from recording_v1 import write_v1

    t0 = time.time_ns()
    ev = [messages.Event(t0 + 5, "mark", "station 1"), messages.Event(t0 + 9, "stop", "x")]
    st = messages.Status(t0 + 7, state="recording", counts={"lidar_data": 3})
    v2, v1 = tmp_path / "v2.mcap", tmp_path / "v1.mcap"
    with RecordingWriter(v2, chunk_size=1 << 20) as w:
        w.write_lidar_packet(t0, make_data_packet(0))
        w.write_event(ev[0])
        w.write_status(st)
        w.write_event(ev[1])
    write_v1(v1, [(t0, (make_data_packet(0), topics.TOPIC_LIDAR_PACKETS)), (ev[0].host_ns, ev[0]),
                  (st.host_ns, st), (ev[1].host_ns, ev[1])])
    for src, profile in ((v2, "ros2"), (v1, "")):
        cut = tmp_path / f"cut_{src.name}"
        data = src.read_bytes()
        cut.write_bytes(data[:len(data) - 30])  # the footer and part of the summary gone
        out = tmp_path / f"rec_{src.name}"
        rep = recover(str(cut), str(out))
        assert rep.messages[topics.TOPIC_EVENTS] == 2
        with open(out, "rb") as fh:
            assert make_reader(fh).get_header().profile == profile
        r = RecordingReader(out)
        assert list(r.events()) == ev and list(r.statuses()) == [st]
        assert list(r.lidar_packets()) == [(t0, make_data_packet(0))]
