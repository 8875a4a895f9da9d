# SPDX-License-Identifier: BSD-3-Clause
"""tripod replay on loopback: UDP timing and rate, IMU over a pty and a brickd-like TCP port."""

from __future__ import annotations

import os
import selectors
import socket
import subprocess
import sys
import threading
import time

import pytest
from sim_fixtures import make_capture

from tripod_processor.io.imu_log import ImuLogReader
from tripod_processor.io.pcap import PcapReader
from tripod_processor.io.replay import (BrickdImuSink, PtyImuSink, Replayer, ReplayInputError,
                                     ReplaySource, open_imu_sink)
from tripod_shared import tfp
from tripod_shared import velodyne as v
from tripod_shared.messages import ImuSample
from tripod_shared.recording import RecordingWriter


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return make_capture(tmp_path_factory.mktemp("replay"), "single")


@pytest.fixture(scope="module")
def dual(tmp_path_factory):
    return make_capture(tmp_path_factory.mktemp("replay"), "dual", lidar={"return_mode": "dual"})


class UdpSink:
    """Two loopback UDP sockets on ephemeral ports, drained by a thread (bounded: stops itself)."""

    def __init__(self):
        self.socks = []
        for _ in range(2):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
            self.socks.append(s)
        self.got = [[], []]
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def addr(self, i):
        return self.socks[i].getsockname()

    def _run(self):
        sel = selectors.DefaultSelector()
        for i, s in enumerate(self.socks):
            sel.register(s, selectors.EVENT_READ, i)
        deadline = time.monotonic() + 60
        while not self._stop.is_set() and time.monotonic() < deadline:
            for key, _ in sel.select(0.05):
                while True:
                    try:
                        self.got[key.data].append(key.fileobj.recv(2048))
                    except BlockingIOError:
                        break

    def stop(self):
        time.sleep(0.1)
        self._stop.set()
        self._t.join()
        for s in self.socks:
            s.close()


def _pcap_payloads(path, port, limit_ns=None):
    out, t0 = [], None
    for d in PcapReader(path):
        t0 = d.t_ns if t0 is None else t0
        if limit_ns is not None and d.t_ns - t0 > limit_ns:
            break
        if d.dst_port == port:
            out.append(d.payload)
    return out


def test_real_time_replay_keeps_timing_and_bytes(capture):
    sink = UdpSink()
    try:
        rp = Replayer(ReplaySource.open(capture), rate=1.0, lidar_addr=sink.addr(0),
                      position_addr=sink.addr(1), limit_s=1.5, realtime_priority=10)
        st = rp.run()
    finally:
        sink.stop()
    want = _pcap_payloads(capture / "capture.pcap", v.DATA_PORT, 1_500_000_000)
    assert st.sent["lidar"] == len(want) and sink.got[0] == want
    assert st.sent["position"] == len(sink.got[1]) > 0
    assert st.achieved_rate == pytest.approx(1.0, abs=0.01)
    # Timing: the typical packet leaves within 0.5 ms of its slot. The tail depends on the host
    # (a shared CI runner gave a 4.9 ms p99 even under SCHED_FIFO), so here it is only bounded
    # by a few scheduler slices; the p99 figure itself is measured by bench/sim_fidelity.py.
    assert st.jitter_us(50) < 500.0
    assert st.jitter_us(99) < 30_000.0


def test_rate_10_and_max(dual, capture):
    st = Replayer(ReplaySource.open(capture), rate=10.0, lidar_addr=("127.0.0.1", 9),
                  position_addr=("127.0.0.1", 9), limit_s=3.0, realtime_priority=10).run()
    assert st.achieved_rate == pytest.approx(10.0, rel=0.06 if "FIFO" in st.scheduling else 0.15)  # loaded CI machines
    # as fast as possible: at least 10x the dual-return packet rate (1507/s). An idle 2-core
    # machine does ~30x; 20x failed once with two benchmarks beside the suite (load 6-7:
    # 25 000 packets/s), so the floor says "far faster than the sensor", not how fast
    blackhole = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blackhole.bind(("127.0.0.1", 0))
    try:
        st = Replayer(ReplaySource.open(dual), rate=float("inf"),
                      lidar_addr=blackhole.getsockname(),
                      position_addr=blackhole.getsockname()).run()
    finally:
        blackhole.close()
    n = len(_pcap_payloads(dual / "capture.pcap", v.DATA_PORT))
    assert st.sent["lidar"] == n and st.send_errors == 0
    assert st.packets_per_s >= 10 * 1507


def test_imu_over_pty_is_byte_exact(capture):
    sink = PtyImuSink()
    got = bytearray()
    fd = os.open(sink.path, os.O_RDONLY | os.O_NOCTTY)
    stop = threading.Event()

    def reader():
        import select

        while True:
            r, _, _ = select.select([fd], [], [], 0.2)
            if not r:
                if stop.is_set():
                    return
                continue
            got.extend(os.read(fd, 4096))

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    try:
        st = Replayer(ReplaySource.open(capture), rate=20.0, lidar_addr=("127.0.0.1", 9),
                      position_addr=("127.0.0.1", 9), imu_sink=sink).run()
        time.sleep(0.2)
    finally:
        stop.set()
        t.join(5)
        os.close(fd)
        sink.close()
    want = b"".join(r.data for r in ImuLogReader(capture / "imu.tripimu"))
    assert st.sent["imu"] > 0 and st.imu_bytes_dropped == 0
    assert bytes(got) == want
    pk = tfp.TfpStreamParser().feed(bytes(got))
    assert len(pk) == st.sent["imu"] and all(p.function_id == 39 for p in pk)


