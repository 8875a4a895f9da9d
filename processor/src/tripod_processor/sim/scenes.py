# SPDX-License-Identifier: BSD-3-Clause
"""Indoor scenes for the simulator: triangle meshes whose every triangle carries a class.

A scene is a closed triangle mesh (so nearly every ray hits something) plus a *route*: a 2D
polyline through the free space along which the operator carries the tripod. Stations are
placed on the route, and transits follow it, so the tripod never passes through a wall.

Classes (``CLASS_NAMES`` order is the class id): 0 ceiling, 1 floor, 2 wall, 3 other.
Pillars and columns are "other" (they are not room boundaries); door lintels and partition
walls are "wall". Id 255 (``NO_RETURN``) marks a firing without a return in label files.

Every parametric scene draws its dimensions from a ``numpy.random.Generator`` so that one seed
gives one scene. ``load_scene_file`` reads any mesh (PLY with a per-face ``class`` property
as written by :func:`write_mesh_ply`, or any format Open3D reads, classified by face normal).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field

import numpy as np

CEILING, FLOOR, WALL, OTHER = 0, 1, 2, 3
CLASS_NAMES = ("ceiling", "floor", "wall", "other")
NO_RETURN = 255

#: Typical diffuse reflectivity of each class on the VLP-16's calibrated 0..100 scale.
CLASS_REFLECTIVITY = {CEILING: 70, FLOOR: 25, WALL: 55, OTHER: 40}

SCENE_NAMES = ("room", "corridor", "two_rooms", "office", "hall")


@dataclass
class Scene:
    """A classified triangle mesh and the route the tripod is carried along.

    Attributes
    ----------
    vertices : (V, 3) float64 [m], world frame (z up, floor at z = 0 for parametric scenes)
    triangles : (T, 3) int32 vertex indices, counter-clockwise seen from the free space
    classes : (T,) uint8 class id per triangle (see ``CLASS_NAMES``)
    reflectivity : (T,) uint8 diffuse reflectivity per triangle, 1..100
    route : (K, 2) float64 [m] polyline through free space (x, y)
    closed_route : whether the route is a loop
    params : the dimensions drawn for this scene (written to meta.json)
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    classes: np.ndarray
    reflectivity: np.ndarray
    route: np.ndarray
    closed_route: bool = False
    params: dict = field(default_factory=dict)

    @property
    def floor_z(self) -> float:
        """Height of the floor [m]: the lowest floor triangle (else the lowest vertex)."""
        f = self.classes == FLOOR
        z = self.vertices[self.triangles[f]][..., 2] if f.any() else self.vertices[:, 2]
        return float(z.min())

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def class_counts(self) -> dict[str, int]:
        return {n: int((self.classes == i).sum()) for i, n in enumerate(CLASS_NAMES)}


