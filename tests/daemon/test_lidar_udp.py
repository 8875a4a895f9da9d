# SPDX-License-Identifier: BSD-3-Clause
"""UDP input: kernel stamps, the encoded message, source filter, receive buffer."""

from __future__ import annotations

import selectors
import socket
import time

from tripod_shared import messages, topics
from tripod_shared.mcap_writer import iter_items

from daemon_helpers import make_data_packet, udp_sender
from tripod_daemon.config import LidarConfig
from tripod_daemon.lidar_udp import LidarInput
from tripod_daemon.stats import Counters


def _input(**kw) -> LidarInput:
    cfg = LidarConfig(bind_address="127.0.0.1", data_port=0, position_port=0, **kw)
    return LidarInput(cfg, Counters())


def _drain_all(inp: LidarInput, sock, want: int, timeout: float = 5.0) -> list:
    out: list = []
    sel = selectors.DefaultSelector()
    sel.register(sock, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sel.select(0.1):
            inp.drain(sock, out)
        c = inp.counts
        if c["lidar_data"] + c["lidar_position"] + c["lidar_filtered"] + c["lidar_malformed"] >= want:
            break
    sel.close()
    return list(iter_items(out))


def test_packet_is_stamped_by_the_kernel_and_encoded_like_shared():
    inp = _input()
    try:
        # Linux turns receive timestamping on through deferred work the first time a socket
        # asks; until then it stamps at the read. A long-running daemon never notices; here one
        # warm-up packet makes the measurement below independent of that.
        udp_sender().sendto(make_data_packet(0), ("127.0.0.1", inp.data_port))
        _drain_all(inp, inp.data_sock, 1)
        time.sleep(0.05)
        inp.counts["lidar_data"] = inp.counts["lidar_bytes"] = 0
        pkt = make_data_packet(42)
        t0 = time.time_ns()
        udp_sender().sendto(pkt, ("127.0.0.1", inp.data_port))
        time.sleep(0.05)  # the stamp is the arrival, not the read
        t_read = time.time_ns()
        items = _drain_all(inp, inp.data_sock, 1)
        assert len(items) == 1
        topic, host_ns, data = items[0]
        assert topic == topics.TOPIC_LIDAR_PACKETS
        assert t0 <= host_ns < t_read - 20_000_000  # stamped on arrival, ~50 ms before the read
        assert data == messages.encode_velodyne_packet(host_ns, pkt)
        assert messages.decode_velodyne_packet(data) == (host_ns, pkt)
        assert inp.counts["lidar_bytes"] == 1206
    finally:
        inp.close()


def test_position_packet_and_pps_state_reach_the_clock():
    inp = _input()
    try:
        pos = bytearray(512)
        pos[198:202] = (1_234_567).to_bytes(4, "little")
        pos[202] = 2  # PPS locked
        nmea = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"
        pos[206 : 206 + len(nmea)] = nmea
        udp_sender().sendto(bytes(pos), ("127.0.0.1", inp.position_port))
        items = _drain_all(inp, inp.position_sock, 1)
        assert [(t, len(d)) for t, _n, d in items] == [(topics.TOPIC_LIDAR_POSITION, 512 + 12)]
        assert messages.decode_position_packet(items[0][2])[1] == bytes(pos)
        assert inp.clock.pps_state == "locked" and inp.clock.nmea.startswith("$GPRMC")
        assert inp.clock.summary()["pps_host_error_ns"] is not None
    finally:
        inp.close()


def test_source_filter():
    inp = _input(source_addresses=["192.0.2.7"])  # a sensor that is not us
    try:
        udp_sender().sendto(make_data_packet(1), ("127.0.0.1", inp.data_port))
        assert _drain_all(inp, inp.data_sock, 1) == []
        assert inp.counts["lidar_filtered"] == 1 and inp.counts["lidar_data"] == 0
    finally:
        inp.close()
    inp = _input(source_addresses=["127.0.0.1"])
    try:
        udp_sender().sendto(make_data_packet(1), ("127.0.0.1", inp.data_port))
        assert len(_drain_all(inp, inp.data_sock, 1)) == 1
    finally:
        inp.close()


def test_receive_buffer_is_large():
    inp = _input(receive_buffer_bytes=8 << 20)
    try:
        # root (or CAP_NET_ADMIN) gets SO_RCVBUFFORCE; otherwise net.core.rmem_max caps it
        with open("/proc/sys/net/core/rmem_max") as fh:
            rmem_max = int(fh.read())
        assert inp.data_rcvbuf >= min(8 << 20, rmem_max)
        assert inp.data_sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= 2 * min(
            8 << 20, rmem_max)
    finally:
        inp.close()


def test_port_in_use_is_an_error_not_a_crash():
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))
    try:
        import pytest

        cfg = LidarConfig(bind_address="127.0.0.1", data_port=blocker.getsockname()[1],
                          position_port=0)
        with pytest.raises(OSError):
            LidarInput(cfg, Counters())
    finally:
        blocker.close()


def test_kernel_drops_are_counted():
    inp = _input(receive_buffer_bytes=65536)  # a tiny buffer: ~30 packets fit
    try:
        s = udp_sender()
        n = 400
        for k in range(n):  # nobody reads meanwhile: the kernel must drop most
            s.sendto(make_data_packet(k), ("127.0.0.1", inp.data_port))
        time.sleep(0.05)
        items = _drain_all(inp, inp.data_sock, n, timeout=1.0)
        received = len(items)
        assert received < n
        # the next datagram after the overflow carries the count
        s.sendto(make_data_packet(n), ("127.0.0.1", inp.data_port))
        time.sleep(0.05)
        _drain_all(inp, inp.data_sock, received + 1, timeout=1.0)
        assert inp.counts["lidar_kernel_drops"] == n - received
    finally:
        inp.close()
