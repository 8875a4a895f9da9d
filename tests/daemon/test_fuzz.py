# SPDX-License-Identifier: BSD-3-Clause
"""Bad input: 100,000 fuzzed datagrams and over 1 MB of random bytes on the serial line, with
good data interleaved. No crash, every bad item counted, every good one recorded."""

from __future__ import annotations

import random
import threading

from tripod_shared import tfp, witmotion
from tripod_shared.recording import RecordingReader
from tripod_shared.velodyne import PacketKind, check_data_packet

from daemon_helpers import FakePty, RunningDaemon, loopback_config, make_data_packet, udp_sender

N_FUZZ = 100_000


def _fuzz_datagram(rng: random.Random, i: int) -> tuple[bytes, str]:
    """One bad datagram and the counter it must land in."""
    kind = rng.randrange(7)
    good = bytearray(make_data_packet(i))
    if kind == 0:  # wrong size, random bytes (runts, jumbo, empty)
        n = rng.choice([0, 1, 100, 511, 512, 1205, 1207, 1248, 2000, 4000, rng.randrange(9000)])
        if n == 1206:
            n = 1205
        return rng.randbytes(n), "lidar_malformed"
    if kind == 1:  # right size, random bytes
        b = bytearray(rng.randbytes(1206))
        b[0] = 0x00  # make sure the first block flag is wrong
        return bytes(b), "lidar_malformed"
    if kind == 2:  # one broken block flag
        blk = rng.randrange(12)
        good[blk * 100 + rng.randrange(2)] ^= 0x5A
        return bytes(good), "lidar_malformed"
    if kind == 3:  # unknown return mode
        good[1204] = rng.choice([0x00, 0x36, 0x3A, 0xFF])
        return bytes(good), "lidar_malformed"
    if kind == 4:  # another sensor (VLP-32C, VLS-128, Puck Hi-Res, Velarray)
        good[1205] = rng.choice([0x24, 0x28, 0x31, 0xA1])
        return bytes(good), "lidar_foreign"
    if kind == 5:  # truncated good packet
        return bytes(good[: rng.randrange(1, 1206)]), "lidar_malformed"
    return bytes(good) + rng.randbytes(rng.randrange(1, 64)), "lidar_malformed"  # trailing junk