class MeshBuilder:
    """Accumulates classified quads and boxes into one triangle mesh."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._t: list[np.ndarray] = []
        self._c: list[int] = []
        self._n = 0

    def quad(self, p0, p1, p2, p3, cls: int) -> None:
        """Quad p0 p1 p2 p3, counter-clockwise seen from the side its normal points to."""
        self._v.append(np.array([p0, p1, p2, p3], dtype=np.float64))
        n = self._n
        self._t.append(np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]], dtype=np.int32))
        self._c += [cls, cls]
        self._n += 4

    def box(self, lo, hi, cls: int, side_cls: int | None = None) -> None:
        """Closed axis-aligned box seen from outside (an obstacle). ``side_cls`` for its sides."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        s = cls if side_cls is None else side_cls
        self.quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1), cls)  # top, +z
        self.quad((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0), cls)  # bottom, -z
        self.quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1), s)  # -y
        self.quad((x1, y1, z0), (x0, y1, z0), (x0, y1, z1), (x1, y1, z1), s)  # +y
        self.quad((x0, y1, z0), (x0, y0, z0), (x0, y0, z1), (x0, y1, z1), s)  # -x
        self.quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1), s)  # +x

    def prism(self, cx: float, cy: float, radius: float, z0: float, z1: float, cls: int,
              sides: int = 12) -> None:
        """Vertical regular prism (a round column), seen from outside; no caps (floor/ceiling)."""
        a = np.linspace(0.0, 2 * np.pi, sides + 1)
        for i in range(sides):
            xa, ya = cx + radius * np.cos(a[i]), cy + radius * np.sin(a[i])
            xb, yb = cx + radius * np.cos(a[i + 1]), cy + radius * np.sin(a[i + 1])
            self.quad((xa, ya, z0), (xb, yb, z0), (xb, yb, z1), (xa, ya, z1), cls)

    def floor_plan(self, rects: list[tuple[float, float, float, float]], height: float) -> None:
        """Floor, ceiling and boundary walls of the union of axis-aligned rectangles.

        The union is cut on the grid of all rectangle edges; each inside cell gets a floor and a
        ceiling quad, and each cell side facing outside gets a wall quad facing inward.
        """
        xs = np.unique([v for r in rects for v in (r[0], r[2])])
        ys = np.unique([v for r in rects for v in (r[1], r[3])])
        cx = 0.5 * (xs[:-1] + xs[1:])
        cy = 0.5 * (ys[:-1] + ys[1:])
        inside = np.zeros((len(cx), len(cy)), dtype=bool)
        for x0, y0, x1, y1 in rects:
            inside |= ((cx > x0) & (cx < x1))[:, None] & ((cy > y0) & (cy < y1))[None, :]
        h = height
        nx, ny = inside.shape

        def inn(i: int, j: int) -> bool:
            return 0 <= i < nx and 0 <= j < ny and bool(inside[i, j])

        for i in range(nx):
            for j in range(ny):
                if not inside[i, j]:
                    continue
                x0, x1, y0, y1 = xs[i], xs[i + 1], ys[j], ys[j + 1]
                self.quad((x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0), FLOOR)
                self.quad((x0, y0, h), (x0, y1, h), (x1, y1, h), (x1, y0, h), CEILING)
                if not inn(i - 1, j):  # wall at x0 facing +x
                    self.quad((x0, y0, 0), (x0, y1, 0), (x0, y1, h), (x0, y0, h), WALL)
                if not inn(i + 1, j):  # wall at x1 facing -x
                    self.quad((x1, y1, 0), (x1, y0, 0), (x1, y0, h), (x1, y1, h), WALL)
                if not inn(i, j - 1):  # wall at y0 facing +y
                    self.quad((x1, y0, 0), (x0, y0, 0), (x0, y0, h), (x1, y0, h), WALL)
                if not inn(i, j + 1):  # wall at y1 facing -y
                    self.quad((x0, y1, 0), (x1, y1, 0), (x1, y1, h), (x0, y1, h), WALL)

    def partition_x(self, x: float, y0: float, y1: float, height: float, doors, thickness=0.12,
                    door_height=2.05) -> None:
        """A wall across the plan at ``x`` from ``y0`` to ``y1`` with door openings.

        ``doors``: list of (ya, yb) openings; a lintel (wall) spans each opening above the door.
        """
        t = thickness / 2
        edges = [y0]
        for ya, yb in sorted(doors):
            edges += [ya, yb]
        edges.append(y1)
        for a, b in zip(edges[0::2], edges[1::2]):
            if b - a > 1e-6:
                self.box((x - t, a, 0), (x + t, b, height), WALL)
        for ya, yb in doors:
            self.box((x - t, ya, door_height), (x + t, yb, height), WALL)

    def build(self, name: str, route, closed_route: bool, params: dict,
              rng: np.random.Generator) -> Scene:
        v = np.concatenate(self._v)
        t = np.concatenate(self._t)
        c = np.asarray(self._c, dtype=np.uint8)
        return Scene(name, v, t, c, surface_reflectivity(c, rng),
                     np.asarray(route, dtype=np.float64), closed_route, params)


