# SPDX-License-Identifier: BSD-3-Clause
"""Small labelled indoor scenes and tripod scans of them, for tests, training and benchmarks.

A scene is a triangle mesh whose triangles carry a class (0 ceiling, 1 floor, 2 wall, 3 other):
a rectilinear room (a box or an L), extruded from its floor polygon, with furniture (desks,
cabinets, chairs, pillars) and shallow objects on the walls. A scan places a VLP-16 lying on its
side on a turning tripod head (the thesis' rig), casts its beams with Open3D's
``RaycastingScene`` and adds Gaussian range noise. This is a compact, self-contained stand-in for
``tripod simulate`` (the digital twin): tests use it so that they run without simulator outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .beams import RING_ELEVATION_DEG, directions

CEILING, FLOOR, WALL, OTHER = 0, 1, 2, 3

# VLP-16: 16 beams from -15 to +15 deg, 2 deg apart [rad]
VLP16_ELEVATIONS = np.deg2rad(RING_ELEVATION_DEG)


@dataclass
class Scene:
    """Triangle mesh with a class per triangle.

    vertices : (V, 3) float64 [m]; triangles : (T, 3) int32; classes : (T,) int32
    footprint : list of (x, y) corners of the room's floor polygon [m]; height : room height [m]
    """

    vertices: np.ndarray
    triangles: np.ndarray
    classes: np.ndarray
    footprint: list = field(default_factory=list)
    height: float = 2.6

    def raycasting_scene(self):
        import open3d as o3d

        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(self.vertices.astype(np.float32), self.triangles.astype(np.uint32))
        return rs


class _MeshBuilder:
    def __init__(self) -> None:
        self.v: list[np.ndarray] = []
        self.t: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.n = 0

    def quad(self, a, b, c, d, cls: int) -> None:
        """Quad with corners a, b, c, d in order."""
        self.v.append(np.array([a, b, c, d], dtype=np.float64))
        self.t.append(np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32) + self.n)
        self.c.append(np.full(2, cls, np.int32))
        self.n += 4

    def box(self, lo, hi, cls: int, faces: str = "xXyYzZ") -> None:
        """Axis-aligned box [lo, hi]; faces: which sides to build (x=-x, X=+x, ...)."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        if "z" in faces:
            self.quad((x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0), cls)
        if "Z" in faces:
            self.quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1), cls)
        if "x" in faces:
            self.quad((x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1), cls)
        if "X" in faces:
            self.quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1), cls)
        if "y" in faces:
            self.quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1), cls)
        if "Y" in faces:
            self.quad((x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1), cls)

    def scene(self, footprint, height) -> Scene:
        return Scene(np.concatenate(self.v), np.concatenate(self.t), np.concatenate(self.c),
                     list(footprint), height)


def _rects_of(kind: str, w: float, d: float, rng) -> list[tuple[float, float, float, float]]:
    """Floor as a union of axis-aligned rectangles (x0, y0, x1, y1)."""
    if kind == "box":
        return [(0.0, 0.0, w, d)]
    # L: a w x d box missing its (+x, +y) corner
    cx, cy = w * rng.uniform(0.4, 0.65), d * rng.uniform(0.4, 0.65)
    return [(0.0, 0.0, w, cy), (0.0, cy, cx, d)]


def _polygon_of(kind, w, d, rects):
    if kind == "box":
        return [(0, 0), (w, 0), (w, d), (0, d)]
    cx, cy = rects[1][2], rects[0][3]
    return [(0, 0), (w, 0), (w, cy), (cx, cy), (cx, d), (0, d)]


def _inside(rects, x, y, margin=0.0) -> bool:
    return any(r[0] + margin <= x <= r[2] - margin and r[1] + margin <= y <= r[3] - margin
               for r in rects)


KINDS = ("box", "L", "two_rooms", "hall")


