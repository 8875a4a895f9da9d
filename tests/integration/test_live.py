# SPDX-License-Identifier: BSD-3-Clause
"""``tripod live`` end to end: a simulated two-station capture (dual return + IMU) replayed at 1x
into a running daemon; ``tripod live`` (its own process) subscribes to the daemon's Zenoh stream
and serves Foxglove; a plain WebSocket client speaking the Foxglove protocol
(``foxglove.sdk.v1``, foxglove.websocket.v1's successor: serverInfo, advertise, subscribe, binary messageData) receives the
rotations, the transforms, the coverage map and the stations, decoded with the schemas the server
advertised."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "daemon"))
from daemon_helpers import RunningDaemon, free_tcp_port, loopback_config  # noqa: E402

from tripod_processor.io.pcap import PcapReader  # noqa: E402
from tripod_processor.io.replay import PtyImuSink, Replayer, ReplaySource  # noqa: E402
from tripod_processor.sim import SimConfig, simulate  # noqa: E402

websockets = pytest.importorskip("websockets")  # a dev requirement: present under `make test`


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    cfg = SimConfig.model_validate({
        "stations": 2, "seed": 7, "lidar": {"return_mode": "dual"},
        "motion": {"pan_s": 2.0, "settle_s": 0.2, "pan_ramp_s": 0.3, "transit_s": 1.0},
    })
    out = tmp_path_factory.mktemp("live") / "capture"
    simulate(cfg, out, nthreads=2)
    return out


def _message_class(channel: dict):
    """The protobuf class of an advertised channel (schema: a base64 FileDescriptorSet)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    todo = list(fds.file)
    while todo:  # dependencies first, whatever the order in the set
        left = []
        for f in todo:
            try:
                pool.Add(f)
            except Exception:  # noqa: BLE001 - a dependency not added yet
                left.append(f)
        assert len(left) < len(todo), "unresolvable schema"
        todo = left
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class FoxgloveClient:
    """Collects (topic, log_time_ns, decoded message) of every advertised channel."""

    def __init__(self, port: int):
        self.port = port
        self.got: list[tuple[str, int, object]] = []
        self.server_info: dict = {}
        self.channels: dict[int, dict] = {}
        self.stop = threading.Event()
        self.subscribed = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    async def _main(self) -> None:
        url = f"ws://127.0.0.1:{self.port}"
        # foxglove-sdk >= 0.30 speaks the protocol as "foxglove.sdk.v1" (the same operations
        # as "foxglove.websocket.v1", which older servers name): offer both
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1",
                                                         "foxglove.websocket.v1"],
                                      max_size=None) as ws:
            self.subprotocol = ws.subprotocol
            subs: dict[int, dict] = {}
            classes: dict[int, object] = {}
            next_id = 1
            t_sub = None
            while not self.stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    msg = None
                if isinstance(msg, str):
                    m = json.loads(msg)
                    if m["op"] == "serverInfo":
                        self.server_info = m
                    elif m["op"] == "advertise":
                        new = []
                        for ch in m["channels"]:
                            self.channels[ch["id"]] = ch
                            subs[next_id] = ch
                            new.append({"id": next_id, "channelId": ch["id"]})
                            next_id += 1
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                        t_sub = time.monotonic()
                elif isinstance(msg, bytes) and msg[0] == 0x01:  # messageData
                    sub_id, log_ns = struct.unpack_from("<IQ", msg, 1)
                    ch = subs[sub_id]
                    payload = msg[13:]
                    if ch["encoding"] == "json":
                        obj = json.loads(payload)
                    else:
                        if sub_id not in classes:
                            classes[sub_id] = _message_class(ch)
                        obj = classes[sub_id].FromString(payload)
                    self.got.append((ch["topic"], log_ns, obj))
                if t_sub is not None and time.monotonic() - t_sub > 0.5:
                    self.subscribed.set()

    def of(self, topic: str) -> list:
        return [m for t, _, m in self.got if t == topic]


def _wait_port(port: int, timeout: float) -> bool:
    import socket

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.1)
    return False


def _cloud_xyz(pc) -> np.ndarray:
    off = {f.name: f.offset for f in pc.fields}
    raw = np.frombuffer(pc.data, np.uint8).reshape(-1, pc.point_stride)
    return np.stack([raw[:, off[c]:off[c] + 4].copy().view("<f4")[:, 0] for c in "xyz"], axis=1)


