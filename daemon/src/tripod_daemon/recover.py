# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon recover FILE``: rebuild a recording whose writer was killed.

A file cut off by ``kill -9`` or a power loss has whole chunks (the recorder closes one at least
every ``flush_interval_s``) followed by, at most, part of one more, and no summary or footer, so
seeking readers refuse it. Recovery streams every whole, CRC-valid record in file order, writes
them to a new file with the same schemas, channels, message times, sequences and metadata plus a
fresh summary and indexes, and reports what was kept and what was lost (the unfinished tail).
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field

from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer


class _ExactReader:
    """File reader that counts bytes and refuses short reads (a cut mid-record is an error,
    never a silently shortened record)."""

    def __init__(self, fh):
        self._fh = fh
        self.pos = 0

    def read(self, n: int = -1) -> bytes:
        data = self._fh.read(n)
        if n is not None and n >= 0 and len(data) < n:
            self.pos += len(data)
            raise EOFError(f"file ends inside a record at byte {self.pos}")
        self.pos += len(data)
        return data


@dataclass
class RecoverReport:
    source: str
    output: str
    complete: bool = False  # the source already had its footer
    messages: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    kept_bytes: int = 0  # source bytes up to the end of the last whole record
    lost_bytes: int = 0  # source bytes after it (an unfinished chunk or record)
    error: str = ""

    @property
    def total_messages(self) -> int:
        return sum(self.messages.values())

    def lines(self) -> list[str]:
        out = [f"{self.source}: {'complete file' if self.complete else 'cut off'}"
               + (f" ({self.error})" if self.error else "")]
        for topic, n in sorted(self.messages.items()):
            out.append(f"  {topic}: {n} messages")
        if self.first_ns is not None:
            out.append(f"  time range: {self.first_ns} .. {self.last_ns} ns "
                       f"({(self.last_ns - self.first_ns) / 1e9:.3f} s)")
        out.append(f"  kept {self.kept_bytes} bytes; lost {self.lost_bytes} bytes after the "
                   "last whole record" + (" (an unfinished chunk)" if self.lost_bytes else ""))
        out.append(f"  wrote {self.output}")
        return out


def recover(source: str, output: str, compression: str = "zstd") -> RecoverReport:
    """Copy every whole record of ``source`` into a well-formed MCAP at ``output``."""
    rep = RecoverReport(source, output)
    size = os.path.getsize(source)
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE}[compression]
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    topics: dict[int, str] = {}
    pending_channels: dict[int, Channel] = {}
    tmp = output + ".part"
    try:
        _recover_into(source, tmp, comp, rep, size, schema_map, channel_map, topics,
                      pending_channels)
    except BaseException:
        # never leave a partial file behind (a full disk, an interrupt)
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
    os.replace(tmp, output)
    return rep


