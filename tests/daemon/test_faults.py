# SPDX-License-Identifier: BSD-3-Clause
"""Faults: kill -9 then recover; IMU unplugged and plugged back; a full disk."""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import time

from mcap.reader import make_reader

from tripod_shared import ros2_msgs as r2
from tripod_shared import tfp
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
from tripod_daemon.main import main


def _start_daemon_process(tmp_path, extra_yaml=""):
    cfg = tmp_path / "daemon.yaml"
    cfg.write_text(
        "lidar:\n  bind_address: 127.0.0.1\n  data_port: 0\n  position_port: 0\n"
        "  receive_buffer_bytes: 16777216\n"
        f"recording:\n  directory: {tmp_path / 'rec'}\n  min_free_bytes: 0\n"
        "zenoh:\n  enabled: false\n" + extra_yaml)
    proc = subprocess.Popen(
        [sys.executable, "-m", "tripod_daemon", "--no-system-config", "--config", str(cfg)],
        stderr=subprocess.PIPE, text=True)
    port = None
    end = time.monotonic() + 30
    while time.monotonic() < end:
        line = proc.stderr.readline()
        m = re.search(r"data on [\d.]+:(\d+)", line)
        if m:
            port = int(m.group(1))
        if "recording to" in line:
            break
    assert port, "daemon did not report its port"
    return proc, port


def test_kill_9_then_recover_keeps_all_but_the_last_second(tmp_path, capsys):
    proc, port = _start_daemon_process(tmp_path)  # flush_interval_s: 1.0 (the default)
    try:
        sock = udp_sender()
        rate = 2000.0
        packets = [make_data_packet(i) for i in range(int(rate * 3.5))]
        send_paced(sock, ("127.0.0.1", port), packets, rate)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()
    files = sorted((tmp_path / "rec").glob("*.mcap"))
    assert len(files) == 1
    cut = files[0]
    # the plain mcap seeking reader cannot use the cut file: no summary, no footer
    with open(cut, "rb") as fh:
        try:
            cut_summary = make_reader(fh).get_summary()
        except Exception:  # noqa: BLE001 - mcap raises on the missing footer
            cut_summary = None
    assert cut_summary is None
    assert main(["recover", str(cut)]) == 0
    report = capsys.readouterr().out
    assert "cut off" in report and "/velodyne/packets" in report
    fixed = cut.with_name(cut.stem + ".recovered.mcap")
    with open(fixed, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        got = [m.data[12:] for _s, ch, m in reader.iter_messages(topics=["/velodyne/packets"])]
    # a prefix of what was sent, byte-exact, in order; at most ~1 s (flush interval) missing
    assert got == packets[: len(got)]
    missing = len(packets) - len(got)
    assert missing <= rate * 1.0 + 200, f"lost {missing} packets (> 1 s at {rate:.0f}/s)"
    # recovering the recovered file finds it complete
    assert main(["recover", str(fixed), "-o", str(tmp_path / "again.mcap")]) == 0
    assert "complete file" in capsys.readouterr().out


def test_recover_bad_input_is_a_clear_error(tmp_path, capsys):
    assert main(["recover", str(tmp_path / "missing.mcap")]) == 2
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(os.urandom(1000))
    assert main(["recover", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and "not an MCAP file" in err


def test_imu_unplug_and_replug_resumes_without_restart(tmp_path):
    dev = FakePty(tmp_path / "tripod-imu")
    cfg = loopback_config(tmp_path, imu={"url": str(dev.link), "reconnect_interval_s": 0.2})
    uid = 0x2B3C4D
    first = [tfp.encode_quaternion_callback(uid, 1.0, 0.0, 0.0, 0.0) for _ in range(50)]
    second = [tfp.encode_quaternion_callback(uid, 0.0, 1.0, 0.0, 0.0) for _ in range(50)]
    try:
        with RunningDaemon(cfg) as d:
            c = d.daemon.counts
            assert d.wait_for(lambda: d.daemon.imu.connected)
            # the driver asks who is there; we answer as a brick and get the period request
            assert tfp.FID_ENUMERATE in dev.read_available(0.3)[:8]
            dev.write(tfp.encode_enumerate_callback(uid))
            asked = []
            end = time.monotonic() + 5
            while not asked and time.monotonic() < end:
                raw = dev.read_available(0.2)
                # requests are sent with response_expected: parse the header by hand
                for i in range(0, max(0, len(raw) - 11)):
                    if raw[i + 5] == tfp.FID_SET_QUATERNION_PERIOD and raw[i + 4] == 12:
                        asked.append(int.from_bytes(raw[i + 8:i + 12], "little"))
            assert asked == [cfg.imu.quaternion_period_ms]
            for f in first:
                dev.write(f)
            assert d.wait_for(lambda: c["imu_samples"] == 50)
            dev.unplug()
            assert d.wait_for(lambda: c["imu_disconnects"] == 1 and not d.daemon.imu.connected)
            dev.plug()  # a new pty behind the same name, as udev does on replug
            assert d.wait_for(lambda: c["imu_connects"] == 2)
            for f in second:
                dev.write(f)
            assert d.wait_for(lambda: c["imu_samples"] == 100)
            assert d.stop() == 0
    finally:
        dev.close()
    rec = list(RecordingReader(d.daemon.recorder.files[0]).imu_samples())
    assert [s.raw for s in rec] == first + second
    assert len(d.daemon.recorder.files) == 1  # same recording across the unplug



def test_full_disk_stops_cleanly_with_a_readable_file(tmp_path):
    disk = tmp_path / "disk"
    size = 8 << 20
    with small_tmpfs(disk, 8 * 1024) as real_tmpfs:
        if real_tmpfs:
            free_space = None  # the real statvfs of the tmpfs
        else:
            def free_space(d):  # quota emulation: 8 MiB minus what the files hold
                return size - sum(f.stat().st_size for f in disk.rglob("*") if f.is_file())
        cfg = loopback_config(
            tmp_path, recording={"directory": str(disk), "min_free_bytes": 3 << 20,
                                 "compression": "none", "flush_interval_s": 0.2})
        rng = random.Random(7)
        packets = []
        for i in range(8000):  # ~9.6 MB: more than the disk holds
            p = bytearray(make_data_packet(i))
            for b in range(12):
                p[b * 100 + 6 : b * 100 + 100] = rng.randbytes(94)
            packets.append(bytes(p))
        kw = {"free_space": free_space} if free_space else {}
        with RunningDaemon(cfg, **kw) as d:
            send_paced(udp_sender(), d.data_addr, packets, 4000)
            assert d.wait_for(lambda: d.daemon.recorder.state == "stopped")
            assert d.wait_for(lambda: b"disk full" in d.daemon.status_json(), timeout=5)
            assert d.stop() == 0
        rec = d.daemon.recorder
        assert "disk full" in rec.message and not rec.active
        assert d.daemon.counts["lidar_data"] == len(packets)  # reception went on
        with open(rec.files[0], "rb") as fh:
            reader = make_reader(fh)
            assert reader.get_summary() is not None  # finished properly: summary and footer
            got = [m.data[12:] for _s, _c, m in reader.iter_messages(topics=["/velodyne/packets"])]
            events = [r2.decode_event_cdr(m.data)
                      for _s, _c, m in reader.iter_messages(topics=["/tripod/events"])]
        assert 1000 < len(got) < len(packets)
        assert got == packets[: len(got)]
        assert events[-1].kind == "stop" and "disk full" in events[-1].label
        # the guard keeps min_free_bytes free: the disk never filled up
        if real_tmpfs:
            st = os.statvfs(disk)
            assert st.f_bavail * st.f_frsize > 1 << 20
