# SPDX-License-Identifier: BSD-3-Clause
"""A chunked MCAP writer that takes blocks of equal-size messages without per-message Python work.

The ``mcap`` package's ``Writer`` builds every message record through a dataclass and a dozen
small writes, and its message index likewise (about 10 µs a message: at 50,000 lidar packets a
second that alone is half a core). Here a lidar batch arrives as a :class:`MessageBlock`: a numpy
array of n rows, each row one whole MCAP Message record (31-byte header, then the message bytes),
so the record headers, the chunk's message index and the statistics are filled with a few numpy
operations per batch, and the rows go into the chunk as one ``bytes``.

The file is a plain MCAP (spec: https://mcap.dev/spec) written as the ``mcap`` package writes it:
schemas and channels inside the chunk where they are first used, a message index after every
chunk, and a summary with repeated schemas and channels, statistics, chunk and metadata indexes
and summary offsets, and CRCs of chunks and summary. The records other than messages and message
indexes (and the chunk's few header fields) are the ``mcap`` package's own (``mcap.records``), so their layout is not ours to get
wrong; any MCAP reader reads the file.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"

#: MCAP Message record header: opcode u8, record length u64, channel_id u16, sequence u32,
#: log_time u64, publish_time u64 (little-endian, packed); the message bytes follow
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
MESSAGE_HEADER_SIZE = MESSAGE_HEADER.size  # 31

_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
_MSG_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel_id, entries' bytes
_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, start, end, size, crc, len(compression)


def message_block_dtype(data_size: int) -> np.dtype:
    """Row type of a :class:`MessageBlock` whose messages are ``data_size`` bytes each."""
    return np.dtype({
        "names": ["opcode", "length", "channel_id", "sequence", "log_time", "publish_time", "data"],
        "formats": ["u1", "<u8", "<u2", "<u4", "<u8", "<u8", f"V{data_size}"],
        "offsets": [0, 1, 9, 11, 15, 23, 31],
        "itemsize": MESSAGE_HEADER_SIZE + data_size,
    })


class MessageBlock:
    """n messages of one topic, all ``data_size`` bytes, as MCAP Message records.

    ``rows`` is a ``(n, 31 + data_size)`` uint8 array: row i holds message i's bytes at
    ``[31:]`` (the header bytes before them are filled by the writer: channel and sequence are
    the file's); ``log_times`` the n host_realtime ns (publish_time = log_time).
    """

    __slots__ = ("topic", "rows", "log_times")

    def __init__(self, topic: str, rows: np.ndarray, log_times: np.ndarray):
        if rows.ndim != 2 or rows.dtype != np.uint8 or rows.shape[1] <= MESSAGE_HEADER_SIZE:
            raise ValueError("rows must be a (n, 31 + size) uint8 array")
        if log_times.shape != (rows.shape[0],):
            raise ValueError("one log time per row")
        self.topic = topic
        self.rows = rows
        self.log_times = log_times

    def __len__(self) -> int:
        return self.rows.shape[0]

    @property
    def data_size(self) -> int:
        return self.rows.shape[1] - MESSAGE_HEADER_SIZE

    @property
    def nbytes(self) -> int:
        """Message bytes (what a list of (topic, ns, data) items would hold)."""
        return self.rows.shape[0] * (self.rows.shape[1] - MESSAGE_HEADER_SIZE)

    def datas(self) -> list[bytes]:
        """Each message's bytes (one copy of the block, then slices)."""
        size = self.rows.shape[1]
        buf = self.rows.tobytes()
        return [buf[o + MESSAGE_HEADER_SIZE:o + size] for o in range(0, len(buf), size)]

    def items(self) -> list[tuple[str, int, bytes]]:
        """The block as (topic, log_time ns, message bytes) items."""
        return list(zip([self.topic] * len(self), self.log_times.tolist(), self.datas()))


def iter_items(batch):
    """(topic, ns, bytes) of every message of a batch of items and :class:`MessageBlock` s."""
    for it in batch:
        if isinstance(it, MessageBlock):
            yield from it.items()
        else:
            yield it


class McapChunkWriter:
    """Write an MCAP file chunk by chunk. Not thread-safe.

    Parameters
    ----------
    stream : binary file object (written sequentially; ``tell`` must work)
    chunk_size : int
        A chunk is finished once its uncompressed records exceed this.
    compression : "zstd" | "lz4" | ""
    level : int, optional
        zstd level (default 3, as the ``mcap`` package); ignored for lz4.
    """

    def __init__(self, stream: IO[bytes], chunk_size: int = 1 << 20, compression: str = "zstd",
                 level: int | None = None):
        if compression == "zstd":
            import zstandard

            self._zstd = zstandard.ZstdCompressor(level=3 if level is None else level)
        elif compression == "lz4":
            import lz4.frame

            self._lz4 = lz4.frame.compress
        elif compression != "":
            raise ValueError(f"unknown compression {compression!r}")
        self._compression = compression
        self._stream = stream
        try:
            self._pos = stream.tell()  # file offset of the next byte we write
        except (OSError, AttributeError):
            self._pos = 0
        self._chunk_size = chunk_size
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._stats = Statistics(
            attachment_count=0, channel_count=0, channel_message_counts=defaultdict(int),
            chunk_count=0, message_count=0, metadata_count=0, message_start_time=0,
            message_end_time=0, schema_count=0)
        self._new_chunk()

    # ---- chunk in progress --------------------------------------------------------------------
    def _new_chunk(self) -> None:
        self._parts: list[bytes] = []  # the chunk's records, in order
        self._size = 0  # their total size
        self._n = 0  # messages in the chunk
        self._t0 = 0
        self._t1 = 0
        # per channel: index entries as (log_times, offsets) arrays, in record order
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._pending: dict[int, tuple[list[int], list[int]]] = {}  # single messages

    def _append(self, data: bytes) -> None:
        self._parts.append(data)
        self._size += len(data)

    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._pos += len(data)

    def _record(self, rec) -> bytes:
        b = RecordBuilder()
        rec.write(b)
        return b.end()

    def _times(self, t0: int, t1: int, n: int) -> None:
        st = self._stats
        if st.message_count == 0:
            st.message_start_time, st.message_end_time = t0, t1
        else:
            st.message_start_time = min(st.message_start_time, t0)
            st.message_end_time = max(st.message_end_time, t1)
        st.message_count += n
        if self._n == 0:
            self._t0, self._t1 = t0, t1
        else:
            self._t0, self._t1 = min(self._t0, t0), max(self._t1, t1)
        self._n += n

    # ---- public -----------------------------------------------------------------------------
    def start(self, profile: str, library: str) -> None:
        self._write(MAGIC)
        self._write(self._record(Header(profile=profile, library=library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        schema = Schema(id=sid, data=data, encoding=encoding, name=name)
        self._schemas[sid] = schema
        self._stats.schema_count += 1
        self._append(self._record(schema))
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        cid = len(self._channels) + 1
        ch = Channel(id=cid, topic=topic, message_encoding=message_encoding,
                     schema_id=schema_id, metadata=dict(metadata or {}))
        self._channels[cid] = ch
        self._stats.channel_count += 1
        self._append(self._record(ch))
        return cid

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        pend = self._pending.get(channel_id)
        if pend is None:
            pend = self._pending[channel_id] = ([], [])
        pend[0].append(log_time)
        pend[1].append(self._size)
        self._append(MESSAGE_HEADER.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence,
                                         log_time, publish_time) + data)
        self._stats.channel_message_counts[channel_id] += 1
        self._times(log_time, log_time, 1)
        if self._size > self._chunk_size:
            self.flush_chunk()

    def add_block(self, channel_id: int, rows: np.ndarray, log_times: np.ndarray,
                  first_sequence: int) -> None:
        """Write ``rows`` (see :class:`MessageBlock`) as messages of ``channel_id`` with
        sequences ``first_sequence``, +1, ...; their header bytes are filled in here."""
        n, size = rows.shape
        if n == 0:
            return
        rec = rows.view(message_block_dtype(size - MESSAGE_HEADER_SIZE)).reshape(n)
        rec["opcode"] = Opcode.MESSAGE
        rec["length"] = size - 9
        rec["channel_id"] = channel_id
        rec["sequence"] = np.arange(first_sequence, first_sequence + n, dtype=np.uint64) \
            .astype(np.uint32)  # wraps like a u32 counter
        rec["log_time"] = log_times
        rec["publish_time"] = log_times
        self._flush_pending(channel_id)
        offsets = self._size + np.arange(n, dtype=np.uint64) * np.uint64(size)
        self._index.setdefault(channel_id, []).append((log_times.astype(np.uint64), offsets))
        self._append(rows.tobytes())
        self._stats.channel_message_counts[channel_id] += n
        self._times(int(log_times.min()), int(log_times.max()), n)
        if self._size > self._chunk_size:
            self.flush_chunk()

    def _flush_pending(self, channel_id: int) -> None:
        """Move a channel's single-message index entries behind its block entries, in order."""
        pend = self._pending.pop(channel_id, None)
        if pend is not None and pend[0]:
            self._index.setdefault(channel_id, []).append(
                (np.array(pend[0], dtype=np.uint64), np.array(pend[1], dtype=np.uint64)))

    def flush_chunk(self) -> None:
        """Finish the chunk in progress (if it holds a message) and write it with its index."""
        if self._n == 0:
            return
        for cid in list(self._pending):
            self._flush_pending(cid)
        # the records are compressed and summed part by part, never joined (no 4 MiB copies)
        parts, size = self._parts, self._size
        crc = 0
        for p in parts:
            crc = zlib.crc32(p, crc)
        if self._compression == "zstd":
            cobj = self._zstd.compressobj(size=size)
            out = [cobj.compress(p) for p in parts]
            out.append(cobj.flush())
        elif self._compression == "lz4":
            out = [self._lz4(b"".join(parts))]
        else:
            out = parts
        csize = sum(len(o) for o in out)
        comp = self._compression.encode()
        # Chunk record: message_start_time, message_end_time, uncompressed_size,
        # uncompressed_crc, compression (string), records (u64 length + bytes)
        head = _CHUNK_HEAD.pack(Opcode.CHUNK, 8 + 8 + 8 + 4 + 4 + len(comp) + 8 + csize,
                                self._t0, self._t1, size, crc, len(comp)) + comp \
            + struct.pack("<Q", csize)
        start = self._pos
        self._write(head)
        for o in out:
            self._write(o)
        index = ChunkIndex(
            message_start_time=self._t0, message_end_time=self._t1, chunk_start_offset=start,
            chunk_length=self._pos - start, message_index_offsets={}, message_index_length=0,
            compression=self._compression, compressed_size=csize, uncompressed_size=size)
        index_start = self._pos
        for cid, parts in self._index.items():
            entries = np.empty(sum(len(p[0]) for p in parts), dtype=_INDEX_ENTRY)
            k = 0
            for times, offs in parts:
                entries["log_time"][k:k + len(times)] = times
                entries["offset"][k:k + len(times)] = offs
                k += len(times)
            body = entries.tobytes()
            index.message_index_offsets[cid] = self._pos
            self._write(_MSG_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + len(body), cid, len(body))
                        + body)
        index.message_index_length = self._pos - index_start
        self._chunk_indexes.append(index)
        self._stats.chunk_count += 1
        self._new_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        offset = self._pos
        rec = self._record(Metadata(name=name, metadata=dict(data)))
        self._write(rec)
        self._stats.metadata_count += 1
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(rec), name=name))

    def finish(self) -> None:
        """Write the last chunk, the data end and the summary; does not close the stream."""
        if self._n == 0 and self._parts:
            # schemas/channels registered after the last message: keep them in the data section
            for p in self._parts:
                self._write(p)
            self._new_chunk()
        self.flush_chunk()
        self._write(self._record(DataEnd(0)))
        summary_start = self._pos
        b = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: int, records) -> None:
            start = b.count
            for r in records:
                r.write(b)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                         group_length=b.count - start))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + b.count
        for o in offsets:
            o.write(b)
        summary = b.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start,
                                     summary_offset_start), crc)
        self._write(summary)
        self._write(self._record(Footer(summary_start=summary_start,
                                        summary_offset_start=summary_offset_start,
                                        summary_crc=crc)))
        self._write(MAGIC)
