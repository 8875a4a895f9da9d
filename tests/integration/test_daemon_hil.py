# SPDX-License-Identifier: BSD-3-Clause
"""Hardware-in-the-loop with the digital twin: ``tripod simulate`` makes a capture (VLP-16 dual
return + IMU Brick 2.0 byte stream), ``tripod replay``'s Replayer sends it over loopback UDP and
a pseudo-terminal into a running daemon; the recording and a Zenoh subscriber must hold every
packet and every IMU sample, byte-exact, in order, without duplicates."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest
import zenoh

from tripod_daemon.config import ZenohConfig
from tripod_daemon.publisher import build_zenoh_config
from tripod_shared import messages
from tripod_shared.recording import RecordingReader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from daemon_helpers import RunningDaemon, free_tcp_port, loopback_config  # noqa: E402

from tripod_processor.io.imu_log import ImuLogReader  # noqa: E402
from tripod_processor.io.pcap import PcapReader  # noqa: E402
from tripod_processor.io.replay import PtyImuSink, Replayer, ReplaySource  # noqa: E402
from tripod_processor.sim import SimConfig, simulate  # noqa: E402


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    cfg = SimConfig.model_validate({
        "stations": 1, "seed": 11, "lidar": {"return_mode": "dual"},
        "motion": {"pan_s": 2.0, "settle_s": 0.2, "pan_ramp_s": 0.3, "transit_s": 1.0},
    })
    out = tmp_path_factory.mktemp("hil") / "capture"
    simulate(cfg, out, nthreads=2)
    return out


def test_simulated_capture_replayed_into_the_daemon(capture, tmp_path):
    data = [d.payload for d in PcapReader(capture / "capture.pcap") if d.dst_port == 2368]
    pos = [d.payload for d in PcapReader(capture / "capture.pcap") if d.dst_port == 8308]
    imu_bytes = b"".join(r.data for r in ImuLogReader(capture / "imu.tripimu"))
    assert len(data) > 1000 and len(pos) > 50 and len(imu_bytes) > 1000

    sink = PtyImuSink()
    port = free_tcp_port()
    # the pty replays the IMU's bytes but cannot answer enumerate: name the simulated brick's UID
    cfg = loopback_config(tmp_path, imu={"url": sink.path, "driver": "tfp",
                                         "tfp_uid": SimConfig().imu.uid},
                          # block: the live path waits for this in-process subscriber, so it gets
                          # every packet (with the default, drop, a slow one loses its own)
                          zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"],
                                 "congestion_control": "block"})
    got: dict[str, list[bytes]] = {}
    lock = threading.Lock()
    seen_status = threading.Event()

    def on_sample(sample):
        leaf = str(sample.key_expr).split("/", 2)[2]
        if leaf == "status":
            seen_status.set()
        with lock:
            got.setdefault(leaf, []).append(sample.payload.to_bytes())

    # a subscriber peer: the daemon's own config builder, connecting to it
    zconf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        with RunningDaemon(cfg) as d, zenoh.open(zconf) as z:
            z.declare_subscriber(f"tripod/{cfg.device_id}/**", on_sample)
            assert seen_status.wait(15)
            assert d.wait_for(lambda: d.daemon.imu.connected)
            stats = Replayer(ReplaySource.open(capture), rate=4.0, lidar_addr=d.data_addr,
                             position_addr=d.position_addr, imu_sink=sink).run()
            c = d.daemon.counts
            assert d.wait_for(lambda: c["lidar_data"] == len(data)
                              and c["lidar_position"] == len(pos)
                              and c["imu_bytes"] == len(imu_bytes))
            assert d.wait_for(lambda: len(got.get("lidar/packets", [])) == len(data), timeout=10)
            assert d.stop() == 0
    finally:
        sink.close()
    assert stats.sent["lidar"] == len(data) and stats.send_errors == 0
    assert stats.imu_bytes_dropped == 0 and stats.imu_bytes_sent == len(imu_bytes)
    r = RecordingReader(d.daemon.recorder.files[0])
    assert [p for _n, p in r.lidar_packets()] == data
    assert [p for _n, p in r.position_packets()] == pos
    samples = list(r.imu_samples())
    assert b"".join(s.raw for s in samples) == imu_bytes  # every IMU byte framed, none garbage
    assert c["imu_garbage_bytes"] == 0 and c["lidar_malformed"] == 0
    assert len(samples) == c["imu_samples"] > 100
    assert [messages.decode_velodyne_packet(b)[1] for b in got["lidar/packets"]] == data
    assert [messages.decode_imu(b).raw for b in got["imu/quaternion"]] == [s.raw for s in samples]
