# SPDX-License-Identifier: BSD-3-Clause
"""Scene library and tripod motion of the simulator."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from tripod_processor.sim import SCENE_NAMES, MotionConfig, load_scene_file, make_scene
from tripod_processor.sim.motion import Trajectory
from tripod_processor.sim.scenes import CEILING, FLOOR, WALL, classify_by_normal, write_mesh_ply


def _raycaster(scene):
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    return rc


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_scene_is_closed_classified_and_route_is_free(name):
    scene = make_scene(name, seed=1)
    assert scene.triangles.max() < len(scene.vertices)
    counts = scene.class_counts()
    assert counts["ceiling"] > 0 and counts["floor"] > 0 and counts["wall"] > 0
    rc = _raycaster(scene)
    # from the route at tripod height every direction hits the mesh (the space is closed) ...
    rng = np.random.default_rng(0)
    L = len(scene.route)
    pts = np.array([scene.route[i % L] + (scene.route[(i + 1) % L] - scene.route[i % L]) * f
                    for i in range(L - (0 if scene.closed_route else 1)) for f in (0.0, 0.5)])
    o = np.c_[pts, np.full(len(pts), 1.45)]
    d = rng.normal(size=(len(o) * 500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = np.c_[np.repeat(o, 500, axis=0), d].astype(np.float32)
    t = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    assert np.isfinite(t).all()
    # ... and the route keeps clear of everything by 0.3 m at heights 0.5 .. 1.7 m (the head; door lintels are at 2.05 m)
    for z in (0.5, 1.0, 1.5, 1.7):
        q = np.c_[pts, np.full(len(pts), z)].astype(np.float32)
        assert rc.compute_distance(o3d.core.Tensor(q)).numpy().min() > 0.3, (name, z)


def test_scenes_depend_on_seed_only():
    a, b, c = make_scene("office", 4), make_scene("office", 4), make_scene("office", 5)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.classes, b.classes)
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)
    with pytest.raises(ValueError, match="unknown scene"):
        make_scene("castle", 0)


def test_mesh_ply_round_trip_keeps_classes(tmp_path):
    scene = make_scene("two_rooms", 2)
    path = tmp_path / "m.ply"
    write_mesh_ply(path, scene)
    back = load_scene_file(path)
    assert np.array_equal(back.classes, scene.classes)
    assert np.allclose(back.vertices, scene.vertices, atol=1e-5)
    m = o3d.io.read_triangle_mesh(str(path))  # opens in the usual tools
    assert len(m.triangles) == len(scene.triangles)


def test_foreign_mesh_is_classified_by_normals(tmp_path):
    box = o3d.geometry.TriangleMesh.create_box(6.0, 4.0, 3.0)
    path = tmp_path / "box.obj"
    o3d.io.write_triangle_mesh(str(path), box)
    scene = load_scene_file(path)
    c = scene.class_counts()
    assert c == {"ceiling": 2, "floor": 2, "wall": 8, "other": 0}
    cls = classify_by_normal(scene.vertices, scene.triangles)
    zc = scene.vertices[scene.triangles].mean(axis=1)[:, 2]
    assert np.all(zc[cls == FLOOR] < 0.1) and np.all(zc[cls == CEILING] > 2.9)
    assert (cls == WALL).sum() == 8
    with pytest.raises(FileNotFoundError):
        load_scene_file(tmp_path / "missing.ply")


def test_trajectory_stations_pans_and_transits():
    scene = make_scene("corridor", 3)
    cfg = MotionConfig()
    n = 5
    traj = Trajectory(scene.route, scene.closed_route, n, cfg, np.random.default_rng(1))
    assert np.all(traj.transit_s >= cfg.transit_s)
    assert traj.duration_s == pytest.approx(n * (2 * cfg.settle_s + cfg.pan_s) + traj.transit_s.sum())
    for st in traj.stations:
        t = np.linspace(st.t_pan_start_s - cfg.settle_s + 1e-6, st.t_pan_end_s + cfg.settle_s - 1e-6, 50)
        R, p = traj.T_world_base(t)
        assert np.ptp(p, axis=0).max() < 1e-9  # the tripod stands still during its station
        _, _, _, _, phi = traj.base_state(np.array([st.t_pan_start_s, st.t_pan_end_s]))
        assert phi[1] - phi[0] == pytest.approx(np.radians(360 + cfg.pan_overlap_deg))
        assert st.index == traj.station_of(np.array([st.t_pan_start_s + 0.5]))[0]
    yaws = np.array([s.yaw_rad for s in traj.stations])
    assert np.all(np.abs(np.diff(yaws)) <= np.pi + 1e-12)
    # smooth: speeds stay human (< 2 m/s) and rotations orthonormal
    t = np.arange(0, traj.duration_s, 0.005)
    R, p = traj.T_world_lidar(t)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9)
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / 0.005
    assert speed.max() < 2.5  # walking pace (offset from the route's centre line in corners)
    walks = np.abs(np.diff([st.arc_m for st in traj.stations]))
    assert np.all(walks / traj.transit_s <= cfg.max_carry_speed_m_s / 1.875 + 1e-9)
