# SPDX-License-Identifier: BSD-3-Clause
"""Static station scans for registration tests and benchmarks: the simulator's scenes and VLP-16
beam model, ray-cast directly to points (no packets), one revolution per head tilt.

A tripod fragment is dense because the head tilts the VLP-16 through several angles while it
spins; ``tilts_deg`` sets them. Points are returned in the lidar frame of the station.
"""

from __future__ import annotations

import numpy as np

from .beams import LASER_VERT_OFFSET_M, firing_directions
from .motion import rot_x
from .scenes import MeshBuilder, Scene


def box_room(width: float = 7.0, depth: float = 4.5, height: float = 2.8) -> Scene:
    """An empty rectangular room (floor, ceiling, four walls): symmetric under 180 deg turns."""
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, width, depth)], height)
    m = 1.0
    route = [(m, m), (width - m, m), (width - m, depth - m), (m, depth - m)]
    return mb.build("box_room", route, True, {"width_m": width, "depth_m": depth,
                                              "height_m": height}, np.random.default_rng(0))


def station_scan(scene: Scene, T_world_lidar: np.ndarray, tilts_deg=(-20, -10, 0, 10, 20),
                 azimuth_step_deg: float = 0.2, range_noise_m: float = 0.03,
                 max_range_m: float = 100.0, seed: int = 0) -> np.ndarray:
    """Ray-cast one revolution per head tilt from a static station.

    Parameters
    ----------
    scene : Scene
        From :func:`tripod_processor.sim.scenes.make_scene` or :func:`box_room`.
    T_world_lidar : (4, 4) array_like
        Station pose (lidar frame at zero tilt) [m].
    tilts_deg : sequence of float
        Head tilts about the lidar x axis [deg], one revolution each.
    azimuth_step_deg : float
        Firing azimuth spacing [deg] (0.2 at 600 rpm).
    range_noise_m : float
        Sigma of Gaussian range noise [m].
    seed : int

    Returns
    -------
    (N, 3) float32 ndarray of points in the station's lidar frame [m].
    """
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    T = np.asarray(T_world_lidar, dtype=np.float64)
    az = np.arange(0.0, 360.0, azimuth_step_deg)
    d_head = firing_directions(np.repeat(az[:, None], 16, axis=1)).reshape(-1, 3)
    o_head = np.zeros_like(d_head)
    o_head[:, 2] = np.tile(LASER_VERT_OFFSET_M, len(az))
    rng = np.random.default_rng(seed)
    out = []
    for tilt in tilts_deg:
        R_lidar_head = rot_x(np.radians(np.array([tilt], dtype=np.float64)))[0]
        d = d_head @ R_lidar_head.T
        o = o_head @ R_lidar_head.T
        dw = d @ T[:3, :3].T
        ow = o @ T[:3, :3].T + T[:3, 3]
        rays = np.concatenate([ow, dw], axis=1).astype(np.float32)
        t = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
        ok = np.isfinite(t) & (t > 0.4) & (t < max_range_m)
        t = t + rng.normal(0.0, range_noise_m, len(t))
        out.append(o[ok] + d[ok] * t[ok, None])
    return np.concatenate(out).astype(np.float32)


def pose(yaw_deg: float = 0.0, xyz=(0.0, 0.0, 0.0), roll_deg: float = 0.0,
         pitch_deg: float = 0.0) -> np.ndarray:
    """4x4 pose from roll, pitch, yaw [deg] (R = Rz Ry Rx) and a translation [m]."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T
