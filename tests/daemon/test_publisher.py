# SPDX-License-Identifier: BSD-3-Clause
"""The live path: a slow subscriber never stalls reception or recording; its drops are counted."""

from __future__ import annotations

import threading
import time

import zenoh

from tripod_shared import messages, topics
from tripod_shared.lidar_block import LidarBlockDecoder, max_packets_for
from tripod_shared.recording import RecordingReader

from daemon_helpers import (
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    make_data_packet,
    send_paced,
    send_paced_in_process,
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


class BlockSubscriber:
    """A live consumer of the lidar blocks, as a Python program should take a fast stream: a
    FIFO channel inside zenoh (no Python call, no interpreter lock on zenoh's receive thread)
    read by a thread of its own, which decodes the blocks (counting what it misses) and keeps
    (host_ns, payload) of every packet; ``delay_s`` per block makes it slow. The subscriber's
    own process here also runs the daemon, whose threads hold the interpreter lock for up to
    its switch interval (5 ms) at a time: a callback per sample would wait for it each time."""

    def __init__(self, session, key: str, delay_s: float = 0.0, capacity: int = 1024):
        self.decoder = LidarBlockDecoder()
        self.packets: list[tuple[int, bytes]] = []
        self.sizes: list[int] = []
        self.delay_s = delay_s
        self.last_mono = 0.0
        self.sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))
        self.thread = threading.Thread(target=self._run, args=(self.sub.handler,), daemon=True)
        self.thread.start()

    def _run(self, handler) -> None:
        while True:
            try:
                sample = handler.recv()
            except zenoh.ZError:  # undeclared, or the session closed
                return
            blk = self.decoder.decode(sample.payload.to_bytes())
            self.last_mono = time.monotonic()
            if blk is not None:
                self.sizes.append(len(blk))
                self.packets += blk.packets()
            if self.delay_s:
                time.sleep(self.delay_s)


def _wait_status(z, cfg) -> None:
    seen = threading.Event()
    sub = z.declare_subscriber(f"tripod/{cfg.device_id}/status", lambda _s: seen.set())
    assert seen.wait(15)
    sub.undeclare()


def test_block_subscriber_gets_every_packet(tmp_path):
    """End to end over loopback at a moderate paced rate (10,000 packets/s, a separate sender
    process): a subscriber of the lidar blocks gets every packet, in order, with the recording's
    stamps, in blocks of at most lidar_block_bytes; nobody asked for the per-packet key, so the
    daemon published none."""
    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    conf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    n = 20_000
    with RunningDaemon(cfg) as d, zenoh.open(conf) as z:
        sub = BlockSubscriber(z, topics.key_lidar_blocks(cfg.device_id))
        _wait_status(z, cfg)
        send_paced_in_process(d.data_addr, 0, n, 10_000, burst=8)
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_data"] == n, timeout=20)
        assert d.wait_for(lambda: len(sub.packets) >= n, timeout=20), len(sub.packets)
        assert d.stop(timeout=30) == 0
    assert [p for _ns, p in sub.packets] == [make_data_packet(k) for k in range(n)]
    recorded = list(RecordingReader(d.daemon.recorder.files[0]).lidar_packets())
    assert [ns for ns, _p in sub.packets] == [ns for ns, _p in recorded]  # the kernel stamps
    dec = sub.decoder
    assert (dec.packets, dec.missing, dec.rejected_total) == (n, 0, 0)
    assert max(sub.sizes) <= max_packets_for(cfg.zenoh.lidar_block_bytes, 1206)
    assert c["zenoh_lidar_packets"] == n and c["zenoh_lidar_blocks"] == len(sub.sizes)
    assert c["zenoh_lidar_per_packet"] == 0 and c["zenoh_dropped"] == 0


