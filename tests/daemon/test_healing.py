# SPDX-License-Identifier: BSD-3-Clause
"""Self-healing: the recorder resumes by itself after its directory was deleted or the disk
filled; stalled inputs are flagged; the watchdog stops when recording stays impossible;
``recover`` writes elsewhere on a full disk and never leaves a partial file."""

from __future__ import annotations

import os
import shutil
import socket
import time

from mcap.reader import make_reader

from tripod_shared.recording import RecordingReader

from daemon_helpers import (
    FakePty,
    RunningDaemon,
    loopback_config,
    make_data_packet,
    send_paced,
    small_tmpfs,
    udp_sender,
)
from tripod_daemon.recover import main as recover_main
from tripod_daemon.systemd import Notifier


def _send(d, start: int, n: int) -> list[bytes]:
    pk = [make_data_packet(start + k) for k in range(n)]
    send_paced(udp_sender(), d.data_addr, pk, 4000)
    return pk


def test_deleted_record_directory_resumes_into_a_new_file(tmp_path):
    rec_dir = tmp_path / "rec"
    cfg = loopback_config(tmp_path, recording={"retry_interval_s": 0.3, "flush_interval_s": 0.1})
    with RunningDaemon(cfg) as d:
        c = d.daemon.counts
        _send(d, 0, 200)
        assert d.wait_for(lambda: c["record_written"] >= 200)
        shutil.rmtree(rec_dir)
        assert d.wait_for(lambda: c["record_resumes"] == 1, timeout=10)
        after = _send(d, 1000, 300)
        assert d.wait_for(lambda: c["lidar_data"] == 500)
        assert d.stop() == 0
    rec = d.daemon.recorder
    assert len(rec.files) == 2 and os.path.dirname(rec.files[1]) == str(rec_dir)
    events = [(e.kind, e.label) for e in RecordingReader(rec.files[1]).events()]
    assert events[0] == ("start", "retry") and events[-1] == ("stop", "shutdown")
    got = [p for _ns, p in RecordingReader(rec.files[1]).lidar_packets()]
    assert got[-300:] == after  # everything after the resume is in the new file


def test_full_disk_resumes_when_space_returns(tmp_path):
    free = [1 << 40]
    cfg = loopback_config(tmp_path, recording={"retry_interval_s": 0.2, "flush_interval_s": 0.1,
                                               "min_free_bytes": 1 << 20})
    with RunningDaemon(cfg, free_space=lambda _d: free[0]) as d:
        c = d.daemon.counts
        _send(d, 0, 100)
        assert d.wait_for(lambda: c["record_written"] >= 100)
        free[0] = 0  # the disk fills
        assert d.wait_for(lambda: d.daemon.recorder.state == "stopped", timeout=5)
        assert d.wait_for(lambda: b"disk full" in d.daemon.status_json(), timeout=5)
        _send(d, 1000, 100)  # arrives while recording is impossible: counted
        assert d.wait_for(lambda: c["record_unrecorded"] >= 100)
        time.sleep(0.5)
        assert c["record_resumes"] == 0  # still full: retried, not resumed
        free[0] = 1 << 40  # space again (files deleted, disk swapped)
        assert d.wait_for(lambda: c["record_resumes"] == 1, timeout=5)
        after = _send(d, 2000, 100)
        assert d.wait_for(lambda: c["lidar_data"] == 300)
        assert d.stop() == 0
    rec = d.daemon.recorder
    assert len(rec.files) == 2
    got = [p for _ns, p in RecordingReader(rec.files[1]).lidar_packets()]
    assert got == after