def surface_reflectivity(classes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Per-triangle reflectivity: the class's typical value, varied per quad (triangle pair)."""
    base = np.array([CLASS_REFLECTIVITY[i] for i in range(len(CLASS_NAMES))], dtype=np.float64)
    b = base[np.minimum(classes, len(CLASS_NAMES) - 1)]
    var = rng.uniform(-12, 12, size=(len(classes) + 1) // 2).repeat(2)[: len(classes)]
    return np.clip(np.round(b + var), 1, 100).astype(np.uint8)


# --------------------------------------------------------------------------- parametric scenes


def _sized(size: dict, name: str, drawn: float, lo: float | None = None) -> float:
    """A drawn dimension, or the configured one (``scene_size``) when given; ``lo``: the
    smallest the scene's furniture and route allow [m]."""
    v = size.get(name)
    if v is None:
        return drawn
    if lo is not None and v < lo:
        raise ValueError(f"scene_size.{name} = {v:g} m is too small for this scene "
                         f"(at least {lo:g} m)")
    return float(v)


def _room(rng: np.random.Generator, size: dict) -> tuple[MeshBuilder, list, bool, dict]:
    w, d, h = rng.uniform(5.0, 9.0), rng.uniform(4.0, 7.0), rng.uniform(2.5, 3.2)
    w, d, h = _sized(size, "width_m", w, 3.2), _sized(size, "depth_m", d, 3.2), \
        _sized(size, "height_m", h)
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, w, d)], h)
    # furniture against the walls: a cabinet, a table, a shelf (class other)
    cab_w = rng.uniform(0.8, 1.6)
    cx = rng.uniform(0.3, w - cab_w - 0.3)
    mb.box((cx, d - 0.45, 0), (cx + cab_w, d - 0.02, rng.uniform(0.9, 2.0)), OTHER)
    tx = rng.uniform(0.2, w - 1.8)
    mb.box((tx, 0.05, 0.70), (tx + 1.6, 0.85, 0.74), OTHER)  # table top
    for lx, ly in ((tx + 0.05, 0.1), (tx + 1.5, 0.1), (tx + 0.05, 0.75), (tx + 1.5, 0.75)):
        mb.box((lx, ly, 0), (lx + 0.05, ly + 0.05, 0.70), OTHER)
    sy = rng.uniform(0.3, d - 1.5)
    mb.box((0.02, sy, 0), (0.40, sy + 1.2, rng.uniform(1.2, 2.2)), OTHER)
    m = 1.4  # route clearance from the walls
    route = [(m, m), (w - m, m), (w - m, d - m), (m, d - m)]
    return mb, route, True, {"width_m": w, "depth_m": d, "height_m": h}


def _corridor(rng: np.random.Generator, size: dict):
    l1, l2 = rng.uniform(10.0, 16.0), rng.uniform(8.0, 12.0)
    wd, h = rng.uniform(1.6, 2.4), rng.uniform(2.4, 3.0)
    l1, wd, h = _sized(size, "length_m", l1, 6.0), _sized(size, "width_m", wd, 1.4), \
        _sized(size, "height_m", h)
    l2 = _sized(size, "leg2_m", l2)
    if 0.0 < l2 < wd + 4.0:
        raise ValueError(f"scene_size.leg2_m = {l2:g} m: 0 (a straight corridor) or at least "
                         f"{wd + 4.0:.1f} m")
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, l1, wd), (l1 - wd, 0, l1, l2)] if l2 > 0 else [(0, 0, l1, wd)], h)
    # a radiator and a bench along the walls
    rx = rng.uniform(1.0, l1 - 4.0)
    mb.box((rx, 0.02, 0.15), (rx + 1.0, 0.12, 0.75), OTHER)
    c = wd / 2
    if l2 > 0:
        by = rng.uniform(2.5, l2 - 2.0)
        mb.box((l1 - 0.45, by, 0.0), (l1 - 0.02, by + 1.2, 0.45), OTHER)
        route = [(1.0, c), (l1 - c, c), (l1 - c, l2 - 1.0)]
    else:  # straight: the bench on the other long wall, the route along the axis
        bx = rng.uniform(1.0, l1 - 2.2)
        mb.box((bx, wd - 0.45, 0.0), (bx + 1.2, wd - 0.02, 0.45), OTHER)
        route = [(1.0, c), (l1 - 1.0, c)]
    return mb, route, False, {"leg1_m": l1, "leg2_m": l2, "width_m": wd, "height_m": h}


