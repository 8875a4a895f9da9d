# SPDX-License-Identifier: BSD-3-Clause
"""MCAP recordings of tripod: the one writer and reader of the layout.

Layout, format version 2 (document of record: ``shared/README.md``): MCAP profile ``ros2``,
every channel CDR with a ``ros2msg`` schema, so ROS 2 tools (``rosbags``, ``ros2 bag``) read it.

==================  ======================================  ========  ============
topic               schema                                  encoding  log_time
==================  ======================================  ========  ============
/velodyne/packets   velodyne_msgs/msg/VelodynePacket        cdr       host receive
/velodyne/position  tripod_msgs/msg/VelodynePositionPacket  cdr       host receive
/imu/quaternion     tripod_msgs/msg/ImuQuaternion           cdr       host read
/tripod/status      diagnostic_msgs/msg/DiagnosticArray     cdr       host
/tripod/events      tripod_msgs/msg/Event                   cdr       host
==================  ======================================  ========  ============

``log_time`` and ``publish_time`` are host_realtime ns (publish_time = log_time). MCAP metadata
record ``tripod`` holds the format version and the writer; the daemon adds its config.

Status and events travel over Zenoh as JSON (panel, ctl, watch); :meth:`RecordingWriter.
write_encoded` takes those JSON bytes and writes their CDR form (the only conversion). Readers
decode by the channel's message encoding, so format version 1 recordings (profile ``""``, status
and events as JSON channels) read the same: :meth:`RecordingReader.events` and
:meth:`RecordingReader.statuses`, or :func:`decode_event_message` / :func:`decode_status_message`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO, BinaryIO

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader

from . import messages as m
from . import ros2_msgs as r2
from . import topics as t
from .mcap_writer import McapChunkWriter, MessageBlock

FORMAT_VERSION = "2"  # 1: profile "", status and events as JSON channels (still read)
PROFILE = "ros2"

_SCHEMAS = {
    t.TOPIC_LIDAR_PACKETS: (m.VELODYNE_PACKET_TYPE, "ros2msg", m.VELODYNE_PACKET_MSGDEF, "cdr"),
    t.TOPIC_LIDAR_POSITION: (m.POSITION_PACKET_TYPE, "ros2msg", m.POSITION_PACKET_MSGDEF, "cdr"),
    t.TOPIC_IMU: (m.IMU_QUATERNION_TYPE, "ros2msg", m.IMU_QUATERNION_MSGDEF, "cdr"),
    t.TOPIC_STATUS: (r2.DIAGNOSTIC_ARRAY_TYPE, "ros2msg", r2.DIAGNOSTIC_ARRAY_MSGDEF, "cdr"),
    t.TOPIC_EVENTS: (r2.EVENT_TYPE, "ros2msg", r2.EVENT_MSGDEF, "cdr"),
}

# topics whose live (Zenoh) payload is JSON: the writer converts them to their CDR form
_FROM_LIVE = {
    t.TOPIC_STATUS: lambda data: r2.encode_status_diagnostics(m.decode_status(data)),
    t.TOPIC_EVENTS: lambda data: r2.encode_event_cdr(m.decode_event(data)),
}


class RecordingWriter:
    """Write a tripod recording. Not thread-safe: one writer thread owns it.

    Parameters
    ----------
    output : path or binary file object
    chunk_size : int
        Uncompressed bytes per chunk before it is compressed and written. The daemon also
        calls :meth:`flush_chunk` on a timer so at most that much time is ever unwritten.
    compression : "zstd" | "lz4" | "none"
    compression_level : int, optional
        zstd level (default 3; the daemon uses 1: 2.6x less CPU, files ~15 % larger).
    metadata : dict[str, str], optional
        Extra entries of the ``tripod`` metadata record.
    """

    def __init__(
        self,
        output: str | os.PathLike | BinaryIO,
        *,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        metadata: dict[str, str] | None = None,
        library: str = "tripod",
        compression_level: int | None = None,
    ):
        comp = {"zstd": "zstd", "lz4": "lz4", "none": ""}
        if compression not in comp:
            raise ValueError(f"unknown compression {compression!r} (zstd, lz4, none)")
        self._own = not hasattr(output, "write")
        self._fh: IO[bytes] = open(output, "wb") if self._own else output  # type: ignore[arg-type]
        self._writer = McapChunkWriter(self._fh, chunk_size=chunk_size,
                                       compression=comp[compression], level=compression_level)
        self._writer.start(profile=PROFILE, library=library)
        self._channels: dict[str, int] = {}
        meta = {"format_version": FORMAT_VERSION, "library": library}
        meta.update(metadata or {})
        self._writer.add_metadata("tripod", {k: str(v) for k, v in meta.items()})
        self._seq: dict[str, int] = {}
        self.messages_written = 0
        self._closed = False

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            name, sch_enc, text, msg_enc = _SCHEMAS[topic]
            sid = self._writer.register_schema(name, sch_enc, text.encode())
            cid = self._writer.register_channel(topic, msg_enc, sid)
            self._channels[topic] = cid
        return cid

    def write_encoded(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Write already-encoded message bytes (the same bytes published over Zenoh).

        Status and events arrive as their Zenoh JSON and are written as CDR
        (``diagnostic_msgs/msg/DiagnosticArray``, ``tripod_msgs/msg/Event``).
        """
        conv = _FROM_LIVE.get(topic)
        if conv is not None:
            data = conv(data)
        self._write(topic, log_time_ns, data)

    def _write(self, topic: str, log_time_ns: int, data: bytes) -> None:
        cid = self._channel(topic)
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._writer.add_message(cid, log_time_ns, data, log_time_ns, seq)
        self.messages_written += 1

    def write_block(self, block: MessageBlock) -> None:
        """Write a block of equal-size messages of one topic (the daemon's lidar batches):
        the same records as :meth:`write_encoded` of each, without per-message Python work."""
        n = len(block)
        if n == 0:
            return
        if block.topic in _FROM_LIVE:
            raise ValueError(f"{block.topic}: JSON live messages cannot be written as a block")
        cid = self._channel(block.topic)
        seq = self._seq.get(block.topic, 0)
        self._seq[block.topic] = seq + n
        self._writer.add_block(cid, block.rows, block.log_times, seq)
        self.messages_written += n

    def write_lidar_packet(self, host_ns: int, payload: bytes) -> None:
        self.write_encoded(t.TOPIC_LIDAR_PACKETS, host_ns, m.encode_velodyne_packet(host_ns, payload))

    def write_position_packet(self, host_ns: int, payload: bytes) -> None:
        self.write_encoded(t.TOPIC_LIDAR_POSITION, host_ns, m.encode_position_packet(host_ns, payload))

    def write_imu(self, sample: m.ImuSample) -> None:
        self.write_encoded(t.TOPIC_IMU, sample.host_ns, m.encode_imu(sample))

    def write_status(self, status: m.Status) -> None:
        self._write(t.TOPIC_STATUS, status.host_ns, r2.encode_status_diagnostics(status))

    def write_event(self, event: m.Event) -> None:
        self._write(t.TOPIC_EVENTS, event.host_ns, r2.encode_event_cdr(event))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, {k: str(v) for k, v in data.items()})

    def flush_chunk(self) -> None:
        """Close the open chunk and write it out now (bounded loss if the process is killed)."""
        self._writer.flush_chunk()
        self._fh.flush()

    def fileno(self) -> int:
        return self._fh.fileno()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._writer.finish()
        self._fh.flush()
        if self._own:
            self._fh.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(slots=True)
