# SPDX-License-Identifier: BSD-3-Clause
"""One reader API over every recording: typed :class:`Event` s in time order.

=====================  =============================================  =========================
source                 events                                         reader
=====================  =============================================  =========================
pcap / pcapng          LIDAR, POSITION                                :func:`pcap_events`
MCAP (ours)            LIDAR, POSITION, IMU (raw bytes), IMU_SAMPLE,  :class:`McapEvents`
                       MARK
IMU log (``.tripimu``) IMU (the bytes as the host read them)          :func:`imu_log_events`
simulator folder       capture.pcap + imu.tripimu, merged             :func:`folder_events`
raw 1206-byte payloads LIDAR without host time                        ``io.packets``
=====================  =============================================  =========================

Every lidar datagram is told data or position by one rule, :func:`lidar_kind`. Streams of
several files merge lazily by host time (:func:`merge`). The decoder's fast path
(``io.packets``, pcap batches read straight into arrays) goes by size alone: the same answer
whenever data and position packets arrive on their own ports (``tripod decode --ports`` keeps
only those).
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import NamedTuple

from tripod_shared import velodyne as vl

#: event kinds
LIDAR, POSITION, IMU, IMU_SAMPLE, MARK = 0, 1, 2, 3, 4
KIND_NAMES = {LIDAR: "lidar", POSITION: "position", IMU: "imu", IMU_SAMPLE: "imu_sample",
              MARK: "mark"}


class Event(NamedTuple):
    """One thing a recording holds, at the host's receive time.

    ``data`` by kind: LIDAR and POSITION the UDP payload (bytes), IMU the raw bytes of one host
    read, IMU_SAMPLE a ``tripod_shared.messages.ImuSample``, MARK the operator's label (str).
    """

    host_ns: int  # host_realtime
    kind: int
    data: object


def lidar_kind(dst_port: int, size: int, data_port: int = vl.DATA_PORT,
               position_port: int = vl.POSITION_PORT) -> int | None:
    """The one data/position rule: a datagram sent to the data port is a data packet, one sent
    to the position port a position packet; on any other port the size decides (1206 data, 512
    position). None: not a lidar datagram. Payload checks (header, product) are the reader's."""
    if dst_port == data_port:
        return LIDAR
    if dst_port == position_port:
        return POSITION
    if size == vl.DATA_PACKET_SIZE:
        return LIDAR
    if size == vl.POSITION_PACKET_SIZE:
        return POSITION
    return None


def pcap_events(reader, data_port: int = vl.DATA_PORT, position_port: int = vl.POSITION_PORT,
                skipped: dict | None = None) -> Iterator[Event]:
    """LIDAR and POSITION events of an open ``io.pcap.PcapReader``; other datagrams are counted
    in ``skipped["other_datagram"]``."""
    for d in reader:
        kind = lidar_kind(d.dst_port, len(d.payload), data_port, position_port)
        if kind is None:
            if skipped is not None:
                skipped["other_datagram"] = skipped.get("other_datagram", 0) + 1
            continue
        yield Event(d.t_ns, kind, d.payload)


def imu_log_events(path: str | os.PathLike) -> Iterator[Event]:
    """IMU events of a tripod IMU log, one per host read."""
    from .imu_log import ImuLogReader

    for rec in ImuLogReader(path):
        yield Event(rec.host_ns, IMU, rec.data)


class McapEvents:
    """Events of one of our MCAP recordings (``tripod_shared.recording``).

    Parameters
    ----------
    kinds : which events to read (default LIDAR and POSITION); IMU gives each sample's raw
        bytes (samples without raw bytes give none), IMU_SAMPLE the decoded sample, MARK the
        operator's station marks.

    A message that does not decode is counted in ``skipped["bad_message:<topic>"]`` and left
    out; ``truncated`` / ``error`` tell whether the file is cut off (after iterating).
    """

    def __init__(self, path: str | os.PathLike, kinds: Iterable[int] = (LIDAR, POSITION)):
        self.path = Path(path)
        self.kinds = frozenset(kinds)
        self.skipped: dict[str, int] = {}
        self.truncated = False
        self.error = ""

    def __iter__(self) -> Iterator[Event]:
        from tripod_shared import messages as m
        from tripod_shared import topics as t
        from tripod_shared.recording import RecordingReader, decode_event_message

        topics = {LIDAR: t.TOPIC_LIDAR_PACKETS, POSITION: t.TOPIC_LIDAR_POSITION,
                  IMU: t.TOPIC_IMU, IMU_SAMPLE: t.TOPIC_IMU, MARK: t.TOPIC_EVENTS}
        want = sorted({topics[k] for k in self.kinds}, key=list(topics.values()).index)
        reader = RecordingReader(self.path)
        for msg in reader.messages(want):
            try:
                if msg.topic == t.TOPIC_LIDAR_PACKETS:
                    yield self._packet(LIDAR, m.decode_velodyne_packet, msg.data)
                elif msg.topic == t.TOPIC_LIDAR_POSITION:
                    yield self._packet(POSITION, m.decode_position_packet, msg.data)
                elif msg.topic == t.TOPIC_IMU:
                    s = m.decode_imu(msg.data)
                    if IMU in self.kinds and s.raw:
                        yield Event(s.host_ns, IMU, s.raw)
                    if IMU_SAMPLE in self.kinds:
                        yield Event(s.host_ns, IMU_SAMPLE, s)
                else:
                    e = decode_event_message(msg)  # CDR, or JSON (format version 1)
                    if e.kind == "mark":
                        yield Event(e.host_ns, MARK, e.label)
            except Exception:  # noqa: BLE001 - a corrupt message is counted, never fatal
                key = f"bad_message:{msg.topic}"
                self.skipped[key] = self.skipped.get(key, 0) + 1
        self.truncated = reader.report.truncated
        self.error = reader.report.error or ""

    @staticmethod
    def _packet(kind: int, decode, data: bytes) -> Event:
        host_ns, payload = decode(data)
        return Event(host_ns, kind, payload)


def merge(*streams: Iterable[Event]) -> Iterator[Event]:
    """Events of several streams, each in time order, merged lazily by host time (stable: on
    equal stamps the earlier stream first)."""
    return heapq.merge(*streams, key=lambda e: e[0])


def folder_events(folder: str | os.PathLike) -> Iterator[Event]:
    """A ``tripod simulate`` folder: ``capture.pcap`` and, when present, ``imu.tripimu``."""
    from .pcap import PcapReader

    folder = Path(folder)
    streams = [pcap_events(PcapReader(folder / "capture.pcap"))]
    if (folder / "imu.tripimu").is_file():
        streams.append(imu_log_events(folder / "imu.tripimu"))
    return merge(*streams)