def make_room(seed: int, kind: str | None = None, size: tuple[float, float] | None = None,
              height: float | None = None, clutter: float = 1.0) -> Scene:
    """Random furnished room.

    Parameters
    ----------
    seed : int
        Layout seed (same seed, same room).
    kind : "box" | "L" | "two_rooms" (a partition wall with a door) | "hall" (large, tall, with
        columns) | None (drawn)
    size : (width, depth) [m] or None (drawn: 3.5..9 m, halls 15..35 m)
    height : room height [m] or None (drawn: 2.4..3.4 m, halls 4..9 m)
    clutter : float
        Scales the number of furniture pieces (0 = empty room).
    """
    rng = np.random.default_rng(seed)
    if kind is None:
        kind = KINDS[int(rng.choice(4, p=[0.4, 0.25, 0.2, 0.15]))]
    if kind not in KINDS:
        raise ValueError(f"unknown room kind {kind!r} (choose from {', '.join(KINDS)})")
    big = kind == "hall"
    if size is not None:
        w, d = size
    else:
        w, d = rng.uniform(15, 35, 2) if big else rng.uniform(3.5, 9.0, 2)
        if kind == "two_rooms":
            w = rng.uniform(8.0, 13.0)
    h = height if height is not None else (rng.uniform(4.0, 9.0) if big else rng.uniform(2.4, 3.4))
    rects = _rects_of("L" if kind == "L" else "box", w, d, rng)
    poly = _polygon_of("L" if kind == "L" else "box", w, d, rects)
    mb = _MeshBuilder()
    if kind == "two_rooms":  # partition (wall, 10 cm) with a door and its lintel (wall)
        _add_partition(mb, w, d, h, rng)
    if kind == "hall":  # columns on a grid (other): square or 8-sided
        _add_columns(mb, w, d, h, rng)
        clutter = clutter * 3
    for x0, y0, x1, y1 in rects:
        mb.quad((x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0), FLOOR)
        mb.quad((x0, y0, h), (x1, y0, h), (x1, y1, h), (x0, y1, h), CEILING)
    for (ax, ay), (bx, by) in zip(poly, poly[1:] + poly[:1]):
        mb.quad((ax, ay, 0), (bx, by, 0), (bx, by, h), (ax, ay, h), WALL)
    _add_furniture(mb, rects, w, d, h, clutter, rng)
    _add_wall_items(mb, poly, h, clutter, rng)
    return mb.scene(poly, h)


def _add_partition(mb: "_MeshBuilder", w: float, d: float, h: float, rng) -> None:
    """A partition wall (10 cm) at mid-width with a door and its lintel (wall)."""
    px = w * rng.uniform(0.4, 0.6)
    dy = rng.uniform(0.5, d - 1.5)
    dh = min(2.1, h - 0.2)
    mb.box((px - 0.05, 0, 0), (px + 0.05, dy, h), WALL, faces="xXY")
    mb.box((px - 0.05, dy + 0.9, 0), (px + 0.05, d, h), WALL, faces="xXy")
    mb.box((px - 0.05, dy, dh), (px + 0.05, dy + 0.9, h), WALL, faces="xXz")


def _add_columns(mb: "_MeshBuilder", w: float, d: float, h: float, rng) -> None:
    """Columns on a grid (other), square or 8-sided, floor to ceiling."""
    sp = rng.uniform(5.0, 8.0)
    r = rng.uniform(0.2, 0.4)
    for cx in np.arange(sp, w - sp / 2, sp):
        for cy in np.arange(sp, d - sp / 2, sp):
            if rng.random() < 0.5:
                mb.box((cx - r, cy - r, 0), (cx + r, cy + r, h), OTHER, faces="xXyY")
            else:
                a = np.linspace(0, 2 * np.pi, 9)
                for a0, a1 in zip(a[:-1], a[1:]):
                    p0 = (cx + r * np.cos(a0), cy + r * np.sin(a0))
                    p1 = (cx + r * np.cos(a1), cy + r * np.sin(a1))
                    mb.quad((*p0, 0), (*p1, 0), (*p1, h), (*p0, h), OTHER)