_SLOW_SUBSCRIBER = r"""
import json, sys, threading, time, zenoh
from tripod_shared import topics
from tripod_shared.lidar_block import LidarBlockDecoder
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
# a small receive buffer: what the kernel holds for this subscriber is drained in seconds
conf.insert_json5("transport/link/tcp/so_rcvbuf", "131072")
conf.insert_json5("transport/shared_memory/enabled", "false")
dec, seqs, last = LidarBlockDecoder(), [], [0.0]
with zenoh.open(conf) as z:
    sub = z.declare_subscriber(topics.key_lidar_blocks(sys.argv[2]), zenoh.handlers.FifoChannel(4))
    def run(handler):
        while True:
            try:
                sample = handler.recv()
            except zenoh.ZError:
                return
            blk = dec.decode(sample.payload.to_bytes())
            if blk is not None:
                seqs.extend(blk.payloads[:, 2:6].copy().view("<u4")[:, 0].tolist())
            last[0] = time.monotonic()
            time.sleep(float(sys.argv[3]))  # slow: this long per block
    threading.Thread(target=run, args=(sub.handler,), daemon=True).start()
    print("subscribed", flush=True)
    sys.stdin.read()  # until the test closes our stdin
    while time.monotonic() - last[0] < 1.0:  # what is on its way still comes
        time.sleep(0.1)
    print(json.dumps({"packets": dec.packets, "missing": dec.missing, "next": dec.next_index,
                      "seqs": seqs}), flush=True)
"""


def test_slow_block_subscriber_loses_only_its_own_data_and_counts_it(tmp_path):
    """congestion_control: drop: a stalled block subscriber (its own process, as on a real
    network) loses blocks of its own and counts exactly how many packets (the blocks' numbers),
    while a fast one beside it and the recording get every packet."""
    import json
    import subprocess
    import sys

    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    conf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    n, tail = 20_000, 60  # 24 MB in 4 s, then a few packets once the slow one is idle
    key = topics.key_lidar_blocks(cfg.device_id)
    with RunningDaemon(cfg) as d, zenoh.open(conf) as zf:
        fast = BlockSubscriber(zf, key)
        slow = subprocess.Popen(  # 20 blocks/s at most
            [sys.executable, "-c", _SLOW_SUBSCRIBER, f"tcp/127.0.0.1:{port}", cfg.device_id,
             "0.05"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert slow.stdout.readline().strip() == "subscribed"
            _wait_status(zf, cfg)
            time.sleep(1.0)  # the slow one's subscription has reached the daemon
            send_paced_in_process(d.data_addr, 0, n, 5_000, burst=8)
            c = d.daemon.counts
            assert d.wait_for(lambda: c["lidar_data"] == n, timeout=20)
            assert d.wait_for(lambda: len(fast.packets) == n, timeout=20), (
                len(fast.packets), fast.decoder.missing)
            # the slow one drains what the kernel holds for it (the daemon's send buffer grows
            # to 4 MiB: ~3 s for it), then the tail in 3 rounds, a second apart
            time.sleep(3.0)
            for r in range(3):
                time.sleep(1.0)
                send_paced(udp_sender(), d.data_addr,
                           [make_data_packet(n + k) for k in range(r * 20, r * 20 + 20)], 100,
                           burst=1)
            assert d.wait_for(lambda: len(fast.packets) == n + tail, timeout=10)
            out, _ = slow.communicate("", timeout=60)
        finally:
            if slow.poll() is None:
                slow.kill()
        assert d.stop(timeout=30) == 0
    got = json.loads(out.strip().splitlines()[-1])
    every = [make_data_packet(k) for k in range(n + tail)]
    assert [p for _ns, p in fast.packets] == every and fast.decoder.missing == 0
    # the slow one lost some, and knows exactly how many: its blocks' numbers
    assert got["missing"] > 0 and got["packets"] + got["missing"] == got["next"] == n + tail
    assert got["seqs"] == sorted(set(got["seqs"])) and got["seqs"][-1] == n + tail - 1
    assert c["zenoh_dropped"] == 0 and c["record_dropped"] == 0
    assert [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).lidar_packets()] == every
