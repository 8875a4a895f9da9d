# SPDX-License-Identifier: BSD-3-Clause
"""Hardware-in-the-loop: real VLP-16 captures and a simulated IMU replayed into a running daemon
over loopback UDP and a pseudo-terminal; the recording and a Zenoh subscriber must hold every
packet and sample, byte-exact, in order, without duplicates."""

from __future__ import annotations

import math
import threading
import time

import pytest

from tripod_shared import messages, tfp, witmotion
from tripod_shared.recording import RecordingReader
from tripod_shared.velodyne import DATA_PORT, POSITION_PORT

from daemon_helpers import (
    FakePty,
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    read_pcap_udp,
    send_paced,
    udp_sender,
)

CAPTURES = [
    # file, data packets, position packets (counts from ../shared/data/README.md)
    ("veloview-vlp16-20hz.pcap", 1902, 367),
    ("mrpt-vlp16-gps.pcap", 293, 57),
    ("scanparser-vlp16-gaps.pcap", 41, 36),  # + one real 200-byte runt on 8308: malformed
    ("rustlidar-vlp16.pcap", 84, 0),
    ("rustlidar-vlp16-id0x21.pcap", 84, 16),
]


def _split(path):
    pk = read_pcap_udp(path)
    data = [p for port, p in pk if port == DATA_PORT]
    pos = [p for port, p in pk if port == POSITION_PORT]
    return data, pos


def _imu_stream(n: int, driver: str, uid: int = 0x1234ABCD) -> list[bytes]:
    """A head turning about z at 0.5 rad/s, 100 Hz: frames exactly as the device sends them."""
    frames = []
    for k in range(n):
        yaw = 0.5 * k * 0.01
        w, z = math.cos(yaw / 2), math.sin(yaw / 2)
        if driver == "tfp":
            frames.append(tfp.encode_quaternion_callback(uid, w, 0.0, 0.0, z))
        else:
            frames.append(witmotion.encode_quaternion(w, 0.0, 0.0, z))
    return frames


def _write_paced(dev: FakePty, frames: list[bytes], period_s: float = 0.002) -> threading.Thread:
    def run():
        for f in frames:
            dev.write(f)
            time.sleep(period_s)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _recorded(path):
    r = RecordingReader(path)
    data = [p for _ns, p in r.lidar_packets()]
    pos = [p for _ns, p in r.position_packets()]
    imu = list(r.imu_samples())
    assert not r.report.truncated, r.report.error
    return data, pos, imu


@pytest.mark.parametrize("name,n_data,n_pos", CAPTURES)
def test_replay_real_capture_is_recorded_byte_exact(name, n_data, n_pos, velodyne_dir, tmp_path):
    data, pos_all = _split(velodyne_dir / name)
    pos = [p for p in pos_all if len(p) == 512]
    assert (len(data), len(pos)) == (n_data, n_pos)
    cfg = loopback_config(tmp_path)
    with RunningDaemon(cfg) as d:
        s = udp_sender()
        # interleave as on the wire: the position port gets its packets between data packets
        step = max(1, len(data) // max(1, len(pos_all)))
        pi = 0
        for i, p in enumerate(data):
            s.sendto(p, d.data_addr)
            if pos_all and i % step == 0 and pi < len(pos_all):
                s.sendto(pos_all[pi], d.position_addr)
                pi += 1
            if i % 64 == 0:
                time.sleep(0.001)
        for p in pos_all[pi:]:
            s.sendto(p, d.position_addr)
        assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == len(data)
                          and d.daemon.counts["lidar_position"] == len(pos)
                          and d.daemon.counts["lidar_malformed"] == len(pos_all) - len(pos))
        rc = d.stop()
    assert rc == 0
    files = d.daemon.recorder.files
    assert len(files) == 1
    rec_data, rec_pos, _ = _recorded(files[0])
    assert rec_data == data  # every packet, byte-exact, in order, no duplicates
    assert rec_pos == pos
    c = d.daemon.counts
    assert c["lidar_malformed"] == len(pos_all) - len(pos)
    assert c["lidar_foreign"] == c["record_dropped"] == 0