def _two_rooms(rng: np.random.Generator, size: dict):
    a, b = rng.uniform(4.5, 7.0), rng.uniform(4.5, 7.0)
    d, h = rng.uniform(4.0, 6.5), rng.uniform(2.5, 3.0)
    door_w = 0.9
    door_y = rng.uniform(1.0, d - 1.0 - door_w)
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, a + b, d)], h)
    mb.partition_x(a, 0, d, h, [(door_y, door_y + door_w)])
    mb.box((0.3, d - 0.5, 0), (1.5, d - 0.05, 1.8), OTHER)  # shelf in room A
    mb.box((a + b - 1.7, 0.1, 0.72), (a + b - 0.2, 0.9, 0.76), OTHER)  # desk in room B
    mb.box((a + b - 1.65, 0.15, 0), (a + b - 0.25, 0.85, 0.72), OTHER)
    yc = door_y + door_w / 2
    route = [(1.3, 1.3), (a - 1.2, d / 2), (a - 0.6, yc), (a + 0.6, yc), (a + 1.2, d / 2),
             (a + b - 1.3, d - 1.3)]
    return mb, route, False, {"room_a_m": a, "room_b_m": b, "depth_m": d, "height_m": h,
                              "door_y_m": door_y, "door_width_m": door_w}


def _office(rng: np.random.Generator, size: dict):
    w, d, h = rng.uniform(14.0, 20.0), rng.uniform(10.0, 14.0), rng.uniform(2.7, 3.1)
    w, d, h = _sized(size, "width_m", w, 8.0), _sized(size, "depth_m", d, 8.0), \
        _sized(size, "height_m", h, 2.4)
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, w, d)], h)
    # aisles at y = d/4 and 3d/4 (route); desk islands between them and the walls
    ya, yb = d / 4, 3 * d / 4
    # pillars on a 6 m grid, kept off the aisles
    for px in np.arange(4.0, w - 2.0, 6.0):
        for py in (d / 2,):
            mb.box((px - 0.25, py - 0.25, 0), (px + 0.25, py + 0.25, h), OTHER)
    desk_rows = [(0.4, ya - 1.0), (ya + 1.0, d / 2 - 0.6), (d / 2 + 0.6, yb - 1.0),
                 (yb + 1.0, d - 0.4)]
    for y0, y1 in desk_rows:
        if y1 - y0 < 0.7:
            continue
        x = 2.2  # the route's cross aisles run at x = 1.2 and w - 1.2
        while x + 1.6 < w - 2.2:
            if rng.random() < 0.8:
                mb.box((x, y0, 0.72), (x + 1.6, min(y0 + 0.8, y1), 0.75), OTHER)
                mb.box((x + 0.05, y0 + 0.05, 0), (x + 0.10, y0 + 0.10, 0.72), OTHER)
                mb.box((x + 1.5, y0 + 0.05, 0), (x + 1.55, y0 + 0.10, 0.72), OTHER)
                if rng.random() < 0.5:  # a screen
                    mb.box((x + 0.5, y0 + 0.1, 0.75), (x + 1.1, y0 + 0.14, 1.15), OTHER)
            x += 1.9
    route = [(1.2, ya), (w - 1.2, ya), (w - 1.2, yb), (1.2, yb)]
    return mb, route, True, {"width_m": w, "depth_m": d, "height_m": h}


def _centered_grid(length: float, margin: float, spacing: float) -> np.ndarray:
    """Positions ``spacing`` apart, centred in [margin, length - margin] (at least one)."""
    n = max(1, int((length - 2 * margin) // spacing) + 1)
    return length / 2 + (np.arange(n) - (n - 1) / 2) * spacing


def _hall(rng: np.random.Generator, size: dict):
    w, d, h = rng.uniform(25.0, 40.0), rng.uniform(15.0, 25.0), rng.uniform(6.0, 10.0)
    w, d, h = _sized(size, "width_m", w, 8.0), _sized(size, "depth_m", d, 8.0), \
        _sized(size, "height_m", h, 2.4)
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, w, d)], h)
    sp = rng.uniform(6.0, 8.0)
    m = 3.0  # the route: a loop 3 m from the walls; columns fill the space inside it
    for x in _centered_grid(w, m + 2.0, sp):
        for y in _centered_grid(d, m + 2.0, sp):
            mb.prism(x, y, 0.3, 0.0, h, OTHER)
    route = [(m, m), (w - m, m), (w - m, d - m), (m, d - m)]
    return mb, route, True, {"width_m": w, "depth_m": d, "height_m": h, "column_spacing_m": sp}


_BUILDERS = {"room": _room, "corridor": _corridor, "two_rooms": _two_rooms, "office": _office,
             "hall": _hall}


#: the ``scene_size`` fields each parametric scene takes
SIZE_FIELDS = {"room": ("width_m", "depth_m", "height_m"),
               "corridor": ("length_m", "leg2_m", "width_m", "height_m"),
               "two_rooms": (), "office": ("width_m", "depth_m", "height_m"),
               "hall": ("width_m", "depth_m", "height_m")}


