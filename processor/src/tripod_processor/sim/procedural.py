# SPDX-License-Identifier: BSD-3-Clause
"""Procedural buildings for training and testing the segmenter, labelled by one convention.

A building is a random floor plan of one layout *family* (:data:`FAMILIES`: ``rooms``,
``corridor``, ``hall``, ``open_plan``, ``L``, ``U``, ``apartment``), cut into rooms that tile its
footprint; walls have a thickness (exterior 0.2-0.5 m, interior 0.08-0.25 m) and openings:
windows (a recess with its reveals, sill, lintel and the window at its back), doors (closed,
open at an angle, or a bare doorway) and wide openings. Then structure (columns, pilasters,
beams, low partitions, stairs and ledges), furniture sets per room type, radiators, things on
the walls and clutter. Every triangle carries a *part* (:data:`PART_NAMES`) and its class comes
from the part through :data:`CONVENTION`, the one label convention that training, evaluation and
the S3DIS 13 -> 4 map (:mod:`tripod_processor.scene.segmentation.s3dis`) share: a surface is
**wall** when it lies in a wall's plane or thickness (wall faces, full-height partitions, the
reveals, sills and lintels of openings, the window or closed door at the back of a recess) and
**other** when it stands in the room (columns, pilasters, beams, low partitions, open door
leaves, stairs and ledges, furniture, radiators, things on the walls).

Deterministic per (family, seed). Seeds are split (:data:`SEED_SPLITS`): train seeds for the
shipped weights, dev seeds looked at while developing, test seeds drawn only to report.
:func:`scan_building` ray-casts a tripod scan (``sim.rooms.scan``: a VLP-16 on its side on a
turning head) from free stations in the building's rooms and returns labelled points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .scenes import CEILING, FLOOR, OTHER, WALL, MeshBuilder

FAMILIES = ("rooms", "corridor", "hall", "open_plan", "L", "U", "apartment")

#: part -> (class, what it is). The label convention, written once; see the module docstring.
CONVENTION: dict[str, tuple[int, str]] = {
    "floor": (FLOOR, "the floor of every room, doorway thresholds included"),
    "ceiling": (CEILING, "the ceiling of every room"),
    "wall": (WALL, "faces of exterior and interior walls and of full-height partitions"),
    "reveal": (WALL, "the sides (jambs) of a window or door opening, in the wall's thickness"),
    "sill": (WALL, "the top of the wall below a window, in the wall's thickness"),
    "lintel": (WALL, "the wall above a door or window opening, its faces and its underside"),
    "window": (WALL, "the back of a window recess: the window in the wall's plane"),
    "door_closed": (WALL, "a closed door leaf in its opening (the back of a door recess)"),
    "door_open": (OTHER, "a door leaf swung out of the wall's plane"),
    "column": (OTHER, "free-standing columns and pillars; pilasters projecting from a wall"),
    "beam": (OTHER, "beams and ducts below the ceiling"),
    "low_partition": (OTHER, "partitions that end below the ceiling (screens, half walls)"),
    "stairs": (OTHER, "steps, stairs, ledges and raised platforms, their tops included"),
    "furniture": (OTHER, "furniture: desks, tables, chairs, cabinets, shelves, beds, sofas"),
    "radiator": (OTHER, "radiators, a few cm off the wall"),
    "wall_item": (OTHER, "boards, pictures, shelves and cabinets hung on walls"),
    "clutter": (OTHER, "small objects on floors and desks, lamps"),
}
PART_NAMES = tuple(CONVENTION)
PART_CLASS = np.array([CONVENTION[p][0] for p in PART_NAMES], np.uint8)

#: seeds per split (family and seed both pick the building): train -> the shipped weights,
#: dev -> looked at while developing, test -> drawn fresh, run only to report (used by the
#: second and third rounds of issue 18), test2 -> fresh for the fourth round, test3 -> fresh
#: for the fifth (the two-stage segmenter), each run once
SEED_SPLITS = {"train": 0, "dev": 500_000, "test": 1_000_000, "test2": 1_100_000,
               "test3": 1_200_000}


def split_seeds(split: str, n: int) -> list[int]:
    """The first ``n`` seeds of a split (:data:`SEED_SPLITS`)."""
    if split not in SEED_SPLITS:
        raise ValueError(f"unknown split {split!r} (choose from {', '.join(SEED_SPLITS)})")
    return [SEED_SPLITS[split] + k for k in range(n)]


@dataclass
class Building:
    """A classified triangle mesh of one generated building.

    vertices : (V, 3) float64 [m], z up, floor at z = 0; triangles : (T, 3) int32
    classes : (T,) uint8 (0 ceiling, 1 floor, 2 wall, 3 other) = ``PART_CLASS[parts]``
    parts : (T,) uint8 index into :data:`PART_NAMES`
    height : ceiling height [m]; rooms : per room, its rectangles (x0, y0, x1, y1) [m]
    room_types : per room, e.g. "office", "corridor"; free : per room, the free floor
    rectangles a tripod may stand in; counts : how many of each element were placed
    """

    family: str
    seed: int
    vertices: np.ndarray
    triangles: np.ndarray
    classes: np.ndarray
    parts: np.ndarray
    height: float
    rooms: list
    room_types: list
    free: list
    counts: dict = field(default_factory=dict)

    def raycasting_scene(self):
        import open3d as o3d

        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(self.vertices.astype(np.float32), self.triangles.astype(np.uint32))
        return rs


class _Builder(MeshBuilder):
    """MeshBuilder whose quads carry a part; the class follows from :data:`CONVENTION`."""

    def __init__(self) -> None:
        super().__init__()
        self._parts: list[int] = []
        self.part = "wall"
        self.counts: dict[str, int] = {}

    def quad(self, p0, p1, p2, p3, cls: int | None = None) -> None:  # noqa: ARG002
        super().quad(p0, p1, p2, p3, CONVENTION[self.part][0])
        self._parts += [PART_NAMES.index(self.part)] * 2

    def pquad(self, part: str, *pts) -> None:
        self.part = part
        self.quad(*pts)

    def pbox(self, part: str, lo, hi) -> None:
        if min(h - l for l, h in zip(lo, hi)) <= 1e-6:
            return
        self.part = part
        self.box(lo, hi, 0)

    def obox(self, part: str, corners_xy, z0: float, z1: float) -> None:
        """A vertical prism over a quadrilateral footprint (4 x-y corners in order)."""
        self.part = part
        c = [np.asarray(q, float) for q in corners_xy]
        for a, b in zip(c, c[1:] + c[:1]):
            self.quad((*a, z0), (*b, z0), (*b, z1), (*a, z1))
        self.quad(*[(*q, z1) for q in c])
        self.quad(*[(*q, z0) for q in c[::-1]])

    def cylinder(self, part: str, cx, cy, r, z0, z1, sides=12, caps=True) -> None:
        self.part = part
        self.prism(cx, cy, r, z0, z1, 0, sides)
        if caps:
            a = np.linspace(0, 2 * np.pi, sides + 1)[:-1]
            ring = [(cx + r * np.cos(t), cy + r * np.sin(t)) for t in a]
            for k in range(1, sides - 1):  # fan as degenerate quads
                for z in (z0, z1):
                    self.quad((*ring[0], z), (*ring[k], z), (*ring[k + 1], z), (*ring[k + 1], z))

    def count(self, what: str, n: int = 1) -> None:
        self.counts[what] = self.counts.get(what, 0) + n

    def build_building(self, family, seed, height, rooms, types, free) -> Building:
        v = np.concatenate(self._v)
        t = np.concatenate(self._t)
        parts = np.asarray(self._parts, np.uint8)
        return Building(family, seed, v, t, PART_CLASS[parts], parts, height, rooms, types, free,
                        dict(self.counts))


# ------------------------------------------------------------------------------ floor plans
def _bsp(rect, n: int, min_side: float, rng) -> list:
    """Split a rectangle into up to ``n`` rooms (guillotine cuts of the largest piece)."""
    out = [tuple(rect)]
    for _ in range(n - 1):
        out.sort(key=lambda r: (r[2] - r[0]) * (r[3] - r[1]))
        x0, y0, x1, y1 = out[-1]
        w, d = x1 - x0, y1 - y0
        along_x = w >= d if abs(w - d) > 0.5 else rng.random() < 0.5
        size = w if along_x else d
        if size < 2 * min_side:
            along_x = not along_x
            size = w if along_x else d
            if size < 2 * min_side:
                break
        f = rng.uniform(max(0.3, min_side / size), min(0.7, 1 - min_side / size))
        out.pop()
        if along_x:
            xm = round(x0 + f * w, 2)
            out += [(x0, y0, xm, y1), (xm, y0, x1, y1)]
        else:
            ym = round(y0 + f * d, 2)
            out += [(x0, y0, x1, ym), (x0, ym, x1, y1)]
    return out


def _plan(family: str, rng):
    """(rooms as lists of rects, room types, height [m], options) of one family."""
    opt: dict = {}
    if family == "rooms":
        w, d = rng.uniform(6, 15), rng.uniform(5, 11)
        h = rng.uniform(2.4, 3.3)
        rs = _bsp((0, 0, w, d), int(rng.integers(2, 6)), 2.2, rng)
        kind = rng.choice(["office", "living", "generic"])
        return [[r] for r in rs], [str(kind)] * len(rs), h, opt
    if family == "corridor":
        length, wc = rng.uniform(12, 30), rng.uniform(1.4, 2.6)
        two_sided = rng.random() < 0.6
        d1, d2 = rng.uniform(3, 6), (rng.uniform(3, 6) if two_sided else 0.0)
        h = rng.uniform(2.4, 3.2)
        rooms, types = [[(0, d2, length, d2 + wc)]], ["corridor"]
        for y0, y1 in ((d2 + wc, d2 + wc + d1), (0, d2)):
            if y1 - y0 < 1:
                continue
            x = 0.0
            while x < length - 0.1:
                wr = rng.uniform(2.6, 5.5)
                x1 = length if length - (x + wr) < 2.4 else x + wr
                rooms.append([(round(x, 2), y0, round(x1, 2), y1)])
                types.append(str(rng.choice(["office", "office", "storage", "meeting"])))
                x = x1
        opt["corridor_room"] = 0
        return rooms, types, h, opt
    if family == "hall":
        w, d = rng.uniform(15, 40), rng.uniform(12, 26)
        h = rng.uniform(4.5, 10)
        rooms, types = [[(0, 0, w, d)]], ["hall"]
        if rng.random() < 0.35:  # small rooms along one side
            ds = rng.uniform(3, 5)
            rooms = [[(0, 0, w, d - ds)]]
            x = 0.0
            while x < w - 0.1:
                wr = rng.uniform(3, 6)
                x1 = w if w - (x + wr) < 3 else x + wr
                rooms.append([(round(x, 2), d - ds, round(x1, 2), d)])
                types.append("storage")
                x = x1
            opt["side_room_height"] = True
        return rooms, types, h, opt
    if family == "open_plan":
        w, d = rng.uniform(14, 30), rng.uniform(10, 20)
        h = rng.uniform(2.7, 3.5)
        rooms, types = [], []
        if rng.random() < 0.7:  # meeting rooms along one long side
            dm = rng.uniform(3, 5)
            main = [(0, 0, w, d - dm)]
            x = 0.0
            while x < w - 0.1:
                wr = rng.uniform(3, 6)
                x1 = w if w - (x + wr) < 3 else x + wr
                if rng.random() < 0.75:
                    rooms.append([(round(x, 2), d - dm, round(x1, 2), d)])
                    types.append("meeting")
                else:  # the open area reaches the wall here
                    main.append((round(x, 2), d - dm, round(x1, 2), d))
                x = x1
            rooms.insert(0, main)
            types.insert(0, "open")
        else:
            rooms, types = [[(0, 0, w, d)]], ["open"]
        return rooms, types, h, opt
    if family in ("L", "U"):
        h = rng.uniform(2.4, 3.4)
        wa, wb = rng.uniform(4, 8), rng.uniform(4, 8)  # arm widths
        la, lb = rng.uniform(9, 18), rng.uniform(8, 16)  # arm lengths
        if family == "L":
            arms = [(0, 0, la, wa), (0, wa, wb, wa + lb)]
        else:
            lc = rng.uniform(8, 16)
            wc = rng.uniform(4, 8)
            arms = [(0, 0, la, wa), (0, wa, wb, wa + lb), (la - wc, wa, la, wa + lc)]
        single = rng.random() < 0.3
        if single:
            return [arms], ["open" if rng.random() < 0.5 else "living"], h, opt
        rooms, types = [], []
        kind = str(rng.choice(["office", "living", "generic"]))
        for arm in arms:
            ln = max(arm[2] - arm[0], arm[3] - arm[1])
            for r in _bsp(arm, int(rng.integers(1, max(2, int(ln // 4)) + 1)), 2.5, rng):
                rooms.append([r])
                types.append(kind)
        return rooms, types, h, opt
    if family == "apartment":
        w, d = rng.uniform(8, 16), rng.uniform(7, 12)
        h = rng.uniform(2.4, 2.9)
        fp = [(0, 0, w, d)]
        if rng.random() < 0.4:  # an L-shaped apartment
            cx, cy = w * rng.uniform(0.45, 0.65), d * rng.uniform(0.45, 0.65)
            fp = [(0, 0, w, cy), (0, cy, cx, d)]
        rs = []
        for r in fp:
            area = (r[2] - r[0]) * (r[3] - r[1])
            rs += _bsp(r, int(np.clip(area // 14, 2, 5)), 2.0, rng)
        rs.sort(key=lambda r: -(r[2] - r[0]) * (r[3] - r[1]))
        names = ["living", "bedroom", "kitchen", "bath", "bedroom", "generic", "storage"]
        types = names[:1] + [str(t) for t in rng.permutation(names[1:])][: len(rs) - 1]
        types += ["generic"] * (len(rs) - len(types))  # an L apartment can have more rooms
        # the smallest room is the bathroom
        if "bath" in types:
            types[types.index("bath")] = types[-1]
            types[-1] = "bath"
        opt["thick_walls"] = True
        return [[r] for r in rs], types, h, opt
    raise ValueError(f"unknown family {family!r} (choose from {', '.join(FAMILIES)})")


@dataclass
class _Run:
    """A straight wall along ``axis`` ("x" or "y") from s0 to s1, occupying [c0, c1] across."""

    axis: str
    s0: float
    s1: float
    c0: float
    c1: float
    rooms: tuple  # (a, b) interior, (a,) exterior
    c_in: float | None = None  # exterior: the inside face
    openings: list = field(default_factory=list)

    @property
    def length(self) -> float:
        return self.s1 - self.s0

    def P(self, s, c, z):
        return (s, c, z) if self.axis == "x" else (c, s, z)


def _wall_runs(rooms, t_int: float, t_ext: float) -> list[_Run]:
    rects = [(r, rid) for rid, rs in enumerate(rooms) for r in rs]
    xs = np.unique([v for r, _ in rects for v in (r[0], r[2])])
    ys = np.unique([v for r, _ in rects for v in (r[1], r[3])])
    cx, cy = 0.5 * (xs[:-1] + xs[1:]), 0.5 * (ys[:-1] + ys[1:])
    grid = np.full((len(cx), len(cy)), -1, int)
    for (x0, y0, x1, y1), rid in rects:
        grid[np.ix_((cx > x0) & (cx < x1), (cy > y0) & (cy < y1))] = rid
    nx, ny = grid.shape
    runs: list[_Run] = []

    def sweep(lines, n_along, get, axis, edges):
        for i, c in enumerate(lines):
            cur, start = None, None
            for j in range(n_along + 1):
                key = None
                if j < n_along:
                    a, b = get(i, j)
                    if a != b and (a >= 0 or b >= 0):
                        key = (a, b)
                if key != cur:
                    if cur is not None:
                        a, b = cur
                        s0, s1 = edges[start], edges[j]
                        if a >= 0 and b >= 0:
                            runs.append(_Run(axis, s0, s1, c - t_int / 2, c + t_int / 2,
                                             (min(a, b), max(a, b))))
                        elif a >= 0:  # inside on the low side: the wall lies beyond c
                            runs.append(_Run(axis, s0, s1, c, c + t_ext, (a,), c_in=c))
                        else:
                            runs.append(_Run(axis, s0, s1, c - t_ext, c, (b,), c_in=c))
                    cur, start = key, j

    def gx(i, j):
        return (grid[i - 1, j] if i > 0 else -1), (grid[i, j] if i < nx else -1)

    def gy(i, j):
        return (grid[j, i - 1] if i > 0 else -1), (grid[j, i] if i < ny else -1)

    sweep(xs, ny, gx, "y", ys)
    sweep(ys, nx, gy, "x", xs)
    return runs


# ------------------------------------------------------------------------------ walls
def _add_openings(runs, rooms, types, h, t_int, rng, opt):
    """Doors between rooms (a spanning tree plus extras), windows and doors in exterior walls."""
    margin = t_int / 2 + 0.2
    n = len(rooms)
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    inner = [r for r in runs if len(r.rooms) == 2 and r.length > 0.9 + 2 * margin]
    order = rng.permutation(len(inner))
    corridor = opt.get("corridor_room")
    if corridor is not None:  # every room opens on the corridor first
        order = sorted(order, key=lambda k: corridor not in inner[k].rooms)
    for k in order:
        r = inner[k]
        a, b = r.rooms
        joined = find(a) == find(b)
        if joined and rng.random() > 0.25:
            continue
        parent[find(a)] = find(b)
        wide = rng.random() < 0.12 and r.length > 2.0 + 2 * margin
        width = rng.uniform(1.2, min(3.0, r.length - 2 * margin)) if wide else rng.uniform(0.8, 1.0)
        width = min(width, r.length - 2 * margin)  # a short wall: a narrower door
        o0 = rng.uniform(r.s0 + margin, r.s1 - margin - width)
        top = h if (wide and rng.random() < 0.4) else min(h - 0.15, rng.uniform(2.0, 2.3) if not wide
                                                          else rng.uniform(2.1, 2.6))
        leaf = None
        if not wide:
            leaf = str(rng.choice(["closed", "open", "open", "none"], p=[0.3, 0.25, 0.25, 0.2]))
        r.openings.append(dict(o0=o0, o1=o0 + width, zb=0.0, zt=top, kind="door", leaf=leaf,
                               hinge=int(rng.integers(2)), side=int(rng.integers(2)),
                               angle=rng.uniform(35, 110)))
    # exterior: windows (recesses: the window sits back in the wall), sometimes a door
    tall = types[0] == "hall" or h > 4.0  # tall windows in tall rooms
    for r in runs:
        if len(r.rooms) != 1 or r.length < 1.2:
            continue
        depth = abs(r.c1 - r.c0)
        if types[r.rooms[0]] in ("bath", "storage") and rng.random() < 0.5:
            continue
        s = r.s0 + 0.3 + rng.uniform(0, 1.0)
        while s < r.s1 - 0.9:
            if rng.random() < 0.25:
                s += rng.uniform(0.5, 2.5)
                continue
            width = rng.uniform(0.6, 2.4)
            if s + width > r.s1 - 0.3:
                break
            if tall:
                zb = rng.uniform(0.8, 3.0)
                zt = min(h - 0.3, zb + rng.uniform(1.2, 4.0))
            elif rng.random() < 0.15:  # French window
                zb, zt = rng.uniform(0.0, 0.1), min(h - 0.2, rng.uniform(2.0, 2.4))
            else:
                zb = rng.uniform(0.4, 1.1)
                zt = min(h - 0.15, rng.uniform(1.9, 2.5))
            back = rng.uniform(0.03, max(0.04, depth - 0.05))  # from the outer face inward
            kind = "window"
            if rng.random() < 0.06:
                kind, zb, zt, width = "door", 0.0, min(h - 0.15, rng.uniform(2.0, 2.3)), min(width, 1.2)
            r.openings.append(dict(o0=s, o1=s + width, zb=zb, zt=zt, kind=kind, back=back))
            s += width + rng.uniform(0.4, 3.0)


def _emit_run(b: _Builder, r: _Run, h: float) -> None:
    P = r.P
    ops = sorted(r.openings, key=lambda o: o["o0"])
    ext = r.c_in is not None
    faces = [r.c_in] if ext else [r.c0, r.c1]
    for c in faces:
        s = r.s0
        for o in ops:
            b.pquad("wall", P(s, c, 0), P(o["o0"], c, 0), P(o["o0"], c, h), P(s, c, h))
            if o["zb"] > 1e-6:
                b.pquad("wall", P(o["o0"], c, 0), P(o["o1"], c, 0), P(o["o1"], c, o["zb"]),
                        P(o["o0"], c, o["zb"]))
            if o["zt"] < h - 1e-6:
                b.pquad("lintel", P(o["o0"], c, o["zt"]), P(o["o1"], c, o["zt"]), P(o["o1"], c, h),
                        P(o["o0"], c, h))
            s = o["o1"]
        b.pquad("wall", P(s, c, 0), P(r.s1, c, 0), P(r.s1, c, h), P(s, c, h))
    for s in (r.s0, r.s1):  # butt ends (free ends of partitions; hidden at junctions)
        b.pquad("wall", P(s, r.c0, 0), P(s, r.c1, 0), P(s, r.c1, h), P(s, r.c0, h))
    for o in ops:
        if ext:  # the recess reaches from the inside face to the window or door at its back
            sgn = 1.0 if r.c1 > r.c_in + 1e-9 and r.c0 == r.c_in else -1.0
            c_out = r.c1 if sgn > 0 else r.c0
            ca, cb = r.c_in, c_out - sgn * o["back"]
        else:
            ca, cb = r.c0, r.c1
        for s in (o["o0"], o["o1"]):
            b.pquad("reveal", P(s, ca, o["zb"]), P(s, cb, o["zb"]), P(s, cb, o["zt"]),
                    P(s, ca, o["zt"]))
        if o["zb"] > 1e-6:
            b.pquad("sill", P(o["o0"], ca, o["zb"]), P(o["o1"], ca, o["zb"]), P(o["o1"], cb, o["zb"]),
                    P(o["o0"], cb, o["zb"]))
        if o["zt"] < h - 1e-6:
            b.pquad("lintel", P(o["o0"], ca, o["zt"]), P(o["o1"], ca, o["zt"]),
                    P(o["o1"], cb, o["zt"]), P(o["o0"], cb, o["zt"]))
        if ext:
            part = "window" if o["kind"] == "window" else "door_closed"
            b.pquad(part, P(o["o0"], cb, o["zb"]), P(o["o1"], cb, o["zb"]), P(o["o1"], cb, o["zt"]),
                    P(o["o0"], cb, o["zt"]))
            b.count("windows" if o["kind"] == "window" else "exterior_doors")
            continue
        b.count("doors_" + str(o["leaf"]) if o["leaf"] else "wide_openings")
        cm = 0.5 * (r.c0 + r.c1)
        if o["leaf"] == "closed":
            lo, hi = P(o["o0"] + 0.01, cm - 0.02, 0.0), P(o["o1"] - 0.01, cm + 0.02, o["zt"] - 0.01)
            b.pbox("door_closed", np.minimum(lo, hi), np.maximum(lo, hi))
        elif o["leaf"] == "open":
            width = o["o1"] - o["o0"] - 0.02
            s_h = o["o0"] + 0.01 if o["hinge"] == 0 else o["o1"] - 0.01
            c_f = r.c0 if o["side"] == 0 else r.c1
            ss = 1.0 if o["hinge"] == 0 else -1.0
            sc = -1.0 if o["side"] == 0 else 1.0
            a = np.deg2rad(o["angle"])
            u = np.array([ss * np.cos(a), sc * np.sin(a)])  # leaf direction in (s, c)
            nrm = np.array([-u[1], u[0]]) * 0.04
            base = np.array([s_h, c_f + sc * 0.005])
            quad_sc = [base, base + width * u, base + width * u + nrm, base + nrm]
            xy = [(q[0], q[1]) if r.axis == "x" else (q[1], q[0]) for q in quad_sc]
            b.obox("door_open", xy, 0.0, o["zt"] - 0.01)


# ------------------------------------------------------------------------------ contents
class _Placer:
    """Places footprints in a room's free rectangles without overlapping what is there."""

    def __init__(self, rng) -> None:
        self.rng = rng
        self.taken: list[tuple] = []  # (x0, y0, x1, y1, max_height)

    def free_at(self, rect, height: float) -> bool:
        x0, y0, x1, y1 = rect
        for a0, b0, a1, b1, mh in self.taken:
            if x0 < a1 and a0 < x1 and y0 < b1 and b0 < y1 and height > mh:
                return False
        return True

    def against_wall(self, area, w: float, d: float, height: float, gap=(0.01, 0.05)):
        """(rect, side) of a w (along the wall) x d footprint against a side of ``area``."""
        x0, y0, x1, y1 = area
        for _ in range(25):
            side = int(self.rng.integers(4))
            g = self.rng.uniform(*gap)
            if side < 2:
                if x1 - x0 < w + 0.11:
                    continue
                x = self.rng.uniform(x0 + 0.05, x1 - w - 0.05)
                y = y0 + g if side == 0 else y1 - g - d
                rect = (x, y, x + w, y + d)
            else:
                if y1 - y0 < w + 0.11:
                    continue
                y = self.rng.uniform(y0 + 0.05, y1 - w - 0.05)
                x = x0 + g if side == 2 else x1 - g - d
                rect = (x, y, x + d, y + w)
            if self.free_at(rect, height) and rect[0] >= x0 and rect[2] <= x1 and rect[1] >= y0 \
                    and rect[3] <= y1:
                return rect, side
        return None

    def inside(self, area, w: float, d: float, height: float, margin: float = 0.5):
        x0, y0, x1, y1 = area
        for _ in range(25):
            if x1 - x0 < w + 2 * margin + 1e-6 or y1 - y0 < d + 2 * margin + 1e-6:
                return None
            x = self.rng.uniform(x0 + margin, x1 - margin - w)
            y = self.rng.uniform(y0 + margin, y1 - margin - d)
            rect = (x, y, x + w, y + d)
            if self.free_at(rect, height):
                return rect
        return None

    def take(self, rect, pad: float = 0.05, max_h: float = 0.0) -> None:
        self.taken.append((rect[0] - pad, rect[1] - pad, rect[2] + pad, rect[3] + pad, max_h))


