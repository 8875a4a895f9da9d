# SPDX-License-Identifier: BSD-3-Clause
"""Read what a reconstruction needs from a recording: lidar packets on the lidar's time line, IMU
orientation samples and the operator's station marks.

Inputs: our MCAP recordings (``tripod_shared.recording``), or a pcap/pcapng of the lidar plus an
IMU log (see :func:`read_imu_log`). Lidar time follows the README's convention: the packets' own
µs-past-the-hour, with the hour from GPRMC when the position packets carry one, else from the
host receive clock.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tripod_shared import velodyne as vl
from tripod_shared.recording import is_mcap
from tripod_shared import nmea
from tripod_shared.timebase import (NS_PER_US, toh_us_to_unix_ns, toh_us_to_unix_ns_array,
                                    unwrap_toh_us_array)


class RecordingError(ValueError):
    """The input cannot be reconstructed (one-line message for the CLI)."""


@dataclass
class LidarPackets:
    """Data packets in recording order.

    Attributes
    ----------
    host_ns : (P,) int64, host_realtime at receive
    lidar_ns : (P,) int64, lidar time on the UNIX time line [ns]
    payload : (P, 1206) uint8, verbatim packets
    """

    host_ns: np.ndarray
    lidar_ns: np.ndarray
    payload: np.ndarray
    return_mode: str = "strongest"

    def __len__(self) -> int:
        return len(self.host_ns)


@dataclass
class ImuTrack:
    """IMU orientation samples in arrival order: host_ns (K,) int64 at the read (non-decreasing;
    several samples of one read share a stamp), q_world_imu (K, 4) w, x, y, z."""

    host_ns: np.ndarray
    q_wxyz: np.ndarray

    def __len__(self) -> int:
        return len(self.host_ns)


@dataclass
class Recording:
    """Everything read from one input, plus what was met on the way."""

    source: str
    lidar: LidarPackets
    imu: ImuTrack | None
    marks: list[tuple[int, str]] = field(default_factory=list)  # (host_ns, label)
    hour_source: str = "host"  # "gprmc" or "host"
    truncated: bool = False
    notes: list[str] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        if len(self.lidar) < 2:
            return 0.0
        return float(self.lidar.lidar_ns[-1] - self.lidar.lidar_ns[0]) * 1e-9


# ---- GPRMC ---------------------------------------------------------------------------------
def gprmc_unix_ns(payload: bytes) -> int | None:
    """UNIX time [ns] of a position packet's GPRMC sentence (whole seconds), or None."""
    raw = bytes(payload[vl.POS_NMEA_OFFSET : vl.POS_NMEA_OFFSET + vl.POS_NMEA_SIZE])
    return nmea.rmc_unix_ns(raw.split(b"\x00", 1)[0].decode("ascii", "replace"))


def _lidar_time(host_ns: np.ndarray, toh_us: np.ndarray, gprmc: list[tuple[int, int]]):
    """Lidar time of each packet; the hour from GPRMC (position packets) when present."""
    if gprmc:
        # offset between the host clock and GPS time, from the position packets (robust median)
        offs = np.array([g - h for h, g in gprmc], dtype=np.int64)
        ref = host_ns + int(np.median(offs))
        return toh_us_to_unix_ns_array(toh_us, ref), "gprmc"
    # one reference for the whole file, unwrapped, so jitter never flips an hour mid-recording
    t0 = toh_us_to_unix_ns(int(toh_us[0]), int(host_ns[0]))
    return t0 + (unwrap_toh_us_array(toh_us) - int(toh_us[0])) * NS_PER_US, "host"


def _finish_lidar(host, payloads, gprmc, rec: Recording | None = None) -> tuple[LidarPackets, str]:
    if not payloads:
        raise RecordingError("no lidar data packets in the input")
    host_ns = np.asarray(host, dtype=np.int64)
    pay = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(-1, vl.DATA_PACKET_SIZE)
    toh = pay[:, vl.TIMESTAMP_OFFSET : vl.TIMESTAMP_OFFSET + 4].copy().view("<u4").ravel()
    lidar_ns, hour_source = _lidar_time(host_ns, toh, gprmc)
    modes = np.unique(pay[:, vl.RETURN_MODE_OFFSET])
    mode = vl.RETURN_MODES.get(int(modes[0]), "strongest") if len(modes) == 1 else "mixed"
    return LidarPackets(host_ns, lidar_ns, pay, mode), hour_source


