# SPDX-License-Identifier: BSD-3-Clause
"""Live lidar blocks (tripod_shared.lidar_block): round trip, and bad blocks rejected with a count,
never a crash."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_shared import lidar_block as lb

SIZE = 1206


def _payloads(rng, n: int, size: int = SIZE) -> np.ndarray:
    return rng.integers(0, 256, (n, size), dtype=np.uint8)


def test_round_trip_arrays_and_bytes():
    rng = np.random.default_rng(1)
    p = _payloads(rng, 37)
    stamps = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(600_000, 700_000, 37))
    data = lb.encode_block(12_345, stamps, p)
    assert len(data) == lb.block_size(37, SIZE) == 24 + 37 * (8 + SIZE)
    blk = lb.decode_block(data)
    assert blk.first_index == 12_345 and len(blk) == 37
    assert blk.host_ns.dtype == np.int64 and (blk.host_ns == stamps).all()
    assert blk.payloads.shape == (37, SIZE) and (blk.payloads == p).all()
    # per-packet view, and the same block from a list of bytes
    pk = blk.packets()
    assert [ns for ns, _ in pk] == stamps.tolist() and pk[5][1] == p[5].tobytes()
    assert lb.encode_block(12_345, stamps.tolist(), [r.tobytes() for r in p]) == data
    # a column range of wider rows (the daemon's recorder rows): strided input, same bytes
    rows = np.zeros((37, 43 + SIZE), np.uint8)
    rows[:, 43:] = p
    assert lb.encode_block(12_345, stamps, rows[:, 43:]) == data
    assert lb.decode_block(memoryview(data)).first_index == 12_345


def test_layout_is_the_documented_one():
    data = lb.encode_block(7, [10, 20], np.full((2, 4), 0xAB, np.uint8))
    assert data[:4] == b"TLB1"
    assert int.from_bytes(data[4:6], "little") == 1  # version
    assert int.from_bytes(data[6:8], "little") == 24  # header size
    assert int.from_bytes(data[8:12], "little") == 2  # count
    assert int.from_bytes(data[12:16], "little") == 4  # packet size
    assert int.from_bytes(data[16:24], "little") == 7  # first index
    assert np.frombuffer(data[24:40], "<i8").tolist() == [10, 20]
    assert data[40:] == b"\xab" * 8


def test_a_later_version_header_is_skipped_by_its_size():
    body = lb.encode_block(3, [5], np.ones((1, 4), np.uint8))
    longer = (b"TLB1" + (1).to_bytes(2, "little") + (32).to_bytes(2, "little") + body[8:24]
              + bytes(8) + body[24:])
    blk = lb.decode_block(longer)
    assert blk.host_ns.tolist() == [5] and blk.payloads.tolist() == [[1, 1, 1, 1]]


def test_max_packets_fits_the_message_size():
    n = lb.max_packets_for(60_000, SIZE)
    assert n == 49 and lb.block_size(n, SIZE) <= 60_000 < lb.block_size(n + 1, SIZE)
    assert lb.max_packets_for(100, SIZE) == 1


def test_encode_refuses_inconsistent_input():
    with pytest.raises(ValueError):
        lb.encode_block(0, [1, 2], np.zeros((3, SIZE), np.uint8))
    with pytest.raises(ValueError):
        lb.encode_block(0, [1, 2], [bytes(SIZE), bytes(SIZE - 1)])
    with pytest.raises(ValueError):
        lb.encode_block(0, [], np.zeros((0, SIZE), np.uint8))


@pytest.mark.parametrize("reason,mutate", [
    ("short", lambda b: b[:10]),
    ("magic", lambda b: b"XLB1" + b[4:]),
    ("version", lambda b: b[:4] + (2).to_bytes(2, "little") + b[6:]),
    ("header", lambda b: b[:6] + (8).to_bytes(2, "little") + b[8:]),
    ("count", lambda b: b[:8] + bytes(4) + b[12:]),
    ("size", lambda b: b[:12] + bytes(4) + b[16:]),
    ("length", lambda b: b[:-1]),  # truncated by one byte
    ("length", lambda b: b + b"\x00"),
    ("length", lambda b: b[:8] + (4).to_bytes(4, "little") + b[12:]),  # count says more
])
def test_bad_blocks_are_rejected_per_reason(reason, mutate):
    rng = np.random.default_rng(2)
    good = lb.encode_block(0, np.arange(3), _payloads(rng, 3))
    with pytest.raises(lb.BlockError) as exc:
        lb.decode_block(mutate(good))
    assert exc.value.reason == reason
    dec = lb.LidarBlockDecoder()
    assert dec.decode(mutate(good)) is None
    assert dec.rejected[reason] == 1 and dec.rejected_total == 1 and dec.packets == 0
    assert dec.decode(good) is not None and dec.packets == 3  # and the stream goes on


def test_every_truncation_and_random_corruption_is_counted_never_a_crash():
    rng = np.random.default_rng(3)
    good = lb.encode_block(100, np.arange(4), _payloads(rng, 4, 16))
    dec = lb.LidarBlockDecoder(packet_size=16)
    for cut in range(len(good)):  # every truncated block
        assert dec.decode(good[:cut]) is None
    assert dec.rejected_total == len(good) and dec.packets == 0
    # random garbage and random bytes flipped in the header: decoded consistently or rejected
    dec = lb.LidarBlockDecoder(packet_size=None)
    n_ok = 0
    for k in range(3000):
        if k % 2:
            buf = rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes()
        else:
            b = bytearray(good)
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(0, 24))] = int(rng.integers(0, 256))
            buf = bytes(b)
        blk = dec.decode(buf)
        if blk is not None:  # only a changed first_index (bytes 16..23) goes unnoticed
            n_ok += 1
            assert buf[:16] == good[:16] and buf[24:] == good[24:]
    assert dec.rejected_total + n_ok == 3000 and dec.rejected_total > 2500


def test_decoder_counts_missing_packets_and_restarts():
    rng = np.random.default_rng(4)
    dec = lb.LidarBlockDecoder(packet_size=8)

    def blk(first, n):
        return lb.encode_block(first, np.arange(n), _payloads(rng, n, 8))

    for first, n in ((0, 5), (5, 5), (20, 3), (23, 1)):  # 10..19 lost
        assert dec.decode(blk(first, n)) is not None
    assert (dec.packets, dec.missing, dec.blocks, dec.next_index) == (14, 10, 4, 24)
    dec.decode(blk(0, 2))  # the daemon restarted: not a loss
    dec.decode(blk(4, 2))  # 2, 3 lost
    assert (dec.missing, dec.restarts) == (12, 1)
    assert dec.decode(blk(6, 2)[:-1]) is None  # a truncated block: rejected, not "missing"
    assert dec.rejected["length"] == 1 and dec.missing == 12
    dec.decode(blk(8, 1))  # 6, 7 were in the rejected block: now missing
    assert dec.missing == 14
    assert dec.decode(lb.encode_block(9, [0], np.zeros((1, 9), np.uint8))) is None  # wrong size
    assert dec.rejected["size"] == 1