def test_replay_capture_with_imu_and_zenoh_subscriber(velodyne_dir, tmp_path):
    import zenoh

    from tripod_daemon.config import ZenohConfig
    from tripod_daemon.publisher import build_zenoh_config

    data, pos = _split(velodyne_dir / "mrpt-vlp16-gps.pcap")
    frames = _imu_stream(300, "tfp")
    dev = FakePty(tmp_path / "tripod-imu")
    port = free_tcp_port()
    cfg = loopback_config(
        tmp_path,
        imu={"url": str(dev.link), "driver": "tfp"},
        # block: this test checks that the live bytes are the recorded ones, for a subscriber
        # in this very process (it shares the interpreter lock with the daemon, so on a busy
        # machine it can fall behind, and with "drop" Zenoh would rightly drop its samples;
        # drop's isolation of a slow subscriber is test_publisher's)
        zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"],
               "congestion_control": "block"},
    )
    got: dict[str, list[bytes]] = {"lidar/packets": [], "lidar/position": [],
                                   "imu/quaternion": [], "status": []}
    lock = threading.Lock()

    def on_sample(sample):
        leaf = str(sample.key_expr).split("/", 2)[2]
        with lock:
            got.setdefault(leaf, []).append(sample.payload.to_bytes())

    # a subscriber peer: the daemon's own config builder, connecting to it
    zconf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        with RunningDaemon(cfg) as d:
            with zenoh.open(zconf) as session:
                sub = session.declare_subscriber(f"tripod/{cfg.device_id}/**", on_sample)
                # a status sample proves the subscription reached the daemon
                assert d.wait_for(lambda: len(got["status"]) > 0)
                assert d.wait_for(lambda: d.daemon.imu.connected)
                # the brick answers the daemon's enumerate before it streams (as brickd does)
                assert tfp.FID_ENUMERATE in dev.read_available(0.3)[:8]
                dev.write(tfp.encode_enumerate_callback(0x1234ABCD))
                writer = _write_paced(dev, frames)
                s = udp_sender()
                send_paced(s, d.data_addr, data, rate_hz=3000)
                send_paced(s, d.position_addr, pos, rate_hz=3000)
                writer.join()
                assert d.wait_for(lambda: d.daemon.counts["imu_samples"] == len(frames)
                                  and d.daemon.counts["lidar_data"] == len(data))
                assert d.wait_for(lambda: len(got["imu/quaternion"]) == len(frames)
                                  and len(got["lidar/packets"]) == len(data), timeout=10)
                sub.undeclare()
            rc = d.stop()
    finally:
        dev.close()
    assert rc == 0
    rec_data, rec_pos, rec_imu = _recorded(d.daemon.recorder.files[0])
    assert rec_data == data and rec_pos == pos
    assert [s.raw for s in rec_imu] == frames  # every sample, as read, in order
    assert all(s.driver == "tfp" and s.device_time_ns == -1 for s in rec_imu)
    # host stamps at the read are non-decreasing and within the run
    stamps = [s.host_ns for s in rec_imu]
    assert stamps == sorted(stamps)
    # the subscriber got the very bytes that were recorded
    assert [messages.decode_velodyne_packet(b)[1] for b in got["lidar/packets"]] == data
    assert [messages.decode_position_packet(b)[1] for b in got["lidar/position"]] == pos
    assert [messages.decode_imu(b).raw for b in got["imu/quaternion"]] == frames
    assert d.daemon.counts["zenoh_dropped"] == 0


def test_witmotion_imu_is_recorded(tmp_path):
    frames = _imu_stream(200, "witmotion")
    dev = FakePty(tmp_path / "tripod-imu")
    cfg = loopback_config(tmp_path, imu={"url": str(dev.link), "driver": "witmotion"})
    try:
        with RunningDaemon(cfg) as d:
            assert d.wait_for(lambda: d.daemon.imu.connected)
            _write_paced(dev, frames, 0.001).join()
            assert d.wait_for(lambda: d.daemon.counts["imu_samples"] == len(frames))
            d.stop()
    finally:
        dev.close()
    _, _, rec_imu = _recorded(d.daemon.recorder.files[0])
    assert [s.raw for s in rec_imu] == frames
    assert rec_imu[0].driver == "witmotion"
    assert rec_imu[10].q_world_imu == pytest.approx(witmotion.decode_quaternion(frames[10][2:10]))


def test_foreign_sensor_is_counted_not_recorded(velodyne_dir, tmp_path):
    data, _ = _split(velodyne_dir / "mrpt-hdl32e.pcap")
    cfg = loopback_config(tmp_path, lidar={"accept_products": [0x22]})
    with RunningDaemon(cfg) as d:
        send_paced(udp_sender(), d.data_addr, data, rate_hz=5000)
        assert d.wait_for(lambda: d.daemon.counts["lidar_foreign"] == len(data))
        d.stop()
    rec_data, _, _ = _recorded(d.daemon.recorder.files[0])
    assert rec_data == [] and d.daemon.counts["lidar_data"] == 0