def _desk(b, x0, y0, x1, y1, rng, top=None):
    top = top if top is not None else rng.uniform(0.70, 0.78)
    b.pbox("furniture", (x0, y0, top - 0.03), (x1, y1, top))
    if rng.random() < 0.5:  # four legs
        for lx, ly in ((x0, y0), (x1 - 0.05, y0), (x0, y1 - 0.05), (x1 - 0.05, y1 - 0.05)):
            b.pbox("furniture", (lx, ly, 0), (lx + 0.05, ly + 0.05, top - 0.03))
    else:  # two side panels
        if x1 - x0 > y1 - y0:
            b.pbox("furniture", (x0, y0, 0), (x0 + 0.03, y1, top - 0.03))
            b.pbox("furniture", (x1 - 0.03, y0, 0), (x1, y1, top - 0.03))
        else:
            b.pbox("furniture", (x0, y0, 0), (x1, y0 + 0.03, top - 0.03))
            b.pbox("furniture", (x0, y1 - 0.03, 0), (x1, y1, top - 0.03))
    if rng.random() < 0.6:  # a screen or a box on it
        w, d = rng.uniform(0.3, 0.6), rng.uniform(0.05, 0.3)
        cx, cy = rng.uniform(x0, x1 - w), rng.uniform(y0, y1 - d)
        b.pbox("clutter", (cx, cy, top), (cx + w, cy + d, top + rng.uniform(0.1, 0.45)))
    return top


