# SPDX-License-Identifier: BSD-3-Clause
"""A rosbag2 folder writer: ``metadata.yaml`` + one MCAP file (profile ``ros2``, CDR messages,
``ros2msg`` schemas), what ``ros2 bag record -s mcap`` writes and ``ros2 bag play`` reads.

The metadata is rosbag2 version 5 (the layout of ROS 2 Humble; later distributions read it).
``offered_qos_profiles`` go to the metadata and to each MCAP channel, so ``/tf_static`` replays
``transient_local`` (latched) as tf2 expects.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

ROSBAG2_VERSION = 5

_INF = "{sec: 2147483647, nsec: 4294967295}"


def qos_profile(durability: str = "volatile", reliability: str = "reliable") -> str:
    """The YAML text rosbag2 stores for one publisher's QoS (history keep-last, depth 0)."""
    dur = {"transient_local": 1, "volatile": 2}[durability]
    rel = {"reliable": 1, "best_effort": 2}[reliability]
    return (f"- history: 3\n  depth: 0\n  reliability: {rel}\n  durability: {dur}\n"
            f"  deadline: {_INF}\n  lifespan: {_INF}\n  liveliness: 1\n"
            f"  liveliness_lease_duration: {_INF}\n  avoid_ros_namespace_conventions: false\n")


@dataclass
class _Topic:
    channel_id: int
    type: str
    qos: str
    count: int = 0


class Rosbag2Writer:
    """Write a rosbag2 folder. Topics are declared with :meth:`add_topic`, messages (CDR bytes)
    written with :meth:`write` at ``log_time_ns`` (UNIX ns), then :meth:`close`.

    Parameters
    ----------
    folder : the bag folder; created; must not exist or be empty (as ``ros2 bag record``)
    """

    def __init__(self, folder: str | os.PathLike, *, library: str = "tripod"):
        from mcap.writer import CompressionType, Writer

        self.folder = Path(folder)
        if self.folder.exists() and any(self.folder.iterdir()):
            raise FileExistsError(f"{self.folder}: exists and is not empty")
        self.folder.mkdir(parents=True, exist_ok=True)
        self.file_name = f"{self.folder.name}_0.mcap"
        self._fh = open(self.folder / self.file_name, "wb")
        self._w = Writer(self._fh, compression=CompressionType.ZSTD)
        self._w.start(profile="ros2", library=library)
        self._topics: dict[str, _Topic] = {}
        self._t_min: int | None = None
        self._t_max: int | None = None

    def add_topic(self, topic: str, msg_type: str, msgdef: str, qos: str | None = None) -> None:
        qos = qos if qos is not None else qos_profile()
        sid = self._w.register_schema(msg_type, "ros2msg", msgdef.encode())
        cid = self._w.register_channel(topic, "cdr", sid, {"offered_qos_profiles": qos})
        self._topics[topic] = _Topic(cid, msg_type, qos)

    def write(self, topic: str, log_time_ns: int, data: bytes) -> None:
        tp = self._topics[topic]
        self._w.add_message(tp.channel_id, int(log_time_ns), data, int(log_time_ns), tp.count)
        tp.count += 1
        t = int(log_time_ns)
        self._t_min = t if self._t_min is None else min(self._t_min, t)
        self._t_max = t if self._t_max is None else max(self._t_max, t)

    def close(self) -> None:
        import yaml

        self._w.finish()
        self._fh.close()
        t0 = self._t_min or 0
        dur = (self._t_max - t0) if self._t_max is not None else 0
        total = sum(t.count for t in self._topics.values())
        info = {
            "version": ROSBAG2_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": dur},
            "starting_time": {"nanoseconds_since_epoch": t0},
            "message_count": total,
            "topics_with_message_count": [
                {"topic_metadata": {"name": name, "type": t.type, "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos},
                 "message_count": t.count}
                for name, t in self._topics.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.file_name],
            "files": [{"path": self.file_name, "starting_time": {"nanoseconds_since_epoch": t0},
                       "duration": {"nanoseconds": dur}, "message_count": total}],
        }
        with open(self.folder / "metadata.yaml", "w", encoding="utf-8") as fh:
            yaml.safe_dump({"rosbag2_bagfile_information": info}, fh, sort_keys=False)

    def __enter__(self) -> "Rosbag2Writer":
        return self

    def __exit__(self, *exc) -> None:
        if not self._fh.closed:
            self.close()
