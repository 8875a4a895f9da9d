# SPDX-License-Identifier: BSD-3-Clause
"""Load, short version: 20x the VLP-16 dual-return packet rate (>= 30,000 packets/s) into a
running daemon for 3 s with recording and Zenoh on: nothing lost, all byte-exact and in order.
The 30-s run, the highest zero-loss rate and the CPU use at 1x are in ``bench/daemon.py``."""

from __future__ import annotations

from tripod_shared.recording import RecordingReader
from tripod_shared.velodyne import VLP16_PACKET_PERIOD_US

from daemon_helpers import (
    RunningDaemon,
    loopback_config,
    make_data_packet,
    send_paced_in_process,
)

DUAL_RATE_HZ = 1e6 / VLP16_PACKET_PERIOD_US["dual"]  # 1507 packets/s


def test_twenty_times_dual_rate_without_loss(tmp_path):
    rate = max(30_000.0, 20 * DUAL_RATE_HZ)
    n = int(rate * 3)
    packets = [make_data_packet(i) for i in range(n)]
    cfg = loopback_config(
        tmp_path, lidar={"receive_buffer_bytes": 128 << 20},
        zenoh={"enabled": True, "listen": ["tcp/127.0.0.1:0"]},
        recording={"flush_interval_s": 1.0})
    with RunningDaemon(cfg) as d:
        achieved = send_paced_in_process(d.data_addr, 0, n, rate)
        assert d.wait_for(lambda: d.daemon.counts["lidar_data"] >= n, timeout=15)
        rc = d.stop()
    assert rc == 0
    assert achieved >= 0.9 * rate, f"sender only reached {achieved:.0f}/s"
    c = d.daemon.counts
    assert c["lidar_data"] == n and c["record_dropped"] == 0
    got = [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).lidar_packets()]
    assert len(got) == n
    assert got == packets
