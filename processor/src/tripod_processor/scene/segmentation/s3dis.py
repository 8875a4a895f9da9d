# SPDX-License-Identifier: BSD-3-Clause
"""Stanford 2D-3D-Semantics (S3DIS) for users who have it: loader, 13 -> 4 class map, and the
standard Area-5 and 6-fold evaluations (per-class IoU from a confusion matrix summed over rooms
and folds).

Layout: ``ROOT/Area_N/<room>/Annotations/<class>_<k>.txt``, lines ``x y z r g b``.
The loader survives the dataset's known defects and reports what it did (``Room.issues``):

* stray non-numeric bytes inside a line (Area_5/hallway_6/Annotations/ceiling_1.txt, line
  180389): the byte is dropped; a line that still does not read as 6 numbers is skipped;
* duplicated files such as ``wall_3 (1).txt`` next to ``wall_3.txt`` (Area_5/office_36): the
  copy is skipped (its points would be counted twice);
* unknown class names (``stairs`` in some rooms) map to "other", empty files are skipped.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .metrics import confusion

S3DIS_CLASSES = ("ceiling", "floor", "wall", "beam", "column", "window", "door", "chair", "table",
                 "bookcase", "sofa", "board", "clutter")
#: S3DIS class id -> tripod class (0 ceiling, 1 floor, 2 wall, 3 other), by the one label
#: convention of ``tripod_processor.sim.procedural.CONVENTION`` (README, "Label convention"):
#: what lies in a wall's plane or thickness is wall, so windows and doors (frames, panes, leaves in
#: their openings) are wall; beams, columns, boards, furniture, clutter (and unknown classes such
#: as stairs) stand in the room or on the wall and are other. Until issue 18, windows and doors
#: mapped to other. An open door leaf is the one S3DIS "door" that the convention calls other;
#: S3DIS does not tell open leaves from closed ones, so they count as wall here.
S3DIS_TO_TRIPOD = np.array([0, 1, 2, 3, 3, 2, 2, 3, 3, 3, 3, 3, 3], np.int32)
UNKNOWN_CLASS = 12  # clutter
AREAS = (1, 2, 3, 4, 5, 6)

_FILE_RE = re.compile(r"^(?P<cls>[A-Za-z]+)_(?P<k>\d+)(?P<copy>\s*\(\d+\))?\.txt$")
_BAD_BYTES = re.compile(rb"[^0-9eE+\-. \t\r\n]")


class S3DISError(ValueError):
    """The S3DIS root is missing or not in the documented layout (one-line message)."""


@dataclass
class Room:
    """One S3DIS room: points (N, 3) float32 [m], rgb (N, 3) uint8, labels13 (N,) int32 in
    [0, 13), labels4 (N,) int32 (tripod classes), issues: what the loader repaired or skipped."""

    area: int
    name: str
    points: np.ndarray
    rgb: np.ndarray
    labels13: np.ndarray
    labels4: np.ndarray
    issues: list = field(default_factory=list)


def parse_annotation(data: bytes, source: str = "") -> tuple[np.ndarray, list[str]]:
    """(N, 6) float64 of an annotation file's bytes; returns (array, issues)."""
    issues: list[str] = []
    if _BAD_BYTES.search(data):
        n_bad = len(_BAD_BYTES.findall(data))
        first = data[: _BAD_BYTES.search(data).start()].count(b"\n") + 1
        issues.append(f"{source}: dropped {n_bad} stray byte(s), first on line {first}")
        data = _BAD_BYTES.sub(b"", data)
    tokens = data.split()
    if len(tokens) % 6 == 0:
        try:
            return np.array(tokens, dtype=np.float64).reshape(-1, 6), issues
        except ValueError:
            pass
    # slow path: line by line, skipping lines that are not 6 numbers
    rows, skipped = [], 0
    for line in data.splitlines():
        parts = line.split()
        if not parts:
            continue
        try:
            vals = [float(x) for x in parts]
        except ValueError:
            skipped += 1
            continue
        if len(vals) != 6:
            skipped += 1
            continue
        rows.append(vals)
    if skipped:
        issues.append(f"{source}: skipped {skipped} malformed line(s)")
    return (np.array(rows, np.float64).reshape(-1, 6)), issues


