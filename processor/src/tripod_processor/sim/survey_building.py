# SPDX-License-Identifier: BSD-3-Clause
"""A building for the digital twin, surveyed as many recordings (``tripod batch --merge``).

One floor, two wings: a hall with columns in the middle, an east and a west corridor leaving it,
four furnished rooms off each corridor (north and south), every space joined to its
neighbours by door openings (1.2 m wide, with a lintel at 2.05 m). Spaces are rectangles
separated by 0.2 m thick walls; a door is a rectangle across the wall, so the floor plan's
union gives door reveals on both sides. Furniture differs from room to room (drawn from the
seed), so two rooms of the same size do not look alike to a registration.

A *survey* is a list of recordings, each a route through the free space (open polylines through
the doors, a loop in a room), with its own start time (a recording a day apart), IMU heading
reference (the IMU's yaw reference is arbitrary at each power-on) and seed. Routes overlap:
every recording of the ``full`` survey revisits a room or a doorway another recording covers
too; the ``small`` survey (tests) has two recordings sharing the hall (3 and 4 stations) and one alone in a west
room (it overlaps nothing: a separate component of the merged model).

All recordings share the building frame (``world``: the mesh's frame, z up), so their truth
(``gt/trajectory.tum`` of each capture) scores a merged model directly.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .scenes import OTHER, MeshBuilder, Scene, write_mesh_ply

HEIGHT_M = 3.0
WALL_M = 0.2
DOOR_W = 1.2
LINTEL_Z = 2.05
CORRIDOR_Y = 5.1  # axis of both corridors [m]

#: spaces (x0, y0, x1, y1) [m]
SPACES = {
    "hall": (0.0, 0.0, 12.0, 10.0),
    "east corridor": (12.2, 4.0, 32.0, 6.2),
    "west corridor": (-18.0, 4.0, -0.2, 6.2),
    "E1": (12.2, 6.4, 18.0, 12.0), "E2": (18.2, 6.4, 25.0, 12.0),
    "E3": (25.2, 6.4, 32.0, 12.0), "E4": (12.2, -2.0, 20.0, 3.8),
    "E5": (20.2, -2.0, 32.0, 3.8),
    "W1": (-8.0, 6.4, -0.2, 12.0), "W2": (-18.0, 6.4, -8.2, 12.0),
    "W3": (-10.0, -2.0, -0.2, 3.8), "W4": (-18.0, -2.0, -10.2, 3.8),
}

#: door centres along the corridors' walls: x of the door of each room [m]
ROOM_DOOR_X = {"E1": 15.0, "E2": 21.5, "E3": 28.5, "E4": 16.0, "E5": 26.5,
               "W1": -4.0, "W2": -13.0, "W3": -5.0, "W4": -14.0}
HALL_E1_DOOR_Y = 8.5  # the hall's second door, into E1 [m]


def _door_rects() -> list[tuple[float, float, float, float]]:
    h = DOOR_W / 2
    c = CORRIDOR_Y
    rects = [(12.0, c - 0.8, 12.2, c + 0.8), (-0.2, c - 0.8, 0.0, c + 0.8),  # hall-corridors
             (12.0, HALL_E1_DOOR_Y - h, 12.2, HALL_E1_DOOR_Y + h)]  # hall-E1
    for room, x in ROOM_DOOR_X.items():
        north = SPACES[room][1] > c
        y0, y1 = (6.2, 6.4) if north else (3.8, 4.0)
        rects.append((x - h, y0, x + h, y1))
    return rects


def _furnish_room(mb: MeshBuilder, rect, door_x: float, north: bool,
                  rng: np.random.Generator) -> None:
    """Cabinets, shelves and desks against the walls (never in front of the door), and a table
    island in some rooms; kept 0.7 m deep at most so the route (1.4 m from the walls) is free."""
    x0, y0, x1, y1 = rect
    door_wall_y = y0 if north else y1
    for _ in range(int(rng.integers(3, 6))):
        side = int(rng.integers(0, 4))  # 0 -x wall, 1 +x wall, 2 -y wall, 3 +y wall
        depth = rng.uniform(0.35, 0.7)
        length = rng.uniform(0.8, 2.2)
        top = rng.uniform(0.7, 2.2)
        if side < 2:
            lo = rng.uniform(y0 + 0.1, max(y0 + 0.2, y1 - length - 0.1))
            xa = x0 + 0.02 if side == 0 else x1 - 0.02 - depth
            mb.box((xa, lo, 0.0), (xa + depth, min(lo + length, y1 - 0.05), top), OTHER)
        else:
            wall_y = y0 if side == 2 else y1
            lo = rng.uniform(x0 + 0.1, max(x0 + 0.2, x1 - length - 0.1))
            hi = min(lo + length, x1 - 0.05)
            if wall_y == door_wall_y and lo < door_x + DOOR_W and hi > door_x - DOOR_W:
                continue  # keep the door free
            ya = y0 + 0.02 if side == 2 else y1 - 0.02 - depth
            mb.box((lo, ya, 0.0), (hi, ya + depth, top), OTHER)
    if rng.random() < 0.6:  # a table island in the middle
        cx = rng.uniform(x0 + 2.6, x1 - 2.6) if x1 - x0 > 5.4 else 0.5 * (x0 + x1)
        cy = 0.5 * (y0 + y1) + rng.uniform(-0.2, 0.2)
        w, d = rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.7)
        mb.box((cx - w / 2, cy - d / 2, 0.72), (cx + w / 2, cy + d / 2, 0.76), OTHER)
        for sx in (-1, 1):
            for sy in (-1, 1):
                lx, ly = cx + sx * (w / 2 - 0.06), cy + sy * (d / 2 - 0.06)
                mb.box((lx - 0.025, ly - 0.025, 0.0), (lx + 0.025, ly + 0.025, 0.72), OTHER)


def make_building(seed: int = 0) -> Scene:
    """The building's classified mesh (frame ``world``: z up, floor at z = 0)."""
    rng = np.random.default_rng([seed, 0xB01D])
    mb = MeshBuilder()
    doors = _door_rects()
    mb.floor_plan(list(SPACES.values()) + doors, HEIGHT_M)
    for x0, y0, x1, y1 in doors:  # lintels above the door openings
        mb.box((x0, y0, LINTEL_Z), (x1, y1, HEIGHT_M), 2)  # class wall
    # hall: four columns, a reception desk, benches
    for cx in (4.0, 8.0):
        for cy in (3.3, 6.7):
            mb.prism(cx, cy, 0.3, 0.0, HEIGHT_M, OTHER)
    mb.box((0.6, 8.6, 0.0), (3.2, 9.3, 1.1), OTHER)
    mb.box((7.0, 0.05, 0.0), (9.5, 0.5, 0.45), OTHER)
    # corridors: radiators and benches on the walls, away from the doors
    for (x0, y0, x1, y1), xs in ((SPACES["east corridor"], (18.5, 23.5, 30.0)),
                                 (SPACES["west corridor"], (-2.5, -9.0, -16.5))):
        for k, x in enumerate(xs):
            w = rng.uniform(0.8, 1.4)
            if k % 2 == 0:
                mb.box((x, y0 + 0.02, 0.15), (x + w, y0 + 0.12, 0.75), OTHER)
            else:
                mb.box((x, y1 - 0.45, 0.0), (x + w, y1 - 0.02, 0.45), OTHER)
    for room, dx in ROOM_DOOR_X.items():
        _furnish_room(mb, SPACES[room], dx, SPACES[room][1] > CORRIDOR_Y, rng)
    params = {"spaces": len(SPACES), "doors": len(doors), "height_m": HEIGHT_M,
              "wall_m": WALL_M, "door_width_m": DOOR_W, "seed": seed}
    hall = SPACES["hall"]
    route = [(2.0, 2.0), (hall[2] - 2.0, 2.0), (hall[2] - 2.0, hall[3] - 2.0),
             (2.0, hall[3] - 2.0)]
    return mb.build("building", route, True, params, rng)