def _recover_into(source, tmp, comp, rep, size, schema_map, channel_map, topics,
                  pending_channels) -> None:
    with open(source, "rb") as src, open(tmp, "wb") as dst:
        reader = _ExactReader(src)
        writer = Writer(dst, chunk_size=4 << 20, compression=comp)
        last_good = 0
        started = False
        try:
            stream = StreamReader(reader, skip_magic=False, emit_chunks=True, validate_crcs=True)
            last_good = reader.pos
            for rec in stream.records:
                if isinstance(rec, Chunk):
                    # decompress and CRC-check the whole chunk before taking any of it
                    from mcap.stream_reader import breakup_chunk

                    records = breakup_chunk(rec, validate_crc=True)
                else:
                    records = [rec]
                for r in records:
                    if not started:
                        # keep the source's profile: ros2 (format 2) or "" (format 1)
                        writer.start(profile=r.profile if isinstance(r, Header) else "",
                                     library="tripod-daemon recover")
                        started = True
                    if isinstance(r, Schema):
                        if r.id not in schema_map:
                            schema_map[r.id] = writer.register_schema(r.name, r.encoding, r.data)
                    elif isinstance(r, Channel):
                        pending_channels[r.id] = r
                    elif isinstance(r, Message):
                        cid = channel_map.get(r.channel_id)
                        if cid is None:
                            ch = pending_channels.get(r.channel_id)
                            if ch is None:
                                continue  # a message without its channel cannot be read
                            cid = writer.register_channel(
                                ch.topic, ch.message_encoding, schema_map.get(ch.schema_id, 0),
                                dict(ch.metadata))
                            channel_map[r.channel_id] = cid
                            topics[r.channel_id] = ch.topic
                        writer.add_message(cid, r.log_time, r.data, r.publish_time, r.sequence)
                        t = topics[r.channel_id]
                        rep.messages[t] = rep.messages.get(t, 0) + 1
                        rep.first_ns = r.log_time if rep.first_ns is None else min(rep.first_ns, r.log_time)
                        rep.last_ns = r.log_time if rep.last_ns is None else max(rep.last_ns, r.log_time)
                    elif isinstance(r, Metadata):
                        writer.add_metadata(r.name, dict(r.metadata))
                    elif isinstance(r, (DataEnd, Footer)):
                        if isinstance(r, Footer):
                            rep.complete = True
                last_good = reader.pos
                if isinstance(rec, DataEnd):
                    rep.complete = True  # the summary after it is rebuilt, not copied
                    last_good = size
                    break
        except Exception as exc:  # noqa: BLE001 - any cut or corruption ends the good part
            rep.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        if not started:
            writer.start(profile="", library="tripod-daemon recover")
        rep.kept_bytes = last_good
        rep.lost_bytes = size - last_good
        writer.add_metadata("tripod_recover", {
            "source": os.path.basename(source), "kept_bytes": str(rep.kept_bytes),
            "lost_bytes": str(rep.lost_bytes), "complete": str(rep.complete),
        })
        writer.finish()
        dst.flush()
        os.fsync(dst.fileno())


def _free(path: str) -> int:
    try:
        st = os.statvfs(path)
    except OSError:
        return -1
    return st.f_bavail * st.f_frsize


def output_candidates(out: str, fallback_dirs: list[str]) -> list[str]:
    """Where to try writing: ``out``, then the same file name in each fallback directory."""
    name = os.path.basename(out)
    return [out] + [os.path.join(d, name) for d in fallback_dirs]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="tripod-daemon recover",
        description="Rebuild a recording whose writer was killed: keep every whole record, add "
        "the summary and indexes, report what was lost.")
    p.add_argument("file", help="the cut-off .mcap")
    p.add_argument("-o", "--output", help="where to write (default: FILE with .recovered.mcap)")
    p.add_argument("--in-place", action="store_true",
                   help="replace FILE with the rebuilt file")
    p.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd")
    p.add_argument("--fallback-dir", action="append", default=None, metavar="DIR",
                   help="where to write when the output's disk is full (repeatable; default: "
                   "$TMPDIR or /tmp, then /var/tmp)")
    a = p.parse_args(argv)
    if not os.path.isfile(a.file):
        print(f"tripod-daemon recover: no such file: {a.file}", file=sys.stderr)
        return 2
    with open(a.file, "rb") as fh:
        if fh.read(8) != b"\x89MCAP0\r\n":
            print(f"tripod-daemon recover: not an MCAP file: {a.file}", file=sys.stderr)
            return 2
    if a.in_place:
        out = a.file
    else:
        stem = a.file[:-5] if a.file.endswith(".mcap") else a.file
        out = a.output or stem + ".recovered.mcap"
    fallback = a.fallback_dir
    if fallback is None:
        fallback = [os.environ.get("TMPDIR") or "/tmp", "/var/tmp"]
    need = os.path.getsize(a.file)  # the rebuilt file is about the size of the source
    errors = []
    for target in output_candidates(out, [] if a.in_place else fallback):
        d = os.path.dirname(os.path.abspath(target))
        if _free(d) < need:
            errors.append(f"{d}: {max(0, _free(d)) >> 20} MiB free, about {need >> 20} MiB "
                          "needed")
            continue
        try:
            rep = recover(a.file, target, a.compression)
        except OSError as exc:  # the partial file is gone; try the next place
            errors.append(f"{target}: {exc}")
            continue
        if target != out:
            print(f"tripod-daemon recover: {errors[-1]}; wrote to {target} instead",
                  file=sys.stderr)
        print("\n".join(rep.lines()))
        return 0
    print("tripod-daemon recover: nowhere to write: " + "; ".join(errors), file=sys.stderr)
    return 1