def test_stalled_lidar_and_imu_are_flagged_and_cleared(tmp_path):
    dev = FakePty(tmp_path / "imu")
    cfg = loopback_config(tmp_path, imu={"url": str(dev.link), "driver": "witmotion"},
                          health={"lidar_stall_s": 0.5, "imu_stall_s": 0.5})
    try:
        with RunningDaemon(cfg) as d:
            assert d.wait_for(lambda: set(d.daemon.health) == {"lidar_stalled", "imu_stalled"},
                              timeout=10)
            # the status is published right after the check that raised the flags, on the
            # daemon's thread: wait for it rather than read it between the two
            assert d.wait_for(lambda: b"lidar stalled: no data for" in d.daemon.status_json()
                              and b"IMU stalled" in d.daemon.status_json(), timeout=5)
            assert "IMU stalled" in d.daemon._status_line()
            s = udp_sender()
            end = time.monotonic() + 10
            while "lidar_stalled" in d.daemon.health and time.monotonic() < end:
                s.sendto(make_data_packet(1), d.data_addr)
                time.sleep(0.01)
            assert "lidar_stalled" not in d.daemon.health
            assert d.daemon.counts["health_lidar_stalled"] == 1
            assert d.stop() == 0
    finally:
        dev.close()


def test_watchdog_stops_when_recording_stays_impossible(tmp_path, monkeypatch):
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(0.1)
    blocker = tmp_path / "file"
    blocker.write_text("x")  # the record directory cannot be made
    cfg = loopback_config(tmp_path, recording={"directory": str(blocker / "rec"),
                                               "retry_interval_s": 0.2},
                          health={"unhealthy_restart_s": 0.8})
    notifier = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"})
    msgs: list[tuple[float, str]] = []
    with RunningDaemon(cfg, notifier=notifier) as d:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 2.5:
            try:
                msgs.append((time.monotonic() - t0, sock.recv(4096).decode()))
            except TimeoutError:
                pass
        d.stop()
    pings = [t for t, m in msgs if "WATCHDOG=1" in m]
    assert pings and max(pings) < 1.6  # pinged at first, then no more
    assert any("unhealthy: not recording" in m for _t, m in msgs)



def test_recover_on_a_full_disk_writes_elsewhere_and_leaves_no_partial(tmp_path, capsys):
    cfg = loopback_config(tmp_path, recording={"compression": "none", "flush_interval_s": 0.1})
    with RunningDaemon(cfg) as d:
        _send(d, 0, 400)
        assert d.wait_for(lambda: d.daemon.counts["record_written"] >= 400)
        d.stop()
    src = d.daemon.recorder.files[0]
    full = tmp_path / "full"
    with small_tmpfs(full, 64) as mounted:
        if not mounted:  # no permission to mount: a directory nobody can write stands in
            full.mkdir(exist_ok=True)
            os.chmod(full, 0o500)
        cut = full / "cut.mcap"
        if mounted:
            with open(src, "rb") as fh:  # a cut-off copy, as small as the tiny disk allows
                cut.write_bytes(fh.read(40_000))
        else:
            cut = tmp_path / "cut.mcap"
            with open(src, "rb") as fh:
                cut.write_bytes(fh.read(40_000))
        out = full / "cut.recovered.mcap"
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        rc = recover_main([str(cut), "-o", str(out), "--fallback-dir", str(elsewhere)])
        err = capsys.readouterr().err
        assert rc == 0, err
        assert "instead" in err
        assert not out.exists() and not list(full.glob("*.part"))
        with open(elsewhere / "cut.recovered.mcap", "rb") as fh:
            assert make_reader(fh).get_summary() is not None
        # nowhere to write: exit 1, one line, nothing partial anywhere
        rc = recover_main([str(cut), "-o", str(out), "--fallback-dir", str(full)])
        err = capsys.readouterr().err
        assert rc == 1 and "nowhere to write" in err and err.count("\n") == 1
        assert not list(full.glob("*.part")) and not out.exists()


def test_stop_while_retrying_ends_the_retries(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    cfg = loopback_config(tmp_path, recording={"directory": str(blocker / "rec"),
                                               "retry_interval_s": 0.1})
    with RunningDaemon(cfg) as d:
        rec = d.daemon.recorder
        assert rec.wanted and not rec.active and rec.state == "error"
        assert d.daemon.control("stop")["ok"]
        assert d.wait_for(lambda: rec.state == "idle")
        blocker.unlink()  # the directory could be made now: no retry may pick that up
        time.sleep(0.5)
        assert not rec.active and d.daemon.counts["record_resumes"] == 0
        d.stop()