def _add_furniture(mb: "_MeshBuilder", rects, w: float, d: float, h: float, clutter: float,
                   rng) -> None:
    """Desks, cabinets against walls, chairs and sometimes a free-standing pillar (other)."""
    def spot(sx, sy, margin=0.3):
        for _ in range(50):
            x, y = rng.uniform(0, w), rng.uniform(0, d)
            if _inside(rects, x, y, margin) and _inside(rects, x + sx, y + sy, margin):
                return x, y
        return None

    n_desks = int(rng.integers(1, 5) * clutter)
    for _ in range(n_desks):  # desk: top slab + 4 legs
        sx, sy = rng.uniform(0.8, 1.8), rng.uniform(0.6, 0.9)
        if rng.random() < 0.5:
            sx, sy = sy, sx
        p = spot(sx, sy)
        if p is None:
            continue
        x, y = p
        top = rng.uniform(0.70, 0.78)
        mb.box((x, y, top - 0.03), (x + sx, y + sy, top), OTHER)
        for lx, ly in ((x, y), (x + sx - 0.05, y), (x, y + sy - 0.05), (x + sx - 0.05, y + sy - 0.05)):
            mb.box((lx, ly, 0), (lx + 0.05, ly + 0.05, top - 0.03), OTHER, faces="xXyY")
    n_cab = int(rng.integers(0, 4) * clutter)
    for _ in range(n_cab):  # cabinet / shelf against a wall
        r = rects[int(rng.integers(len(rects)))]
        side = int(rng.integers(4))
        depth, width, tall = rng.uniform(0.35, 0.6), rng.uniform(0.6, 2.0), rng.uniform(0.8, 2.1)
        if side in (0, 1):
            x = rng.uniform(r[0], max(r[0], r[2] - width))
            y = r[1] + 0.02 if side == 0 else r[3] - depth - 0.02
            lo, hi = (x, y, 0), (x + width, y + depth, tall)
        else:
            y = rng.uniform(r[1], max(r[1], r[3] - width))
            x = r[0] + 0.02 if side == 2 else r[2] - depth - 0.02
            lo, hi = (x, y, 0), (x + depth, y + width, tall)
        if _inside(rects, lo[0], lo[1]) and _inside(rects, hi[0], hi[1]):
            mb.box(lo, hi, OTHER, faces="xXyYZ")
    n_chairs = int(rng.integers(0, 6) * clutter)
    for _ in range(n_chairs):
        p = spot(0.45, 0.45)
        if p is None:
            continue
        x, y = p
        mb.box((x, y, 0.42), (x + 0.45, y + 0.45, 0.47), OTHER)
        mb.box((x, y, 0.47), (x + 0.45, y + 0.05, 0.95), OTHER)
        mb.box((x + 0.2, y + 0.2, 0.0), (x + 0.25, y + 0.25, 0.42), OTHER, faces="xXyY")
    if rng.random() < 0.3 * clutter:  # a free-standing pillar
        p = spot(0.4, 0.4, margin=0.8)
        if p is not None:
            x, y = p
            s = rng.uniform(0.25, 0.5)
            mb.box((x, y, 0), (x + s, y + s, h), OTHER, faces="xXyY")


def _add_wall_items(mb: "_MeshBuilder", poly, h: float, clutter: float, rng) -> None:
    """Pictures, boards and radiators on the walls (thin boxes, other)."""
    for _ in range(int(rng.integers(0, 5) * clutter)):  # pictures, boards, radiators on walls
        k = int(rng.integers(len(poly)))
        (ax, ay), (bx, by) = poly[k], poly[(k + 1) % len(poly)]
        length = np.hypot(bx - ax, by - ay)
        wl = rng.uniform(0.4, min(1.6, 0.6 * length))
        s0 = rng.uniform(0.1, max(0.11, length - wl - 0.1))
        z0 = rng.uniform(0.3, max(0.31, h - 1.4))
        zh = rng.uniform(0.4, 1.0)
        t = rng.uniform(0.04, 0.15)  # thickness [m]
        ux, uy = (bx - ax) / length, (by - ay) / length
        nx, ny = -uy, ux  # inward normal for counter-clockwise polygons
        p0 = np.array([ax + ux * s0, ay + uy * s0])
        p1 = p0 + np.array([ux, uy]) * wl
        q0, q1 = p0 + np.array([nx, ny]) * t, p1 + np.array([nx, ny]) * t
        mb.quad((*q0, z0), (*q1, z0), (*q1, z0 + zh), (*q0, z0 + zh), OTHER)
        mb.quad((*p0, z0), (*p1, z0), (*q1, z0), (*q0, z0), OTHER)
        mb.quad((*p0, z0 + zh), (*p1, z0 + zh), (*q1, z0 + zh), (*q0, z0 + zh), OTHER)
        mb.quad((*p0, z0), (*q0, z0), (*q0, z0 + zh), (*p0, z0 + zh), OTHER)
        mb.quad((*p1, z0), (*q1, z0), (*q1, z0 + zh), (*p1, z0 + zh), OTHER)