def _chair(b, x, y, rng):
    s = rng.uniform(0.4, 0.5)
    seat = rng.uniform(0.42, 0.5)
    b.pbox("furniture", (x, y, seat - 0.05), (x + s, y + s, seat))
    side = int(rng.integers(4))
    back = [(x, y, x + s, y + 0.05), (x, y + s - 0.05, x + s, y + s), (x, y, x + 0.05, y + s),
            (x + s - 0.05, y, x + s, y + s)][side]
    b.pbox("furniture", (back[0], back[1], seat), (back[2], back[3], seat + rng.uniform(0.35, 0.5)))
    b.pbox("furniture", (x + s / 2 - 0.03, y + s / 2 - 0.03, 0), (x + s / 2 + 0.03, y + s / 2 + 0.03,
                                                                   seat - 0.05))


def _against(b, pl, area, part, w, d, height, rng, z0=0.0, gap=(0.01, 0.05)):
    got = pl.against_wall(area, w, d, height, gap)
    if got is None:
        return None
    rect, side = got
    b.pbox(part, (rect[0], rect[1], z0), (rect[2], rect[3], height))
    pl.take(rect)
    return rect, side


def _shelf_unit(b, pl, area, rng, h):
    tall = min(h - 0.05, rng.uniform(1.2, 2.4) if rng.random() < 0.9 else h - 0.02)
    got = pl.against_wall(area, rng.uniform(0.6, 2.0), rng.uniform(0.3, 0.6), tall)
    if got is None:
        return
    (x0, y0, x1, y1), side = got
    pl.take((x0, y0, x1, y1))
    if rng.random() < 0.5:  # closed cabinet
        b.pbox("furniture", (x0, y0, 0), (x1, y1, tall))
        return
    # open shelf: sides, back, boards; things on the boards
    along_x = side < 2
    t = 0.02
    if along_x:
        b.pbox("furniture", (x0, y0, 0), (x0 + t, y1, tall))
        b.pbox("furniture", (x1 - t, y0, 0), (x1, y1, tall))
        yb = (y0, y0 + t) if side == 0 else (y1 - t, y1)
        b.pbox("furniture", (x0, yb[0], 0), (x1, yb[1], tall))
    else:
        b.pbox("furniture", (x0, y0, 0), (x1, y0 + t, tall))
        b.pbox("furniture", (x0, y1 - t, 0), (x1, y1, tall))
        xb = (x0, x0 + t) if side == 2 else (x1 - t, x1)
        b.pbox("furniture", (xb[0], y0, 0), (xb[1], y1, tall))
    for z in np.arange(0.05, tall, rng.uniform(0.3, 0.45)):
        b.pbox("furniture", (x0, y0, z), (x1, y1, z + t))
        if rng.random() < 0.7:
            fx = rng.uniform(0.2, 0.8)
            b.pbox("clutter", (x0 + 0.03, y0 + 0.03, z + t),
                   (x0 + 0.03 + fx * (x1 - x0 - 0.06), y1 - 0.03, z + t + rng.uniform(0.1, 0.3)))