def make_scene(name: str, seed: int, size: dict | None = None) -> Scene:
    """Parametric scene ``name`` (one of ``SCENE_NAMES``), dimensions drawn from ``seed``;
    ``size`` (``SceneSizeConfig`` fields) fixes some of them (None values: drawn)."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown scene {name!r} (choose from {', '.join(SCENE_NAMES)})")
    size = {k: v for k, v in (size or {}).items() if v is not None}
    bad = sorted(set(size) - set(SIZE_FIELDS[name]))
    if bad:
        raise ValueError(f"scene {name!r} has no size {', '.join(bad)} (it takes: "
                         f"{', '.join(SIZE_FIELDS[name]) or 'none'})")
    rng = np.random.default_rng([seed, 0x5CE7E])
    mb, route, closed, params = _BUILDERS[name](rng, size)
    return mb.build(name, route, closed, {k: round(float(v), 4) for k, v in params.items()}, rng)


def check_route(scene: Scene, route_xy: np.ndarray, closed: bool, clearance_m: float = 0.25,
                heights_m: tuple[float, ...] = (0.5, 1.0, 1.5, 1.7)) -> None:
    """Raise ValueError (one line) unless the route keeps ``clearance_m`` from the mesh at the
    tripod's heights above the floor and lies inside the scene (a ceiling above it)."""
    import open3d as o3d

    pts = np.asarray(route_xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError("a route needs at least two (x, y) points")
    seq = np.vstack([pts, pts[:1]]) if closed else pts
    samples = [seq[i] + (seq[i + 1] - seq[i]) * f for i in range(len(seq) - 1)
               for f in np.linspace(0, 1, max(2, int(np.linalg.norm(seq[i + 1] - seq[i]) / 0.2)),
                                    endpoint=False)]
    xy = np.asarray(samples)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    z0 = scene.floor_z
    for h in heights_m:
        q = np.c_[xy, np.full(len(xy), z0 + h)].astype(np.float32)
        d = rc.compute_distance(o3d.core.Tensor(q)).numpy()
        bad = np.argmin(d)
        if d[bad] < clearance_m:
            raise ValueError(
                f"the route passes {d[bad]:.2f} m from the mesh at ({xy[bad, 0]:.2f}, "
                f"{xy[bad, 1]:.2f}), {h} m above the floor: give a free route with route_xy")
    up = np.c_[xy, np.full(len(xy), z0 + 1.0), np.zeros((len(xy), 2)), np.ones(len(xy))]
    t = rc.cast_rays(o3d.core.Tensor(up.astype(np.float32)))["t_hit"].numpy()
    if not np.isfinite(t).all():
        i = int(np.argmin(np.isfinite(t)))
        raise ValueError(f"the route leaves the scene at ({xy[i, 0]:.2f}, {xy[i, 1]:.2f}) "
                         "(no ceiling above): give a route inside it with route_xy")


# --------------------------------------------------------------------------- mesh files


def write_mesh_ply(path: str | os.PathLike, scene: Scene) -> None:
    """Binary little-endian PLY: vertices (float x, y, z) and faces with ``uchar class`` and
    ``uchar reflectivity`` properties (MeshLab, CloudCompare and Open3D open it)."""
    v = scene.vertices.astype("<f4")
    nt = len(scene.triangles)
    face = np.empty(nt, dtype=[("n", "u1"), ("i", "<i4", (3,)), ("cls", "u1"), ("refl", "u1")])
    face["n"] = 3
    face["i"] = scene.triangles
    face["cls"] = scene.classes
    face["refl"] = scene.reflectivity
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment tripod simulated scene {scene.name}\n"
        "comment class: 0 ceiling, 1 floor, 2 wall, 3 other\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {nt}\nproperty list uchar int vertex_indices\n"
        "property uchar class\nproperty uchar reflectivity\nend_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(face.tobytes())


_PLY_TYPES = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "<i2",
              "ushort": "<u2", "int16": "<i2", "uint16": "<u2", "int": "<i4", "uint": "<u4",
              "int32": "<i4", "uint32": "<u4", "float": "<f4", "float32": "<f4",
              "double": "<f8", "float64": "<f8"}


