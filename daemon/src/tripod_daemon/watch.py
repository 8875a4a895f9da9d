# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon watch``: subscribe to a tripod's live stream and print rates once a second.

A minimal example of a live consumer: the lidar packets come in blocks (``lidar/blocks``,
decoded by ``tripod_shared.lidar_block``), the other payloads are the CDR/JSON bytes of the MCAP
recording, so ``tripod_shared.messages`` decodes them. It also counts the lidar packets this
subscriber missed (``lidar lost N``), from the gaps in the blocks' packet numbers: Zenoh drops a
slow subscriber's samples without telling the daemon, so only the subscriber can count them;
and the gaps in the packets' device timestamps (``stamp gaps N``: also what was lost before the
daemon, e.g. on the network from the sensor). It subscribes to each key it shows, not to
``tripod/<id>/**``, which would also match the per-packet key and make the daemon publish every
packet a second time.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from tripod_shared import messages, topics
from tripod_shared.lidar_block import LidarBlockDecoder
from tripod_shared.velodyne import PacketGapCounter


def main(argv: list[str] | None = None) -> int:
    import zenoh

    p = argparse.ArgumentParser(prog="tripod-daemon watch",
                                description="Print the live stream's rates and status.")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="zenoh endpoint of the daemon, e.g. tcp/192.168.1.20:7447")
    p.add_argument("--device-id", default=topics.DEFAULT_DEVICE_ID)
    p.add_argument("--seconds", type=float, default=0, help="stop after this long (0: never)")
    a = p.parse_args(argv)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    if a.connect:
        conf.insert_json5("connect/endpoints", json.dumps(a.connect))
    counts: dict[str, int] = {}
    last_imu: list = [None]
    last_status: list = [None]
    gaps = PacketGapCounter()
    blocks = LidarBlockDecoder()
    lock = threading.Lock()

    def on_block(sample) -> None:
        with lock:
            blk = blocks.decode(sample.payload.to_bytes())  # None: rejected, counted
            if blk is None:
                return
            counts["lidar/packets"] = counts.get("lidar/packets", 0) + len(blk)
            for p in blk.payloads:
                gaps.add(p.tobytes())

    def on_sample(sample) -> None:
        key = str(sample.key_expr)
        leaf = key.split("/", 2)[-1]
        with lock:
            counts[leaf] = counts.get(leaf, 0) + 1
        try:
            if leaf == "imu/quaternion":
                last_imu[0] = messages.decode_imu(sample.payload.to_bytes())
            elif leaf == "status":
                last_status[0] = messages.decode_status(sample.payload.to_bytes())
        except Exception:  # noqa: BLE001 - a bad payload is just not shown
            pass

    dev = a.device_id
    keys = [topics.key_lidar_position(dev), topics.key_imu(dev), topics.key_status(dev),
            topics.key_events(dev)]
    t_end = time.monotonic() + a.seconds if a.seconds else None
    with zenoh.open(conf) as session:
        session.declare_subscriber(topics.key_lidar_blocks(dev), on_block)
        for key in keys:
            session.declare_subscriber(key, on_sample)
        print(f"watching {topics.KEY_ROOT}/{dev}/{{lidar/blocks,lidar/position,imu/quaternion,"
              "status,events}} (Ctrl-C to stop)", flush=True)
        try:
            while t_end is None or time.monotonic() < t_end:
                time.sleep(1.0)
                with lock:
                    snap = dict(counts)
                    counts.clear()
                    lost, stamp_gaps, bad = blocks.missing, gaps.missing, blocks.rejected_total
                parts = [f"{k} {v}/s" for k, v in sorted(snap.items())] or ["nothing received"]
                if blocks.packets:
                    parts.append(f"lidar lost {lost}, stamp gaps {stamp_gaps}"
                                 + (f", bad blocks {bad}" if bad else ""))
                q = last_imu[0]
                if q is not None:
                    parts.append(f"q_world_imu=({q.w:+.3f},{q.x:+.3f},{q.y:+.3f},{q.z:+.3f})")
                st = last_status[0]
                if st is not None:
                    parts.append(f"[{st.state}{' ' + st.file if st.file else ''}]")
                print("  ".join(parts), flush=True)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