def _furnish(b: _Builder, pl: _Placer, area, kind: str, h: float, rng) -> None:
    """A furniture set for one free rectangle of a room of type ``kind``."""
    ax0, ay0, ax1, ay1 = area
    aw, ad = ax1 - ax0, ay1 - ay0
    scale = aw * ad / 20.0
    if kind in ("office", "generic", "open", "meeting"):
        if kind == "meeting" or (kind == "generic" and rng.random() < 0.3):
            w, d = min(aw - 1.6, rng.uniform(1.6, 4.0)), min(ad - 1.6, rng.uniform(0.9, 1.4))
            if w > 0.8 and d > 0.6:
                rect = pl.inside(area, w, d, 0.8, margin=0.8)
                if rect:
                    _desk(b, *rect, rng)
                    pl.take(rect, pad=0.6)
                    for k in range(int(rng.integers(2, 8))):
                        cx = rng.uniform(rect[0], rect[2] - 0.45)
                        cy = rect[1] - 0.55 if k % 2 else rect[3] + 0.1
                        _chair(b, cx, cy, rng)
        n = int(rng.integers(1, 3 + int(2 * scale)))
        for _ in range(n):
            w, d = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9)
            got = pl.against_wall(area, w, d, 0.8) if rng.random() < 0.6 else None
            rect = got[0] if got else pl.inside(area, w, d, 0.8, margin=0.6)
            if rect is None:
                continue
            _desk(b, *rect, rng)
            pl.take(rect)
            if rng.random() < 0.7:
                _chair(b, rect[0] + rng.uniform(0, max(0.01, rect[2] - rect[0] - 0.5)),
                       rect[1] - 0.5 if rng.random() < 0.5 else rect[3] + 0.05, rng)
        for _ in range(int(rng.integers(0, 3 + int(scale)))):
            _shelf_unit(b, pl, area, rng, h)
    elif kind == "living":
        w, d = rng.uniform(1.6, 2.6), rng.uniform(0.8, 1.0)
        got = pl.against_wall(area, w, d, 0.9)
        if got:  # sofa: seat, back, arms
            (x0, y0, x1, y1), side = got
            pl.take((x0, y0, x1, y1))
            b.pbox("furniture", (x0, y0, 0.0), (x1, y1, 0.45))
            bk = [(x0, y0, x1, y0 + 0.2), (x0, y1 - 0.2, x1, y1), (x0, y0, x0 + 0.2, y1),
                  (x1 - 0.2, y0, x1, y1)][side]
            b.pbox("furniture", (bk[0], bk[1], 0.45), (bk[2], bk[3], 0.9))
        rect = pl.inside(area, rng.uniform(0.6, 1.2), rng.uniform(0.5, 0.8), 0.5)
        if rect:
            b.pbox("furniture", (rect[0], rect[1], 0.38), (rect[2], rect[3], 0.42))
            b.pbox("furniture", (rect[0] + 0.05, rect[1] + 0.05, 0), (rect[2] - 0.05, rect[3] - 0.05,
                                                                      0.38))
            pl.take(rect)
        _against(b, pl, area, "furniture", rng.uniform(1.2, 2.2), rng.uniform(0.35, 0.5),
                 rng.uniform(0.4, 0.7), rng)  # sideboard
        for _ in range(int(rng.integers(1, 3))):
            _shelf_unit(b, pl, area, rng, h)
        rect = pl.inside(area, rng.uniform(0.8, 1.6), rng.uniform(0.8, 1.0), 0.8)
        if rect:
            _desk(b, *rect, rng)
            pl.take(rect)
            for _ in range(int(rng.integers(0, 4))):
                _chair(b, rng.uniform(rect[0] - 0.3, rect[2]), rect[1] - 0.5, rng)
    elif kind == "bedroom":
        w, d = rng.uniform(0.9, 1.8), rng.uniform(1.9, 2.1)
        got = pl.against_wall(area, w, d, 0.9, gap=(0.0, 0.03))
        if got:
            (x0, y0, x1, y1), side = got
            pl.take((x0, y0, x1, y1))
            b.pbox("furniture", (x0, y0, 0.0), (x1, y1, rng.uniform(0.4, 0.55)))
            hb = [(x0, y0, x1, y0 + 0.06), (x0, y1 - 0.06, x1, y1), (x0, y0, x0 + 0.06, y1),
                  (x1 - 0.06, y0, x1, y1)][side]
            b.pbox("furniture", (hb[0], hb[1], 0), (hb[2], hb[3], rng.uniform(0.8, 1.1)))
        tall = h - 0.02 if rng.random() < 0.3 else rng.uniform(1.9, 2.3)
        _against(b, pl, area, "furniture", rng.uniform(1.0, 2.4), rng.uniform(0.55, 0.65),
                 min(tall, h - 0.02), rng)  # wardrobe
        for _ in range(int(rng.integers(0, 3))):
            _against(b, pl, area, "furniture", 0.45, 0.4, rng.uniform(0.45, 0.6), rng)
    elif kind == "kitchen":
        w = min(max(aw, ad) - 0.3, rng.uniform(1.8, 4.0))
        got = _against(b, pl, area, "furniture", w, 0.6, rng.uniform(0.86, 0.92), rng, gap=(0, 0.01))
        if got and rng.random() < 0.8:  # upper cabinets above the counter, on the wall
            (x0, y0, x1, y1), side = got
            dd = 0.35
            r2 = [(x0, y0, x1, y0 + dd), (x0, y1 - dd, x1, y1), (x0, y0, x0 + dd, y1),
                  (x1 - dd, y0, x1, y1)][side]
            b.pbox("wall_item", (r2[0], r2[1], rng.uniform(1.4, 1.55)),
                   (r2[2], r2[3], min(h - 0.05, rng.uniform(2.1, 2.4))))
        _against(b, pl, area, "furniture", 0.65, 0.65, rng.uniform(1.7, 2.0), rng)  # fridge
        rect = pl.inside(area, rng.uniform(0.8, 1.4), rng.uniform(0.7, 0.9), 0.8, margin=0.5)
        if rect:
            _desk(b, *rect, rng)
            pl.take(rect)
            for _ in range(int(rng.integers(1, 4))):
                _chair(b, rng.uniform(rect[0] - 0.2, rect[2] - 0.2), rect[3] + 0.05, rng)
    elif kind == "bath":
        _against(b, pl, area, "furniture", rng.uniform(1.5, 1.8), 0.75, rng.uniform(0.5, 0.6), rng,
                 gap=(0, 0.01))  # tub
        got = _against(b, pl, area, "furniture", rng.uniform(0.5, 0.9), 0.45, 0.85, rng)  # basin
        if got:  # a mirror cabinet above it
            (x0, y0, x1, y1), side = got
            r2 = [(x0, y0, x1, y0 + 0.15), (x0, y1 - 0.15, x1, y1), (x0, y0, x0 + 0.15, y1),
                  (x1 - 0.15, y0, x1, y1)][side]
            b.pbox("wall_item", (r2[0], r2[1], 1.2), (r2[2], r2[3], 1.9))
        _against(b, pl, area, "furniture", 0.4, 0.6, 0.42, rng)  # toilet
    elif kind in ("storage",):
        for _ in range(int(rng.integers(1, 5))):
            _shelf_unit(b, pl, area, rng, h)
    elif kind == "corridor":
        for _ in range(int(rng.integers(0, 3))):
            _against(b, pl, area, "furniture", rng.uniform(0.8, 1.8), rng.uniform(0.3, 0.5),
                     rng.uniform(0.4, 1.9), rng)  # benches, lockers, shelves
    elif kind == "hall":
        for _ in range(int(rng.integers(0, 4 + int(scale / 3)))):
            rect = pl.inside(area, rng.uniform(1.2, 2.4), rng.uniform(0.6, 1.0), 0.8, margin=1.5)
            if rect:
                _desk(b, *rect, rng)
                pl.take(rect, pad=0.5)
                for k in range(int(rng.integers(0, 5))):
                    _chair(b, rect[0] + 0.5 * k, rect[1] - 0.6, rng)
        for _ in range(int(rng.integers(0, 4))):
            _shelf_unit(b, pl, area, rng, min(h, 3.0))
    # clutter: boxes, bins, plants on the floor
    for _ in range(int(rng.integers(0, 4 + int(2 * scale)))):
        s = rng.uniform(0.2, 0.6)
        zt = rng.uniform(0.2, 1.0)
        got = pl.against_wall(area, s, s, zt) if rng.random() < 0.6 else None
        rect = got[0] if got else pl.inside(area, s, s, zt, margin=0.3)
        if rect is None:
            continue
        if rng.random() < 0.4:
            b.cylinder("clutter", 0.5 * (rect[0] + rect[2]), 0.5 * (rect[1] + rect[3]), s / 2, 0, zt,
                       sides=8)
        else:
            b.pbox("clutter", (rect[0], rect[1], 0), (rect[2], rect[3], zt))
        pl.take(rect)


