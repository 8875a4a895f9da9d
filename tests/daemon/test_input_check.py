# SPDX-License-Identifier: BSD-3-Clause
"""Stricter inputs: position packets (size, time, PPS, NMEA structure and checksum) and TFP
frames (UID, length, function id; a cut-off frame never becomes a sample)."""

from __future__ import annotations

import math
import random
import struct

import pytest

from tripod_shared import messages, tfp
from tripod_shared.recording import RecordingReader
from tripod_shared.velodyne import POSITION_PORT

from daemon_helpers import RunningDaemon, loopback_config, read_pcap_udp, udp_sender
from tripod_daemon.config import ImuConfig
from tripod_daemon.imu_serial import TfpDriver
from tripod_daemon.input_check import nmea_reject_reason, position_reject_reason
from tripod_daemon.stats import Counters

GPRMC = b"$GPRMC,081802.00,A,3649.7478558,N,00224.4542928,W,0.034,212.5,210116,0.0,E,A*2E\r\n"


def _position(nmea: bytes = GPRMC, toh_us: int = 1_234_567, pps: int = 2) -> bytes:
    p = bytearray(512)
    struct.pack_into("<I", p, 198, toh_us)
    p[202] = pps
    p[206 : 206 + len(nmea)] = nmea
    return bytes(p)


def _real_position_packets(velodyne_dir) -> list[bytes]:
    out = []
    for name in ("mrpt-vlp16-gps.pcap", "veloview-vlp16-20hz.pcap", "scanparser-vlp16-gaps.pcap"):
        out += [p for port, p in read_pcap_udp(velodyne_dir / name)
                if port == POSITION_PORT and len(p) == 512]
    return out


def test_real_position_packets_pass_and_each_defect_has_its_reason(velodyne_dir):
    real = _real_position_packets(velodyne_dir)
    assert len(real) == 57 + 367 + 36
    assert [position_reject_reason(p) for p in real] == [None] * len(real)
    assert position_reject_reason(_position()) is None
    assert position_reject_reason(_position(b"")) is None  # no GPS receiver attached
    assert position_reject_reason(_position()[:511]) == "size"
    assert position_reject_reason(_position(toh_us=3_600_000_000)) == "time"
    assert position_reject_reason(_position(pps=4)) == "pps"
    assert position_reject_reason(_position(GPRMC.replace(b"*2E", b"*2F"))) == "nmea_checksum"
    assert position_reject_reason(_position(GPRMC.replace(b"3649", b"3648"))) == "nmea_checksum"
    for bad in (b"GPRMC,1*00", b"$GPRMC,1*0", b"$gprmc,1*00", GPRMC + b"$GPGGA*00",
                b"$GPRMC," + b"1" * 90 + b"*00", b"$GPRMC,\x01*00"):
        assert nmea_reject_reason(bad.ljust(128, b"\x00")) == "nmea_structure", bad
    field = bytearray(GPRMC.ljust(128, b"\x00"))
    field[120] = 0x41  # junk after the NUL padding starts
    assert nmea_reject_reason(bytes(field)) == "nmea_structure"


def test_100k_random_position_datagrams_none_accepted(tmp_path, velodyne_dir):
    rng = random.Random(16)
    n = 100_000
    junk = []
    for i in range(n):
        p = bytearray(rng.randbytes(512))
        if i % 2:  # plausible header fields, so only the NMEA check can refuse them
            struct.pack_into("<I", p, 198, rng.randrange(3_600_000_000))
            p[202] = rng.randrange(4)
            if i % 4 == 1:  # a sentence-like start
                p[206:213] = b"$GPRMC,"
        junk.append(bytes(p))
    real = _real_position_packets(velodyne_dir)[:57]
    cfg = loopback_config(tmp_path, lidar={"receive_buffer_bytes": 128 << 20})
    with RunningDaemon(cfg) as d:
        s = udp_sender()
        for k, p in enumerate(junk):
            s.sendto(p, d.position_addr)
            if k % 2000 == 0 and k // 2000 < len(real):
                s.sendto(real[k // 2000], d.position_addr)
        sent_real = min(len(real), (n - 1) // 2000 + 1)
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_malformed"] + c["lidar_position"] >= n + sent_real,
                          timeout=60)
        assert d.stop() == 0
    assert c["lidar_position"] == sent_real and c["lidar_malformed"] == n
    kinds = {k: v for k, v in c.items() if k.startswith("position_rejected_") and v}
    assert sum(kinds.values()) == n and set(kinds) <= {
        "position_rejected_time", "position_rejected_pps", "position_rejected_nmea_structure",
        "position_rejected_nmea_checksum"}
    assert kinds["position_rejected_nmea_structure"] >= n // 2 - 100
    rec = [p for _ns, p in RecordingReader(d.daemon.recorder.files[0]).position_packets()]
    assert rec == real[:sent_real]
    assert d.daemon.lidar_clock.summary()["pps"] == "locked"  # only the real packets reached it


class _Port:
    def __init__(self):
        self.written = b""

    def write(self, b):
        self.written += b


def _driver(uid=None):
    counts = Counters()
    cfg = ImuConfig(url="x", tfp_uid=tfp.base58_encode(uid) if uid else "")
    return TfpDriver(cfg, counts), counts


@pytest.mark.parametrize("known_uid", [True, False])
def test_1mb_of_garbage_and_cut_frames_no_sample_invented(known_uid):
    uid = 0x6A1B2C3D
    rng = random.Random(7)
    frames = []
    for k in range(4000):  # distinct plausible quaternions, so every sample is identifiable
        half = 0.00075 * k  # half the yaw [rad]
        frames.append(tfp.encode_quaternion_callback(uid, math.cos(half), 0.0, 0.0,
                                                     math.sin(half)))
    stream = bytearray()
    intact = []
    garbage = 0
    if not known_uid:
        stream += tfp.encode_enumerate_callback(uid)  # the brick answers enumerate first
    for f in frames:
        r = rng.random()
        if r < 0.2:  # cut off: 1..15 bytes of it, then the next frame
            stream += f[: rng.randrange(1, len(f))]
        elif r < 0.4:  # random bytes between frames
            g = rng.randbytes(rng.randrange(1, 3000))
            garbage += len(g)
            stream += g
            stream += f
            intact.append(f)
        else:
            stream += f
            intact.append(f)
    assert len(stream) > 1 << 20 and len(set(frames)) == len(frames)
    drv, counts = _driver(uid if known_uid else None)
    out = []
    port = _Port()
    pos = 0
    ns = 0
    while pos < len(stream):  # reads of random sizes, as a serial line delivers them
        n = rng.randrange(1, 300)
        ns += 1000
        drv.feed(bytes(stream[pos : pos + n]), ns, port, out)
        pos += n
    drv.feed(b"", ns + 1000, port, out)
    raws = [messages.decode_imu(data).raw for _t, _ns, data in out]
    frame_set = set(frames)
    assert [r.hex() for r in raws if r not in frame_set] == []  # nothing invented
    assert raws == sorted(raws, key=frames.index)  # in order, no duplicates
    kept = set(raws)
    # every intact frame is kept except where random bytes right before it happened to look
    # like the start of one of ours (none expected with a 4-byte UID)
    assert len([f for f in intact if f not in kept]) <= 2
    assert counts["imu_samples"] == len(raws)
