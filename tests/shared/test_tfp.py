# SPDX-License-Identifier: BSD-3-Clause
"""TFP framing: the doc's hex dumps, quaternion callbacks, resync on garbage."""

import random

from tripod_shared import tfp, witmotion


def test_doc_examples():
    p = tfp.TfpStreamParser()
    # the documented callback (fid 32, not an IMU Brick 2.0 quaternion) is not accepted as one
    assert tfp.HEADER.unpack(bytes.fromhex("3213 78d8 0e20 0800".replace(" ", ""))) == (3631747890, 14, 32, 8, 0)
    assert tfp.base58_decode("b1Q") == 33688 and tfp.base58_decode("6wVE7W") == 3631747890
    assert tfp.base58_encode(3631747890) == "6wVE7W"
    assert tfp.encode_packet(33688, 1, b"", 1, True) == bytes.fromhex("9883000008011800")
    assert p.feed(b"") == []


def test_quaternion_callbacks_with_garbage():
    rng = random.Random(1)
    uid = 3631747890
    qs = [(0.5, 0.5, -0.5, 0.5), (1.0, 0.0, 0.0, 0.0), (0.7071, 0.0, 0.7071, 0.0)]
    stream = b""
    for q in qs:
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
        stream += tfp.encode_quaternion_callback(uid, *q)
    p = tfp.TfpStreamParser(uid=uid)
    got = []
    for i in range(0, len(stream), 5):  # feed in small pieces, as a serial line does
        got += p.feed(stream[i : i + 5])
    assert [g.function_id for g in got] == [tfp.FID_CALLBACK_QUATERNION] * 3
    for g, q in zip(got, qs):
        d = tfp.decode_quaternion(g.payload)
        assert max(abs(a - b) for a, b in zip(d, q)) < 1e-3
    assert p.garbage_bytes + 16 * 3 + p.pending == len(stream)


def test_witmotion_resync():
    frames = witmotion.encode_quaternion(0.0, 1.0, 0.0, 0.0) + b"\x55\x00\x01" + witmotion.encode_quaternion(1, 0, 0, 0)
    p = witmotion.WitStreamParser()
    got = p.feed(frames)
    assert len(got) == 2 and p.garbage_bytes == 3
    assert witmotion.decode_quaternion(got[0].data) == (0.0, 1.0, 0.0, 0.0)
