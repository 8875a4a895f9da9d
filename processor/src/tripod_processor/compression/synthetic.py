# SPDX-License-Identifier: BSD-3-Clause
"""Synthetic indoor captures for training and testing the compressor when no simulator output
is at hand: random box rooms with furniture, ray cast with a VLP-16-like scan pattern.

The sensor pattern follows the VLP-16: 16 beams from -15 to +15 deg elevation (2 deg apart),
0.2 deg azimuth steps (1800 firings per revolution). A tripod fragment is a set of revolutions at
different orientations of the lidar (the tilting head), all from one station. Range noise is
Gaussian (VLP-16 datasheet: +-3 cm accuracy; sigma 1 cm here).
"""

from __future__ import annotations

import numpy as np

from ..sim.beams import LASER_ELEVATION_DEG, RING_ELEVATION_DEG, directions

VLP16_ELEVATIONS_DEG = RING_ELEVATION_DEG  # 16 beams
VLP16_AZIMUTH_STEP_DEG = 0.2


def _box(o3d, size, center, rotation_z=0.0):
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size) / 2.0)
    c, s = np.cos(rotation_z), np.sin(rotation_z)
    m.rotate(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), center=(0, 0, 0))
    m.translate(center)
    return m


def random_room(rng: np.random.Generator):
    """A random furnished room as an open3d TriangleMesh; returns (mesh, room_size [m])."""
    import open3d as o3d

    w, d, h = rng.uniform(3.0, 11.0), rng.uniform(3.0, 13.0), rng.uniform(2.4, 3.6)
    t = 0.2  # wall thickness [m]
    parts = [
        _box(o3d, (w + 2 * t, d + 2 * t, t), (w / 2, d / 2, -t / 2)),          # floor
        _box(o3d, (w + 2 * t, d + 2 * t, t), (w / 2, d / 2, h + t / 2)),       # ceiling
        _box(o3d, (t, d, h), (-t / 2, d / 2, h / 2)),                          # walls
        _box(o3d, (t, d, h), (w + t / 2, d / 2, h / 2)),
        _box(o3d, (w, t, h), (w / 2, -t / 2, h / 2)),
        _box(o3d, (w, t, h), (w / 2, d + t / 2, h / 2)),
    ]
    # furniture: tables, cabinets, shelves, boxes; some rotated
    for _ in range(rng.integers(3, 14)):
        kind = rng.integers(0, 4)
        yaw = rng.choice([0.0, 0.0, rng.uniform(0, np.pi)])
        x, y = rng.uniform(0.4, w - 0.4), rng.uniform(0.4, d - 0.4)
        if kind == 0:  # table: top + 4 legs
            sx, sy, sz = rng.uniform(0.6, 2.0), rng.uniform(0.5, 1.2), rng.uniform(0.7, 0.8)
            parts.append(_box(o3d, (sx, sy, 0.04), (x, y, sz), yaw))
            for lx in (-1, 1):
                for ly in (-1, 1):
                    off = np.array([lx * (sx / 2 - 0.05), ly * (sy / 2 - 0.05)])
                    c, s = np.cos(yaw), np.sin(yaw)
                    ox, oy = c * off[0] - s * off[1], s * off[0] + c * off[1]
                    parts.append(_box(o3d, (0.05, 0.05, sz), (x + ox, y + oy, sz / 2), yaw))
        elif kind == 1:  # cabinet / shelf against a wall
            sx, sy, sz = rng.uniform(0.4, 2.5), rng.uniform(0.3, 0.6), rng.uniform(0.8, 2.2)
            wall = rng.integers(0, 4)
            if wall == 0:
                x, yaw = sy / 2, np.pi / 2
            elif wall == 1:
                x, yaw = w - sy / 2, np.pi / 2
            elif wall == 2:
                y, yaw = sy / 2, 0.0
            else:
                y, yaw = d - sy / 2, 0.0
            parts.append(_box(o3d, (sx, sy, sz), (x, y, sz / 2), yaw))
        elif kind == 2:  # box / chair-sized block
            s3 = rng.uniform(0.3, 0.9, size=3)
            parts.append(_box(o3d, tuple(s3), (x, y, s3[2] / 2), yaw))
        else:  # pillar or partition
            if rng.random() < 0.5:
                cyl = o3d.geometry.TriangleMesh.create_cylinder(rng.uniform(0.1, 0.3), h, 24)
                cyl.translate((x, y, h / 2))
                parts.append(cyl)
            else:
                parts.append(_box(o3d, (rng.uniform(1.0, w / 2), 0.1, h), (x, y, h / 2), yaw))
    mesh = parts[0]
    for p in parts[1:]:
        mesh += p
    return mesh, np.array([w, d, h])