def test_brickd_tcp_answers_enumerate_and_streams(capture):
    uid = tfp.base58_decode("6wVE7W")
    sink = open_imu_sink("tcp:0", uid=uid)
    assert isinstance(sink, BrickdImuSink)
    c = socket.create_connection(("127.0.0.1", sink.port), timeout=5)
    try:
        c.sendall(tfp.encode_enumerate(sequence=1))
        c.sendall(tfp.encode_set_quaternion_period(uid, 10, sequence=2))
        assert sink.wait_for_client(5)
        time.sleep(0.2)
        st = Replayer(ReplaySource.open(capture), rate=20.0, lidar_addr=("127.0.0.1", 9),
                      position_addr=("127.0.0.1", 9), imu_sink=sink, limit_s=2.0).run()
        c.settimeout(0.5)
        data = bytearray()
        while True:
            try:
                chunk = c.recv(65536)
            except socket.timeout:
                break
            if not chunk:
                break
            data += chunk
    finally:
        c.close()
        sink.close()
    p = tfp.TfpStreamParser()
    pk = p.feed(bytes(data))
    enum = [x for x in pk if x.function_id == tfp.FID_CALLBACK_ENUMERATE]
    assert len(enum) == 1 and tfp.decode_enumerate_callback(enum[0].payload) == (uid, 18)
    acks = [x for x in pk if x.function_id == tfp.FID_SET_QUATERNION_PERIOD]
    assert len(acks) == 1 and acks[0].sequence == 2
    quats = [x for x in pk if x.function_id == tfp.FID_CALLBACK_QUATERNION]
    assert len(quats) == st.sent["imu"] > 0 and p.garbage_bytes == 0


def test_mcap_recording_replays(tmp_path, capture):
    rec = tmp_path / "rec.mcap"
    n_lidar = 0
    with RecordingWriter(rec) as w:
        for i, d in enumerate(PcapReader(capture / "capture.pcap")):
            if d.dst_port == v.DATA_PORT:
                w.write_lidar_packet(d.t_ns, d.payload)
                n_lidar += 1
            if i > 800:
                break
        for r in list(ImuLogReader(capture / "imu.tripimu"))[:50]:
            q = tfp.decode_quaternion(r.data[8:])
            w.write_imu(ImuSample(r.host_ns, *q, raw=r.data))
    sink = UdpSink()
    try:
        st = Replayer(ReplaySource.open(rec), rate=float("inf"), lidar_addr=sink.addr(0),
                      position_addr=sink.addr(1), imu_sink=None).run()
    finally:
        sink.stop()
    assert st.sent["lidar"] == n_lidar == len(sink.got[0])
    assert st.sent["imu"] == 0  # no IMU sink: IMU events are skipped, nothing else breaks


def test_bad_inputs(tmp_path):
    with pytest.raises(ReplayInputError, match="no such"):
        ReplaySource.open(tmp_path / "missing.pcap")
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"hello world, not a capture")
    with pytest.raises(ReplayInputError, match="neither"):
        ReplaySource.open(junk)
    with pytest.raises(ReplayInputError, match="bad IMU output"):
        open_imu_sink("usb:3")


def test_cli_replay(capture):
    env = dict(os.environ, COLUMNS="120")
    r = subprocess.run([sys.executable, "-m", "tripod_processor", "replay", str(capture),
                        "--rate", "max", "--imu", "tcp:0"], capture_output=True, text=True,
                       timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("imu: brickd tcp:127.0.0.1:")
    n = len(_pcap_payloads(capture / "capture.pcap", v.DATA_PORT))
    row = next(line for line in r.stdout.splitlines() if "lidar sent" in line)
    assert row.split()[-2] == str(n)
    bad = subprocess.run([sys.executable, "-m", "tripod_processor", "replay", "/nonexistent"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no such" in bad.stderr


def test_imu_to_a_serial_device(capture):
    """serial:DEV goes through pyserial; a pty's slave stands in for the device here."""
    import select
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    name = os.ttyname(slave)
    sink = open_imu_sink(f"serial:{name}@921600")
    got = bytearray()
    try:
        st = Replayer(ReplaySource.open(capture), rate=float("inf"), lidar_addr=("127.0.0.1", 9),
                      position_addr=("127.0.0.1", 9), imu_sink=sink, limit_s=0.5).run()
        deadline = time.monotonic() + 5
        while len(got) < st.imu_bytes_sent and time.monotonic() < deadline:
            r, _, _ = select.select([master], [], [], 0.2)
            if r:
                got.extend(os.read(master, 65536))
    finally:
        sink.close()
        os.close(master)
        os.close(slave)
    recs = list(ImuLogReader(capture / "imu.tripimu"))[: st.sent["imu"]]
    assert st.sent["imu"] > 10 and bytes(got) == b"".join(r.data for r in recs)
    with pytest.raises(ReplayInputError, match="cannot open serial"):
        open_imu_sink("serial:/dev/does-not-exist")


def test_loops_and_stop(capture):
    hole = ("127.0.0.1", 9)
    once = Replayer(ReplaySource.open(capture), rate=float("inf"), lidar_addr=hole,
                    position_addr=hole).run()
    twice = Replayer(ReplaySource.open(capture), rate=float("inf"), lidar_addr=hole,
                     position_addr=hole, loops=2).run()
    assert twice.sent["lidar"] == 2 * once.sent["lidar"] > 0
    assert twice.capture_span_s == pytest.approx(2 * once.capture_span_s + 0.001, abs=1e-6)
    # forever, until stopped from another thread
    rp = Replayer(ReplaySource.open(capture), rate=50.0, lidar_addr=hole, position_addr=hole,
                  loops=0)
    threading.Timer(0.5, rp.stop_event.set).start()
    st = rp.run()
    assert st.stopped_early and st.sent["lidar"] > 0