class RecordedMessage:
    topic: str
    log_time_ns: int  # host_realtime
    data: bytes
    sequence: int = 0
    encoding: str = "cdr"  # the channel's message encoding: cdr, or json (format version 1)


@dataclass
class ReadReport:
    """What reading a recording met: message counts per topic and whether it ended early."""

    messages: dict[str, int] = field(default_factory=dict)
    truncated: bool = False
    error: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


class RecordingReader:
    """Stream a tripod recording in file order; tolerant of files cut off mid-write.

    Reading never seeks, so constant memory however long the file. A file that ends early
    (writer killed) yields every whole message before the cut and sets ``report.truncated``.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise FileNotFoundError(f"no such recording: {self.path}")
        self.report = ReadReport()

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RecordedMessage]:
        want = set(topics) if topics is not None else None
        channels: dict[int, Channel] = {}
        report = self.report = ReadReport()
        with open(self.path, "rb") as fh:
            try:
                reader = StreamReader(fh, skip_magic=False, emit_chunks=False)
                for rec in reader.records:
                    if isinstance(rec, Channel):
                        channels[rec.id] = rec
                    elif isinstance(rec, Message):
                        ch = channels.get(rec.channel_id)
                        if ch is None:
                            continue
                        report.messages[ch.topic] = report.messages.get(ch.topic, 0) + 1
                        if want is None or ch.topic in want:
                            yield RecordedMessage(ch.topic, rec.log_time, rec.data, rec.sequence,
                                                  ch.message_encoding)
                    elif isinstance(rec, Metadata):
                        report.metadata[rec.name] = dict(rec.metadata)
            except (McapError, EOFError, ValueError, OSError, Exception) as exc:  # noqa: BLE001
                # mcap raises several types at a cut (EndOfFile, struct.error, zstd errors)
                report.truncated = True
                report.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__

    def lidar_packets(self) -> Iterator[tuple[int, bytes]]:
        """(host_ns, 1206-byte payload) of every data packet, in recording order."""
        for msg in self.messages([t.TOPIC_LIDAR_PACKETS]):
            yield m.decode_velodyne_packet(msg.data)

    def position_packets(self) -> Iterator[tuple[int, bytes]]:
        for msg in self.messages([t.TOPIC_LIDAR_POSITION]):
            yield m.decode_position_packet(msg.data)

    def imu_samples(self) -> Iterator[m.ImuSample]:
        for msg in self.messages([t.TOPIC_IMU]):
            yield m.decode_imu(msg.data)

    def events(self) -> Iterator[m.Event]:
        for msg in self.messages([t.TOPIC_EVENTS]):
            yield decode_event_message(msg)

    def statuses(self) -> Iterator[m.Status]:
        for msg in self.messages([t.TOPIC_STATUS]):
            yield decode_status_message(msg)


def decode_event_message(msg: RecordedMessage) -> m.Event:
    """The event of a ``/tripod/events`` message, CDR (format 2) or JSON (format 1)."""
    return m.decode_event(msg.data) if msg.encoding == "json" else r2.decode_event_cdr(msg.data)


def decode_status_message(msg: RecordedMessage) -> m.Status:
    """The status of a ``/tripod/status`` message, CDR (format 2) or JSON (format 1)."""
    if msg.encoding == "json":
        return m.decode_status(msg.data)
    return r2.decode_status_diagnostics(msg.data)


def is_mcap(path: str | os.PathLike) -> bool:
    with open(path, "rb") as fh:
        return fh.read(8) == b"\x89MCAP0\r\n"
