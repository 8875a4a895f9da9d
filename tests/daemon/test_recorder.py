# SPDX-License-Identifier: BSD-3-Clause
"""MCAP writer thread: timed chunk flush, split by size and duration, bounded queue."""

from __future__ import annotations

import re
import time

from mcap.reader import make_reader

from tripod_shared import messages, topics
from tripod_shared.recording import RecordingReader

from daemon_helpers import make_data_packet
from tripod_daemon.config import RecordingConfig
from tripod_daemon.recorder import Recorder
from tripod_daemon.stats import Counters


def _items(start: int, n: int):
    t0 = time.time_ns()
    return [(topics.TOPIC_LIDAR_PACKETS, t0 + k, messages.encode_velodyne_packet(
        t0 + k, make_data_packet(start + k))) for k in range(n)]


def _packets(path):
    return [p for _ns, p in RecordingReader(path).lidar_packets()]


def test_timed_flush_puts_data_on_disk_while_recording(tmp_path):
    cfg = RecordingConfig(directory=str(tmp_path), flush_interval_s=0.2, min_free_bytes=0,
                          chunk_size_bytes=64 << 20)
    rec = Recorder(cfg, Counters())
    try:
        assert rec.start("test")
        assert re.fullmatch(r"tripod_\d{8}T\d{6}Z\.mcap", rec.file.rsplit("/", 1)[1])
        rec.submit(_items(0, 100))
        time.sleep(0.6)  # > flush interval; the chunk is far from full
        reader = RecordingReader(rec.file)
        on_disk = [p for _ns, p in reader.lidar_packets()]
        assert len(on_disk) == 100 and reader.report.truncated  # no footer yet, data there
    finally:
        rec.close()
    with open(rec.files[0], "rb") as fh:
        assert make_reader(fh).get_summary().statistics.message_count >= 102  # + start/stop


def test_split_by_size_keeps_every_message_in_order(tmp_path):
    cfg = RecordingConfig(directory=str(tmp_path), max_file_bytes=150_000, compression="none",
                          chunk_size_bytes=32_000, min_free_bytes=0, flush_interval_s=0.1)
    counts = Counters()
    rec = Recorder(cfg, counts)
    items = _items(0, 1000)
    try:
        assert rec.start()
        for k in range(0, 1000, 50):
            rec.submit(items[k : k + 50])
            time.sleep(0.01)
    finally:
        rec.close()
    assert len(rec.files) >= 5 and counts["record_files"] == len(rec.files)
    assert len(set(rec.files)) == len(rec.files)
    got = [p for f in rec.files for p in _packets(f)]
    assert got == [make_data_packet(k) for k in range(1000)]
    for f in rec.files:
        with open(f, "rb") as fh:
            assert make_reader(fh).get_summary() is not None


def test_split_by_duration(tmp_path):
    cfg = RecordingConfig(directory=str(tmp_path), max_file_duration_s=0.3, min_free_bytes=0,
                          flush_interval_s=0.1)
    rec = Recorder(cfg, Counters())
    try:
        assert rec.start()
        for k in range(10):
            rec.submit(_items(k * 10, 10))
            time.sleep(0.1)
    finally:
        rec.close()
    assert len(rec.files) >= 2
    assert [p for f in rec.files for p in _packets(f)] == [make_data_packet(k) for k in range(100)]


def test_full_backlog_drops_and_counts_never_blocks_and_stays_in_budget(tmp_path):
    cfg = RecordingConfig(directory=str(tmp_path), queue_bytes=1 << 20, min_free_bytes=0)
    counts = Counters()
    rec = Recorder(cfg, counts)
    peak = 0
    said = set()
    try:
        assert rec.start()
        t0 = time.perf_counter()
        for k in range(200):  # 8000 packets, ~10 MB offered at once: far over the budget
            rec.submit(_items(k * 40, 40))
            peak = max(peak, rec.pending_bytes)
            said.add(rec.overload.split(":")[0])
        assert time.perf_counter() - t0 < 1.0
        assert "disk cannot keep up" in said  # (cleared again once the backlog is half gone)
    finally:
        rec.close()
    assert 0 < peak <= cfg.queue_bytes
    assert counts["record_dropped"] > 0
    assert counts["record_dropped"] + counts["record_written"] == 200 * 40
    # what was written is whole batches, in order
    got = _packets(rec.files[0])
    assert got == sorted(got, key=lambda p: int.from_bytes(p[2:6], "little"))


def test_not_recording_ignores_data_and_mark_says_so(tmp_path):
    cfg = RecordingConfig(directory=str(tmp_path), min_free_bytes=0)
    rec = Recorder(cfg, Counters())
    try:
        rec.submit(_items(0, 10))
        assert rec.mark("nothing open") is False
        assert rec.start() and rec.mark("station 1")
        rec.stop("done")  # returns at once; the writer finishes the file in queue order
        end = time.monotonic() + 5
        while rec.file is not None and time.monotonic() < end:
            time.sleep(0.01)
        assert rec.state == "idle" and rec.file is None and not rec.active
    finally:
        rec.close()
    events = list(RecordingReader(rec.files[0]).events())
    assert [(e.kind, e.label) for e in events] == [("start", "start"), ("mark", "station 1"),
                                                  ("stop", "done")]


def test_unwritable_directory_is_a_status_not_a_crash(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    cfg = RecordingConfig(directory=str(blocker / "sub"), min_free_bytes=0)
    rec = Recorder(cfg, Counters())
    try:
        assert rec.start() is False
        assert rec.state == "error" and "cannot use" in rec.message
    finally:
        rec.close()