def _wall_things(b: _Builder, pl: _Placer, runs, room_id, area, h, rng, types):
    """Radiators under windows, boards and pictures, hanging lamps for one room area."""
    x0, y0, x1, y1 = area
    for r in runs:
        if room_id not in r.rooms:
            continue
        # the face of this run towards the room
        if r.c_in is not None:
            face = r.c_in
        else:
            a, b_ = r.rooms
            face = r.c1 if room_id == b_ else r.c0
            if a == b_:
                continue
        lo_c, hi_c = (y0, y1) if r.axis == "x" else (x0, x1)
        if abs(face - lo_c) < abs(face - hi_c):
            inward = 1.0
        else:
            inward = -1.0
        s_lo, s_hi = (x0, x1) if r.axis == "x" else (y0, y1)
        s_lo, s_hi = max(s_lo, r.s0 + 0.1), min(s_hi, r.s1 - 0.1)
        if s_hi - s_lo < 0.5:
            continue

        def item(part, sa, sb, za, zb, gap, depth):
            ca, cb = face + inward * gap, face + inward * (gap + depth)
            p, q = r.P(sa, min(ca, cb), za), r.P(sb, max(ca, cb), zb)
            rect = (min(p[0], q[0]), min(p[1], q[1]), max(p[0], q[0]), max(p[1], q[1]))
            if zb > 0.5 and za < 2.0 and not pl.free_at(rect, zb):
                return
            b.pbox(part, (rect[0], rect[1], za), (rect[2], rect[3], zb))
            if za < 1.2:
                pl.take(rect)

        for o in r.openings:
            if o["kind"] == "window" and o["zb"] > 0.5 and rng.random() < 0.6:
                sa, sb = max(s_lo, o["o0"] + 0.05), min(s_hi, o["o1"] - 0.05)
                if sb - sa > 0.3:
                    item("radiator", sa, sb, rng.uniform(0.1, 0.2),
                         min(o["zb"] - 0.05, rng.uniform(0.5, 0.9)), rng.uniform(0.03, 0.07),
                         rng.uniform(0.06, 0.14))
                    b.count("radiators")
        busy = [(o["o0"] - 0.2, o["o1"] + 0.2) for o in r.openings]
        for _ in range(int(rng.integers(0, 3))):
            w = rng.uniform(0.3, 1.8)
            if s_hi - s_lo < w + 0.2:
                continue
            sa = rng.uniform(s_lo, s_hi - w)
            if any(sa < e1 and e0 < sa + w for e0, e1 in busy):
                continue
            busy.append((sa, sa + w))
            kind = rng.random()
            if kind < 0.3:  # a radiator
                item("radiator", sa, sa + w, 0.12, rng.uniform(0.5, 0.9), rng.uniform(0.03, 0.07),
                     rng.uniform(0.06, 0.14))
                b.count("radiators")
            elif kind < 0.75:  # board or picture
                za = rng.uniform(0.8, 1.5)
                item("wall_item", sa, sa + w, za, min(h - 0.2, za + rng.uniform(0.3, 1.2)), 0.0,
                     rng.uniform(0.02, 0.06))
            else:  # a wall shelf or cabinet
                za = rng.uniform(1.2, 1.8)
                item("wall_item", sa, sa + w, za, min(h - 0.1, za + rng.uniform(0.03, 0.8)), 0.0,
                     rng.uniform(0.2, 0.4))
    for _ in range(int(rng.integers(0, 3))):  # hanging lamps
        cx, cy = rng.uniform(x0 + 0.5, max(x0 + 0.51, x1 - 0.5)), rng.uniform(y0 + 0.5,
                                                                             max(y0 + 0.51, y1 - 0.5))
        drop = rng.uniform(0.05, min(1.0, h - 2.2))
        s = rng.uniform(0.15, 0.6)
        b.pbox("clutter", (cx - s, cy - 0.1, h - drop), (cx + s, cy + 0.1, h - drop + 0.08))
        if drop > 0.12:
            b.pbox("clutter", (cx - 0.01, cy - 0.01, h - drop + 0.08), (cx + 0.01, cy + 0.01, h))