def vlp16_fragment(mesh, station: np.ndarray, rng: np.random.Generator, n_revolutions: int = 24,
                   range_noise_m: float = 0.01) -> np.ndarray:
    """Ray cast ``n_revolutions`` VLP-16 revolutions at random head orientations from ``station``.

    Returns
    -------
    points : (N, 3) float32 [m], world frame; no-returns and ranges < 0.4 m are dropped.
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    el = np.deg2rad(VLP16_ELEVATIONS_DEG)
    az = np.deg2rad(np.arange(0.0, 360.0, VLP16_AZIMUTH_STEP_DEG))
    ee, aa = np.meshgrid(el, az, indexing="ij")
    dirs_lidar = directions(aa, ee).reshape(-1, 3)
    out = []
    for _ in range(n_revolutions):
        tilt, yaw = rng.uniform(-np.pi / 2, np.pi / 2), rng.uniform(0, 2 * np.pi)
        ct, st, cy, sy = np.cos(tilt), np.sin(tilt), np.cos(yaw), np.sin(yaw)
        R = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array(
            [[1, 0, 0], [0, ct, -st], [0, st, ct]])
        dirs = dirs_lidar @ R.T
        rays = np.concatenate([np.broadcast_to(station, dirs.shape), dirs], 1).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        ok = np.isfinite(t) & (t > 0.4)
        r = t[ok] + rng.normal(0.0, range_noise_m, ok.sum())
        out.append(station + dirs[ok] * r[:, None])
    return np.concatenate(out).astype(np.float32)


def random_fragment(seed: int, n_revolutions: int = 24) -> np.ndarray:
    """One synthetic fragment (N, 3) float32 [m] of a random room, reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    mesh, size = random_room(rng)
    station = np.array([rng.uniform(0.2, 0.8) * size[0], rng.uniform(0.2, 0.8) * size[1],
                        rng.uniform(1.0, 1.7)])
    return vlp16_fragment(mesh, station, rng, n_revolutions)


# VLP-16 firing order: lasers 0..15 fire in this sequence of elevations [deg]
VLP16_FIRING_ORDER_DEG = tuple(int(e) for e in LASER_ELEVATION_DEG)


def ordered_scan(seed: int, n_revolutions: float = 1.0, room=(6.0, 4.5, 2.8),
                 range_lattice_m: float | None = 0.002, range_noise_m: float = 0.01,
                 dropout: float = 0.05, laser_z_m=None) -> np.ndarray:
    """A VLP-16 scan in the sensor frame, in firing order, of a box room (no open3d needed).

    The sensor sits at the origin, inside an axis-aligned box of size ``room`` [m] placed at a
    random offset; each firing (azimuth step 0.2 deg) shoots the 16 lasers in the VLP-16's
    order. Ranges get Gaussian noise, are rounded to ``range_lattice_m`` (the VLP-16 reports
    2 mm steps; None: not rounded), and a fraction ``dropout`` of returns is lost.
    ``laser_z_m``: optional (16,) vertical offsets [m] of the lasers, in firing order (the
    VLP-16 manual's calibration: each beam leaves the spin axis at its own height), so a
    point is (0, 0, z_j) + r (cos el_j cos az, cos el_j sin az, sin el_j).

    Returns
    -------
    points : (N, 3) float32 [m], sensor frame, acquisition order
    """
    rng = np.random.default_rng(seed)
    lo = -rng.uniform(0.3, 0.7, 3) * np.asarray(room)
    hi = lo + np.asarray(room)
    az = np.deg2rad(np.arange(0.0, 360.0 * n_revolutions, 0.2) + rng.uniform(0, 360))
    el = np.deg2rad(np.asarray(VLP16_FIRING_ORDER_DEG, np.float64))
    aa, ee = np.meshgrid(az, el, indexing="ij")  # azimuth-major: firing after firing
    d = directions(aa, ee).reshape(-1, 3)
    o = np.zeros((len(az), len(el), 3))
    if laser_z_m is not None:
        o[:, :, 2] = np.asarray(laser_z_m, np.float64).reshape(len(el))
    o = o.reshape(-1, 3)  # each beam's centre on the spin axis [m]
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf)).min(1)
    r = t + rng.normal(0.0, range_noise_m, len(t))
    if range_lattice_m:
        r = np.round(r / range_lattice_m) * range_lattice_m
    keep = rng.random(len(t)) >= dropout
    return (o[keep] + d[keep] * r[keep, None]).astype(np.float32)