def load_room(room_dir: Path, area: int) -> Room:
    """Read one room from its ``Annotations`` folder."""
    ann = Path(room_dir) / "Annotations"
    if not ann.is_dir():
        raise S3DISError(f"{room_dir}: no Annotations folder")
    files = sorted(p for p in ann.iterdir() if p.is_file() and p.suffix == ".txt")
    names = {p.name for p in files}
    P, C, L13 = [], [], []
    issues: list[str] = []
    for f in files:
        m = _FILE_RE.match(f.name)
        if not m:
            issues.append(f"{f.name}: not <class>_<k>.txt, skipped")
            continue
        if m.group("copy"):
            base = f"{m.group('cls')}_{m.group('k')}.txt"
            if base in names:
                issues.append(f"{f.name}: duplicate of {base}, skipped")
                continue
        cls = m.group("cls").lower()
        cid = S3DIS_CLASSES.index(cls) if cls in S3DIS_CLASSES else UNKNOWN_CLASS
        if cls not in S3DIS_CLASSES:
            issues.append(f"{f.name}: unknown class {cls!r} -> clutter")
        arr, iss = parse_annotation(f.read_bytes(), f"{room_dir.name}/{f.name}")
        issues += iss
        if len(arr) == 0:
            issues.append(f"{f.name}: no points, skipped")
            continue
        P.append(arr[:, :3].astype(np.float32))
        C.append(np.clip(arr[:, 3:6], 0, 255).astype(np.uint8))
        L13.append(np.full(len(arr), cid, np.int32))
    if not P:
        raise S3DISError(f"{room_dir}: no readable annotation files")
    labels13 = np.concatenate(L13)
    return Room(area, Path(room_dir).name, np.concatenate(P), np.concatenate(C), labels13,
                S3DIS_TO_TRIPOD[labels13], issues)


def room_dirs(root, areas: Iterable[int] = AREAS) -> list[tuple[int, Path]]:
    """(area, room folder) of every room of the given areas, sorted."""
    root = Path(root)
    if not root.is_dir():
        raise S3DISError(f"S3DIS root not found: {root}")
    out = []
    for a in areas:
        ad = root / f"Area_{a}"
        if not ad.is_dir():
            raise S3DISError(f"{root}: no folder Area_{a}")
        out += [(a, d) for d in sorted(ad.iterdir()) if (d / "Annotations").is_dir()]
    return out


def iter_rooms(root, areas: Iterable[int] = AREAS) -> Iterator[Room]:
    for a, d in room_dirs(root, areas):
        yield load_room(d, a)


def area5_split() -> list[tuple[tuple[int, ...], int]]:
    """The standard split: train on areas 1-4 and 6, test on area 5."""
    return [((1, 2, 3, 4, 6), 5)]


def six_fold_splits() -> list[tuple[tuple[int, ...], int]]:
    """6-fold cross-validation: each area tested once, trained on the other five."""
    return [(tuple(a for a in AREAS if a != t), t) for t in AREAS]


def evaluate(root, splits, train_fn: Callable[[list[Room]], object],
             predict_fn: Callable[[object, np.ndarray], np.ndarray]) -> tuple[np.ndarray, list]:
    """Summed 4-class confusion matrix over the test rooms of every split.

    train_fn(rooms) -> model; predict_fn(model, points) -> (N,) labels in [0, 4).
    Returns (confusion (4, 4), per-split confusions).
    """
    total = np.zeros((4, 4), np.int64)
    per = []
    for train_areas, test_area in splits:
        model = train_fn(list(iter_rooms(root, train_areas)))
        c = np.zeros((4, 4), np.int64)
        for room in iter_rooms(root, [test_area]):
            c += confusion(room.labels4, predict_fn(model, room.points))
        per.append(c)
        total += c
    return total, per