def _read_classified_ply(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """(vertices, triangles, classes or None) of a binary-LE triangle PLY; None if not that kind."""
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            return None
        fmt = fh.readline().split()
        if len(fmt) < 2 or fmt[1] != b"binary_little_endian":
            return None
        elements: list[list] = []
        while True:
            line = fh.readline()
            if not line:
                return None
            w = line.decode("ascii", "replace").split()
            if not w or w[0] in ("comment", "obj_info"):
                continue
            if w[0] == "end_header":
                break
            if w[0] == "element":
                elements.append([w[1], int(w[2]), []])
            elif w[0] == "property":
                elements[-1][2].append(w[1:])
        out = {}
        for name, count, props in elements:
            if name == "face":
                fields = []
                for p in props:
                    if p[0] == "list":
                        if p[1] not in ("uchar", "uint8") or p[2] not in ("int", "uint", "int32",
                                                                           "uint32"):
                            return None
                        fields += [("n", "u1"), ("i", _PLY_TYPES[p[2]], (3,))]
                    else:
                        fields.append((p[1], _PLY_TYPES[p[0]]))
            else:
                if any(p[0] == "list" for p in props):
                    return None
                fields = [(p[1], _PLY_TYPES[p[0]]) for p in props]
            arr = np.frombuffer(fh.read(np.dtype(fields).itemsize * count), dtype=fields,
                                count=count)
            out[name] = arr
    if "vertex" not in out or "face" not in out or not np.all(out["face"]["n"] == 3):
        return None
    vx = out["vertex"]
    verts = np.stack([vx["x"], vx["y"], vx["z"]], axis=1).astype(np.float64)
    f = out["face"]
    cls = f["class"].astype(np.uint8) if "class" in (f.dtype.names or ()) else None
    return verts, f["i"].astype(np.int32), cls


def classify_by_normal(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Class per triangle from its normal and height: horizontal faces in the lowest / highest
    15 % of the mesh's height span are floor / ceiling, near-vertical faces spanning more than
    half of the height are walls, everything else is other."""
    p = vertices[triangles]  # (T, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    z = p[:, :, 2]
    zmin, zmax = vertices[:, 2].min(), vertices[:, 2].max()
    span = max(zmax - zmin, 1e-9)
    cls = np.full(len(triangles), OTHER, dtype=np.uint8)
    horiz = np.abs(n[:, 2]) > 0.95
    cls[horiz & (z.max(axis=1) < zmin + 0.15 * span)] = FLOOR
    cls[horiz & (z.min(axis=1) > zmax - 0.15 * span)] = CEILING
    vert = np.abs(n[:, 2]) < 0.1
    cls[vert & (z.max(axis=1) - z.min(axis=1) > 0.5 * span)] = WALL
    return cls


def default_route(vertices: np.ndarray) -> np.ndarray:
    """A loop inset from the mesh's horizontal bounds (for meshes that come without a route)."""
    lo, hi = vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)
    m = np.minimum(0.3 * (hi - lo), 1.5)
    return np.array([[lo[0] + m[0], lo[1] + m[1]], [hi[0] - m[0], lo[1] + m[1]],
                     [hi[0] - m[0], hi[1] - m[1]], [lo[0] + m[0], hi[1] - m[1]]])


def load_scene_file(path: str | os.PathLike, seed: int = 0) -> Scene:
    """Read a mesh file as a scene.

    A binary PLY with a per-face ``class`` property (our own mesh output) keeps its classes;
    any other mesh Open3D can read (PLY, OBJ, STL, OFF, GLTF) is classified by face normal.
    The route is a loop inset from the mesh bounds: make sure that space is free.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no such mesh file: {path}")
    got = None
    try:
        got = _read_classified_ply(path)
    except (ValueError, KeyError, struct.error, IndexError):
        got = None
    if got is None:
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(path)
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        tris = np.asarray(mesh.triangles, dtype=np.int32)
        cls = None
    else:
        verts, tris, cls = got
    if len(tris) == 0:
        raise ValueError(f"{path}: no triangles in this mesh")
    if cls is None:
        cls = classify_by_normal(verts, tris)
    cls = np.minimum(cls, OTHER).astype(np.uint8)
    rng = np.random.default_rng([seed, 0x5CE7E])
    return Scene(os.path.basename(path), verts, tris, cls, surface_reflectivity(cls, rng),
                 default_route(verts), True, {"file": os.path.abspath(path)})