def test_fuzzed_datagrams_are_counted_and_good_ones_recorded(tmp_path):
    rng = random.Random(2024)
    bad = [_fuzz_datagram(rng, i) for i in range(N_FUZZ)]
    expected = {"lidar_malformed": 0, "lidar_foreign": 0}
    for payload, where in bad:
        expected[where] += 1
        # the generator's expectation agrees with the shared classifier the daemon uses
        if len(payload) == 1206:
            want = PacketKind.FOREIGN if where == "lidar_foreign" else PacketKind.MALFORMED
            assert check_data_packet(payload, (0x22, 0x21)) == want
    good = [make_data_packet(10_000_000 + i) for i in range(N_FUZZ // 10)]
    pos_bad = [rng.randbytes(rng.randrange(600)) for _ in range(2000)]
    pos_bad = [p for p in pos_bad if len(p) != 512] + [b"\x00" * 198 + b"\xff" * 314]  # bad toh
    cfg = loopback_config(tmp_path, lidar={"receive_buffer_bytes": 128 << 20})
    with RunningDaemon(cfg) as d:
        s = udp_sender()
        c = d.daemon.counts
        gi = 0
        for i, (payload, _w) in enumerate(bad):
            s.sendto(payload, d.data_addr)
            if i % 10 == 9:
                s.sendto(good[gi], d.data_addr)
                gi += 1
            if i % 2000 == 1999:  # keep well inside the receive buffer
                d.wait_for(lambda: c["lidar_malformed"] + c["lidar_foreign"] + c["lidar_data"]
                           >= i + gi - 8000, timeout=10, step=0.005)
        for p in pos_bad:
            s.sendto(p, d.position_addr)
        total = len(bad) + len(good)
        assert d.wait_for(lambda: c["lidar_malformed"] + c["lidar_foreign"] + c["lidar_data"]
                          >= total and c["lidar_malformed"] >= expected["lidar_malformed"]
                          + len(pos_bad), timeout=30)
        assert d.stop() == 0
    assert c["lidar_data"] == len(good)
    assert c["lidar_foreign"] == expected["lidar_foreign"]
    assert c["lidar_malformed"] == expected["lidar_malformed"] + len(pos_bad)
    assert c["lidar_position"] == 0
    got = [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).lidar_packets()]
    assert got == good


def _interleave(rng, frames, garbage_total):
    chunks, garbage = [], 0
    per = garbage_total // len(frames) + 1
    for f in frames:
        g = rng.randbytes(rng.randrange(per // 2, per * 3 // 2))
        garbage += len(g)
        chunks += [g, f]
    return b"".join(chunks), garbage


def _feed_pty(dev, blob):
    t = threading.Thread(target=dev.write, args=(blob,), daemon=True)
    t.start()
    return t


def test_random_bytes_on_the_tfp_line(tmp_path):
    rng = random.Random(99)
    uid = 0x51F00D
    frames = [tfp.encode_quaternion_callback(uid, *q) for q in
              [(0.5, 0.5, 0.5, 0.5), (1, 0, 0, 0), (0, 0, 0.6, 0.8), (0.6, 0.8, 0, 0)] * 250]
    blob, garbage = _interleave(rng, frames, 1 << 20)
    assert garbage >= 1 << 20
    dev = FakePty(tmp_path / "imu")
    cfg = loopback_config(tmp_path, imu={"url": str(dev.link), "driver": "tfp",
                                         "tfp_uid": tfp.base58_encode(uid)})
    try:
        with RunningDaemon(cfg) as d:
            c = d.daemon.counts
            assert d.wait_for(lambda: d.daemon.imu.connected)
            _feed_pty(dev, blob).join(60)
            assert d.wait_for(lambda: c["imu_bytes"] >= len(blob), timeout=60)
            assert d.wait_for(lambda: c["imu_samples"] >= len(frames))
            assert d.stop() == 0
    finally:
        dev.close()
    rec = list(RecordingReader(d.daemon.recorder.files[0]).imu_samples())
    assert [s.raw for s in rec] == frames
    # every random byte is accounted for as garbage (none taken for a frame)
    assert c["imu_garbage_bytes"] == garbage
    assert c["imu_bytes"] == len(blob)


def test_random_bytes_on_the_witmotion_line(tmp_path):
    rng = random.Random(5)
    frames = [witmotion.encode_quaternion(0.0, 0.6, 0.0, 0.8) for _ in range(400)]
    blob, garbage = _interleave(rng, frames, 200_000)
    dev = FakePty(tmp_path / "imu")
    cfg = loopback_config(tmp_path, imu={"url": str(dev.link), "driver": "witmotion"})
    try:
        with RunningDaemon(cfg) as d:
            c = d.daemon.counts
            assert d.wait_for(lambda: d.daemon.imu.connected)
            _feed_pty(dev, blob).join(60)
            assert d.wait_for(lambda: c["imu_bytes"] >= len(blob), timeout=60)
            assert d.stop() == 0
    finally:
        dev.close()
    rec = [s.raw for s in RecordingReader(d.daemon.recorder.files[0]).imu_samples()]
    # 0x55 frames have only an 8-bit checksum: random bytes can form a valid-looking frame
    # (about one per 65,536 bytes). Those are counted (imu_other_frames, or a sample whose raw
    # bytes are not one of ours); every real frame must still be there, in order.
    it = iter(rec)
    assert all(any(r == f for r in it) for f in frames)
    false_frames = c["imu_other_frames"] + (len(rec) - len(frames))
    assert c["imu_garbage_bytes"] + 11 * false_frames == garbage
