# SPDX-License-Identifier: BSD-3-Clause
"""PacketGapCounter: a live subscriber counts the packets it missed from device timestamps."""

from __future__ import annotations

import struct
from pathlib import Path

from tripod_shared.velodyne import TIMESTAMP_OFFSET, PacketGapCounter

DATA = Path(__file__).resolve().parents[3] / "shared/data/velodyne/vlp16go-1000-payloads.bin"
if not DATA.exists():
    DATA = Path("/work/shared/data/velodyne/vlp16go-1000-payloads.bin")


def _payloads() -> list[bytes]:
    raw = DATA.read_bytes()
    return [raw[k * 1206:(k + 1) * 1206] for k in range(len(raw) // 1206)]


def test_real_stream_without_loss_counts_none_and_dropped_packets_are_counted():
    pk = _payloads()  # contiguous device timestamps (strongest return: 1327 µs apart)
    c = PacketGapCounter()
    assert sum(c.add(p) for p in pk) == 0 and c.packets == 1000
    dropped = {5, 6, 7, 100, 501, 999}  # 999: the last, unseen by the counter
    c = PacketGapCounter()
    for k, p in enumerate(pk):
        if k not in dropped:
            c.add(p)
    assert c.missing == 5


def test_hour_wrap_and_long_pauses():
    p = bytearray(_payloads()[0])

    def at(t_us: int) -> bytes:
        struct.pack_into("<I", p, TIMESTAMP_OFFSET, t_us % 3_600_000_000)
        return bytes(p)

    c = PacketGapCounter()
    c.add(at(3_600_000_000 - 1327))
    assert c.add(at(3_600_000_000 + 1327)) == 1  # one packet missing across the hour
    assert c.add(at(3_600_000_000 + 5_000_000)) == 0  # a 5 s pause: not counted as loss
    assert c.missing == 1
