# SPDX-License-Identifier: BSD-3-Clause
"""A procedural building (``sim.procedural``) as a capture scene: its mesh and a tripod route.

``tripod simulate`` takes any classified mesh as ``scene_file``, but a building's default route
(a loop inset from the mesh bounds) runs through its interior walls and furniture. The route
here is derived from the building's free floor: the free rectangles of its largest room on a
10 cm grid, each cell kept when the mesh is at least ``clearance_m`` away at every height the
tripod occupies (0.5-1.7 m above the floor), and the longest shortest path through the biggest
connected free region (two breadth-first searches), sampled every ~0.5 m. The stations spread
along it, so they share one room (and overlap) while seeing it from its two far ends.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .procedural import Building
from .scenes import Scene, surface_reflectivity

#: heights above the floor the tripod (legs, head, lidar) occupies [m], as ``check_route``
TRIPOD_HEIGHTS_M = (0.5, 1.0, 1.5, 1.7)


def building_scene(building: Building, clearance_m: float = 0.45, cell_m: float = 0.10,
                   max_route_m: float | None = 15.0) -> Scene:
    """``building`` as a :class:`~.scenes.Scene` whose route is :func:`free_route`'s (open),
    its middle ``max_route_m`` [m] when longer (a big hall's stations stay within sight)."""
    rng = np.random.default_rng([building.seed, 0x5CE7E])
    cls = building.classes.astype(np.uint8)
    return Scene(f"{building.family}_{building.seed}", building.vertices.astype(np.float64),
                 building.triangles.astype(np.int32), cls, surface_reflectivity(cls, rng),
                 free_route(building, clearance_m, cell_m, max_length_m=max_route_m), False,
                 {"family": building.family, "seed": int(building.seed),
                  "height_m": round(float(building.height), 4)})


def free_route(building: Building, clearance_m: float = 0.45, cell_m: float = 0.10,
               step_m: float = 0.5, max_length_m: float | None = None) -> np.ndarray:
    """(K, 2) [m] an open route through the largest room's free floor (module docstring); its
    middle ``max_length_m`` [m] when longer.

    Raises ValueError (one line) when the room has no free region 2 m long."""
    import open3d as o3d

    areas = [(sum((a[2] - a[0]) * (a[3] - a[1]) for a in al), rid)
             for rid, al in enumerate(building.free) if al]
    if not areas:
        raise ValueError(f"{building.family} {building.seed}: no free floor")
    rid = max(areas)[1]
    rects = building.free[rid]
    lo = np.min([r[:2] for r in rects], 0)
    hi = np.max([r[2:] for r in rects], 0)
    nx, ny = (np.ceil((hi - lo) / cell_m).astype(int) + 1)
    gx, gy = np.meshgrid(lo[0] + cell_m * np.arange(nx), lo[1] + cell_m * np.arange(ny),
                         indexing="ij")
    xy = np.c_[gx.ravel(), gy.ravel()]
    inside = np.zeros(len(xy), bool)
    for x0, y0, x1, y1 in rects:
        inside |= (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(building.vertices.astype(np.float32)),
                     o3d.core.Tensor(building.triangles.astype(np.uint32)))
    free = inside.copy()
    for h in TRIPOD_HEIGHTS_M:
        q = np.c_[xy[free], np.full(int(free.sum()), h)].astype(np.float32)
        d = rs.compute_distance(o3d.core.Tensor(q)).numpy()
        idx = np.flatnonzero(free)
        free[idx[d < clearance_m]] = False
    grid = free.reshape(nx, ny)
    start = _largest_component_cell(grid)
    if start is None:
        raise ValueError(f"{building.family} {building.seed}: no free region in room {rid}")
    far, _ = _bfs(grid, start)
    end, prev = _bfs(grid, far)
    path = [end]
    while path[-1] != far:
        path.append(prev[path[-1]])
    pts = np.array([(lo[0] + i * cell_m, lo[1] + j * cell_m) for i, j in path])
    if len(pts) < 2 or np.linalg.norm(pts[-1] - pts[0]) < 2.0:
        raise ValueError(f"{building.family} {building.seed}: the free region of room {rid} "
                         "is under 2 m long")
    # keep every ~step_m along the path (its ends included): a polyline of grid-safe points
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    s0, s1 = 0.0, seg[-1]
    if max_length_m is not None and seg[-1] > max_length_m:
        s0 = (seg[-1] - max_length_m) / 2
        s1 = s0 + max_length_m
    at = np.searchsorted(seg, np.r_[np.arange(s0, s1, step_m), s1])
    keep = np.unique(at.clip(0, len(pts) - 1))
    return pts[keep]


def _neighbours(grid, c):
    i, j = c
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        a, b = i + di, j + dj
        if 0 <= a < grid.shape[0] and 0 <= b < grid.shape[1] and grid[a, b]:
            yield (a, b)


def _bfs(grid, start):
    """(the farthest cell from ``start``, predecessor map) of a 4-connected search."""
    prev = {start: start}
    q = deque([start])
    last = start
    while q:
        last = q.popleft()
        for n in _neighbours(grid, last):
            if n not in prev:
                prev[n] = last
                q.append(n)
    return last, prev


def _largest_component_cell(grid):
    """The first cell (row-major) of the largest 4-connected free region; None when none."""
    from scipy import ndimage

    lab, n = ndimage.label(grid)  # the default structure is 4-connected in 2-D
    if n == 0:
        return None
    big = 1 + int(np.argmax(np.bincount(lab.ravel())[1:]))
    i, j = np.argwhere(lab == big)[0]
    return (int(i), int(j))
