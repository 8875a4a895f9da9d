# SPDX-License-Identifier: BSD-3-Clause
"""Find the recordings under the paths given to ``tripod batch``: each one is a list of input
files exactly as ``tripod reconstruct`` takes them.

- **Our MCAP files**, grouped into recordings by the daemon's split naming
  (``tripod_daemon.recorder``): every file is ``<prefix>_<YYYYmmddTHHMMSS>Z.mcap`` (``_<k>``
  added on a name collision), named by its own UTC start; a file whose first event is
  ``start`` with reason ``split`` (size/duration limit) or ``rotate`` (split on demand)
  continues the file before it with the same prefix in the same folder. Any other start
  reason, or another name, begins a recording.
- **pcap/pcapng + IMU log** pairs: ``X.pcap`` with ``X.tripimu`` (or ``X.imu.txt``,
  ``X.imu.csv``, ``X.txt``, ``X.csv``) beside it. A pcap without one is still listed (it fails
  with the reconstruction's own one-line error: no IMU).
- **Simulator folders** as ``tripod simulate`` writes them (``capture.pcap`` +
  ``imu.tripimu``): one recording; the folder is not searched further.

Folders are searched recursively; files are taken as given.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

_SPLIT_NAME = re.compile(r"^(?P<prefix>.+)_(?P<stamp>\d{8}T\d{6})Z(?:_(?P<k>\d+))?\.mcap$")
#: start reasons the daemon writes when it continues the same recording in a new file
CONTINUATION_REASONS = ("split", "rotate")
_PCAP_SUFFIXES = (".pcap", ".pcapng")
_IMU_SUFFIXES = (".tripimu", ".imu.txt", ".imu.csv", ".txt", ".csv")


@dataclass
class BatchRecording:
    """One recording of a batch: ``inputs`` as ``tripod reconstruct RECORDING...`` takes them,
    ``imu`` as its ``--imu``; ``name`` is unique in the batch and names its output folder."""

    name: str
    kind: str  # "mcap" | "pcap" | "sim"
    inputs: list[Path]
    imu: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def files(self) -> list[Path]:
        """Every file read: the fingerprint of the input."""
        out: list[Path] = []
        for p in self.inputs:
            if p.is_dir():
                out += [q for q in (p / "capture.pcap", p / "imu.tripimu") if q.is_file()]
            else:
                out.append(p)
        if self.imu is not None:
            out.append(self.imu)
        return out


def is_sim_folder(path: Path) -> bool:
    return path.is_dir() and (path / "capture.pcap").is_file()


def first_start_reason(path: Path) -> str | None:
    """The reason of the file's first ``start`` event (None: no event, or unreadable)."""
    import struct

    from tripod_shared.recording import RecordingReader

    try:  # the reader decodes by the channel's encoding: format 2 (CDR) and format 1 (JSON)
        for ev in RecordingReader(path).events():
            return ev.label if ev.kind == "start" else None
    except (OSError, ValueError, KeyError, IndexError, struct.error):
        return None
    return None


def _is_mcap(path: Path) -> bool:
    from tripod_shared.recording import is_mcap

    try:
        return is_mcap(path)
    except OSError:
        return False


def group_mcap(files: list[Path]) -> list[list[Path]]:
    """MCAP files → recordings (lists of files in time order), by the daemon's split naming."""
    named: dict[tuple[Path, str], list[tuple[str, int, Path]]] = {}
    groups: list[list[Path]] = []
    for f in files:
        m = _SPLIT_NAME.match(f.name)
        if m is None:
            groups.append([f])
            continue
        named.setdefault((f.parent, m["prefix"]), []).append((m["stamp"], int(m["k"] or 0), f))
    for key in sorted(named, key=lambda k: (str(k[0]), k[1])):
        current: list[Path] = []
        for _, _, f in sorted(named[key]):
            if current and first_start_reason(f) in CONTINUATION_REASONS:
                current.append(f)
            else:
                if current:
                    groups.append(current)
                current = [f]
        groups.append(current)
    return groups


def _imu_beside(pcap: Path) -> Path | None:
    stem = pcap.with_suffix("")
    for suf in _IMU_SUFFIXES:
        cand = stem.with_name(stem.name + suf)
        if cand.is_file():
            return cand
    return None


def discover(paths: list[Path]) -> tuple[list[BatchRecording], list[str]]:
    """The recordings under ``paths`` (in a stable order) and one-line notes on what was
    passed over (missing paths, files of no known kind given explicitly)."""
    notes: list[str] = []
    mcaps: list[Path] = []
    pcaps: list[Path] = []
    sims: list[Path] = []
    seen: set[Path] = set()

    def take(f: Path, explicit: bool) -> None:
        r = f.resolve()
        if r in seen:
            return
        seen.add(r)
        if f.suffix == ".mcap" or (explicit and f.suffix not in _PCAP_SUFFIXES + _IMU_SUFFIXES
                                   and _is_mcap(f)):
            mcaps.append(f)
        elif f.suffix in _PCAP_SUFFIXES:
            pcaps.append(f)
        elif explicit and f.suffix not in _IMU_SUFFIXES:
            notes.append(f"{f}: not a recording (MCAP, pcap or simulate folder); passed over")

    def walk(d: Path) -> None:
        if is_sim_folder(d):
            if d.resolve() not in seen:
                seen.add(d.resolve())
                sims.append(d)
            return
        for child in sorted(d.iterdir()):
            if child.is_dir():
                walk(child)
            elif child.is_file():
                take(child, explicit=False)

    for p in paths:
        if p.is_dir():
            walk(p)
        elif p.is_file():
            take(p, explicit=True)
        else:
            notes.append(f"{p}: no such file or folder; passed over")

    recs: list[BatchRecording] = []
    for group in group_mcap(mcaps):
        recs.append(BatchRecording(group[0].stem, "mcap", group))
    for p in pcaps:
        imu = _imu_beside(p)
        rec = BatchRecording(p.stem, "pcap", [p], imu)
        if imu is None:
            rec.notes.append(f"no IMU log beside {p.name} (looked for "
                             f"{', '.join('*' + s for s in _IMU_SUFFIXES)})")
        recs.append(rec)
    for d in sims:
        recs.append(BatchRecording(d.resolve().name, "sim", [d]))
    _unique_names(recs)
    return recs, notes


def _unique_names(recs: list[BatchRecording]) -> None:
    """Names are output folder names: make them unique (``name``, ``name-2``, ...)."""
    used: set[str] = set()
    for r in recs:
        base = re.sub(r"[^A-Za-z0-9._+-]", "_", r.name) or "recording"
        name, k = base, 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        r.name = name
