# SPDX-License-Identifier: BSD-3-Clause
"""The live path: a slow subscriber never stalls reception or recording; its drops are counted."""

from __future__ import annotations

import threading
import time

import zenoh

from tripod_shared import messages
from tripod_shared.recording import RecordingReader

from daemon_helpers import (
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    make_data_packet,
    send_paced,
    udp_sender,
)
from tripod_daemon.config import ZenohConfig
from tripod_daemon.publisher import build_zenoh_config


def test_zenoh_config_from_our_keys():
    conf = build_zenoh_config(ZenohConfig(mode="client", connect=["tcp/10.1.2.3:7447"],
                                          listen=["tcp/127.0.0.1:7448"]))
    assert '"client"' in conf.get_json("mode")
    assert "tcp/10.1.2.3:7447" in conf.get_json("connect/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"  # off unless asked


def test_slow_subscriber_drops_are_counted_and_recording_is_complete(tmp_path):
    port = free_tcp_port()
    # congestion_control: block -- publishing waits for the slow subscriber, our queue overflows
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"],
                                           "queue_messages": 500, "congestion_control": "block"})
    # a subscriber peer: the daemon's own config builder, connecting to it
    conf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    received = [0]
    status_seen = threading.Event()

    def slow(sample):
        if str(sample.key_expr).endswith("/status"):
            status_seen.set()
            return
        received[0] += 1
        time.sleep(0.002)  # a subscriber that manages 500 messages/s, far below the stream

    n = 20_000
    packets = [make_data_packet(k) for k in range(n)]
    with RunningDaemon(cfg) as d, zenoh.open(conf) as z:
        z.declare_subscriber(f"tripod/{cfg.device_id}/**", slow)
        assert status_seen.wait(15)
        t0 = time.monotonic()
        send_paced(udp_sender(), d.data_addr, packets, 10_000)
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_data"] == n, timeout=10)
        received_in_time = time.monotonic() - t0
        assert d.wait_for(lambda: c["zenoh_dropped"] + c["zenoh_published"] >= n, timeout=20)
        t_stop = time.monotonic()
        assert d.stop(timeout=30) == 0
        stop_s = time.monotonic() - t_stop
    assert received_in_time < 6  # reception kept pace with the sender (2 s of packets)
    assert c["zenoh_dropped"] > 0 and c["record_dropped"] == 0
    assert received[0] < n
    got = [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).lidar_packets()]
    assert got == packets  # the recording is complete whatever the subscriber does
    assert stop_s < 15


def test_slow_subscriber_loses_only_its_own_data(tmp_path):
    """congestion_control: drop (the default): zenoh queues per link, so a stalled subscriber
    loses its own samples while a fast one beside it gets every packet, and so does the file."""
    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    assert cfg.zenoh.congestion_control == "drop"
    key = f"tripod/{cfg.device_id}/lidar/packets"
    conf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    fast: list[bytes] = []
    slow = [0]
    seen = [threading.Event(), threading.Event()]

    def on_fast(sample):
        fast.append(sample.payload.to_bytes())

    def on_slow(sample):
        slow[0] += 1
        time.sleep(0.005)  # manages 200 samples/s, far below the stream

    n = 6_000  # 4 s at the VLP-16's dual-return rate
    packets = [make_data_packet(k) for k in range(n)]
    with RunningDaemon(cfg) as d, zenoh.open(conf) as zf, zenoh.open(conf) as zs:
        for i, z in enumerate((zf, zs)):
            z.declare_subscriber(f"tripod/{cfg.device_id}/status",
                                 lambda _s, e=seen[i]: e.set())
        zf.declare_subscriber(key, on_fast)
        zs.declare_subscriber(key, on_slow)
        assert seen[0].wait(15) and seen[1].wait(15)
        send_paced(udp_sender(), d.data_addr, packets, 1508, burst=8)
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_data"] == n, timeout=10)
        assert d.wait_for(lambda: len(fast) == n, timeout=10), (len(fast), slow[0])
        slow_then = slow[0]
        assert d.stop(timeout=30) == 0
    assert [messages.decode_velodyne_packet(b)[1] for b in fast] == packets  # all, in order
    assert slow_then < n  # the slow one lost (or had not yet got) its share
    assert c["zenoh_dropped"] == 0 and c["record_dropped"] == 0
    got = [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).lidar_packets()]
    assert got == packets