def free_station(scene: Scene, rng, margin: float = 0.6) -> np.ndarray:
    """A random tripod position inside the room, away from walls [m] (sensor 1.2..1.7 m up)."""
    xs = [p[0] for p in scene.footprint]
    ys = [p[1] for p in scene.footprint]
    rs = scene.raycasting_scene()
    import open3d as o3d

    for _ in range(200):
        x, y = rng.uniform(min(xs), max(xs)), rng.uniform(min(ys), max(ys))
        z = rng.uniform(1.2, 1.7)
        # inside and free: horizontal rays must all hit something farther than margin
        a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        rays = np.zeros((16, 6), np.float32)
        rays[:, :3] = (x, y, z)
        rays[:, 3], rays[:, 4] = np.cos(a), np.sin(a)
        t = rs.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        down = np.array([[x, y, z, 0, 0, -1]], np.float32)
        t_down = rs.cast_rays(o3d.core.Tensor(down))["t_hit"].numpy()[0]
        # closed around, nothing near, and standing on the floor (not on a desk or in a cabinet)
        if np.all(np.isfinite(t)) and t.min() > margin and abs(t_down - z) < 1e-3:
            return np.array([x, y, z])
    raise RuntimeError("no free station found")


def scan(scene: Scene, station, *, head_steps: int = 24, azimuth_step_deg: float = 0.4,
         noise_m: float = 0.015, max_range: float = 100.0, seed: int = 0,
         tilt_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Simulated tripod scan: a VLP-16 on its side, the head turning through 180 deg.

    Parameters
    ----------
    scene : Scene
    station : (3,) sensor position [m]
    head_steps : head yaw positions over 180 deg (each one a full VLP-16 turn)
    azimuth_step_deg : VLP-16 firing resolution [deg]
    noise_m : range noise sigma [m]
    seed : noise seed
    tilt_deg : tilt the returned cloud by this angle about a random horizontal axis (an IMU error)

    Returns
    -------
    points : (N, 3) float32 [m] in the scene frame, labels : (N,) int32 (the class of the hit)
    """
    import open3d as o3d

    rng = np.random.default_rng(seed)
    alpha = np.deg2rad(np.arange(0, 360, azimuth_step_deg))
    om = VLP16_ELEVATIONS
    a, o = np.meshgrid(alpha, om, indexing="ij")
    # sensor frame: spin axis z_s; lying on its side: z_s -> world x (before the head yaw)
    d_s = directions(a, o).reshape(-1, 3)
    R_side = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)  # rotate z_s onto world x
    dirs = []
    for psi in np.linspace(0, np.pi, head_steps, endpoint=False) + rng.uniform(0, np.pi / head_steps):
        c, s = np.cos(psi), np.sin(psi)
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        dirs.append(d_s @ (Rz @ R_side).T)
    dirs = np.concatenate(dirs)
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3] = station
    rays[:, 3:] = dirs
    rs = scene.raycasting_scene()
    ans = rs.cast_rays(o3d.core.Tensor(rays), nthreads=0)
    t = ans["t_hit"].numpy()
    prim = ans["primitive_ids"].numpy()
    ok = np.isfinite(t) & (t > 0.5) & (t < max_range)  # VLP-16 minimum range ~0.5 m
    t = t[ok] + rng.normal(0, noise_m, ok.sum())
    pts = np.asarray(station)[None] + dirs[ok] * t[:, None]
    labels = scene.classes[prim[ok]].astype(np.int32)
    if tilt_deg:
        axis = np.array([*rng.normal(size=2), 0.0])
        pts = (pts - station) @ _axis_angle(axis, np.deg2rad(tilt_deg)).T + station
    return pts.astype(np.float32), labels


def _axis_angle(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def scan_room(seed: int, *, n_stations: int = 1, **scan_kwargs) -> tuple[np.ndarray, np.ndarray, Scene]:
    """A random room scanned from ``n_stations`` random stations (merged), with labels."""
    scene = make_room(seed)
    rng = np.random.default_rng(seed + 7919)
    P, L = [], []
    for k in range(n_stations):
        st = free_station(scene, rng)
        p, lab = scan(scene, st, seed=seed * 101 + k, **scan_kwargs)
        P.append(p)
        L.append(lab)
    return np.concatenate(P), np.concatenate(L), scene
