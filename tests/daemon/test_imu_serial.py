# SPDX-License-Identifier: BSD-3-Clause
"""IMU through pyserial's socket:// URL (brickd's TCP port): the TFP handshake, samples, and
reconnection when brickd goes away and comes back."""

from __future__ import annotations

import socket
import threading
import time

from tripod_shared import tfp
from tripod_shared.recording import RecordingReader

from daemon_helpers import RunningDaemon, loopback_config
from tripod_daemon.config import ImuConfig
from tripod_daemon.imu_serial import ImuInput
from tripod_daemon.stats import Counters

UID = 0x6E1A2B


class FakeBrickd:
    """A TCP server speaking TFP like brickd with one IMU Brick 2.0 behind it."""

    def __init__(self, port: int = 0):
        self.srv = socket.socket()
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.srv.bind(("127.0.0.1", port))
        self.srv.listen(1)
        self.port = self.srv.getsockname()[1]
        self.periods: list[int] = []
        self.sent: list[bytes] = []
        self.conn: socket.socket | None = None

    def serve_one(self, n_samples: int) -> None:
        """Accept the daemon, answer enumerate, wait for the period request, stream samples."""
        conn, _ = self.srv.accept()
        self.conn = conn
        parser_buf = b""
        conn.settimeout(5)
        while not self.periods or len(self.periods) < self._want:
            parser_buf += conn.recv(256)
            while len(parser_buf) >= 8:
                length, fid = parser_buf[4], parser_buf[5]
                if len(parser_buf) < length:
                    break
                pkt, parser_buf = parser_buf[:length], parser_buf[length:]
                if fid == tfp.FID_ENUMERATE:
                    conn.sendall(tfp.encode_enumerate_callback(UID))
                elif fid == tfp.FID_SET_QUATERNION_PERIOD:
                    self.periods.append(int.from_bytes(pkt[8:12], "little"))
        for k in range(n_samples):
            f = tfp.encode_quaternion_callback(UID, 1.0, 0.0, 0.0, 0.001 * k)
            self.sent.append(f)
            conn.sendall(f)
            time.sleep(0.002)

    def serve_in_thread(self, n_samples: int, want_periods: int) -> threading.Thread:
        self._want = want_periods
        t = threading.Thread(target=self.serve_one, args=(n_samples,), daemon=True)
        t.start()
        return t

    def drop_client(self) -> None:
        if self.conn:
            self.conn.close()
            self.conn = None

    def close(self) -> None:
        self.drop_client()
        self.srv.close()


def test_brickd_socket_url_handshake_samples_and_reconnect(tmp_path):
    brickd = FakeBrickd()
    cfg = loopback_config(tmp_path, imu={"url": f"socket://127.0.0.1:{brickd.port}",
                                         "driver": "tfp", "quaternion_period_ms": 5,
                                         "reconnect_interval_s": 0.2})
    try:
        server = brickd.serve_in_thread(100, want_periods=1)
        with RunningDaemon(cfg) as d:
            c = d.daemon.counts
            server.join(20)
            assert brickd.periods == [5]  # the daemon asked for the configured period
            assert d.wait_for(lambda: c["imu_samples"] == 100)
            brickd.drop_client()  # brickd restarted
            server = brickd.serve_in_thread(50, want_periods=2)
            server.join(20)
            assert d.wait_for(lambda: c["imu_samples"] == 150)
            assert c["imu_connects"] == 2 and c["imu_disconnects"] == 1
            assert d.stop() == 0
    finally:
        brickd.close()
    rec = [s.raw for s in RecordingReader(d.daemon.recorder.files[0]).imu_samples()]
    assert rec == brickd.sent


def test_missing_device_is_retried_quietly_without_crashing(tmp_path):
    counts = Counters()
    imu = ImuInput(ImuConfig(url=str(tmp_path / "no-such-tty"), reconnect_interval_s=0.05),
                   counts)
    assert imu.try_open() is False and "no-such-tty" in imu.last_error
    assert imu.try_open() is False  # within the interval: not even tried
    time.sleep(0.06)
    assert imu.try_open() is False and counts["imu_connects"] == 0
    bad = ImuInput(ImuConfig(url="nonsense://x"), Counters())
    assert bad.try_open() is False and bad.last_error