def test_live_view_over_foxglove_websocket(capture, tmp_path):
    n_data = sum(1 for d in PcapReader(capture / "capture.pcap") if d.dst_port == 2368)
    sink = PtyImuSink()
    zport, wport = free_tcp_port(), free_tcp_port()
    cfg = loopback_config(tmp_path, imu={"url": sink.path, "driver": "tfp",
                                         "tfp_uid": SimConfig().imu.uid},
                          zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{zport}"]})
    live = None
    client = FoxgloveClient(wport)
    try:
        with RunningDaemon(cfg) as d:
            assert d.wait_for(lambda: d.daemon.imu.connected)
            live = subprocess.Popen(
                [sys.executable, "-m", "tripod_processor", "live", "--connect",
                 f"tcp/127.0.0.1:{zport}", "--port", str(wport), "--duration", "60"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                env={**os.environ, "PYTHONUNBUFFERED": "1"})
            assert _wait_port(wport, 30), "tripod live did not open its WebSocket port"
            client.thread.start()
            assert client.subscribed.wait(10), client.error
            time.sleep(1.0)  # the live view's zenoh session has reached the daemon
            stats = Replayer(ReplaySource.open(capture), rate=1.0, lidar_addr=d.data_addr,
                             position_addr=d.position_addr, imu_sink=sink).run()
            assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == n_data)
            time.sleep(2.5)  # the last rotation, and the stream-stopped station end
            client.stop.set()
            client.thread.join(10)
            live.send_signal(signal.SIGTERM)
            out, err = live.communicate(timeout=20)
            d.stop()
    finally:
        sink.close()
        if live is not None and live.poll() is None:
            live.kill()
    assert client.error is None, client.error
    assert live.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    print("tripod live:", json.dumps(summary))

    # the protocol: serverInfo, then the advertised channels with Foxglove's schemas
    assert client.server_info.get("op") == "serverInfo"
    topics = {c["topic"]: c for c in client.channels.values()}
    assert topics["/lidar/points"]["schemaName"] == "foxglove.PointCloud"
    assert topics["/tf"]["schemaName"] == "foxglove.FrameTransforms"

    # the current rotation: dual-return VLP-16 rotations in the lidar frame
    clouds = client.of("/lidar/points")
    rotations = n_data / 150.7  # 10 Hz, dual return: 1507 packets/s
    assert len(clouds) >= 0.7 * rotations
    assert summary["rotations_shown"] >= len(clouds) - 1
    assert summary["rotations_shown"] + summary["rotations_dropped"] >= summary["rotations"] - 1
    full = [pc for pc in clouds if len(pc.data) // pc.point_stride > 20000]
    assert len(full) >= 0.6 * rotations  # a whole dual-return rotation: ~2 x 16 x 900 returns
    xyz = _cloud_xyz(full[len(full) // 2])
    r = np.linalg.norm(xyz, axis=1)
    assert all(pc.frame_id == "lidar" for pc in clouds)
    assert 0.4 <= r.min() and r.max() < 100 and 0.5 < np.median(r) < 20  # a room

    # transforms: world -> imu -> lidar, unit quaternions, the head turning while it pans
    tfs = client.of("/tf")
    assert len(tfs) == len(clouds)
    q = []
    for m in tfs:
        pairs = [(t.parent_frame_id, t.child_frame_id) for t in m.transforms]
        assert pairs == [("world", "imu"), ("imu", "lidar")]
        rot = m.transforms[0].rotation
        q.append([rot.w, rot.x, rot.y, rot.z])
    q = np.asarray(q)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    assert summary["rotations_without_imu"] <= 2
    angle = np.degrees(2 * np.arccos(np.clip(np.abs(q @ q[0]), 0, 1)))
    assert angle.max() > 30  # the head panned

    # a growing coverage map in the world frame
    cov = client.of("/coverage")
    sizes = [len(pc.data) // pc.point_stride for pc in cov]
    assert len(cov) >= 3 and sizes == sorted(sizes) and sizes[-1] > sizes[0] > 1000
    assert all(pc.frame_id == "world" for pc in cov)

    # every station's fragment
    frags = client.of("/stations/fragment")
    assert len(frags) == len(summary["stations"]) == 2, summary["stations"]
    for pc in frags:
        assert len(pc.data) // pc.point_stride > 1000

    # the counters reach the client too; nothing was written
    st = client.of("/live/stats")
    assert st and st[-1]["rotations_shown"] > 0
    assert summary["lag_median_s"] < 1.0
    assert not list(Path.cwd().glob("*.mcap"))


def test_rotation_cutter_matches_the_decoder(velodyne_dir):
    """Rotations cut at packet granularity on the azimuth wrap: as many as the decoder's
    (VeloView's capture: 51 wraps), every packet in exactly one rotation, in order."""
    from tripod_processor.decode import decode_file
    from tripod_processor.live import RotationCutter

    path = velodyne_dir / "veloview-vlp16-20hz.pcap"
    pk = [(d.t_ns, d.payload) for d in PcapReader(path) if d.dst_port == 2368]
    cut = RotationCutter()
    rots = [r for r in (cut.feed(t, p) for t, p in pk) if r is not None]
    rots.append(cut.flush())
    assert [p for r in rots for p in r[0]] == [p for _, p in pk]
    run = decode_file(path)
    for _ in run:
        pass
    # a wrap between the blocks of a packet is seen at the next packet: only one inside the
    # capture's very last packet is missed
    assert run.report.summary()["rotations"] == 51
    assert len(rots) - 1 in (50, 51)
    assert all(37 <= len(r[0]) <= 38 for r in rots[1:-1])  # 754 packets/s at 20 Hz


def test_voxel_set_grows_and_bounds():
    from tripod_processor.live.view import VoxelSet, voxel_centres, voxel_keys

    rng = np.random.default_rng(0)
    xyz = rng.uniform(-20, 20, (5000, 3)).astype(np.float32)
    keys = voxel_keys(xyz, 0.1)
    back = voxel_centres(keys, 0.1)
    # every point lies in a voxel whose centre is within half a voxel on each axis
    assert np.abs(voxel_centres(voxel_keys(xyz[:1], 0.1), 0.1)[0] - xyz[0]).max() <= 0.05 + 1e-6
    assert len(back) == len(keys) <= 5000
    vs = VoxelSet(0.1, max_voxels=6000)
    vs.add(xyz[:2500])
    n1 = len(vs)
    vs.add(xyz[:2500])
    assert len(vs) == n1  # the same points again: nothing new
    vs.add(xyz)
    assert len(vs) == len(keys) > n1
    vs.add(rng.uniform(-20, 20, (5000, 3)))
    assert len(vs) >= 6000 and vs.full
    n_full = len(vs)
    vs.add(rng.uniform(-20, 20, (5000, 3)))
    assert len(vs) == n_full