# --------------------------------------------------------------------------- routes


def room_visit(room: str) -> list[tuple[float, float]]:
    """From the corridor axis at the room's door, through the door, a U through the room, and
    back to the corridor axis (in and out 0.25 m either side of the door's centre)."""
    x0, y0, x1, y1 = SPACES[room]
    d = ROOM_DOOR_X[room]
    north = y0 > CORRIDOR_Y
    s = 1.0 if north else -1.0
    inner = (y0 + 1.4) if north else (y1 - 1.4)  # 1.4 m inside the room
    far = (y1 - 1.4) if north else (y0 + 1.4)
    xa, xb = max(x0 + 1.4, d - 2.2), min(x1 - 1.4, d + 2.2)
    door_in = y0 + 0.8 if north else y1 - 0.8
    c = CORRIDOR_Y
    return [(d - 0.25, c), (d - 0.25, door_in), (xa, inner + 0.2 * s), (xa, far), (xb, far),
            (xb, inner + 0.2 * s), (d + 0.25, door_in), (d + 0.25, c)]


@dataclass
class SurveyRecording:
    """One recording of a survey: a route through the building and its station count."""

    name: str
    route_xy: list[tuple[float, float]]
    stations: int
    closed: bool = False


def _n(route, closed: bool, spacing: float) -> int:
    p = np.asarray(route, dtype=np.float64)
    if closed:
        p = np.vstack([p, p[:1]])
    return max(2, int(round(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() / spacing)))