def read_recording(paths, imu_log: str | os.PathLike | None = None) -> Recording:
    """Read a recording: one or more MCAP files of ours (a recording split by the daemon), or a
    pcap/pcapng with an IMU log (a tripod IMU log ``*.tripimu`` or text lines ``t w x y z``), or
    a ``tripod simulate`` folder (``capture.pcap`` + ``imu.tripimu``).

    Raises
    ------
    RecordingError
        Missing or unreadable file, no lidar packets, no usable data.
    """
    items = [Path(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    if not items:
        raise RecordingError("no recording given")
    files: list[Path] = []
    for p in items:
        if p.is_dir():
            cap, imu = p / "capture.pcap", p / "imu.tripimu"
            if not cap.is_file():
                raise RecordingError(f"{p}: a folder without capture.pcap")
            files.append(cap)
            if imu.is_file() and imu_log is None:
                imu_log = imu
        elif not p.is_file():
            raise RecordingError(f"no such recording: {p}")
        elif p.stat().st_size == 0:
            raise RecordingError(f"{p}: empty file")
        elif p.suffix == ".tripimu" or (p.suffix in (".txt", ".csv") and imu_log is None):
            imu_log = p
        else:
            files.append(p)
    if not files:
        raise RecordingError("no lidar recording given (only an IMU log)")
    recs = [_read_mcap(f) if is_mcap(f) else _read_pcap(f) for f in files]
    rec = recs[0] if len(recs) == 1 else _concatenate(recs)
    if imu_log is not None:
        rec.imu = read_imu_log(imu_log)
    return rec


def _concatenate(recs: list[Recording]) -> Recording:
    """One recording from the parts the daemon split it into, in time order."""
    recs = sorted(recs, key=lambda r: int(r.lidar.lidar_ns[0]))
    lid = LidarPackets(np.concatenate([r.lidar.host_ns for r in recs]),
                       np.concatenate([r.lidar.lidar_ns for r in recs]),
                       np.concatenate([r.lidar.payload for r in recs]), recs[0].lidar.return_mode)
    imus = [r.imu for r in recs if r.imu is not None]
    imu = None
    if imus:
        imu = _imu_track(list(np.concatenate([i.host_ns for i in imus])),
                         np.concatenate([i.q_wxyz for i in imus]))
    out = Recording(" + ".join(r.source for r in recs), lid, imu,
                    sum((r.marks for r in recs), []), recs[0].hour_source,
                    any(r.truncated for r in recs), sum((r.notes for r in recs), []))
    for r in recs:
        for k, v in r.skipped.items():
            out.skipped[k] = out.skipped.get(k, 0) + v
    return out


def _read_mcap(path: Path) -> Recording:
    from ..io.events import IMU_SAMPLE, LIDAR, MARK, POSITION, McapEvents

    events = McapEvents(path, (LIDAR, POSITION, IMU_SAMPLE, MARK))
    lidar = _LidarCollector()
    imu_t, imu_q, marks = [], [], []
    for host_ns, kind, data in events:
        if kind == IMU_SAMPLE:
            imu_t.append(host_ns)
            imu_q.append((data.w, data.x, data.y, data.z))
        elif kind == MARK:
            marks.append((host_ns, data))
        else:
            lidar.add(host_ns, kind, data)
    skipped = dict(events.skipped)
    for k, v in lidar.skipped.items():
        skipped[k] = skipped.get(k, 0) + v
    lidar_packets, hour_source = _finish_lidar(lidar.host, lidar.payloads, lidar.gprmc)
    rec = Recording(str(path), lidar_packets, _imu_track(imu_t, imu_q), marks, hour_source,
                    events.truncated, skipped=skipped)
    if events.truncated:
        rec.notes.append(f"recording is cut off ({events.error or None}); every whole message "
                         "before the cut was used")
    return rec


def _read_pcap(path: Path) -> Recording:
    from ..io.pcap import PcapFormatError, PcapReader

    try:
        reader = PcapReader(path)
    except PcapFormatError as exc:
        raise RecordingError(str(exc)) from None
    lidar = _LidarCollector()
    for b in reader.payload_batches(vl.DATA_PACKET_SIZE):  # C++ record scan: no Python step
        lidar.add_batch(b)                                  # per data packet
    lidar_packets, hour_source = _finish_lidar(lidar.host, lidar.payloads, lidar.gprmc)
    rec = Recording(str(path), lidar_packets, None, [], hour_source, reader.stats.truncated,
                    skipped=lidar.skipped)
    if reader.stats.truncated:
        rec.notes.append("pcap is cut off mid-record; every whole packet before the cut was used")
    return rec


class _LidarCollector:
    """Data packets (checked: whole, VLP-16 header) and the GPRMC times of position packets."""

    def __init__(self) -> None:
        self.host: list[int] = []
        self.payloads: list[bytes] = []
        self.gprmc: list[tuple[int, int]] = []  # (host_ns, GPS UNIX ns)
        self.skipped: dict[str, int] = {}

    def add(self, host_ns: int, kind: int, payload: bytes) -> None:
        from ..io.events import LIDAR

        if kind == LIDAR:
            if vl.check_data_packet(payload) != vl.PacketKind.DATA:
                self.skipped["bad_lidar_packet"] = self.skipped.get("bad_lidar_packet", 0) + 1
                return
            self.host.append(host_ns)
            self.payloads.append(payload)
        elif len(payload) == vl.POSITION_PACKET_SIZE:
            g = gprmc_unix_ns(payload)
            if g is not None:
                self.gprmc.append((host_ns, g))
        else:
            self.skipped["bad_position_packet"] = self.skipped.get("bad_position_packet", 0) + 1

    def add_batch(self, batch) -> None:
        """The datagrams of an ``io.pcap.PayloadBatch``, as :meth:`add` of each would take them
        (``io.events.lidar_kind`` by port and size, :func:`tripod_shared.velodyne.
        check_data_packet` vectorised over the batch's 1206-byte payloads)."""
        from ..io.events import LIDAR, POSITION, lidar_kind

        data, port = batch.data, batch.data_port.astype(np.int64)
        if len(data):
            # 1206 bytes to the position port are position packets (skipped below); else data
            to_pos = port == vl.POSITION_PORT
            flags = data[:, : vl.TIMESTAMP_OFFSET].reshape(len(data), -1, vl.BLOCK_SIZE)[:, :, :2]
            ok = ((flags[:, :, 0] == 0xFF).all(1) & (flags[:, :, 1] == 0xEE).all(1)
                  & np.isin(data[:, vl.RETURN_MODE_OFFSET], list(vl.RETURN_MODES))
                  & np.isin(data[:, vl.PRODUCT_ID_OFFSET],
                            [vl.PRODUCT_VLP16, vl.PRODUCT_HDL32E]))
            n_bad = int((~ok & ~to_pos).sum())
            if n_bad:
                self.skipped["bad_lidar_packet"] = self.skipped.get("bad_lidar_packet", 0) + n_bad
            if to_pos.any():
                self.skipped["bad_position_packet"] = (self.skipped.get("bad_position_packet", 0)
                                                       + int(to_pos.sum()))
            keep = ok & ~to_pos
            if keep.any():
                self.host.extend(batch.data_t_ns[keep].tolist())
                self.payloads.append(np.ascontiguousarray(data[keep]).tobytes())
        for t_ns, dst_port, payload in batch.others:
            kind = lidar_kind(dst_port, len(payload))
            if kind is None:
                self.skipped["other_datagram"] = self.skipped.get("other_datagram", 0) + 1
            elif kind in (LIDAR, POSITION):
                self.add(t_ns, kind, payload)


def _imu_track(t, q) -> ImuTrack | None:
    if not t:
        return None
    host = np.asarray(t, dtype=np.int64)
    quat = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    norm = np.linalg.norm(quat, axis=1)
    ok = np.isfinite(norm) & (norm > 0.5)
    host, quat = host[ok], quat[ok] / norm[ok, None]
    order = np.argsort(host, kind="stable")  # equal stamps (several samples per read) stay
    host, quat = host[order], quat[order]
    return ImuTrack(host, quat) if len(host) >= 2 else None


def read_imu_log(path: str | os.PathLike) -> ImuTrack:
    """Read an IMU log beside a pcap: a tripod IMU log (``imu_log``: raw TFP/WitMotion bytes
    with host read times), or text lines ``host_time_s w x y z`` (or ``host_ns,w,x,y,z``;
    ``#`` comments). Times are host_realtime, like the pcap's capture stamps.
    """
    from ..io.imu_log import MAGIC, ImuLogError, ImuLogReader

    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no such IMU log: {path}")
    with open(path, "rb") as fh:
        binary = fh.read(len(MAGIC)) == MAGIC
    if binary:
        try:
            t, q = ImuLogReader(path).parse_quaternions()
        except ImuLogError as exc:
            raise RecordingError(str(exc)) from None
        track = _imu_track(list(t), q)
        if track is None:
            raise RecordingError(f"{path}: no IMU quaternions in the log")
        return track
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for ln in fh:
            ln = ln.strip()
            if not ln or ln.startswith("#"):
                continue
            parts = ln.replace(",", " ").split()
            if len(parts) < 5:
                continue
            try:
                rows.append([float(x) for x in parts[:5]])
            except ValueError:
                continue
    if len(rows) < 2:
        raise RecordingError(f"{path}: no IMU samples (expected lines 'time w x y z')")
    a = np.asarray(rows)
    t = a[:, 0]
    host = (t * 1e9).astype(np.int64) if np.median(t) < 1e11 else t.astype(np.int64)
    track = _imu_track(list(host), a[:, 1:5])
    if track is None:
        raise RecordingError(f"{path}: no valid IMU quaternions")
    return track