def _structure(b: _Builder, pl: _Placer, family, types, free, h, rng,
               generator: int | None = None) -> None:
    """Columns, pilasters, beams, low partitions, stairs and ledges. From generator 4 on, the
    big rooms of the other families (:func:`_hall_like`) also get a hall's share of pilasters and
    of stairs / ledges, and a column grid as often as a hall (generators 2-3: bit-identical)."""
    parts = (GENERATOR if generator is None else int(generator)) >= 4
    for rid, areas in enumerate(free):
        kind = types[rid]
        for area in areas:
            x0, y0, x1, y1 = area
            aw, ad = x1 - x0, y1 - y0
            big = kind in ("hall", "open") or aw * ad > 60
            # generator 4: a big room of another family gets the hall's parts; the extra draws
            # below only happen when it is on, so older versions draw the same stream
            hall_like = parts and kind != "hall" and _hall_like(kind, aw, ad)
            big = big or hall_like
            if big and rng.random() < 0.75:  # a grid of columns
                sp = rng.uniform(4.5, 8.0)
                r = rng.uniform(0.15, 0.4)
                round_ = rng.random() < 0.5
                nx, ny = max(1, int((aw - 3) // sp)), max(1, int((ad - 3) // sp))
                for cx in x0 + aw / 2 + (np.arange(nx) - (nx - 1) / 2) * sp:
                    for cy in y0 + ad / 2 + (np.arange(ny) - (ny - 1) / 2) * sp:
                        if round_:
                            b.cylinder("column", cx, cy, r, 0, h, caps=False)
                        else:
                            b.pbox("column", (cx - r, cy - r, 0), (cx + r, cy + r, h))
                        pl.take((cx - r, cy - r, cx + r, cy + r), pad=0.4)
                        b.count("columns")
            elif rng.random() < (0.35 if family == "apartment" else 0.2) and aw > 3 and ad > 3:
                r = rng.uniform(0.12, 0.3)  # a single pillar
                rect = pl.inside(area, 2 * r, 2 * r, h, margin=1.0)
                if rect:
                    b.pbox("column", (rect[0], rect[1], 0), (rect[2], rect[3], h))
                    pl.take(rect, pad=0.4)
                    b.count("columns")
            if (kind == "hall" and rng.random() < 0.5) or rng.random() < 0.1 or \
                    (hall_like and rng.random() < HALL_PARTS["pilasters"]):  # pilasters
                sp = rng.uniform(3.0, 6.0)
                wp, dp = rng.uniform(0.3, 0.7), rng.uniform(0.12, 0.4)
                for s in np.arange(x0 + sp / 2, x1 - 0.5, sp):
                    for yy, y2 in ((y0, y0 + dp), (y1 - dp, y1)):
                        rect = (s - wp / 2, yy, s + wp / 2, y2)
                        if pl.free_at(rect, h):
                            b.pbox("column", (rect[0], rect[1], 0), (rect[2], rect[3], h))
                            pl.take(rect)
                            b.count("pilasters")
            if h > 2.6 and ((big and rng.random() < 0.5) or rng.random() < 0.15):  # beams
                depth = rng.uniform(0.2, min(0.7, h - 2.3))
                wb = rng.uniform(0.2, 0.45)
                sp = rng.uniform(2.5, 6.0)
                if aw > ad:
                    for s in np.arange(x0 + sp, x1 - 0.5, sp):
                        b.pbox("beam", (s - wb / 2, y0, h - depth), (s + wb / 2, y1, h))
                        b.count("beams")
                else:
                    for s in np.arange(y0 + sp, y1 - 0.5, sp):
                        b.pbox("beam", (x0, s - wb / 2, h - depth), (x1, s + wb / 2, h))
                        b.count("beams")
            if kind in ("open", "living", "hall") and rng.random() < 0.5 and min(aw, ad) > 4:
                for _ in range(int(rng.integers(1, 4))):  # low partitions, screens, half walls
                    ln, t = rng.uniform(1.2, 4.0), rng.uniform(0.04, 0.15)
                    zt = rng.uniform(1.0, min(2.0, h - 0.4))
                    along_x = rng.random() < 0.5
                    rect = pl.inside(area, ln, t, zt, 0.8) if along_x else pl.inside(area, t, ln,
                                                                                      zt, 0.8)
                    if rect:
                        b.pbox("low_partition", (rect[0], rect[1], 0), (rect[2], rect[3], zt))
                        pl.take(rect, pad=0.3)
                        b.count("low_partitions")
            if (kind == "hall" and rng.random() < 0.6) or (big and rng.random() < 0.2) or \
                    rng.random() < 0.06 or (hall_like and rng.random() < HALL_PARTS["stairs"]):
                _stairs(b, pl, area, h, rng)


#: generator 4: the extra chance, per big room of another family (:func:`_hall_like`), of pilasters
#: and of stairs / ledges, drawn after the older versions' own chances (pilasters 0.1, stairs
#: 0.2 + 0.06 for a big room) fail, so that in all a hall-like room gets them about as often as a
#: hall (0.5 and 0.6); column grids: such a room counts as big (0.75, the hall's chance).
HALL_PARTS = {"pilasters": 0.45, "stairs": 0.47}
#: generator 4: a room is hall-like from this floor area [m^2] and narrower side [m] on
HALL_LIKE_AREA_M2, HALL_LIKE_SIDE_M = 40.0, 5.0


def _hall_like(kind: str, w: float, d: float) -> bool:
    """Generator 4: whether a free area of a room of another family than the hall is big enough
    to get a hall's parts (an open plan's open area, a big room, an L / U arm; not a corridor)."""
    return kind != "corridor" and (kind == "open" or (w * d >= HALL_LIKE_AREA_M2
                                                      and min(w, d) >= HALL_LIKE_SIDE_M))


def _stairs(b: _Builder, pl: _Placer, area, h, rng) -> None:
    """A ledge or platform against a wall, reached by steps (all "stairs")."""
    x0, y0, x1, y1 = area
    if y1 - y0 < 4.5 or x1 - x0 < 3.4:
        return
    top = rng.uniform(0.15, min(1.2, h - 2.2))
    dep = rng.uniform(1.5, min(5.0, 0.35 * (y1 - y0)))
    wid = rng.uniform(2.0, min(10.0, 0.6 * (x1 - x0)))
    n = max(1, int(round(top / 0.17)))
    run = 0.28 * n
    got = pl.against_wall(area, wid, dep + run, top + 0.1, gap=(0.0, 0.0))
    if got is None:
        return
    (rx0, ry0, rx1, ry1), side = got
    pl.take((rx0, ry0, rx1, ry1), pad=0.2)
    b.count("stairs")
    # the platform at the wall, the steps in front of it
    for k in range(n + 1):
        zt = top * (n - k + 1) / (n + 1) if k else top
        off = 0 if k == 0 else dep + 0.28 * (k - 1)
        ln = dep if k == 0 else 0.28
        if side == 0:
            lo, hi = (rx0, ry0 + off, 0), (rx1, ry0 + off + ln, zt)
        elif side == 1:
            lo, hi = (rx0, ry1 - off - ln, 0), (rx1, ry1 - off, zt)
        elif side == 2:
            lo, hi = (rx0 + off, ry0, 0), (rx0 + off + ln, ry1, zt)
        else:
            lo, hi = (rx1 - off - ln, ry0, 0), (rx1 - off, ry1, zt)
        b.pbox("stairs", lo, hi)


# ------------------------------------------------------------------------------ building
#: version of the generator: rows and models trained on an older one are told apart by it
#: (1: issue 18's first two rounds; 2: tall buildings in every family, :data:`TALL`; 3, opt-in:
#: their tall range reaches a hall's 10 m — not the default: the weights trained on its rows
#: were worse on 30 dev halls, shipped and held out; 4, opt-in: generator 2's heights, and the big
#: rooms of the other families get a hall's pilasters, stairs / ledges and column grids,
#: :data:`HALL_PARTS`). Set it (``bench/scene.py --generator 4``) to draw another version's
#: buildings (2 and 3: only :data:`TALL_BY_GENERATOR` differs; 2 and 4: only :func:`_structure`).
GENERATOR = 2
#: generator version -> family -> (chance, lowest, highest [m]): some buildings of every family
#: but the hall are tall (lobbies, atria, old buildings, workshops), so that a model never trained
#: on halls has seen small rooms with walls as high as a hall's (4.5-10 m; generator 2 stopped at
#: 8 m, so walls of 8-10 m were a hall's alone). Drawn from a stream of its own: the layout and
#: contents of a building are those of its normal-height draw, and a building that is not tall is
#: the same in every version; a tall one keeps its uniform draw, scaled to the new range.
TALL_BY_GENERATOR = {
    2: {"rooms": (0.3, 4.0, 8.0), "corridor": (0.2, 3.5, 6.0), "open_plan": (0.3, 4.0, 8.0),
        "L": (0.3, 4.0, 8.0), "U": (0.3, 4.0, 8.0), "apartment": (0.25, 3.0, 4.5)},
    3: {"rooms": (0.3, 4.0, 10.0), "corridor": (0.2, 3.5, 6.0), "open_plan": (0.3, 4.0, 10.0),
        "L": (0.3, 4.0, 10.0), "U": (0.3, 4.0, 10.0), "apartment": (0.25, 3.0, 4.5)},
}
TALL_BY_GENERATOR[4] = TALL_BY_GENERATOR[2]  # generator 4 changes the parts, not the heights
#: the current version's table (what :func:`make_building` draws with :data:`GENERATOR` unset)
TALL = TALL_BY_GENERATOR[GENERATOR]


def _tall(family: str, h: float, rng, generator: int | None = None) -> float:
    """The ceiling height [m]: ``h`` or, with the chance of ``generator``'s table
    (:data:`TALL_BY_GENERATOR`, default :data:`GENERATOR`), a tall one."""
    table = TALL_BY_GENERATOR[GENERATOR if generator is None else int(generator)]
    chance, lo, hi = table.get(family, (0.0, h, h))
    return float(rng.uniform(lo, hi)) if rng.random() < chance else h


def make_building(family: str, seed: int, generator: int | None = None) -> Building:
    """A random building of ``family`` (one of :data:`FAMILIES`); same (family, seed,
    generator), same building (``generator``: a version of :data:`TALL_BY_GENERATOR`, default
    :data:`GENERATOR`)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r} (choose from {', '.join(FAMILIES)})")
    rng = np.random.default_rng([int(seed), FAMILIES.index(family), 0xB11D])
    rooms, types, h, opt = _plan(family, rng)
    h = _tall(family, h, np.random.default_rng([int(seed), FAMILIES.index(family), 0x7A11]),
              generator)
    thick = opt.get("thick_walls", False)
    t_ext = rng.uniform(0.3, 0.5) if thick else rng.uniform(0.2, 0.45)
    t_int = rng.uniform(0.08, 0.25)
    runs = _wall_runs(rooms, t_int, t_ext)
    _add_openings(runs, rooms, types, h, t_int, rng, opt)
    b = _Builder()
    # floor and ceiling: one quad each over the footprint's bounds (what lies outside the
    # exterior walls is never seen: the building is closed)
    lo = np.min([r[:2] for rs in rooms for r in rs], 0) - 1.0
    hi = np.max([r[2:] for rs in rooms for r in rs], 0) + 1.0
    b.pquad("floor", (lo[0], lo[1], 0), (hi[0], lo[1], 0), (hi[0], hi[1], 0), (lo[0], hi[1], 0))
    b.pquad("ceiling", (lo[0], lo[1], h), (lo[0], hi[1], h), (hi[0], hi[1], h), (hi[0], lo[1], h))
    for r in runs:
        _emit_run(b, r, h)
    # free floor of each room: its rectangles less half an interior wall on every side
    m = t_int / 2 + 0.02
    free = [[(r[0] + m, r[1] + m, r[2] - m, r[3] - m) for r in rs] for rs in rooms]
    pl = _Placer(rng)
    for run in runs:  # keep doorways clear (1 m either side), furniture low under windows
        for o in run.openings:
            if o["kind"] == "door" or o.get("zb", 0) < 0.3:
                c_lo, c_hi = min(run.c0, run.c1) - 1.1, max(run.c0, run.c1) + 1.1
                mh = 0.0
            else:
                c_lo, c_hi = min(run.c0, run.c1) - 0.6, max(run.c0, run.c1) + 0.6
                mh = o["zb"] - 0.05
            p, q = run.P(o["o0"] - 0.1, c_lo, 0), run.P(o["o1"] + 0.1, c_hi, 0)
            pl.taken.append((min(p[0], q[0]), min(p[1], q[1]), max(p[0], q[0]), max(p[1], q[1]), mh))
    _structure(b, pl, family, types, free, h, rng, generator)
    for rid, areas in enumerate(free):
        for area in areas:
            _wall_things(b, pl, runs, rid, area, h, rng, types)
            _furnish(b, pl, area, types[rid], h, rng)
    b.count("rooms", len(rooms))
    return b.build_building(family, int(seed), h, rooms, types, free)


# ------------------------------------------------------------------------------ scanning
def free_stations(building: Building, n: int, rng, clearance: float = 0.5,
                  rs=None) -> list[np.ndarray]:
    """Up to ``n`` tripod positions (sensor 1.2-1.7 m up) in free floor of different rooms:
    every horizontal ray travels more than ``clearance`` [m] and the floor is straight below."""
    import open3d as o3d

    rs = rs or building.raycasting_scene()
    areas = [(rid, a) for rid, al in enumerate(building.free) for a in al
             if min(a[2] - a[0], a[3] - a[1]) > 2 * clearance + 0.2]
    if not areas:
        return []
    weights = np.array([(a[2] - a[0]) * (a[3] - a[1]) for _, a in areas])
    corridor = [k for k, (rid, _) in enumerate(areas) if building.room_types[rid] == "corridor"]
    out: list[np.ndarray] = []
    used: set = set()
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    for i in range(n):
        for _ in range(200):
            if i == 0 and corridor:
                k = int(rng.choice(corridor))
            else:
                free_k = [k for k in range(len(areas)) if areas[k][0] not in used]
                pool = free_k if free_k else list(range(len(areas)))
                w = weights[pool] / weights[pool].sum()
                k = int(rng.choice(pool, p=w))
            x0, y0, x1, y1 = areas[k][1]
            x = rng.uniform(x0 + clearance, x1 - clearance)
            y = rng.uniform(y0 + clearance, y1 - clearance)
            z = rng.uniform(1.2, 1.7)
            rays = np.zeros((len(ang) + 1, 6), np.float32)
            rays[:, :3] = (x, y, z)
            rays[:-1, 3], rays[:-1, 4] = np.cos(ang), np.sin(ang)
            rays[-1, 5] = -1
            t = rs.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            if np.all(np.isfinite(t)) and t[:-1].min() > clearance and abs(t[-1] - z) < 1e-3:
                out.append(np.array([x, y, z]))
                used.add(areas[k][0])
                break
    return out


def scan_building(building: Building, rng, n_stations: int | None = None,
                  head_steps: int | None = None, noise_m: float | None = None,
                  return_parts: bool = False):
    """Labelled points of a tripod scan of ``building`` from 1-3 free stations (merged, as a
    registered map would be), each a VLP-16 on its side on a turning head (``sim.rooms.scan``).

    Returns (points (N, 3) float32 [m], labels (N,) int32) [, parts (N,) uint8].
    """
    from .rooms import scan

    n_stations = int(rng.integers(1, 4)) if n_stations is None else n_stations
    rs = building.raycasting_scene()
    stations = free_stations(building, n_stations, rng, rs=rs)
    if not stations:
        raise RuntimeError(f"{building.family} {building.seed}: no free station")

    class _Parts:  # the scan reads labels from .classes: give it the parts instead
        def __init__(self, b):
            self.classes = b.parts

        def raycasting_scene(self):
            return rs

    P, L = [], []
    src = _Parts(building) if return_parts else building
    for k, st in enumerate(stations):
        hs = int(rng.integers(8, 15)) if head_steps is None else head_steps
        nm = float(rng.uniform(0.005, 0.03)) if noise_m is None else noise_m
        p, lab = scan(src, st, head_steps=hs, noise_m=nm, seed=int(rng.integers(1 << 31)))
        P.append(p)
        L.append(lab)
    p, lab = np.concatenate(P), np.concatenate(L)
    if return_parts:
        return p, PART_CLASS[lab].astype(np.int32), lab.astype(np.uint8)
    return p, lab


def labelled_scan(family: str, seed: int, **kw):
    """(points, labels) of one scan of one building: :func:`make_building` then
    :func:`scan_building` with the scan drawn from the same seed."""
    b = make_building(family, seed)
    rng = np.random.default_rng([int(seed), FAMILIES.index(family), 0x5CA4])
    return scan_building(b, rng, **kw)