def survey_plan(size: str = "full", spacing_m: float = 1.9) -> list[SurveyRecording]:
    """The recordings of a survey: ``full`` (8 recordings, ≥ 200 stations, for the benchmark)
    or ``small`` (3 recordings, 10 stations, for the tests)."""
    c = CORRIDOR_Y
    if size == "small":
        return [SurveyRecording("hall", [(2.5, 2.5), (9.5, 2.5), (9.5, 7.5)], 3),
                SurveyRecording("hall-east", [(2.5, 7.8), (6.0, 7.8), (6.0, c), (13.5, c)], 4),
                SurveyRecording("west-room", [(-16.5, -0.6), (-11.7, -0.6), (-11.7, 2.4)], 3)]
    if size != "full":
        raise ValueError(f"unknown survey size {size!r} (full or small)")
    hall_loop = [(2.0, 2.0), (10.0, 2.0), (10.0, 8.0), (2.0, 8.0)]
    routes = {
        "hall": (hall_loop, True),
        "east-north": ([(6.0, c)] + room_visit("E1") + room_visit("E2") + room_visit("E3")
                       + [(31.0, c)], False),
        "east-south": ([(31.0, c)] + room_visit("E5") + room_visit("E4") + [(6.0, c)], False),
        "west-north": ([(6.0, c)] + room_visit("W1") + room_visit("W2") + [(-17.0, c)], False),
        "west-south": ([(-17.0, c)] + room_visit("W4") + room_visit("W3") + [(4.0, c)], False),
        "east-revisit": ([(4.0, HALL_E1_DOOR_Y), (13.6, HALL_E1_DOOR_Y), (15.25, 8.8),
                          (15.25, c)] + room_visit("E2") + [(24.0, c), (10.0, c)], False),
        "west-revisit": ([(9.0, 2.0), (2.0, 2.0), (1.5, c), (-2.0, c)] + room_visit("W3")
                         + [(-7.0, c)], False),
        "cross": ([(-10.0, c), (14.0, c)]
                  + room_visit("E4") + [(19.0, c)], False),
    }
    return [SurveyRecording(name, r, _n(r, closed, spacing_m), closed)
            for name, (r, closed) in routes.items()]


# --------------------------------------------------------------------------- captures


def survey_configs(size: str = "full", seed: int = 0, pan_s: float = 5.0,
                   mesh_file: str = "building.ply") -> list[tuple[str, dict]]:
    """(name, SimConfig dict) of each recording: the building as ``scene_file``, the route,
    short pans (cheap stations), a start a day apart, its own IMU heading reference and seed."""
    out = []
    for k, r in enumerate(survey_plan(size)):
        out.append((f"{k:02d}-{r.name}", {
            "scene_file": mesh_file, "route_xy": [list(p) for p in r.route_xy],
            "route_closed": r.closed, "stations": r.stations, "seed": seed * 1000 + 31 * k + 7,
            "start_unix_ns": 1_767_268_800_000_000_000 + k * 86_400_000_000_000
            + int((k * 7919) % 3600) * 1_000_000_000,
            "motion": {"pan_s": pan_s, "transit_s": 3.0, "station_lateral_jitter_m": 0.1},
            "imu": {"yaw_offset_deg": float((37.0 + 97.0 * k) % 360.0)},
        }))
    return out


def simulate_survey(out_dir: str | os.PathLike, size: str = "full", seed: int = 0,
                    pan_s: float = 5.0, nthreads: int = 0, progress=None) -> list[Path]:
    """Simulate every recording of a survey into ``out_dir/<k>-<name>/`` (each a ``tripod
    simulate`` folder; an existing complete one of the same config is kept, wherever its mesh
    file was) and the building mesh
    ``out_dir/building.ply``. Returns the recording folders."""
    from .capture import META_FILE, simulate
    from .config import SimConfig

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mesh = out / "building.ply"
    if not mesh.is_file():
        write_mesh_ply(mesh, make_building(seed))
    dirs = []
    plan = survey_configs(size, seed, pan_s, str(mesh.resolve()))
    for i, (name, cfg) in enumerate(plan):
        d = out / name
        done = d / META_FILE
        want = SimConfig.model_validate(cfg)
        if not done.is_file() or not _same_config(json.loads(done.read_text())["config"], want):
            simulate(want, d, nthreads=nthreads)
        dirs.append(d)
        if progress is not None:
            progress(i + 1, len(plan))
    return dirs


def _same_config(meta_config: dict, cfg) -> bool:
    """The capture's config equals ``cfg`` but for the mesh file's path (a moved survey)."""
    a = dict(meta_config)
    b = cfg.model_dump(mode="json")
    a.pop("scene_file", None)
    b.pop("scene_file", None)
    return a == b
